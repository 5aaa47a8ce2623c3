"""Shared pieces of the point-cloud board detectors (lidar, stereo).

The pipeline both detectors follow, each step a function here:

1. :func:`box_mask` crops to an optional region of interest;
2. :func:`remove_ground` drops the largest near-horizontal plane below the sensor;
3. :func:`euclidean_clusters` groups the rest by voxel-grid connectivity;
4. :func:`board_candidates` ranks the clusters whose RANSAC plane has the board's size (or
   could be a partial view of it);
5. the detector finds hole-edge points (modality-specific) and maps them into the board plane
   with :func:`board_frame` (x right, y up as seen from the sensor, z toward the sensor);
6. :func:`find_hole_square` finds the four holes: a Hough vote for the square template, a rigid
   square-of-circles fit, per-hole circle fits and the square check.

A step that cannot go on raises :class:`StepFailed` (internal) carrying the stable reason code
and a detail sentence; the detectors turn it into a
:class:`~rigcal.detect.result.DetectionFailure`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.errors import ConfigError, GeometryError
from rigcal.geometry.fitting import (
    PlaneFit,
    SquareCirclesFit,
    circle_angular_gap,
    fit_circle_2d,
    fit_square_circles_2d,
    plane_basis,
    ransac_plane,
    square_template_2d,
)

__all__ = [
    "BoardDetectorConfig",
    "BoardSegment",
    "HoleParams",
    "HoleSquare",
    "StepFailed",
    "board_frame",
    "box_mask",
    "euclidean_clusters",
    "find_hole_square",
    "board_candidates",
    "remove_ground",
    "rings_from_elevation",
]


class StepFailed(Exception):
    """A detection step found no board; ``reason`` is the stable code, ``detail`` the numbers."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# ----------------------------------------------------------------------------- config checks


def check_box(box_min, box_max, where: str):
    """Validated ROI corners as two (3,) arrays, or (None, None)."""
    if box_min is None and box_max is None:
        return None, None
    if box_min is None or box_max is None:
        raise ConfigError(f"{where}: roi_min_xyz and roi_max_xyz must be given together")
    lo = np.asarray(box_min, dtype=float).reshape(-1)
    hi = np.asarray(box_max, dtype=float).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(np.r_[lo, hi])):
        raise ConfigError(
            f"{where}: roi_min_xyz / roi_max_xyz must be 3 finite numbers each, got "
            f"{box_min!r} and {box_max!r}"
        )
    if np.any(hi <= lo):
        raise ConfigError(
            f"{where}: roi_max_xyz {hi.tolist()} must exceed roi_min_xyz {lo.tolist()}"
        )
    return lo, hi


def check_positive(obj, names: tuple[str, ...], where: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ConfigError(f"{where}.{name} must be a positive number, got {v!r}")


def check_seed(seed, where: str) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"{where}.seed must be an integer >= 0, got {seed!r}")


