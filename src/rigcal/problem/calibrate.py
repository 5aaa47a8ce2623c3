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
from rigcal.errors import ConfigError, ConvergenceError, InputError, RigcalError
from rigcal.problem.consistency import (
    FAIL,
    NOTE,
    PLAUSIBLE_NOISE,
    Check,
    noise_check,
    noise_summary,
    pair_checks,
    pair_residuals,
    verdict,
)
from rigcal.geometry.se3 import adjoint, invert, se3_exp, se3_log
from rigcal.problem.configurations import (
    MODES,
    RADAR_PLANE_FREE,
    RADAR_PLANE_HELD,
    board_block,
    build_pairwise,
    build_pse,
    initial_board_poses,
    pairs_for_mode,
)
from rigcal.problem.determined import determined_check
from rigcal.problem.evaluate import anchor_errors, evaluate_pairs
from rigcal.problem.fixedpoint import Anderson
from rigcal.problem.globalise import solve_global
from rigcal.problem.initialise import default_reference, initial_poses
from rigcal.problem.mistakes import input_checks, named_checks
from rigcal.problem.observability import check_observable
from rigcal.problem.outliers import OutlierRule, find_outliers
from rigcal.problem.pairs import all_pairs, pair_data
from rigcal.problem.result import CalibrationResult, SensorEstimate
from rigcal.problem.numerics import scale_rows, single_threaded
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
    geometry_warnings,
    pose_std,
    relative_estimates,
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
    #: PSE noise: ``iterated`` (per-sensor, per-axis, re-estimated until converged) or
    #: ``identity`` (1 for every axis of every sensor: the original tool's fixed-noise PSE)
    pse_noise: str = "iterated"
    #: largest std [m, deg] of a determined pose per sensor kind (``{"radar": (0.1, 2.0)}``);
    #: kinds not given keep :data:`rigcal.problem.determined.DETERMINED_BOUND`
    max_std: Mapping[str, tuple[float, float]] | None = None


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
    if options.pse_noise not in PSE_NOISE:
        raise ConfigError(
            f"unknown PSE noise '{options.pse_noise}' (expected one of: {', '.join(PSE_NOISE)})"
        )
    if options.cross_validation_folds < 0 or options.cross_validation_folds == 1:
        raise ConfigError("cross_validation_folds must be 0 (off) or at least 2")
    return reference


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
    if mode == "fcpe":
        prob = build_pairwise(dataset, poses0, reference, all_pairs(dataset), options.hold_radar_plane)
        sol = solve_from(prob)
        return _Fit(dict(sol.poses), prob, sol, {}, 0, {})
    if mode == "mcpe":
        # each sensor against the reference: independent pairwise problems (paper eq. 6)
        probs, sols = [], []
        for pair in pairs_for_mode(dataset, mode, reference):
            other = pair[1] if pair[0] == reference else pair[0]
            prob = build_pairwise(dataset, poses0, reference, [pair], options.hold_radar_plane)
            prob = replace(prob, poses=tuple(p for p in prob.poses if p.name in (reference, other)))
            probs.append(prob)
            sols.append(solve_from(prob))
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
    sol = solve_from(prob, layout=layout)
    if not sol.converged:
        raise ConvergenceError(f"PSE did not converge: {sol.status}")
    if options.pse_noise == "identity":
        boards = {k: sol.poses[board_block(k)] for k in boards}
        return _Fit({s: sol.poses[s] for s in dataset.names}, prob.with_poses(sol.poses), sol, {}, 0, boards)
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


