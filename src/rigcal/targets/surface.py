"""A target's surface: the closest surface point and the surface normal there.

Measurements without distinct keypoints (every lidar point on a plate or a cylinder) are tied
to the target by their distance to its surface. :class:`TargetSurface` answers, for points in
the target frame, the closest point of the surface and a unit normal to use for a
point-to-plane residual ``n . (y - p)``:

* analytic surfaces from a target's ``kind`` and ``dims`` - the diamond plate (a filled
  square turned 45 degrees in z = 0), the closed cylinder (lateral surface and both end
  discs), the circle board (a rectangle with four holes) - exact to rounding;
* any other target (a template cloud, e.g. a PCD from the original tool): the nearest
  template point and the normal of a plane fitted to its neighbours.

A flat analytic target (the diamond plate, the circle board: the plane z = 0 of the target
frame) is ``planar`` and has a ``boundary``: the signed in-plane distance of points to its
outline (positive inside; the circle board's holes are not part of it) and its gradient -
where a scanning lidar's rings leave the plate (:mod:`rigcal.problem.residuals`). The
cylinder's lateral surface answers ``ray_range``: where rays from a point meet it, for a
lidar's range along its ray.

Where the closest point lies inside a face the normal is the face's; where the point is
beyond an edge or rim (the closest point is on the boundary) the normal is the direction from
the closest point to the point, so the residual is the distance to the boundary. Pure
functions of the inputs; nothing is mutated.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from rigcal.errors import InputError
from rigcal.targets.circle_board import board_centres
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.templates import REQUIRED_DIMS, board_from_dims, plate_centre_y

__all__ = ["TargetSurface", "surface_distance_m"]

#: below this distance [m] a point counts as on the surface (its face normal is used)
_ON_SURFACE_M = 1e-9
#: template neighbours for a normal
_NORMAL_NEIGHBOURS = 8


def _as_points(points: Any) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        p = p.reshape(-1, 3)
    return p


def _boundary_normals(p: np.ndarray, closest: np.ndarray, face_normal: np.ndarray,
                      clamped: np.ndarray) -> np.ndarray:
    """Face normals, replaced by the unit direction closest -> p where the closest point is on
    a boundary (``clamped``) and p is off the surface."""
    d = p - closest
    dist = np.linalg.norm(d, axis=1)
    use = clamped & (dist > _ON_SURFACE_M)
    out = np.array(face_normal, dtype=float, copy=True)
    out[use] = d[use] / dist[use, None]
    return out


def _diamond_square(dims) -> tuple[np.ndarray, float]:
    """The diamond plate's centre (2,) in its plane and its square's half side [m]."""
    sq = float(dims["square_m"])
    c = np.array([(int(dims["cols"]) + 1) * sq / 2.0, (int(dims["rows"]) + 1) * sq / 2.0])
    return c, float(dims["side_m"]) / 2.0


def _diamond(dims, p):
    c, half = _diamond_square(dims)
    s = 1.0 / math.sqrt(2.0)
    dx, dy = p[:, 0] - c[0], p[:, 1] - c[1]
    # in the square's own axes (turned 45 degrees) the closest point is a clamp
    u, v = (dx + dy) * s, (dy - dx) * s
    uc, vc = np.clip(u, -half, half), np.clip(v, -half, half)
    closest = np.column_stack([c[0] + (uc - vc) * s, c[1] + (uc + vc) * s, np.zeros(len(p))])
    clamped = (uc != u) | (vc != v)
    face = np.broadcast_to([0.0, 0.0, 1.0], p.shape)
    return closest, _boundary_normals(p, closest, face, clamped)


def _cylinder(dims, p):
    r, h = float(dims["radius_m"]), float(dims["height_m"])
    rho = np.hypot(p[:, 0], p[:, 1])
    safe = np.maximum(rho, 1e-12)
    radial = np.column_stack([p[:, 0] / safe, p[:, 1] / safe, np.zeros(len(p))])
    radial[rho < 1e-12] = [1.0, 0.0, 0.0]
    z_side = np.clip(p[:, 2], -h, 0.0)
    side = np.column_stack([r * radial[:, :2], z_side])
    side_clamped = z_side != p[:, 2]
    scale = np.minimum(1.0, r / safe)[:, None]
    disc_xy = p[:, :2] * scale
    disc_clamped = rho > r
    cands = [(side, radial, side_clamped)]
    for zc, nz in ((0.0, 1.0), (-h, -1.0)):
        cands.append((np.column_stack([disc_xy, np.full(len(p), zc)]),
                      np.broadcast_to([0.0, 0.0, nz], p.shape), disc_clamped))
    dist = np.stack([np.linalg.norm(c - p, axis=1) for c, _, _ in cands])
    best = np.argmin(dist, axis=0)
    closest = np.choose(best[:, None], [c for c, _, _ in cands])
    face = np.choose(best[:, None], [n for _, n, _ in cands])
    clamped = np.choose(best, [k for _, _, k in cands])
    return closest, _boundary_normals(p, closest, face, clamped)


def _circle_board_rect(dims):
    """The circle board, its plate's centre height in the board frame and its half width and
    half height [m]."""
    board = board_from_dims(dims)
    cy = plate_centre_y(board, float(dims.get("holes_above_plate_centre_m", -0.3)))
    return board, cy, board.width_m / 2, board.height_m / 2


def _circle_board(dims, p):
    board, cy, w, hgt = _circle_board_rect(dims)
    x = np.clip(p[:, 0], -w, w)
    y = np.clip(p[:, 1], cy - hgt, cy + hgt)
    clamped = (x != p[:, 0]) | (y != p[:, 1])
    closest = np.column_stack([x, y, np.zeros(len(p))])
    radius = board.hole_diameter_m / 2
    for c in board_centres(board)[:, :2]:
        d = closest[:, :2] - c
        dc = np.linalg.norm(d, axis=1)
        inside = dc < radius
        if np.any(inside):
            unit = np.where(dc[:, None] > 1e-12, d / np.maximum(dc, 1e-12)[:, None], [1.0, 0.0])
            closest[inside, :2] = c + radius * unit[inside]
            clamped = clamped | inside
    face = np.broadcast_to([0.0, 0.0, 1.0], p.shape)
    return closest, _boundary_normals(p, closest, face, clamped)


def _diamond_boundary(dims, xy):
    c, half = _diamond_square(dims)
    s = 1.0 / math.sqrt(2.0)
    dx, dy = xy[:, 0] - c[0], xy[:, 1] - c[1]
    u, v = (dx + dy) * s, (dy - dx) * s
    use_u = np.abs(u) >= np.abs(v)
    f = half - np.where(use_u, np.abs(u), np.abs(v))
    gu = -np.sign(u)[:, None] * np.array([s, s])
    gv = -np.sign(v)[:, None] * np.array([-s, s])
    return f, np.where(use_u[:, None], gu, gv)


def _diamond_corners(dims):
    c, half = _diamond_square(dims)
    return c + math.sqrt(2.0) * half * np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def _circle_board_corners(dims):
    _, cy, w, hgt = _circle_board_rect(dims)
    return np.array([[w, cy + hgt], [-w, cy + hgt], [-w, cy - hgt], [w, cy - hgt]])


def _circle_board_boundary(dims, xy):
    _, cy, w, hgt = _circle_board_rect(dims)
    fx = w - np.abs(xy[:, 0])
    fy = hgt - np.abs(xy[:, 1] - cy)
    use_x = fx <= fy
    gx = np.column_stack([-np.sign(xy[:, 0]), np.zeros(len(xy))])
    gy = np.column_stack([np.zeros(len(xy)), -np.sign(xy[:, 1] - cy)])
    return np.where(use_x, fx, fy), np.where(use_x[:, None], gx, gy)


def _cylinder_ray(dims, origins, dirs):
    """Rays ``origins + s dirs`` (unit dirs) against the cylinder's lateral surface (axis z,
    radius r; the infinite tube): the near hit's range ``s``, its gradients ``ds/d origin`` and
    ``ds/d dir`` (N, 3), whether the ray meets the tube (``hit``) and the hit's height ``z``. A
    ray that misses gets the range of its closest approach to the axis (where it would touch the
    tube first) and that range's gradients, so the range is continuous across the silhouette."""
    r = float(dims["radius_m"])
    o, w = origins, dirs
    oxy = np.column_stack([o[:, 0], o[:, 1], np.zeros(len(o))])
    wxy = np.column_stack([w[:, 0], w[:, 1], np.zeros(len(w))])
    a = np.maximum(np.einsum("ni,ni->n", wxy, wxy), 1e-12)
    b = np.einsum("ni,ni->n", oxy, wxy)
    c = np.einsum("ni,ni->n", oxy, oxy) - r * r
    disc = b * b - a * c
    hit = disc > 0
    root = np.sqrt(np.maximum(disc, 0.0))
    # the near root, without cancellation when the ray starts far from the tube
    near = np.where(b < 0, c / np.maximum(root - b, 1e-300), (-b - root) / a)
    s = np.where(hit, near, -b / a)
    h = o + s[:, None] * w
    rho = np.maximum(np.hypot(h[:, 0], h[:, 1]), 1e-12)
    n = np.column_stack([h[:, 0] / rho, h[:, 1] / rho, np.zeros(len(h))])
    # a hit: |h_xy| = r holds, so ds = -n . (do + s dw) / (n . w); a miss: s = -b / a
    nw = np.einsum("ni,ni->n", n, w)
    nw = np.where(np.abs(nw) < _MIN_COS, np.where(nw > 0, _MIN_COS, -_MIN_COS), nw)
    g_o = np.where(hit[:, None], -n / nw[:, None], -wxy / a[:, None])
    g_w = np.where(hit[:, None], -s[:, None] * n / nw[:, None],
                   -oxy / a[:, None] + (2 * b / a**2)[:, None] * wxy)
    return s, g_o, g_w, hit, h[:, 2]