def check_axis(v, name: str, where: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-9:
        raise ConfigError(f"{where}.{name} must be a non-zero 3-vector, got {v!r}")
    return a / np.linalg.norm(a)


@dataclass(frozen=True)
class BoardDetectorConfig:
    """Settings both point-cloud detectors share; :class:`rigcal.detect.lidar.LidarDetectorConfig`
    and :class:`rigcal.detect.stereo.StereoDetectorConfig` give them their own defaults and add
    their own fields (the field meanings are documented there).

    Subclasses name themselves in errors with ``WHERE`` and list their extra positive fields in
    ``EXTRA_POSITIVE``; ``_check_extra`` adds further checks."""

    WHERE: ClassVar[str] = "board detector"
    EXTRA_POSITIVE: ClassVar[tuple[str, ...]] = ()

    roi_min_xyz: tuple[float, float, float] | None = None
    roi_max_xyz: tuple[float, float, float] | None = None
    min_range_m: float = 0.5
    max_range_m: float = 15.0
    up_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    remove_ground: bool = True
    ground_threshold_m: float = 0.1
    ground_max_angle_deg: float = 30.0
    ground_iterations: int = 100
    cluster_cell_m: float = 0.2
    min_board_points: int = 30
    check_board_size: bool = True
    allow_partial_board: bool = True
    size_tolerance_m: float = 0.3
    max_board_candidates: int = 3
    plane_threshold_m: float = 0.05
    plane_iterations: int = 200
    jump_m: float = 0.15
    min_radius_m: float = 0.06
    max_radius_m: float = 0.10
    circle_threshold_m: float = 0.03
    min_edge_points: int = 8
    refine_square: bool = True
    square_tolerance_m: float = 0.03
    vote_cell_m: float = 0.01
    vote_angle_step_deg: float = 6.0
    seed: int = 0

    def __post_init__(self) -> None:
        where = self.WHERE
        check_box(self.roi_min_xyz, self.roi_max_xyz, where)
        check_axis(self.up_axis, "up_axis", where)
        check_seed(self.seed, where)
        check_positive(
            self,
            ("min_range_m", "max_range_m", "ground_threshold_m", "ground_max_angle_deg",
             "ground_iterations", "cluster_cell_m", "min_board_points", "size_tolerance_m",
             "max_board_candidates", "plane_threshold_m", "plane_iterations", "jump_m",
             "min_radius_m", "max_radius_m", "circle_threshold_m", "min_edge_points",
             "square_tolerance_m", "vote_cell_m", "vote_angle_step_deg") + self.EXTRA_POSITIVE,
            where,
        )
        if self.max_range_m <= self.min_range_m:
            raise ConfigError(
                f"{where}: max_range_m ({self.max_range_m}) must exceed min_range_m "
                f"({self.min_range_m})"
            )
        if self.max_radius_m < self.min_radius_m:
            raise ConfigError(
                f"{where}: max_radius_m ({self.max_radius_m}) must be >= min_radius_m "
                f"({self.min_radius_m})"
            )
        self._check_extra()

    def _check_extra(self) -> None:
        """Checks of a subclass's own fields (none here)."""


# ----------------------------------------------------------------------------- segmentation


def box_mask(
    points: np.ndarray, box_min: np.ndarray | None, box_max: np.ndarray | None
) -> np.ndarray:
    """(N,) bool: finite points inside the axis-aligned box (every finite point without a box)."""
    p = np.asarray(points, float)
    ok = np.isfinite(p).all(axis=1)
    if box_min is not None:
        with np.errstate(invalid="ignore"):
            ok &= np.all((p >= box_min) & (p <= box_max), axis=1)
    return ok


def remove_ground(
    points: np.ndarray,
    up: np.ndarray,
    rng: np.random.Generator,
    *,
    threshold_m: float,
    max_angle_deg: float,
    iterations: int,
    min_fraction: float = 0.05,
    min_points: int = 50,
    min_spread_m: float = 0.3,
    fit_sample: int = 20000,
) -> tuple[np.ndarray, PlaneFit | None]:
    """Drop the ground: the RANSAC plane of the points below the sensor whose normal is within
    ``max_angle_deg`` of ``up`` (sensor frame), holding at least ``min_fraction`` of the points
    spread over an area (standard deviation >= ``min_spread_m`` along both in-plane axes, so a
    tilted plane cutting a wall or the board along a line is not taken for the ground).

    The plane is fitted on at most ``fit_sample`` random points below the sensor.
    Returns the (N,) mask of points off the ground band (``|distance| >= threshold_m``; all
    points when no ground is found) and the ground plane (normal up) or None.
    """
    p = np.asarray(points, float)
    keep_all = np.ones(p.shape[0], dtype=bool)
    below = np.nonzero(p @ up < 0)[0]
    if below.size < max(min_points, 3):
        return keep_all, None
    # the ground is large: fit it on a random subset (fractions are preserved), apply to all
    sample = below if below.size <= fit_sample else below[rng.integers(0, below.size, fit_sample)]
    try:
        fit = ransac_plane(
            p[sample], threshold_m, rng, iterations, normal_hint=up, max_angle_deg=max_angle_deg
        )
    except GeometryError:
        return keep_all, None
    fraction = fit.inliers.sum() / sample.size * below.size / p.shape[0]
    if fraction * p.shape[0] < min_points or fraction < min_fraction or fit.normal @ up <= 0:
        return keep_all, None
    inl = p[sample][fit.inliers]
    qc = inl - inl.mean(axis=0)
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(qc.T @ qc / inl.shape[0]), 0.0))
    if spread[1] < min_spread_m:
        return keep_all, None
    return np.abs(p @ fit.normal + fit.d) >= threshold_m, fit


