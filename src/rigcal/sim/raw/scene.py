"""The world a raw-data simulation sees: the circle board, the ground and a back wall.

Frames: the world frame is the rig frame (vehicle parked, x forward, y left, z up, origin on
the ground), so the ground is the plane ``z = ground_height_m`` (0 by default). The board frame
is that of :mod:`rigcal.targets.circle_board` (origin at the centre of the four holes on the
front face, x right and y up seen from the front, z toward the viewer).

Board plate: ``board.width_m`` x ``board.height_m`` (1.0 m x 1.5 m), a thin rectangle in the
board's z = 0 plane, centred horizontally on the holes. The holes are not centred vertically:
their centre sits ``holes_above_plate_centre_m`` above the plate centre, by default -0.3 m, i.e.
**0.3 m below the plate centre** (0.45 m above the bottom edge, 1.05 m below the top edge). With
the reflector at the height of a bumper radar (about 0.5 m) such a board stands just above the
ground; with the holes above the centre its bottom edge would be in the ground. The plate is
double-sided and has no thickness: a ray through a hole continues to the wall or the ground.
The corner reflector sits ``board.reflector_offset_m`` behind the front face at the centre of
the holes; it is radar-only (Styrofoam and reflector are not modelled for lidar or camera).

Back wall: an infinite vertical plane facing the sensors. Unless given explicitly
(``wall_point_world`` and ``wall_normal_world``) it is placed ``wall_distance_m`` behind the
board origin, perpendicular to the horizontal part of the board's z axis, when the scene is
built; :meth:`Scene.with_board` keeps the wall where it is (a wall does not follow the board).

Surfaces carry a :class:`Material`: lidar reflectivity, a grey level and a speckle texture for
cameras. Textures are fixed random tiles drawn from ``texture_seed`` and evaluated in surface
coordinates (board x, y for the plate; horizontal and vertical metres along the wall; world x, y
on the ground), so every camera sees the same texture at the same 3D point - stereo matches.

Surface ids: :data:`SURFACE_NONE` (-1, no hit), :data:`SURFACE_PLATE` (0),
:data:`SURFACE_WALL` (1), :data:`SURFACE_GROUND` (2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache
from typing import NamedTuple

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.errors import InputError
from rigcal.targets.circle_board import board_centres, reflector_in_board
from rigcal.geometry.se3 import as_rigid

SURFACE_NONE = -1
SURFACE_PLATE = 0
SURFACE_WALL = 1
SURFACE_GROUND = 2
SURFACE_NAMES = {SURFACE_PLATE: "plate", SURFACE_WALL: "wall", SURFACE_GROUND: "ground"}

_TEXTURE_TILE_PX = 1024
_EPS_T = 1e-6




def _finite_positive(value: float, what: str, allow_zero: bool = False) -> float:
    ok = isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value)
    ok = ok and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{what} must be a finite number {bound}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Material:
    """How a surface looks.

    * ``reflectivity``: lidar reflectivity in [0, 1]; intensity = 255 * reflectivity * |cos|
      of the incidence angle;
    * ``grey``: camera grey level [0, 255] seen head-on (shading: ``0.75 + 0.25 |cos|``);
    * ``texture_contrast``: relative amplitude of the speckle texture (0 = uniform);
    * ``texture_cell_m``: size of one speckle cell on the surface [m].
    """

    reflectivity: float
    grey: float
    texture_contrast: float = 0.0
    texture_cell_m: float = 0.02

    def __post_init__(self) -> None:
        if not (math.isfinite(self.reflectivity) and 0.0 <= self.reflectivity <= 1.0):
            raise InputError(f"material.reflectivity must be in [0, 1], got {self.reflectivity!r}")
        if not (math.isfinite(self.grey) and 0.0 <= self.grey <= 255.0):
            raise InputError(f"material.grey must be in [0, 255], got {self.grey!r}")
        if not (math.isfinite(self.texture_contrast) and 0.0 <= self.texture_contrast <= 1.0):
            raise InputError(
                f"material.texture_contrast must be in [0, 1], got {self.texture_contrast!r}"
            )
        _finite_positive(self.texture_cell_m, "material.texture_cell_m")


#: White Styrofoam: bright, a faint texture (so stereo finds disparities on the plate).
PLATE_MATERIAL = Material(reflectivity=0.7, grey=220.0, texture_contrast=0.05, texture_cell_m=0.015)
#: A darker, textured wall.
WALL_MATERIAL = Material(reflectivity=0.35, grey=105.0, texture_contrast=0.4, texture_cell_m=0.02)
#: Asphalt-like ground.
GROUND_MATERIAL = Material(reflectivity=0.15, grey=85.0, texture_contrast=0.4, texture_cell_m=0.02)


class RayHits(NamedTuple):
    """Result of :meth:`Scene.cast` for N rays.

    ``range_m`` (N,) distance from the ray origin [m] (inf: no hit); ``surface`` (N,) int8
    surface id (:data:`SURFACE_NONE` = -1 for no hit); ``points_world`` (N, 3) hit points (NaN
    for no hit).
    """

    range_m: np.ndarray
    surface: np.ndarray
    points_world: np.ndarray


class _Plane(NamedTuple):
    """A surface plane: origin, in-plane axes u, v and normal n (world or sensor frame)."""

    sid: int
    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    n: np.ndarray


class _Trace(NamedTuple):
    """Nearest hit per ray: parameter t along the (unnormalised) direction, surface id,
    surface coordinates (a, b) along the plane's u, v axes, and n . d of the hit plane."""

    t: np.ndarray
    sid: np.ndarray
    a: np.ndarray
    b: np.ndarray
    ndotd: np.ndarray


