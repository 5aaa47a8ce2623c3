"""A frame-checked transform value for API edges; inner loops use raw (4, 4) arrays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.errors import GeometryError
from rigcal.geometry.se3 import invert, transform_points


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Transform:
    """``matrix`` maps a point in ``from_frame`` into ``to_frame`` (``T_to_from``).

    Composition checks frames: ``T_a_b @ T_b_c`` works, ``T_a_b @ T_c_d`` raises GeometryError.
    """

    matrix: np.ndarray
    to_frame: str
    from_frame: str

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=float)
        if m.shape != (4, 4):
            raise GeometryError(
                f"transform {self.to_frame}<-{self.from_frame} must be a 4x4 matrix, got shape {m.shape}"
            )
        if not np.all(np.isfinite(m)):
            raise GeometryError(
                f"transform {self.to_frame}<-{self.from_frame} has non-finite entries (NaN or inf)"
            )
        R = m[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise GeometryError(
                f"transform {self.to_frame}<-{self.from_frame} has no proper rotation block"
            )
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise GeometryError(
                f"transform {self.to_frame}<-{self.from_frame} last row must be [0, 0, 0, 1]"
            )
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)

    def __matmul__(self, other: "Transform") -> "Transform":
        if not isinstance(other, Transform):
            return NotImplemented
        if self.from_frame != other.to_frame:
            raise GeometryError(
                f"cannot compose T_{self.to_frame}_{self.from_frame} with "
                f"T_{other.to_frame}_{other.from_frame}: inner frames "
                f"'{self.from_frame}' and '{other.to_frame}' differ"
            )
        return Transform(self.matrix @ other.matrix, self.to_frame, other.from_frame)

    def inverse(self) -> "Transform":
        return Transform(invert(self.matrix), self.from_frame, self.to_frame)

    def apply(self, points_from: np.ndarray) -> np.ndarray:
        """Map (N, 3) points from ``from_frame`` into ``to_frame``."""
        return transform_points(self.matrix, points_from)
