"""Circle-board detector for stereo point clouds (camera optical frame: z forward, x right,
y down), organised (from :func:`rigcal.sensors.stereo.point_cloud_from_pair`) or not.

Steps:

1. keep finite points within ``[min_range_m, max_range_m]`` and the optional ROI box;
   segmentation runs on at most ``max_segment_points`` of them (a regular image stride for an
   organised cloud, a seeded random subset otherwise);
2. remove the ground (near-horizontal plane below the camera, ``up_axis`` = -y), cluster, rank
   the clusters whose RANSAC plane has the board's size (or could be a partial view of it), as
   the lidar detector does; the plane is then refined by least squares on all the plate's points;
3. hole boundaries. Stereo depth is noisy along the viewing ray but the bearing is precise, so
   everything is moved along its ray onto the board plane and fitted in-plane:

   * organised cloud: the plate is the image region whose points lie within ``jump_m`` of the
     plane; holes are the regions it encloses (points behind the plate or missing: the
     left-right check of SGBM leaves half-occluded pixels empty) whose area fits a hole. Edge
     samples sit half-way between a plate pixel and its 4-neighbour in a hole; their pixel rays
     (intrinsics recovered from the cloud itself) meet the plane;
   * unorganised cloud: the plate's points moved onto the plane, rasterised into an occupancy
     grid (cell ~1.5 x the point spacing unless ``grid_cell_m``); the holes are the empty
     regions the plate encloses and edge samples lie between occupied and empty cells;
4. the four holes, the square check and the order (TL, TR, BL, BR as seen from the camera) as
   for lidar (:func:`rigcal.detect.pointcloud.find_hole_square`).

Failure reasons: ``no_points_in_roi``, ``no_board_plane``, ``too_few_edge_points``,
``circles_not_found``, ``not_square``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.detect.pointcloud import (
    BoardDetectorConfig,
    BoardSegment,
    HoleParams,
    StepFailed,
    board_frame,
    box_mask,
    check_axis,
    check_box,
    check_positive,
    find_hole_square,
    rays_to_plane,
    segment_board,
)
from rigcal.detect.result import BoardDetection, DetectionFailure, DetectionResult
from rigcal.errors import ConfigError
from rigcal.geometry.fitting import (
    PlaneFit,
    from_plane_2d,
    intersect_rays_plane,
    plane_basis,
    to_plane_2d,
)
from rigcal.recording import PointCloudFrame, StereoFrame

__all__ = ["StereoDetectorConfig", "detect_board_stereo", "detect_board_stereo_pair"]


@dataclass(frozen=True)
class StereoDetectorConfig(BoardDetectorConfig):
    """Settings of :func:`detect_board_stereo` (defaults: 1-2 MP stereo, board at 2-8 m).

    Fields as in :class:`rigcal.detect.lidar.LidarDetectorConfig`, plus: ``max_segment_points``
    (points used for segmentation), ``jump_m`` (distance from the plate's plane beyond which a
    point is not plate: larger than for lidar because stereo depth is noisier),
    ``min_hole_area_fraction`` / ``max_hole_area_fraction`` (an enclosed region is a hole if its
    area is within these fractions of a hole's expected area) and ``grid_cell_m`` (occupancy
    cell for unorganised clouds; None: from the point density).
    """

    WHERE: ClassVar[str] = "stereo detector"
    EXTRA_POSITIVE: ClassVar[tuple[str, ...]] = (
        "max_segment_points", "min_hole_area_fraction", "max_hole_area_fraction")

    max_range_m: float = 12.0
    up_axis: tuple[float, float, float] = (0.0, -1.0, 0.0)
    ground_threshold_m: float = 0.15
    min_board_points: int = 200
    plane_threshold_m: float = 0.1
    plane_iterations: int = 250
    jump_m: float = 0.25
    min_radius_m: float = 0.045  # SGBM block matching fattens the plate: holes look smaller
    circle_threshold_m: float = 0.02
    min_edge_points: int = 12
    max_segment_points: int = 60000
    min_hole_area_fraction: float = 0.2
    max_hole_area_fraction: float = 3.0
    grid_cell_m: float | None = None

    def _check_extra(self) -> None:
        if self.grid_cell_m is not None:
            check_positive(self, ("grid_cell_m",), self.WHERE)
        if self.max_hole_area_fraction <= self.min_hole_area_fraction:
            raise ConfigError(f"{self.WHERE}: max_hole_area_fraction must exceed min_hole_area_fraction")


# ----------------------------------------------------------------------------- helpers


def _intrinsics_from_cloud(
    points_hw: np.ndarray, valid: np.ndarray, rng: np.random.Generator
) -> tuple[float, float, float, float] | None:
    """(fx, fy, cx, cy) of a pinhole organised cloud (``u = fx X/Z + cx``), or None if the
    cloud does not follow a pinhole model to 0.05 px."""
    v_idx, u_idx = np.nonzero(valid & (points_hw[..., 2] > 0))
    if v_idx.size < 100:
        return None
    if v_idx.size > 20000:
        pick = rng.integers(0, v_idx.size, 20000)
        v_idx, u_idx = v_idx[pick], u_idx[pick]
    p = points_hw[v_idx, u_idx]
    out = []
    for coord, k in ((u_idx, 0), (v_idx, 1)):
        A = np.column_stack([p[:, k] / p[:, 2], np.ones(p.shape[0])])
        sol, *_ = np.linalg.lstsq(A, coord.astype(float), rcond=None)
        res = A @ sol - coord
        if np.sqrt(np.mean(res * res)) > 0.05 or sol[0] <= 0:
            return None
        out.append(sol)
    return float(out[0][0]), float(out[1][0]), float(out[0][1]), float(out[1][1])


def _enclosed_regions(mask: np.ndarray) -> np.ndarray:
    """Labels (H, W) of the 4-connected regions of ``~mask`` enclosed by ``mask`` (else 0)."""
    import cv2

    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    sub = np.ones((y1 - y0 + 2, x1 - x0 + 2), np.uint8)
    sub[1:-1, 1:-1] = ~mask[y0:y1, x0:x1]
    _, lab = cv2.connectedComponents(sub, connectivity=4)
    outside = lab[0, 0]
    lab[lab == outside] = 0
    out = np.zeros(mask.shape, np.int32)
    out[y0:y1, x0:x1] = lab[1:-1, 1:-1]
    return out


def _boundary_samples(plate: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """(K, 2) (row, col) points half-way between a plate cell and a 4-neighbouring hole cell."""
    out = []
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        h, w = plate.shape
        a = plate[max(0, -dr) : h - max(0, dr), max(0, -dc) : w - max(0, dc)]
        b = hole[max(0, dr) : h - max(0, -dr), max(0, dc) : w - max(0, -dc)]
        r, c = np.nonzero(a & b)
        r = r + max(0, -dr)
        c = c + max(0, -dc)
        out.append(np.column_stack([r + dr / 2, c + dc / 2]))
    return np.concatenate(out).astype(float)


def _keep_holes(
    regions: np.ndarray, expected_area: float, cfg: StereoDetectorConfig
) -> tuple[np.ndarray, list[int]]:
    """Mask of the enclosed regions whose area fits a hole, and their areas."""
    areas = np.bincount(regions.reshape(-1))
    lo, hi = cfg.min_hole_area_fraction * expected_area, cfg.max_hole_area_fraction * expected_area
    keep = [k for k in range(1, areas.size) if lo <= areas[k] <= hi]
    is_hole = np.zeros(areas.size, bool)
    is_hole[keep] = True
    return is_hole[regions], [int(areas[k]) for k in keep]


def _refine_plane(
    points: np.ndarray, normal: np.ndarray, d: float, thr: float
) -> tuple[np.ndarray, float, float]:
    """Least-squares plane of the (finite) points within ``thr`` of the given one, and its rms
    distance (the given plane kept if they are too few or collinear). Computed here from the
    3x3 scatter of the centred points: the plate holds ~10^5 of them, and
    :func:`~rigcal.geometry.fitting.fit_plane_lstsq` would copy and check them again."""
    near = np.abs(points @ normal + d) < thr
    n = int(near.sum())
    if n < 3:
        return normal, d, float("nan")
    q = points[near]
    c = np.ones(n) @ q / n
    q -= c
    w, v = np.linalg.eigh(q.T @ q / n)  # ascending
    if not np.all(np.isfinite(w)) or w[1] <= 1e-12 * max(w[2], 1e-300):
        return normal, d, float("nan")
    nrm = v[:, 0] / np.linalg.norm(v[:, 0])
    off = -float(nrm @ c)
    if off < 0:
        nrm, off = -nrm, -off
    return nrm, off, float(np.sqrt(max(w[0], 0.0)))


# ----------------------------------------------------------------------------- detector


def detect_board_stereo(
    frame: PointCloudFrame,
    board: BoardGeometry = BoardGeometry(),
    config: StereoDetectorConfig = StereoDetectorConfig(),
) -> DetectionResult:
    """The four hole centres (4, 3) [m] in the camera optical frame, TL, TR, BL, BR as seen
    from the camera, or a :class:`DetectionFailure` with its reason (module docstring).

    ``quality``: ``plane_rms_m``, ``circle_rms_m``, ``radius_m``, ``square_error_m``,
    ``diag_side_ratio``, ``edge_points``, ``edge_points_used``, ``board_points``,
    ``organised`` (1.0 / 0.0), ``partial_board``, ``range_m``.
    """
    cfg = config

    def fail(reason: str, detail: str) -> DetectionFailure:
        return DetectionFailure(frame.sensor, frame.t_ns, reason, detail)

    seg = _segment(frame, board, cfg)
    if isinstance(seg, StepFailed):
        return fail(seg.reason, seg.detail)
    pts, usable, idx, cands, up, rng = seg
    hp = HoleParams.from_config(board, cfg)
    failures: list[StepFailed] = []
    for cand in cands[: cfg.max_board_candidates]:
        try:
            return _detect_on_candidate(frame, pts, usable, idx[cand.indices], cand, up, hp, cfg,
                                        rng)
        except StepFailed as exc:
            failures.append(exc)
    return fail(failures[0].reason, failures[0].detail)


def _usable(pts: np.ndarray, cfg: StereoDetectorConfig) -> tuple[np.ndarray, bool]:
    """(usable mask, whether an ROI box applies): finite points within the range limits and
    the ROI box."""
    lo, hi = check_box(cfg.roi_min_xyz, cfg.roi_max_xyz, "stereo detector")
    with np.errstate(invalid="ignore", over="ignore"):
        # a NaN coordinate makes r2 NaN, an infinite one makes it inf or NaN: both fail
        r2 = np.einsum("ij,ij->i", pts, pts)
        usable = (r2 >= cfg.min_range_m ** 2) & (r2 <= cfg.max_range_m ** 2)
    if lo is not None:
        usable &= box_mask(pts, lo, hi)
    return usable, lo is not None


def _segment(frame: PointCloudFrame, board: BoardGeometry, cfg: StereoDetectorConfig):
    """Steps 1-2 of the module docstring: (points, usable mask, indices of the segmented
    points, board candidates over them, up axis, rng), or the StepFailed that stops there."""
    pts = frame.points_xyz
    n_all = pts.shape[0]
    up = check_axis(cfg.up_axis, "up_axis", "stereo detector")
    usable, roi = _usable(pts, cfg)
    n_use = int(usable.sum())
    if n_use < cfg.min_board_points:
        return StepFailed(
            "no_points_in_roi",
            f"{n_use} of {n_all} points are finite, within {cfg.min_range_m}-{cfg.max_range_m} m"
            + (" and in the ROI" if roi else "") + f"; need {cfg.min_board_points}",
        )
    rng = np.random.default_rng(cfg.seed)
    organised = frame.organized_shape is not None
    if organised:
        h, w = frame.organized_shape
        stride = max(1, int(math.ceil(math.sqrt(n_use / cfg.max_segment_points))))
        grid = np.zeros((h, w), bool)
        grid[::stride, ::stride] = True
        idx = np.nonzero(usable & grid.reshape(-1))[0]
    else:
        idx = np.nonzero(usable)[0]
        if idx.size > cfg.max_segment_points:
            idx = np.sort(rng.choice(idx, cfg.max_segment_points, replace=False))
    min_seg = cfg.min_board_points
    if organised:  # the board's points were thinned by stride^2
        min_seg = max(10, int(cfg.min_board_points / (stride * stride)))
    try:
        idx, cands = segment_board(pts[idx], idx, board, up, rng, cfg, min_seg)
    except StepFailed as exc:
        return exc
    return pts, usable, idx, cands, up, rng


def _detect_on_candidate(
    frame, pts, usable, cluster, seg: BoardSegment, up, hp, cfg, rng, intr=None, prefit=False
) -> BoardDetection:
    """Steps 3-4 on one candidate; ``intr`` (fx, fy, cx, cy) of an organised cloud when known
    (else recovered from the cloud); ``prefit``: the candidate's plane is coarse, refit it
    before taking the plate (organised clouds)."""
    normal, d = seg.plane.normal, seg.plane.d
    seed_idx = cluster[seg.plane.inliers]
    organised = frame.organized_shape is not None
    if organised:
        h, w = frame.organized_shape
        P = pts.reshape(h, w, 3)
        if intr is None:
            intr = _intrinsics_from_cloud(P, usable.reshape(h, w), rng)
    else:
        intr = None
    if intr is not None:
        edges3d, plate_idx, info = _organised_edges(
            P, usable.reshape(h, w), seed_idx, normal, d, intr, hp, cfg, prefit
        )
        normal, d = info.pop("plane")
    else:
        edges3d, plate_idx, info = _unorganised_edges(pts, usable, seed_idx, normal, d, hp, cfg)
        normal, d = info.pop("plane")
    # the frame's origin (the plate's centroid on the plane) only shifts the in-plane
    # coordinates: a regular subset of the plate's points is as good
    sub = plate_idx[:: max(1, plate_idx.size // 20000)]
    normal, origin, basis = board_frame(normal, d, up, rays_to_plane(pts[sub], normal, d))
    holes = find_hole_square(to_plane_2d(edges3d, origin, basis), hp)
    centres = from_plane_2d(holes.centres_uv, origin, basis)
    quality = {
        "plane_rms_m": info["plane_rms_m"],
        "circle_rms_m": holes.square.rms,
        "radius_m": holes.square.radius,
        "square_error_m": holes.square_error_m,
        "diag_side_ratio": holes.diag_side_ratio,
        "edge_points": float(edges3d.shape[0]),
        "edge_points_used": float(holes.edges_used),
        "board_points": float(plate_idx.size),
        "organised": float(intr is not None),
        "partial_board": float(seg.partial),
        "range_m": float(np.linalg.norm(centres.mean(axis=0))),
    }
    return BoardDetection(frame.sensor, frame.t_ns, centres, quality)


def _plate_region(P, valid, seed_rc, normal, d, cfg) -> np.ndarray:
    """(H, W) bool: the 8-connected region of valid pixels within ``jump_m`` of the plane that
    holds most of the seed pixels ``seed_rc`` (rows, cols)."""
    import cv2

    with np.errstate(invalid="ignore"):
        s = P @ normal + d
    plate_px = valid & (np.abs(s) < cfg.jump_m)
    _, lab = cv2.connectedComponents(plate_px.astype(np.uint8), connectivity=8)
    seed_lab = lab[seed_rc]
    seed_lab = seed_lab[seed_lab > 0]
    if seed_lab.size == 0:
        raise StepFailed("no_board_plane", "the board plane's points form no image region")
    return lab == int(np.argmax(np.bincount(seed_lab)))


def _organised_edges(P, valid, seed_idx, normal, d, intr, hp: HoleParams, cfg, prefit=False):
    h, w = valid.shape
    fx, fy, cx, cy = intr
    seed_rc = np.divmod(seed_idx, w)
    if prefit:
        # the seed plane may be coarse (tilted: part of the plate outside jump_m of it): refit
        # it on the plate of every other row and column first, then take the plate again
        sub = _plate_region(P[::2, ::2], valid[::2, ::2], (seed_rc[0] // 2, seed_rc[1] // 2),
                            normal, d, cfg)
        normal, d, _ = _refine_plane(P[::2, ::2][sub], normal, d, cfg.jump_m)
        normal, d, _ = _refine_plane(P[::2, ::2][sub], normal, d, cfg.plane_threshold_m)
    plate = _plate_region(P, valid, seed_rc, normal, d, cfg)
    flat = plate.reshape(-1)
    plate_pts = P.reshape(-1, 3)[flat]
    normal, d, rms = _refine_plane(plate_pts, normal, d, cfg.plane_threshold_m)
    if d < 0:
        normal, d = -normal, -d
    plate_idx = np.nonzero(flat)[0]
    # expected hole area [px]: at the plate's median depth, foreshortened
    centre = np.median(plate_pts[:: max(1, plate_pts.shape[0] // 20000)], axis=0)
    z = float(centre[2])
    cosang = abs(float(normal @ centre)) / float(np.linalg.norm(centre))
    expected = math.pi * (hp.radius_m * fx / z) * (hp.radius_m * fy / z) * cosang
    regions = _enclosed_regions(plate)
    hole, areas = _keep_holes(regions, expected, cfg)
    rc = _boundary_samples(plate, hole)
    if rc.shape[0] == 0:
        raise StepFailed(
            "too_few_edge_points",
            f"the plate encloses no hole-sized region (expected ~{expected:.0f} px; "
            f"{int(regions.max())} enclosed regions)",
        )
    dirs = np.column_stack([(rc[:, 1] - cx) / fx, (rc[:, 0] - cy) / fy, np.ones(rc.shape[0])])
    edges = intersect_rays_plane(dirs, normal, d)
    info = {"plane": (normal, d), "plane_rms_m": rms, "hole_areas_px": areas}
    return edges[np.isfinite(edges).all(axis=1)], plate_idx, info


def _unorganised_edges(pts, usable, seed_idx, normal, d, hp: HoleParams, cfg):
    import cv2

    use = np.nonzero(usable)[0]
    s = pts[use] @ normal + d
    near = use[np.abs(s) < cfg.jump_m]
    normal, d, rms = _refine_plane(pts[near], normal, d, cfg.plane_threshold_m)
    if d < 0:
        normal, d = -normal, -d
    basis_tmp = plane_basis(normal)
    origin = -d * normal
    seed_uv = to_plane_2d(rays_to_plane(pts[seed_idx], normal, d), origin, basis_tmp)
    seed_uv = seed_uv[np.isfinite(seed_uv).all(axis=1)]
    lo = seed_uv.min(axis=0) - 0.1
    hi = seed_uv.max(axis=0) + 0.1
    uv = to_plane_2d(rays_to_plane(pts[near], normal, d), origin, basis_tmp)
    inside = np.isfinite(uv).all(axis=1) & np.all((uv >= lo) & (uv <= hi), axis=1)
    uv, plate_idx = uv[inside], near[inside]
    if cfg.grid_cell_m is not None:
        cell = float(cfg.grid_cell_m)
    else:
        area = float(np.prod(np.clip(hi - lo - 0.2, 0.05, None)))
        cell = float(np.clip(1.5 * math.sqrt(area / max(uv.shape[0], 1)), 0.003, 0.03))
    size = np.ceil((hi - lo) / cell).astype(int) + 1
    if size[0] * size[1] > 4_000_000:
        raise StepFailed(
            "too_few_edge_points", f"occupancy grid of {size[0]}x{size[1]} cells is too large"
        )
    ij = np.floor((uv - lo) / cell).astype(int)
    occ = np.zeros((size[0], size[1]), np.uint8)
    occ[ij[:, 0], ij[:, 1]] = 1
    occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n_lab, lab, stats, _ = cv2.connectedComponentsWithStats(occ, connectivity=8)
    if n_lab < 2:
        raise StepFailed("too_few_edge_points", "the plate's occupancy grid is empty")
    plate = lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    expected = math.pi * (hp.radius_m / cell) ** 2
    regions = _enclosed_regions(plate)
    hole, areas = _keep_holes(regions, expected, cfg)
    ij_e = _boundary_samples(plate, hole)
    if ij_e.shape[0] == 0:
        raise StepFailed(
            "too_few_edge_points",
            f"the plate's occupancy grid ({cell * 1000:.1f} mm cells) encloses no hole-sized "
            "region",
        )
    uv_e = lo + (ij_e + 0.5) * cell
    edges = from_plane_2d(uv_e, origin, basis_tmp)
    info = {"plane": (normal, d), "plane_rms_m": rms, "hole_areas_cells": areas, "cell_m": cell}
    return edges, plate_idx, info


# ----------------------------------------------------------------------------- from a pair


def detect_board_stereo_pair(
    frame: StereoFrame,
    rig,
    board: BoardGeometry = BoardGeometry(),
    config: StereoDetectorConfig = StereoDetectorConfig(),
    sgbm=None,
    *,
    coarse_factor: int | None = None,
    margin_px: int = 32,
) -> DetectionResult:
    """:func:`detect_board_stereo` on a rectified pair (``rig``: its
    :class:`~rigcal.sensors.stereo.StereoRig`), matching at full resolution only where the
    board can be.

    1. SGBM on the pair shrunk ``coarse_factor`` times (default: to about 480 px wide; at 4x,
       1/16 of the pixels and 1/4 of the disparities) and the detector's segmentation (ground
       removal, clusters with a plane of the board's size) on at most an eighth of
       ``max_segment_points`` of that coarse cloud (it only has to find the candidates): the
       board candidates and how far they are;
    2. for each candidate (best first, at most ``max_board_candidates``): SGBM at full
       resolution in the window around its points (plus ``margin_px``), searching disparities
       from ``sgbm.min_disparity`` up to the candidate's nearest point's disparity plus 25 % and
       16 px (never more than ``sgbm.num_disparities``; the background seen through the holes
       has smaller disparities and stays in range), then the whole detector on that window's
       organised cloud: the fit is the full-resolution one;
    3. if no window gives a detection, the whole pair is matched at full resolution as
       :func:`~rigcal.sensors.stereo.point_cloud_from_pair` does and detected there (the
       result, or failure, is then exactly that of :func:`detect_board_stereo`).

    ``quality`` gets ``window_fraction``: the fraction of the image matched at full
    resolution."""
    from rigcal.sensors.stereo import SgbmParams, point_cloud_from_pair, point_cloud_in_window

    params = SgbmParams() if sgbm is None else sgbm
    if coarse_factor is None:
        coarse_factor = max(1, int(rig.width) // 480)
    windows = _board_windows(frame, rig, board, config, params, coarse_factor, margin_px) \
        if coarse_factor > 1 else []
    for window, d_max, cand in windows:
        span = int(math.ceil((1.25 * d_max + 16 - params.min_disparity) / 16)) * 16
        fine = dataclasses.replace(params, num_disparities=max(16, min(span,
                                                                       params.num_disparities)))
        cloud = point_cloud_in_window(frame, rig, window, fine)
        intr = (rig.fx, rig.fy, rig.cx - window[0], rig.cy - window[1])
        det = _detect_seeded(cloud, cand, board, config, intr)
        if not isinstance(det, BoardDetection):  # the whole detector on the window
            det = detect_board_stereo(cloud, board, config)
        if isinstance(det, BoardDetection):
            u0, v0, u1, v1 = window
            fraction = (u1 - u0) * (v1 - v0) / float(rig.width * rig.height)
            return BoardDetection(det.sensor, det.t_ns, det.points,
                                  {**det.quality, "window_fraction": fraction})
    det = detect_board_stereo(point_cloud_from_pair(frame, rig, params), board, config)
    if isinstance(det, BoardDetection):
        det = BoardDetection(det.sensor, det.t_ns, det.points,
                             {**det.quality, "window_fraction": 1.0})
    return det


def _detect_seeded(frame: PointCloudFrame, cand: BoardSegment, board: BoardGeometry,
                   cfg: StereoDetectorConfig, intr=None) -> DetectionResult:
    """Step 3 of the detector on a full-resolution window, seeded by the coarse candidate
    instead of segmenting the window again: the seeds are the usable points within the plane
    threshold (doubled: the coarse plane is coarser) of the candidate's plane. The coarse
    plane can be tilted enough to cut off part of the plate, so it is first refitted on the
    plate of every other row and column (points within ``jump_m``, then the plane threshold);
    the plate is then found, refitted and searched for holes exactly as after a
    segmentation."""
    pts = frame.points_xyz
    if frame.organized_shape is None or pts.shape[0] == 0:
        return DetectionFailure(frame.sensor, frame.t_ns, "no_board_plane", "not an organised cloud")
    up = check_axis(cfg.up_axis, "up_axis", "stereo detector")
    usable, _ = _usable(pts, cfg)
    normal, d = cand.plane.normal, float(cand.plane.d)
    with np.errstate(invalid="ignore"):
        near = np.abs(pts @ normal + d) < 2.0 * cfg.plane_threshold_m
    seeds = np.nonzero(usable & near)[0]
    if seeds.size < max(10, cfg.min_board_points // 4):
        return DetectionFailure(frame.sensor, frame.t_ns, "no_board_plane",
                                f"{seeds.size} window points near the coarse board plane")
    seg = BoardSegment(np.arange(seeds.size), PlaneFit(normal, d, np.ones(seeds.size, bool),
                                                        float(cand.plane.rms)),
                       cand.extents_m, cand.partial)
    hp = HoleParams.from_config(board, cfg)
    try:
        return _detect_on_candidate(frame, pts, usable, seeds, seg, up, hp, cfg,
                                    np.random.default_rng(cfg.seed), intr, prefit=True)
    except StepFailed as exc:
        return DetectionFailure(frame.sensor, frame.t_ns, exc.reason, exc.detail)


def _board_windows(frame, rig, board, config, params, factor, margin_px
                   ) -> list[tuple[tuple[int, int, int, int], float, BoardSegment]]:
    """Full-resolution windows (u0, v0, u1, v1) around the board candidates of the coarse
    cloud, each with the candidate's largest disparity [px] and the candidate itself (its
    plane is in the same optical frame as the full-resolution cloud; best candidate first)."""
    from rigcal.sensors.stereo import downsample_pair, point_cloud_from_pair

    small, small_rig = downsample_pair(frame, rig, factor)
    coarse_params = dataclasses.replace(
        params, min_disparity=params.min_disparity // factor,
        num_disparities=max(16, int(math.ceil(params.num_disparities / factor / 16)) * 16),
        speckle_window_size=max(1, params.speckle_window_size // (factor * factor)),
    )
    cloud = point_cloud_from_pair(small, small_rig, coarse_params)
    coarse_cfg = dataclasses.replace(
        config, min_board_points=max(10, config.min_board_points // (factor * factor)),
        max_segment_points=max(1000, config.max_segment_points // 8))
    seg = _segment(cloud, board, coarse_cfg)
    if isinstance(seg, StepFailed):
        return []
    pts, _, idx, cands, _, _ = seg
    h, w = cloud.organized_shape
    out = []
    for cand in cands[: config.max_board_candidates]:
        members = idx[cand.indices]
        z_min = float(np.min(pts[members, 2]))
        if not z_min > 0:
            continue
        rows, cols = np.divmod(members, w)
        window = (max(0, int(cols.min()) * factor - margin_px),
                  max(0, int(rows.min()) * factor - margin_px),
                  min(rig.width, (int(cols.max()) + 1) * factor + margin_px),
                  min(rig.height, (int(rows.max()) + 1) * factor + margin_px))
        out.append((window, rig.fx * rig.baseline_m / z_min, cand))
    return out
