"""Detections of a calibration board by every sensor of a rig: immutable values.

A dataset has K board placements. Each sensor holds a dense table of its detections with a
validity mask (NaN rows are "not detected"):

* ``lidar`` / ``camera``: ``points`` (K, 4, 3) circle centres in the sensor frame [m], ordered
  top-left, top-right, bottom-left, bottom-right as seen from the front of the board;
* ``radar`` (2D): ``points`` (K, 2) reflector position (x, y) in the radar frame [m], i.e.
  range * (cos azimuth, sin azimuth) - elevation is not measured;
* ``radar3d``: ``points`` (K, 3) reflector position in the radar frame [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum
from functools import cached_property
from typing import Iterable, Mapping

import numpy as np

from rigcal.errors import InputError


class SensorKind(str, Enum):
    LIDAR = "lidar"
    CAMERA = "camera"
    RADAR = "radar"  # 2D: range + azimuth, within an elevation field of view
    RADAR3D = "radar3d"

    @property
    def is_point_cloud(self) -> bool:
        """True for sensors that measure the four circle centres in 3D."""
        return self in (SensorKind.LIDAR, SensorKind.CAMERA)

    @property
    def is_radar(self) -> bool:
        return self in (SensorKind.RADAR, SensorKind.RADAR3D)

    @property
    def point_shape(self) -> tuple[int, ...]:
        """Shape of one board's detection."""
        return {
            SensorKind.LIDAR: (4, 3),
            SensorKind.CAMERA: (4, 3),
            SensorKind.RADAR: (2,),
            SensorKind.RADAR3D: (3,),
        }[self]

    @classmethod
    def parse(cls, value: str, where: str) -> "SensorKind":
        try:
            return cls(str(value).strip().lower())
        except ValueError:
            allowed = ", ".join(k.value for k in cls)
            raise InputError(f"{where}: unknown sensor kind '{value}' (expected one of: {allowed})")


DEFAULT_MAX_ELEVATION_DEG = 9.0


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class SensorDetections:
    """One sensor's detections of K board placements (see module docstring for layouts)."""

    name: str
    kind: SensorKind
    points: np.ndarray
    frame_id: str = ""
    max_elevation_rad: float = math.radians(DEFAULT_MAX_ELEVATION_DEG)
    source: str = ""
    excluded: frozenset[int] = field(default_factory=frozenset)
    #: tolerances of the sensor's nominal mounting (``prior`` in the manifest; see
    #: :mod:`rigcal.problem.priors`): direction -> 1-sigma [m / deg]; empty: none
    prior: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=float)
        expected = self.kind.point_shape
        if pts.ndim != 1 + len(expected) or pts.shape[1:] != expected:
            raise InputError(
                f"sensor '{self.name}' ({self.kind.value}): detections must have shape "
                f"(K, {', '.join(map(str, expected))}), got {pts.shape}"
            )
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)
        if not self.frame_id:
            object.__setattr__(self, "frame_id", self.name)
        object.__setattr__(self, "excluded", frozenset(int(k) for k in self.excluded))
        object.__setattr__(self, "prior", dict(self.prior))

    @property
    def num_boards(self) -> int:
        return int(self.points.shape[0])

    @property
    def detected(self) -> np.ndarray:
        """(K,) bool: every coordinate of the board's detection is finite."""
        flat = self.points.reshape(self.num_boards, -1)
        return np.all(np.isfinite(flat), axis=1)

    @property
    def valid(self) -> np.ndarray:
        """(K,) bool: detected and not excluded (ignore file or outlier)."""
        v = self.detected.copy()
        for k in self.excluded:
            if 0 <= k < v.size:
                v[k] = False
        return v

    def with_excluded(self, boards: Iterable[int]) -> "SensorDetections":
        """A copy with ``boards`` added to the excluded set."""
        return replace(self, excluded=self.excluded | frozenset(int(b) for b in boards))


@dataclass(frozen=True)
class BoardGeometry:
    """The circle board of Domhof et al.: four holes on a square, a corner reflector behind."""

    spacing_m: float = 0.24
    reflector_offset_m: float = 0.105
    hole_diameter_m: float = 0.15
    width_m: float = 1.0
    height_m: float = 1.5

    def __post_init__(self) -> None:
        for name in ("spacing_m", "hole_diameter_m", "width_m", "height_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"board.{name} must be a positive number, got {v!r}")
        if not (math.isfinite(self.reflector_offset_m) and self.reflector_offset_m >= 0):
            raise InputError(
                f"board.reflector_offset_m must be >= 0, got {self.reflector_offset_m!r}"
            )


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Dataset:
    """All sensors' detections of the same K board placements."""

    sensors: tuple[SensorDetections, ...]
    board: BoardGeometry = BoardGeometry()
    reference: str | None = None
    source: str = ""

    def __post_init__(self) -> None:
        sensors = tuple(self.sensors)
        object.__setattr__(self, "sensors", sensors)
        if len(sensors) < 2:
            raise InputError(
                f"{self.source or 'dataset'}: calibration needs at least two sensors, "
                f"got {len(sensors)}"
            )
        names = [s.name for s in sensors]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise InputError(f"{self.source or 'dataset'}: duplicate sensor names: {dupes}")
        counts = {s.name: s.num_boards for s in sensors}
        if len(set(counts.values())) != 1:
            detail = ", ".join(f"{n}: {c}" for n, c in counts.items())
            raise InputError(
                f"{self.source or 'dataset'}: sensors have different numbers of board "
                f"placements ({detail}); every detection file must cover the same K boards"
            )
        if self.reference is not None and self.reference not in names:
            raise InputError(
                f"{self.source or 'dataset'}: reference sensor '{self.reference}' is not one of "
                f"{names}"
            )

    @property
    def num_boards(self) -> int:
        return self.sensors[0].num_boards

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    @cached_property
    def derived(self) -> dict:
        """Values computed from this dataset, kept with it (it is immutable): e.g. the
        comparable pairs' anchors on all boards (:func:`rigcal.problem.pairs.pair_data`)."""
        return {}

    @cached_property
    def pairs(self) -> tuple[tuple[str, str], ...]:
        """Every comparable sensor pair ``(a, b)`` in dataset order, derived once per dataset
        (two 2D radars share no 3D point, so they are not a pair)."""
        radar = SensorKind.RADAR
        return tuple(
            (a.name, b.name)
            for i, a in enumerate(self.sensors)
            for b in self.sensors[i + 1:]
            if not (a.kind == radar and b.kind == radar)
        )

    def sensor(self, name: str) -> SensorDetections:
        for s in self.sensors:
            if s.name == name:
                return s
        raise InputError(f"unknown sensor '{name}' (sensors: {list(self.names)})")

    def with_excluded(self, exclusions: Mapping[str, Iterable[int]]) -> "Dataset":
        """A copy where ``exclusions[sensor]`` boards are marked invalid for that sensor."""
        for name in exclusions:
            self.sensor(name)  # raises for unknown names
        new = tuple(
            s.with_excluded(exclusions.get(s.name, ())) if s.name in exclusions else s
            for s in self.sensors
        )
        return replace(self, sensors=new)

    def with_reference(self, reference: str | None) -> "Dataset":
        return replace(self, reference=reference)

    def select_boards(self, boards: Iterable[int]) -> "Dataset":
        """A copy in which only ``boards`` stay valid (others excluded) - for cross-validation."""
        keep = set(int(b) for b in boards)
        drop = [k for k in range(self.num_boards) if k not in keep]
        return self.with_excluded({s.name: drop for s in self.sensors})
