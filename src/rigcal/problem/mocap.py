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
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from rigcal.dataset import SensorKind
from rigcal.errors import ConfigError, ConvergenceError, InputError, RigcalError
from rigcal.geometry.se3 import invert
from rigcal.geometry.so3 import so3_log
from rigcal.problem.numerics import single_threaded
from rigcal.problem.residuals import MODEL_CAMERA, MODEL_POINT, MODEL_SURFACE
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

    def __post_init__(self) -> None:
        T = np.array(self.T_robot_target, dtype=float)
        m = np.array(self.measured, dtype=float)
        if T.shape != (4, 4):
            raise InputError(f"observation of '{self.target}' by '{self.sensor}': T_robot_target must be 4x4")
        if m.ndim != 2 or m.shape[1] not in (2, 3) or m.shape[0] == 0:
            raise InputError(
                f"observation of '{self.target}' by '{self.sensor}' at {self.t_ns}: measured must be "
                f"(n, 3) points or (n, 2) pixels with n >= 1, got {m.shape}"
            )
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
    #: the uncertainty assumes (a few holds cannot show a small one): a Vicon-class system
    #: tracks a still 0.5 m body to about 0.5 mrad and 0.25 mm from hold to hold
    hold_sigma_floor: tuple[float, float] = (0.0005, 0.00025)

    def __post_init__(self) -> None:
        if self.correspondences not in CORRESPONDENCES:
            raise ConfigError(f"mocap options: correspondences must be one of {CORRESPONDENCES}, "
                              f"got {self.correspondences!r}")
        if not int(self.max_correspondence_iterations) >= 1:
            raise ConfigError("mocap options: max_correspondence_iterations must be >= 1")
        floor = tuple(float(v) for v in self.hold_sigma_floor)
        if len(floor) != 2 or not all(np.isfinite(v) and v >= 0 for v in floor):
            raise ConfigError("mocap options: hold_sigma_floor must be (rotation_rad, translation_m) >= 0")
        object.__setattr__(self, "hold_sigma_floor", floor)


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


def _target_blocks(observations, options) -> list[int]:
    """Index of the target pose block of every observation (shared when several sensors see one
    target at the same time and target poses are estimated)."""
    if options.target_pose_sigma is None:
        return list(range(len(observations)))
    order = sorted(range(len(observations)), key=lambda i: (observations[i].target, observations[i].t_ns))
    out = [0] * len(observations)
    current, last = -1, None
    for i in order:
        o = observations[i]
        if last is None or o.target != last.target or o.t_ns - last.t_ns > options.sync_tolerance_ns:
            current += 1
            last = o
        out[i] = current
    return out


def _add(items, key, block, board, points, measured, normals=None) -> None:
    if len(points) == 0:
        return
    d = items.setdefault(key, {"frame": [], "points": [], "measured": [], "board": [], "normals": []})
    d["frame"] += [block] * len(points)
    d["points"].append(points)
    d["measured"].append(measured)
    d["board"].append(np.full(len(points), board))
    if normals is not None:
        d["normals"].append(normals)


def _build(sensors, observations, poses, surfaces, options, boards=None, block_poses=None, phase="centroid"):
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
        if k not in made:
            made[k] = block
            start = block_poses.get(block, o.T_robot_target) if block_poses else o.T_robot_target
            blocks.append(PoseBlock(block, start, (free,) * 6))
            if free:
                prior_blocks.append(block)
                prior_T.append(o.T_robot_target)
        sensor = names[o.sensor]
        normals = None
        model = MODEL_CAMERA if sensor.kind == SensorKind.CAMERA else MODEL_POINT
        if o.keypoints_target is not None:
            pts, meas = o.keypoints_target, o.measured
        elif phase == "surface" and sensor.kind == SensorKind.LIDAR:
            T_R_T = block_poses.get(block, o.T_robot_target) if block_poses else o.T_robot_target
            pts, normals, keep = _closest_on_surface(o, sensor, poses[o.sensor], T_R_T, surfaces[o.target], options)
            meas, model = o.measured[keep], MODEL_SURFACE
        else:
            pts, keep = _correspond(o, sensor, poses[o.sensor], surfaces[o.target].template, options)
            if pts is None:
                continue
            meas = o.measured[keep]
        # a surface batch per target: its closest points follow the poses inside the solve
        part = "surface" if model == MODEL_SURFACE else ""
        _add(items, (o.sensor, model, o.target if part else "", part), block, i, pts, meas, normals)
    batches = []
    for (name, model, target, part), d in items.items():
        s = names[name]
        meas = np.concatenate(d["measured"])
        surface = model == MODEL_SURFACE
        sigma = np.full((len(meas), 1 if surface else meas.shape[1]), s.sigma)
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
                surface=surfaces[target] if surface else None,
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

    @property
    def match_fraction(self) -> float:
        total = sum(t for _, t in self.matches.values())
        return sum(w for w, _ in self.matches.values()) / total if total else float("nan")


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapFit:
    """:func:`calibrate_mocap_fit`'s value: the calibration and per-sensor fit statistics."""

    result: CalibrationResult
    sensors: Mapping[str, MocapSensorFit]


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


