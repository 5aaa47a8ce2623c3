"""Analytic targets generated from their dimensions, and distances to their ideal surfaces.

Frames (all metres):

* **Checkerboard diamond** (Charron et al., Fig. 2 left; the original tool's simulated target):
  the frame of the checkerboard printed on it. Origin at the checkerboard's outer corner, x
  along its columns, y along its rows, z out of the front face; the plate is the z = 0 plane.
  ``rows`` x ``cols`` counts **inner** corners; inner corner (r, c) sits at
  ``((c + 1) * square_m, (r + 1) * square_m, 0)``, listed row by row with c fastest (the order
  of the original tool's ``keypoints_camera``). The diamond is a square plate of side
  ``side_m`` turned 45 degrees, centred on the checkerboard centre
  ``((cols + 1) / 2 * square_m, (rows + 1) / 2 * square_m)``; its corners (the lidar keypoints)
  are listed -y, +x, +y, -x from that centre, at ``side_m / sqrt(2)``. The shared
  ``CheckerboardTargetSim.json`` is exactly ``diamond_target(0.5, 0.029, rows=6, cols=7)``.
* **Cylinder** (Fig. 2 right): axis along z, origin at the centre of the top end, the body
  occupying ``-height_m <= z <= 0`` (as the tool's ``cylinder_target_rotated.pcd``). No distinct
  keypoints: both keypoint sets are None and matching uses the template.
* **Circle board** (Domhof et al.; :mod:`rigcal.targets.circle_board`): origin at the centre of
  the four holes on the front face, x right, y up, z out of the front face. The plate is
  ``width_m`` x ``height_m``, centred on the holes horizontally; the holes sit
  ``holes_above_plate_centre_m`` above the plate centre (default -0.3 m, i.e. 0.3 m below it,
  as in :mod:`rigcal.sim.raw.scene`). Lidar and camera keypoints are the 4 hole centres (TL,
  TR, BL, BR).

Templates are sampled on a square grid of ``resolution_m`` plus the outlines (plate edges,
hole rims, cylinder end circles) so that edges and corners are represented exactly.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.errors import InputError
from rigcal.targets.circle_board import board_centres
from rigcal.targets.definition import CropBox, Target, TargetKind

__all__ = [
    "REQUIRED_DIMS",
    "analytic_target",
    "board_from_dims",
    "checkerboard_inner_corners",
    "circle_board_target",
    "cylinder_target",
    "diamond_corners",
    "diamond_target",
    "plate_centre_y",
]

DEFAULT_RESOLUTION_M = 0.005
DEFAULT_CROP_MARGIN_M = 0.1


def _positive(value: Any, what: str) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not math.isfinite(float(value)) or float(value) <= 0:
        raise InputError(f"{what} must be a finite number > 0, got {value!r}")
    return float(value)


def _count(value: Any, what: str) -> int:
    ok = isinstance(value, (int, np.integer)) or (
        isinstance(value, (float, np.floating)) and float(value).is_integer())
    if isinstance(value, bool) or not ok or int(value) < 1:
        raise InputError(f"{what} must be a whole number >= 1, got {value!r}")
    return int(value)


def _segment(a: np.ndarray, b: np.ndarray, resolution_m: float) -> np.ndarray:
    n = max(int(math.ceil(np.linalg.norm(b - a) / resolution_m)), 1)
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + s * (b - a)


def _circle(centre_xy: np.ndarray, radius: float, z: float, resolution_m: float) -> np.ndarray:
    n = max(int(math.ceil(2 * math.pi * radius / resolution_m)), 8)
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([centre_xy[0] + radius * np.cos(a), centre_xy[1] + radius * np.sin(a),
                            np.full(n, z)])


def _grid(lo: np.ndarray, hi: np.ndarray, resolution_m: float) -> np.ndarray:
    """(P, 2) grid points covering [lo, hi] with the edges included."""
    axes = []
    for a, b in zip(lo, hi):
        n = max(int(math.ceil((b - a) / resolution_m)), 1)
        axes.append(np.linspace(a, b, n + 1))
    gx, gy = np.meshgrid(*axes, indexing="xy")
    return np.column_stack([gx.ravel(), gy.ravel()])


# --------------------------------------------------------------------------------------------
# checkerboard diamond


def checkerboard_inner_corners(rows: int, cols: int, square_m: float) -> np.ndarray:
    """(rows * cols, 3) inner corners in the checkerboard frame, row by row, column fastest:
    corner (r, c) at ``((c + 1) * square_m, (r + 1) * square_m, 0)``."""
    rows = _count(rows, "checkerboard rows")
    cols = _count(cols, "checkerboard cols")
    sq = _positive(square_m, "checkerboard square_m")
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return np.column_stack([(c.ravel() + 1) * sq, (r.ravel() + 1) * sq, np.zeros(rows * cols)])


def diamond_corners(side_m: float, centre_xy: Any = (0.0, 0.0)) -> np.ndarray:
    """(4, 3) corners of a square of side ``side_m`` turned 45 degrees about ``centre_xy`` in
    the z = 0 plane, ordered -y, +x, +y, -x."""
    h = _positive(side_m, "diamond side_m") / math.sqrt(2.0)
    cx, cy = (float(v) for v in np.asarray(centre_xy, dtype=float).reshape(2))
    return np.array([[cx, cy - h, 0.0], [cx + h, cy, 0.0], [cx, cy + h, 0.0], [cx - h, cy, 0.0]])


def diamond_target(side_m: float = 0.5, square_m: float = 0.029, rows: int = 6, cols: int = 7,
                   *, name: str = "diamond", resolution_m: float = DEFAULT_RESOLUTION_M,
                   crop_margin_m: float = DEFAULT_CROP_MARGIN_M) -> Target:
    """The diamond target with a checkerboard (defaults: the original tool's simulated target,
    0.5 m diamond, 6 x 7 inner corners of 29 mm squares). Lidar keypoints: the 4 diamond
    corners; camera keypoints: the checkerboard inner corners; template: the plate sampled at
    ``resolution_m`` with its outline. The checkerboard must fit on the diamond."""
    side = _positive(side_m, "diamond side_m")
    sq = _positive(square_m, "checkerboard square_m")
    res = _positive(resolution_m, "resolution_m")
    inner = checkerboard_inner_corners(rows, cols, sq)
    rows, cols = int(rows), int(cols)
    centre = np.array([(cols + 1) * sq / 2.0, (rows + 1) * sq / 2.0])
    h = side / math.sqrt(2.0)
    if (cols + 1) * sq / 2.0 + (rows + 1) * sq / 2.0 > h + 1e-12:
        raise InputError(
            f"diamond target: a {cols + 1} x {rows + 1}-square checkerboard of {sq} m squares "
            f"does not fit on a diamond of side {side} m"
        )
    corners = diamond_corners(side, centre)
    grid = _grid(centre - h, centre + h, res)
    inside = np.abs(grid[:, 0] - centre[0]) + np.abs(grid[:, 1] - centre[1]) <= h + 1e-12
    plate = np.column_stack([grid[inside], np.zeros(int(inside.sum()))])
    outline = np.vstack([_segment(corners[i], corners[(i + 1) % 4], res) for i in range(4)])
    template = np.vstack([plate, outline])
    return Target(
        name=name, kind=TargetKind.CHECKERBOARD_DIAMOND, template=template,
        lidar_keypoints=corners, camera_keypoints=inner,
        dims={"side_m": side, "square_m": sq, "rows": rows, "cols": cols},
        crop_box=CropBox.around(template, crop_margin_m), planar=True, use_lidar_keypoints=True,
    )


# --------------------------------------------------------------------------------------------
# cylinder


def cylinder_target(radius_m: float, height_m: float, *, name: str = "cylinder",
                    caps: bool = True, resolution_m: float = DEFAULT_RESOLUTION_M,
                    crop_margin_m: float = DEFAULT_CROP_MARGIN_M) -> Target:
    """A cylinder of ``radius_m`` and ``height_m`` (axis z, top end at z = 0, body below).
    Template: its lateral surface, plus the two end discs when ``caps``; no keypoints."""
    r = _positive(radius_m, "cylinder radius_m")
    h = _positive(height_m, "cylinder height_m")
    res = _positive(resolution_m, "resolution_m")
    n_around = max(int(math.ceil(2 * math.pi * r / res)), 8)
    n_along = max(int(math.ceil(h / res)), 1)
    a = np.linspace(0.0, 2 * math.pi, n_around, endpoint=False)
    z = np.linspace(-h, 0.0, n_along + 1)
    A, Z = np.meshgrid(a, z, indexing="xy")
    parts = [np.column_stack([r * np.cos(A.ravel()), r * np.sin(A.ravel()), Z.ravel()])]
    if caps:
        disc = _grid(np.array([-r, -r]), np.array([r, r]), res)
        disc = disc[np.hypot(disc[:, 0], disc[:, 1]) < r]
        for zc in (0.0, -h):
            parts.append(np.column_stack([disc, np.full(len(disc), zc)]))
    template = np.vstack(parts)
    return Target(
        name=name, kind=TargetKind.CYLINDER, template=template, lidar_keypoints=None,
        camera_keypoints=None, dims={"radius_m": r, "height_m": h},
        crop_box=CropBox.around(template, crop_margin_m), planar=False,
        use_lidar_keypoints=False,
    )


# --------------------------------------------------------------------------------------------
# circle board


def board_from_dims(dims: Mapping[str, float]) -> BoardGeometry:
    """The circle board's geometry from a target's ``dims`` (defaults for what is missing)."""
    fields = ("spacing_m", "reflector_offset_m", "hole_diameter_m", "width_m", "height_m")
    return BoardGeometry(**{f: float(dims[f]) for f in fields if f in dims})


def plate_centre_y(board: BoardGeometry, holes_above_plate_centre_m: float) -> float:
    """y [m] of the plate's centre in the board frame (hole pattern centred at the origin)."""
    off = float(holes_above_plate_centre_m)
    if not math.isfinite(off):
        raise InputError(f"holes_above_plate_centre_m must be finite, got {off!r}")
    cy = -off
    h = board.spacing_m / 2 + board.hole_diameter_m / 2
    if abs(cy) + h > board.height_m / 2 or h > board.width_m / 2:
        raise InputError(
            f"circle board: holes_above_plate_centre_m = {off} puts the holes (spacing "
            f"{board.spacing_m} m, diameter {board.hole_diameter_m} m) off the "
            f"{board.width_m} x {board.height_m} m plate"
        )
    return cy


