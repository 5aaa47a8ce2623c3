"""Robust ICP of a target's template cloud onto a lidar scan (Charron et al., III-C).

The template (dense, complete, in the target frame) is aligned to the scan (sparse, partial, in
the sensor frame): every scan point is matched to its nearest template point, so a partial view
never drags the template towards parts the sensor did not see. The unknown is
``T_sensor_target``; internally the inverse ``A = T_target_sensor`` is updated on the left,
``A <- exp(xi) A`` with ``xi = (omega, v)``.

Costs (:class:`IcpOptions` ``method``):

* ``point_to_point`` - ``|A p - q|^2``, solved in closed form (weighted Kabsch) each iteration;
* ``point_to_plane`` - ``(n . (A p - q))^2`` with the template's normals, Gauss-Newton;
* ``combined`` (default) - point-to-plane plus, for an open template (a plate), rim rows along
  the rim's in-plane outward direction ``m``, residual ``m . (A p - q_rim)``: scan points
  outside the rim are pulled in, and the observed rim points (``rim_points_sensor``: where the
  scan lines leave the target) are pulled onto the rim from both sides. A sparse
  ring scan sees a plate's in-plane position only through the ring ends near its edges; plain
  point-to-point cannot use them well: the interior matches lock the scan onto the template's
  sampling grid and the ring ends, a few millimetres inside the edges, pull only once they are
  outside. Pulling the edges onto the ring ends from both sides balances opposite edges.

Robustness (``loss``): ``huber`` (weights ``min(1, delta / e)``), ``trimmed`` (the worst
``trim_fraction`` of matches dropped) or ``none``; matches beyond the correspondence gate are
always dropped, and the gate shrinks towards four robust sigmas as the fit converges. Directions
the data do not constrain (a cylinder's spin, and its slide along the axis when no end is seen)
are left where they started: the Gauss-Newton step drops curvatures below
``min_curvature_ratio`` times the largest (rotations about the scan centroid, scaled by the
scan's size, so rotations and translations compare).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from rigcal.errors import GeometryError, InputError
from rigcal.extract.guidance import check_points, check_pose
from rigcal.extract.result import ICP_DIVERGED, ExtractionFailure
from rigcal.geometry.align import kabsch
from rigcal.geometry.se3 import invert, se3_exp, transform_points
from rigcal.geometry.so3 import hat, so3_log

__all__ = [
    "IcpOptions",
    "IcpResult",
    "PreparedTemplate",
    "estimate_normals",
    "icp_align",
    "prepare_template",
    "principal_extents",
    "rim_directions",
    "voxel_downsample",
]

METHODS = ("point_to_point", "point_to_plane", "combined")
LOSSES = ("huber", "trimmed", "none")


# ---------------------------------------------------------------------------- template
def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per occupied ``voxel_m`` cube: the mean of the points in it. (M, 3) -> (K, 3)."""
    p = check_points(points, "points")
    if voxel_m <= 0:
        return p
    keys = np.floor(p / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((counts.shape[0], 3))
    np.add.at(sums, inverse, p)
    return sums / counts[:, None]


def estimate_normals(points: np.ndarray, neighbours: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 3) from the PCA of each point's ``neighbours`` nearest points, oriented
    away from the cloud's centroid (outward on a closed convex-ish surface), and the surface
    variation (N,) ``l0 / (l0 + l1 + l2)`` of the PCA eigenvalues: near 0 on a smooth surface,
    up to 1/3 where the normal is undefined (sharp edges, corners)."""
    p = check_points(points, "points", minimum=3)
    k = int(min(max(neighbours, 3), p.shape[0]))
    _, idx = cKDTree(p).query(p, k=k)
    nb = p[idx]  # (N, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    lam, vecs = np.linalg.eigh(cov)
    n = vecs[:, :, 0]
    flip = np.einsum("ni,ni->n", n, p - p.mean(axis=0)) < 0
    n[flip] *= -1.0
    variation = lam[:, 0] / np.maximum(lam.sum(axis=1), 1e-300)
    return n, variation


def rim_directions(
    points: np.ndarray, normals: np.ndarray, neighbours: int = 32, threshold: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """The rim of an open surface: outward in-plane unit directions (N, 3) (zero rows off the
    rim) and, for rim points, where the surface ends along that direction (N, 3).

    Inside a surface the centroid of a point's ``neighbours`` nearest points, projected into its
    tangent plane, sits on the point; at a rim it is pushed inward. A point whose offset exceeds
    ``threshold`` times the mean neighbour distance is on the rim, its direction is minus the
    offset. That flags a band a few samples wide; each rim point is moved out to the outermost
    sample near it along its direction, plus half the sample spacing (a sampled surface stops
    about half a spacing short of its true edge)."""
    p = check_points(points, "points", minimum=3)
    k = int(min(max(neighbours, 3), p.shape[0]))
    tree = cKDTree(p)
    dist, idx = tree.query(p, k=k)
    off = p[idx].mean(axis=1) - p
    off -= np.einsum("ni,ni->n", off, normals)[:, None] * normals
    size = np.linalg.norm(off, axis=1)
    rim = size > threshold * np.mean(dist[:, 1:], axis=1)
    directions = np.zeros_like(p)
    directions[rim] = -off[rim] / size[rim, None]
    edge = p.copy()
    spacing = float(np.median(dist[:, 1]))
    for i in np.flatnonzero(rim):
        nb = tree.query_ball_point(p[i], 3.0 * spacing)
        reach = max(float(np.max((p[nb] - p[i]) @ directions[i])), 0.0)
        edge[i] = p[i] + (reach + 0.5 * spacing) * directions[i]
    return directions, edge


def principal_extents(points: np.ndarray) -> np.ndarray:
    """Extents (3,) [m] of points (N, 3) along their principal axes, largest first."""
    p = np.asarray(points, dtype=float)
    if p.shape[0] < 2:
        return np.zeros(3)
    c = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    ext = np.ptp(c @ vt.T, axis=0)
    return np.sort(np.pad(ext, (0, 3 - ext.shape[0])))[::-1]


@dataclass(frozen=True, eq=False)  # holds arrays and trees: compare by identity
class PreparedTemplate:
    """A template cloud ready for ICP, in the target frame.

    ``points`` (M, 3) [m] (voxel filtered), unit ``normals`` (M, 3), ``smooth`` (M,) bool
    where the normal is well defined (not on a sharp edge), ``rim`` (M, 3) outward
    in-plane unit directions at the rim of an open surface (zero rows elsewhere; all zero for a
    closed surface), ``rim_edge`` (M, 3) where the surface ends beyond each rim point,
    ``planar`` whether the template is thinner than 1 % of its size (a plate: seen from either
    side). Build it with :func:`prepare_template`.
    """

    points: np.ndarray
    normals: np.ndarray
    smooth: np.ndarray
    rim: np.ndarray
    rim_edge: np.ndarray
    planar: bool

    def __post_init__(self) -> None:
        for name in ("points", "normals", "smooth", "rim", "rim_edge"):
            a = np.array(getattr(self, name), dtype=bool if name == "smooth" else float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        on_rim = np.any(self.rim != 0, axis=1)
        object.__setattr__(self, "_tree", cKDTree(self.points))
        object.__setattr__(self, "_rim_index", np.flatnonzero(on_rim))
        object.__setattr__(
            self, "_rim_tree", cKDTree(self.points[on_rim]) if np.any(on_rim) else None
        )

    @property
    def tree(self) -> cKDTree:
        return self._tree  # type: ignore[attr-defined]

    @property
    def has_rim(self) -> bool:
        return self._rim_tree is not None  # type: ignore[attr-defined]

    def nearest_rim(self, x: np.ndarray, gate_m: float) -> tuple[np.ndarray, np.ndarray]:
        """For points (N, 3) in the target frame: distance (N,) to the nearest rim point within
        ``gate_m`` (inf if none) and that point's row in ``points`` (meaningless where inf)."""
        if self._rim_tree is None:  # type: ignore[attr-defined]
            return np.full(len(x), np.inf), np.zeros(len(x), dtype=int)
        d, j = self._rim_tree.query(x, distance_upper_bound=gate_m)  # type: ignore[attr-defined]
        j = np.minimum(j, len(self._rim_index) - 1)  # type: ignore[attr-defined]
        return d, self._rim_index[j]  # type: ignore[attr-defined]

    @property
    def extents_m(self) -> np.ndarray:
        """Sorted (largest first) extents [m] along the template's principal axes."""
        return principal_extents(self.points)

    def visible_from(self, T_sensor_target: np.ndarray) -> np.ndarray:
        """(M,) bool: template points whose outward normal faces the sensor origin at this pose
        (all of them for a planar template)."""
        if self.planar:
            return np.ones(len(self.points), dtype=bool)
        eye = invert(np.asarray(T_sensor_target, dtype=float))[:3, 3]  # sensor in target frame
        return np.einsum("ni,ni->n", self.normals, eye[None, :] - self.points) > 0


def prepare_template(
    points_target: np.ndarray,
    voxel_m: float = 0.004,
    normal_neighbours: int = 16,
    open_surface: bool | None = None,
    max_variation: float = 0.05,
) -> PreparedTemplate:
    """Downsample a template cloud (M, 3) [m] on a ``voxel_m`` grid, estimate its normals and,
    for an open surface, its rim; index it. ``open_surface`` defaults to "the template is
    planar" (a closed solid's sharp edges, such as a cylinder's, are not a rim). Points whose
    surface variation exceeds ``max_variation`` (sharp edges) get no point-to-plane rows: their
    normals are a blend of two faces and would pull along directions the data do not fix (a
    cylinder's axis). Do this once per target and reuse it for every frame."""
    p = voxel_downsample(points_target, voxel_m)
    if p.shape[0] < 10:
        raise InputError(f"template: only {p.shape[0]} points after {voxel_m} m voxel filtering")
    ext = principal_extents(p)
    planar = bool(ext[2] < 0.01 * ext[0])
    if planar:  # one consistent normal on a flat plate: the plate's own
        c = p - p.mean(axis=0)
        n = np.broadcast_to(np.linalg.svd(c, full_matrices=False)[2][2], p.shape).copy()
        smooth = np.ones(len(p), dtype=bool)
    else:
        n, variation = estimate_normals(p, normal_neighbours)
        smooth = variation < max_variation
    is_open = planar if open_surface is None else bool(open_surface)
    rim, edge = rim_directions(p, n) if is_open else (np.zeros_like(p), p)
    return PreparedTemplate(p, n, smooth, rim, edge, planar)


# ---------------------------------------------------------------------------- options, result
@dataclass(frozen=True)
class IcpOptions:
    """Settings of :func:`icp_align` (see the module docstring). Distances [m], angles [rad].
    ``rim_weight``: the weight of rim rows against point-to-plane rows."""

    method: str = "combined"
    loss: str = "huber"
    huber_delta_m: float = 0.01
    trim_fraction: float = 0.1
    rim_weight: float = 1.0
    max_iterations: int = 80
    max_correspondence_m: float = 0.25
    min_correspondence_m: float = 0.05
    min_curvature_ratio: float = 1e-3
    tolerance_translation_m: float = 1e-6
    tolerance_rotation_rad: float = 1e-7
    min_inlier_fraction: float = 0.5
    max_rms_m: float = 0.03
    max_translation_change_m: float = 0.75
    max_rotation_change_rad: float = math.radians(25.0)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"IcpOptions.method must be one of {METHODS}, got '{self.method}'")
        if self.loss not in LOSSES:
            raise InputError(f"IcpOptions.loss must be one of {LOSSES}, got '{self.loss}'")
        if not 0.0 <= self.trim_fraction < 1.0:
            raise InputError(
                f"IcpOptions.trim_fraction must be in [0, 1), got {self.trim_fraction}"
            )
        for name in (
            "huber_delta_m", "max_correspondence_m", "min_correspondence_m", "max_rms_m",
        ):
            if not getattr(self, name) > 0:
                raise InputError(f"IcpOptions.{name} must be > 0, got {getattr(self, name)}")
        if self.min_correspondence_m > self.max_correspondence_m:
            raise InputError(
                "IcpOptions.min_correspondence_m must not exceed max_correspondence_m, got "
                f"{self.min_correspondence_m} > {self.max_correspondence_m}"
            )
        if self.max_iterations < 1:
            raise InputError(f"IcpOptions.max_iterations must be >= 1, got {self.max_iterations}")


