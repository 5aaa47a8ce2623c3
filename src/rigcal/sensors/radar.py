"""Radar measurement model: range and azimuth, elevation not measured (paper eq. 3 and 4).

Radar frame: x forward (boresight), y left, z up. Azimuth = atan2(y, x); elevation =
atan2(z, hypot(x, y)). A 2D radar reports the point at its measured 3D range on the radar
plane: ``p(x) = |x| * (cos az, sin az)``.
"""

from __future__ import annotations

import numpy as np


def project_2d(points_radar: np.ndarray) -> np.ndarray:
    """(N, 2) 2D radar measurement of (N, 3) points in the radar frame [m]."""
    x = np.asarray(points_radar, dtype=float)
    rng = np.linalg.norm(x, axis=-1)
    rho = np.hypot(x[..., 0], x[..., 1])
    s = rng / np.maximum(rho, 1e-12)
    return x[..., :2] * s[..., None]


def project_2d_jacobian(points_radar: np.ndarray) -> np.ndarray:
    """(N, 2, 3) derivative of :func:`project_2d` with respect to the 3D point."""
    x = np.asarray(points_radar, dtype=float)
    rng = np.maximum(np.linalg.norm(x, axis=-1), 1e-12)
    rho = np.maximum(np.hypot(x[..., 0], x[..., 1]), 1e-12)
    s = rng / rho
    planar = np.concatenate([x[..., :2], np.zeros(x.shape[:-1] + (1,))], axis=-1)
    ds = x / (rng * rho)[..., None] - planar * (rng / rho**3)[..., None]
    J = x[..., :2, None] * ds[..., None, :]
    J[..., 0, 0] += s
    J[..., 1, 1] += s
    return J


def elevation(points_radar: np.ndarray) -> np.ndarray:
    """(N,) elevation angle [rad] of (N, 3) points in the radar frame."""
    x = np.asarray(points_radar, dtype=float)
    return np.arctan2(x[..., 2], np.hypot(x[..., 0], x[..., 1]))


def elevation_jacobian(points_radar: np.ndarray) -> np.ndarray:
    """(N, 3) derivative of :func:`elevation`."""
    x = np.asarray(points_radar, dtype=float)
    rho = np.maximum(np.hypot(x[..., 0], x[..., 1]), 1e-12)
    r2 = np.maximum(np.sum(x * x, axis=-1), 1e-24)
    return np.stack(
        [-x[..., 2] * x[..., 0] / (r2 * rho), -x[..., 2] * x[..., 1] / (r2 * rho), rho / r2],
        axis=-1,
    )