_HALF_NEIGHBOURS = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) > (0, 0, 0)]
)


def euclidean_clusters(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, int]:
    """Connected components of the occupied voxels (edge ``cell_m``, 26-neighbourhood).

    Points closer than ``cell_m`` always share a cluster; points up to ``2 * sqrt(3) * cell_m``
    apart may. Returns (N,) labels 0..K-1 and K.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    p = np.asarray(points, float)
    if p.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), 0
    v = np.floor(p / cell_m).astype(np.int64)
    v -= v.min(axis=0) - 1  # one empty layer on each side: neighbour keys never wrap
    dims = v.max(axis=0) + 2
    strides = np.array([dims[1] * dims[2], dims[2], 1], dtype=np.int64)
    key = v @ strides
    uniq, inv = np.unique(key, return_inverse=True)
    rows, cols = [], []
    for off in _HALF_NEIGHBOURS @ strides:
        nk = uniq + off
        pos = np.searchsorted(uniq, nk)
        pos[pos >= uniq.size] = 0
        hit = uniq[pos] == nk
        rows.append(np.nonzero(hit)[0])
        cols.append(pos[hit])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    graph = coo_matrix((np.ones(r.size, dtype=np.int8), (r, c)), shape=(uniq.size, uniq.size))
    k, comp = connected_components(graph, directed=False)
    return comp[inv.reshape(-1)].astype(np.int64), int(k)


class BoardSegment(NamedTuple):
    """A board candidate: ``indices`` (M,) into the points given to :func:`board_candidates`,
    ``plane`` (normal toward the sensor; ``inliers`` over ``indices``), ``extents_m`` (2,)
    the plate's measured (short, long) side lengths, ``partial`` True when only part of the
    plate is seen (it is smaller than the board but could hold the holes)."""

    indices: np.ndarray
    plane: PlaneFit
    extents_m: np.ndarray
    partial: bool


def _in_plane_extents(q: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Sorted (short, long) extents of planar points along their principal in-plane axes,
    trimmed to the 0.5..99.5 percentiles (a stand or a stray point does not count)."""
    uv = (q - q.mean(axis=0)) @ plane_basis(normal).T
    _, _, vt = np.linalg.svd(uv - uv.mean(axis=0), full_matrices=False)
    ab = uv @ vt.T
    lo, hi = np.percentile(ab, [0.5, 99.5], axis=0)
    return np.sort(hi - lo)