class IcpResult(NamedTuple):
    """A converged (or iteration-capped) alignment.

    ``T_sensor_target`` (4, 4); ``distances_m`` (N,) each scan point's distance to its nearest
    template point at that pose; ``inliers`` (N,) bool those within the final gate ``gate_m``;
    ``rms_m`` RMS distance of the inliers; ``converged`` False when ``max_iterations`` ran out
    first.
    """

    T_sensor_target: np.ndarray
    distances_m: np.ndarray
    inliers: np.ndarray
    rms_m: float
    inlier_fraction: float
    iterations: int
    converged: bool
    gate_m: float


# ---------------------------------------------------------------------------- ICP
def _robust_weights(e: np.ndarray, opts: IcpOptions) -> np.ndarray:
    w = np.ones_like(e)
    if opts.loss == "huber":
        big = e > opts.huber_delta_m
        w[big] = opts.huber_delta_m / e[big]
    elif opts.loss == "trimmed" and opts.trim_fraction > 0 and e.size > 10:
        keep = int(math.ceil((1.0 - opts.trim_fraction) * e.size))
        cut = np.partition(e, keep - 1)[keep - 1]
        w[e > cut] = 0.0
    return w


def _solve_truncated(
    H: np.ndarray, g: np.ndarray, centre: np.ndarray, length_m: float, rel: float
) -> np.ndarray:
    """The step ``xi`` minimising ``xi' H xi / 2 + g' xi``, keeping only directions whose
    curvature exceeds ``rel`` times the largest; what the data do not constrain (a cylinder's
    spin, its slide along the axis) is left unchanged. Curvatures are compared in balanced
    units: rotation about ``centre`` (the scan's centroid) scaled by ``length_m`` (its size),
    so the cut does not depend on where the target frame's origin is."""
    M = np.eye(6)
    M[3:, :3] = hat(centre)
    M[:, :3] /= length_m
    Hb, gb = M.T @ H @ M, M.T @ g
    lam, V = np.linalg.eigh(Hb)
    keep = lam > rel * max(float(lam[-1]), 1e-300)
    coef = np.zeros(6)
    coef[keep] = (V[:, keep].T @ gb) / lam[keep]
    return -(M @ (V @ coef))


