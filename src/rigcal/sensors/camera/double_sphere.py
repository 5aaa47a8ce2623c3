"""The double sphere camera (Usenko, Demmel and Cremers, 3DV 2018).

Parameters ``(fx, fy, cx, cy, xi, alpha)``. A point is projected onto a unit sphere, the sphere's
centre is shifted by ``xi`` along z onto a second unit sphere, and the result is projected by a
pinhole shifted by ``alpha / (1 - alpha)``::

    d1 = |(x, y, z)|,   d2 = |(x, y, xi d1 + z)|
    den = alpha d2 + (1 - alpha) (xi d1 + z)
    u = fx x / den + cx,   v = fy y / den + cy

``alpha`` must lie in [0, 1] and ``xi`` above -1 (at ``xi <= -1`` not even the optical axis
has a one-to-one neighbourhood). The domain is where all of these hold:

* the front half-space ``z > MIN_DEPTH_M`` every rigcal camera model shares;
* the paper's bound ``z > -w2 d1`` with ``w1 = alpha / (1 - alpha)`` for ``alpha <= 0.5``, else
  ``(1 - alpha) / alpha``, and ``w2 = (w1 + xi) / sqrt(2 w1 xi + xi^2 + 1)``;
* ``den > 0`` (the projection is defined) and the radial map ``theta -> |m|`` still increases,
  which works out to ``d1 + xi z > 0`` and ``(1 - alpha) d2 + alpha (xi d1 + z) > 0``. The
  paper's bound alone is not enough for strongly negative ``xi`` with ``alpha > 0.5``: with
  ``xi = -0.745``, ``alpha = 0.984`` the image radius peaks at 43 deg off axis while the bound
  allows 54 deg. For common lenses (``xi`` about -0.3..0.3) every bound lies beyond the front
  half-space.

Each condition holds on a cone around the optical axis, so the domain is one cone on which the
projection is one-to-one. Unprojection is closed form; pixels outside the disc
``r^2 < 1 / (2 alpha - 1)`` (``alpha > 0.5``) or whose ray leaves the domain give NaN.

Kalibr's ``ds`` model writes the same parameters in the order ``(xi, alpha, fx, fy, cx, cy)``;
the original tool's ``DOUBLESPHERE`` uses ``(fx, fy, cx, cy, xi, alpha)`` with ``eps`` for ``xi``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.errors import InputError
from rigcal.sensors.camera.base import MIN_DEPTH_M, CameraModel


@dataclass(frozen=True, eq=False, repr=False)
class DoubleSphereCamera(CameraModel):
    """Double sphere fisheye; ``params = (fx, fy, cx, cy, xi, alpha)``."""

    name = "double_sphere"
    param_names = ("fx", "fy", "cx", "cy", "xi", "alpha")

    @classmethod
    def from_intrinsics(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        xi: float = 0.0,
        alpha: float = 0.5,
    ) -> "DoubleSphereCamera":
        return cls(width, height, np.array([fx, fy, cx, cy, xi, alpha], dtype=float))

    def _check_params(self) -> None:
        super()._check_params()
        xi, alpha = self.params[4], self.params[5]
        if not 0.0 <= alpha <= 1.0:
            raise InputError(f"{self.name} camera: alpha must be in [0, 1], got {alpha}")
        if not xi > -1.0:
            raise InputError(
                f"{self.name} camera: xi must be > -1 (no one-to-one domain otherwise), got {xi}"
            )

    # ------------------------------------------------------------------ domain
    @staticmethod
    def _w1(alpha: float) -> float:
        return alpha / (1.0 - alpha) if alpha <= 0.5 else (1.0 - alpha) / alpha

    @property
    def w2(self) -> float:
        """The paper's domain bound ``z > -w2 |p|`` (one of the conditions of the domain)."""
        xi, alpha = float(self.params[4]), float(self.params[5])
        w1 = self._w1(alpha)
        return (w1 + xi) / math.sqrt(2.0 * w1 * xi + xi * xi + 1.0)

    @property
    def max_radius2(self) -> float:
        """Squared normalised radius ``((u - cx) / fx)^2 + ((v - cy) / fy)^2`` that pixels must stay
        below to be unprojected (``inf`` for ``alpha <= 0.5``)."""
        alpha = float(self.params[5])
        return 1.0 / (2.0 * alpha - 1.0) if alpha > 0.5 else math.inf

    # ------------------------------------------------------------------ helpers
    def _terms(
        self, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(d1, xi d1 + z, d2, den)`` of points (N, 3)."""
        xi, alpha = self.params[4], self.params[5]
        r = np.hypot(points[:, 0], points[:, 1])  # hypot: no overflow for far points
        d1 = np.hypot(r, points[:, 2])
        zs = xi * d1 + points[:, 2]
        d2 = np.hypot(r, zs)
        den = alpha * d2 + (1.0 - alpha) * zs
        return d1, zs, d2, den

    # ------------------------------------------------------------------ model hooks
    def _in_domain(self, points: np.ndarray) -> np.ndarray:
        xi, alpha = self.params[4], self.params[5]
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite rows compare False
            d1, zs, d2, den = self._terms(points)
            z = points[:, 2]
            increasing = (d1 + xi * z > 0) & ((1.0 - alpha) * d2 + alpha * zs > 0)
            return (z > MIN_DEPTH_M) & (z > -self.w2 * d1) & (den > 0) & increasing

    def _project(self, points: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = self.params[:4]
        _, _, _, den = self._terms(points)
        return np.stack(
            [fx * points[:, 0] / den + cx, fy * points[:, 1] / den + cy], axis=1
        )

    def _den_gradient(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(den, d den / d point (N, 3))``."""
        xi, alpha = self.params[4], self.params[5]
        d1, zs, d2, den = self._terms(points)
        dd1 = points / d1[:, None]  # d d1 / dp
        dzs = xi * dd1
        dzs[:, 2] += 1.0
        dd2 = zs[:, None] * dzs
        dd2[:, :2] += points[:, :2]
        dd2 /= d2[:, None]
        return den, alpha * dd2 + (1.0 - alpha) * dzs

    def _project_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        den, dden = self._den_gradient(points)
        J = np.empty((points.shape[0], 2, 3))
        J[:, 0, :] = -(fx * points[:, 0] / (den * den))[:, None] * dden
        J[:, 1, :] = -(fy * points[:, 1] / (den * den))[:, None] * dden
        J[:, 0, 0] += fx / den
        J[:, 1, 1] += fy / den
        return J

    def _params_jacobian(self, points: np.ndarray) -> np.ndarray:
        fx, fy = self.params[:2]
        alpha = self.params[5]
        x, y = points[:, 0], points[:, 1]
        d1, zs, d2, den = self._terms(points)
        dden_dxi = alpha * zs * d1 / d2 + (1.0 - alpha) * d1
        dden_dalpha = d2 - zs
        J = np.zeros((points.shape[0], 2, 6))
        J[:, 0, 0] = x / den
        J[:, 1, 1] = y / den
        J[:, 0, 2] = 1.0
        J[:, 1, 3] = 1.0
        for col, dden in ((4, dden_dxi), (5, dden_dalpha)):
            J[:, 0, col] = -fx * x * dden / (den * den)
            J[:, 1, col] = -fy * y * dden / (den * den)
        return J

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy, xi, alpha = self.params
        m = (uv - np.array([cx, cy])) / np.array([fx, fy])
        r2 = np.sum(m * m, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mz = (1.0 - alpha * alpha * r2) / (
                alpha * np.sqrt(1.0 - (2.0 * alpha - 1.0) * r2) + 1.0 - alpha
            )
            scale = (mz * xi + np.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
            rays = np.stack([scale * m[:, 0], scale * m[:, 1], scale * mz - xi], axis=1)
            ok = (r2 < self.max_radius2) & np.isfinite(rays).all(axis=1)
        rays[~ok] = np.nan
        if np.any(ok):
            in_domain = self._in_domain(rays[ok])
            idx = np.flatnonzero(ok)
            rays[idx[~in_domain]] = np.nan
        return rays
