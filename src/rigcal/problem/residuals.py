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

A lidar's point on a flat target (the plane ``z = 0`` of frame A) is better tied by its range
along its ray (``MODEL_RANGE``): the ray from B's origin along the measured direction
``u = z / |z|`` meets the plane at range ``s``, and

    r = (|z| - s) / sigma             (the range error, one row per point)

Its gradient is taken where the ray meets the plane, not at the measured point: a range error
moves the measured point along a slanted ray, so a point-to-plane gradient at it errs with its
own residual (errors in variables: a tilt bias of a few mrad per view at 15 mm of noise).
On a curved surface (a ``surface`` whose ``ray_range`` gives the range to the hit and its
gradients: the cylinder's tube, ``ds = -n . (do + s dw) / (n . w)`` with the normal ``n`` at
the hit) the range is the same residual with the hit found on that surface: the closest point of a
measured point is worse there than on a plane - its range noise across a thin tube makes the
tube look fatter (about sigma^2 / (2 radius): 2 mm for a VLP-16's 15 mm on the paper's 56.4 mm
radius).

Where a scanning lidar's ring leaves a plate (``MODEL_RAY_EDGE``) the edge lies between the last
ray that returned from the plate and the next ray of the ring, which did not: with both rays'
directions ``(u_end, u_next)`` in B and the plate's outline (``surface.boundary(xy)``: the signed
in-plane distance to the outline, positive inside, and its gradient),

    r = (f(h_end) + f(h_next)) / (2 sigma)

with ``h`` where each ray meets the plane: zero when the edge lies half-way between the two
rays. Where the ring crosses the edge is uniform over the step, so ``sigma`` is the step's
width across the edge over sqrt(12). No range enters: the rays' directions are exact.

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
MODEL_RANGE = "range"  # a lidar point's range error along its ray to the plane z = 0 of frame A
MODEL_RAY_EDGE = "ray_edge"  # a lidar ring's end on a plate of frame A: (u_end, u_next) rays in B

#: rows of ``measured`` per item and rows of the residual per item, by model
MEASURED_DIM = {MODEL_POINT: 3, MODEL_RADAR2D: 2, MODEL_CAMERA: 2, MODEL_SURFACE: 3, MODEL_RANGE: 3,
                MODEL_RAY_EDGE: 6}
RESIDUAL_DIM = {MODEL_POINT: 3, MODEL_RADAR2D: 2, MODEL_CAMERA: 2, MODEL_SURFACE: 1, MODEL_RANGE: 1,
                MODEL_RAY_EDGE: 1}


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
    if model == MODEL_RANGE:
        curved = surface if getattr(surface, "curved_ray", False) else None
        return _range_residuals(T_W_A, T_W_B, measured, sigma, curved)
    if model == MODEL_RAY_EDGE:
        return _edge_residuals(T_W_A, T_W_B, measured, sigma, surface)
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


#: rays meeting a plane at less than this |cos| of their angle to it are treated as meeting it
#: at this angle (a grazing ray's range is not a measurement of the plane)
_MIN_RAY_COS = 1e-3


def ray_plane_hits(T_W_A: np.ndarray, T_W_B: np.ndarray, dirs_B: np.ndarray):
    """Where rays from B's origin along ``dirs_B`` (n, 3) (unit, in B) meet the plane z = 0 of
    frame A (batches: T (n, 4, 4)): the hits ``h`` (n, 3) in A, the ranges ``s`` (n,) along the
    rays, and their Jacobians ``dh_A, dh_B`` (n, 3, 6) and ``ds_A, ds_B`` (n, 6) for the right
    perturbations of both poses."""
    n = len(dirs_B)
    o, Jo_B, Jo_A = point_in_observer(T_W_B, T_W_A, np.zeros((n, 3)))
    y, Jy_B, Jy_A = point_in_observer(T_W_B, T_W_A, np.asarray(dirs_B, dtype=float))
    w = y - o
    wz = w[:, 2]
    wz = np.where(np.abs(wz) < _MIN_RAY_COS, np.where(wz < 0, -_MIN_RAY_COS, _MIN_RAY_COS), wz)
    s = -o[:, 2] / wz
    out = []
    for Jo, Jy in ((Jo_A, Jy_A), (Jo_B, Jy_B)):
        Jw = Jy - Jo
        ds = -(Jo[:, 2, :] + s[:, None] * Jw[:, 2, :]) / wz[:, None]
        dh = Jo + s[:, None, None] * Jw + w[:, :, None] * ds[:, None, :]
        out.append((dh, ds))
    h = o + s[:, None] * w
    return h, s, out[0][0], out[1][0], out[0][1], out[1][1]


def _range_residuals(T_W_A, T_W_B, measured_B, sigma, surface=None):
    """The range residual to A's plane z = 0 (:func:`ray_plane_hits`), or to a curved
    ``surface`` (:func:`ray_surface_hits`)."""
    rho = np.linalg.norm(measured_B, axis=1)
    u = measured_B / np.maximum(rho, 1e-12)[:, None]
    if surface is None:
        _, s, _, _, ds_A, ds_B = ray_plane_hits(T_W_A, T_W_B, u)
    else:
        s, _, ds_A, ds_B = ray_surface_hits(T_W_A, T_W_B, u, surface)
    inv_sigma = 1.0 / sigma  # (n, 1)
    r = (rho - s)[:, None] * inv_sigma
    return r, (-ds_A[:, None, :]) * inv_sigma[..., None], (-ds_B[:, None, :]) * inv_sigma[..., None]


def ray_surface_hits(T_W_A: np.ndarray, T_W_B: np.ndarray, dirs_B: np.ndarray, surface):
    """Where rays from B's origin along ``dirs_B`` (n, 3) meet a curved ``surface`` of frame A
    (``surface.ray_range(origins, dirs) -> (s, ds/d origin, ds/d dir, on)``): the ranges ``s``
    (n,), whether each hit is on the surface, and ``ds_A, ds_B`` (n, 6) for the right
    perturbations of both poses."""
    n = len(dirs_B)
    o, Jo_B, Jo_A = point_in_observer(T_W_B, T_W_A, np.zeros((n, 3)))
    y, Jy_B, Jy_A = point_in_observer(T_W_B, T_W_A, np.asarray(dirs_B, dtype=float))
    s, g_o, g_w, on = surface.ray_range(o, y - o)
    ds = [np.einsum("ni,nij->nj", g_o, Jo) + np.einsum("ni,nij->nj", g_w, Jy - Jo)
          for Jo, Jy in ((Jo_A, Jy_A), (Jo_B, Jy_B))]
    return s, on, ds[0], ds[1]


def _edge_residuals(T_W_A, T_W_B, rays_B, sigma, surface):
    if surface is None or not hasattr(surface, "boundary"):
        raise ValueError("ray-edge residuals need a plate surface with a boundary")
    n = len(rays_B)
    h, _, dh_A, dh_B, _, _ = ray_plane_hits(np.concatenate([T_W_A, T_W_A]), np.concatenate([T_W_B, T_W_B]),
                                            np.concatenate([rays_B[:, :3], rays_B[:, 3:]]))
    f, g = surface.boundary(h[:, :2])
    inv = 0.5 / sigma[:, 0]
    r = (f[:n] + f[n:]) * inv
    JA = (np.einsum("ni,nij->nj", g, dh_A[:, :2, :]))
    JB = (np.einsum("ni,nij->nj", g, dh_B[:, :2, :]))
    JA = (JA[:n] + JA[n:]) * inv[:, None]
    JB = (JB[:n] + JB[n:]) * inv[:, None]
    return r[:, None], JA[:, None, :], JB[:, None, :]


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