#: a ray meeting a surface at less than this |cos| of its angle to the normal is treated as
#: meeting it at this angle (its range's gradient is bounded)
_MIN_COS = 1e-3


_RAY = {TargetKind.CYLINDER: _cylinder_ray}

_BOUNDARY = {
    TargetKind.CHECKERBOARD_DIAMOND: (_diamond_boundary, _diamond_corners),
    TargetKind.CIRCLE_BOARD: (_circle_board_boundary, _circle_board_corners),
}

_ANALYTIC = {
    TargetKind.CHECKERBOARD_DIAMOND: _diamond,
    TargetKind.CYLINDER: _cylinder,
    TargetKind.CIRCLE_BOARD: _circle_board,
}


def _template_normals(template: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Unit normals of planes fitted to every template point's neighbours."""
    k = min(_NORMAL_NEIGHBOURS, len(template))
    if k < 3:
        return np.tile([0.0, 0.0, 1.0], (len(template), 1))
    _, idx = tree.query(template, k=k)
    nb = template[idx]  # (K, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


class TargetSurface:
    """The surface of one target (see the module docstring). Immutable once built.

    ``TargetSurface.of(target)``: analytic when the target's kind and dims define one, its
    template cloud otherwise; ``TargetSurface.of_template(points)``: from a cloud alone.
    ``template`` (K, 3): the target's template points (for centroid-aligned matching)."""

    __slots__ = ("name", "template", "_dims", "_analytic", "_boundary", "_ray", "_tree", "_normals")

    def __init__(self, name: str, template: np.ndarray, kind: TargetKind = TargetKind.CUSTOM,
                 dims=None):
        t = np.array(template, dtype=float)
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
            raise InputError(f"target '{name}': template must be a non-empty (K, 3) array, "
                             f"got shape {t.shape}")
        t.setflags(write=False)
        dims = dict(dims or {})
        analytic = _ANALYTIC.get(kind)
        if analytic is not None and any(d not in dims for d in REQUIRED_DIMS[kind]):
            analytic = None
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "template", t)
        object.__setattr__(self, "_dims", dims)
        object.__setattr__(self, "_analytic", analytic)
        object.__setattr__(self, "_boundary", _BOUNDARY.get(kind) if analytic is not None else None)
        object.__setattr__(self, "_ray", _RAY.get(kind) if analytic is not None else None)
        tree = normals = None
        if analytic is None:
            tree = cKDTree(t)
            normals = _template_normals(t, tree)
            normals.setflags(write=False)
        object.__setattr__(self, "_tree", tree)
        object.__setattr__(self, "_normals", normals)

    def __setattr__(self, key, value):
        raise AttributeError("TargetSurface is immutable")

    @classmethod
    def of(cls, target: Target) -> "TargetSurface":
        return cls(target.name, target.template, target.kind, target.dims)

    @classmethod
    def of_template(cls, template: Any, name: str = "template") -> "TargetSurface":
        return cls(name, np.asarray(template, dtype=float))

    @property
    def analytic(self) -> bool:
        return self._analytic is not None

    @property
    def planar(self) -> bool:
        """A flat plate in the target frame's plane z = 0 with a known outline (the diamond,
        the circle board)."""
        return self._boundary is not None

    @property
    def curved_ray(self) -> bool:
        """A curved analytic surface that answers :meth:`ray_range` (the cylinder)."""
        return self._ray is not None

    @property
    def ray_radius_m(self) -> float:
        """The radius of a ``curved_ray`` surface (the cylinder's tube) [m]; NaN otherwise."""
        return float(self._dims["radius_m"]) if self._ray is not None else float("nan")

    def ray_range(self, origins: Any, dirs: Any):
        """Where rays ``origins + s dirs`` (N, 3), unit ``dirs``, target frame, meet the
        cylinder's lateral surface: (N,) range ``s`` to the near hit, (N, 3) its gradients with
        respect to the origin and the direction, (N,) whether the hit lies on the tube between
        its two end discs. A ray that misses the tube gets the range of its closest approach
        (``False``). Only for a ``curved_ray`` surface (ValueError otherwise)."""
        if self._ray is None:
            raise ValueError(f"target '{self.name}': no analytic curved surface to meet rays with")
        o = np.asarray(origins, dtype=float).reshape(-1, 3)
        w = np.asarray(dirs, dtype=float).reshape(-1, 3)
        s, g_o, g_w, hit, z = self._ray(self._dims, o, w)
        on = hit & (z <= 0.0) & (z >= -float(self._dims["height_m"]))
        return s, g_o, g_w, on

    def boundary(self, xy: Any) -> tuple[np.ndarray, np.ndarray]:
        """(N,) signed distance [m] of in-plane points (N, 2) (the plane z = 0 of the target
        frame) to the plate's outline, positive inside, and (N, 2) its gradient. Only for a
        ``planar`` surface (ValueError otherwise)."""
        if self._boundary is None:
            raise ValueError(f"target '{self.name}': not a flat plate with a known outline")
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        return self._boundary[0](self._dims, p)

    def corner_distance(self, xy: Any) -> np.ndarray:
        """(N,) in-plane distance [m] of points (N, 2) to the nearest corner of the plate's
        outline (where :meth:`boundary` turns from one side to the next). Only for a
        ``planar`` surface."""
        if self._boundary is None:
            raise ValueError(f"target '{self.name}': not a flat plate with a known outline")
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        corners = self._boundary[1](self._dims)
        return np.min(np.linalg.norm(p[:, None, :] - corners[None], axis=2), axis=1)

    def closest(self, points_target: Any) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) closest surface points and (N, 3) unit normals for points (N, 3) in the
        target frame [m]."""
        p = _as_points(points_target)
        if self._analytic is not None:
            return self._analytic(self._dims, p)
        _, j = self._tree.query(p)
        return self.template[j], self._normals[j]

    def distance(self, points_target: Any) -> np.ndarray:
        """(N,) distance [m] of points (N, 3) in the target frame to the surface (for a
        template: to the nearest template point)."""
        p = _as_points(points_target)
        c, _ = self.closest(p)
        return np.linalg.norm(p - c, axis=1)


def surface_distance_m(target: Target, points_target: Any) -> np.ndarray:
    """(N,) distance [m] from points (N, 3) in the target frame to the target's ideal
    (analytic) surface. InputError for a custom target or missing dims."""
    if target.kind is TargetKind.CUSTOM:
        raise InputError(f"target '{target.name}': a custom target has no analytic surface")
    missing = [d for d in REQUIRED_DIMS[target.kind] if d not in target.dims]
    if missing:
        raise InputError(f"target '{target.name}': surface distance needs dims "
                         f"{', '.join(missing)}")
    return TargetSurface.of(target).distance(points_target)
