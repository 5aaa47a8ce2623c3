"""The solver finishes (issue 10 item 1): on clean random subsets of the real Prius boards every
mode converges to a constrained optimum, the case that used to stall reaches the same optimum
as an independent solver, and data that cannot determine a pose are refused up front with a
message that says what is missing."""

from __future__ import annotations

import numpy as np
import pytest
from rigcal.errors import ConvergenceError, GeometryError, RigcalError
from rigcal.geometry.se3 import se3_exp
from rigcal.problem.calibrate import CalibrationOptions, _fit, calibrate
from rigcal.problem.configurations import build_pairwise
from rigcal.problem.initialise import initial_poses
from rigcal.problem.pairs import all_pairs
from rigcal.problem.solver import solve
from rigcal.problem.verify import kkt_violations, reference_solve

#: a step tolerance far below the statistical default, for checks of the optimum itself
TIGHT = 1e-9
#: the issue's reproduction: FCPE on these boards stalled ("Newton step is 1.77 sigma")
ISSUE_BOARDS = [1, 5, 6, 10, 11, 13, 14, 15, 22, 23]


def test_issue_subset_fcpe_reaches_the_kkt_point_scipy_finds(real_dataset):
    sub = real_dataset.select_boards(ISSUE_BOARDS)
    start = initial_poses(sub, "lidar1", robust=True)
    problem = build_pairwise(sub, start, "lidar1", all_pairs(sub))
    sol = solve(problem, step_sigma=TIGHT)
    assert sol.converged, sol.status
    k = kkt_violations(problem, sol.poses)
    # the hard case: several elevation limits bind at once (two of them for the same reflector,
    # once through each 3D sensor), which made the old active-set loop cycle
    assert np.sum(k["multipliers"] > 0) >= 2
    assert k["stationarity"] < 1e-6, k
    assert k["violation"] <= problem.fov_tolerance_rad
    # SLSQP from the same start ends in a local minimum no lower than ours (on this data it is
    # another, 7 mm away, at +0.3 % cost); SLSQP started at ours finds nothing to improve
    cost_from_start, _, _ = reference_solve(problem)
    assert sol.cost <= cost_from_start * (1 + 1e-9)
    cost, poses, ok = reference_solve(problem, sol.poses)
    assert ok and sol.cost == pytest.approx(cost, rel=1e-9)
    for name in ("camera1", "radar1"):
        np.testing.assert_allclose(sol.poses[name], poses[name], atol=1e-6)
    # the point the old solver stalled at (cost 0.0057597) was no minimum: this is 1.6 % lower
    stalled_cost = 0.005759699843
    assert sol.cost < stalled_cost * (1 - 1e-2)
    # and the default (statistical) tolerance stops at the same optimum
    default = solve(problem)
    assert default.converged and default.cost == pytest.approx(sol.cost, rel=1e-9)


def _draws(K: int, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(29, K, replace=False)) for _ in range(n)]


@pytest.mark.parametrize(
    "mode, K, n",
    [("fcpe", 4, 40), ("fcpe", 10, 40), ("mcpe", 4, 40), ("mcpe", 10, 40), ("pse", 4, 12), ("pse", 10, 6)],
)
@pytest.mark.slow
def test_random_board_subsets_all_converge(real_dataset, mode, K, n):
    """Seeded draws of K of the 29 boards (the issue measured 0-6 % FCPE, 0-3 % MCPE and
    4-29 % PSE failures on such draws); every one must converge to a feasible point. (PSE draws
    are fewer: each runs the noise loop; benchmarks/bench_solver_reliability.py runs 200.)"""
    options = CalibrationOptions(mode=mode)
    failures = []
    for boards in _draws(K, n, seed=1000 + K):
        sub = real_dataset.select_boards(boards)
        try:
            fit = _fit(sub, mode, "lidar1", initial_poses(sub, "lidar1", robust=True), options)
        except ConvergenceError as exc:
            failures.append((boards.tolist(), str(exc)))
            continue
        assert fit.solution.converged
        for c in fit.solution.limit_residuals:
            assert np.all(c <= 1e-7)
    assert not failures, failures


