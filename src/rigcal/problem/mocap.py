"""Motion-capture calibration (Charron, Waslander, Narasimhan) as a configuration of the problem.

A motion-capture system (MCS) tracks the robot (``T_M_R``) and every target (``T_M_T``), so each
target observation comes with the target's pose in the robot frame, ``T_R_T = T_M_R^-1 T_M_T``,
known to sub-millimetre accuracy. Every sensor is calibrated to the robot frame even when no
two sensors see the same target:

* lidar (eq. 2): ``e = P_L - T_R_L^-1 T_R_T P_T`` for measured keypoints ``P_L``;
* camera (eq. 3): ``e = rho - pi(T_R_C^-1 T_R_T P_T)`` for measured pixels ``rho``.

Each observation is a pose block ``T_R_T`` held at its MCS value; sensors are free. Targets
without distinct keypoints (a cylinder, or every lidar point on a plate) give measured points
with unknown correspondences: they are matched to the target's template points by nearest
neighbours after aligning centroids (under the current calibration), the problem is solved, and
correspondences are re-estimated until the calibration stops changing (paper III-D).

Centroid alignment is robust far from the truth but biased near it whenever the sensor sees
only part of the target (a lidar sees the near half of a cylinder: the centroids differ by
centimetres). With ``correspondences="surface"`` (the default) the paper's matching only gets
the calibration close; then every lidar point is tied to the closest point of the target's
surface (:class:`rigcal.targets.surface.TargetSurface`, analytic for the diamond, cylinder and
circle board): the residual is the point's distance to the surface, its closest point found
again at every evaluation inside the solve (fixed point-to-plane correspondences would cycle
at the plate's edges on noisy data). On exact data this recovers the calibration exactly;
cameras keep the paper's matching.

With ``target_pose_sigma`` set, target poses are estimated too under a prior from the MCS
(small per-target corrections); sensors that see the same target at the same time then share
its pose - the direct sensor-to-sensor coupling of overlapping views. Circle-board placements
(Domhof et al.) can join the same problem (``boards``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from rigcal.dataset import SensorKind
from rigcal.errors import ConfigError, ConvergenceError, InputError, RigcalError
from rigcal.geometry.se3 import adjoint, invert, se3_exp
from rigcal.geometry.so3 import so3_log
from rigcal.problem.numerics import single_threaded
from rigcal.problem.residuals import (MODEL_CAMERA, MODEL_POINT, MODEL_RANGE, MODEL_RAY_EDGE, MODEL_SURFACE,
                                     ray_plane_hits)
from rigcal.problem.result import CalibrationResult, SensorEstimate
from rigcal.problem.solver import Observations, PoseBlock, PosePriors, Problem, solve
from rigcal.problem.uncertainty import pose_std, relative_estimates
from rigcal.targets.surface import TargetSurface

ROBOT = "robot"


@dataclass(frozen=True, eq=False)
class MocapSensor:
    """A sensor to calibrate to the robot frame: ``kind`` lidar (3D keypoints, ``sigma`` in m)
    or camera (pixels through ``camera``, a :mod:`rigcal.sensors.camera` model; ``sigma`` in px)."""

    name: str
    kind: SensorKind
    camera: object | None = None
    sigma: float = 0.01
    frame_id: str = ""

    def __post_init__(self) -> None:
        if self.kind not in (SensorKind.LIDAR, SensorKind.CAMERA):
            raise ConfigError(f"sensor '{self.name}': mocap calibration takes lidars and cameras, not {self.kind.value}")
        if self.kind == SensorKind.CAMERA and self.camera is None:
            raise ConfigError(f"sensor '{self.name}': a camera needs a camera model (intrinsics)")
        if not self.sigma > 0:
            raise ConfigError(f"sensor '{self.name}': sigma must be > 0")
        if not self.frame_id:
            object.__setattr__(self, "frame_id", self.name)


@dataclass(frozen=True, eq=False)
class TargetObservation:
    """One sensor's observation of one target at one time.

    ``T_robot_target`` (4, 4): the target's pose in the robot frame from the MCS at ``t_ns``.
    ``measured``: (n, 3) points in the sensor frame [m] (lidar) or (n, 2) pixels (camera).
    ``keypoints_target``: (n, 3) the corresponding points in the target frame when known (e.g.
    diamond corners, checkerboard corners, in the same order); None when correspondences must be
    estimated against the target's template points.
    """

    sensor: str
    target: str
    t_ns: int
    T_robot_target: np.ndarray
    measured: np.ndarray
    keypoints_target: np.ndarray | None = None
    #: which hold (one still pose of the target) the observation belongs to: frames of one hold
    #: share their errors (the MCS pose of the still target, the extractor's view of it) and
    #: are not independent. "" = found from the MCS poses (consecutive observations of one
    #: target by one sensor whose ``T_robot_target`` stays within a few centimetres / degrees)
    hold: str = ""
    #: (6,) how ``T_robot_target`` changes with time at ``t_ns``: the twist (rad/s, m/s;
    #: rotation first) with ``T_robot_target(t_ns + h) ~ T_robot_target exp(h velocity)``, from
    #: the MCS streams. None: not known (taken as still). With it, the clock offset between the
    #: MCS and the sensor is estimated (:class:`MocapOptions` ``time_offset_sigma_s``)
    velocity: np.ndarray | None = None
    #: (6, 6) covariance of the MCS's error of ``T_robot_target`` at this capture (a right
    #: perturbation, rotation first; rad^2, m^2): the MCS streams' own scatter. None: unknown
    #: (the per-capture error is then estimated from the residuals alone)
    pose_cov: np.ndarray | None = None
    #: (E, 6) for a scanning lidar's points on a flat plate: where each ring leaves the plate,
    #: the unit directions ``[u_end, u_next]`` (sensor frame) of the ring's last ray on the plate
    #: and its next ray, which missed it (:func:`rigcal.extract.lidar.ring_edge_rays`). Given
    #: (even empty), the points are tied to the plate by their range along their rays and the
    #: plate's in-plane pose by these ring ends (:mod:`rigcal.problem.residuals`,
    #: ``MODEL_RANGE`` and ``MODEL_RAY_EDGE``); None: by the points' distance to the surface
    edge_rays: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = f"observation of '{self.target}' by '{self.sensor}' at t = {self.t_ns} ns"
        try:
            T = np.array(self.T_robot_target, dtype=float)
            m = np.array(self.measured, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: T_robot_target and measured must be arrays of numbers") from None
        if T.shape != (4, 4):
            raise InputError(f"observation of '{self.target}' by '{self.sensor}': T_robot_target must be 4x4")
        if not np.all(np.isfinite(T)):
            raise InputError(f"{where}: T_robot_target has non-finite entries (NaN or inf): the "
                             "MCS pose at this time is not known")
        if m.ndim != 2 or m.shape[1] not in (2, 3) or m.shape[0] == 0:
            raise InputError(
                f"observation of '{self.target}' by '{self.sensor}' at {self.t_ns}: measured must be "
                f"(n, 3) points or (n, 2) pixels with n >= 1, got {m.shape}"
            )
        if not np.all(np.isfinite(m)):
            raise InputError(f"{where}: measured has non-finite entries (NaN or inf)")
        for key, shape in (("velocity", (6,)), ("pose_cov", (6, 6)), ("edge_rays", None)):
            v = getattr(self, key)
            if v is None:
                continue
            a = np.array(v, dtype=float)
            if shape is None:  # edge_rays: (E, 6), any E (none: empty)
                a = a.reshape(0, 6) if a.size == 0 else a
                fits = a.ndim == 2 and a.shape[1] == 6
            else:
                fits = a.shape == shape
            if not fits or not np.all(np.isfinite(a)):
                want = "(E, 6)" if shape is None else str(shape)
                raise InputError(f"{where}: {key} must be finite numbers of shape {want}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, key, a)
        if self.keypoints_target is not None:
            k = np.array(self.keypoints_target, dtype=float)
            if k.shape != (m.shape[0], 3):
                raise InputError(
                    f"observation of '{self.target}' by '{self.sensor}': {m.shape[0]} measurements but "
                    f"keypoints of shape {k.shape}"
                )
            k.setflags(write=False)
            object.__setattr__(self, "keypoints_target", k)
        for a in (T, m):
            a.setflags(write=False)
        object.__setattr__(self, "T_robot_target", T)
        object.__setattr__(self, "measured", m)


#: correspondence schemes for measurements without keypoints (see the module docstring)
CORRESPONDENCES = ("surface", "centroid")
#: how each sensor's estimate is made from the solution (MocapOptions.estimator)
ESTIMATORS = ("gls", "ls")


@dataclass(frozen=True)
class MocapOptions:
    loss: str = "huber"
    loss_scale: float = 3.0  # in units of sigma
    #: "centroid": the paper's centroid-aligned nearest template points throughout;
    #: "surface": then lidar points to the closest surface point (point-to-plane)
    correspondences: str = "surface"
    #: the centroid phase hands over to the surface phase once the calibration changes less
    #: than these per iteration
    handover_translation_m: float = 1e-4
    handover_rotation_rad: float = 1e-4
    max_correspondence_iterations: int = 30
    #: correspondences have settled when no sensor's calibration changes by more than these
    #: or by more than ``settle_fraction`` of its own standard deviation (on noisy data the
    #: nearest neighbours can keep switching by amounts far below the uncertainty)
    translation_tolerance_m: float = 1e-6
    rotation_tolerance_rad: float = 1e-7
    settle_fraction: float = 0.01
    #: drop correspondences farther than this many sigma after alignment (0 = keep all)
    max_correspondence_sigma: float = 0.0
    #: (rotation [rad], translation [m]) std of the MCS target poses: when set, every target
    #: pose is estimated too (small per-target corrections under this prior), and observations
    #: of one target by several sensors within ``sync_tolerance_ns`` share one pose - the
    #: direct sensor-to-sensor coupling of overlapping views. None: MCS poses held exact.
    target_pose_sigma: tuple[float, float] | None = None
    sync_tolerance_ns: int = 5_000_000
    #: circle-board detections' noise [m] when board placements join the problem
    board_sigma_m: float = 0.01
    #: (rotation [rad], translation [m]): the least per-hold error of a still target's MCS pose
    #: the uncertainty assumes. (0, 0), the default: the per-hold error is estimated from the
    #: holds alone (a sensor needs ``min_holds`` of them); a floor makes the covariance wider
    #: where the holds show less
    hold_sigma_floor: tuple[float, float] = (0.0, 0.0)
    #: a sensor whose targets were seen in fewer distinct holds (still poses of the target
    #: apart by more than ``HOLD_DISTINCT_M`` or ``HOLD_DISTINCT_RAD``) is refused: its
    #: per-hold error cannot be told from its pose
    min_holds: int = 3
    #: std [s] of the clock offset between the MCS and each sensor assumed before the data
    #: (a prior): estimated per sensor when the target moved relative to the robot in the
    #: kept frames (observations with ``velocity``); 0 = the clocks are synchronised, no offset
    time_offset_sigma_s: float = 0.05
    #: the offset counts as determined when its std is at most this [s]; otherwise, when an
    #: offset the size of ``time_offset_sigma_s`` would widen the pose's uncertainty by more
    #: than ``OFFSET_MATTERS`` (in variance), the result is flagged
    time_offset_resolution_s: float = 0.001
    #: a lidar's points on a curved surface (the cylinder's tube) tied by their range along the
    #: ray (False: by their distance to the surface, biased under range noise across a thin tube)
    curved_ranges: bool = True
    #: "ls" (the default): the least-squares solution with the sandwich covariance under the
    #: estimated noise model; "gls": each sensor's estimate weighted by its estimated noise
    #: model (one generalised least-squares step from the solution,
    #: :func:`rigcal.problem.mocap_noise.gls`, where the weighting test accepts the model's
    #: weights) - more accurate where MCS errors dominate, its regions measured in docs/mocap.md.
    #: Sensors coupled by estimated target poses or board placements keep least squares
    estimator: str = "ls"

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ConfigError(f"mocap options: estimator must be one of {', '.join(ESTIMATORS)}, "
                              f"got {self.estimator!r}")
        if not isinstance(self.curved_ranges, (bool, np.bool_)):
            raise ConfigError(f"mocap options: curved_ranges must be true or false, got {self.curved_ranges!r}")
        if self.correspondences not in CORRESPONDENCES:
            raise ConfigError(f"mocap options: correspondences must be one of {CORRESPONDENCES}, "
                              f"got {self.correspondences!r}")
        if not int(self.max_correspondence_iterations) >= 1:
            raise ConfigError("mocap options: max_correspondence_iterations must be >= 1")
        try:
            floor = tuple(float(v) for v in self.hold_sigma_floor)
        except (TypeError, ValueError):
            floor = ()
        if len(floor) != 2 or not all(np.isfinite(v) and v >= 0 for v in floor):
            raise ConfigError("mocap options: hold_sigma_floor must be (rotation_rad, translation_m) >= 0, "
                              f"got {self.hold_sigma_floor!r}")
        object.__setattr__(self, "hold_sigma_floor", floor)
        if isinstance(self.min_holds, bool) or not int(self.min_holds) >= 1:
            raise ConfigError(f"mocap options: min_holds must be an integer >= 1, got {self.min_holds!r}")
        for key in ("time_offset_sigma_s", "time_offset_resolution_s"):
            v = float(getattr(self, key))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"mocap options: {key} must be a number >= 0 [s], got {getattr(self, key)!r}")


def _check(sensors: Sequence[MocapSensor], observations: Sequence[TargetObservation], initial, templates):
    names = {s.name: s for s in sensors}
    if len(names) != len(sensors):
        raise ConfigError("duplicate sensor names")
    seen = {s: 0 for s in names}
    for o in observations:
        if o.sensor not in names:
            raise InputError(f"observation by unknown sensor '{o.sensor}' (sensors: {', '.join(names)})")
        s = names[o.sensor]
        dim = 2 if s.kind == SensorKind.CAMERA else 3
        if o.measured.shape[1] != dim:
            raise InputError(
                f"observation of '{o.target}' by '{o.sensor}': a {s.kind.value} measures "
                f"{'pixels (n, 2)' if dim == 2 else 'points (n, 3)'}, got {o.measured.shape}"
            )
        if o.keypoints_target is None and o.target not in templates:
            raise InputError(
                f"target '{o.target}' has no keypoint correspondences and no template points "
                f"(templates: {', '.join(templates) or 'none'})"
            )
        seen[o.sensor] += 1
    missing = [s for s, n in seen.items() if n == 0]
    if missing:
        raise InputError(f"sensor(s) {missing} never saw a target: nothing to calibrate them with")
    for s in names:
        if s not in initial:
            raise InputError(f"no initial calibration T_robot_sensor for '{s}'")


def _correspond(obs: TargetObservation, sensor: MocapSensor, T_R_S: np.ndarray, template: np.ndarray, options: MocapOptions):
    """Target-frame template points matched to the measured points (centroid-aligned NNS)."""
    T_S_T = invert(T_R_S) @ obs.T_robot_target
    X = template @ T_S_T[:3, :3].T + T_S_T[:3, 3]
    m = obs.measured
    if sensor.kind == SensorKind.CAMERA:
        uv, valid = sensor.camera.project(X)
        ok = np.all(np.isfinite(uv), axis=1)
        # prefer points that face the camera when a surface normal is not known: all projected
        cand, idx = uv[ok], np.flatnonzero(ok)
        if cand.shape[0] == 0:
            return None, None
    else:
        cand, idx = X, np.arange(len(X))
    aligned = cand - cand.mean(axis=0) + m.mean(axis=0)
    d, j = cKDTree(aligned).query(m)
    keep = np.ones(len(m), dtype=bool)
    if options.max_correspondence_sigma > 0:
        keep = d <= options.max_correspondence_sigma * sensor.sigma
    return template[idx[j]][keep], keep


def _closest_on_surface(obs: TargetObservation, sensor: MocapSensor, T_R_S: np.ndarray, T_R_T: np.ndarray,
                        surface: TargetSurface, options: MocapOptions):
    """Closest surface points and normals (target frame) of the measured lidar points placed by
    the current calibration, and which measurements are kept."""
    T_T_S = invert(T_R_T) @ T_R_S
    y = obs.measured @ T_T_S[:3, :3].T + T_T_S[:3, 3]
    q, n = surface.closest(y)
    keep = np.ones(len(y), dtype=bool)
    if options.max_correspondence_sigma > 0:
        keep = np.linalg.norm(y - q, axis=1) <= options.max_correspondence_sigma * sensor.sigma
    return q[keep], n[keep], keep


def _target_pose(o: TargetObservation, block: str, block_poses, free: bool) -> np.ndarray:
    """The target pose an observation is built at: its block's estimate when target poses are
    estimated (``free``) and one is known, else the observation's own MCS pose."""
    return block_poses.get(block, o.T_robot_target) if block_poses and free else o.T_robot_target