def _hold_moments(Js, r, obs_of_row, hold_of_row, Ads, C):
    """Within-hold noise and the between-hold error's moment equation of one sensor (its rows).

    ``Js`` (n, 6): the residuals' Jacobian w.r.t. the sensor's pose; ``r`` (n,): the whitened
    residuals; ``Ads[i]``: the adjoint of ``T_sensor_target`` of observation i (a right
    perturbation ``delta`` of the target's pose moves the residuals by ``-Js Ad delta``);
    ``C = (Js' Js)^-1``. Every hold g has its own error ``delta_g`` of the target's pose shared
    by its frames (the MCS error of the still target, the extractor's view of it), with
    ``cov(delta_g) = lam * diag(I3 / HOLD_BASELINE_M^2, I3)``.

    Returns ``(sigma_w^2, [M_g], data)``: the within-hold variance (the residuals left after
    fitting every hold's own ``delta_g``), ``M_g = Js_g' Jd_g`` per hold (the sandwich's
    pieces), and ``(z, A0, K)``: the residuals in the holds' pose directions (after the
    sensor's own fit) with ``cov(z) = sigma_w^2 A0 + lam K`` - None with fewer than two holds."""
    holds = sorted(set(hold_of_row))
    Jd = np.zeros_like(Js)
    for i in set(obs_of_row):
        rows = obs_of_row == i
        Jd[rows] = -Js[rows] @ Ads[i]
    Dh = np.sqrt(np.r_[np.full(3, 1.0 / HOLD_BASELINE_M ** 2), np.ones(3)])
    n = len(r)
    projs, Ms, within_sq, within_dof, q, a, bases = [], [], 0.0, 0, 0.0, 0.0, []
    for g in holds:
        rows = hold_of_row == g
        Jg = Jd[rows]
        G = Jg.T @ Jg
        pinv = np.linalg.pinv(G, rcond=1e-9)
        rank = int(np.linalg.matrix_rank(G, tol=1e-9 * max(float(np.abs(G).max()), 1e-300)))
        fitted = Jg @ (pinv @ (Jg.T @ r[rows]))
        U, sv, _ = np.linalg.svd(Jg, full_matrices=False)
        basis = np.zeros((n, rank))
        basis[rows] = U[:, :rank]
        bases.append(basis)
        within_sq += float(np.sum((r[rows] - fitted) ** 2))
        within_dof += int(np.sum(rows)) - rank
        q += float(np.sum(fitted ** 2))
        Asg = Js[rows].T @ Js[rows]
        a += rank - float(np.trace(C @ Asg))
        projs.append((rows, Jg, pinv))
        Ms.append(Js[rows].T @ Jg)
    s2w = within_sq / within_dof if within_dof > 0 else float(np.sum(r * r)) / max(n - 6, 1)
    if len(holds) < 2:
        return s2w, Ms, None
    b = 0.0
    for g in holds:  # the hold error of hold g, residualised, seen in every hold's projector
        X = Jd * (hold_of_row == g)[:, None] * Dh[None, :]
        X = X - Js @ (C @ (Js.T @ X))
        for rows, Jg, pinv in projs:
            Y = Jg @ (pinv @ (Jg.T @ X[rows]))
            b += float(np.sum(Y ** 2))
    E = np.hstack(bases)
    F = E - Js @ (C @ (Js.T @ E))  # (I - H) E: the residuals seen in the holds' pose directions
    A0 = F.T @ F
    w, V = np.linalg.eigh(0.5 * (A0 + A0.T))
    keep = w > 1e-9 * max(float(w.max()), 1e-300)
    V = V[:, keep]
    z = V.T @ (F.T @ r)
    K = np.zeros((V.shape[1], V.shape[1]))
    for g in holds:
        X = V.T @ (F.T @ (Jd * (hold_of_row == g)[:, None] * Dh[None, :]))
        K += X @ X.T
    return s2w, Ms, (z, V.T @ A0 @ V, K)


