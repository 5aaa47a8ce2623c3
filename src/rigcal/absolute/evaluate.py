"""Checks of an absolute calibration ``T_body_sensor`` (paper, sections IV-B and IV-C2).

* :func:`ground_normal_angle` - eq. 13: the ground normal a sensor observes, mapped into the
  body frame, should be the body Z axis (0, 0, 1); the angle between them measures the roll
  and pitch error of ``T_body_sensor`` together (the paper: 0.02 deg after calibration).
* :func:`yaw_from_straight_drive` - the yaw error: while the vehicle drives straight along its
  X axis, static poles mapped into the body frame with a yaw error ``alpha`` drift sideways,
  ``dY/dX = tan(alpha)``. Poles are extracted per lidar scan (:func:`extract_poles`),
  associated over the drive (:func:`track_poles`), a line ``Y = a + b X`` is fitted per pole
  and ``alpha = atan(b)``; the median over poles is reported.
* :func:`labelling_repeatability` - the spread of a wheel centre over repeated labellings
  (Table IV).

Sign conventions: errors are **believed minus true**. With ``R_believed = R(err) @ R_true``
(``err`` = roll, pitch, yaw about the body axes), ``alpha ~ yaw``, the observed normal's tilt
gives ``roll_error_rad ~ roll`` and ``pitch_error_rad ~ pitch``; ``correct`` applies the
inverse rotation.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rigcal.absolute.labels import GroundPlane, fit_ground_plane
from rigcal.errors import GeometryError, InputError
from rigcal.geometry.fitting import fit_circle_2d, plane_basis
from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import matrix_from_rpy

__all__ = [
    "GroundNormalCheck",
    "Pole",
    "Repeatability",
    "YawDrift",
    "extract_poles",
    "ground_normal_angle",
    "labelling_repeatability",
    "track_poles",
    "yaw_from_pole_tracks",
    "yaw_from_straight_drive",
]


def _transform(T: np.ndarray, what: str) -> np.ndarray:
    m = np.asarray(T, dtype=float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise InputError(f"{what}: expected a finite (4, 4) transform, got shape {m.shape}")
    return m


def _cloud(points: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what}: expected an (N, 3) point cloud, got shape {p.shape}")
    return p[np.all(np.isfinite(p), axis=1)]


# ----------------------------------------------------------------------------- eq. 13


class GroundNormalCheck(NamedTuple):
    """Eq. 13: ``angle_rad`` between the observed ground normal in the body frame
    ``normal_body`` (3,) and (0, 0, 1); its signed parts ``roll_error_rad`` (about body X)
    and ``pitch_error_rad`` (about body Y); ``ground`` the plane fitted in the sensor frame."""

    angle_rad: float
    roll_error_rad: float
    pitch_error_rad: float
    normal_body: np.ndarray
    ground: GroundPlane

    @property
    def angle_deg(self) -> float:
        return math.degrees(self.angle_rad)

    def correct(self, T_body_sensor: np.ndarray) -> np.ndarray:
        """``T_body_sensor`` with the roll and pitch error removed (rotation only)."""
        T = _transform(T_body_sensor, "T_body_sensor")
        E = matrix_from_rpy(np.array([self.roll_error_rad, self.pitch_error_rad, 0.0]))
        return from_rt(E.T @ T[:3, :3], T[:3, 3])


def ground_normal_angle(
    points_sensor: np.ndarray,
    T_body_sensor: np.ndarray,
    *,
    threshold_m: float = 0.025,
    max_range_m: float | None = None,
    max_tilt_deg: float = 20.0,
    rng: np.random.Generator | int = 0,
    source: str = "sensor",
) -> GroundNormalCheck:
    """Eq. 13 for one sensor: fit the ground in ``points_sensor`` (N, 3) (a scan or its ground
    points, sensor frame) by RANSAC with inlier tolerance ``threshold_m`` (2.5 cm as in the
    paper), optionally within ``max_range_m`` of the sensor, the normal searched within
    ``max_tilt_deg`` of the body Z axis seen from the sensor; map the normal into the body
    frame with ``T_body_sensor`` and compare it with (0, 0, 1).
    """
    p = _cloud(points_sensor, f"{source}: ground points")
    T = _transform(T_body_sensor, "T_body_sensor")
    if max_range_m is not None:
        p = p[np.linalg.norm(p, axis=1) <= float(max_range_m)]
    up_sensor = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    ground = fit_ground_plane(
        p, threshold_m=threshold_m, up_hint=up_sensor, lower_band_m=None,
        max_tilt_deg=max_tilt_deg, min_fraction=0.05, rng=rng, source=source,
    )
    n = T[:3, :3] @ ground.normal
    n = n / np.linalg.norm(n)
    angle = math.acos(min(1.0, max(-1.0, float(n[2]))))
    # R(roll, pitch) @ z = (sin p cos r, -sin r, cos p cos r)
    roll = math.atan2(-n[1], math.hypot(n[0], n[2]))
    pitch = math.atan2(n[0], n[2])
    n.setflags(write=False)
    return GroundNormalCheck(angle, roll, pitch, n, ground)


# ----------------------------------------------------------------------------- poles


class Pole(NamedTuple):
    """A thin vertical object in one scan (sensor frame): ``position`` (3,) where its axis
    meets the ground [m], ``centroid`` (3,) of its points, ``radius_m`` of the circle fitted to
    its cross-section (NaN when the centroid was used), ``height_span_m`` of its points above
    the ground, ``n_points``."""

    position: np.ndarray
    centroid: np.ndarray
    radius_m: float
    height_span_m: float
    n_points: int


_GROUND_SAMPLE = 8000


def _clusters(uv: np.ndarray, gap: float) -> np.ndarray:
    """Labels of single-linkage clusters: points closer than ``gap`` are connected."""
    n = uv.shape[0]
    pairs = cKDTree(uv).query_pairs(gap, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def extract_poles(
    points_sensor: np.ndarray,
    *,
    ground: GroundPlane | None = None,
    up_hint: Sequence[float] = (0.0, 0.0, 1.0),
    min_height_m: float = 0.3,
    max_height_m: float = 3.0,
    cluster_gap_m: float = 0.3,
    max_radius_m: float = 0.25,
    min_height_span_m: float = 1.0,
    min_points: int = 10,
    max_range_m: float | None = 20.0,
    ground_threshold_m: float = 0.05,
    rng: np.random.Generator | int = 0,
    source: str = "scan",
) -> tuple[Pole, ...]:
    """Thin vertical clusters (poles, trunks) in a lidar scan (N, 3), sensor frame.

    1. the ground: ``ground`` or a RANSAC plane near ``up_hint`` (tolerance
       ``ground_threshold_m``) fitted to at most ~8000 of the points (evenly strided);
    2. points ``min_height_m`` .. ``max_height_m`` above it, within ``max_range_m`` of the
       sensor, projected onto the ground;
    3. single-linkage clusters with ``cluster_gap_m``;
    4. a cluster is a pole when it has ``min_points``, spans ``min_height_span_m`` in height
       and fits within ``max_radius_m`` of its centre;
    5. its position: the centre of a circle fitted to its cross-section (the pole's axis -
       unlike the centroid, not pulled toward the sensor by seeing only the near side), or the
       centroid when the circle fit fails or is larger than ``max_radius_m``; lifted onto the
       ground plane.
    """
    p = _cloud(points_sensor, f"{source}: points")
    if ground is None:
        near = p if max_range_m is None else p[np.linalg.norm(p, axis=1) <= max_range_m]
        stride = max(1, near.shape[0] // _GROUND_SAMPLE)  # the ground need not be exact here
        ground = fit_ground_plane(
            near[::stride], threshold_m=ground_threshold_m, up_hint=up_hint, lower_band_m=None,
            min_inliers=50, min_fraction=0.05, rng=rng, source=source,
        )
    h = ground.height(p)
    sel = (h >= min_height_m) & (h <= max_height_m)
    if max_range_m is not None:
        sel &= np.linalg.norm(p, axis=1) <= float(max_range_m)
    q, hq = p[sel], h[sel]
    if q.shape[0] < max(min_points, 3):
        return ()
    basis = plane_basis(ground.normal)
    foot0 = -ground.offset_m * ground.normal  # the ground point below the sensor
    uv = (q - foot0) @ basis.T
    labels = _clusters(uv, float(cluster_gap_m))
    poles = []
    for k in np.unique(labels):
        m = labels == k
        if m.sum() < min_points:
            continue
        span = float(hq[m].max() - hq[m].min())
        c2 = uv[m].mean(axis=0)
        if span < min_height_span_m or np.max(np.linalg.norm(uv[m] - c2, axis=1)) > max_radius_m:
            continue
        centre2, radius = c2, float("nan")
        try:
            fit = fit_circle_2d(uv[m], centre0=c2 + 0.05 * c2 / max(np.linalg.norm(c2), 1e-9))
            if fit.radius <= max_radius_m and np.linalg.norm(fit.centre - c2) <= max_radius_m:
                centre2, radius = fit.centre, fit.radius
        except GeometryError:
            pass
        position = foot0 + centre2 @ basis
        position.setflags(write=False)
        centroid = q[m].mean(axis=0)
        centroid.setflags(write=False)
        poles.append(Pole(position, centroid, radius, span, int(m.sum())))
    return tuple(poles)


def _common_shift(
    prev: np.ndarray, cur: np.ndarray, previous: np.ndarray, gate: float, max_step: float
) -> np.ndarray:
    """The displacement most pole pairs of two consecutive scans agree on (all static poles move
    alike); ties go to the one closest to the ``previous`` displacement."""
    if prev.shape[0] == 0 or cur.shape[0] == 0:
        return previous
    diffs = (cur[None, :, :] - prev[:, None, :]).reshape(-1, 3)
    diffs = diffs[np.linalg.norm(diffs, axis=1) <= max_step]
    if diffs.shape[0] == 0:
        return previous
    close = np.linalg.norm(diffs[:, None, :] - diffs[None, :, :], axis=2) < gate / 2
    support = close.sum(axis=1)
    best = np.flatnonzero(support == support.max())
    k = best[np.argmin(np.linalg.norm(diffs[best] - previous, axis=1))]
    return diffs[close[k]].mean(axis=0)


def track_poles(
    poles_body: Sequence[np.ndarray],
    *,
    gate_m: float = 1.0,
    max_step_m: float = 3.0,
    min_points: int = 5,
) -> tuple[np.ndarray, ...]:
    """Associate per-scan pole positions (body frame, (P_k, 3) per scan, in driving order)
    into tracks of one static pole each, (M, 3) arrays.

    Between consecutive scans all static poles move by the same displacement (at most
    ``max_step_m``): the one most pole pairs agree on. Each track takes the detection nearest
    to its last position plus that displacement, within ``gate_m`` (greedy, closest pairs
    first); a track that misses a scan ends. Tracks with fewer than ``min_points`` detections
    are dropped.
    """
    tracks: list[list[np.ndarray]] = []
    active: list[int] = []  # tracks that matched in the previous scan
    velocity = np.zeros(3)
    previous = np.zeros((0, 3))
    for det in poles_body:
        d = np.asarray(det, dtype=float).reshape(-1, 3)
        velocity = _common_shift(previous, d, velocity, gate_m, max_step_m)
        last = np.array([tracks[i][-1] for i in active]).reshape(-1, 3)
        pred = last + velocity
        used_t: set[int] = set()
        used_d: set[int] = set()
        new_active = []
        if len(active) and d.shape[0]:
            dist = np.linalg.norm(pred[:, None, :] - d[None, :, :], axis=2)
            for flat in np.argsort(dist, axis=None):
                i, j = np.unravel_index(flat, dist.shape)
                if dist[i, j] > gate_m:
                    break
                if i in used_t or j in used_d:
                    continue
                used_t.add(int(i))
                used_d.add(int(j))
                tracks[active[i]].append(d[j])
                new_active.append(active[i])
        for j in range(d.shape[0]):
            if j not in used_d:
                tracks.append([d[j]])
                new_active.append(len(tracks) - 1)
        active = new_active
        previous = d
    return tuple(np.array(t) for t in tracks if len(t) >= min_points)


class YawDrift(NamedTuple):
    """The yaw error from a straight drive: ``alpha_rad`` the median over poles of
    ``atan(dY/dX)``, ``per_pole_alpha_rad`` (P,), ``spans_m`` (P,) the X range each pole was
    seen over, ``tracks`` the (M, 3) body-frame positions of each pole."""

    alpha_rad: float
    per_pole_alpha_rad: np.ndarray
    spans_m: np.ndarray
    tracks: tuple[np.ndarray, ...]

    @property
    def alpha_deg(self) -> float:
        return math.degrees(self.alpha_rad)

    def correct(self, T_body_sensor: np.ndarray) -> np.ndarray:
        """``T_body_sensor`` with the yaw error removed: ``Rz(-alpha) @ R`` (rotation only)."""
        T = _transform(T_body_sensor, "T_body_sensor")
        return from_rt(matrix_from_rpy(np.array([0.0, 0.0, -self.alpha_rad])) @ T[:3, :3], T[:3, 3])


def yaw_from_pole_tracks(
    tracks: Sequence[np.ndarray], *, min_span_m: float = 5.0, min_points: int = 5
) -> YawDrift:
    """Fit ``Y = a + b X`` by least squares to each pole track (body frame, (M, 3)) seen over
    at least ``min_span_m`` in X with ``min_points`` positions; ``alpha = atan(b)``, median
    over the poles. GeometryError when no track qualifies."""
    alphas, spans, kept = [], [], []
    for t in tracks:
        a = np.asarray(t, dtype=float).reshape(-1, 3)
        if a.shape[0] < min_points:
            continue
        span = float(np.ptp(a[:, 0]))
        if span < min_span_m:
            continue
        b = np.polyfit(a[:, 0], a[:, 1], 1)[0]
        alphas.append(math.atan(b))
        spans.append(span)
        kept.append(a)
    if not alphas:
        raise GeometryError(
            f"straight drive: none of {len(tracks)} pole tracks was seen over {min_span_m} m "
            f"with {min_points} positions; drive further past the poles"
        )
    al = np.array(alphas)
    return YawDrift(float(np.median(al)), al, np.array(spans), tuple(kept))


def yaw_from_straight_drive(
    poles_per_scan: Sequence[np.ndarray | Sequence[Pole]],
    T_body_sensor: np.ndarray,
    *,
    gate_m: float = 1.0,
    max_step_m: float = 3.0,
    min_span_m: float = 5.0,
    min_points: int = 5,
) -> YawDrift:
    """The yaw error of ``T_body_sensor`` from a straight drive along the body X axis.

    ``poles_per_scan``: for each scan in driving order, the pole positions in the sensor frame,
    (P_k, 3) or a sequence of :class:`Pole` (from :func:`extract_poles`). They are mapped into
    the body frame with ``T_body_sensor``, tracked (:func:`track_poles`) and fitted
    (:func:`yaw_from_pole_tracks`). ``alpha > 0`` means the believed yaw is too large.
    """
    T = _transform(T_body_sensor, "T_body_sensor")
    per_scan = []
    for k, det in enumerate(poles_per_scan):
        if len(det) and isinstance(det[0], Pole):
            a = np.array([pole.position for pole in det])
        else:
            a = np.asarray(det, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(a)):
            raise InputError(f"straight drive: scan {k} has non-finite pole positions")
        per_scan.append(a @ T[:3, :3].T + T[:3, 3])
    tracks = track_poles(per_scan, gate_m=gate_m, max_step_m=max_step_m, min_points=min_points)
    return yaw_from_pole_tracks(tracks, min_span_m=min_span_m, min_points=min_points)


# ----------------------------------------------------------------------------- Table IV


class Repeatability(NamedTuple):
    """Spread of repeated labellings of one point: ``mean_m`` (3,), ``std_m`` (3,) per axis
    (sample standard deviation, ddof=1) [m], ``count``."""

    mean_m: np.ndarray
    std_m: np.ndarray
    count: int


def labelling_repeatability(centres: np.ndarray) -> Repeatability:
    """Per-axis spread of R >= 2 repeated estimates (R, 3) of one wheel centre (Table IV)."""
    c = np.asarray(centres, dtype=float)
    if c.ndim != 2 or c.shape[1] != 3:
        raise InputError(f"repeatability: expected (R, 3) repeated centres, got shape {c.shape}")
    if c.shape[0] < 2:
        raise InputError(f"repeatability: needs at least 2 repeated labellings, got {c.shape[0]}")
    if not np.all(np.isfinite(c)):
        raise InputError("repeatability: got non-finite centres")
    return Repeatability(c.mean(axis=0), c.std(axis=0, ddof=1), int(c.shape[0]))