def _target_blocks(observations, options) -> list[int]:
    """Index of the target pose block of every observation (shared when several sensors see one
    target at the same time and target poses are estimated)."""
    if options.target_pose_sigma is None:
        return list(range(len(observations)))
    order = sorted(range(len(observations)), key=lambda i: (observations[i].target, observations[i].t_ns))
    out = [0] * len(observations)
    current, first = -1, None
    for i in order:
        o = observations[i]
        # one pose only for observations close in time *and* in MCS pose: stamps alone would
        # merge a session whose stamps are wrong (1 ns apart) into one pose
        if first is None or o.target != first.target or o.t_ns - first.t_ns > options.sync_tolerance_ns \
                or not _same_pose(o.T_robot_target, first.T_robot_target, SHARED_POSE_M, SHARED_POSE_RAD):
            current += 1
            first = o
        out[i] = current
    return out


def _add(items, key, block, board, points, measured, normals=None, sigma=None) -> None:
    if len(points) == 0:
        return
    d = items.setdefault(key, {"frame": [], "points": [], "measured": [], "board": [], "normals": [],
                               "sigma": []})
    d["frame"] += [block] * len(points)
    d["points"].append(points)
    d["measured"].append(measured)
    d["board"].append(np.full(len(points), board))
    if normals is not None:
        d["normals"].append(normals)
    if sigma is not None:
        d["sigma"].append(sigma)


#: a ring end ties the plate's edge only where the ring crosses it at a fair angle: the step
#: between the two rays' hits must cross the outline by at least this fraction of its length
EDGE_MIN_CROSSING = 0.3
#: ... and away from the outline's corners by this many steps
EDGE_CORNER_STEPS = 3.0


def _edge_items(o: TargetObservation, T_R_S: np.ndarray, T_R_T: np.ndarray, surface: TargetSurface):
    """The ring ends of a lidar observation usable under the current poses, and each one's
    std: the step between its two rays' hits across the plate's outline over sqrt(12) (where
    the ring crosses the edge is uniform over the step), and the side of the outline each one
    ends on (an integer label: its inward normal's direction in degrees). (rays (k, 6),
    sigma (k, 1), side (k,))."""
    rays = o.edge_rays
    if rays is None or len(rays) == 0:
        return np.zeros((0, 6)), np.zeros((0, 1)), np.zeros(0, dtype=int)
    k = len(rays)
    TA = np.broadcast_to(T_R_T, (2 * k, 4, 4))
    TB = np.broadcast_to(T_R_S, (2 * k, 4, 4))
    h, srange, *_ = ray_plane_hits(TA, TB, np.concatenate([rays[:, :3], rays[:, 3:]]))
    f, g = surface.boundary(h[:, :2])
    cross = f[:k] - f[k:]
    length = np.linalg.norm(h[:k] - h[k:], axis=1)
    # near a corner of the outline the nearest side changes between (or under) the two rays
    corner = np.minimum(surface.corner_distance(h[:k, :2]), surface.corner_distance(h[k:, :2]))
    ok = (srange[:k] > 0) & (srange[k:] > 0) & (length > 0) & (cross >= EDGE_MIN_CROSSING * length) \
        & (corner > EDGE_CORNER_STEPS * length)
    side = np.round(np.degrees(np.arctan2(g[:k, 1], g[:k, 0]))).astype(int)
    return rays[ok], (cross[ok] / np.sqrt(12.0))[:, None], side[ok]


#: a lidar point on a curved surface (the cylinder's tube) is tied by its range along its ray
#: where the ray meets the surface at least this steeply (|cos| of the angle to the normal); a
#: grazing point's range hardly depends on where the surface is across the ray, and its closest
#: point would be biased, so it is left out
RANGE_MIN_COS = 0.5


def _ray_selection(o: TargetObservation, T_R_S: np.ndarray, T_R_T: np.ndarray, surface: TargetSurface):
    """Which points of a lidar observation on a curved surface are tied by their range along
    the ray (their rays meet the tube between its end discs at ``RANGE_MIN_COS`` or steeper,
    under the current poses) and which by their distance to the surface (the rest that lie
    nearest an end disc, where the surface is flat); grazing points are in neither."""
    T_T_S = invert(T_R_T) @ T_R_S
    p = np.asarray(o.measured, dtype=float)
    rho = np.maximum(np.linalg.norm(p, axis=1), 1e-12)
    w = (p / rho[:, None]) @ T_T_S[:3, :3].T
    origin = np.broadcast_to(T_T_S[:3, 3], w.shape)
    s, _, _, on = surface.ray_range(origin, w)
    _, n = surface.closest(origin + s[:, None] * w)
    steep = -np.einsum("ni,ni->n", n, w) >= RANGE_MIN_COS
    _, normal = surface.closest(p @ T_T_S[:3, :3].T + T_T_S[:3, 3])
    disc = ~on & (np.abs(normal[:, 2]) > 0.5)
    return on & steep, disc