@dataclass(frozen=True, eq=False)
class Scene:
    """An immutable scene: board pose ``T_world_board`` (4, 4), ground, back wall, materials.

    See the module docstring for the geometry. ``wall_point_world`` / ``wall_normal_world``
    (3,) fix the wall explicitly (normal toward the sensors); when left ``None`` they are
    computed from the board pose and ``wall_distance_m``. ``has_wall`` / ``has_ground`` switch
    the surfaces off. ``sky_grey`` is the grey level cameras see where no surface is hit.
    """

    T_world_board: np.ndarray
    board: BoardGeometry = BoardGeometry()
    holes_above_plate_centre_m: float = -0.3
    wall_distance_m: float = 2.5
    wall_point_world: np.ndarray | None = None
    wall_normal_world: np.ndarray | None = None
    has_wall: bool = True
    has_ground: bool = True
    ground_height_m: float = 0.0
    plate_material: Material = PLATE_MATERIAL
    wall_material: Material = WALL_MATERIAL
    ground_material: Material = GROUND_MATERIAL
    sky_grey: float = 180.0
    texture_seed: int = 0

    def __post_init__(self) -> None:
        T = as_rigid(self.T_world_board, "scene.T_world_board")
        object.__setattr__(self, "T_world_board", T)
        if not isinstance(self.board, BoardGeometry):
            raise InputError(
                f"scene.board must be a BoardGeometry, got {type(self.board).__name__}"
            )
        off = float(self.holes_above_plate_centre_m)
        half = self.board.height_m / 2.0
        r = self.board.hole_diameter_m / 2.0
        s = self.board.spacing_m / 2.0
        if not (math.isfinite(off) and abs(off) + s + r < half and s + r < self.board.width_m / 2):
            raise InputError(
                f"scene.holes_above_plate_centre_m = {self.holes_above_plate_centre_m!r} puts the "
                f"holes (square {self.board.spacing_m} m, diameter {self.board.hole_diameter_m} m) "
                f"outside the {self.board.width_m} x {self.board.height_m} m plate"
            )
        object.__setattr__(self, "holes_above_plate_centre_m", off)
        _finite_positive(self.wall_distance_m, "scene.wall_distance_m")
        if not math.isfinite(self.ground_height_m):
            raise InputError(f"scene.ground_height_m must be finite, got {self.ground_height_m!r}")
        if not (math.isfinite(self.sky_grey) and 0.0 <= self.sky_grey <= 255.0):
            raise InputError(f"scene.sky_grey must be in [0, 255], got {self.sky_grey!r}")
        for name in ("plate_material", "wall_material", "ground_material"):
            if not isinstance(getattr(self, name), Material):
                raise InputError(f"scene.{name} must be a Material")
        if (self.wall_point_world is None) != (self.wall_normal_world is None):
            raise InputError(
                "scene: give both wall_point_world and wall_normal_world, or neither "
                "(the wall is then placed wall_distance_m behind the board)"
            )
        if self.wall_point_world is None:
            z = T[:3, 2]
            n = np.array([z[0], z[1], 0.0])
            if np.linalg.norm(n) < 1e-6:  # board lying flat: use its own normal
                n = z.copy()
            n = n / np.linalg.norm(n)
            point = T[:3, 3] - self.wall_distance_m * n
        else:
            point = np.array(self.wall_point_world, dtype=float)
            n = np.array(self.wall_normal_world, dtype=float)
            if point.shape != (3,) or n.shape != (3,) or not np.all(np.isfinite(np.r_[point, n])):
                raise InputError(
                    f"scene: wall_point_world and wall_normal_world must be finite (3,) vectors, "
                    f"got {point.shape} and {n.shape}"
                )
            if np.linalg.norm(n) < 1e-9:
                raise InputError("scene.wall_normal_world must not be zero")
            n = n / np.linalg.norm(n)
        point.setflags(write=False)
        n.setflags(write=False)
        object.__setattr__(self, "wall_point_world", point)
        object.__setattr__(self, "wall_normal_world", n)
        object.__setattr__(self, "texture_seed", int(self.texture_seed))

    # ------------------------------------------------------------------ geometry

    def with_board(self, T_world_board: np.ndarray) -> "Scene":
        """A copy with the board at another pose; the wall stays where it is."""
        return replace(self, T_world_board=T_world_board)

    @property
    def plate_bounds_board(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the plate in the board frame [m]."""
        w2, h2 = self.board.width_m / 2.0, self.board.height_m / 2.0
        c = -self.holes_above_plate_centre_m
        return (-w2, w2, c - h2, c + h2)

    def plate_corners_world(self) -> np.ndarray:
        """(4, 3) plate corners in the world frame [m]: top-left, top-right, bottom-left,
        bottom-right as seen from the front."""
        x0, x1, y0, y1 = self.plate_bounds_board
        pts = np.array([[x0, y1, 0.0], [x1, y1, 0.0], [x0, y0, 0.0], [x1, y0, 0.0]])
        return pts @ self.T_world_board[:3, :3].T + self.T_world_board[:3, 3]

    def hole_centres_world(self) -> np.ndarray:
        """(4, 3) hole centres (TL, TR, BL, BR) in the world frame [m]."""
        return board_centres(self.board) @ self.T_world_board[:3, :3].T + self.T_world_board[:3, 3]

    def reflector_world(self) -> np.ndarray:
        """(3,) reflector phase centre in the world frame [m]."""
        T = self.T_world_board
        return T[:3, :3] @ reflector_in_board(self.board) + T[:3, 3]

    def material(self, surface: int) -> Material:
        """The material of a surface id."""
        if surface == SURFACE_PLATE:
            return self.plate_material
        if surface == SURFACE_WALL:
            return self.wall_material
        if surface == SURFACE_GROUND:
            return self.ground_material
        raise InputError(f"scene: no material for surface id {surface!r}")

    @cached_property
    def _planes(self) -> tuple[_Plane, ...]:
        """The surface planes in the world frame (computed once per scene)."""
        T = self.T_world_board
        planes = [_Plane(SURFACE_PLATE, T[:3, 3], T[:3, 0], T[:3, 1], T[:3, 2])]
        if self.has_wall:
            n = np.asarray(self.wall_normal_world)
            up = np.array([0.0, 0.0, 1.0])
            u = np.cross(up, n)  # horizontal along the wall (right as seen from the front)
            if np.linalg.norm(u) < 1e-6:
                u = np.array([1.0, 0.0, 0.0])
            u = u / np.linalg.norm(u)
            v = np.cross(n, u)
            p0 = np.asarray(self.wall_point_world)
            planes.append(_Plane(SURFACE_WALL, p0, u, v, n))
        if self.has_ground:
            planes.append(
                _Plane(
                    SURFACE_GROUND,
                    np.array([0.0, 0.0, self.ground_height_m]),
                    np.array([1.0, 0.0, 0.0]),
                    np.array([0.0, 1.0, 0.0]),
                    np.array([0.0, 0.0, 1.0]),
                )
            )
        return tuple(planes)

    def planes_in(self, T_frame_world: np.ndarray) -> tuple[_Plane, ...]:
        """The surface planes expressed in another frame (for rays cast from a sensor origin)."""
        R, t = T_frame_world[:3, :3], T_frame_world[:3, 3]
        return tuple(
            _Plane(p.sid, R @ p.origin + t, R @ p.u, R @ p.v, R @ p.n) for p in self._planes
        )

    # ------------------------------------------------------------------ ray casting

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> RayHits:
        """Nearest hit of N rays: ``origins`` (N, 3) or (3,), ``dirs`` (N, 3) in the world frame.

        Directions need not be unit vectors (they are normalised); rays start at their origin
        (hits at t <= 1e-6 m are ignored). Returns a :class:`RayHits` with ranges [m] measured
        from the origins. Fully vectorised (float64).
        """
        d = np.asarray(dirs, dtype=float)
        if d.ndim != 2 or d.shape[1] != 3:
            raise InputError(f"scene.cast: dirs must be (N, 3), got {d.shape}")
        o = np.asarray(origins, dtype=float)
        if o.shape != (3,) and o.shape != d.shape:
            raise InputError(
                f"scene.cast: origins must be (3,) or (N, 3) like dirs {d.shape}, got {o.shape}"
            )
        norm = np.sqrt(np.einsum("ij,ij->i", d, d))
        if np.any(~np.isfinite(norm)) or np.any(norm <= 0):
            raise InputError("scene.cast: every direction must be finite and non-zero")
        du = np.ascontiguousarray((d / norm[:, None]).T)  # (3, N): fast per-axis rows
        if o.ndim == 1:
            ox, oy, oz = (float(c) for c in o)
        else:
            ox, oy, oz = np.ascontiguousarray(o.T)
        tr = trace_planes(
            self._planes, self.plate_bounds_board, self.board, (ox, oy, oz), du[0], du[1], du[2],
            need_uv=False,
        )
        t_hit = np.where(tr.sid >= 0, tr.t, np.nan)
        pts = np.ascontiguousarray((du * t_hit).T + o)
        return RayHits(range_m=tr.t, surface=tr.sid, points_world=pts)


def trace_planes(
    planes: tuple[_Plane, ...],
    plate_bounds: tuple[float, float, float, float],
    board: BoardGeometry,
    origin: tuple,
    dx: np.ndarray,
    dy: np.ndarray,
    dz: np.ndarray | float,
    max_t: float = np.inf,
    need_uv: bool = True,
) -> _Trace:
    """Core ray caster on broadcastable direction components (any shape, float32 or float64).

    ``origin`` = (ox, oy, oz), scalars (shared origin) or arrays like the directions. Returns
    the nearest hit per ray with ``t`` along the given (possibly unnormalised) directions; rays
    without a hit (or beyond ``max_t``) get t = inf and surface -1. With ``need_uv=False`` the
    surface coordinates of wall and ground hits are not computed (left 0).
    """
    dx, dy = np.asarray(dx), np.asarray(dy)
    dtype = np.result_type(dx.dtype, dy.dtype, np.float32)
    shape = np.broadcast_shapes(dx.shape, dy.shape, np.shape(dz), *(np.shape(c) for c in origin))
    best_t = np.full(shape, np.inf, dtype=dtype)
    best_sid = np.full(shape, SURFACE_NONE, dtype=np.int8)
    best_a = np.zeros(shape, dtype=dtype)
    best_b = np.zeros(shape, dtype=dtype)
    best_nd = np.zeros(shape, dtype=dtype)
    ox, oy, oz = origin
    x0, x1, y0, y1 = plate_bounds
    s2 = board.spacing_m / 2.0
    r2 = (board.hole_diameter_m / 2.0) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for p in planes:
            n, u, v, p0 = (np.asarray(q, dtype=float) for q in (p.n, p.u, p.v, p.origin))
            rel = (ox - p0[0], oy - p0[1], oz - p0[2])  # origin relative to the plane origin
            num = _as(-(n[0] * rel[0] + n[1] * rel[1] + n[2] * rel[2]), dtype)
            ra = _as(u[0] * rel[0] + u[1] * rel[1] + u[2] * rel[2], dtype)
            rb = _as(v[0] * rel[0] + v[1] * rel[1] + v[2] * rel[2], dtype)
            nd = _dot(n, dx, dy, dz, dtype)
            t = num / nd
            if p.sid == SURFACE_GROUND:
                ok = nd < 0  # the ground is seen from above only
            else:
                ok = np.isfinite(t)
            ok = ok & (t > _EPS_T) & (t < best_t) & (t <= max_t)
            if p.sid == SURFACE_PLATE or need_uv:
                a = ra + t * _dot(u, dx, dy, dz, dtype)
                b = rb + t * _dot(v, dx, dy, dz, dtype)
            if p.sid == SURFACE_PLATE:
                ok = ok & (a >= x0) & (a <= x1) & (b >= y0) & (b <= y1)
                ha = np.abs(a) - dtype.type(s2)
                hb = np.abs(b) - dtype.type(s2)
                ok = ok & (ha * ha + hb * hb >= dtype.type(r2))
            np.copyto(best_t, np.broadcast_to(t, shape), where=ok)
            np.copyto(best_sid, np.int8(p.sid), where=ok)
            if p.sid == SURFACE_PLATE or need_uv:
                np.copyto(best_a, np.broadcast_to(a, shape), where=ok)
                np.copyto(best_b, np.broadcast_to(b, shape), where=ok)
            np.copyto(best_nd, np.broadcast_to(nd, shape), where=ok)
    return _Trace(best_t, best_sid, best_a, best_b, best_nd)


def _as(x, dtype) -> np.ndarray:
    return dtype.type(x) if np.ndim(x) == 0 else np.asarray(x).astype(dtype, copy=False)


def _dot(w: np.ndarray, dx, dy, dz, dtype) -> np.ndarray:
    """w . (dx, dy, dz) broadcast, skipping zero weights (cheap for axis-aligned planes)."""
    out = None
    for wi, di in zip(w, (dx, dy, dz)):
        if abs(wi) < 1e-15:
            continue
        term = dtype.type(wi) * di if np.ndim(di) else dtype.type(wi * di)
        out = term if out is None else out + term
    if out is None:
        return np.zeros(np.broadcast_shapes(np.shape(dx), np.shape(dy), np.shape(dz)), dtype=dtype)
    return np.asarray(out, dtype=dtype)


@lru_cache(maxsize=16)
def texture_tile(seed: int, surface: int) -> np.ndarray:
    """A (1024, 1024) float32 tile of uniform speckle in [-1, 1] for one surface (read-only)."""
    ss = np.random.SeedSequence([abs(int(seed)), int(int(seed) < 0), int(surface) + 7])
    tile = np.random.default_rng(ss).uniform(-1.0, 1.0, (_TEXTURE_TILE_PX, _TEXTURE_TILE_PX))
    tile = tile.astype(np.float32)
    tile.setflags(write=False)
    return tile


def check_sim_call(where: str, model, model_type: type, scene, rng, T_world_sensor, what: str) -> np.ndarray:
    """Validate a simulator call's arguments (model type, Scene, numpy Generator, rigid pose);
    returns the pose as a read-only rigid (4, 4). Errors are InputError prefixed with ``where``."""
    if not isinstance(model, model_type):
        raise InputError(
            f"{where}: model must be a {model_type.__name__}, got {type(model).__name__}"
        )
    if not isinstance(scene, Scene):
        raise InputError(f"{where}: scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise InputError(
            f"{where}: rng must be a numpy.random.Generator, got {type(rng).__name__}"
        )
    return as_rigid(T_world_sensor, f"{where}: {what}")