def _accumulate(H, g, J, r, w) -> None:
    Jw = J * w[:, None]
    H += Jw.T @ J
    g += Jw.T @ r


def _rim_matches(tpl: PreparedTemplate, x: np.ndarray, gate: float, two_sided: bool | None):
    """Points (in the target frame) to pull onto the rim, their rim directions and rim points:
    with ``two_sided`` every point within ``gate`` of the rim, else only points outside it."""
    dr, jr = tpl.nearest_rim(x, gate)
    found = np.isfinite(dr)
    m, q = tpl.rim[jr[found]], tpl.rim_edge[jr[found]]
    xf = x[found]
    if not two_sided:
        out = np.einsum("ni,ni->n", m, xf - q) > 0
        xf, m, q = xf[out], m[out], q[out]
    return xf, m, q


def icp_align(
    template: PreparedTemplate | np.ndarray,
    scan_sensor: np.ndarray,
    T_sensor_target_init: np.ndarray,
    options: IcpOptions | None = None,
    *,
    rim_points_sensor: np.ndarray | None = None,
    sensor: str = "",
    t_ns: int = 0,
) -> IcpResult | ExtractionFailure:
    """Align ``template`` (a :class:`PreparedTemplate`, or raw (M, 3) points in the target
    frame) to ``scan_sensor`` (N, 3) [m], starting from ``T_sensor_target_init`` (4, 4).

    Fails with ``icp_diverged`` when fewer than 6 matches remain, the pose becomes non-finite,
    the final inlier fraction is below ``min_inlier_fraction``, the inlier RMS above
    ``max_rms_m``, or the pose moved further from the start than ``max_translation_change_m`` /
    ``max_rotation_change_rad``.

    ``rim_points_sensor`` (E, 3) [m]: where the scan says the target's rim is (for a ring scan,
    the ends of each ring's run on the target, moved out by half an azimuth step - the edge lies
    anywhere between the last hit and the first miss). With the ``combined`` method and an open
    template they are pulled onto the nearest rim point (within the correspondence gate) from
    both sides; scan points outside the rim are always pulled in.
    """
    opts = options or IcpOptions()
    rim_obs = None if rim_points_sensor is None or len(rim_points_sensor) == 0 else check_points(
        rim_points_sensor, "rim_points_sensor")
    tpl = template if isinstance(template, PreparedTemplate) else prepare_template(template)
    scan = check_points(scan_sensor, "scan_sensor", minimum=3)
    T0 = check_pose(T_sensor_target_init, "T_sensor_target_init")
    A = invert(T0)
    gate = opts.max_correspondence_m
    converged = False
    it = 0

    def fail(detail: str) -> ExtractionFailure:
        return ExtractionFailure(sensor, t_ns, ICP_DIVERGED, detail)

    for it in range(1, opts.max_iterations + 1):
        x = transform_points(A, scan)
        dist, j = tpl.tree.query(x, distance_upper_bound=gate)
        ok = np.isfinite(dist)
        if np.sum(ok) < 6:
            return fail(
                f"iteration {it}: {int(np.sum(ok))} scan points within {gate:.3f} m of the template"
            )
        xo, q, n = x[ok], tpl.points[j[ok]], tpl.normals[j[ok]]
        if opts.method == "point_to_point":
            w = _robust_weights(dist[ok], opts)
            if not np.any(w > 0):
                return fail(f"iteration {it}: every match has zero weight")
            try:
                A_new = kabsch(scan[ok], q, w)
            except GeometryError as exc:
                return fail(f"iteration {it}: {exc}")
            d_rot = float(np.linalg.norm(so3_log(A_new[:3, :3] @ A[:3, :3].T)))
            d_trans = float(np.linalg.norm(A_new[:3, 3] - A[:3, 3]))
            A = A_new
        else:
            H, g = np.zeros((6, 6)), np.zeros(6)
            r = np.einsum("ni,ni->n", n, xo - q)
            _accumulate(H, g, np.concatenate([np.cross(xo, n), n], axis=1), r,
                        _robust_weights(np.abs(r), opts) * tpl.smooth[j[ok]])
            if opts.method == "combined" and tpl.has_rim:
                xs, ms, qs = _rim_matches(tpl, x, gate, None)
                if rim_obs is not None:
                    xe, me, qe = _rim_matches(tpl, transform_points(A, rim_obs), gate, True)
                    xs, ms, qs = np.vstack([xs, xe]), np.vstack([ms, me]), np.vstack([qs, qe])
                if len(xs):
                    rr = np.einsum("ni,ni->n", ms, xs - qs)
                    _accumulate(H, g, np.concatenate([np.cross(xs, ms), ms], axis=1), rr,
                                opts.rim_weight * _robust_weights(np.abs(rr), opts))
            centre = xo.mean(axis=0)
            size = max(float(np.sqrt(np.mean(np.sum((xo - centre) ** 2, axis=1)))), 0.01)
            xi = _solve_truncated(H, g, centre, size, opts.min_curvature_ratio)
            if not np.all(np.isfinite(xi)):
                return fail(f"iteration {it}: non-finite update")
            A = se3_exp(xi) @ A
            d_rot, d_trans = float(np.linalg.norm(xi[:3])), float(np.linalg.norm(xi[3:]))
        if not np.all(np.isfinite(A)):
            return fail(f"iteration {it}: non-finite pose")
        sigma = 1.4826 * float(np.median(dist[ok]))
        gate = float(np.clip(4.0 * sigma, opts.min_correspondence_m, opts.max_correspondence_m))
        if d_rot < opts.tolerance_rotation_rad and d_trans < opts.tolerance_translation_m:
            converged = True
            break

    T = invert(A)
    dist, _ = tpl.tree.query(transform_points(A, scan))
    inl = dist <= gate
    frac = float(np.mean(inl))
    rms = float(np.sqrt(np.mean(dist[inl] ** 2))) if np.any(inl) else math.inf
    dT = invert(T0) @ T
    moved_t = float(np.linalg.norm(T[:3, 3] - T0[:3, 3]))
    moved_r = float(np.linalg.norm(so3_log(dT[:3, :3])))
    if frac < opts.min_inlier_fraction:
        return fail(
            f"{frac:.0%} of the scan points within {gate:.3f} m of the template, need "
            f"{opts.min_inlier_fraction:.0%}"
        )
    if rms > opts.max_rms_m:
        return fail(f"inlier RMS {rms:.4f} m > {opts.max_rms_m} m")
    if moved_t > opts.max_translation_change_m or moved_r > opts.max_rotation_change_rad:
        return fail(
            f"the pose moved {moved_t:.3f} m / {math.degrees(moved_r):.2f} deg from the start, "
            f"limits {opts.max_translation_change_m} m / "
            f"{math.degrees(opts.max_rotation_change_rad):.1f} deg"
        )
    return IcpResult(T, dist, inl, rms, frac, it, converged, gate)
