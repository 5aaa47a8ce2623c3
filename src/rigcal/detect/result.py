"""What a detector returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Union

import numpy as np


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class BoardDetection:
    """The board found in one frame, in the sensor's frame.

    ``points``: lidar/camera (4, 3) circle centres ordered top-left, top-right, bottom-left,
    bottom-right as seen from the sensor (the layout of :mod:`rigcal.dataset`); 2D radar (2,)
    reflector x, y; 3D radar (3,). ``quality`` holds detector-specific figures (e.g. plane RMS,
    circle fit residuals, square error) for diagnostics.
    """

    sensor: str
    t_ns: int
    points: np.ndarray
    quality: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=float)
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "quality", MappingProxyType(dict(self.quality)))
        object.__setattr__(self, "t_ns", int(self.t_ns))

    @property
    def ok(self) -> bool:
        return True


@dataclass(frozen=True)
class DetectionFailure:
    """No board in this frame, and why. ``reason`` is a short stable code (for summary tables,
    e.g. ``"no_plane"``, ``"not_square"``), ``detail`` a human sentence with the numbers seen."""

    sensor: str
    t_ns: int
    reason: str
    detail: str = ""

    @property
    def ok(self) -> bool:
        return False


DetectionResult = Union[BoardDetection, DetectionFailure]
