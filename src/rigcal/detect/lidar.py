"""Circle-board detector for spinning lidars (ring scans), after Domhof et al. 2021, III-B.

Steps (sensor frame: x forward, y left, z up):

1. keep finite points within ``[min_range_m, max_range_m]`` and the optional ROI box;
2. remove the ground (RANSAC plane within ``ground_max_angle_deg`` of ``up_axis``, below the
   sensor), cluster the rest on a voxel grid and rank the clusters whose plane measures the
   board's width x height, or could be a partial view of it
   (:func:`rigcal.detect.pointcloud.board_candidates`); steps 3-4 run on the best candidates in
   turn (at most ``max_board_candidates``) until one holds the four holes;
3. hole edges from range discontinuities along each ring (``ring`` field, or rings recovered
   by elevation binning): inside the plate, consecutive plate points whose in-between returns
   all lie behind the plate (or are missing) bracket a hole. The edge is put on the ray half-way
   in azimuth between the last plate return and the first return through the hole, intersected
   with the board plane (unbiased to +-half an azimuth step, free of range noise). The plate's
   outer boundary never brackets a gap, so it is not mistaken for a hole;
4. the four holes in the board plane (:func:`rigcal.detect.pointcloud.find_hole_square`), the
   square check, and the centres ordered TL, TR, BL, BR as seen from the sensor: "up" is
   ``up_axis`` projected into the board plane, "left/right" as seen looking from the sensor
   toward the board. The square's in-plane rotation is taken in [-45, 45) deg, so a board
   rolled by about 45 deg in its own plane has no well-defined "top-left".

Failure reasons: ``no_points_in_roi``, ``no_board_plane``, ``too_few_edge_points``,
``circles_not_found``, ``not_square``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.detect.pointcloud import (
    BoardDetectorConfig,
    HoleParams,
    StepFailed,
    board_frame,
    box_mask,
    check_axis,
    check_box,
    find_hole_square,
    rings_from_elevation,
    segment_board,
)
from rigcal.detect.result import BoardDetection, DetectionFailure, DetectionResult
from rigcal.geometry.fitting import from_plane_2d, intersect_rays_plane, to_plane_2d
from rigcal.recording import PointCloudFrame

__all__ = ["LidarDetectorConfig", "detect_board_lidar"]


@dataclass(frozen=True)
class LidarDetectorConfig(BoardDetectorConfig):
    """Settings of :func:`detect_board_lidar` (defaults suit a 16-128 ring lidar, board 2-10 m).

    ``roi_min_xyz`` / ``roi_max_xyz``: optional box [m] in the sensor frame (both or neither);
    without it the board is found automatically. ``up_axis``: the sensor-frame direction that
    is "up" (ground normal hint and the order of the holes). ``cluster_cell_m``: voxel edge of the
    Euclidean clustering (must exceed the ring spacing on the board / 2). ``size_tolerance_m``:
    allowed deviation of the plate's measured sides from ``board.width_m`` x ``height_m``;
    ``allow_partial_board`` also accepts a plane smaller than the plate (cut by the field of
    view); ``max_board_candidates`` candidates are searched for holes, best first.
    ``jump_m``: depth discontinuity that separates the plate from what lies behind a hole.
    ``ring_gap_deg``: elevation gap that separates rings when the cloud has no ``ring`` field.
    ``min_radius_m`` / ``max_radius_m``: accepted hole radius. ``circle_threshold_m``: edge
    point to circle distance for inliers. ``refine_square``: return the centres of the rigid
    square fitted to all holes' edges (else each hole's own circle). ``square_tolerance_m``:
    allowed deviation of the per-hole centres' sides and diagonals from the square.
    ``seed`` seeds every RANSAC (detections are deterministic).
    """

    WHERE: ClassVar[str] = "lidar detector"
    EXTRA_POSITIVE: ClassVar[tuple[str, ...]] = ("ring_gap_deg",)

    ring_gap_deg: float = 0.12


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _ring_edges(
    points: np.ndarray,
    usable: np.ndarray,
    rings: np.ndarray | None,
    plate: np.ndarray,
    normal: np.ndarray,
    d: float,
    cfg: LidarDetectorConfig,
) -> tuple[np.ndarray, dict]:
    """Hole-edge points (K, 3) on the board plane from ring discontinuities.

    ``usable`` (N,) finite points in range; ``plate`` (N,) the board's plate points.
    """
    xy = points[:, :2]
    pp = points[plate]
    if pp.shape[0] < 2:
        return np.zeros((0, 3)), {"rings_on_board": 0}
    az0 = math.atan2(float(pp[:, 1].sum()), float(pp[:, 0].sum()))
    rel_plate = _wrap(np.arctan2(pp[:, 1], pp[:, 0]) - az0)
    margin = math.radians(2.0)
    lo, hi = rel_plate.min() - margin, rel_plate.max() + margin
    cand = np.nonzero(usable)[0]
    rel = _wrap(np.arctan2(xy[cand, 1], xy[cand, 0]) - az0)
    inside = (rel >= lo) & (rel <= hi)
    sec = cand[inside]
    rel = rel[inside]
    if rings is None:
        ring = rings_from_elevation(points[sec], cfg.ring_gap_deg)
    else:
        ring = rings[sec]
    is_plate = plate[sec]
    plate_rings = np.unique(ring[is_plate])
    keep = np.isin(ring, plate_rings)
    sec, rel, ring, is_plate = sec[keep], rel[keep], ring[keep], is_plate[keep]
    order = np.lexsort((rel, ring))
    sec, rel, ring, is_plate = sec[order], rel[order], ring[order], is_plate[order]
    s = points[sec] @ normal + d  # > 0: toward the sensor
    blocker = ~is_plate & ~(s < -cfg.jump_m)  # neither plate nor behind it
    pos = np.nonzero(is_plate)[0]
    info = {"rings_on_board": int(plate_rings.size)}
    if pos.size < 2:
        return np.zeros((0, 3)), info
    a, b = pos[:-1], pos[1:]
    same = ring[a] == ring[b]
    dz = rel[b] - rel[a]
    adjacent = same & (b == a + 1)
    if not np.any(adjacent):
        return np.zeros((0, 3)), info
    step = float(np.median(dz[adjacent]))
    info["azimuth_step_deg"] = math.degrees(step)
    gap = same & ((b > a + 1) | (dz > 1.5 * step))
    nb = np.concatenate([[0], np.cumsum(blocker)])
    clear = nb[b] - nb[a + 1] == 0  # no blocker strictly between a and b
    gap &= clear
    a, b = a[gap], b[gap]
    if a.size == 0:
        return np.zeros((0, 3)), info
    nxt = np.minimum(a + 1, rel.size - 1)
    prv = np.maximum(b - 1, 0)
    left_pair = (b > a + 1) & (rel[nxt] - rel[a] < 1.5 * step)
    right_pair = (b > a + 1) & (rel[b] - rel[prv] < 1.5 * step)
    az_l = np.where(left_pair, 0.5 * (rel[a] + rel[nxt]), rel[a] + 0.5 * step) + az0
    az_r = np.where(right_pair, 0.5 * (rel[b] + rel[prv]), rel[b] - 0.5 * step) + az0
    pa, pb = points[sec[a]], points[sec[b]]
    el_a = np.arctan2(pa[:, 2], np.hypot(pa[:, 0], pa[:, 1]))
    el_b = np.arctan2(pb[:, 2], np.hypot(pb[:, 0], pb[:, 1]))

    def rays(az, el):
        return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])

    left = intersect_rays_plane(rays(az_l, el_a), normal, d)
    right = intersect_rays_plane(rays(az_r, el_b), normal, d)
    rng_m = np.linalg.norm(pa, axis=1)
    width = np.linalg.norm(left - right, axis=1)
    ok = np.isfinite(width) & (width <= 2 * cfg.max_radius_m + 3 * step * rng_m)
    info["gaps"] = int(a.size)
    info["hole_gaps"] = int(ok.sum())
    return np.concatenate([left[ok], right[ok]]), info


def detect_board_lidar(
    frame: PointCloudFrame,
    board: BoardGeometry = BoardGeometry(),
    config: LidarDetectorConfig = LidarDetectorConfig(),
) -> DetectionResult:
    """The four hole centres (4, 3) [m] in the lidar frame, TL, TR, BL, BR as seen from the
    sensor, or a :class:`DetectionFailure` with its reason (see the module docstring).

    ``quality``: ``plane_rms_m``, ``circle_rms_m``, ``radius_m``, ``square_error_m``,
    ``diag_side_ratio``, ``edge_points``, ``edge_points_used``, ``board_points``,
    ``partial_board`` (1.0 when only part of the plate was seen), ``range_m``, ``rings_on_board``.
    """
    cfg = config

    def fail(reason: str, detail: str) -> DetectionFailure:
        return DetectionFailure(frame.sensor, frame.t_ns, reason, detail)

    pts = frame.points_xyz
    n_all = pts.shape[0]
    lo, hi = check_box(cfg.roi_min_xyz, cfg.roi_max_xyz, "lidar detector")
    up = check_axis(cfg.up_axis, "up_axis", "lidar detector")
    finite = np.isfinite(pts).all(axis=1)
    with np.errstate(invalid="ignore"):
        r = np.linalg.norm(np.where(finite[:, None], pts, 0.0), axis=1)
    usable = finite & (r >= cfg.min_range_m) & (r <= cfg.max_range_m)
    roi = usable & box_mask(pts, lo, hi) if lo is not None else usable
    idx = np.nonzero(roi)[0]
    if idx.size < cfg.min_board_points:
        return fail(
            "no_points_in_roi",
            f"{idx.size} of {n_all} points are finite, within {cfg.min_range_m}-{cfg.max_range_m} m"
            + (" and in the ROI" if lo is not None else "") + f"; need {cfg.min_board_points}",
        )
    rng = np.random.default_rng(cfg.seed)
    rings = None
    if "ring" in frame.fields:
        rings = np.asarray(frame.fields["ring"]).astype(np.int64)
    hp = HoleParams.from_config(board, cfg)
    try:
        idx, cands = segment_board(pts[idx], idx, board, up, rng, cfg)
    except StepFailed as exc:
        return fail(exc.reason, exc.detail)
    failures: list[StepFailed] = []
    for seg in cands[: cfg.max_board_candidates]:
        try:
            cluster = idx[seg.indices]
            return _detect_on_candidate(frame, pts, usable, cluster, seg, rings, up, hp, cfg)
        except StepFailed as exc:
            failures.append(exc)
    return fail(failures[0].reason, failures[0].detail)  # the best candidate's reason


def _detect_on_candidate(frame, pts, usable, cluster, seg, rings, up, hp, cfg) -> BoardDetection:
    normal, d = seg.plane.normal, seg.plane.d
    s = pts[cluster] @ normal + d
    plate_idx = cluster[np.abs(s) < cfg.jump_m]
    normal, origin, basis = board_frame(normal, d, up, pts[cluster[seg.plane.inliers]])
    plate = np.zeros(pts.shape[0], dtype=bool)
    plate[plate_idx] = True
    edges, info = _ring_edges(pts, usable, rings, plate, normal, d, cfg)
    holes = find_hole_square(to_plane_2d(edges, origin, basis), hp)
    centres = from_plane_2d(holes.centres_uv, origin, basis)
    quality = {
        "plane_rms_m": seg.plane.rms,
        "circle_rms_m": holes.square.rms,
        "radius_m": holes.square.radius,
        "square_error_m": holes.square_error_m,
        "diag_side_ratio": holes.diag_side_ratio,
        "edge_points": float(edges.shape[0]),
        "edge_points_used": float(holes.edges_used),
        "board_points": float(plate_idx.size),
        "partial_board": float(seg.partial),
        "range_m": float(np.linalg.norm(centres.mean(axis=0))),
        "rings_on_board": float(info.get("rings_on_board", 0)),
    }
    return BoardDetection(frame.sensor, frame.t_ns, centres, quality)