def circle_board_target(board: BoardGeometry = BoardGeometry(), *,
                        holes_above_plate_centre_m: float = -0.3, name: str = "circle_board",
                        resolution_m: float = 0.01,
                        crop_margin_m: float = DEFAULT_CROP_MARGIN_M) -> Target:
    """The circle board of Domhof et al.: a plate with four holes. Lidar and camera keypoints:
    the hole centres (TL, TR, BL, BR); template: plate points outside the holes, the plate's
    outline and the hole rims."""
    res = _positive(resolution_m, "resolution_m")
    cy = plate_centre_y(board, holes_above_plate_centre_m)
    w, hgt = board.width_m, board.height_m
    lo, hi = np.array([-w / 2, cy - hgt / 2]), np.array([w / 2, cy + hgt / 2])
    centres = board_centres(board)
    radius = board.hole_diameter_m / 2
    grid = _grid(lo, hi, res)
    d = np.linalg.norm(grid[:, None, :] - centres[None, :, :2], axis=2)
    plate = grid[np.all(d > radius, axis=1)]
    corners = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0],
                        [lo[0], hi[1], 0.0]])
    outline = np.vstack([_segment(corners[i], corners[(i + 1) % 4], res) for i in range(4)])
    rims = np.vstack([_circle(c[:2], radius, 0.0, res) for c in centres])
    template = np.vstack([np.column_stack([plate, np.zeros(len(plate))]), outline, rims])
    return Target(
        name=name, kind=TargetKind.CIRCLE_BOARD, template=template, lidar_keypoints=centres,
        camera_keypoints=centres,
        dims={"spacing_m": board.spacing_m, "hole_diameter_m": board.hole_diameter_m,
              "width_m": w, "height_m": hgt, "reflector_offset_m": board.reflector_offset_m,
              "holes_above_plate_centre_m": float(holes_above_plate_centre_m)},
        crop_box=CropBox.around(template, crop_margin_m), planar=True, use_lidar_keypoints=True,
    )


