"""What a measurement extractor returns: a :class:`Measurement` or an :class:`ExtractionFailure`.

A measurement holds the target keypoints measured in one sensor frame (Charron et al., III-C):

* camera, checkerboard: ``keypoints`` (N, 2) corner pixels [px], ordered like the target's
  camera keypoints (``keypoint_index[i]`` is the row of the target keypoint that pixel i sees);
* camera, cylinder: the pixels of the silhouette's contour (N, 2) [px], no correspondences
  (``keypoint_index`` is None);
* lidar, keypoint target (diamond): the target's lidar keypoints (K, 3) [m] in the sensor frame,
  put there by the ICP-refined target pose;
* lidar, keypoint-free target (cylinder): the scan points (N, 3) [m] that lie on the fitted
  template (the "edge points"), no correspondences.

``T_sensor_target`` is the refined pose of the target frame in the sensor frame (PnP or ICP),
or None when the extractor was asked not to estimate it. ``extras`` holds named read-only arrays
(each extractor documents its keys), ``quality`` named figures for diagnostics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Union

import numpy as np

from rigcal.errors import InputError

# Reason codes of ExtractionFailure: short, stable, for summary tables.
TARGET_NOT_IN_VIEW = "target_not_in_view"
TARGET_MOVING = "target_moving"
NO_POSE_DATA = "no_pose_data"
CROP_OUTSIDE_IMAGE = "crop_outside_image"
BLACK_IMAGE = "black_image"
NO_CORNERS = "no_corners"
PATTERN_SIZE_MISMATCH = "pattern_size_mismatch"
PNP_FAILED = "pnp_failed"
NO_OUTLINE = "no_outline"
NO_CONTOUR = "no_contour"
NO_POINTS_IN_CROP = "no_points_in_crop"
NO_CLUSTER = "no_cluster"
ICP_DIVERGED = "icp_diverged"
#: a grid whose symmetric orderings (a checkerboard turned half round) the guess cannot tell apart
ORIENTATION_AMBIGUOUS = "orientation_ambiguous"

REASONS = frozenset(
    {
        TARGET_NOT_IN_VIEW,
        TARGET_MOVING,
        NO_POSE_DATA,
        CROP_OUTSIDE_IMAGE,
        BLACK_IMAGE,
        NO_CORNERS,
        PATTERN_SIZE_MISMATCH,
        PNP_FAILED,
        NO_OUTLINE,
        NO_CONTOUR,
        NO_POINTS_IN_CROP,
        NO_CLUSTER,
        ICP_DIVERGED,
        ORIENTATION_AMBIGUOUS,
    }
)
"""Every reason code an extractor may report."""


def _frozen(a: np.ndarray, dtype=None) -> np.ndarray:
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Measurement:
    """Target keypoints measured in one sensor frame at one time (see the module docstring).

    ``target`` names the target kind (``"checkerboard"``, ``"cylinder"``, ``"diamond"``, ...).
    ``keypoints``: (N, 2) pixels or (N, 3) points [m] in the sensor frame.
    ``keypoint_index``: (N,) int rows into the target's keypoints, or None (no correspondences).
    ``T_sensor_target``: (4, 4) refined target pose in the sensor frame, or None.
    """

    sensor: str
    t_ns: int
    target: str
    keypoints: np.ndarray
    keypoint_index: np.ndarray | None = None
    T_sensor_target: np.ndarray | None = None
    extras: Mapping[str, np.ndarray] = field(default_factory=dict)
    quality: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        kp = _frozen(self.keypoints, float)
        if kp.ndim != 2 or kp.shape[1] not in (2, 3):
            raise InputError(
                f"sensor '{self.sensor}': measurement keypoints must be (N, 2) pixels or (N, 3) "
                f"points, got shape {kp.shape}"
            )
        object.__setattr__(self, "keypoints", kp)
        if self.keypoint_index is not None:
            idx = _frozen(self.keypoint_index, int)
            if idx.shape != (kp.shape[0],):
                raise InputError(
                    f"sensor '{self.sensor}': keypoint_index has shape {idx.shape}, expected "
                    f"({kp.shape[0]},)"
                )
            object.__setattr__(self, "keypoint_index", idx)
        if self.T_sensor_target is not None:
            T = _frozen(self.T_sensor_target, float)
            if T.shape != (4, 4):
                raise InputError(
                    f"sensor '{self.sensor}': T_sensor_target must be 4x4, got {T.shape}"
                )
            object.__setattr__(self, "T_sensor_target", T)
        object.__setattr__(
            self, "extras", MappingProxyType({k: _frozen(v) for k, v in dict(self.extras).items()})
        )
        object.__setattr__(
            self, "quality", MappingProxyType({k: float(v) for k, v in dict(self.quality).items()})
        )
        object.__setattr__(self, "t_ns", int(self.t_ns))

    @property
    def ok(self) -> bool:
        return True

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])


@dataclass(frozen=True)
class ExtractionFailure:
    """No measurement from this frame, and why: ``reason`` is one of :data:`REASONS`,
    ``detail`` a sentence with the numbers seen."""

    sensor: str
    t_ns: int
    reason: str
    detail: str = ""

    def __post_init__(self) -> None:
        if self.reason not in REASONS:
            raise InputError(
                f"unknown extraction failure reason '{self.reason}' "
                f"(expected one of {sorted(REASONS)})"
            )
        object.__setattr__(self, "t_ns", int(self.t_ns))

    @property
    def ok(self) -> bool:
        return False


ExtractionResult = Union[Measurement, ExtractionFailure]