def test_pse_noise_loop_converges_where_it_oscillated(real_dataset):
    """K = 4 draws whose per-sensor noise estimates oscillated for 100 iterations before."""
    for boards in ([0, 11, 18, 21], [9, 16, 26, 27], [1, 8, 19, 25]):
        r = calibrate(real_dataset.select_boards(boards), CalibrationOptions(mode="pse"))
        assert r.converged and r.noise_iterations < 100
        for sig in r.noise_sigma_m.values():
            assert all(1e-4 <= s < 1.0 for s in sig)


def test_lower_fcpe_minimum_found_from_either_radar_tilt(real_dataset):
    """The FCPE cost on all 29 boards has two minima differing in the radar's tilt; solve() is
    local (from the radar pitched +4 deg it stays in the higher one), calibrate() also tries the
    mirrored tilt and returns the lower one from either start."""
    init = initial_poses(real_dataset, "lidar1")
    pitched = dict(init)
    pitched["radar1"] = init["radar1"] @ se3_exp(np.radians([0.0, 4.0, 0.0, 0, 0, 0]))
    local = solve(build_pairwise(real_dataset, pitched, "lidar1", all_pairs(real_dataset)))
    assert local.converged
    results = [
        calibrate(real_dataset, CalibrationOptions(mode="fcpe", initial=start, detect_outliers=False))
        for start in (None, pitched)
    ]
    assert results[0].cost == pytest.approx(results[1].cost, rel=1e-9)
    assert results[0].cost < local.cost * (1 - 1e-3)
    assert results[0].cost == pytest.approx(22789.6e-6, rel=1e-5)


# --------------------------------------------------------------------------- refusals


def test_collinear_reflectors_are_refused_before_solving(real_dataset):
    # boards 3, 8 and 19 lie within 0.1 mm of one line in the radar's plane
    sub = real_dataset.select_boards([3, 8, 19])
    for mode in ("fcpe", "mcpe", "pse"):
        with pytest.raises(GeometryError, match=r"3 boards radar1 shares with lidar1.* collinear in radar1"):
            calibrate(sub, CalibrationOptions(mode=mode))
    # three boards off one line are fine
    r = calibrate(real_dataset.select_boards([3, 8, 20]), CalibrationOptions(mode="fcpe"))
    assert r.converged


def test_too_few_shared_boards_are_named(real_dataset):
    with pytest.raises(RigcalError, match=r"radar1 shares only 2 boards with lidar1 or camera1"):
        calibrate(real_dataset.select_boards([0, 5]), CalibrationOptions(mode="fcpe"))


def test_mcpe_needs_boards_shared_with_the_reference(real_dataset):
    """lidar1 and camera1 share no board (each misses the other's three), so MCPE cannot relate
    camera1 to lidar1; FCPE can, through the radar."""
    sub = real_dataset.select_boards([0, 1, 2, 3, 4, 5])
    sub = sub.with_excluded({"lidar1": {0, 1, 2}, "camera1": {3, 4, 5}})
    with pytest.raises(GeometryError, match=r"camera1 shares no boards with lidar1"):
        calibrate(sub, CalibrationOptions(mode="mcpe", detect_outliers=False))
    assert calibrate(sub, CalibrationOptions(mode="fcpe", detect_outliers=False)).converged


def test_pse_keeps_and_reports_a_noise_without_redundancy(real_dataset):
    """On these 4 boards the radar's range axis has (almost) no redundancy: its variance
    component would collapse to the floor; it is kept at its value instead, and said so."""
    sub = real_dataset.select_boards([0, 11, 18, 21])
    fit = _fit(sub, "pse", "lidar1", initial_poses(sub, "lidar1", robust=True), CalibrationOptions(mode="pse"))
    notes = fit.solution.extra.get("notes", ())
    assert any(n.startswith("radar1: noise of axis 0 kept at") for n in notes), notes
    assert fit.noise["radar1"][0] > 10 * 1e-4  # not at the floor
