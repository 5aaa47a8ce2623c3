"""End-to-end relative calibration: initialise, find outliers, solve a configuration,
estimate noise (PSE), propagate uncertainty, evaluate. Returns a :class:`CalibrationResult`."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
from threadpoolctl import threadpool_limits

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import ConfigError, ConvergenceError, RigcalError
from rigcal.problem.configurations import (
    MODES,
    RADAR_PLANE_HELD,
    board_block,
    build_pairwise,
    build_pse,
    initial_board_poses,
    pairs_for_mode,
)
from rigcal.problem.evaluate import anchor_errors, evaluate_pairs
from rigcal.problem.fixedpoint import Anderson
from rigcal.problem.globalise import solve_global
from rigcal.problem.initialise import default_reference, initial_poses
from rigcal.problem.observability import check_observable
from rigcal.problem.outliers import OutlierRule, find_outliers
from rigcal.problem.pairs import all_pairs, pair_data
from rigcal.problem.result import CalibrationResult, SensorEstimate
from rigcal.problem.solver import Problem, Solution, merge_independent, prepare, solve
from rigcal.problem.uncertainty import geometry_warnings, pose_std, relative_estimates, weak_directions

log = logging.getLogger(__name__)

#: Cauchy scale [m] of the robust screening solve
ROBUST_SCALE_M = 0.05
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
    initial guess. initial: optional ``T_reference_sensor`` guesses (else Kabsch).
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


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class _Fit:
    poses: dict[str, np.ndarray]
    problem: Problem
    solution: Solution
    noise: dict[str, tuple[float, ...]]
    noise_iterations: int
    board_poses: dict[int, np.ndarray]


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
    if options.cross_validation_folds < 0 or options.cross_validation_folds == 1:
        raise ConfigError("cross_validation_folds must be 0 (off) or at least 2")
    return reference


def _fit(
    dataset: Dataset,
    mode: str,
    reference: str,
    poses0: Mapping[str, np.ndarray],
    options: CalibrationOptions,
) -> _Fit:
    # refuse, saying what is missing, when the boards cannot determine the poses
    check_observable(dataset, mode, reference, options.hold_radar_plane)
    if mode == "fcpe":
        prob = build_pairwise(dataset, poses0, reference, all_pairs(dataset), options.hold_radar_plane)
        sol = solve_global(prob)
        return _Fit(dict(sol.poses), prob, sol, {}, 0, {})
    if mode == "mcpe":
        # each sensor against the reference: independent pairwise problems (paper eq. 6)
        probs, sols = [], []
        for pair in pairs_for_mode(dataset, mode, reference):
            other = pair[1] if pair[0] == reference else pair[0]
            prob = build_pairwise(dataset, poses0, reference, [pair], options.hold_radar_plane)
            prob = replace(prob, poses=tuple(p for p in prob.poses if p.name in (reference, other)))
            probs.append(prob)
            sols.append(solve_global(prob))
        prob, sol = merge_independent(probs, sols)
        return _Fit(dict(sol.poses), prob, sol, {}, 0, {})
    # PSE with iterated diagonal noise: one Gauss-Newton step, then a variance-component update,
    # until the noise model stops changing; then a full solve, and a last check of the noise
    poses = {k: np.asarray(v) for k, v in poses0.items()}
    boards = initial_board_poses(dataset, poses)
    sigmas = {s.name: np.ones(2 if s.kind == SensorKind.RADAR else 3) for s in dataset.sensors}
    prob = build_pse(dataset, poses, boards, reference, sigmas, options.hold_radar_plane)
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
    sol = solve_global(prob, layout=layout)
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
    prob = build_pairwise(dataset, poses0, reference, all_pairs(dataset), options.hold_radar_plane)
    sol = solve(prob, loss="cauchy", loss_scale=ROBUST_SCALE_M)
    poses = dict(sol.poses) if sol.converged else dict(poses0)
    return find_outliers(dataset, poses, options.outlier_rule), poses


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
            fit = _fit(dataset.select_boards(train), mode, reference, poses, options)
        except RigcalError as exc:
            log.info("cross-validation fold %d skipped: %s", f, exc)
            continue
        for a, b in all_pairs(dataset):
            p = pair_data(dataset, a, b, test)
            if p is None or p.num_boards == 0:
                continue
            sq.setdefault(p.label, []).append(anchor_errors(p, fit.poses) ** 2)
    return {k: float(np.sqrt(np.mean(np.concatenate(v)))) for k, v in sq.items()}


def calibrate(dataset: Dataset, options: CalibrationOptions = CalibrationOptions()) -> CalibrationResult:
    """Calibrate every sensor of ``dataset`` into the reference sensor's frame.

    Raises ConfigError for bad options, InputError when sensors cannot be related, and
    ConvergenceError when the solver does not converge (never a silent result).
    """
    t0 = time.perf_counter()
    reference = _check(dataset, options)
    mode = options.mode.lower()
    ignored = {s.name: tuple(sorted(s.excluded)) for s in dataset.sensors if s.excluded}
    with threadpool_limits(limits=1):
        poses0 = initial_poses(
            dataset, reference, robust=options.detect_outliers, given=options.initial
        )
        outliers: dict[str, set[int]] = {}
        work = dataset
        if options.detect_outliers:
            outliers, poses0 = _robust_screen(dataset, reference, poses0, options)
            work = dataset.with_excluded(outliers)
        fit = _fit(work, mode, reference, poses0, options)
        for _ in range(3):
            if not (options.detect_outliers and fit.solution.converged):
                break
            more = find_outliers(work, fit.poses, options.outlier_rule)
            if not more:
                break
            for s, ks in more.items():
                outliers.setdefault(s, set()).update(ks)
            work = dataset.with_excluded(outliers)
            fit = _fit(work, mode, reference, fit.poses, options)
        sol = fit.solution
        if not sol.converged:
            raise ConvergenceError(f"{mode.upper()} did not converge: {sol.status}")
        rmse, per_board = evaluate_pairs(work, fit.poses)
        cv = (
            _cross_validation(work, mode, reference, fit.poses, options)
            if options.cross_validation_folds
            else {}
        )
    covariances = {s.name: sol.pose_covariance(s.name) for s in dataset.sensors}
    stds = {name: pose_std(fit.poses[name], cov) for name, cov in covariances.items()}
    warnings = _warnings(work, mode, reference, fit, options, stds)
    sensors = {}
    for s in dataset.sensors:
        cov = covariances[s.name]
        held = ()
        if s.name == reference:
            held = ("x", "y", "z", "roll", "pitch", "yaw")
        elif options.hold_radar_plane and s.kind == SensorKind.RADAR:
            held = RADAR_PLANE_HELD
        sensors[s.name] = SensorEstimate(
            name=s.name,
            kind=s.kind,
            frame_id=s.frame_id,
            T_reference_sensor=fit.poses[s.name].copy(),
            covariance=cov,
            std=stds[s.name],
            held=held,
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
        relative=relative_estimates(dataset.names, fit.poses, sol.joint_covariance),
    )


def _warnings(
    dataset: Dataset,
    mode: str,
    reference: str,
    fit: _Fit,
    options: CalibrationOptions,
    stds: Mapping[str, Mapping[str, float]],
) -> list[str]:
    sol = fit.solution
    out: list[str] = []
    pairs = all_pairs(dataset) if mode != "mcpe" else pairs_for_mode(dataset, mode, reference)
    out += geometry_warnings(dataset, pairs)
    if sol.rank_deficient:
        out.append(
            "the problem is rank deficient: some degrees of freedom are not determined by the "
            "boards (their reported std is not meaningful)"
        )
    for s in dataset.sensors:
        if s.name == reference:
            continue
        weak = weak_directions(stds[s.name])
        if s.kind == SensorKind.RADAR and not options.hold_radar_plane:
            weak_plane = [w for w in weak if w.split(" ")[0] in ("z", "roll", "pitch")]
            if weak_plane:
                out.append(
                    f"{s.name} (2D radar): {', '.join(weak_plane)} weakly observable - a 2D radar "
                    "measures range and azimuth only; hold z, roll and pitch at a known mounting "
                    "with --hold-radar-plane and an initial guess"
                )
            weak = [w for w in weak if w not in weak_plane]
        if weak:
            out.append(f"{s.name}: weakly observable: {', '.join(weak)}")
    # boards pushed to the edge of a 2D radar's elevation field of view
    for batch, c in zip(fit.problem.limits, sol.limit_residuals):
        edge = int(np.sum(c > -math.radians(0.05)))
        if edge:
            deg = math.degrees(float(batch.max_elevation_rad[0]))
            out.append(
                f"{batch.observer[0]}: {edge} board(s) of {batch.label} sit on the edge of the "
                f"±{deg:g} deg elevation field of view - the radar's tilt there is set by that "
                "limit rather than by measurements; consider --hold-radar-plane"
            )
    return out
