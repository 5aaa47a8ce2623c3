"""End-to-end relative calibration: initialise, find outliers, solve a configuration,
estimate noise (PSE), propagate uncertainty, evaluate. Returns a :class:`CalibrationResult`."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import ConfigError, ConvergenceError, RigcalError
from rigcal.problem.consistency import NOTE, Check, noise_check, pair_checks, verdict
from rigcal.geometry.se3 import adjoint, invert, se3_exp, se3_log
from rigcal.problem.configurations import (
    MODES,
    RADAR_PLANE_FREE,
    board_block,
    build_pairwise,
    build_pse,
    initial_board_poses,
    keep_poses,
    pairs_for_mode,
)
from rigcal.problem.evaluate import anchor_errors, evaluate_pairs
from rigcal.problem.fixedpoint import Anderson
from rigcal.problem.globalise import solve_global
from rigcal.problem.initialise import default_reference, initial_poses
from rigcal.problem.observability import check_observable
from rigcal.problem.outliers import OutlierRule, find_outliers
from rigcal.problem.pairs import all_pairs, pair_data
from rigcal.problem.priors import HOLD_RADAR_PLANE, SensorPrior, merge_priors
from rigcal.problem.result import BoundedSet, CalibrationResult, SensorEstimate
from rigcal.problem.numerics import scale_rows, single_threaded
from rigcal.stages import StageClock
from rigcal.problem.noise import (
    DetectionUnits,
    detection_units,
    estimate_theta,
    group_design,
    noise_map,
    row_batches,
    sandwich,
    theta_by_sensor,
)
from rigcal.problem.solver import (
    DOF_NAMES,
    PoseBlock,
    Problem,
    Solution,
    combine_solutions,
    linearise,
    merge_independent,
    prepare,
    solve,
)
from rigcal.problem.uncertainty import (
    BOUNDED_RADAR_DIRECTIONS,
    fov_bounds,
    fov_bounds_joint,
    fov_polytope,
    geometry_warnings,
    pose_std,
    relative_estimates,
    sensor_bounded_values,
    weak_directions,
)

log = logging.getLogger(__name__)

#: Cauchy scale [m] of the robust screening solve
ROBUST_SCALE_M = 0.05
#: PSE noise models: re-estimated per sensor and axis, or fixed at 1 (the original tool's)
PSE_NOISE = ("iterated", "identity")
#: PSE noise floor [m]: no sensor is assumed better than this
NOISE_FLOOR_M = 1e-4
#: PSE: pseudo-redundancy of the current noise value in each update; an axis with less summed
#: redundancy than this is reported as held (its noise is not estimable)
MIN_REDUNDANCY = 0.5
#: PSE: noise updates after one Gauss-Newton step each before every update gets a full solve
ONE_STEP_NOISE_ITERATIONS = 30


@dataclass(frozen=True)
class CalibrationOptions:
    """How to calibrate.

    mode: ``mcpe``, ``fcpe`` or ``pse``. reference: sensor whose frame is the common frame
    (default: the dataset's, else the first lidar). detect_outliers: find and exclude bad
    detections by consensus. hold_radar_plane: hold every 2D radar's z, roll and pitch at the
    initial guess (the prior ``{z_m: 0, roll_deg: 0, pitch_deg: 0}``). initial: optional
    ``T_reference_sensor`` guesses (else Kabsch) - also the nominal mounting that priors are
    around. prior: tolerances (:mod:`rigcal.problem.priors`) for every sensor without its own
    (``SensorDetections.prior``, the manifest's); priors: per sensor, above both.
    cross_validation_folds: k-fold leave-boards-out RMSE (0 = skip).
    """

    mode: str = "fcpe"
    reference: str | None = None
    detect_outliers: bool = True
    hold_radar_plane: bool = False
    initial: Mapping[str, np.ndarray] | None = None
    cross_validation_folds: int = 0
    max_noise_iterations: int = 100
    noise_tolerance: float = 1e-3
    outlier_rule: OutlierRule = field(default_factory=OutlierRule)
    seed: int = 0
    #: PSE noise: ``iterated`` (per-sensor, per-axis, re-estimated until converged) or
    #: ``identity`` (1 for every axis of every sensor: the original tool's fixed-noise PSE)
    pse_noise: str = "iterated"
    #: mounting tolerances for every sensor without its own prior (``{"z_m": 0.01, ...}``)
    prior: Mapping[str, float] | None = None
    #: mounting tolerances per sensor (above the manifest's and ``prior``)
    priors: Mapping[str, Mapping[str, float]] | None = None


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class _Fit:
    poses: dict[str, np.ndarray]
    problem: Problem
    solution: Solution
    noise: dict[str, tuple[float, ...]]
    noise_iterations: int
    board_poses: dict[int, np.ndarray]
    #: per observation batch (label), the noise scale the priors were weighted against (the
    #: batch's residual rows carry ``prior_scale`` times the whitened noise of a prior); 1: none
    prior_scale: Mapping[str, float] = field(default_factory=dict)


def _check(dataset: Dataset, options: CalibrationOptions) -> str:
    mode = str(options.mode).lower()
    if mode not in MODES:
        raise ConfigError(f"unknown mode '{options.mode}' (expected one of: {', '.join(MODES)})")
    reference = options.reference or default_reference(dataset)
    if reference not in dataset.names:
        raise ConfigError(
            f"reference sensor '{reference}' is not in the rig (sensors: {', '.join(dataset.names)})"
        )
    if mode == "pse" and dataset.sensor(reference).kind == SensorKind.RADAR:
        raise ConfigError("PSE needs a 3D reference sensor (lidar, camera or 3D radar), not a 2D radar")
    if mode == "pse" and not any(s.kind.is_point_cloud for s in dataset.sensors):
        raise ConfigError("PSE needs a lidar or camera (the board poses come from their circle centres); "
                          f"this rig has only radars ({', '.join(dataset.names)}): use FCPE or MCPE")
    if options.pse_noise not in PSE_NOISE:
        raise ConfigError(
            f"unknown PSE noise '{options.pse_noise}' (expected one of: {', '.join(PSE_NOISE)})"
        )
    if options.cross_validation_folds < 0 or options.cross_validation_folds == 1:
        raise ConfigError("cross_validation_folds must be 0 (off) or at least 2")
    priors = sensor_priors(dataset, reference, options)
    if _radar_reference(dataset, mode, reference) and any(p.soft for p in priors.values()):
        raise ConfigError(
            f"MCPE with the 2D radar '{reference}' as reference holds the other sensors' height, roll "
            "and pitch relative to it at the automatic guess: mounting priors are not used there; "
            "calibrate with FCPE or PSE, or a 3D reference"
        )
    return reference


def nominal_poses(options: CalibrationOptions, reference: str) -> dict[str, np.ndarray]:
    """``options.initial`` as ``T_reference_sensor`` in this run's reference frame (a file whose
    poses are relative to another frame is re-expressed when it holds the reference's pose)."""
    given = {k: np.asarray(v, dtype=float) for k, v in (options.initial or {}).items()}
    if reference in given:
        T_inv = invert(given[reference])
        given = {k: T_inv @ v for k, v in given.items()}
        given[reference] = np.eye(4)
    return given


def sensor_priors(dataset: Dataset, reference: str, options: CalibrationOptions) -> dict[str, SensorPrior]:
    """Every sensor's mounting prior (:func:`rigcal.problem.priors.merge_priors`) around its
    nominal pose from ``options.initial``; ``hold_radar_plane`` holds every 2D radar's z, roll
    and pitch (at the nominal pose, else at the automatic initial guess). ConfigError for a
    prior without a nominal pose."""
    held = {
        s.name: HOLD_RADAR_PLANE for s in dataset.sensors if s.kind == SensorKind.RADAR
    } if options.hold_radar_plane else None
    manifest = {s.name: s.prior for s in dataset.sensors if s.prior}
    tolerances = merge_priors(dataset.names, reference, manifest, options.prior, options.priors, held)
    nominal = nominal_poses(options, reference)
    out = {}
    for name, tol in tolerances.items():
        T = nominal.get(name)
        own = {k: v for k, v in tol.items() if not (held and name in held and k in held[name])}
        if T is None and own:
            raise ConfigError(
                f"sensor '{name}': a mounting prior ({', '.join(f'{k} {v:g}' for k, v in own.items())}) "
                f"needs its nominal pose: give --initial FILE holding {name}'s pose"
            )
        out[name] = SensorPrior(name, np.eye(4) if T is None else T, tol)
    return out


def _noise_scale(sol: Solution) -> float:
    """The observations' noise scale in the problem's units (its a-posteriori std of unit
    weight), against which priors are weighted."""
    return max(math.sqrt(max(sol.sigma0_sq, 0.0)), 1e-9)


def _solve_with_priors(build, solve_from, priors: Mapping[str, SensorPrior]):
    """(problem, solution, prior scale) of a problem ``build(prior_scale)`` whose observations
    are not whitened by their noise (FCPE, MCPE, PSE with identity noise): first solved without
    the soft priors, whose residual scale then weighs them (one global scale ``s``: the
    observations' rows and a prior's ``log(T0^-1 T) / (tolerance / s)`` are then in the same
    units), then solved again with them from that solution."""
    prob = build(None)
    sol = solve_from(prob)
    if not any(p.soft and p.sensor in prob.pose_names for p in priors.values()):
        return prob, sol, 1.0
    scale = _noise_scale(sol)
    prob = build(scale)
    return prob, solve_from(prob, start=sol.poses), scale


def _fit(
    dataset: Dataset,
    mode: str,
    reference: str,
    poses0: Mapping[str, np.ndarray],
    options: CalibrationOptions,
    search: bool = True,
) -> _Fit:
    """The mode's fit from ``poses0``; ``search`` also tries the alternative radar tilts
    (:func:`solve_global`), without it one local solve (a refit from a nearby solution)."""
    solve_from = solve_global if search else solve
    # refuse, saying what is missing, when the boards cannot determine the poses
    check_observable(dataset, mode, reference, options.hold_radar_plane)
    priors = sensor_priors(dataset, reference, options)
    hold = options.hold_radar_plane
    if mode == "fcpe":
        prob, sol, scale = _solve_with_priors(
            lambda s: build_pairwise(dataset, poses0, reference, all_pairs(dataset), hold, priors, s),
            solve_from, priors,
        )
        return _Fit(dict(sol.poses), prob, sol, {}, 0, {}, {b.label: scale for b in prob.observations})
    if mode == "mcpe":
        # each sensor against the reference: independent pairwise problems (paper eq. 6)
        probs, sols, scales = [], [], {}
        for pair in pairs_for_mode(dataset, mode, reference):
            other = pair[1] if pair[0] == reference else pair[0]
            prob, sol, scale = _solve_with_priors(
                lambda s: keep_poses(build_pairwise(dataset, poses0, reference, [pair], hold, priors, s),
                                     (reference, other)),
                solve_from, priors,
            )
            probs.append(prob)
            sols.append(sol)
            scales.update({b.label: scale for b in prob.observations})
        prob, sol = merge_independent(probs, sols)
        return _Fit(dict(sol.poses), prob, sol, {}, 0, {}, scales)
    # PSE with iterated diagonal noise: one Gauss-Newton step, then a variance-component update,
    # until the noise model stops changing; then a full solve, and a last check of the noise
    poses = {k: np.asarray(v) for k, v in poses0.items()}
    boards = initial_board_poses(dataset, poses)
    sigmas = {s.name: np.ones(2 if s.kind == SensorKind.RADAR else 3) for s in dataset.sensors}
    if options.pse_noise == "identity":
        # the noise stays 1 m: weigh the priors against the residuals' scale, as FCPE does
        prob, sol, scale = _solve_with_priors(
            lambda s: build_pse(dataset, poses, boards, reference, sigmas, hold, priors, s), solve_from, priors,
        )
        if not sol.converged:
            raise ConvergenceError(f"PSE did not converge: {sol.status}")
        boards = {k: sol.poses[board_block(k)] for k in boards}
        return _Fit({s: sol.poses[s] for s in dataset.names}, prob.with_poses(sol.poses), sol, {}, 0, boards,
                    {b.label: scale for b in prob.observations})
    # the observations are whitened by the iterated noise: the priors by their own tolerances
    prob = build_pse(dataset, poses, boards, reference, sigmas, hold, priors, 1.0)
    layout = prepare(prob)

    held: dict[str, np.ndarray] = {}  # per sensor: axes whose noise the data cannot estimate

    def vce(problem: Problem, sol: Solution) -> tuple[dict[str, np.ndarray], float]:
        # variance component estimation: sigma^2 = sum(residual^2) / sum(redundancy) per sensor
        # axis; unlike the plain mean square it does not collapse when board poses absorb noise.
        # An axis with (almost) no redundancy has no residual to estimate from: it is held.
        sq: dict[str, np.ndarray] = {}
        red_sum: dict[str, np.ndarray] = {}
        for batch, r, red in zip(problem.observations, sol.residuals, sol.redundancy):
            metric = r * batch.sigma  # back to metres
            sq[batch.sensor] = sq.get(batch.sensor, 0.0) + np.sum(metric**2, axis=0)
            red_sum[batch.sensor] = red_sum.get(batch.sensor, 0.0) + np.sum(red, axis=0)
        new = {}
        for name, total in sq.items():
            # the current value counts as MIN_REDUNDANCY pseudo-observations: the same fixed
            # point (var = sum r^2 / redundancy), but an axis without redundancy (both ~0)
            # keeps its value instead of collapsing to the floor - continuously, no switch
            red = red_sum[name]
            var = (total + MIN_REDUNDANCY * sigmas[name] ** 2) / (red + MIN_REDUNDANCY)
            new[name] = np.maximum(np.sqrt(var), NOISE_FLOOR_M)
            held[name] = red < MIN_REDUNDANCY
        change = max(float(np.max(np.abs(new[s] / sigmas[s] - 1.0))) for s in new)
        return new, change

    def damped(new: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], bool]:
        # the fixed point iteration on log sigma oscillates when a sensor has little redundancy
        # (a contraction ratio near -1): halve the step of a component each time its update
        # changes sign, let it grow back while the updates keep their direction. Returns the
        # damped noise and whether it is pinned: every update flips and the damped steps are
        # negligible - the noise sits where the update jumps (an elevation limit switching
        # between binding and free changes the residuals and redundancy discontinuously)
        out, moved, pinned = {}, 0.0, True
        for name, v in new.items():
            step = np.log(v) - np.log(sigmas[name])
            w = weight.setdefault(name, np.ones_like(step))
            last = last_step.get(name)
            if last is not None:
                flip = step * last < 0.0
                w[:] = np.where(flip, 0.5 * w, np.minimum(1.0, 1.5 * w))
            last_step[name] = step
            big = np.abs(step) >= options.noise_tolerance
            pinned = pinned and bool(np.all(w[big] <= 1.0 / 64.0))
            moved = max(moved, float(np.max(np.abs(w * step))))
            out[name] = np.maximum(sigmas[name] * np.exp(w * step), NOISE_FLOOR_M)
        return out, pinned and moved < 0.1 * options.noise_tolerance

    anderson = Anderson()
    notes: list[str] = []
    weight: dict[str, np.ndarray] = {}
    last_step: dict[str, np.ndarray] = {}
    converged_noise = False
    pinned = False
    it = 0
    # first a full solve with identity noise (the paper's starting point) so the poses are
    # converged before the one-step noise updates begin
    sol = solve_from(prob, layout=layout)
    if not sol.converged:
        raise ConvergenceError(f"PSE did not converge: {sol.status}")
    history: list[dict[str, np.ndarray]] = []
    for it in range(1, options.max_noise_iterations + 1):
        # one Gauss-Newton step per noise update; if that has not settled after a while (little
        # redundancy: the poses still move with the weights), converge the poses every time
        # so the noise update is a fixed-point map of the noise alone
        full = it > ONE_STEP_NOISE_ITERATIONS
        sol = solve(
            prob, want_redundancy=True, max_iterations=200 if full else 1,
            layout=layout, warm=sol.extra.get("lm_state"), start=sol.poses,
        )
        if full and not sol.converged:
            raise ConvergenceError(f"PSE did not converge: {sol.status}")
        new, change = vce(prob, sol)
        if full:
            # a fixed-point map of the noise alone now: Anderson-accelerate it
            if change < options.noise_tolerance:
                converged_noise = True
                break
            names = sorted(new)
            x = np.concatenate([np.log(sigmas[k]) for k in names])
            x_new = anderson.step(x, np.concatenate([np.log(new[k]) for k in names]) - x)
            stuck = anderson.stuck(0.1 * options.noise_tolerance)
            if stuck:
                x_new = anderson.best
            off = 0
            for k in names:
                n = sigmas[k].size
                sigmas[k] = np.maximum(np.exp(x_new[off : off + n]), NOISE_FLOOR_M)
                off += n
            prob = prob.with_sigmas(sigmas)
            if stuck:
                sol = solve(prob, want_redundancy=True, layout=layout, start=sol.poses)
                if not sol.converged:
                    raise ConvergenceError(f"PSE did not converge: {sol.status}")
                new, change = vce(prob, sol)
                jumps = {k: np.abs(np.log(new[k] / sigmas[k])) > options.noise_tolerance for k in names}
                unsettled = ", ".join(k for k in names if np.any(jumps[k]))
                notes.append(
                    f"PSE noise of {unsettled} is not unique: the noise update jumps there "
                    "(too little redundancy - a field-of-view limit switches between binding and "
                    "free as the weights change); the estimate at the jump is used"
                )
                converged_noise = True
                break
            continue
        new, pinned = damped(new)
        if change < options.noise_tolerance or pinned:
            if not full:  # the poses had one step only: converge them, then check again
                sol = solve(prob, want_redundancy=True, layout=layout, start=sol.poses)
                if not sol.converged:
                    break
                new, change = vce(prob, sol)
                new, pinned = damped(new)
            if change < options.noise_tolerance or pinned:
                converged_noise = True
                break
            history = []
        history.append({k: np.log(v) for k, v in new.items()})
        if len(history) == 3:
            # extrapolate only components that converge monotonically (never damped): across
            # a jump of the update, extrapolation throws the iterate out
            extra = _aitken(history, new)
            new = {k: np.where(weight[k] >= 1.0, extra[k], v) for k, v in new.items()}
            history = []
        sigmas.update(new)
        prob = prob.with_sigmas(sigmas)
    if not converged_noise:
        if sol is not None and sol.status != "iteration limit reached" and not sol.converged:
            raise ConvergenceError(f"PSE did not converge: {sol.status}")
        raise ConvergenceError(
            f"PSE: the per-sensor noise estimates did not converge in {options.max_noise_iterations} "
            "iterations; try mode fcpe, or check the detections for outliers"
        )
    notes += [
        f"{name}: noise of axis {', '.join(str(i) for i in np.flatnonzero(h))} kept at "
        f"{', '.join(f'{sigmas[name][i]:.4g}' for i in np.flatnonzero(h))} m - its detections have "
        "no redundancy (nothing else measures what they measure), so the noise cannot be estimated"
        for name, h in held.items()
        if np.any(h)
    ]
    if notes:
        log.info("PSE: %s", "; ".join(notes))
        sol = replace(sol, extra={**sol.extra, "notes": tuple(notes)})
    prob = prob.with_poses(sol.poses)
    poses = {s: sol.poses[s] for s in dataset.names}
    boards = {k: sol.poses[board_block(k)] for k in boards}
    noise = {s: tuple(float(x) for x in v) for s, v in sigmas.items()}
    return _Fit(poses, prob, sol, noise, it, boards)


def _aitken(history: list[dict[str, np.ndarray]], latest: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Aitken extrapolation of a linearly converging fixed point (log noise), per component,
    only where three successive iterates move monotonically with a contraction ratio < 0.95."""
    x0, x1, x2 = history
    out = {}
    for k, v in latest.items():
        d1, d2 = x1[k] - x0[k], x2[k] - x1[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = d2 / d1
        ok = np.isfinite(ratio) & (ratio > 0) & (ratio < 0.95)
        step = np.where(ok, d2 * ratio / (1.0 - np.where(ok, ratio, 0.0)), 0.0)
        step = np.clip(step, -1.0, 1.0)  # at most a factor e per extrapolation
        out[k] = np.maximum(np.exp(x2[k] + step), NOISE_FLOOR_M)
    return out


def _robust_screen(
    dataset: Dataset, reference: str, poses0: Mapping[str, np.ndarray], options: CalibrationOptions
) -> tuple[dict[str, set[int]], dict[str, np.ndarray]]:
    """Outliers under the RANSAC initial poses; if any pair disagrees beyond the thresholds,
    refine the poses with a robust (Cauchy) solve before judging."""
    outliers = find_outliers(dataset, poses0, options.outlier_rule)
    if not outliers:
        return outliers, dict(poses0)
    # (held directions only: a prior's weight needs the noise scale, which outliers would spoil)
    prob = build_pairwise(dataset, poses0, reference, all_pairs(dataset), options.hold_radar_plane,
                          sensor_priors(dataset, reference, options), None)
    sol = solve(prob, loss="cauchy", loss_scale=ROBUST_SCALE_M)
    poses = dict(sol.poses) if sol.converged else dict(poses0)
    return find_outliers(dataset, poses, options.outlier_rule), poses


def _relative(
    dataset: Dataset, fit: _Fit, sol: Solution, units: DetectionUnits, reference: str,
    bounded: Mapping[str, Mapping[str, tuple[float, float]]],
) -> dict:
    """Every sensor pair's relative pose with its covariance, propagated from the honest joint
    covariance ``sol`` of the poses (correlations included), and the quantities a bounded
    direction moves. With a 2D radar reference (MCPE) the height, roll and pitch between two
    other sensors come from the automatic guess (a fit of their shared boards), not from the
    pairs solved: their own pair's covariance is added."""
    out = relative_estimates(dataset.names, fit.poses, sol.joint_covariance, sol.extra.get("bounded_sets", {}))
    if "radar_reference" not in sol.extra:
        return out
    for key, rel in out.items():
        a, b = rel.to, rel.frm
        if reference in (a, b) or (a, b) not in all_pairs(dataset):
            continue
        local = {n: invert(fit.poses[a]) @ fit.poses[n] for n in dataset.names}
        prob = keep_poses(build_pairwise(dataset, local, a, [(a, b)]), (a, b))
        if not prob.observations:
            continue
        pair_fit = _Fit(local, prob, solve(prob, max_iterations=0), {}, 0, {})
        C = rel.covariance + _honest_covariance(dataset, pair_fit, units)[0].pose_covariance(b)
        out[key] = replace(rel, covariance=C, std=pose_std(rel.T_to_from, C))
    return out


def _radar_reference(dataset: Dataset, mode: str, reference: str) -> bool:
    return mode == "mcpe" and dataset.sensor(reference).kind == SensorKind.RADAR


def _fit_radar_reference(
    dataset: Dataset,
    mode: str,
    reference: str,
    poses0: Mapping[str, np.ndarray],
    options: CalibrationOptions,
    covariance: bool = True,
) -> _Fit:
    """MCPE with a 2D radar as reference (paper Table III's radar rows). A 2D radar measures
    no elevation, so each pair (sensor, radar) leaves the sensor's height, roll and pitch
    relative to the radar undetermined: solved independently they drift apart within the
    field of view and the sensors disagree with each other. Here every pair is solved with the
    radar's own z, roll and pitch held at the automatic guess, which puts every reflector on
    the radar plane for every sensor alike (the sensors stay consistent with each other), and
    only its in-plane pose (x, y, yaw) free. The covariance adds, jointly for all sensors, how
    far their poses move when the radar is tilted or lifted to the extremes its field of view
    allows (the same tilt for every pair: those moves are correlated). ``covariance=False``:
    the poses alone (the same poses; no covariance, no field-of-view profile solves)."""
    check_observable(dataset, mode, reference, options.hold_radar_plane)
    radar = reference
    problems, sols, fits = {}, {}, {}
    for s in dataset.names:
        if s == radar:
            continue
        pair = tuple(sorted((s, radar), key=dataset.names.index))
        start = {n: invert(poses0[s]) @ poses0[n] for n in dataset.names}  # world: sensor s
        prob = keep_poses(build_pairwise(dataset, start, s, [pair], hold_radar_plane=True), (s, radar))
        if not prob.observations:
            raise ConfigError(f"MCPE: sensor '{s}' shares no board with the reference '{radar}'")
        sol = solve(prob)
        if not sol.converged:
            raise ConvergenceError(f"MCPE ({s}-{radar}) did not converge: {sol.status}")
        problems[s] = prob.with_poses(sol.poses)
        sols[s] = sol
        fits[s] = _Fit(dict(sol.poses), problems[s], sol, {}, 0, {})
    names = list(problems)
    poses = {radar: np.eye(4)}
    n = 6 * len(names)
    cov = np.zeros((n, n))
    for s in names:
        poses[s] = invert(sols[s].poses[radar])
    if not covariance:
        # no covariance was computed: NaN, so that nothing can use it as one
        pose_only = combine_solutions(list(sols.values()), poses=poses, covariance=np.full((n, n), np.nan),
                                      columns=_radar_reference_columns(radar, names),
                                      status="every pair converged", extra={})
        return _Fit(poses, _merged_radar_problem(dataset, radar, poses, problems), pose_only, {}, 0, {})
    units = detection_units(dataset)
    intervals, vertices = fov_bounds_joint(list(problems.values()), radar)
    moves = np.zeros((len(vertices), n))
    for j, s in enumerate(names):
        T_s_r = sols[s].poses[radar]
        # T_radar_s = (T_s_r e^xi)^-1 = T_radar_s e^(-Ad(T_s_r) xi)
        Ad = -adjoint(T_s_r)
        C_r = _honest_covariance(dataset, fits[s], units)[0].pose_covariance(radar)
        cov[6 * j : 6 * j + 6, 6 * j : 6 * j + 6] = Ad @ C_r @ Ad.T
        for v, xi in enumerate(_profile_moves(problems[s], radar, vertices)):
            moves[v, 6 * j : 6 * j + 6] = Ad @ xi
    if len(vertices):
        cov += moves.T @ moves / len(vertices) / 3.0
    sol = combine_solutions(
        list(sols.values()), poses=poses, covariance=cov, columns=_radar_reference_columns(radar, names),
        status="every pair converged", extra={"radar_reference": intervals},
    )
    return _Fit(poses, _merged_radar_problem(dataset, radar, poses, problems), sol, {}, 0, {})


def _radar_reference_columns(radar: str, names: list[str]) -> dict[str, np.ndarray]:
    columns = {radar: -np.ones(6, dtype=int)}
    columns.update({s: np.arange(6 * j, 6 * j + 6) for j, s in enumerate(names)})
    return columns


def _merged_radar_problem(dataset: Dataset, radar: str, poses, problems) -> Problem:
    # residuals depend only on relative poses: the pairs' batches hold in the radar's frame too
    return Problem(
        tuple(PoseBlock(n, poses[n], (False,) * 6 if n == radar else (True,) * 6) for n in dataset.names),
        tuple(b for p in problems.values() for b in p.observations),
        tuple(b for p in problems.values() for b in p.limits),
    )


def _theta_all_pairs(dataset: Dataset, poses: Mapping[str, np.ndarray], reference: str, units: DetectionUnits) -> np.ndarray:
    """The noise model estimated from every comparable pair's residuals at ``poses``."""
    problem = build_pairwise(dataset, poses, reference, all_pairs(dataset))
    r, J, _, _, _ = linearise(problem)
    M = group_design(noise_map(problem, dataset, units), units)
    return estimate_theta(r, M, 1.0, batches=row_batches(problem))


def _profile_moves(
    problem: Problem, radar: str, vertices: list[np.ndarray], directions: tuple[str, ...] = tuple(BOUNDED_RADAR_DIRECTIONS)
) -> list[np.ndarray]:
    """A 2D radar's pose moves (right perturbation, (6,)) when its bounded ``directions`` (of
    roll, pitch and z) are set to each extreme of ``vertices`` and its in-plane pose (x, y,
    yaw) is solved again with everything else held."""
    T0 = problem.pose(radar).T

    # only the batches that involve the radar change when it moves
    def involves(b) -> bool:
        return radar in b.observer or radar in b.frame

    held = Problem(
        tuple(replace(p, free=RADAR_PLANE_FREE if p.name == radar else (False,) * 6) for p in problem.poses),
        tuple(b for b in problem.observations if involves(b)),
    )  # no limits: the extremes are on them already; this asks only how x, y, yaw follow
    layout = prepare(held)
    moves = []
    for v in vertices:
        xi = np.zeros(6)
        xi[[BOUNDED_RADAR_DIRECTIONS[d] for d in directions]] = v
        sol = solve(held, layout=layout, start={radar: T0 @ se3_exp(xi)}, max_iterations=50)
        moves.append(se3_log(invert(T0) @ sol.poses[radar]) if sol.converged else xi)
    return moves


def _spread(moves: list[np.ndarray]) -> np.ndarray:
    """(6, 6) second moment of a 2D radar's pose over the set its field of view allows (the
    moves of :func:`_profile_moves` to its extremes), scaled to those of a uniform distribution
    over the set (a third of the extremes')."""
    if not moves:
        return np.zeros((6, 6))
    M = np.array(moves)
    return (M.T @ M) / len(moves) / 3.0


def _bounded_map(vertices: list[np.ndarray], moves: list[np.ndarray], k: int) -> np.ndarray:
    """(6, k): the pose's move per unit offset of each bounded direction, a least-squares fit
    of the re-solved moves to the extremes (the in-plane pose follows a tilt: a heading the
    azimuths measure stays put while the radar tilts)."""
    if not vertices:
        return np.eye(6)[:, :k]
    B, M = np.array(vertices).reshape(-1, k), np.array(moves).reshape(-1, 6)
    return np.linalg.lstsq(B, M, rcond=1e-9)[0].T


def _cross_validation(
    dataset: Dataset, mode: str, reference: str, poses: Mapping[str, np.ndarray], options: CalibrationOptions
) -> dict[str, float]:
    K = dataset.num_boards
    usable = [k for k in range(K) if sum(bool(s.valid[k]) for s in dataset.sensors) >= 2]
    folds = min(options.cross_validation_folds, len(usable))
    if folds < 2:
        return {}
    rng = np.random.default_rng(options.seed)
    order = rng.permutation(usable)
    sq: dict[str, list[np.ndarray]] = {}
    for f in range(folds):
        test = order[f::folds]
        train = np.setdiff1d(usable, test)
        try:
            if _radar_reference(dataset, mode, reference):
                fit = _fit_radar_reference(dataset.select_boards(train), mode, reference, poses, options,
                                           covariance=False)
            else:  # a refit from the full fit: one local solve (the full fit chose the basin)
                fit = _fit(dataset.select_boards(train), mode, reference, poses, options, search=False)
        except RigcalError as exc:
            log.info("cross-validation fold %d skipped: %s", f, exc)
            continue
        for a, b in all_pairs(dataset):
            p = pair_data(dataset, a, b, test)
            if p is None or p.num_boards == 0:
                continue
            sq.setdefault(p.label, []).append(anchor_errors(p, fit.poses) ** 2)
    return {k: float(np.sqrt(np.mean(np.concatenate(v)))) for k, v in sq.items()}


def _fit_screened(
    dataset: Dataset, mode: str, reference: str, options: CalibrationOptions, covariance: bool = True
) -> tuple[_Fit, Dataset, dict[str, set[int]]]:
    """Initial guess, outlier screening and the mode's fit: (fit, dataset without the outliers,
    outliers per sensor). Raises ConvergenceError when the fit does not converge.
    ``covariance=False``: the poses are all that is wanted (a radar-reference MCPE skips its
    covariance and profile solves; the poses are the same)."""
    poses0 = initial_poses(
        dataset, reference, robust=options.detect_outliers, given=nominal_poses(options, reference)
    )
    outliers: dict[str, set[int]] = {}
    work = dataset
    if options.detect_outliers:
        outliers, poses0 = _robust_screen(dataset, reference, poses0, options)
        work = dataset.with_excluded(outliers)
    if _radar_reference(dataset, mode, reference):
        def fit_mode(*args):
            return _fit_radar_reference(*args, covariance=covariance)
    else:
        fit_mode = _fit
    fit = fit_mode(work, mode, reference, poses0, options)
    for _ in range(3):
        if not (options.detect_outliers and fit.solution.converged):
            break
        more = find_outliers(work, fit.poses, options.outlier_rule)
        if not more:
            break
        for s, ks in more.items():
            outliers.setdefault(s, set()).update(ks)
        work = dataset.with_excluded(outliers)
        fit = fit_mode(work, mode, reference, fit.poses, options)
    sol = fit.solution
    if not sol.converged:
        raise ConvergenceError(f"{mode.upper()} did not converge: {sol.status}")
    return fit, work, outliers


def calibrate_poses(dataset: Dataset, options: CalibrationOptions = CalibrationOptions()) -> dict[str, np.ndarray]:
    """Only the poses ``T_reference_sensor`` that :func:`calibrate` would return (the same
    initial guess, outlier screening and fit), without the covariance, the consistency checks,
    warnings and cross-validation: for studies that only evaluate the poses. Raises as
    :func:`calibrate`."""
    reference = _check(dataset, options)
    with single_threaded():
        fit, _, _ = _fit_screened(dataset, options.mode.lower(), reference, options, covariance=False)
    return {s.name: np.array(fit.poses[s.name], dtype=float) for s in dataset.sensors}


def calibrate(dataset: Dataset, options: CalibrationOptions = CalibrationOptions()) -> CalibrationResult:
    """Calibrate every sensor of ``dataset`` into the reference sensor's frame.

    Raises ConfigError for bad options, InputError when sensors cannot be related, and
    ConvergenceError when the solver does not converge (never a silent result). BLAS runs on
    one thread throughout (covariance and checks included), so the result is the same to the
    last bit in any process - a Dask worker of ``calibrate --batch`` or the command line.
    """
    with single_threaded():
        return _calibrate(dataset, options)


def _calibrate(dataset: Dataset, options: CalibrationOptions) -> CalibrationResult:
    t0 = time.perf_counter()
    reference = _check(dataset, options)
    mode = options.mode.lower()
    priors = sensor_priors(dataset, reference, options)
    ignored = {s.name: tuple(sorted(s.excluded)) for s in dataset.sensors if s.excluded}
    clock = StageClock(log)
    with single_threaded():
        fit, work, outliers = _fit_screened(dataset, mode, reference, options)
        clock.lap(f"{mode.upper()} fit with outlier screening"
                  + (f" ({fit.noise_iterations} noise iterations)" if fit.noise_iterations else ""))
        rmse, per_board = evaluate_pairs(work, fit.poses)
        cv = (
            _cross_validation(work, mode, reference, fit.poses, options)
            if options.cross_validation_folds
            else {}
        )
        if options.cross_validation_folds:
            clock.lap(f"cross-validation ({options.cross_validation_folds} folds)")
    units = detection_units(work)
    if "radar_reference" in fit.solution.extra:
        sol, bounded, theta = fit.solution, {}, _theta_all_pairs(work, fit.poses, reference, units)
    else:
        sol, bounded, theta = _honest_covariance(work, fit, units, priors)
    covariances = {s.name: sol.pose_covariance(s.name) for s in dataset.sensors}
    sets = sol.extra.get("bounded_sets", {})
    stds = {name: pose_std(fit.poses[name], cov) for name, cov in covariances.items()}
    clock.lap("covariance")
    weak = {
        name: [w for w in weak_directions(std) if w.split(" ")[0] not in bounded.get(name, {})]
        for name, std in stds.items() if name != reference
    }
    warnings = _warnings(work, mode, reference, fit, options, weak, bounded)
    pair_check, board_check, _ = pair_checks(
        work, fit.poses, reference, units, theta, sol.joint_covariance, options.outlier_rule
    )
    noise_model = theta_by_sensor(units, theta)
    result_verdict = verdict(
        pair_check, board_check, sol.rank_deficient,
        {name: sensor_bounded_values(fit.poses[name], stds[name], iv, sol.extra.get("bounded_sets", {}).get(name))
         for name, iv in bounded.items()},
        weak, noise_check(work, noise_model),
    )
    clock.lap(f"consistency checks ({result_verdict.status})")
    if "radar_reference" in sol.extra:
        intervals = sol.extra["radar_reference"]
        iv = ", ".join(f"{d} offsets {lo:+.3g} .. {hi:+.3g} {'m' if d == 'z' else 'deg'}"
                       for d, (lo, hi) in intervals.items())
        text = (
            f"MCPE with the 2D radar '{reference}' as reference: it measures no elevation, so the "
            f"other sensors' height, roll and pitch relative to it are held at the automatic guess "
            f"(every reflector on the radar plane) and are bounded only by its field of view "
            f"({iv} about / along the radar's own axes, already in the reported covariance); only "
            "their in-plane pose comes from the pairs. FCPE or a 3D reference determines them "
            "from the other pairs"
        )
        warnings.append(text)
        result_verdict = replace(result_verdict, checks=result_verdict.checks + (Check("bounded", NOTE, text),))
    sensors = {}
    for s in dataset.sensors:
        cov = covariances[s.name]
        held: tuple[str, ...] = ()
        prior = priors.get(s.name)
        if s.name == reference:
            held = ("x", "y", "z", "roll", "pitch", "yaw")
        elif prior is not None:
            held = tuple(d for d in ("x", "y", "z", "roll", "pitch", "yaw") if prior.held[DOF_NAMES.index(d)])
        sensors[s.name] = SensorEstimate(
            name=s.name,
            kind=s.kind,
            frame_id=s.frame_id,
            T_reference_sensor=fit.poses[s.name].copy(),
            covariance=cov,
            std=stds[s.name],
            held=held,
            bounded=bounded.get(s.name, {}),
            bounded_set=sets.get(s.name),
            prior=dict(prior.tolerance) if prior is not None and s.name != reference else {},
        )
    return CalibrationResult(
        mode=mode,
        reference=reference,
        converged=True,
        sensors=sensors,
        rmse_m=rmse,
        per_board_m=per_board,
        outliers={s: tuple(sorted(ks)) for s, ks in outliers.items() if ks},
        ignored=ignored,
        warnings=tuple(warnings),
        iterations=sol.iterations,
        cost=sol.cost,
        num_boards=dataset.num_boards,
        noise_sigma_m=fit.noise,
        noise_iterations=fit.noise_iterations,
        board_poses=fit.board_poses,
        cross_validation_rmse_m=cv,
        solve_time_s=time.perf_counter() - t0,
        relative=_relative(work, fit, sol, units, reference, bounded),
        noise_model=noise_model,
        verdict=result_verdict,
        joint_covariance=None if "radar_reference" in sol.extra else sol.joint_covariance(list(sensors)),
    )


def _honest_covariance(
    dataset: Dataset, fit: _Fit, units: DetectionUnits, priors: Mapping[str, SensorPrior] | None = None
) -> tuple[Solution, dict[str, dict[str, tuple[float, float]]], np.ndarray]:
    """The solution with a covariance that holds (see :mod:`rigcal.problem.noise`): per-sensor
    noise estimated from the residuals, the sandwich around the solve's weights (pairs that
    share a sensor's detections are correlated), and every 2D radar's z, roll and pitch
    without a prior reported as the interval its field of view allows instead of a Gaussian -
    the other parameters' covariance widened by what those directions may still move them.

    A mounting prior is one more measurement of its directions (the nominal pose, off the
    truth by its tolerance): its precision enters the sandwich's bread as the solve weighted
    it and its meat with its own noise (``A = J'J/s^2 + P``, ``meat = J'D Theta D'J/s^2 + P``
    for observation rows that carry ``s`` times a prior's whitened noise, ``P`` the priors'
    ``1 / tolerance^2``).

    Returns (solution, bounded intervals per sensor, the noise model's group variances)."""
    sol = fit.solution
    problem = fit.problem.with_poses(sol.poses)
    r_w, J_w, _, _, layout = linearise(problem)
    sigma = np.concatenate([b.sigma.ravel() for b in problem.observations]) if problem.observations else np.zeros(0)
    m, n = J_w.shape
    Dw = scale_rows(noise_map(problem, dataset, units), 1.0 / sigma)
    # the fitted parameters absorb n of the m residual degrees of freedom (a row-by-row
    # account, (I - H) D, was tried: near-collinear groups then collapse to the floor)
    theta = estimate_theta(r_w, group_design(Dw, units), m / max(m - n, 1), batches=row_batches(problem))
    # the priors' precision per free column [1 / rad^2, 1 / m^2]
    precision = np.zeros(n)
    for name, pr in (priors or {}).items():
        if name not in layout.index:
            continue
        cols, sig = layout.cols[layout.index[name]], pr.sigma
        for i in range(6):
            if cols[i] >= 0 and np.isfinite(sig[i]) and sig[i] > 0:
                precision[cols[i]] += 1.0 / sig[i] ** 2
    bounded: dict[str, dict[str, tuple[float, float]]] = {}
    b_cols: list[int] = []
    spread: dict[str, np.ndarray] = {}
    sets: dict[str, BoundedSet] = {}
    for s in dataset.sensors:
        if s.kind != SensorKind.RADAR or s.name not in layout.index:
            continue
        cols = layout.cols[layout.index[s.name]]
        # a direction with a prior is determined (by the prior and the data), not bounded
        dirs = {d: int(cols[i]) for d, i in BOUNDED_RADAR_DIRECTIONS.items() if cols[i] >= 0 and precision[cols[i]] == 0}
        if not dirs:
            continue
        intervals, vertices = fov_bounds(problem, s.name, tuple(dirs))
        bounded[s.name] = {d: intervals[d] for d in dirs}
        b_cols += list(dirs.values())
        moves = _profile_moves(problem, s.name, vertices, tuple(dirs))
        spread[s.name] = _spread(moves)
        sets[s.name] = BoundedSet(tuple(dirs), *fov_polytope([problem], s.name, tuple(dirs)),
                                  _bounded_map(vertices, moves, len(dirs)))
    # Gaussian part with the bounded directions held at the estimate, plus the spread of the
    # radar's pose over the bounded set (nonlinear: each extreme re-solved)
    free = np.setdiff1d(np.arange(n), b_cols)
    J_f, D_f, P_f = J_w[:, free], Dw, None
    if np.any(precision[free] > 0):
        s_rows = np.concatenate([np.full(b.size * b.dim, float(fit.prior_scale.get(b.label, 1.0)))
                                 for b in problem.observations])
        J_f, D_f, P_f = J_f / s_rows[:, None], scale_rows(Dw, 1.0 / s_rows), precision[free]
    _, C_ff = sandwich(J_f, D_f, units, theta, prior_precision=P_f)
    cov = np.zeros((n, n))
    cov[np.ix_(free, free)] = C_ff
    for name, S in spread.items():
        cols = layout.cols[layout.index[name]]
        keep = cols >= 0
        cov[np.ix_(cols[keep], cols[keep])] += S[np.ix_(keep, keep)]
    return replace(sol, covariance=cov, extra={**sol.extra, "bounded_sets": sets}), bounded, theta


def _warnings(
    dataset: Dataset,
    mode: str,
    reference: str,
    fit: _Fit,
    options: CalibrationOptions,
    weak: Mapping[str, list[str]],
    bounded: Mapping[str, Mapping[str, tuple[float, float]]],
) -> list[str]:
    sol = fit.solution
    out: list[str] = []
    pairs = all_pairs(dataset) if mode != "mcpe" else pairs_for_mode(dataset, mode, reference)
    out += geometry_warnings(dataset, pairs)
    out += list(sol.extra.get("notes", ()))
    if sol.rank_deficient:
        out.append(
            "the problem is rank deficient: some degrees of freedom are not determined by the "
            "boards (their reported std is not meaningful)"
        )
    for s in dataset.sensors:
        if s.name in bounded:
            deg = math.degrees(s.max_elevation_rad)
            out.append(
                f"{s.name} (2D radar): {', '.join(bounded[s.name])} are not measured, only bounded by "
                f"the ±{deg:g} deg elevation field of view (see 'bounded'); to pin them, give the "
                f"known mounting with --initial FILE and its tolerance (--prior "
                f"{s.name}:z_m=0.02,roll_deg=1,pitch_deg=1), or --hold-radar-plane"
            )
        elif (
            s.kind == SensorKind.RADAR and options.hold_radar_plane and s.name != reference
            and not (options.initial and s.name in options.initial)
        ):
            out.append(
                f"{s.name} (2D radar): z, roll and pitch are held at the automatic initial guess, "
                "which assumes every reflector on the radar plane - without --initial this is "
                "only as good as that assumption (the radar pairs' RMSE shows it)"
            )
        if weak.get(s.name):
            out.append(f"{s.name}: weakly observable: {', '.join(weak[s.name])}")
    return out