def _fit_statistics(prob: Problem, sol, sensors, observations, holds, options: MocapOptions):
    """Per-sensor noise (within-hold variance component) and hold errors at the solution:
    returns (reduced chi2 per sensor, hold inflation per sensor, hold sigmas per sensor, joint
    covariance function)."""
    from rigcal.geometry.se3 import adjoint
    from rigcal.problem.solver import _evaluate, prepare

    layout = prepare(prob)
    T = np.stack([sol.poses[p.name] for p in prob.poses])
    r, J, _, _ = _evaluate(prob, layout, T, "linear", 1.0, True)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    m_obs = layout.m_obs
    row_obs, row_sensor = [], []
    for b in prob.observations:
        ours = b.label.startswith(ROBOT)
        row_obs.append(np.repeat(np.where(ours, b.board, -1), b.dim))
        row_sensor += [b.sensor if ours else None] * (b.size * b.dim)
    row_obs = np.concatenate(row_obs + [np.full(len(r) - m_obs, -1)])
    row_sensor = np.array(row_sensor + [None] * (len(r) - m_obs), dtype=object)
    scale, infl, hold_sigma, blocks, stats, determined = {}, {}, {}, {}, {}, {}
    for s in sensors:
        rows = row_sensor == s.name
        cols = layout.cols[layout.index[s.name]]
        cols = cols[cols >= 0]
        Js, rs = J[np.ix_(rows, cols)], r[rows]
        obs_rows = row_obs[rows]
        hold_rows = np.array([holds[i] for i in obs_rows], dtype=object)
        Ads = {int(i): adjoint(invert(sol.poses[s.name]) @ observations[int(i)].T_robot_target)
               for i in set(obs_rows.tolist())}
        A = Js.T @ Js
        wA = np.linalg.eigvalsh(0.5 * (A + A.T)) if A.size else np.zeros(1)
        determined[s.name] = bool(np.all(np.isfinite(wA)) and wA.max() > 0 and wA.min() > 1e-12 * wA.max())
        Cs = np.linalg.pinv(A, rcond=1e-12)
        s2w, Ms, eq = _hold_moments(Js, rs, obs_rows, hold_rows, Ads, Cs)
        scale[s.name] = s2w if s2w > 0 else 1.0
        stats[s.name] = (cols, A, Cs, None, Ms, eq, len(set(obs_rows.tolist())))
    # the per-hold error's variance lam by maximum likelihood from the sensor's residuals in its
    # holds' pose directions, at least the MCS's own accuracy (options.hold_sigma_floor)
    from scipy.optimize import minimize_scalar
    from scipy.stats import chi2, f as f_dist

    def ml(data) -> tuple[float, float]:
        """(lam, Fisher information) by maximum likelihood from ``[((z, A0, K), s2)]``."""
        if not data:
            return 0.0, 0.0

        def nll(lam: float) -> float:
            out = 0.0
            for (z, A0, K), s2 in data:
                S = s2 * A0 + lam * K
                sign, logdet = np.linalg.slogdet(S)
                out += 0.5 * (logdet + float(z @ np.linalg.solve(S, z))) if sign > 0 else np.inf
            return out

        scale_k = sum(np.trace(K) for (_, _, K), _ in data)
        hi = max(float(sum(z @ z for (z, _, _), _ in data) / max(scale_k, 1e-300)), 1e-18)
        res = minimize_scalar(lambda t: nll(np.exp(t)), bounds=(np.log(hi) - 30, np.log(hi) + 5),
                              method="bounded")
        lam = float(np.exp(res.x)) if res.fun < nll(0.0) else 0.0
        info = 0.0
        for (z, A0, K), s2 in data:
            SK = np.linalg.solve(s2 * A0 + lam * K, K)
            info += 0.5 * float(np.sum(SK * SK.T))
        return lam, info

    floor_r, floor_t = options.hold_sigma_floor
    lam_floor = max(floor_t ** 2, (floor_r * HOLD_BASELINE_M) ** 2)
    # every sensor its own per-hold error: the MCS's and its extraction's (a camera's corners
    # err alike in every frame of one view), estimated from its own holds
    chosen = {}
    for n in stats:
        lam, info = ml([(stats[n][5], scale[n])] if stats[n][5] is not None else [])
        if lam <= lam_floor:
            chosen[n] = (lam_floor, 1.0)  # a known least value, not an estimate: no widening
            continue
        # estimated from few holds (nu degrees of freedom, from its Fisher information): the
        # hold part widened so that a 6-DOF region holds the truth as often as it says
        nu = 2.0 * lam ** 2 * info
        small = float(6.0 * f_dist.ppf(0.95, 6, nu) / chi2.ppf(0.95, 6)) if 0.5 < nu < 1e6 else 1.0
        chosen[n] = (lam, small)
    for s in sensors:
        cols, A, Cs, _, Ms, eq, n_obs = stats[s.name]
        tt2, small = chosen[s.name]
        tr2 = tt2 / HOLD_BASELINE_M ** 2
        naive = scale[s.name] * Cs
        Psi = np.diag([tr2] * 3 + [tt2] * 3)
        # one hold: nothing to estimate its error from, and its frames may be copies of each
        # other (counted as one)
        copies = 1.0 if eq is not None else max(1.0, float(n_obs))
        meat = copies * scale[s.name] * A + small * sum(M @ Psi @ M.T for M in Ms)
        cov = Cs @ meat @ Cs
        w_, V_ = np.linalg.eigh(0.5 * (cov + cov.T))
        cov = (V_ * np.clip(w_, 0.0, None)) @ V_.T  # rounding leaves tiny negative ones
        infl[s.name] = float(np.trace(cov) / np.trace(naive)) if np.trace(naive) > 0 else 1.0
        hold_sigma[s.name] = (float(np.sqrt(tr2)), float(np.sqrt(tt2)))
        blocks[s.name] = (cols, cov, naive)
    # the joint covariance: the full one with every sensor's rows weighted by its own noise,
    # each sensor's block replaced by its hold-aware one and cross terms scaled alike
    w = np.ones(len(r))
    for s in sensors:
        w[row_sensor == s.name] = 1.0 / np.sqrt(scale[s.name])
    Jw = J * w[:, None]
    C = np.linalg.pinv(Jw.T @ Jw, rcond=1e-12)
    D = np.ones(C.shape[0])
    for name, (cols, cov, naive) in blocks.items():
        D[cols] = np.sqrt(max(infl[name], 1.0))
    C = D[:, None] * C * D[None, :]
    for name, (cols, cov, naive) in blocks.items():
        C[np.ix_(cols, cols)] = cov

    def joint(names):
        cols = np.concatenate([layout.cols[layout.index[n]] for n in names])
        out = np.zeros((len(cols), len(cols)))
        idx = np.flatnonzero(cols >= 0)
        if idx.size:
            c = cols[idx]
            out[np.ix_(idx, idx)] = C[np.ix_(c, c)]
        return out

    return scale, infl, hold_sigma, joint, determined


