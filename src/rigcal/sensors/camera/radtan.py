"""The radial-tangential ("plumb bob") camera: OpenCV's and ROS's default distortion model.

Parameters ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)``. With ``(x', y') = (x / z, y / z)`` and
``r2 = x'^2 + y'^2``::

    radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x'' = x' radial + 2 p1 x' y' + p2 (r2 + 2 x'^2)
    y'' = y' radial + p1 (r2 + 2 y'^2) + 2 p2 x' y'
    u = fx x'' + cx,   v = fy y'' + cy

(the same as ``cv2.projectPoints`` with ``distCoeffs = (k1, k2, p1, p2, k3)``). A polynomial
distortion folds back far from the centre; the model's domain is the disc of normalised radius
where the radial map ``r -> r * radial(r^2)`` still increases (:attr:`RadtanCamera.max_radius`),
so points beyond it are reported invalid instead of landing at a wrong pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rigcal.errors import InputError
from rigcal.sensors.camera.base import CameraModel, as_pixels, intrinsics_from_camera_matrix
from rigcal.sensors.camera.pinhole import normalised_jacobian

_UNDISTORT_ITERATIONS = 30
_UNDISTORT_TOL = 1e-12  # normalised units, squared residual


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) of ideal ones ``xn`` (N, 2);
    ``dist = (k1, k2, p1, p2, k3)``."""
    k1, k2, p1, p2, k3 = dist
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def distort_jacobian(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 2, 2) derivative of :func:`distort` with respect to ``xn``."""
    k1, k2, p1, p2, k3 = dist
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    J = np.empty((xn.shape[0], 2, 2))
    J[:, 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    J[:, 0, 1] = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 0] = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return J


def monotonic_radius(k1: float, k2: float, k3: float) -> float:
    """Largest normalised radius up to which ``r * (1 + k1 r^2 + k2 r^4 + k3 r^6)`` increases
    (``inf`` if it always does)."""
    # d/dr = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 with s = r^2
    roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])
    s = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    return math.sqrt(min(s)) if s else math.inf


@dataclass(frozen=True, eq=False, repr=False)
class RadtanCamera(CameraModel):
    """Pinhole + plumb-bob distortion; ``params = (fx, fy, cx, cy, k1, k2, p1, p2, k3)``."""

    name = "radtan"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

    @classmethod
    def from_intrinsics(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        k1: float = 0.0,
        k2: float = 0.0,
        p1: float = 0.0,
        p2: float = 0.0,
        k3: float = 0.0,
    ) -> "RadtanCamera":
        return cls(width, height, np.array([fx, fy, cx, cy, k1, k2, p1, p2, k3], dtype=float))

    @classmethod
    def from_opencv(
        cls, width: int, height: int, camera_matrix: np.ndarray, dist_coeffs: np.ndarray
    ) -> "RadtanCamera":
        """From OpenCV's K (3, 3) and ``(k1, k2, p1, p2[, k3])``; K must have no skew."""
        d = np.asarray(dist_coeffs, dtype=float).reshape(-1)
        if d.size not in (4, 5):
            raise InputError(
                f"radtan camera: expected 4 or 5 distortion coefficients (k1, k2, p1, p2[, k3]), "
                f"got {d.size}"
            )
        fx, fy, cx, cy = intrinsics_from_camera_matrix(camera_matrix, "radtan")
        k3 = d[4] if d.size == 5 else 0.0
        return cls.from_intrinsics(width, height, fx, fy, cx, cy, d[0], d[1], d[2], d[3], k3)

    # ------------------------------------------------------------------ OpenCV interop
    @property
    def dist_coeffs(self) -> np.ndarray:
        """(5,) OpenCV distortion coefficients ``(k1, k2, p1, p2, k3)``."""
        return np.array(self.params[4:9])

    @cached_property
    def max_radius(self) -> float:
        """Normalised radius ``hypot(x/z, y/z)`` beyond which the radial distortion folds back."""
        k1, k2, _, _, k3 = self.params[4:9]
        return monotonic_radius(k1, k2, k3)

    # ------------------------------------------------------------------ helpers
    def undistort_points(self, uv: np.ndarray, pixels: bool = False) -> np.ndarray:
        """Undistorted (N, 2) coordinates of distorted pixels ``uv`` (N, 2) [px].

        Normalised image coordinates ``(x/z, y/z)`` by default; with ``pixels=True`` the ideal
        (undistorted) pixels ``K @ (x/z, y/z, 1)``. NaN where the distortion cannot be inverted.
        """
        p = as_pixels(uv)
        xn = np.full(p.shape, np.nan)
        ok = np.isfinite(p).all(axis=1)
        if np.any(ok):
            xn[ok] = self._undistort(p[ok])
        if not pixels:
            return xn
        fx, fy, cx, cy = self.params[:4]
        return xn * np.array([fx, fy]) + np.array([cx, cy])

    def _undistort(self, uv: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params[:4]
        dist = self.params[4:9]
        xd = (uv - np.array([cx, cy])) / np.array([fx, fy])
        xn = xd.copy()
        for _ in range(_UNDISTORT_ITERATIONS):
            res = distort(xn, dist) - xd
            if np.all(np.sum(res * res, axis=1) < _UNDISTORT_TOL**2):
                break
            J = distort_jacobian(xn, dist)
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (J[:, 1, 1] * res[:, 0] - J[:, 0, 1] * res[:, 1]) / det
                dy = (-J[:, 1, 0] * res[:, 0] + J[:, 0, 0] * res[:, 1]) / det
            step = np.stack([dx, dy], axis=1)
            xn = xn - step
        res = distort(xn, dist) - xd
        with np.errstate(invalid="ignore"):
            bad = ~(np.sum(res * res, axis=1) < 1e-18) | ~(
                np.sum(xn * xn, axis=1) < self.max_radius**2
            )
        xn[bad] = np.nan
        return xn

    # ------------------------------------------------------------------ model hooks
    def _in_domain(self, points: np.ndarray) -> np.ndarray:
        z = points[:, 2]
        front = z > 1e-6
        r2 = np.full(z.shape, np.inf)
        r2[front] = np.sum((points[front, :2] / z[front, None]) ** 2, axis=1)
        return front & (r2 < self.max_radius**2)

    def _project(self, points: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params[:4]
        xd = distort(points[:, :2] / points[:, 2:3], self.params[4:9])
        return xd * np.array([fx, fy]) + np.array([cx, cy])

    def _project_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        xn = points[:, :2] / points[:, 2:3]
        Jd = distort_jacobian(xn, self.params[4:9])
        return np.array([fx, fy])[None, :, None] * (Jd @ normalised_jacobian(points))

    def _params_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        xn = points[:, :2] / points[:, 2:3]
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        xd = distort(xn, self.params[4:9])
        J = np.zeros((points.shape[0], 2, 9))
        J[:, 0, 0] = xd[:, 0]
        J[:, 1, 1] = xd[:, 1]
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        for col, power in ((4, 1), (5, 2), (8, 3)):  # k1, k2, k3
            rp = r2**power
            J[:, 0, col] = fx * x * rp
            J[:, 1, col] = fy * y * rp
        J[:, 0, 6] = fx * 2.0 * x * y  # p1
        J[:, 1, 6] = fy * (r2 + 2.0 * y * y)
        J[:, 0, 7] = fx * (r2 + 2.0 * x * x)  # p2
        J[:, 1, 7] = fy * 2.0 * x * y
        return J

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        xn = self._undistort(uv)
        return np.concatenate([xn, np.ones((xn.shape[0], 1))], axis=1)