# --------------------------------------------------------------------------------------------
# from a kind and dims


#: the dims each analytic kind needs
REQUIRED_DIMS = {
    TargetKind.CHECKERBOARD_DIAMOND: ("side_m", "square_m", "rows", "cols"),
    TargetKind.CYLINDER: ("radius_m", "height_m"),
    TargetKind.CIRCLE_BOARD: (),
}


def analytic_target(kind: TargetKind | str, dims: Mapping[str, float], *, name: str | None = None,
                    resolution_m: float | None = None) -> Target:
    """The analytic target of ``kind`` from ``dims`` (the names :class:`Target.dims` uses).

    checkerboard_diamond needs side_m, square_m, rows, cols; cylinder radius_m, height_m; the
    circle board takes any of BoardGeometry's fields and holes_above_plate_centre_m (defaults
    otherwise). ``custom`` has no analytic form. InputError names the missing dimensions."""
    k = TargetKind.parse(kind)
    if k is TargetKind.CUSTOM:
        raise InputError("a custom target has no analytic template; give a template cloud")
    missing = [d for d in REQUIRED_DIMS[k] if d not in dims]
    if missing:
        raise InputError(
            f"analytic {k.value} target needs dims {', '.join(REQUIRED_DIMS[k])}; missing "
            f"{', '.join(missing)}"
        )
    extra: dict[str, Any] = {"name": name or k.value}
    if resolution_m is not None:
        extra["resolution_m"] = resolution_m
    if k is TargetKind.CHECKERBOARD_DIAMOND:
        return diamond_target(dims["side_m"], dims["square_m"], dims["rows"], dims["cols"],
                              **extra)
    if k is TargetKind.CYLINDER:
        return cylinder_target(dims["radius_m"], dims["height_m"], **extra)
    board = board_from_dims(dims)
    return circle_board_target(board, holes_above_plate_centre_m=float(
        dims.get("holes_above_plate_centre_m", -0.3)), **extra)
