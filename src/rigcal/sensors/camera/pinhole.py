"""The pinhole camera: ``u = fx * x / z + cx``, ``v = fy * y / z + cy`` (no distortion, no skew).

Parameters ``(fx, fy, cx, cy)`` [px]; points in the camera optical frame (z forward) [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.sensors.camera.base import CameraModel


def normalised_jacobian(points: np.ndarray) -> np.ndarray:
    """(N, 2, 3) derivative of ``(x / z, y / z)`` with respect to ``(x, y, z)``."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    J = np.zeros((points.shape[0], 2, 3))
    J[:, 0, 0] = 1.0 / z
    J[:, 1, 1] = 1.0 / z
    J[:, 0, 2] = -x / (z * z)
    J[:, 1, 2] = -y / (z * z)
    return J


@dataclass(frozen=True, eq=False, repr=False)
class PinholeCamera(CameraModel):
    """An undistorted pinhole camera; ``params = (fx, fy, cx, cy)`` [px]."""

    name = "pinhole"
    param_names = ("fx", "fy", "cx", "cy")

    @classmethod
    def from_intrinsics(
        cls, width: int, height: int, fx: float, fy: float, cx: float, cy: float
    ) -> "PinholeCamera":
        return cls(width, height, np.array([fx, fy, cx, cy], dtype=float))

    @property
    def dist_coeffs(self) -> np.ndarray:
        """(5,) OpenCV distortion coefficients (all zero)."""
        return np.zeros(5)

    def _project(self, points: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params
        xn = points[:, :2] / points[:, 2:3]
        return np.stack([fx * xn[:, 0] + cx, fy * xn[:, 1] + cy], axis=1)

    def _project_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        return normalised_jacobian(points) * np.array([fx, fy])[None, :, None]

    def _params_jacobian(self, points: np.ndarray) -> np.ndarray:
        xn = points[:, :2] / points[:, 2:3]
        J = np.zeros((points.shape[0], 2, 4))
        J[:, 0, 0] = xn[:, 0]
        J[:, 1, 1] = xn[:, 1]
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        return J

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params
        return np.stack(
            [(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy, np.ones(uv.shape[0])], axis=1
        )