def _edge_selection(sensors, observations, poses, surfaces, options, block_poses=None,
                    curved: bool = False) -> dict[int, tuple]:
    """Per lidar observation tied by its range along the ray, what ties it under the current
    poses: on a flat plate with ring ends, the ends usable and their stds
    (:func:`_edge_items`); on a curved surface (the cylinder), which points are tied by their
    range and which by their distance to the surface (:func:`_ray_selection`). Chosen once, when
    the surface phase starts, and kept (chosen again at every solve, an end at a threshold could
    come and go and the calibration never settle). ``(rays, sigma, side, range_mask,
    surface_mask)``, the masks None on a plate (every point by its range). Plates without
    ``curved``, curved surfaces with it: a curved surface's range starts from the settled
    point-to-surface answer (from the centroid phase's, biased by centimetres, a thin tube's
    ranges can settle on a wrong pose)."""
    names = {s.name: s for s in sensors}
    target_of = _target_blocks(observations, options)
    free = options.target_pose_sigma is not None
    out = {}
    for i, o in enumerate(observations):
        if names[o.sensor].kind != SensorKind.LIDAR or o.keypoints_target is not None or o.target not in surfaces:
            continue
        surface = surfaces[o.target]
        # a plate is never curved: the two selections are apart
        plate = o.edge_rays is not None and surface.planar
        if not ((options.curved_ranges and surface.curved_ray) if curved else plate):
            continue
        T_R_T = _target_pose(o, f"target:{target_of[i]}", block_poses, free)
        if plate:
            out[i] = (*_edge_items(o, poses[o.sensor], T_R_T, surface), None, None)
        else:
            out[i] = (np.zeros((0, 6)), np.zeros((0, 1)), np.zeros(0, dtype=int),
                      *_ray_selection(o, poses[o.sensor], T_R_T, surface))
    return out


def _build(sensors, observations, poses, surfaces, options, boards=None, block_poses=None, phase="centroid",
           edges=None):
    blocks = [PoseBlock(s.name, poses[s.name]) for s in sensors]
    names = {s.name: s for s in sensors}
    # (sensor, model, target, part) -> the items of one residual batch; point and pixel
    # batches hold every target, surface batches one target each
    items: dict[tuple[str, str, str, str], dict[str, list]] = {}
    target_of = _target_blocks(observations, options)
    free = options.target_pose_sigma is not None
    made: dict[int, str] = {}
    prior_blocks, prior_T = [], []
    for i, o in enumerate(observations):
        k = target_of[i]
        block = f"target:{k}"
        # held target poses are the observations' own (they change with a clock offset)
        T_R_T = _target_pose(o, block, block_poses, free)
        if k not in made:
            made[k] = block
            blocks.append(PoseBlock(block, T_R_T, (free,) * 6))
            if free:
                prior_blocks.append(block)
                prior_T.append(o.T_robot_target)
        sensor = names[o.sensor]
        normals = None
        model = MODEL_CAMERA if sensor.kind == SensorKind.CAMERA else MODEL_POINT
        if o.keypoints_target is not None:
            pts, meas = o.keypoints_target, o.measured
        elif phase == "surface" and edges and i in edges:
            # a scanning lidar's points (:func:`_edge_selection`): each point's range along its
            # ray; on a plate its outline where the rings leave it, on a cylinder the points
            # nearest its end discs by their distance to them
            rays, sig, _, on_ray, on_disc = edges[i]
            if len(rays):
                _add(items, (o.sensor, MODEL_RAY_EDGE, o.target, "edge"), block, i, np.zeros((len(rays), 3)),
                     rays, sigma=sig)
            if on_disc is not None and on_disc.any():
                disc = replace(o, measured=o.measured[on_disc])
                q, nrm, keep = _closest_on_surface(disc, sensor, poses[o.sensor], T_R_T, surfaces[o.target], options)
                _add(items, (o.sensor, MODEL_SURFACE, o.target, "surface"), block, i, q, disc.measured[keep], nrm)
            meas = o.measured if on_ray is None else o.measured[on_ray]
            if not len(meas):
                continue
            pts, model = np.zeros((len(meas), 3)), MODEL_RANGE
        elif phase == "surface" and sensor.kind == SensorKind.LIDAR:
            pts, normals, keep = _closest_on_surface(o, sensor, poses[o.sensor], T_R_T, surfaces[o.target], options)
            meas, model = o.measured[keep], MODEL_SURFACE
        else:
            pts, keep = _correspond(o, sensor, poses[o.sensor], surfaces[o.target].template, options)
            if pts is None:
                continue
            meas = o.measured[keep]
        # a surface batch per target: its closest points follow the poses inside the solve
        part = {MODEL_SURFACE: "surface", MODEL_RANGE: "range"}.get(model, "")
        _add(items, (o.sensor, model, o.target if part else "", part), block, i, pts, meas, normals)
    batches = []
    for (name, model, target, part), d in items.items():
        s = names[name]
        meas = np.concatenate(d["measured"])
        surface = model == MODEL_SURFACE
        if model == MODEL_RAY_EDGE:
            sigma = np.concatenate(d["sigma"])  # known: the scan's step, not the sensor's noise
        else:
            sigma = np.full((len(meas), 1 if model in (MODEL_SURFACE, MODEL_RANGE) else meas.shape[1]), s.sigma)
        batches.append(
            Observations(
                label=f"{ROBOT}-{name}" + (f":{part}:{target}" if part else ""),
                sensor=name,
                model=model,
                frame=tuple(d["frame"]),
                observer=(name,) * len(d["frame"]),
                points=np.concatenate(d["points"]),
                measured=meas,
                sigma=sigma,
                board=np.concatenate(d["board"]),
                camera=s.camera,
                normals=np.concatenate(d["normals"]) if surface else None,
                surface=surfaces[target] if surface or model in (MODEL_RAY_EDGE, MODEL_RANGE) else None,
            )
        )
    limits = []
    if boards is not None:
        from rigcal.problem.configurations import _pair_batches
        from rigcal.problem.pairs import all_pairs, pair_data

        for a, b in all_pairs(boards):
            p = pair_data(boards, a, b)
            if p is None or p.num_boards == 0:
                continue
            obs, lim = _pair_batches(p, boards)
            batches.append(obs.with_sigma(np.full(obs.measured.shape[1], options.board_sigma_m)))
            if lim is not None:
                limits.append(lim)
    priors = ()
    if prior_blocks:
        rot, trans = options.target_pose_sigma
        priors = (PosePriors("mcs", tuple(prior_blocks), np.array(prior_T), np.array([rot] * 3 + [trans] * 3)),)
    return Problem(tuple(blocks), tuple(batches), tuple(limits), priors)


def _settled(sol, poses, sensors, options: MocapOptions) -> tuple[bool, float, float]:
    """Whether no sensor's calibration moved by more than the tolerances (or the fraction of
    its std) in this solve; and the largest translation [m] and rotation [rad] change."""
    settled, worst_t, worst_r = True, 0.0, 0.0
    for s in sensors:
        new, old = sol.poses[s.name], poses[s.name]
        dt = float(np.linalg.norm(new[:3, 3] - old[:3, 3]))
        dr = float(np.linalg.norm(so3_log(old[:3, :3].T @ new[:3, :3])))
        cov = sol.pose_covariance(s.name)
        std_r = float(np.sqrt(max(np.trace(cov[:3, :3]), 0.0)))
        std_t = float(np.sqrt(max(np.trace(cov[3:, 3:]), 0.0)))
        tol_t = max(options.translation_tolerance_m, options.settle_fraction * std_t)
        tol_r = max(options.rotation_tolerance_rad, options.settle_fraction * std_r)
        settled &= dt <= tol_t and dr <= tol_r
        worst_t, worst_r = max(worst_t, dt), max(worst_r, dr)
    return settled, worst_t, worst_r


#: observations of one target by several sensors share one estimated target pose
#: (``target_pose_sigma``) only when their MCS poses agree within these
SHARED_POSE_M = 0.005
SHARED_POSE_RAD = 0.005
#: holds whose target poses (robot frame) are closer than these count as one view for
#: ``MocapOptions.min_holds``
HOLD_DISTINCT_M = 0.05
HOLD_DISTINCT_RAD = np.radians(5.0)
#: the clock offset matters when an offset of the assumed size widens a pose's covariance by
#: more than this factor (largest generalised eigenvalue)
OFFSET_MATTERS = 1.5
#: consecutive observations of one target by one sensor belong to one hold while the target's
#: pose in the robot frame moves less than these between them (used when ``hold`` is not set)
HOLD_TRANSLATION_M = 0.03
HOLD_ROTATION_RAD = np.radians(2.0)
#: a camera start is repaired by PnP when fewer than this fraction of the target points project
#: into the image under it (e.g. a start behind the camera)
MIN_VALID_PROJECTION = 0.5
#: a still target's per-hold MCS error: a translation error t and a rotation error t / this
#: (the markers' baseline: a Vicon body's markers span about half a metre)
HOLD_BASELINE_M = 0.5
_OFFSET_ITERATIONS = 8
_OFFSET_SETTLED_S = 1e-5


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapSensorFit:
    """How one sensor's calibration fits its measurements (see :func:`calibrate_mocap_fit`).

    ``unit``: ``"m"`` (lidar) or ``"px"`` (camera). ``sigma_nominal``: the configured noise;
    ``noise_sigma``: this sensor's own noise estimated from its residuals (its variance
    component, in ``unit``); ``reduced_chi2``: ``(noise_sigma / sigma_nominal) ** 2``;
    ``hold_inflation``: the trace of the covariance over that of the covariance with independent
    frames (> 1 when the frames of one hold share their errors); ``hold_sigma``: the std of the
    per-hold error of the target pose (rotation [rad], translation [m]) estimated from how the
    holds scatter; ``holds``,
    ``observations``, ``residuals``: counts behind them; ``matches[target] = (within, total)``:
    measurements within 3 configured sigma of the fitted model, per target; ``covariance_naive``
    (6, 6): the covariance with one noise scale shared by every sensor and every frame counted
    as independent (what was reported before); ``start``: ``"initial"`` or ``"pnp"`` (a camera
    whose initial pose put the target outside the image, started from PnP of its corners)."""

    name: str
    kind: SensorKind
    unit: str
    sigma_nominal: float
    noise_sigma: float
    reduced_chi2: float
    hold_inflation: float
    holds: int
    observations: int
    residuals: int
    matches: Mapping[str, tuple[int, int]]
    covariance_naive: np.ndarray
    start: str = "initial"
    #: (rotation [rad], translation [m]) std of the per-hold error of the target's pose
    hold_sigma: tuple[float, float] = (0.0, 0.0)
    #: the estimated error components (see :mod:`rigcal.problem.mocap_noise`), readable:
    #: ``capture_m`` / ``capture_rad`` (the MCS's error of the target pose per capture),
    #: ``jitter_s`` (timing error of a frame's stamp), ``hold_m`` / ``hold_rad`` (per hold)
    components: Mapping[str, float] = field(default_factory=dict)
    #: degrees of freedom of the estimated components (``inf``: a floor, not an estimate)
    components_dof: Mapping[str, float] = field(default_factory=dict)
    #: the clock offset [s] between the MCS and the sensor (its stamps minus the capture time
    #: on the MCS clock) and its std; NaN when nothing moved in its kept frames (no offset
    #: could act) or offsets are not estimated
    time_offset_s: float = float("nan")
    time_offset_std_s: float = float("nan")
    #: how much an unknown offset of the assumed size widens the covariance (largest
    #: generalised eigenvalue of the covariance with the offset over the one without; 1: none)
    time_offset_effect: float = 1.0
    #: ``"none"`` (nothing moved in its kept frames, or offsets not estimated), ``"determined"``
    #: (std at most ``time_offset_resolution_s``), ``"irrelevant"`` (not determined, but an
    #: offset of the assumed size would hardly change the pose) or ``"undetermined"`` (not
    #: determined and it matters: the result should be flagged)
    time_offset_status: str = "none"
    #: distinct holds (views) behind the estimate
    views: int = 0
    #: Satterthwaite's degrees of freedom of the covariance (its error components were
    #: estimated from the residuals of few holds; ``inf``: known) and how much wider (in
    #: variance) its 95 % region was made for that (1: not at all)
    noise_dof: float = float("inf")
    region_widening: float = 1.0
    #: the thinnest curved target (the cylinder) whose points this lidar's fit ties by their
    #: range along the ray, and its radius [m] ("" and NaN: none) - against the lidar's range
    #: noise it says whether the linearised covariance holds (the verdict's ``thin`` note)
    curved_target: str = ""
    curved_radius_m: float = float("nan")
    #: the per-hold error (``hold_m`` / ``hold_rad``) is the MCS's, estimated from the holds of
    #: every sensor that agrees with it, not from this sensor's alone (its degrees of freedom
    #: in ``components_dof`` are the pooled estimate's)
    hold_pooled: bool = False
    #: how the estimate was made: ``"gls"`` (weighted by the estimated noise model) or ``"ls"``
    #: (the least-squares solution: ``MocapOptions.estimator``, sensors coupled by estimated
    #: target poses, or the weighting test rejected the model's weights), and the weighting
    #: test's statistic over its chi-square 99 % quantile (> 1: rejected; NaN: not tested)
    estimator: str = "ls"
    weighting_test: float = float("nan")

    @property
    def match_fraction(self) -> float:
        total = sum(t for _, t in self.matches.values())
        return sum(w for w, _ in self.matches.values()) / total if total else float("nan")


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapFit:
    """:func:`calibrate_mocap_fit`'s value: the calibration and per-sensor fit statistics."""

    result: CalibrationResult
    sensors: Mapping[str, MocapSensorFit]
    #: the observations as fitted: ``T_robot_target`` at each sensor's capture time (its clock
    #: offset applied, :func:`shift_observation`), in the order given
    observations: tuple = ()


