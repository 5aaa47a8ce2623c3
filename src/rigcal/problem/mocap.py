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
from threadpoolctl import threadpool_limits

from rigcal.dataset import SensorKind
from rigcal.errors import ConfigError, ConvergenceError, InputError
from rigcal.geometry.se3 import invert
from rigcal.geometry.so3 import so3_log
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

    def __post_init__(self) -> None:
        if self.correspondences not in CORRESPONDENCES:
            raise ConfigError(f"mocap options: correspondences must be one of {CORRESPONDENCES}, "
                              f"got {self.correspondences!r}")
        if not int(self.max_correspondence_iterations) >= 1:
            raise ConfigError("mocap options: max_correspondence_iterations must be >= 1")


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


def calibrate_mocap(
    sensors: Sequence[MocapSensor],
    observations: Sequence[TargetObservation],
    initial: Mapping[str, np.ndarray],
    templates: Mapping[str, np.ndarray | TargetSurface] | None = None,
    options: MocapOptions = MocapOptions(),
    boards=None,
) -> CalibrationResult:
    """``T_robot_sensor`` for every sensor from MCS-tracked target observations.

    ``initial``: ``T_robot_sensor`` guesses (e.g. CAD or TF). ``templates``: target name ->
    its :class:`~rigcal.targets.surface.TargetSurface` (``TargetSurface.of(target)``: analytic
    when it can be) or (K, 3) template points in the target frame, for observations without
    correspondences. ``options.correspondences`` chooses how those are matched.
    ``boards``: an optional :class:`rigcal.dataset.Dataset` of circle-board placements seen by
    these sensors (same names): their pairwise terms join the problem (Domhof et al.).
    Raises ConvergenceError when the correspondence iterations do not settle.
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
    kinds = {s.name: s.kind for s in sensors}
    needs_iterations = any(o.keypoints_target is None for o in observations)
    # the surface phase applies to lidar measurements without keypoints
    handover = options.correspondences == "surface" and any(
        o.keypoints_target is None and kinds[o.sensor] == SensorKind.LIDAR for o in observations)
    phase, phase_it, it = "centroid", 0, 0
    sol = None
    with threadpool_limits(limits=1):
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
    estimates, rmse, reproj = {}, {}, {}
    errors: dict[str, list[np.ndarray]] = {s.name: [] for s in sensors}
    for b, r in zip(prob.observations, sol.residuals):
        if b.label.startswith(ROBOT):
            errors[b.sensor].append(np.linalg.norm(r * b.sigma, axis=1))
    for s in sensors:
        cov = sol.pose_covariance(s.name)
        estimates[s.name] = SensorEstimate(
            name=s.name, kind=s.kind, frame_id=s.frame_id, T_reference_sensor=poses[s.name].copy(),
            covariance=cov, std=pose_std(poses[s.name], cov),
        )
        e = np.concatenate(errors[s.name]) if errors[s.name] else np.full(1, np.nan)
        value = float(np.sqrt(np.mean(e**2)))
        (reproj if s.kind == SensorKind.CAMERA else rmse)[f"{ROBOT}-{s.name}"] = value
    return CalibrationResult(
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
        noise_iterations=it,
        solve_time_s=time.perf_counter() - t0,
        reprojection_px=reproj,
        relative=relative_estimates([s.name for s in sensors], poses, sol.joint_covariance),
    )
