"""The Kannala-Brandt ("equidistant", OpenCV fisheye) camera.

Parameters ``(fx, fy, cx, cy, k1, k2, k3, k4)``. With ``r = hypot(x, y)`` and the angle off the
optical axis ``theta = atan2(r, z)`` [rad]::

    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    u = fx theta_d x / r + cx,   v = fy theta_d y / r + cy

(the same as ``cv2.fisheye.projectPoints`` with ``D = (k1, k2, k3, k4)`` and no skew; Kalibr's
``pinhole`` + ``equidistant``). The model's domain is the cone of angles where ``theta -> theta_d``
still increases (:attr:`KannalaBrandtCamera.max_angle_rad`), intersected with the front half-space
``z > MIN_DEPTH_M`` every rigcal camera model shares: points beyond it are reported invalid instead
of landing at a wrong pixel, and pixels beyond its image circle unproject to NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rigcal.errors import InputError
from rigcal.sensors.camera.base import MIN_DEPTH_M, CameraModel, intrinsics_from_camera_matrix

_UNPROJECT_ITERATIONS = 100
_UNPROJECT_TOL = 1e-14  # |theta_d(theta) - rho| [rad] at which Newton stops
_UNPROJECT_ACCEPT = 1e-11  # residual [rad] above which a pixel is reported not invertible
_SMALL_RADIUS = 1e-8  # below r / z = this, theta / r is replaced by its limit 1 / z


def theta_d(theta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Distorted angles ``theta (1 + k1 theta^2 + ... + k4 theta^8)`` of angles ``theta`` [rad];
    ``k = (k1, k2, k3, k4)``."""
    k1, k2, k3, k4 = k
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def theta_d_derivative(theta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``d theta_d / d theta = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8``."""
    k1, k2, k3, k4 = k
    t2 = theta * theta
    return 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))


def monotonic_angle(k1: float, k2: float, k3: float, k4: float) -> float:
    """Smallest angle [rad] at which ``theta_d(theta)`` stops increasing (``inf`` if never)."""
    # d theta_d / d theta = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 + 9 k4 s^4 with s = theta^2
    roots = np.roots([9.0 * k4, 7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])
    s = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    return math.sqrt(min(s)) if s else math.inf


@dataclass(frozen=True, eq=False, repr=False)
class KannalaBrandtCamera(CameraModel):
    """Equidistant fisheye; ``params = (fx, fy, cx, cy, k1, k2, k3, k4)``."""

    name = "kannala_brandt"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

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
        k3: float = 0.0,
        k4: float = 0.0,
    ) -> "KannalaBrandtCamera":
        return cls(width, height, np.array([fx, fy, cx, cy, k1, k2, k3, k4], dtype=float))

    @classmethod
    def from_opencv(
        cls, width: int, height: int, camera_matrix: np.ndarray, fisheye_coeffs: np.ndarray
    ) -> "KannalaBrandtCamera":
        """From OpenCV fisheye's K (3, 3) and ``D = (k1, k2, k3, k4)``; K must have no skew."""
        d = np.asarray(fisheye_coeffs, dtype=float).reshape(-1)
        if d.size != 4:
            raise InputError(
                f"kannala_brandt camera: expected 4 fisheye coefficients (k1, k2, k3, k4), "
                f"got {d.size}"
            )
        fx, fy, cx, cy = intrinsics_from_camera_matrix(camera_matrix, "kannala_brandt")
        return cls.from_intrinsics(width, height, fx, fy, cx, cy, *d)

    # ------------------------------------------------------------------ OpenCV interop
    @property
    def fisheye_coeffs(self) -> np.ndarray:
        """(4,) ``D = (k1, k2, k3, k4)`` for ``cv2.fisheye`` (not plumb-bob ``dist_coeffs``)."""
        return np.array(self.params[4:8])

    @cached_property
    def max_angle_rad(self) -> float:
        """Angle off the optical axis [rad] up to which points are in the model's domain:
        where ``theta_d`` stops increasing, at most pi / 2 (the camera plane)."""
        return min(monotonic_angle(*self.params[4:8]), math.pi / 2)

    # ------------------------------------------------------------------ helpers
    def _angles(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(r, theta, theta / r)`` of points (N, 3) with z > 0; ``theta / r`` -> 1 / z on axis."""
        z = points[:, 2]
        r = np.hypot(points[:, 0], points[:, 1])
        theta = np.arctan2(r, z)
        small = r < _SMALL_RADIUS * z
        theta_over_r = np.empty_like(r)
        theta_over_r[small] = 1.0 / z[small]  # theta = r / z (1 - (r/z)^2 / 3 + ...)
        theta_over_r[~small] = theta[~small] / r[~small]
        return r, theta, theta_over_r

    # ------------------------------------------------------------------ model hooks
    def _in_domain(self, points: np.ndarray) -> np.ndarray:
        theta = np.arctan2(np.hypot(points[:, 0], points[:, 1]), points[:, 2])
        return (points[:, 2] > MIN_DEPTH_M) & (theta < self.max_angle_rad)

    def _project(self, points: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params[:4]
        _, theta, theta_over_r = self._angles(points)
        t2 = theta * theta
        k1, k2, k3, k4 = self.params[4:8]
        scale = theta_over_r * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))  # theta_d / r
        return np.stack([fx * scale * points[:, 0] + cx, fy * scale * points[:, 1] + cy], axis=1)

    def _project_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        k = self.params[4:8]
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        r, theta, theta_over_r = self._angles(points)
        t2 = theta * theta
        k1, k2, k3, k4 = k
        b = theta_over_r * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))  # theta_d / r
        dtd = theta_d_derivative(theta, k)
        rho2 = r * r + z * z
        a = dtd * z / rho2  # d theta_d / d r at fixed z
        # u = fx b(r, z) x: du/dx = fx (b + (x / r)^2 (a - b)); a - b -> 0 on the axis
        safe_r = np.where(r > 0, r, 1.0)
        ex, ey = np.where(r > 0, x / safe_r, 0.0), np.where(r > 0, y / safe_r, 0.0)
        c = a - b
        J = np.empty((points.shape[0], 2, 3))
        J[:, 0, 0] = fx * (b + ex * ex * c)
        J[:, 0, 1] = fx * ex * ey * c
        J[:, 1, 0] = fy * ex * ey * c
        J[:, 1, 1] = fy * (b + ey * ey * c)
        dz = -dtd / rho2  # (d theta_d / d z) / r
        J[:, 0, 2] = fx * x * dz
        J[:, 1, 2] = fy * y * dz
        return J

    def _params_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        x, y = points[:, 0], points[:, 1]
        _, theta, theta_over_r = self._angles(points)
        t2 = theta * theta
        k1, k2, k3, k4 = self.params[4:8]
        b = theta_over_r * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        J = np.zeros((points.shape[0], 2, 8))
        J[:, 0, 0] = b * x
        J[:, 1, 1] = b * y
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        power = theta_over_r.copy()  # (theta / r) theta^(2j) for k_j
        for col in (4, 5, 6, 7):
            power = power * t2
            J[:, 0, col] = fx * x * power
            J[:, 1, col] = fy * y * power
        return J

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params[:4]
        k = self.params[4:8]
        m = (uv - np.array([cx, cy])) / np.array([fx, fy])
        rho = np.hypot(m[:, 0], m[:, 1])  # = theta_d
        theta_max = self.max_angle_rad
        inside = rho < float(theta_d(np.array(theta_max), k))
        theta = np.full(rho.shape, np.nan)
        theta[inside] = self._solve_theta(rho[inside], theta_max)
        with np.errstate(invalid="ignore", divide="ignore"):
            sin_over_rho = np.where(rho > 0, np.sin(theta) / rho, 1.0)
        rays = np.stack(
            [m[:, 0] * sin_over_rho, m[:, 1] * sin_over_rho, np.cos(theta)], axis=1
        )
        rays[~inside] = np.nan
        with np.errstate(invalid="ignore"):
            rays[~(rays[:, 2] > MIN_DEPTH_M)] = np.nan
        return rays

    def _solve_theta(self, rho: np.ndarray, theta_max: float) -> np.ndarray:
        """Angles ``theta`` in [0, theta_max) with ``theta_d(theta) = rho`` (safeguarded Newton:
        ``theta_d`` increases on the bracket, so a step leaving it is replaced by bisection)."""
        k = self.params[4:8]
        lo = np.zeros_like(rho)
        hi = np.full_like(rho, theta_max)
        theta = np.minimum(rho, theta_max)  # theta_d ~ theta near the axis
        for _ in range(_UNPROJECT_ITERATIONS):
            f = theta_d(theta, k) - rho
            done = np.abs(f) <= _UNPROJECT_TOL
            if np.all(done):
                break
            lo = np.where(f < 0, theta, lo)
            hi = np.where(f > 0, theta, hi)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = theta - f / theta_d_derivative(theta, k)
            outside = ~((step > lo) & (step < hi))
            theta = np.where(done, theta, np.where(outside, 0.5 * (lo + hi), step))
        f = theta_d(theta, k) - rho
        with np.errstate(invalid="ignore"):
            theta[~(np.abs(f) <= _UNPROJECT_ACCEPT)] = np.nan
        return theta