def hold_labels(observations: Sequence[TargetObservation]) -> list[str]:
    """The hold of every observation: ``"<sensor>/<hold>"`` with the observation's own ``hold``,
    else consecutive observations (in time) of one target by one sensor whose
    ``T_robot_target`` moves less than HOLD_TRANSLATION_M / HOLD_ROTATION_RAD from the previous
    one share a hold."""
    out = [""] * len(observations)
    order = sorted(range(len(observations)),
                   key=lambda i: (observations[i].sensor, observations[i].target, observations[i].t_ns))
    prev = None
    k = 0
    for i in order:
        o = observations[i]
        if o.hold:
            out[i] = f"{o.sensor}/{o.hold}"
            continue
        if prev is not None and prev.sensor == o.sensor and prev.target == o.target:
            dt = float(np.linalg.norm(o.T_robot_target[:3, 3] - prev.T_robot_target[:3, 3]))
            dr = float(np.linalg.norm(so3_log(prev.T_robot_target[:3, :3].T @ o.T_robot_target[:3, :3])))
            if dt > HOLD_TRANSLATION_M or dr > HOLD_ROTATION_RAD:
                k += 1
        else:
            k += 1
        out[i] = f"{o.sensor}/{o.target}#{k}"
        prev = o
    return out


def _valid_fraction(sensor: MocapSensor, obs: Sequence[TargetObservation], T_R_S: np.ndarray) -> float:
    ok = total = 0
    for o in obs:
        pts = o.keypoints_target
        if pts is None:
            continue
        X = (invert(T_R_S) @ o.T_robot_target)
        x = pts @ X[:3, :3].T + X[:3, 3]
        uv, valid = sensor.camera.project(x)
        ok += int(np.sum(np.all(np.isfinite(uv), axis=1) & np.asarray(valid, dtype=bool)))
        total += len(pts)
    return ok / total if total else 1.0


def _pnp_start(sensor: MocapSensor, obs: Sequence[TargetObservation]) -> np.ndarray | None:
    """``T_robot_camera`` from PnP of every observation with corners: the medoid of the poses
    ``T_robot_target inv(T_camera_target)`` (None when no PnP succeeds)."""
    from rigcal.extract.camera import solve_pnp

    cands = []
    for o in obs:
        if o.keypoints_target is None or len(o.keypoints_target) < 4:
            continue
        fit = solve_pnp(sensor.camera, o.keypoints_target, o.measured, sensor=sensor.name, t_ns=o.t_ns)
        if hasattr(fit, "T_camera_target"):
            cands.append(o.T_robot_target @ invert(fit.T_camera_target))
    if not cands:
        return None

    def dist(a, b):
        return float(np.linalg.norm(a[:3, 3] - b[:3, 3])) + float(np.linalg.norm(so3_log(a[:3, :3].T @ b[:3, :3])))

    cost = [sum(dist(a, b) for b in cands) for a in cands]
    return cands[int(np.argmin(cost))]


def _same_pose(A: np.ndarray, B: np.ndarray, metres: float = 0.002, radians: float = 0.002) -> bool:
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3])) <= metres
            and float(np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3]))) <= radians)


def _better_start(sensor: MocapSensor, obs, T_a: np.ndarray, T_b: np.ndarray, surfaces, options):
    """``T_b`` when the camera's own problem solved from it ends at a lower cost than solved
    from ``T_a`` (by more than rounding), else None."""
    costs = []
    for T in (T_a, T_b):
        prob = _build([sensor], obs, {sensor.name: T}, surfaces, options)
        try:
            sol = solve(prob, loss=options.loss, loss_scale=options.loss_scale)
        except RigcalError:
            costs.append(np.inf)
            continue
        costs.append(sol.cost if sol.converged else np.inf)
    return T_b if costs[1] < 0.999 * costs[0] else None