def _matches(prob: Problem, sol, sensors, observations, scale) -> dict[str, dict[str, tuple[int, int]]]:
    out: dict[str, dict[str, list[int]]] = {s.name: {} for s in sensors}
    for b, raw in zip(prob.observations, sol.residuals):
        if not b.label.startswith(ROBOT):
            continue
        lim = 3.0 * np.sqrt(b.dim)  # residuals whitened by the configured sigma
        e = np.linalg.norm(raw, axis=1)
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
    with single_threaded():
        block_poses: dict[str, np.ndarray] = {}
        while True:
            it += 1
            phase_it += 1
            prob = _build(sensors, observations, poses, surfaces, options, boards, block_poses, phase)
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
            if settled:
                break
            if phase_it >= options.max_correspondence_iterations:
                raise ConvergenceError(
                    f"mocap calibration: {phase} correspondences still changing after "
                    f"{options.max_correspondence_iterations} iterations"
                )
    assert sol is not None
    holds = hold_labels(observations)
    coupled = options.target_pose_sigma is not None or boards is not None
    with single_threaded():
        scale, infl, hsig, joint, determined = _fit_statistics(prob, sol, sensors, observations, holds, options)
        if coupled or any(abs(np.log(v)) > np.log(4.0) for v in scale.values()):
            # every sensor weighted by its own noise (and the robust loss's scale with it)
            factor = {n: float(np.sqrt(v)) for n, v in scale.items()}
            prob = prob.with_observations(tuple(
                b.with_sigma(b.sigma * factor[b.sensor]) if b.label.startswith(ROBOT) else b
                for b in prob.observations))
            sol2 = solve(prob, loss=options.loss, loss_scale=options.loss_scale, start=sol.poses)
            if sol2.converged:
                sol = sol2
                poses = {s.name: sol.poses[s.name] for s in sensors}
            s2, infl, hsig, joint, determined = _fit_statistics(prob, sol, sensors, observations, holds, options)
            scale = {n: scale[n] * s2[n] for n in scale}
            prob = prob.with_observations(tuple(
                b.with_sigma(b.sigma / factor[b.sensor]) if b.label.startswith(ROBOT) else b
                for b in prob.observations))
    for s in sensors:
        if s.kind == SensorKind.CAMERA:
            own = [o for o in observations if o.sensor == s.name]
            valid = _valid_fraction(s, own, poses[s.name])
            if valid < MIN_VALID_PROJECTION:
                raise ConvergenceError(
                    f"camera '{s.name}': only {100 * valid:.0f} % of its target points project into "
                    f"the image under the estimate: its pose is not determined by its measurements",
                    sensor=s.name)
    estimates, rmse, reproj, fits, noise = {}, {}, {}, {}, {}
    errors: dict[str, list[np.ndarray]] = {s.name: [] for s in sensors}
    for b, r in zip(prob.observations, sol.residuals):
        if b.label.startswith(ROBOT):
            errors[b.sensor].append(np.linalg.norm(r * b.sigma, axis=1))
    matches = _matches(prob, sol, sensors, observations, scale)
    for s in sensors:
        cov = joint([s.name])
        if not determined[s.name] or not np.all(np.isfinite(cov)):
            raise ConvergenceError(
                f"sensor '{s.name}': its measurements do not determine its pose (their information "
                f"matrix is singular: too few measured points, or none that depend on the pose); "
                f"no estimate is returned", sensor=s.name)
        estimates[s.name] = SensorEstimate(
            name=s.name, kind=s.kind, frame_id=s.frame_id, T_reference_sensor=poses[s.name].copy(),
            covariance=cov, std=pose_std(poses[s.name], cov),
        )
        e = np.concatenate(errors[s.name]) if errors[s.name] else np.full(1, np.nan)
        value = float(np.sqrt(np.mean(e**2)))
        (reproj if s.kind == SensorKind.CAMERA else rmse)[f"{ROBOT}-{s.name}"] = value
        sigma = float(s.sigma * np.sqrt(scale[s.name]))
        if s.kind == SensorKind.LIDAR:
            noise[s.name] = (sigma,)
        fits[s.name] = MocapSensorFit(
            name=s.name, kind=s.kind, unit="px" if s.kind == SensorKind.CAMERA else "m",
            sigma_nominal=float(s.sigma), noise_sigma=sigma, reduced_chi2=float(scale[s.name]),
            hold_inflation=float(infl[s.name]), hold_sigma=hsig[s.name],
            holds=len({h for h, o in zip(holds, observations) if o.sensor == s.name}),
            observations=sum(1 for o in observations if o.sensor == s.name),
            residuals=int(sum(len(x) for x in errors[s.name])),
            matches=matches.get(s.name, {}), covariance_naive=sol.pose_covariance(s.name),
            start=starts[s.name],
        )
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
        num_boards=len(observations),
        noise_sigma_m=noise,
        noise_iterations=it,
        solve_time_s=time.perf_counter() - t0,
        reprojection_px=reproj,
        relative=relative_estimates([s.name for s in sensors], poses, joint),
    )
    return MocapFit(result=result, sensors=fits)
