"""Pure residual functions with analytic Jacobians.

Every residual here has the same shape: a point ``p`` fixed in frame A is seen by sensor B.

    x = T_W_B^-1 @ T_W_A @ p          (the point in B's frame)
    r = (h(x) - z) / sigma            (whitened)

``h`` is the identity for 3D sensors (lidar, stereo camera, 3D radar), the 2D radar
projection (range, azimuth; elevation dropped - paper eq. 3) for 2D radars, and a camera
model's projection to pixels for cameras (points outside the model's domain, e.g. behind the
camera, give a zero residual and no gradient).

The surface model turns this around for a point ``z`` measured by B on a known surface of A
(a lidar point on a target plate): with ``p`` the surface point it corresponds to and ``n``
the surface normal there, both in A,

    y = T_W_A^-1 @ T_W_B @ z          (the measured point in A's frame)
    r = n . (y - p) / sigma           (signed point-to-plane distance, one row per point)

Given a ``surface`` (anything with ``closest(y) -> (p, n)``, e.g. a
:class:`rigcal.targets.surface.TargetSurface`) ``p`` and ``n`` are found again at every
evaluation: ``r`` is then the distance of ``y`` to the surface itself and ``n^T dy`` its
exact gradient (the closest point moves along the surface, orthogonal to ``n``), so one
least-squares solve minimises point-to-surface distances with no correspondence loop.

Poses are
perturbed on the right, ``T <- T @ exp(xi)`` with ``xi = (omega, v)``, so Jacobians are
with respect to (omega, v) expressed in each pose's own frame.

The elevation field-of-view constraint (paper eq. 4) is a one-sided (hinge) residual
``max(0, |elevation(x)| - max_elevation) / sigma_fov``: zero inside the field of view.
"""

from __future__ import annotations

import numpy as np

from rigcal.geometry.so3 import hat
from rigcal.sensors.radar import elevation, elevation_jacobian, project_2d, project_2d_jacobian

MODEL_POINT = "point3d"
MODEL_RADAR2D = "radar2d"
MODEL_CAMERA = "camera"  # pixels through a rigcal.sensors.camera model (paper 001, eq. 3)
MODEL_SURFACE = "surface"  # a measured 3D point's distance to a surface of frame A (point-to-plane)

#: rows of ``measured`` per item and rows of the residual per item, by model
MEASURED_DIM = {MODEL_POINT: 3, MODEL_RADAR2D: 2, MODEL_CAMERA: 2, MODEL_SURFACE: 3}
RESIDUAL_DIM = {MODEL_POINT: 3, MODEL_RADAR2D: 2, MODEL_CAMERA: 2, MODEL_SURFACE: 1}


def point_in_observer(
    T_W_A: np.ndarray, T_W_B: np.ndarray, points_A: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = T_W_B^-1 T_W_A p for batches: T (n, 4, 4), p (n, 3).

    Returns x (n, 3), dx/dxi_A (n, 3, 6), dx/dxi_B (n, 3, 6).
    """
    RA, tA = T_W_A[:, :3, :3], T_W_A[:, :3, 3]
    RB, tB = T_W_B[:, :3, :3], T_W_B[:, :3, 3]
    RBt = np.swapaxes(RB, 1, 2)
    q = np.einsum("nij,nj->ni", RA, points_A) + tA
    x = np.einsum("nij,nj->ni", RBt, q - tB)
    RBtRA = RBt @ RA
    JA = np.empty(x.shape + (6,))
    JA[:, :, :3] = -RBtRA @ hat(points_A)
    JA[:, :, 3:] = RBtRA
    JB = np.empty(x.shape + (6,))
    JB[:, :, :3] = hat(x)
    JB[:, :, 3:] = -np.eye(3)
    return x, JA, JB


def observation_residuals(
    T_W_A: np.ndarray,
    T_W_B: np.ndarray,
    points_A: np.ndarray,
    measured: np.ndarray,
    sigma: np.ndarray,
    model: str,
    camera=None,
    normals_A: np.ndarray | None = None,
    surface=None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals (n, d) and Jacobians (n, d, 6) for frame A and observer B.

    ``model`` MODEL_SURFACE needs ``normals_A`` (n, 3) unit normals at ``points_A`` or a
    ``surface`` to find both; its ``measured`` are points in B and ``sigma`` is (n, 1)."""
    if model == MODEL_SURFACE:
        return _surface_residuals(T_W_A, T_W_B, points_A, normals_A, measured, sigma, surface)
    x, JA, JB = point_in_observer(T_W_A, T_W_B, points_A)
    if model == MODEL_POINT:
        h, H = x, None
    elif model == MODEL_RADAR2D:
        h, H = project_2d(x), project_2d_jacobian(x)
    elif model == MODEL_CAMERA:
        uv, _ = camera.project(x)
        H = camera.project_jacobian(x)
        ok = np.all(np.isfinite(uv), axis=1) & np.all(np.isfinite(H.reshape(len(x), -1)), axis=1)
        h = np.where(ok[:, None], uv, measured)
        H = np.where(ok[:, None, None], H, 0.0)
    else:  # pragma: no cover - guarded where problems are built
        raise ValueError(f"unknown measurement model {model!r}")
    inv_sigma = 1.0 / sigma
    r = (h - measured) * inv_sigma
    if H is not None:
        JA = H @ JA
        JB = H @ JB
    JA = JA * inv_sigma[..., None]
    JB = JB * inv_sigma[..., None]
    return r, JA, JB


def _surface_residuals(T_W_A, T_W_B, points_A, normals_A, measured_B, sigma, surface=None):
    # the measured point seen from A: the roles of point_in_observer swap
    y, JB, JA = point_in_observer(T_W_B, T_W_A, measured_B)
    if surface is not None:
        points_A, normals_A = surface.closest(y)
    if normals_A is None:
        raise ValueError("surface residuals need the surface normals at the points, or the surface")
    inv_sigma = 1.0 / sigma  # (n, 1)
    r = np.einsum("ni,ni->n", normals_A, y - points_A)[:, None] * inv_sigma
    JA = np.einsum("ni,nij->nj", normals_A, JA)[:, None, :] * inv_sigma[..., None]
    JB = np.einsum("ni,nij->nj", normals_A, JB)[:, None, :] * inv_sigma[..., None]
    return r, JA, JB


def elevation_limit_residuals(
    T_W_A: np.ndarray,
    T_W_B: np.ndarray,
    points_A: np.ndarray,
    max_elevation_rad: np.ndarray,
    sigma_rad: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hinge residuals (n, 1) and Jacobians (n, 1, 6): zero while |elevation| <= max."""
    x, JA, JB = point_in_observer(T_W_A, T_W_B, points_A)
    e = elevation(x)
    excess = np.abs(e) - max_elevation_rad
    active = excess > 0
    r = np.where(active, excess, 0.0)[:, None] / sigma_rad
    g = (np.sign(e) * active / sigma_rad)[:, None] * elevation_jacobian(x)
    JA = np.einsum("ni,nij->nj", g, JA)[:, None, :]
    JB = np.einsum("ni,nij->nj", g, JB)[:, None, :]
    return r, JA, JB