def board_candidates(
    points: np.ndarray,
    board: BoardGeometry,
    rng: np.random.Generator,
    *,
    cell_m: float,
    min_points: int,
    plane_threshold_m: float,
    plane_iterations: int,
    size_tolerance_m: float,
    check_size: bool = True,
    allow_partial: bool = True,
    max_candidates: int = 30,
    max_splits: int = 4,
) -> list[BoardSegment]:
    """Board candidates among (N, 3) points (ground already removed), best first.

    Euclidean clusters whose RANSAC plane holds ``min_points``: a plane measuring the plate's
    width x height within ``size_tolerance_m`` is a full match (ranked by size error); with
    ``allow_partial`` a plane no larger than the plate, at least its width along its long side
    and 0.4 m along its short side is a partial view (ranked after the full matches). Without
    ``check_size`` every plane is a candidate, most inliers first.

    When no cluster is a full match, up to ``max_splits`` clusters too large for the board (a
    board close to a wall merges with it) are split: their dominant plane's inliers and the
    rest are clustered again and the parts considered. Raises StepFailed('no_board_plane')
    with what was seen when there is no candidate.
    """
    p = np.asarray(points, float)
    if p.shape[0] < min_points:
        raise StepFailed(
            "no_board_plane", f"{p.shape[0]} points left for the board, need {min_points}"
        )
    nominal = np.sort([board.width_m, board.height_m])
    max_span = float(np.hypot(*nominal)) + 2 * size_tolerance_m + 0.5
    seen: list[str] = []
    scored: list[tuple[float, int, BoardSegment]] = []

    def clusters_of(idx: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], int]:
        """(fitting, oversized) clusters of p[idx] with >= min_points, largest first."""
        labels, k = euclidean_clusters(p[idx], cell_m)
        counts = np.bincount(labels, minlength=k)
        order = np.argsort(labels, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        fitting, oversized = [], []
        for lab in np.nonzero(counts >= min_points)[0]:
            members = idx[order[starts[lab] : starts[lab] + counts[lab]]]
            span = float(np.linalg.norm(np.ptp(p[members], axis=0)))
            if check_size and span > max_span:
                seen.append(f"{counts[lab]} pts spanning {span:.1f} m")
                oversized.append(members)
            else:
                fitting.append(members)
        fitting.sort(key=lambda i: -i.size)
        return fitting, oversized, k

    def consider(idx: np.ndarray) -> None:
        try:
            fit = ransac_plane(
                p[idx], plane_threshold_m, rng, plane_iterations, min_inliers=min_points
            )
        except GeometryError as exc:
            seen.append(f"{idx.size} pts, no plane ({exc})")
            return
        ext = _in_plane_extents(p[idx][fit.inliers], fit.normal)
        err = np.abs(ext - nominal)
        seen.append(f"{idx.size} pts, plane {ext[0]:.2f} x {ext[1]:.2f} m")
        partial = False
        if not check_size:
            score = -float(fit.inliers.sum())
        elif np.max(err) <= size_tolerance_m:
            score = float(np.sum(err))
        elif (
            allow_partial
            and np.all(ext <= nominal + size_tolerance_m)
            and ext[1] >= nominal[0] - size_tolerance_m
            and ext[0] >= 0.4
        ):
            score, partial = 100.0 + float(np.sum(err)), True
        else:
            return
        scored.append((score, len(scored), BoardSegment(idx, fit, ext, partial)))

    fitting, oversized, k = clusters_of(np.arange(p.shape[0]))
    n_large = len(fitting) + len(oversized)
    for idx in fitting[:max_candidates]:
        consider(idx)
    if check_size and not any(not seg.partial for _, _, seg in scored) and oversized:
        # nearest first: a board close to a wall is usually nearer than the rest of the scene
        oversized.sort(key=lambda i: float(np.linalg.norm(np.median(p[i], axis=0))))
        for idx in oversized[:max_splits]:
            try:
                fit = ransac_plane(p[idx], plane_threshold_m, rng, plane_iterations)
            except GeometryError:
                continue
            for part in (idx[fit.inliers], idx[~fit.inliers]):
                if part.size >= min_points:
                    for sub in clusters_of(part)[0][:max_candidates]:
                        consider(sub)
    if not scored:
        shown = "; ".join(seen[:6]) + (" ..." if len(seen) > 6 else "")
        raise StepFailed(
            "no_board_plane",
            f"no cluster of >= {min_points} points is a {nominal[0]:.2f} x {nominal[1]:.2f} m "
            f"plane (+-{size_tolerance_m} m) among {k} clusters ({n_large} large enough): "
            f"{shown or 'none'}",
        )
    scored.sort(key=lambda t: (t[0], t[1]))
    return [t[2] for t in scored]


def segment_board(
    points: np.ndarray,
    indices: np.ndarray,
    board: BoardGeometry,
    up: np.ndarray,
    rng: np.random.Generator,
    cfg: BoardDetectorConfig,
    min_points: int | None = None,
) -> tuple[np.ndarray, list[BoardSegment]]:
    """Step 2 of both point-cloud detectors: ``points`` (the cloud's rows ``indices``) without
    the ground (when ``cfg.remove_ground``), then the board candidates among the rest
    (:func:`board_candidates`, at least ``min_points`` each, default ``cfg.min_board_points``).
    Returns the indices that are left and the candidates over them; StepFailed if none."""
    if cfg.remove_ground:
        above, _ = remove_ground(
            points, up, rng, threshold_m=cfg.ground_threshold_m,
            max_angle_deg=cfg.ground_max_angle_deg, iterations=cfg.ground_iterations,
        )
        indices, points = indices[above], points[above]
    candidates = board_candidates(
        points, board, rng, cell_m=cfg.cluster_cell_m,
        min_points=cfg.min_board_points if min_points is None else min_points,
        plane_threshold_m=cfg.plane_threshold_m, plane_iterations=cfg.plane_iterations,
        size_tolerance_m=cfg.size_tolerance_m, check_size=cfg.check_board_size,
        allow_partial=cfg.allow_partial_board,
    )
    return indices, candidates


def rings_from_elevation(points: np.ndarray, gap_deg: float) -> np.ndarray:
    """(N,) ring labels of lidar points from their elevation angles: sorted elevations split
    wherever consecutive values differ by more than ``gap_deg``."""
    p = np.asarray(points, float)
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    order = np.argsort(el, kind="stable")
    lab = np.zeros(p.shape[0], dtype=np.int64)
    lab[order] = np.concatenate([[0], np.cumsum(np.diff(el[order]) > gap_deg)])
    return lab


def board_frame(
    normal: np.ndarray, d: float, up: np.ndarray, plate_points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Board-plane frame from a plane (``normal . p + d = 0``) in a sensor frame.

    Returns ``normal`` flipped toward the sensor (the origin), ``origin`` (3,) the plate
    points' centroid projected onto the plane, and ``basis`` (2, 3): x right and y up as seen
    from the sensor (y = ``up`` projected into the plane). Raises StepFailed('no_board_plane')
    when the plane is (nearly) perpendicular to ``up``.
    """
    n = np.asarray(normal, float)
    if d < 0:
        n, d = -n, -d
    try:
        basis = plane_basis(n, up)
    except GeometryError:
        tilt = math.degrees(math.acos(min(1.0, abs(float(n @ up)))))
        raise StepFailed(
            "no_board_plane", f"board plane is {tilt:.1f} deg from horizontal; 'up' is undefined"
        ) from None
    c = np.asarray(plate_points, float).mean(axis=0)
    origin = c - (c @ n + d) * n
    return n, origin, basis


def rays_to_plane(points: np.ndarray, normal: np.ndarray, d: float) -> np.ndarray:
    """Points moved along their sensor ray (from the origin) onto the plane: removes range
    noise, keeps the bearing. Rays parallel to the plane give NaN."""
    p = np.asarray(points, float)
    den = p @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -d / den
    out = p * t[:, None]
    out[~(np.abs(den) > 1e-12) | ~(t > 0)] = np.nan
    return out


# ----------------------------------------------------------------------------- the four holes


class HoleParams(NamedTuple):
    """What :func:`find_hole_square` needs (built by each detector from its config)."""

    spacing_m: float
    radius_m: float
    min_radius_m: float
    max_radius_m: float
    gate_m: float
    min_edge_points: int
    square_tolerance_m: float
    refine_square: bool
    vote_cell_m: float = 0.01
    vote_angle_step_deg: float = 6.0
    radius_weight: float = 4.0
    max_vote_points: int = 600

    @classmethod
    def from_config(cls, board: BoardGeometry, cfg) -> "HoleParams":
        return cls(
            spacing_m=board.spacing_m,
            radius_m=board.hole_diameter_m / 2,
            min_radius_m=cfg.min_radius_m,
            max_radius_m=cfg.max_radius_m,
            gate_m=cfg.circle_threshold_m,
            min_edge_points=cfg.min_edge_points,
            square_tolerance_m=cfg.square_tolerance_m,
            refine_square=cfg.refine_square,
            vote_cell_m=cfg.vote_cell_m,
            vote_angle_step_deg=cfg.vote_angle_step_deg,
        )


class HoleSquare(NamedTuple):
    """The four holes in the board plane (2D, x right, y up): ``centres_uv`` (4, 2) the
    returned centres TL, TR, BL, BR; ``square`` the rigid-square fit; ``individual_uv`` (4, 2)
    per-hole circle centres (NaN where a hole's edges do not determine it);
    ``square_error_m`` the largest side/diagonal deviation of the individual centres (NaN if
    fewer than two); ``diag_side_ratio`` (NaN unless all four individual centres exist)."""

    centres_uv: np.ndarray
    square: SquareCirclesFit
    individual_uv: np.ndarray
    square_error_m: float
    diag_side_ratio: float
    edges_used: int


def _vote_square(edges: np.ndarray, hp: HoleParams) -> tuple[np.ndarray, float, float]:
    """Hough vote for the square template's centre and rotation. Returns the best (centre (2,),
    angle, peak votes).

    Separable in two steps: every edge point votes on the circle of hole centres it could
    belong to (one grid, the same for every rotation); then, for each rotation, a square
    centre gets the hole-centre votes at its four holes (the template's offsets rounded to
    whole cells, so each rotation is four shifted sums of that grid, not a vote per point)."""
    cell = hp.vote_cell_m
    step = math.radians(hp.vote_angle_step_deg)
    thetas = np.arange(-math.pi / 4, math.pi / 4 - 1e-9, step)
    n_phi = max(16, int(math.ceil(2 * math.pi * hp.radius_m / cell)))
    phis = np.linspace(0, 2 * math.pi, n_phi, endpoint=False)
    ring = hp.radius_m * np.column_stack([np.cos(phis), np.sin(phis)])
    tmpl = square_template_2d(hp.spacing_m)
    c, s = np.cos(thetas), np.sin(thetas)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (T, 2, 2)
    offs = np.einsum("tij,kj->tki", rot, tmpl)  # (T, 4, 2): hole k of rotation t - centre
    margin = hp.spacing_m * math.sqrt(0.5) + hp.radius_m + 3 * cell
    lo = edges.min(axis=0) - margin
    size = np.ceil((edges.max(axis=0) + margin - lo) / cell).astype(np.int64) + 1
    # hole-centre votes: at most radius + 1 cell from the edges, well inside the margin
    ij = np.floor((edges[:, None, :] - ring[None] - lo) / cell).astype(np.int64)
    holes = np.bincount((ij[..., 0] * size[1] + ij[..., 1]).reshape(-1),
                        minlength=int(size[0] * size[1])).reshape(size[0], size[1])
    # square centre (i, j) of rotation t: sum over k of holes[(i, j) + shift[t, k]], zero
    # outside the grid (padded by the largest shift)
    shift = np.rint(offs / cell).astype(np.int64)
    pad = int(np.abs(shift).max())
    padded = np.zeros((size[0] + 2 * pad, size[1] + 2 * pad))
    padded[pad:-pad or None, pad:-pad or None] = holes
    acc = np.zeros((len(thetas), size[0], size[1]))
    for t in range(len(thetas)):
        for di, dj in shift[t]:
            acc[t] += padded[pad + di : pad + di + size[0], pad + dj : pad + dj + size[1]]
    # 3x3 box smoothing in x, y (tolerates the radius and quantisation errors)
    sm = acc.copy()
    sm[:, 1:, :] += acc[:, :-1, :]
    sm[:, :-1, :] += acc[:, 1:, :]
    sm2 = sm.copy()
    sm2[:, :, 1:] += sm[:, :, :-1]
    sm2[:, :, :-1] += sm[:, :, 1:]
    t, i, j = np.unravel_index(int(np.argmax(sm2)), sm2.shape)
    centre = lo + (np.array([i, j]) + 0.5) * cell
    return centre, float(thetas[t]), float(sm2[t, i, j])


def _pair_errors(centres: np.ndarray, spacing: float) -> np.ndarray:
    """Deviations of the pairwise distances of (4, 2) centres (NaN rows skipped) from the
    square's sides and diagonals."""
    r2 = math.sqrt(2)
    pairs = [(0, 1, 1.0), (2, 3, 1.0), (0, 2, 1.0), (1, 3, 1.0), (0, 3, r2), (1, 2, r2)]
    errs = []
    for i, j, f in pairs:
        if np.all(np.isfinite(centres[[i, j]])):
            errs.append(abs(float(np.linalg.norm(centres[i] - centres[j])) - f * spacing))
    return np.array(errs)


def find_hole_square(edges_uv: np.ndarray, hp: HoleParams) -> HoleSquare:
    """The four holes from (M, 2) hole-edge points in the board plane.

    1. a Hough vote over the square's centre and rotation (template of known side and radius);
    2. :func:`~rigcal.geometry.fitting.fit_square_circles_2d` from the vote's peak;
    3. each hole's own circle fit (points nearest to it, radius pulled toward the square's);
       a hole counts only if its points surround its centre (largest angular gap < 180 deg);
    4. the square check: individual centres' sides and diagonals within ``square_tolerance_m``.

    Raises StepFailed with 'too_few_edge_points', 'circles_not_found' or 'not_square'.
    """
    e = np.asarray(edges_uv, float)
    e = e[np.isfinite(e).all(axis=1)]
    if e.shape[0] < hp.min_edge_points:
        raise StepFailed(
            "too_few_edge_points", f"{e.shape[0]} hole-edge points, need {hp.min_edge_points}"
        )
    vote_pts = e[:: max(1, int(math.ceil(e.shape[0] / hp.max_vote_points)))]
    centre0, angle0, peak = _vote_square(vote_pts, hp)
    try:
        sq = fit_square_circles_2d(
            e, hp.spacing_m, centre0, angle0, hp.radius_m, gate=hp.gate_m,
            radius_weight=hp.radius_weight,
        )
    except GeometryError as exc:
        raise StepFailed("circles_not_found", f"square-of-circles fit failed: {exc}") from None
    per_hole = np.bincount(sq.labels[sq.labels >= 0], minlength=4)
    used = int(per_hole.sum())
    if np.sum(per_hole >= 2) < 3 or used < hp.min_edge_points:
        raise StepFailed(
            "circles_not_found",
            f"the best square of holes explains {used} of {e.shape[0]} edge points "
            f"(per hole {per_hole.tolist()}); need >= {hp.min_edge_points} on >= 3 holes",
        )
    if not hp.min_radius_m <= sq.radius <= hp.max_radius_m:
        raise StepFailed(
            "circles_not_found",
            f"fitted hole radius {sq.radius:.3f} m outside "
            f"[{hp.min_radius_m}, {hp.max_radius_m}] m",
        )
    # per-hole fits: each edge point goes to its nearest centre if close enough
    dist = np.linalg.norm(e[:, None, :] - sq.centres[None], axis=2)
    near = np.argmin(dist, axis=1)
    near_ok = dist[np.arange(e.shape[0]), near] < hp.max_radius_m + 2 * hp.gate_m
    indiv = np.full((4, 2), np.nan)
    for k in range(4):
        q = e[near_ok & (near == k)]
        if q.shape[0] < 3:
            continue
        best = None
        starts = [sq.centres[k]]
        try:
            fit0 = fit_circle_2d(q)
            if hp.min_radius_m / 2 < fit0.radius < 2 * hp.max_radius_m:
                starts.append(fit0.centre)
        except GeometryError:
            pass
        for c0 in starts:
            try:
                fit = fit_circle_2d(
                    q, centre0=c0, radius_prior=sq.radius, radius_weight=hp.radius_weight
                )
            except GeometryError:
                continue
            if best is None or fit.rms < best.rms:
                best = fit
        if best is None or not hp.min_radius_m <= best.radius <= hp.max_radius_m:
            continue
        inl = q[np.abs(np.linalg.norm(q - best.centre, axis=1) - best.radius) < hp.gate_m]
        if inl.shape[0] >= 3 and circle_angular_gap(inl, best.centre) < math.pi:
            indiv[k] = best.centre
    errs = _pair_errors(indiv, hp.spacing_m)
    square_err = float(errs.max()) if errs.size else float("nan")
    ratio = float("nan")
    if np.all(np.isfinite(indiv)):
        sides = [np.linalg.norm(indiv[i] - indiv[j]) for i, j in ((0, 1), (2, 3), (0, 2), (1, 3))]
        diags = [np.linalg.norm(indiv[0] - indiv[3]), np.linalg.norm(indiv[1] - indiv[2])]
        ratio = float(np.mean(diags) / np.mean(sides))
    if errs.size and square_err > hp.square_tolerance_m:
        raise StepFailed(
            "not_square",
            f"hole centres deviate {square_err * 100:.1f} cm from a {hp.spacing_m} m square "
            f"(tolerance {hp.square_tolerance_m * 100:.1f} cm; diagonal/side {ratio:.3f}, "
            f"expected {math.sqrt(2):.3f})",
        )
    if hp.refine_square:
        centres = sq.centres
    else:
        if not np.all(np.isfinite(indiv)):
            names = ("TL", "TR", "BL", "BR")
            missing = [n for n, ok in zip(names, np.isfinite(indiv[:, 0])) if not ok]
            raise StepFailed(
                "circles_not_found",
                f"hole(s) {', '.join(missing)} not determined by their own edge points "
                f"(refine_square is off)",
            )
        centres = indiv
    return HoleSquare(centres, sq, indiv, square_err, ratio, used)