def _relative(dataset: Dataset, fit: _Fit, units: DetectionUnits, reference: str) -> dict:
    """Every sensor pair's relative pose with its covariance. With a 2D radar reference (MCPE)
    the height, roll and pitch between two other sensors come from the automatic guess (a fit
    of their shared boards), not from the pairs solved: their own pair's covariance is added."""
    sol = fit.solution
    out = relative_estimates(dataset.names, fit.poses, sol.joint_covariance)
    if "radar_reference" not in sol.extra:
        return out
    for key, rel in out.items():
        a, b = rel.to, rel.frm
        if reference in (a, b) or (a, b) not in all_pairs(dataset):
            continue
        local = {n: invert(fit.poses[a]) @ fit.poses[n] for n in dataset.names}
        prob = build_pairwise(dataset, local, a, [(a, b)])
        prob = replace(prob, poses=tuple(p for p in prob.poses if p.name in (a, b)))
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
        prob = build_pairwise(dataset, start, s, [pair], hold_radar_plane=True)
        prob = replace(prob, poses=tuple(p for p in prob.poses if p.name in (s, radar)))
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
    gaussian = cov.copy()  # without the moves the radar's tilt allows: what "determined" judges
    if len(vertices):
        cov += moves.T @ moves / len(vertices) / 3.0
    sol = combine_solutions(
        list(sols.values()), poses=poses, covariance=cov, columns=_radar_reference_columns(radar, names),
        status="every pair converged", extra={"radar_reference": intervals, "gaussian_covariance": gaussian},
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


def _profile_moves(problem: Problem, radar: str, vertices: list[np.ndarray]) -> list[np.ndarray]:
    """A 2D radar's pose moves (right perturbation, (6,)) when its roll, pitch and z are set to
    each extreme of ``vertices`` and its in-plane pose (x, y, yaw) is solved again with
    everything else held."""
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
        xi[list(BOUNDED_RADAR_DIRECTIONS.values())] = v
        sol = solve(held, layout=layout, start={radar: T0 @ se3_exp(xi)}, max_iterations=50)
        moves.append(se3_log(invert(T0) @ sol.poses[radar]) if sol.converged else xi)
    return moves


def _profile_spread(problem: Problem, radar: str, vertices: list[np.ndarray]) -> np.ndarray:
    """(6, 6) second moment of a 2D radar's pose over the set its field of view allows (the
    moves of :func:`_profile_moves`), scaled to those of a uniform distribution over the set
    (a third of the extremes')."""
    moves = _profile_moves(problem, radar, vertices)
    if not moves:
        return np.zeros((6, 6))
    M = np.array(moves)
    return (M.T @ M) / len(moves) / 3.0


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
        dataset, reference, robust=options.detect_outliers, given=options.initial
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
    ConvergenceError when the solver does not converge (never a silent result).
    """
    t0 = time.perf_counter()
    reference = _check(dataset, options)
    mode = options.mode.lower()
    ignored = {s.name: tuple(sorted(s.excluded)) for s in dataset.sensors if s.excluded}
    # cheap checks of the detections first: a mistake found there is named even when the
    # solve then fails on it
    inputs = input_checks(dataset, options.initial)
    try:
        with single_threaded():
            fit, work, outliers = _fit_screened(dataset, mode, reference, options)
            rmse, per_board = evaluate_pairs(work, fit.poses)
            cv = (
                _cross_validation(work, mode, reference, fit.poses, options)
                if options.cross_validation_folds
                else {}
            )
    except RigcalError as exc:
        if inputs.status == FAIL:
            raise InputError(f"{inputs.detail} (the calibration then failed: {exc})") from None
        raise
    units = detection_units(work)
    if "radar_reference" in fit.solution.extra:
        sol, bounded, theta = fit.solution, {}, _theta_all_pairs(work, fit.poses, reference, units)
    else:
        sol, bounded, theta = _honest_covariance(work, fit, units)
    covariances = {s.name: sol.pose_covariance(s.name) for s in dataset.sensors}
    stds = {name: pose_std(fit.poses[name], cov) for name, cov in covariances.items()}
    weak = {
        name: [w for w in weak_directions(std) if w.split(" ")[0] not in bounded.get(name, {})]
        for name, std in stds.items() if name != reference
    }
    warnings = _warnings(work, mode, reference, fit, options, weak, bounded)
    noise_model = theta_by_sensor(units, theta)
    result_verdict = _verdict(dataset, work, fit, units, sol, outliers, options, reference, stds, bounded, weak,
                              inputs)
    if "radar_reference" in sol.extra:
        intervals = sol.extra["radar_reference"]
        iv = ", ".join(f"{d} {lo:+.3g}..{hi:+.3g} {'m' if d == 'z' else 'deg'}" for d, (lo, hi) in intervals.items())
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
            bounded=bounded.get(s.name, {}),
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
        relative=_relative(work, fit, units, reference),
        noise_model=noise_model,
        verdict=result_verdict,
    )


def _verdict(dataset: Dataset, work: Dataset, fit: _Fit, units: DetectionUnits, sol: Solution, outliers,
             options: CalibrationOptions, reference: str, stds, bounded, weak, inputs: Check):
    """The result's verdict (:mod:`rigcal.problem.consistency`): the input checks, every pair
    and board against the noise the residuals support, the named mistakes
    (:mod:`rigcal.problem.mistakes`) and whether every pose is determined
    (:mod:`rigcal.problem.determined`)."""
    residuals = pair_residuals(work, fit.poses, reference, units, sol.joint_covariance)
    pair_check, board_check, _ = pair_checks(
        work, fit.poses, reference, units, None, sol.joint_covariance, options.outlier_rule, residuals
    )
    verdict_noise = noise_summary(units, residuals.region) if residuals is not None else {}
    radar_reference = "radar_reference" in sol.extra
    held = {s.name: RADAR_PLANE_HELD for s in dataset.sensors
            if options.hold_radar_plane and s.kind == SensorKind.RADAR}
    covariances = {s.name: sol.pose_covariance(s.name) for s in dataset.sensors}
    if radar_reference:
        # the moves the reference radar's bounded tilt and height allow are bounded, not undetermined
        gauss = replace(sol, covariance=sol.extra["gaussian_covariance"])
        covariances = {s.name: gauss.pose_covariance(s.name) for s in dataset.sensors}
        stds = {n: pose_std(fit.poses[n], c) for n, c in covariances.items()}
    determined = determined_check(dataset, stds, covariances, reference, options.max_std, radar_reference, held)
    undetermined = {e.item.split(" ")[0] for e in determined.evidence if not e.statistic <= e.threshold}
    weak = {k: v for k, v in weak.items() if k not in undetermined}
    kept = {} if options.detect_outliers else find_outliers(work, fit.poses, options.outlier_rule)
    tested = residuals
    if radar_reference and residuals is not None:
        # the others' height, roll and pitch relative to the reference radar are held at a
        # guess (decimetres, degrees off): the extra parameters are estimated at the poses a
        # local joint fit of every pair gives (their test linearises about a least-squares point)
        sol_all = solve(build_pairwise(work, fit.poses, reference, all_pairs(work)))
        if sol_all.converged:
            tested = pair_residuals(work, dict(sol_all.poses), reference, units, sol.joint_covariance)
    # the tests of an extra parameter leave out sensors the boards leave undetermined (a
    # linearisation about a pose the boards do not fix says nothing) - not those undetermined
    # because their noise is implausibly large (a mistake in their detections, to be named)
    noisy = {s for s in undetermined if any(
        v["estimate"] > PLAUSIBLE_NOISE[dataset.sensor(s).kind.value].get(c, np.inf)
        for c, v in verdict_noise.get(s, {}).items())}
    named = named_checks(tested, dataset, outliers, kept, sorted(undetermined - noisy))
    return verdict(
        pair_check, board_check, sol.rank_deficient, bounded, weak, noise_check(work, verdict_noise),
        inputs=inputs, named=named, determined=determined, noise_model=verdict_noise,
    )


def _honest_covariance(
    dataset: Dataset, fit: _Fit, units: DetectionUnits
) -> tuple[Solution, dict[str, dict[str, tuple[float, float]]], np.ndarray]:
    """The solution with a covariance that holds (see :mod:`rigcal.problem.noise`): per-sensor
    noise estimated from the residuals, the sandwich around the solve's weights (pairs that
    share a sensor's detections are correlated), and every 2D radar's z, roll and pitch
    reported as the interval its field of view allows instead of a Gaussian - the other
    parameters' covariance widened by what those directions may still move them.

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
    bounded: dict[str, dict[str, tuple[float, float]]] = {}
    b_cols: list[int] = []
    spread: dict[str, np.ndarray] = {}
    for s in dataset.sensors:
        if s.kind != SensorKind.RADAR or s.name not in layout.index:
            continue
        cols = layout.cols[layout.index[s.name]]
        dirs = {d: int(cols[i]) for d, i in BOUNDED_RADAR_DIRECTIONS.items() if cols[i] >= 0}
        if not dirs:
            continue
        intervals, vertices = fov_bounds(problem, s.name)
        bounded[s.name] = {d: intervals[d] for d in dirs}
        b_cols += list(dirs.values())
        spread[s.name] = _profile_spread(problem, s.name, vertices)
    # Gaussian part with the bounded directions held at the estimate, plus the spread of the
    # radar's pose over the bounded set (nonlinear: each extreme re-solved)
    free = np.setdiff1d(np.arange(n), b_cols)
    _, C_ff = sandwich(J_w[:, free], Dw, units, theta)
    cov = np.zeros((n, n))
    cov[np.ix_(free, free)] = C_ff
    for name, S in spread.items():
        cols = layout.cols[layout.index[name]]
        keep = cols >= 0
        cov[np.ix_(cols[keep], cols[keep])] += S[np.ix_(keep, keep)]
    return replace(sol, covariance=cov), bounded, theta


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
                f"{s.name} (2D radar): z, roll and pitch are not measured, only bounded by the "
                f"±{deg:g} deg elevation field of view (see 'bounded'); to pin them, give the "
                "known mounting with --initial FILE and --hold-radar-plane"
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