def _sqrt_psd(S: np.ndarray) -> np.ndarray:
    """``L`` with ``L L' = S`` for a symmetric positive semi-definite ``S``."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    return V * np.sqrt(np.clip(w, 0.0, None))


def _body_shape() -> np.ndarray:
    """(6, 6) default shape of one MCS body's pose error: translation variance 1, rotation
    variance 1 / HOLD_BASELINE_M^2 (a marker error over the markers' baseline)."""
    return np.diag([1.0 / HOLD_BASELINE_M ** 2] * 3 + [1.0] * 3)


def _default_shape(T_robot_target: np.ndarray) -> np.ndarray:
    """(6, 6) default shape of the error of ``T_robot_target`` (target right perturbation) when
    the target body and the robot body each err like :func:`_body_shape`: the robot's error
    reaches the target through the lever arm between them."""
    D = _body_shape()
    Ad = adjoint(invert(T_robot_target))
    return D + Ad @ D @ Ad.T


def _noisy(b: Observations) -> bool:
    """Whether a batch's rows are a mocap sensor's measurements, whitened by its configured
    noise (a ring end's std is the scan's step, known: not scaled with the sensor's noise)."""
    return b.label.startswith(ROBOT) and b.model != MODEL_RAY_EDGE


def _rows(prob: Problem, sol):
    """Whitened residuals (m,), dense Jacobian (m, n_free), the layout, and per row the
    observation index (-1: not an observation of a mocap sensor), the sensor name and whether
    its variance is known (a ring end: not the sensor's noise)."""
    from rigcal.problem.solver import _evaluate, prepare

    layout = prepare(prob)
    T = np.stack([sol.poses[p.name] for p in prob.poses])
    r, J, _, _ = _evaluate(prob, layout, T, "linear", 1.0, True)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    row_obs, row_sensor, row_known = [], [], []
    for b in prob.observations:
        ours = b.label.startswith(ROBOT)
        row_obs.append(np.repeat(np.where(ours, b.board, -1), b.dim))
        row_sensor += [b.sensor if ours else None] * (b.size * b.dim)
        row_known.append(np.full(b.size * b.dim, ours and not _noisy(b)))
    extra = len(r) - layout.m_obs
    row_obs = np.concatenate(row_obs + [np.full(extra, -1)])
    row_sensor = np.array(row_sensor + [None] * extra, dtype=object)
    row_known = np.concatenate(row_known + [np.zeros(extra, dtype=bool)])
    return r, J, layout, row_obs, row_sensor, row_known


@dataclass
class _Linear:
    """One sensor's rows of the problem linearised at the solution."""

    r: np.ndarray  # (n,) whitened residuals
    Js: np.ndarray  # (n, 6) w.r.t. the sensor's pose (right perturbation)
    cols: np.ndarray  # the sensor's free columns in the problem
    frames: list[tuple[int, np.ndarray, np.ndarray]]  # (observation, row mask, Jd (n_f, 6))
    j_offset: np.ndarray | None  # (n,) w.r.t. the clock offset [s]; None: nothing moved
    known: np.ndarray | None = None  # (n,) rows of known variance (ring ends); None: none


def _linearise(r, J, layout, row_obs, row_sensor, row_known, name: str, T_R_S: np.ndarray,
               observations: Sequence[TargetObservation], with_offset: bool) -> _Linear:
    rows = row_sensor == name
    cols = layout.cols[layout.index[name]]
    cols = cols[cols >= 0]
    Js, rs = J[np.ix_(rows, cols)], r[rows]
    obs_rows = row_obs[rows]
    frames = []
    j = np.zeros(len(rs))
    T_S_R = invert(T_R_S)
    for i in sorted(set(obs_rows.tolist())):
        m = obs_rows == i
        Jd = -Js[m] @ adjoint(T_S_R @ observations[i].T_robot_target)
        frames.append((i, m, Jd))
        v = observations[i].velocity
        if v is not None:
            # time_offset = stamp - capture time: the pose at capture is T(t - offset)
            j[m] = -(Jd @ v)
    moved = with_offset and bool(np.any(j != 0.0))
    known = row_known[rows]
    return _Linear(rs, Js, cols, frames, j if moved else None, known if known.any() else None)


def _edge_loading(lin: _Linear, edges: Mapping[int, tuple] | None) -> np.ndarray:
    """The ``edge`` loading (n, one column per frame and side of the plate's outline) of a
    lidar's ring ends: the ends of one frame on one side share an error. The firing azimuths of
    a revolution are one phase for every ring, and where the rings cross one straight edge
    differs from ring to ring by nearly whole steps (for a 45 deg side seen face on, the 2 deg
    between rings is 10 steps of 0.2 deg): where each ring's end falls within its step is then
    the same for all of them. Empty without ring ends."""
    if lin.known is None or not edges:
        return np.zeros((len(lin.r), 0))
    cols = []
    for i, m, _ in lin.frames:
        rows = np.flatnonzero(m & lin.known)
        if i not in edges or len(rows) == 0:
            continue
        side = edges[i][2]
        if len(side) != len(rows):
            continue
        for sd in np.unique(side):
            c = np.zeros(len(lin.r))
            c[rows[side == sd]] = 1.0
            cols.append(c)
    return np.column_stack(cols) if cols else np.zeros((len(lin.r), 0))


def _loadings(lin: _Linear, observations: Sequence[TargetObservation], holds: Sequence[str],
              edges: Mapping[int, tuple] | None = None):
    """The random-effect loadings of one sensor (see :mod:`rigcal.problem.mocap_noise`) and
    whether the per-capture shape came from the MCS streams (``pose_cov``)."""
    n = len(lin.r)
    obs = [observations[i] for i, _, _ in lin.frames]
    streams = all(o.pose_cov is not None for o in obs) and any(np.any(o.pose_cov != 0) for o in obs)
    cap = np.zeros((n, 6 * len(lin.frames)))
    jit = np.zeros((n, len(lin.frames)))
    for k, ((i, m, Jd), o) in enumerate(zip(lin.frames, obs)):
        S = o.pose_cov if streams else _default_shape(o.T_robot_target)
        cap[m, 6 * k: 6 * k + 6] = Jd @ _sqrt_psd(S)
        if o.velocity is not None:
            jit[m, k] = Jd @ o.velocity
    # the still target's error per hold (its MCS body, what the extractor makes of the view):
    # rotation [rad] and translation [m] each with its own variance (a lidar's plate seen at a
    # slant errs in tilt, an MCS body in both)
    hold_ids = sorted({holds[i] for i, _, _ in lin.frames})
    hold_r = np.zeros((n, 3 * len(hold_ids)))
    hold_t = np.zeros((n, 3 * len(hold_ids)))
    for (i, m, Jd) in lin.frames:
        g = hold_ids.index(holds[i])
        hold_r[m, 3 * g: 3 * g + 3] = Jd[:, :3]
        hold_t[m, 3 * g: 3 * g + 3] = Jd[:, 3:]
    loads = {"capture": cap, "hold_rot": hold_r, "hold": hold_t}
    if np.any(jit != 0.0):
        loads["jitter"] = jit
    # a camera's grid seen in one hold: the detector's affine error of that view
    affine = _view_affine(lin, observations, holds, hold_ids)
    if affine.shape[1]:
        loads["view_affine"] = affine
    edge = _edge_loading(lin, edges)
    if edge.shape[1]:
        loads["edge"] = edge
    return loads, streams


def _view_affine(lin: _Linear, observations: Sequence[TargetObservation], holds: Sequence[str],
                 hold_ids: Sequence[str]) -> np.ndarray:
    """The ``view_affine`` loading (n, 6 per hold) of a camera's corner grids: per hold, an
    affine distortion of the grid's image (a shift in u and v, and u and v linear in the
    corner's position on the target, :func:`_grid_coordinates`), shared by every frame of the
    hold; one variance for the six (in px at the grid's edge). A corner detector's error of one
    view is mostly that (measured on the simulated session, seed 7: 97 % or more of each
    view's pose error), not independent per corner; for a small grid its directions are nearly
    the pose's, so the view component (the pose directions taken out) cannot show it, and an
    isotropic per-hold pose error claims it in every direction. Empty for lidars and grids
    without correspondences."""
    n = len(lin.r)
    A = np.zeros((n, 6 * len(hold_ids)))
    for i, m, _ in lin.frames:
        o = observations[i]
        kp = o.keypoints_target
        uv = np.asarray(o.measured, dtype=float)
        rows = np.flatnonzero(m)
        if kp is None or uv.ndim != 2 or uv.shape[1] != 2 or len(rows) != 2 * len(uv) or len(uv) < 3:
            continue
        x, y = _grid_coordinates(np.asarray(kp, dtype=float))
        h = holds[i]
        g = 6 * list(hold_ids).index(h)
        ru, rv = rows[0::2], rows[1::2]
        A[ru, g], A[rv, g + 1] = 1.0, 1.0
        A[ru, g + 2], A[ru, g + 3] = x, y
        A[rv, g + 4], A[rv, g + 5] = x, y
    used = np.any(A != 0.0, axis=0)
    return A if used.any() else np.zeros((n, 0))


def _grid_coordinates(keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The keypoints' coordinates (K,), (K,) in the plane they span (their two principal
    directions about their centroid), scaled to at most 1 in absolute value: what an affine
    error of the grid's image is linear in. From the target frame, so the same in every frame
    of a hold (a measured grid's own noise would make the loading differ frame to frame)."""
    c = keypoints - keypoints.mean(axis=0)
    _, _, Vt = np.linalg.svd(c, full_matrices=False)
    xy = c @ Vt[:2].T
    return tuple((xy / max(float(np.abs(xy).max()), 1e-12)).T)


def _view_groups(lin: _Linear, observations: Sequence[TargetObservation], holds: Sequence[str]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The ``view`` component's rows: ``groups`` (n,), one keypoint coordinate (by its
    target-frame position) in every frame of one hold (-1: rows without correspondences, or of a
    coordinate seen in only one frame of its hold), and
    ``pose`` (n, k): per hold, an orthonormal basis of the directions in which a change of the
    sensor's pose moves that hold's keypoint coordinates. The view component is a per-keypoint
    error with those directions taken out (loaded with the opposite sign): an error of a hold
    that looks like a pose error is the hold components' (it moves the estimate as one), the
    rest the view's (it does not) - so the two cannot trade one for the other."""
    out = np.full(len(lin.r), -1)
    ids: dict[tuple, int] = {}
    hold_of_group: list[str] = []
    for i, m, _ in lin.frames:
        o = observations[i]
        if o.keypoints_target is None:
            continue
        rows = np.flatnonzero(m)
        dim = len(rows) // len(o.keypoints_target)
        if dim * len(o.keypoints_target) != len(rows):
            continue  # some keypoints were dropped (max_correspondence_sigma): no grouping
        keys = np.round(o.keypoints_target, 6)
        for j, row in enumerate(rows):
            key = (holds[i], *keys[j // dim], j % dim)
            if key not in ids:
                ids[key] = len(ids)
                hold_of_group.append(holds[i])
            out[row] = ids[key]
    if not ids:
        return out, np.zeros((len(lin.r), 0))
    # a coordinate seen in one frame of its hold: its view offset cannot be told from its noise
    # (with one frame per hold the two are one variance, and the split of it was arbitrary:
    # seen, a point noise of 6e-7 px where 2 px were drawn)
    counts = np.bincount(out[out >= 0], minlength=len(ids))
    kept = np.flatnonzero(counts >= 2)
    renumber = np.full(len(ids), -1)
    renumber[kept] = np.arange(len(kept))
    out = np.where(out >= 0, renumber[np.maximum(out, 0)], -1)
    hold_of_group = [hold_of_group[k] for k in kept]
    n_groups = len(kept)
    if not n_groups:
        return out, np.zeros((len(lin.r), 0))
    # the mean Jacobian of every group (its rows are the same coordinate in each frame)
    sums = np.zeros((n_groups, 6))
    counts = np.zeros(n_groups)
    g = out >= 0
    np.add.at(sums, out[g], lin.Js[g])
    np.add.at(counts, out[g], 1.0)
    mean = sums / np.maximum(counts, 1.0)[:, None]
    hold_names = sorted(set(hold_of_group))
    groups_of = {h: np.array([k for k, hh in enumerate(hold_of_group) if hh == h]) for h in hold_names}
    cols = []
    for h in hold_names:
        idx = groups_of[h]
        U, sv, _ = np.linalg.svd(mean[idx], full_matrices=False)
        keep = sv > 1e-9 * max(float(sv.max()), 1e-300)
        Q = np.zeros((n_groups, int(keep.sum())))
        Q[idx] = U[:, keep]
        cols.append(Q)
    Qall = np.hstack(cols)  # (groups, k)
    pose = np.zeros((len(lin.r), Qall.shape[1]))
    pose[g] = Qall[out[g]]
    return out, pose


@dataclass
class _SensorStats:
    cols: np.ndarray
    cov: np.ndarray  # (6, 6) reported
    naive: np.ndarray
    s2: float
    comp: object  # mocap_noise.Components
    noise: dict[str, float]
    hold_sigma: tuple[float, float]
    offset_std: float
    offset_effect: float
    determined: bool
    dof: float = float("inf")
    widening: float = 1.0
    #: the generalised least-squares step from the solution: the free pose columns (right
    #: perturbation), then the clock offset's [s] when it is estimated; zeros: least squares
    step: np.ndarray = None  # type: ignore[assignment]
    #: the estimate's kind ("gls" or "ls") and the weighting test's statistic over its 99 %
    #: quantile (> 1: the model's weights rejected; NaN: not weighted)
    estimator: str = "ls"
    weighting: float = float("nan")


@dataclass(frozen=True)
class _NoiseInputs:
    """What one sensor's noise model is fitted from (:func:`rigcal.problem.mocap_noise.fit_components`'s
    arguments) and whether its per-capture shape came from the MCS streams."""

    r: np.ndarray
    X: np.ndarray
    loadings: dict
    floors: dict
    groups: np.ndarray
    known: np.ndarray
    streams: bool

    def fit(self, fixed=None):
        from rigcal.problem.mocap_noise import fit_components

        return fit_components(self.r, self.X, self.loadings, self.floors, self.groups, self.known, fixed)


def _noise_inputs(lin: _Linear, observations, holds, options: MocapOptions, edges=None) -> _NoiseInputs:
    loads, streams = _loadings(lin, observations, holds, edges)
    X = lin.Js if lin.j_offset is None else np.column_stack([lin.Js, lin.j_offset])
    floor_r, floor_t = options.hold_sigma_floor
    floors = {"hold": floor_t ** 2, "hold_rot": floor_r ** 2}
    if streams:
        floors["capture"] = 1.0  # the MCS streams' own scatter: a known least value
    groups, view_pose = _view_groups(lin, observations, holds)
    if view_pose.shape[1]:
        loads["view_pose"] = view_pose
    return _NoiseInputs(lin.r, X, loads, floors, groups, lin.known, streams)


def _components(inputs: Mapping[str, _NoiseInputs]) -> dict:
    """Every sensor's noise components: each fitted on its own, then the MCS's per-hold error
    of a still target (``hold_rot``, ``hold``) estimated once from every sensor's holds
    (:func:`rigcal.problem.mocap_noise.fit_shared`). The pooled value must agree with every
    sensor's residuals: held at it, no sensor's fit may cost more than the likelihood test's
    level over its own; else the sensor with the largest per-hold error of its own keeps its
    own estimates and the value is pooled again over the others (its holds must not lend their
    degrees of freedom to a value they contradict), until every sensor left agrees or fewer
    than two are left. The MCS's error is part of every sensor's per-hold error, so the pooled
    value is a least value: a sensor whose own estimate of a component is below it takes the
    pooled value (and its degrees of freedom) for it; one whose own is larger (an error of its
    own on top, a lidar's corner bias) keeps its own."""
    from rigcal.problem.mocap_noise import LIKELIHOOD_RATIO, fit_shared

    out = {name: inp.fit() for name, inp in inputs.items()}
    members = list(inputs)
    while len(members) >= 2:
        kept = fit_shared([{"r": inputs[n].r, "X": inputs[n].X, "loadings": inputs[n].loadings,
                            "groups": inputs[n].groups, "known": inputs[n].known} for n in members]).kept()
        if not kept:
            break
        held = {n: inputs[n].fit(fixed=kept) for n in members}
        if any(held[n].deviance - out[n].deviance > LIKELIHOOD_RATIO for n in members):
            # the sensor with the largest per-hold error of its own is left out (an error of
            # its own on top of the MCS's drags the pooled value up until the others reject it)
            # and the value pooled again without it
            members.remove(max(members, key=lambda n: sum(out[n].get(c) / v for c, (v, _) in kept.items())))
            continue
        for n in members:
            below = {c: vd for c, vd in kept.items() if out[n].get(c) < vd[0]}
            if below:
                out[n] = held[n] if below == kept else inputs[n].fit(fixed=below)
        break
    return out


def _sensor_statistics(lin: _Linear, inputs: _NoiseInputs, comp, observations, options: MocapOptions,
                       weighted: bool = False, offset: float = 0.0) -> _SensorStats:
    """One sensor's covariance (and clock offset's std) under its noise model ``comp``.
    ``weighted``: of the generalised least-squares estimate (:func:`mocap_noise.gls`; its step
    from the solution in ``step``), else of the least-squares one the solver returned (the
    sandwich). ``offset``: the clock offset [s] the solution has (the prior's mean is 0)."""
    from scipy.stats import chi2

    from rigcal.problem.mocap_noise import (WEIGHTING_LEVEL, WEIGHTS, NoiseCovariance, effective_dof, gls, ls_step,
                                            sandwich, weighting_test, widening)

    X, loads, groups, streams = inputs.X, inputs.loadings, inputs.groups, inputs.streams
    prior = None
    if lin.j_offset is not None:
        prior = np.r_[np.zeros(6), 1.0 / options.time_offset_sigma_s]
    step = np.zeros(X.shape[1])
    parts = sandwich(X, loads, comp, prior, groups, lin.known)

    def parts_of(Xs):
        return sandwich(Xs, loads, comp, None, groups, lin.known)

    test = float("nan")
    if weighted:
        from rigcal.problem.solver import _robust

        # rows far outside their std under the noise model (an outlier) weigh as the solver's
        # robust loss would have them
        robust = None if options.loss == "linear" else (lambda u2: _robust(u2, options.loss, options.loss_scale)[1])
        mean = None if prior is None else np.r_[np.zeros(6), offset]
        vcov = NoiseCovariance(loads, comp, groups, lin.known, len(lin.r))
        g_step, g_parts = gls(lin.r, X, loads, comp, prior, mean, groups, lin.known, robust, vcov)
        # the weights only where the model describes the residuals (Hausman's test): a step
        # larger than the model allows keeps the least-squares estimate
        d = g_step - ls_step(lin.r, X, comp, prior, mean, lin.known)
        stat, dof = weighting_test(d, sum(parts.values()), sum(v for c, v in g_parts.items() if c != WEIGHTS))
        test = stat / float(chi2.ppf(WEIGHTING_LEVEL, dof)) if dof else 0.0
        if test <= 1.0:
            step, parts = g_step, g_parts

            def parts_of(Xs):
                return gls(lin.r, Xs, loads, comp, None, None, groups, lin.known, robust, vcov)[1]
    # the components were estimated from few groups: the covariance widened so that a 6-DOF
    # region holds the truth as often as it says (Satterthwaite's degrees of freedom)
    # (the weights' own part, a GLS estimate's, is not an estimated variance's share: left out
    # of the count)
    nu = effective_dof({c: v for c, v in parts.items() if c != WEIGHTS}, comp, 6)
    k = widening(nu)
    cov_all = k * sum(v for c, v in parts.items() if c != "prior") + parts.get("prior", 0.0)
    cov = cov_all[:6, :6]
    offset_std, effect = float("nan"), 1.0
    if lin.j_offset is not None:
        offset_std = float(np.sqrt(max(cov_all[6, 6], 0.0)))
        fixed_parts = parts_of(lin.Js)
        fixed = widening(effective_dof(fixed_parts, comp, 6)) * sum(fixed_parts.values())
        try:
            L = np.linalg.cholesky(fixed + 1e-18 * np.eye(6) * max(float(np.trace(fixed)), 1e-300))
            Li = np.linalg.inv(L)
            effect = float(np.linalg.eigvalsh(Li @ cov @ Li.T).max())
        except np.linalg.LinAlgError:
            effect = float("inf")
    A = lin.Js.T @ lin.Js
    wA = np.linalg.eigvalsh(0.5 * (A + A.T)) if A.size else np.zeros(1)
    determined = bool(np.all(np.isfinite(wA)) and wA.max() > 0 and wA.min() > 1e-12 * wA.max())
    obs = [observations[i] for i, _, _ in lin.frames]
    cap = comp.get("capture")
    if streams:
        cap_t = float(np.sqrt(cap * np.mean([np.trace(o.pose_cov[3:, 3:]) / 3 for o in obs])))
        cap_r = float(np.sqrt(cap * np.mean([np.trace(o.pose_cov[:3, :3]) / 3 for o in obs])))
    else:
        cap_t, cap_r = float(np.sqrt(cap)), float(np.sqrt(cap)) / HOLD_BASELINE_M
    hold_t = float(np.sqrt(comp.get("hold")))
    hold_r = float(np.sqrt(comp.get("hold_rot")))
    noise = {"capture_m": cap_t, "capture_rad": cap_r, "jitter_s": float(np.sqrt(comp.get("jitter"))),
             "hold_m": hold_t, "hold_rad": hold_r,
             "ring_end": float(np.sqrt(comp.get("edge"))),
             "view": float(np.sqrt(comp.get("view"))),
             "view_affine": float(np.sqrt(comp.get("view_affine")))}
    return _SensorStats(lin.cols, cov, np.zeros((6, 6)), comp.s2, comp, noise,
                        (hold_r, hold_t), offset_std, effect, determined, float(nu), float(k), step,
                        "gls" if test <= 1.0 else "ls", test)


def _statistics(prob: Problem, sol, sensors, observations, holds, options: MocapOptions,
                offsets: Mapping[str, float], edges=None):
    """Per-sensor noise components, covariances (and clock-offset std) at the solution, and a
    function giving the joint covariance of a list of sensors. ``offsets``: the clock offset
    [s] of every sensor whose offset is estimated.

    With ``options.estimator == "gls"`` each sensor's estimate is the generalised least-squares
    one under its noise model: ``stats[name].step`` (6 + 1,) is the step from the solution to it
    (the pose's right perturbation, the clock offset's), its ``cov`` the GLS covariance. When
    the sensors are coupled (target poses estimated, board placements), with ``"ls"`` or where
    the weighting test rejects the weights, the least-squares solution and its covariance stand
    (zero steps)."""
    r, J, layout, row_obs, row_sensor, row_known = _rows(prob, sol)
    stats: dict[str, _SensorStats] = {}
    lins = {s.name: _linearise(r, J, layout, row_obs, row_sensor, row_known, s.name, sol.poses[s.name],
                               observations, s.name in offsets) for s in sensors}
    inputs = {name: _noise_inputs(lin, observations, holds, options, edges) for name, lin in lins.items()}
    comps = _components(inputs)
    coupled = any(p.free != (False,) * 6 for p in prob.poses if p.name.startswith("target:")) \
        or any(not b.label.startswith(ROBOT) for b in prob.observations)
    weighted = options.estimator == "gls" and not coupled
    for s in sensors:
        lin = lins[s.name]
        st = _sensor_statistics(lin, inputs[s.name], comps[s.name], observations, options, weighted,
                                float(offsets.get(s.name, 0.0)))
        st.naive = sol.pose_covariance(s.name)
        free = layout.cols[layout.index[s.name]] >= 0
        k = int(free.sum())
        xi = np.zeros(6)
        xi[free] = st.step[:k]
        st.step = np.r_[xi, st.step[k] if lin.j_offset is not None else 0.0]
        stats[s.name] = st
    C = None
    if coupled:
        # the joint covariance: the full one with every sensor's rows weighted by its own noise,
        # each sensor's block replaced by its own and cross terms scaled alike
        w = np.ones(len(r))
        for s in sensors:
            w[(row_sensor == s.name) & ~row_known] = 1.0 / np.sqrt(stats[s.name].s2)
        Jw = J * w[:, None]
        C = np.linalg.pinv(Jw.T @ Jw, rcond=1e-12)
        D = np.ones(C.shape[0])
        for name, st in stats.items():
            base = np.trace(C[np.ix_(st.cols, st.cols)])
            D[st.cols] = np.sqrt(max(np.trace(st.cov) / base, 1.0)) if base > 0 else 1.0
        C = D[:, None] * C * D[None, :]
        for name, st in stats.items():
            C[np.ix_(st.cols, st.cols)] = st.cov

    def joint(names):
        if C is None:
            out = np.zeros((6 * len(names), 6 * len(names)))
            for k, n in enumerate(names):
                out[6 * k: 6 * k + 6, 6 * k: 6 * k + 6] = stats[n].cov
            return out
        cols = np.concatenate([layout.cols[layout.index[n]] for n in names])
        out = np.zeros((len(cols), len(cols)))
        idx = np.flatnonzero(cols >= 0)
        if idx.size:
            c = cols[idx]
            out[np.ix_(idx, idx)] = C[np.ix_(c, c)]
        return out

    return stats, joint


def shift_observation(obs: TargetObservation, time_offset_s: float) -> TargetObservation:
    """``obs`` with ``T_robot_target`` at the capture time when the sensor stamps its frames
    ``time_offset_s`` later than the MCS's clock: ``T(t - offset) ~ T(t) exp(-offset velocity)``
    (unchanged without a velocity or a zero offset)."""
    from dataclasses import replace

    if obs.velocity is None or time_offset_s == 0.0:
        return obs
    return replace(obs, T_robot_target=obs.T_robot_target @ se3_exp(-time_offset_s * obs.velocity))


def _offset_steps(prob, sol, sensors, observations, offsets, options: MocapOptions) -> dict[str, float]:
    """One Gauss-Newton step of every moving sensor's clock offset jointly with its pose (the
    pose is then solved again with the offset applied): least squares with the residuals
    weighted by their scatter and the offset's prior ``N(0, time_offset_sigma_s^2)``."""
    r, J, layout, row_obs, row_sensor, row_known = _rows(prob, sol)
    out = {}
    for s in sensors:
        if s.name not in offsets:
            continue
        lin = _linearise(r, J, layout, row_obs, row_sensor, row_known, s.name, sol.poses[s.name], observations,
                         True)
        if lin.j_offset is None:
            out[s.name] = 0.0
            continue
        X = np.column_stack([lin.Js, lin.j_offset])
        s2 = max(float(lin.r @ lin.r) / max(len(lin.r) - 7, 1), 1e-300)
        A = X.T @ X / s2
        A[6, 6] += 1.0 / options.time_offset_sigma_s ** 2
        g = X.T @ lin.r / s2
        g[6] += offsets[s.name] / options.time_offset_sigma_s ** 2
        try:
            step = -np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            step = -np.linalg.pinv(A) @ g
        out[s.name] = float(step[6])
    return out


def _offset_status(estimated: bool, std: float, effect: float, options: MocapOptions) -> str:
    if not estimated:
        return "none"
    if std <= options.time_offset_resolution_s:
        return "determined"
    return "undetermined" if effect > OFFSET_MATTERS else "irrelevant"


def distinct_holds(observations: Sequence[TargetObservation], holds: Sequence[str]) -> int:
    """How many distinct views the holds give: holds whose (first) target poses in the robot
    frame lie within HOLD_DISTINCT_M and HOLD_DISTINCT_RAD of an earlier one count once."""
    firsts: dict[str, np.ndarray] = {}
    for o, h in zip(observations, holds):
        firsts.setdefault(h, o.T_robot_target)
    views: list[np.ndarray] = []
    for T in firsts.values():
        if not any(_same_pose(T, V, HOLD_DISTINCT_M, HOLD_DISTINCT_RAD) for V in views):
            views.append(T)
    return len(views)


def _check_holds(sensors, observations, holds, options: MocapOptions) -> None:
    """ConvergenceError naming the first sensor seen in fewer than ``options.min_holds``
    distinct holds: its per-hold error cannot be told from its pose."""
    need = int(options.min_holds)
    for s in sensors:
        mine = [(o, h) for o, h in zip(observations, holds) if o.sensor == s.name]
        n = distinct_holds([o for o, _ in mine], [h for _, h in mine])
        if n >= need:
            continue
        raw = len({h for _, h in mine})
        same = f" ({raw} holds, but at nearly the same target pose)" if raw > n else ""
        what = "image" if s.kind == SensorKind.CAMERA else "field of view"
        raise ConvergenceError(
            f"sensor '{s.name}': its measurements do not determine its pose: its targets were seen "
            f"in {n} distinct hold{'s' if n != 1 else ''}{same}, and at least {need} are needed to "
            f"tell the error of a hold (the MCS's and the extractor's, shared by its frames) from "
            f"the sensor's pose: hold the target {need - n} more time{'s' if need - n != 1 else ''} "
            f"in its {what}, at other distances, places in the {what} and tilts (more than "
            f"{100 * HOLD_DISTINCT_M:.0f} cm / {np.degrees(HOLD_DISTINCT_RAD):.0f} deg apart)",
            sensor=s.name)


def _residuals_at(prob: Problem) -> tuple[np.ndarray, ...]:
    """The whitened residuals (n, d) of every observation batch at the problem's own poses."""
    from rigcal.problem.solver import _evaluate, prepare

    layout = prepare(prob)
    T = np.stack([p.T for p in prob.poses])
    return tuple(_evaluate(prob, layout, T, "linear", 1.0, False)[3])


def _matches(prob: Problem, residuals, sensors, observations, whitened) -> dict[str, dict[str, tuple[int, int]]]:
    """Per sensor and target, (measurements within 3 configured sigma, measurements);
    ``residuals``: each batch's whitened residuals, ``whitened[sensor]``: the sigma they were
    whitened by, over the configured."""
    out: dict[str, dict[str, list[int]]] = {s.name: {} for s in sensors}
    for b, raw in zip(prob.observations, residuals):
        if not _noisy(b):
            continue
        lim = 3.0 * np.sqrt(b.dim)
        e = np.linalg.norm(raw, axis=1) * whitened.get(b.sensor, 1.0)
        for i, ok in zip(b.board, e <= lim):
            t = observations[int(i)].target
            c = out[b.sensor].setdefault(t, [0, 0])
            c[0] += int(ok)
            c[1] += 1
    return {s: {t: (c[0], c[1]) for t, c in d.items()} for s, d in out.items()}


def calibrate_mocap(
    sensors: Sequence[MocapSensor],
    observations: Sequence[TargetObservation],
    initial: Mapping[str, np.ndarray],
    templates: Mapping[str, np.ndarray | TargetSurface] | None = None,
    options: MocapOptions = MocapOptions(),
    boards=None,
) -> CalibrationResult:
    """``T_robot_sensor`` for every sensor from MCS-tracked target observations: the
    ``result`` of :func:`calibrate_mocap_fit` (see there)."""
    return calibrate_mocap_fit(sensors, observations, initial, templates, options, boards).result


def calibrate_mocap_fit(
    sensors: Sequence[MocapSensor],
    observations: Sequence[TargetObservation],
    initial: Mapping[str, np.ndarray],
    templates: Mapping[str, np.ndarray | TargetSurface] | None = None,
    options: MocapOptions = MocapOptions(),
    boards=None,
) -> MocapFit:
    """``T_robot_sensor`` for every sensor from MCS-tracked target observations, with each
    sensor's fit statistics (:class:`MocapSensorFit`).

    ``initial``: ``T_robot_sensor`` guesses (e.g. CAD or TF). ``templates``: target name ->
    its :class:`~rigcal.targets.surface.TargetSurface` (``TargetSurface.of(target)``: analytic
    when it can be) or (K, 3) template points in the target frame, for observations without
    correspondences. ``options.correspondences`` chooses how those are matched.
    ``boards``: an optional :class:`rigcal.dataset.Dataset` of circle-board placements seen by
    these sensors (same names): their pairwise terms join the problem (Domhof et al.).

    A camera whose initial pose puts most target corners outside the image (e.g. behind it)
    starts from PnP of its corners instead. The uncertainty is honest about two things the
    least-squares covariance is not: every sensor has its own noise (a variance component per
    sensor, ``result.noise_sigma_m`` for lidars, ``MocapSensorFit.noise_sigma`` for all), and
    the frames of one hold share their errors (the covariance of a sensor is widened by how
    much more its per-hold scores scatter than independent frames would:
    ``MocapSensorFit.hold_inflation``).

    Raises ConvergenceError when the correspondence iterations do not settle, or when a
    sensor's measurements leave its pose undetermined (e.g. a camera that sees none of its
    target points under the initial calibration and whose corners PnP cannot place).
    """
    surfaces = {k: v if isinstance(v, TargetSurface) else TargetSurface.of_template(v, k)
                for k, v in (templates or {}).items()}
    _check(sensors, observations, initial, surfaces)
    holds = hold_labels(observations)
    _check_holds(sensors, observations, holds, options)
    if boards is not None:
        unknown = [n for n in boards.names if n not in {s.name for s in sensors}]
        if unknown:
            raise InputError(f"board dataset sensors {unknown} are not among the mocap sensors")
    t0 = time.perf_counter()
    poses = {s.name: np.asarray(initial[s.name], dtype=float) for s in sensors}
    starts = {s.name: "initial" for s in sensors}
    for s in sensors:
        if s.kind != SensorKind.CAMERA:
            continue
        own = [o for o in observations if o.sensor == s.name]
        valid = _valid_fraction(s, own, poses[s.name])
        if valid >= MIN_VALID_PROJECTION:
            # a second start from PnP of the corners: a plate seen in few views has a mirrored
            # pose that fits almost as well, and a far-off start can end there; the start whose
            # solution fits better is kept
            if all(o.keypoints_target is not None for o in own):
                T = _pnp_start(s, own)
                if T is not None and not _same_pose(T, poses[s.name]):
                    better = _better_start(s, own, poses[s.name], T, surfaces, options)
                    if better is not None:
                        poses[s.name], starts[s.name] = better, "pnp"
            continue
        T = _pnp_start(s, own)
        if T is None or _valid_fraction(s, own, T) < MIN_VALID_PROJECTION:
            raise ConvergenceError(
                f"camera '{s.name}': under the initial calibration only {100 * valid:.0f} % of its "
                f"target points project into the image (is the initial T_robot_sensor right? a "
                f"start behind the camera sees nothing) and PnP of its measured corners could not "
                f"place the camera either", sensor=s.name
            )
        poses[s.name], starts[s.name] = T, "pnp"
    kinds = {s.name: s.kind for s in sensors}
    needs_iterations = any(o.keypoints_target is None for o in observations)
    # the surface phase applies to lidar measurements without keypoints
    handover = options.correspondences == "surface" and any(
        o.keypoints_target is None and kinds[o.sensor] == SensorKind.LIDAR for o in observations)
    phase, phase_it, it = "centroid", 0, 0
    sol = None
    edges = None  # the ring ends' selection, made when the surface phase starts
    curved_done = False  # the curved surfaces' ranges, chosen when the surface phase settles
    with single_threaded():
        block_poses: dict[str, np.ndarray] = {}
        while True:
            it += 1
            phase_it += 1
            if phase == "surface" and edges is None:
                edges = _edge_selection(sensors, observations, poses, surfaces, options, block_poses)
            prob = _build(sensors, observations, poses, surfaces, options, boards, block_poses, phase, edges)
            sol = solve(prob, loss=options.loss, loss_scale=options.loss_scale)
            block_poses = {k: v for k, v in sol.poses.items() if k.startswith("target:")}
            if not sol.converged:
                raise ConvergenceError(f"mocap calibration did not converge: {sol.status}")
            settled, change_t, change_r = _settled(sol, poses, sensors, options)
            poses = {s.name: sol.poses[s.name] for s in sensors}
            if not needs_iterations:
                break
            if handover and phase == "centroid":
                # the paper's matching only has to get close: its fixed point is biased anyway
                close = change_t <= options.handover_translation_m and change_r <= options.handover_rotation_rad
                if close or phase_it >= options.max_correspondence_iterations:
                    phase, phase_it = "surface", 0
                continue
            if settled and phase == "surface" and not curved_done:
                curved_done = True
                more = _edge_selection(sensors, observations, poses, surfaces, options, block_poses, curved=True)
                if more:
                    edges, phase_it = {**(edges or {}), **more}, 0
                    continue
            if settled:
                break
            if phase_it >= options.max_correspondence_iterations:
                raise ConvergenceError(
                    f"mocap calibration: {phase} correspondences still changing after "
                    f"{options.max_correspondence_iterations} iterations"
                )
    assert sol is not None
    # the clock offset of every sensor whose target moved relative to the robot in its kept
    # frames, jointly with its pose (Gauss-Newton on the offset, the poses solved again)
    offsets: dict[str, float] = {}
    if options.time_offset_sigma_s > 0:
        offsets = {s.name: 0.0 for s in sensors
                   if any(o.sensor == s.name and o.velocity is not None and np.any(o.velocity != 0)
                          for o in observations)}
    shifted = list(observations)
    if offsets:
        with single_threaded():
            for _ in range(_OFFSET_ITERATIONS):
                steps = _offset_steps(prob, sol, sensors, shifted, offsets, options)
                for n, d in steps.items():
                    offsets[n] += d
                shifted = [shift_observation(o, offsets.get(o.sensor, 0.0)) for o in observations]
                prob = _build(sensors, shifted, poses, surfaces, options, boards, block_poses, phase, edges)
                # the sensors (and estimated target poses) start where they were; held target
                # poses are the shifted observations'
                start = {k: v for k, v in sol.poses.items()
                         if not k.startswith("target:") or options.target_pose_sigma is not None}
                sol2 = solve(prob, loss=options.loss, loss_scale=options.loss_scale, start=start)
                if not sol2.converged:
                    raise ConvergenceError(f"mocap calibration did not converge: {sol2.status}")
                sol = sol2
                poses = {s.name: sol.poses[s.name] for s in sensors}
                block_poses = {k: v for k, v in sol.poses.items() if k.startswith("target:")}
                if max((abs(d) for d in steps.values()), default=0.0) < _OFFSET_SETTLED_S:
                    break
    coupled = options.target_pose_sigma is not None or boards is not None
    # residuals of ``sol`` are whitened by the configured sigma times this (a reweighted solve
    # whitens by the estimated noise): _matches judges against the configured sigma
    whitened = {s.name: 1.0 for s in sensors}
    with single_threaded():
        stats, joint = _statistics(prob, sol, sensors, shifted, holds, options, offsets, edges)
        if coupled or any(abs(np.log(st.s2)) > np.log(4.0) for st in stats.values()):
            # every sensor weighted by its own noise (and the robust loss's scale with it)
            factor = {n: float(np.sqrt(st.s2)) for n, st in stats.items()}
            prob = prob.with_observations(tuple(
                b.with_sigma(b.sigma * factor[b.sensor]) if _noisy(b) else b
                for b in prob.observations))
            sol2 = solve(prob, loss=options.loss, loss_scale=options.loss_scale, start=sol.poses)
            if sol2.converged:
                sol = sol2
                poses = {s.name: sol.poses[s.name] for s in sensors}
                whitened = factor
            stats, joint = _statistics(prob, sol, sensors, shifted, holds, options, offsets, edges)
            for n, st in stats.items():
                st.s2 *= factor[n] ** 2
                st.noise["view"] *= factor[n]
                st.noise["view_affine"] *= factor[n]
            prob = prob.with_observations(tuple(
                b.with_sigma(b.sigma / factor[b.sensor]) if _noisy(b) else b
                for b in prob.observations))
    # each sensor's generalised least-squares estimate under its noise model: one step from
    # the least-squares solution (zero when the sensors are coupled or options.estimator == "ls")
    residuals = sol.residuals
    if any(np.any(st.step != 0.0) for st in stats.values()):
        poses = {n: T @ se3_exp(stats[n].step[:6]) for n, T in poses.items()}
        offsets = {n: o + float(stats[n].step[6]) for n, o in offsets.items()}
        if offsets:
            shifted = [shift_observation(o, offsets.get(o.sensor, 0.0)) for o in observations]
        # the matches counted where the estimate is (with the offsets it has)
        at = _build(sensors, shifted, poses, surfaces, options, boards, block_poses, phase, edges)
        residuals, whitened = _residuals_at(at), {s.name: 1.0 for s in sensors}
        prob = at
    for s in sensors:
        if s.kind == SensorKind.CAMERA:
            own = [o for o in shifted if o.sensor == s.name]
            valid = _valid_fraction(s, own, poses[s.name])
            if valid < MIN_VALID_PROJECTION:
                raise ConvergenceError(
                    f"camera '{s.name}': only {100 * valid:.0f} % of its target points project into "
                    f"the image under the estimate: its pose is not determined by its measurements",
                    sensor=s.name)
    estimates, rmse, reproj, fits = {}, {}, {}, {}
    matches = _matches(prob, residuals, sensors, shifted, whitened)
    thinnest = _thinnest_ranged(shifted, surfaces, edges)
    for s in sensors:
        st = stats[s.name]
        cov = joint([s.name])
        if not st.determined or not np.all(np.isfinite(cov)):
            raise ConvergenceError(
                f"sensor '{s.name}': its measurements do not determine its pose (their information "
                f"matrix is singular: too few measured points, or none that depend on the pose); "
                f"no estimate is returned", sensor=s.name)
        estimates[s.name] = SensorEstimate(
            name=s.name, kind=s.kind, frame_id=s.frame_id, T_reference_sensor=poses[s.name].copy(),
            covariance=cov, std=pose_std(poses[s.name], cov),
        )
        own = [o for o in shifted if o.sensor == s.name]
        e = np.concatenate([measured_residuals(o, s, poses[s.name], surfaces.get(o.target)) for o in own])
        e = e[np.isfinite(e)]
        value = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
        (reproj if s.kind == SensorKind.CAMERA else rmse)[f"{ROBOT}-{s.name}"] = value
        sigma = float(s.sigma * np.sqrt(st.s2))
        naive = st.naive
        curved_target, curved_radius = thinnest.get(s.name, ("", float("nan")))
        fits[s.name] = MocapSensorFit(
            name=s.name, kind=s.kind, unit="px" if s.kind == SensorKind.CAMERA else "m",
            sigma_nominal=float(s.sigma), noise_sigma=sigma, reduced_chi2=float(st.s2),
            hold_inflation=float(np.trace(cov) / np.trace(naive)) if np.trace(naive) > 0 else 1.0,
            hold_sigma=st.hold_sigma,
            holds=len({h for h, o in zip(holds, shifted) if o.sensor == s.name}),
            observations=len(own), residuals=int(e.size),
            matches=matches.get(s.name, {}), covariance_naive=naive, start=starts[s.name],
            components=MappingProxyType({**{k: v for k, v in st.noise.items() if k not in ("view", "view_affine")
                                            and (k != "ring_end" or "edge" in st.comp.values)},
                                         f"view_{'px' if s.kind == SensorKind.CAMERA else 'm'}":
                                             st.noise["view"] * float(s.sigma),
                                         **({"view_affine_px": st.noise["view_affine"] * float(s.sigma)}
                                            if s.kind == SensorKind.CAMERA else {})}),
            components_dof=MappingProxyType({k: float(v) for k, v in st.comp.dof.items()}),
            time_offset_s=float(offsets[s.name]) if s.name in offsets else float("nan"),
            time_offset_std_s=st.offset_std, time_offset_effect=st.offset_effect,
            time_offset_status=_offset_status(s.name in offsets, st.offset_std, st.offset_effect, options),
            views=distinct_holds(own, [h for h, o in zip(holds, shifted) if o.sensor == s.name]),
            noise_dof=st.dof, region_widening=st.widening,
            curved_target=curved_target, curved_radius_m=curved_radius,
            hold_pooled=bool(st.comp.fixed),
            estimator=st.estimator,
            weighting_test=st.weighting,
        )
    noise_model = {}
    for s in sensors:
        f = fits[s.name]
        comps = {("point_px" if f.unit == "px" else "point_m"): f.noise_sigma, **f.components}
        if np.isfinite(f.time_offset_s):
            comps["time_offset_s"] = f.time_offset_s
            comps["time_offset_std_s"] = f.time_offset_std_s
        noise_model[s.name] = {k: float(v) for k, v in comps.items()}
    result = CalibrationResult(
        mode="mocap",
        reference=ROBOT,
        converged=True,
        sensors=estimates,
        rmse_m=rmse,
        per_board_m={},
        outliers={},
        iterations=sol.iterations,
        cost=sol.cost,
        num_boards=0,
        noise_model=noise_model,
        noise_iterations=it,
        solve_time_s=time.perf_counter() - t0,
        reprojection_px=reproj,
        relative=relative_estimates([s.name for s in sensors], poses, joint),
    )
    return MocapFit(result=result, sensors=fits, observations=tuple(shifted))


def _thinnest_ranged(observations, surfaces, edges) -> dict[str, tuple[str, float]]:
    """Per sensor, the curved target of smallest radius that some of its points are tied to by
    their range along the ray (:func:`_edge_selection`'s range mask), and that radius."""
    out: dict[str, tuple[str, float]] = {}
    for i, sel in (edges or {}).items():
        on_ray = sel[3]
        if on_ray is None or not np.any(on_ray):
            continue
        o = observations[i]
        radius = surfaces[o.target].ray_radius_m
        if o.sensor not in out or radius < out[o.sensor][1]:
            out[o.sensor] = (o.target, radius)
    return out


def measured_residuals(obs: TargetObservation, sensor: MocapSensor, T_robot_sensor: np.ndarray,
                       surface: TargetSurface | None = None) -> np.ndarray:
    """The measured residual of every point of one observation under ``T_robot_sensor`` - the
    one definition every mocap output uses (tables, ``calibration.yaml``, the report,
    ``diagnostics.csv``): (n,) distances [m] between the measured lidar keypoints and the target
    keypoints placed by the MCS, or reprojection errors [px] of a camera's keypoints; without
    correspondences, a lidar point's distance to the target's surface and a pixel's distance to
    the nearest projected template point (``surface`` needed then). NaN for a camera keypoint
    that does not project."""
    T_st = invert(np.asarray(T_robot_sensor, dtype=float)) @ obs.T_robot_target
    if obs.keypoints_target is not None:
        X = obs.keypoints_target @ T_st[:3, :3].T + T_st[:3, 3]
        if sensor.kind == SensorKind.CAMERA:
            uv, _ = sensor.camera.project(X)
            return np.linalg.norm(obs.measured - uv, axis=1)
        return np.linalg.norm(obs.measured - X, axis=1)
    if surface is None:
        raise InputError(f"observation of '{obs.target}' by '{sensor.name}': no keypoints and no "
                         "target surface to measure its residual against")
    if sensor.kind == SensorKind.CAMERA:
        X = surface.template @ T_st[:3, :3].T + T_st[:3, 3]
        uv, _ = sensor.camera.project(X)
        ok = np.all(np.isfinite(uv), axis=1)
        if not np.any(ok):
            return np.full(len(obs.measured), np.nan)
        d, _ = cKDTree(uv[ok]).query(obs.measured)
        return d
    T_ts = invert(T_st)
    return surface.distance(obs.measured @ T_ts[:3, :3].T + T_ts[:3, 3])
