"""A calibration target as data: keypoints and a template cloud in the target frame.

Charron et al. (section III) make the calibration target-agnostic: a target is known by

* ``lidar_keypoints`` (N, 3): points a lidar extractor measures (the diamond's 4 corners, the
  circle board's 4 hole centres), or None when the target has no distinct lidar keypoints
  (the cylinder: its template points are used instead);
* ``camera_keypoints`` (M, 3): points a camera extractor measures (checkerboard inner corners,
  hole centres), or None (the cylinder: its contour is matched against the template);
* ``template`` (K, 3): a dense cloud of the target's surface, for ICP and for correspondence
  search when keypoints are not distinct;
* ``crop_box``: an axis-aligned box in the target frame that contains the target, to cut
  measurements out of a scan once the target's pose is roughly known.

All coordinates are metres in the target frame, the frame the motion capture system tracks
(``T_M_T`` maps target-frame points into the mocap frame). Analytic targets are built in
:mod:`rigcal.targets.templates`; the original tool's JSON files are read by
:mod:`rigcal.io.config.vicon_json`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from rigcal.errors import InputError

__all__ = ["CropBox", "Target", "TargetKind"]


class TargetKind(str, Enum):
    """Which analytic shape a target has (``custom``: only keypoints and a template)."""

    CHECKERBOARD_DIAMOND = "checkerboard_diamond"
    CYLINDER = "cylinder"
    CIRCLE_BOARD = "circle_board"
    CUSTOM = "custom"

    @classmethod
    def parse(cls, value: Any, what: str = "target kind") -> "TargetKind":
        if isinstance(value, TargetKind):
            return value
        try:
            return cls(str(value).strip().lower())
        except ValueError:
            raise InputError(
                f"{what}: unknown target kind {value!r} (expected one of "
                f"{', '.join(k.value for k in cls)})"
            ) from None


def _points(value: Any, what: str, allow_none: bool) -> np.ndarray | None:
    if value is None:
        if allow_none:
            return None
        raise InputError(f"{what}: expected an (N, 3) array of points, got None")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected an (N, 3) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise InputError(f"{what}: expected a non-empty (N, 3) array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: points must be finite (no NaN or infinity)")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class CropBox:
    """Axis-aligned box in the target frame: ``min_xyz`` <= p <= ``max_xyz`` [m]."""

    min_xyz: np.ndarray
    max_xyz: np.ndarray

    def __post_init__(self) -> None:
        lo = np.array(self.min_xyz, dtype=float).reshape(-1)
        hi = np.array(self.max_xyz, dtype=float).reshape(-1)
        if lo.shape != (3,) or hi.shape != (3,):
            raise InputError(f"crop box: min and max need 3 values each, got {lo.size} and "
                             f"{hi.size}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise InputError("crop box: bounds must be finite")
        if np.any(lo >= hi):
            axis = "xyz"[int(np.flatnonzero(lo >= hi)[0])]
            raise InputError(
                f"crop box: {axis} min must be below max, got min {lo.tolist()} max {hi.tolist()}"
            )
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "min_xyz", lo)
        object.__setattr__(self, "max_xyz", hi)

    @classmethod
    def from_bounds(cls, bounds: Any) -> "CropBox":
        """From ``(x_min, x_max, y_min, y_max, z_min, z_max)`` (the original tool's
        ``crop_scan`` layout)."""
        b = np.asarray(bounds, dtype=float).reshape(-1)
        if b.size != 6:
            raise InputError(f"crop box: expected 6 bounds (x_min, x_max, y_min, y_max, z_min, "
                             f"z_max), got {b.size}")
        return cls(b[0::2], b[1::2])

    @classmethod
    def around(cls, points: Any, margin_m: float) -> "CropBox":
        """The bounding box of ``points`` (N, 3) grown by ``margin_m`` on every side."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if not (math.isfinite(margin_m) and margin_m > 0):
            raise InputError(f"crop box: margin_m must be > 0, got {margin_m!r}")
        return cls(p.min(axis=0) - margin_m, p.max(axis=0) + margin_m)

    def bounds(self) -> tuple[float, float, float, float, float, float]:
        """``(x_min, x_max, y_min, y_max, z_min, z_max)``."""
        lo, hi = self.min_xyz, self.max_xyz
        return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), float(lo[2]),
                float(hi[2]))

    def contains(self, points_target: Any) -> np.ndarray:
        """(N,) bool: which points (N, 3), given in the target frame, are inside the box."""
        p = np.asarray(points_target, dtype=float).reshape(-1, 3)
        return np.all((p >= self.min_xyz) & (p <= self.max_xyz), axis=1)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Target:
    """A calibration target in its own frame (see the module docstring).

    ``dims`` holds the shape's dimensions by name, units in the name (``side_m``,
    ``square_m``, ``rows``, ``cols``, ``radius_m``, ``height_m``, ``spacing_m``, ...).
    ``planar`` says the target is a plate (the original tool's ``is_target_2d``).
    ``use_lidar_keypoints``: match lidar measurements against ``lidar_keypoints`` (True) or
    against the template (False; the cylinder, or sparse lidars). ``crop_image_px`` keeps the
    original tool's ``crop_image`` (image margins [px], width and height) when known."""

    name: str
    kind: TargetKind
    template: np.ndarray
    lidar_keypoints: np.ndarray | None = None
    camera_keypoints: np.ndarray | None = None
    dims: Mapping[str, float] = field(default_factory=dict)
    crop_box: CropBox | None = None
    planar: bool = False
    use_lidar_keypoints: bool = True
    crop_image_px: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InputError(f"target: name must be a non-empty string, got {self.name!r}")
        what = f"target '{self.name}'"
        object.__setattr__(self, "kind", TargetKind.parse(self.kind, what))
        object.__setattr__(self, "template", _points(self.template, f"{what}: template", False))
        object.__setattr__(self, "lidar_keypoints",
                           _points(self.lidar_keypoints, f"{what}: lidar_keypoints", True))
        object.__setattr__(self, "camera_keypoints",
                           _points(self.camera_keypoints, f"{what}: camera_keypoints", True))
        dims: dict[str, float] = {}
        for k, v in dict(self.dims).items():
            if not isinstance(k, str) or not k:
                raise InputError(f"{what}: dims keys must be names, got {k!r}")
            ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            if not ok or not math.isfinite(float(v)):
                raise InputError(f"{what}: dims['{k}'] must be a finite number, got {v!r}")
            dims[k] = int(v) if isinstance(v, (int, np.integer)) else float(v)
        object.__setattr__(self, "dims", MappingProxyType(dims))
        if self.crop_box is not None and not isinstance(self.crop_box, CropBox):
            raise InputError(f"{what}: crop_box must be a CropBox or None")
        if self.use_lidar_keypoints and self.lidar_keypoints is None:
            raise InputError(f"{what}: use_lidar_keypoints is set but there are no lidar "
                             "keypoints")
        object.__setattr__(self, "planar", bool(self.planar))
        object.__setattr__(self, "use_lidar_keypoints", bool(self.use_lidar_keypoints))
        if self.crop_image_px is not None:
            c = tuple(float(v) for v in np.asarray(self.crop_image_px, dtype=float).reshape(-1))
            if len(c) != 2 or not all(math.isfinite(v) and v >= 0 for v in c):
                raise InputError(f"{what}: crop_image_px must be two numbers >= 0, got "
                                 f"{self.crop_image_px!r}")
            object.__setattr__(self, "crop_image_px", c)

    @property
    def lidar_points(self) -> np.ndarray:
        """(N, 3) the points lidar measurements are matched to: keypoints or the template."""
        if self.use_lidar_keypoints and self.lidar_keypoints is not None:
            return self.lidar_keypoints
        return self.template

    @property
    def camera_points(self) -> np.ndarray:
        """(M, 3) the points camera measurements are matched to: keypoints or the template."""
        return self.camera_keypoints if self.camera_keypoints is not None else self.template

    def with_template(self, template: Any) -> "Target":
        """A new Target with another template cloud (K, 3) in the target frame."""
        return replace(self, template=template)

    def with_params(self, **changes: Any) -> "Target":
        """A new Target with the given fields replaced (validated again)."""
        return replace(self, **changes)
