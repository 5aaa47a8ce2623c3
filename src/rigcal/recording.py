"""Raw sensor data as immutable values: what readers (bags, folders) produce and detectors eat.

Every frame carries the sensor name, a timestamp in integer nanoseconds (``t_ns``) and its
data in the sensor's own frame (lidar/radar: x forward, y left, z up; camera: optical frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Union

import numpy as np

from rigcal.errors import InputError


def _frozen(a: np.ndarray, dtype=None) -> np.ndarray:
    """A read-only array of ``a``: ``a`` itself when nobody can write to it any more (read-only
    all the way down to an owner or to immutable bytes, as the file readers hand over), else a
    read-only copy."""
    if isinstance(a, np.ndarray) and (dtype is None or a.dtype == np.dtype(dtype)) and _sealed(a):
        return a
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


def _sealed(a: np.ndarray) -> bool:
    b: object = a
    while isinstance(b, np.ndarray):
        if b.flags.writeable:
            return False
        if b.base is None:
            return True
        b = b.base
    return isinstance(b, bytes)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PointCloudFrame:
    """A point cloud: ``points_xyz`` (N, 3) [m] plus optional per-point ``fields`` (N,) such as
    ``intensity``, ``ring`` (lidar laser index) or ``rcs`` (radar cross-section, dBsm).

    ``organized_shape`` (H, W) is set when the cloud is organised (e.g. from a stereo camera):
    row-major, invalid points NaN.
    """

    sensor: str
    t_ns: int
    points_xyz: np.ndarray
    fields: Mapping[str, np.ndarray] = field(default_factory=dict)
    organized_shape: tuple[int, int] | None = None
    frame_id: str = ""

    def __post_init__(self) -> None:
        pts = _frozen(self.points_xyz, float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(
                f"sensor '{self.sensor}': a point cloud must be (N, 3) x, y, z, got {pts.shape}"
            )
        object.__setattr__(self, "points_xyz", pts)
        flds = {}
        for k, v in dict(self.fields).items():
            arr = _frozen(v)
            if arr.shape != (pts.shape[0],):
                raise InputError(
                    f"sensor '{self.sensor}': field '{k}' has shape {arr.shape}, expected "
                    f"({pts.shape[0]},)"
                )
            flds[k] = arr
        object.__setattr__(self, "fields", MappingProxyType(flds))
        object.__setattr__(self, "t_ns", int(self.t_ns))
        if self.organized_shape is not None:
            h, w = (int(x) for x in self.organized_shape)
            if h * w != pts.shape[0]:
                raise InputError(
                    f"sensor '{self.sensor}': organised shape {h}x{w} does not match "
                    f"{pts.shape[0]} points"
                )
            object.__setattr__(self, "organized_shape", (h, w))

    def __len__(self) -> int:
        return int(self.points_xyz.shape[0])


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class ImageFrame:
    """An image (H, W) mono or (H, W, 3) BGR, uint8, as OpenCV uses it."""

    sensor: str
    t_ns: int
    image: np.ndarray
    frame_id: str = ""

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
            raise InputError(
                f"sensor '{self.sensor}': expected a uint8 image (H, W) or (H, W, 3), got "
                f"{img.dtype} {img.shape}"
            )
        object.__setattr__(self, "image", _frozen(img))
        object.__setattr__(self, "t_ns", int(self.t_ns))

    @property
    def size_wh(self) -> tuple[int, int]:
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class StereoFrame:
    """A rectified stereo pair (left, right), both uint8 of the same size."""

    sensor: str
    t_ns: int
    left: np.ndarray
    right: np.ndarray
    frame_id: str = ""

    def __post_init__(self) -> None:
        lft, rgt = np.asarray(self.left), np.asarray(self.right)
        if lft.shape != rgt.shape or lft.dtype != np.uint8 or rgt.dtype != np.uint8:
            raise InputError(
                f"sensor '{self.sensor}': a stereo pair needs two uint8 images of one size, got "
                f"{lft.dtype} {lft.shape} and {rgt.dtype} {rgt.shape}"
            )
        object.__setattr__(self, "left", _frozen(lft))
        object.__setattr__(self, "right", _frozen(rgt))
        object.__setattr__(self, "t_ns", int(self.t_ns))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class RadarFrame:
    """A radar detection list: ``points`` (N, 2) x, y for a 2D radar or (N, 3) for a 3D radar
    [m], ``rcs_dbsm`` (N,) radar cross-sections (NaN if unknown)."""

    sensor: str
    t_ns: int
    points: np.ndarray
    rcs_dbsm: np.ndarray
    frame_id: str = ""

    def __post_init__(self) -> None:
        pts = _frozen(self.points, float)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise InputError(
                f"sensor '{self.sensor}': radar detections must be (N, 2) or (N, 3), got {pts.shape}"
            )
        rcs = _frozen(self.rcs_dbsm, float)
        if rcs.shape != (pts.shape[0],):
            raise InputError(
                f"sensor '{self.sensor}': {pts.shape[0]} radar detections but {rcs.shape} RCS values"
            )
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "rcs_dbsm", rcs)
        object.__setattr__(self, "t_ns", int(self.t_ns))


Frame = Union[PointCloudFrame, ImageFrame, StereoFrame, RadarFrame]
