"""Lidar measurement extractor guided by the expected target pose (Charron et al., III-C).

Steps (lidar frame: x forward, y left, z up):

1. the target must be expected inside the lidar's range and field of view
   (:func:`rigcal.extract.guidance.lidar_view`);
2. crop the cloud to a box around the expected target: the template's bounds plus
   ``crop_pad_m``, grown by the calibration uncertainty's margin at the target's distance
   (:func:`rigcal.extract.guidance.lidar_crop_box`); optionally drop points near a known ground
   plane (the mocap knows the floor);
3. Euclidean clustering with a tolerance from the lidar's angular resolution and the target's
   range, ``factor * range * angular_step`` (neighbouring returns on the target are that far
   apart): :func:`cluster_tolerance`, :func:`euclidean_clusters`;
4. choose the cluster by a weighted score of its centroid error (against the centroid of the
   template part that faces the sensor at the expected pose, in units of the position margin)
   and of how its principal extents match that visible template's (relative to the target's
   size): :func:`score_clusters`;
5. robust ICP of the template onto the chosen cluster, started at the expected pose shifted so
   the centroids agree (:func:`rigcal.extract.icp.icp_align`); for a plate, the ends of the scan
   lines on it (:func:`ring_ends`) hold its in-plane position;
6. keypoints: the target's lidar keypoints put into the sensor frame by the refined pose (a
   diamond's corners), or - for a target without distinct keypoints (a cylinder) - the cluster
   points that lie on the fitted template.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rigcal.errors import InputError
from rigcal.extract.guidance import (
    PoseUncertainty,
    box_from_points,
    check_points,
    check_pose,
    lidar_crop_box,
    lidar_view,
)
from rigcal.extract.icp import (
    IcpOptions,
    PreparedTemplate,
    icp_align,
    prepare_template,
    principal_extents,
)
from rigcal.extract.result import (
    ICP_DIVERGED,
    NO_CLUSTER,
    NO_POINTS_IN_CROP,
    ExtractionFailure,
    ExtractionResult,
    Measurement,
)
from rigcal.geometry.se3 import transform_points
from rigcal.geometry.so3 import so3_log
from rigcal.recording import PointCloudFrame

__all__ = [
    "ClusterScore",
    "LidarSpec",
    "cluster_tolerance",
    "euclidean_clusters",
    "extract_lidar_target",
    "extract_target_lidar",
    "multi_start_icp",
    "ring_edge_rays",
    "ring_ends",
    "score_clusters",
]


@dataclass(frozen=True)
class LidarSpec:
    """What the extractor needs to know about a spinning lidar (defaults: Velodyne VLP-16):
    angular steps between neighbouring beams [rad], range limits [m], field of view [rad]."""

    vertical_step_rad: float = math.radians(2.0)
    horizontal_step_rad: float = math.radians(0.2)
    min_range_m: float = 0.5
    max_range_m: float = 100.0
    elevation_fov_rad: tuple[float, float] = (math.radians(-15.0), math.radians(15.0))
    azimuth_fov_rad: tuple[float, float] = (-math.pi, math.pi)

    def __post_init__(self) -> None:
        if not (self.vertical_step_rad > 0 and self.horizontal_step_rad > 0):
            raise InputError(
                f"LidarSpec: angular steps must be > 0, got {self.vertical_step_rad}, "
                f"{self.horizontal_step_rad}"
            )
        if not 0 <= self.min_range_m < self.max_range_m:
            raise InputError(
                f"LidarSpec: need 0 <= min_range_m < max_range_m, got {self.min_range_m}, "
                f"{self.max_range_m}"
            )

    @property
    def angular_step_rad(self) -> float:
        """The coarser of the two steps: the widest gap between neighbouring returns."""
        return max(self.vertical_step_rad, self.horizontal_step_rad)


def cluster_tolerance(
    range_m: float, angular_step_rad: float, factor: float = 1.5, min_m: float = 0.02
) -> float:
    """Euclidean clustering tolerance [m] for a target at ``range_m``: ``factor`` times the
    spacing ``range_m * angular_step_rad`` of neighbouring returns, at least ``min_m``."""
    return max(float(factor) * float(range_m) * float(angular_step_rad), float(min_m))


def euclidean_clusters(
    points: np.ndarray, tolerance_m: float, min_points: int = 5
) -> list[np.ndarray]:
    """Connected components of points (N, 3) linked when closer than ``tolerance_m``; index
    arrays of the components with at least ``min_points`` points, largest first."""
    p = check_points(points, "points", minimum=0)
    if p.shape[0] == 0:
        return []
    pairs = cKDTree(p).query_pairs(float(tolerance_m), output_type="ndarray")
    n = p.shape[0]
    graph = coo_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)
    )
    _, labels = connected_components(graph, directed=False)
    counts = np.bincount(labels)
    order = np.argsort(-counts, kind="stable")
    return [np.flatnonzero(labels == lab) for lab in order if counts[lab] >= min_points]


class ClusterScore(NamedTuple):
    """One cluster's score (lower is better) and its parts: ``centroid_error_m``,
    ``extent_error`` (mean absolute extent difference over the target size, unitless)."""

    index: int
    score: float
    centroid_error_m: float
    extent_error: float
    points: int


def score_clusters(
    points: np.ndarray,
    clusters: list[np.ndarray],
    expected_centroid: np.ndarray,
    expected_extents_m: np.ndarray,
    position_scale_m: float,
    weights: tuple[float, float] = (1.0, 1.0),
) -> list[ClusterScore]:
    """Score clusters against the expected target, best first.

    ``score = weights[0] * |centroid - expected_centroid| / position_scale_m
    + weights[1] * mean_i |extent_i - expected_extent_i| / max(expected_extents)``, extents
    along the principal axes, sorted largest first.
    """
    c_exp = np.asarray(expected_centroid, dtype=float).reshape(3)
    e_exp = np.asarray(expected_extents_m, dtype=float).reshape(3)
    size = max(float(e_exp.max()), 1e-6)
    scale = max(float(position_scale_m), 1e-6)
    out = []
    for i, idx in enumerate(clusters):
        q = points[idx]
        ce = float(np.linalg.norm(q.mean(axis=0) - c_exp))
        ee = float(np.mean(np.abs(principal_extents(q) - e_exp)) / size)
        out.append(ClusterScore(i, weights[0] * ce / scale + weights[1] * ee, ce, ee, len(idx)))
    return sorted(out, key=lambda s: s.score)


def _rings(p: np.ndarray, vertical_step_rad: float):
    """Every point's ring (points of one elevation: a split where the sorted elevations jump by
    more than 0.3 vertical steps), elevation, and azimuth about the points' mean azimuth ``az0``
    (so a target behind the lidar does not wrap): (ring, el, daz, az0)."""
    el = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    az = np.arctan2(p[:, 1], p[:, 0])
    az0 = math.atan2(float(np.mean(np.sin(az))), float(np.mean(np.cos(az))))
    daz = (az - az0 + math.pi) % (2 * math.pi) - math.pi
    order = np.argsort(el, kind="stable")
    ring = np.zeros(len(p), dtype=int)
    ring[order] = np.concatenate([[0], np.cumsum(np.diff(el[order]) > 0.3 * vertical_step_rad)])
    return ring, el, daz, az0


def _direction(el: float, az: float) -> np.ndarray:
    ce = math.cos(el)
    return np.array([ce * math.cos(az), ce * math.sin(az), math.sin(el)])


def ring_ends(
    points: np.ndarray,
    vertical_step_rad: float,
    horizontal_step_rad: float,
    gap_steps: float = 2.5,
) -> np.ndarray:
    """Where each scan line leaves a target: for every ring (points of one elevation) and every
    run of it without a gap of ``gap_steps`` azimuth steps, its first and last point moved out by
    half an azimuth step (same range and elevation). The target's edge lies anywhere between the
    last hit and the first miss, so the half-step point is an unbiased guess of where the ring
    crosses it. (E, 3) [m]; runs of one point give nothing.
    """
    p = check_points(points, "points", minimum=0)
    if p.shape[0] < 2:
        return np.zeros((0, 3))
    rng = np.linalg.norm(p, axis=1)
    ring, el, daz, az0 = _rings(p, vertical_step_rad)
    half = 0.5 * horizontal_step_rad
    ends = []
    for r in np.unique(ring):
        idx = np.flatnonzero(ring == r)
        idx = idx[np.argsort(daz[idx], kind="stable")]
        breaks = np.flatnonzero(np.diff(daz[idx]) > gap_steps * horizontal_step_rad)
        for run in np.split(idx, breaks + 1):
            if len(run) < 2:
                continue
            for i, sign in ((run[0], -1.0), (run[-1], 1.0)):
                ends.append(rng[i] * _direction(el[i], az0 + daz[i] + sign * half))
    return np.array(ends).reshape(-1, 3)


#: a ring's end is used for the plate's edge only when the ring's last steps before it are
#: regular: this many of them, each within RING_STEP_TOLERANCE of the azimuth step
RING_END_RUN = 3
RING_STEP_TOLERANCE = 0.25


def ring_edge_rays(
    points: np.ndarray,
    vertical_step_rad: float,
    horizontal_step_rad: float,
    azimuth_fov_rad: tuple[float, float] | None = None,
) -> np.ndarray:
    """The rays between which each scan line leaves a plate: for every ring (points of one
    elevation) of a target's returns ``points`` (N, 3) (sensor frame), at each of its two
    outermost points, that point's unit direction ``u_end`` and the direction of the ring's next
    ray beyond it ``u_next`` (one azimuth step further out, same elevation), which did not return
    from the plate. (E, 6) rows ``[u_end, u_next]``; the directions are exact whatever the
    range noise. An end is left out when the ring's last ``RING_END_RUN`` steps before it are
    not regular (a gap: the plate's hole, a dropped return) or when its next ray lies outside
    ``azimuth_fov_rad`` (lo, hi) [rad, counter-clockwise from +x]: there the ring ends where
    the lidar stops looking, not at the plate's edge."""
    p = check_points(points, "points", minimum=0)
    if p.shape[0] < RING_END_RUN + 1:
        return np.zeros((0, 6))
    ring, el, daz, az0 = _rings(p, vertical_step_rad)
    step = float(horizontal_step_rad)
    out = []
    for r in np.unique(ring):
        idx = np.flatnonzero(ring == r)
        if len(idx) < RING_END_RUN + 1:
            continue
        idx = idx[np.argsort(daz[idx], kind="stable")]
        d = np.diff(daz[idx])
        regular = np.abs(d - step) <= RING_STEP_TOLERANCE * step
        for i, sign, ok in ((idx[0], -1.0, regular[:RING_END_RUN].all()),
                            (idx[-1], 1.0, regular[-RING_END_RUN:].all())):
            if not ok:
                continue
            a_end = az0 + daz[i]
            a_next = a_end + sign * step
            if azimuth_fov_rad is not None:
                lo, hi = azimuth_fov_rad
                if hi - lo < 2 * math.pi - 1e-9:
                    rel = (a_next - lo) % (2 * math.pi)
                    if rel > (hi - lo) % (2 * math.pi) + 1e-12:
                        continue
            out.append(np.concatenate([_direction(el[i], a_end), _direction(el[i], a_next)]))
    return np.array(out).reshape(-1, 6)


#: the coarse global search: the template's plane (its thinnest axis) laid on the cluster's
#: both ways, turned about it in these steps [deg]; a short ICP from each, the best refined
MULTI_START_SPIN_DEG = 45.0
MULTI_START_ITERATIONS = 15


def _axes(points: np.ndarray) -> np.ndarray:
    """(3, 3) principal axes (columns, largest extent first) forming a right-handed frame."""
    q = points - points.mean(axis=0)
    _, _, Vt = np.linalg.svd(q, full_matrices=False)
    R = Vt.T.copy()
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1.0
    return R


def multi_start_icp(
    template: PreparedTemplate,
    cluster: np.ndarray,
    T_expected: np.ndarray,
    options: IcpOptions | None = None,
    *,
    rim_points_sensor: np.ndarray | None = None,
    on_template_m: float = 0.02,
    sensor: str = "",
    t_ns: int = 0,
):
    """ICP of ``template`` onto ``cluster`` (N, 3) from many orientations, not one: the
    template's principal frame laid on the cluster's with the four proper sign choices of the
    axes, each turned about the cluster's thinnest axis (a plate's normal) in
    MULTI_START_SPIN_DEG steps, centroids together. A short ICP from every start ranks them by
    the share of cluster points on the fitted template (then the RMS; among fits as good as the
    best - a symmetric template - the one closest to ``T_expected`` (4, 4)), and the best is
    refined by a full ICP. Returns the :func:`rigcal.extract.icp.icp_align` result of the best
    start, or its failure when none fits."""
    from dataclasses import replace as _replace

    opts = options or IcpOptions()
    coarse = _replace(opts, max_iterations=MULTI_START_ITERATIONS,
                      max_rotation_change_rad=math.pi, max_translation_change_m=2.0)
    Rt = _axes(template.points)
    Rc = _axes(cluster)
    n = Rc[:, 2]
    centre_t = template.points.mean(axis=0)
    centre_c = cluster.mean(axis=0)
    best, best_key, last_fail = None, None, None
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        base = Rc @ np.diag(signs) @ Rt.T
        for spin in np.arange(0.0, 360.0, MULTI_START_SPIN_DEG):
            a = math.radians(spin)
            K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
            Rs = np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * (K @ K)
            R = Rs @ base
            T0 = np.eye(4)
            T0[:3, :3] = R
            T0[:3, 3] = centre_c - R @ centre_t
            fit = icp_align(template, cluster, T0, coarse, rim_points_sensor=rim_points_sensor,
                            sensor=sensor, t_ns=t_ns)
            if isinstance(fit, ExtractionFailure):
                last_fail = fit
                continue
            on = float(np.mean(fit.distances_m <= on_template_m))
            dR = T_expected[:3, :3].T @ fit.T_sensor_target[:3, :3]
            turn = float(np.linalg.norm(so3_log(dR)))
            key = (round(on, 2), -round(fit.rms_m, 4), -turn)
            if best_key is None or key > best_key:
                best, best_key = fit, key
    if best is None:
        return last_fail if last_fail is not None else ExtractionFailure(
            sensor, t_ns, "icp_diverged", "no start of the global search fitted the template")
    return icp_align(template, cluster, best.T_sensor_target, opts,
                     rim_points_sensor=rim_points_sensor, sensor=sensor, t_ns=t_ns)


def _cloud(cloud, sensor: str, t_ns: int | None) -> tuple[np.ndarray, str, int]:
    if isinstance(cloud, PointCloudFrame):
        return cloud.points_xyz, sensor or cloud.sensor, cloud.t_ns if t_ns is None else t_ns
    p = np.asarray(cloud, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"sensor '{sensor}': a point cloud must be (N, 3), got {p.shape}")
    return p, sensor, 0 if t_ns is None else t_ns


def extract_lidar_target(
    cloud,
    T_lidar_target_expected: np.ndarray,
    template: PreparedTemplate | np.ndarray,
    *,
    keypoints_target: np.ndarray | None = None,
    lidar: LidarSpec | None = None,
    uncertainty: PoseUncertainty | None = None,
    crop_box_target: tuple[np.ndarray, np.ndarray] | None = None,
    crop_pad_m: float = 0.05,
    ground_plane: tuple[np.ndarray, float] | None = None,
    ground_clearance_m: float = 0.05,
    cluster_factor: float = 1.5,
    min_cluster_points: int = 10,
    score_weights: tuple[float, float] = (1.0, 1.0),
    icp_options: IcpOptions | None = None,
    on_template_m: float = 0.02,
    min_on_template_fraction: float = 0.6,
    min_fraction_in_view: float = 0.5,
    multi_start: bool = False,
    sensor: str = "",
    t_ns: int | None = None,
    target: str = "target",
) -> ExtractionResult:
    """Find the target in a lidar cloud near its expected pose and measure its keypoints.

    ``cloud``: (N, 3) [m] in the lidar frame, or a :class:`rigcal.recording.PointCloudFrame`.
    ``T_lidar_target_expected`` (4, 4): the mocap-predicted pose. ``template``: the target's
    template cloud in the target frame ((M, 3), or prepared once with
    :func:`rigcal.extract.icp.prepare_template`). ``keypoints_target`` (K, 3) [m]: the target's
    lidar keypoints, or None for a target measured by its surface points (cylinder).
    ``crop_box_target``: ``(min_xyz, max_xyz)`` in the target frame (default: the template's
    bounds plus ``crop_pad_m``), grown by ``uncertainty``. ``ground_plane``: ``(n, d)`` with
    ``n . p + d = 0`` in the lidar frame; points within ``ground_clearance_m`` of it are dropped.
    ``on_template_m``: the distance within which a scan point counts as on the fitted template;
    a fit that leaves more than ``1 - min_on_template_fraction`` of the cluster off the template
    explains only part of it (e.g. the plate laid along one ring of a far-off guess) and is
    refused as ``icp_diverged``. ``multi_start``: a coarse global search over the template's
    orientation instead of one ICP from the expected pose (a guess tens of degrees off):
    :func:`multi_start_icp`.

    Returns a :class:`Measurement` (``keypoints`` (K, 3) with ``keypoint_index`` 0..K-1, or the
    on-template points (M, 3) without; ``T_sensor_target`` the ICP pose; extras
    ``cluster_points`` (C, 3) and ``on_template`` (C,) bool) or an :class:`ExtractionFailure`:
    ``target_not_in_view``, ``no_points_in_crop``, ``no_cluster``, ``icp_diverged``.
    """
    pts, sensor, t_ns = _cloud(cloud, sensor, t_ns)
    spec = lidar or LidarSpec()
    unc = uncertainty or PoseUncertainty()
    T_exp = check_pose(T_lidar_target_expected, "T_lidar_target_expected")
    tpl = template if isinstance(template, PreparedTemplate) else prepare_template(template)
    kp = None if keypoints_target is None else check_points(keypoints_target, "keypoints_target")
    quality: dict[str, float] = {}

    view = lidar_view(
        T_exp, tpl.points, spec.min_range_m, spec.max_range_m, spec.elevation_fov_rad,
        spec.azimuth_fov_rad, min_fraction_in_view,
    )
    quality["fraction_in_view"] = view.fraction
    if not view.visible:
        return ExtractionFailure(sensor, t_ns, view.reason, f"target template: {view.detail}")

    if crop_box_target is not None:
        lo, hi = crop_box_target
    else:
        lo, hi = box_from_points(tpl.points, crop_pad_m)
    box = lidar_crop_box(T_exp, lo, hi, unc)
    finite = np.all(np.isfinite(pts), axis=1)
    keep = finite.copy()
    keep[finite] = box.contains(pts[finite])
    if ground_plane is not None:
        n = np.asarray(ground_plane[0], dtype=float).reshape(3)
        nn = float(np.linalg.norm(n))
        if not nn > 0:
            raise InputError(f"sensor '{sensor}': ground plane normal must be non-zero")
        height = (pts @ n + float(ground_plane[1])) / nn
        keep &= np.abs(height) > ground_clearance_m
    crop = pts[keep]
    quality["points_in_crop"] = float(crop.shape[0])
    if crop.shape[0] < min_cluster_points:
        return ExtractionFailure(
            sensor, t_ns, NO_POINTS_IN_CROP,
            f"{crop.shape[0]} points in the {np.round(box.size_m, 2).tolist()} m crop box, need "
            f"{min_cluster_points}",
        )

    visible = tpl.visible_from(T_exp)
    vis_pts = transform_points(T_exp, tpl.points[visible])
    c_exp = vis_pts.mean(axis=0)
    distance = float(np.linalg.norm(c_exp))
    tol = cluster_tolerance(distance, spec.angular_step_rad, cluster_factor)
    clusters = euclidean_clusters(crop, tol, min_cluster_points)
    quality.update(cluster_tolerance_m=tol, clusters=float(len(clusters)))
    if not clusters:
        return ExtractionFailure(
            sensor, t_ns, NO_CLUSTER,
            f"no cluster of >= {min_cluster_points} points at tolerance {tol:.3f} m among "
            f"{crop.shape[0]} cropped points",
        )
    margin = unc.margin_m(distance)
    e_exp = principal_extents(vis_pts)
    scores = score_clusters(crop, clusters, c_exp, e_exp, max(margin, 0.05), score_weights)
    best = scores[0]
    limit = margin + float(tpl.extents_m[0])
    if best.centroid_error_m > limit:
        return ExtractionFailure(
            sensor, t_ns, NO_CLUSTER,
            f"the best cluster's centroid is {best.centroid_error_m:.3f} m from the expected "
            f"target, more than the {limit:.3f} m margin",
        )
    cluster = crop[clusters[best.index]]
    quality.update(
        cluster_points=float(best.points),
        cluster_score=best.score,
        cluster_centroid_error_m=best.centroid_error_m,
        cluster_extent_error=best.extent_error,
        runner_up_score=scores[1].score if len(scores) > 1 else math.inf,
    )

    T0 = T_exp.copy()
    T0[:3, 3] += cluster.mean(axis=0) - c_exp
    rim_obs = None
    if tpl.has_rim:
        rim_obs = ring_ends(cluster, spec.vertical_step_rad, spec.horizontal_step_rad)
        quality["ring_ends"] = float(len(rim_obs))
    if multi_start:
        fit = multi_start_icp(tpl, cluster, T_exp, icp_options, rim_points_sensor=rim_obs,
                              on_template_m=on_template_m, sensor=sensor, t_ns=t_ns)
    else:
        fit = icp_align(
            tpl, cluster, T0, icp_options, rim_points_sensor=rim_obs, sensor=sensor, t_ns=t_ns
        )
    if isinstance(fit, ExtractionFailure):
        return fit
    T = fit.T_sensor_target
    dT = np.linalg.inv(T_exp) @ T
    on = fit.distances_m <= on_template_m
    if np.mean(on) < min_on_template_fraction:
        return ExtractionFailure(
            sensor, t_ns, ICP_DIVERGED,
            f"the fitted template holds only {int(np.sum(on))} of the cluster's {len(on)} points "
            f"within {on_template_m:g} m (a partial match, e.g. one ring; need "
            f"{100 * min_on_template_fraction:.0f} %)",
        )
    quality.update(
        icp_rms_m=fit.rms_m,
        icp_inlier_fraction=fit.inlier_fraction,
        icp_iterations=float(fit.iterations),
        icp_converged=float(fit.converged),
        on_template_points=float(np.sum(on)),
        correction_translation_m=float(np.linalg.norm(T[:3, 3] - T_exp[:3, 3])),
        correction_rotation_deg=math.degrees(float(np.linalg.norm(so3_log(dT[:3, :3])))),
    )
    if kp is not None:
        keypoints = transform_points(T, kp)
        index = np.arange(len(kp))
    else:
        keypoints = cluster[on]
        index = None
    return Measurement(
        sensor=sensor,
        t_ns=t_ns,
        target=target,
        keypoints=keypoints,
        keypoint_index=index,
        T_sensor_target=T,
        extras={"cluster_points": cluster, "on_template": on},
        quality=quality,
    )


def extract_target_lidar(
    cloud,
    target,
    T_lidar_target_expected: np.ndarray,
    template: PreparedTemplate | None = None,
    **options,
) -> ExtractionResult:
    """:func:`extract_lidar_target` for a :class:`rigcal.targets.definition.Target` (read
    duck-typed: ``template``, ``lidar_keypoints``, ``use_lidar_keypoints``, ``crop_box``).

    ``template``: the target's template already prepared (:func:`prepare_template`; pass it
    when extracting many frames), else prepared here. The lidar keypoints are measured when
    ``use_lidar_keypoints``, else the on-template points. The target's crop box is used when it
    holds at least 95 % of the template (the original tool's files have boxes that do not:
    then the template's bounds plus ``crop_pad_m`` are). ``options`` go to the extractor.
    """
    tpl = template if template is not None else prepare_template(target.template)
    keypoints = target.lidar_keypoints if getattr(target, "use_lidar_keypoints", False) else None
    box = getattr(target, "crop_box", None)
    if box is not None and "crop_box_target" not in options:
        lo, hi = np.asarray(box.min_xyz, float), np.asarray(box.max_xyz, float)
        inside = np.all((tpl.points >= lo) & (tpl.points <= hi), axis=1)
        if np.mean(inside) >= 0.95:
            options["crop_box_target"] = (lo, hi)
    options.setdefault("target", getattr(target, "name", "target"))
    return extract_lidar_target(
        cloud, T_lidar_target_expected, tpl, keypoints_target=keypoints, **options
    )
