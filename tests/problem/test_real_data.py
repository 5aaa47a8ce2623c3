"""The original tool's example data (TU Delft Prius: lidar1, camera1, radar1, 29 boards):
RMSEs of the three configurations against the numbers the original tool reports."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry.se3 import invert, se3_exp
from rigcal.problem.configurations import RADAR_PLANE_HELD, pairs_for_mode
from rigcal.problem.evaluate import anchor_errors
from rigcal.problem.initialise import initial_poses
from rigcal.problem.pairs import pair_data, reflector_points
from rigcal.sensors.radar import elevation

PAIRS = ("lidar1-camera1", "lidar1-radar1", "camera1-radar1")
MM = 1e-3


def _poses(result) -> dict[str, np.ndarray]:
    return {k: v.T_reference_sensor for k, v in result.sensors.items()}


def test_fcpe_rmse_matches_the_original_tool(real_calibration):
    r = real_calibration("fcpe")
    assert r.converged and r.reference == "lidar1"
    assert set(r.rmse_m) == set(PAIRS)
    assert r.rmse_m["lidar1-camera1"] <= 15.26 * MM
    assert r.rmse_m["camera1-radar1"] <= 21.11 * MM
    # The original tool reports 14.27 mm for lidar1-radar1. Our loop-closed FCPE optimum trades
    # 0.03 mm on lidar-radar for 0.21 mm on camera-radar and has the lower total cost (below).
    assert r.rmse_m["lidar1-radar1"] <= 14.30 * MM


def test_fcpe_total_cost_is_below_the_original_tools(real_dataset, real_calibration):
    """FCPE minimises the sum over pairs of squared anchor errors; weighted by each pair's anchor
    count, ours must be lower than what the original tool's per-pair RMSEs imply."""
    r = real_calibration("fcpe")
    counts = {}
    for a, b in (("lidar1", "camera1"), ("lidar1", "radar1"), ("camera1", "radar1")):
        p = pair_data(real_dataset, a, b)
        counts[p.label] = p.points.shape[0]
    assert counts == {"lidar1-camera1": 116, "lidar1-radar1": 29, "camera1-radar1": 29}
    ours = sum(counts[k] * (r.rmse_m[k] / MM) ** 2 for k in PAIRS)
    original = 116 * 15.25**2 + 29 * 14.27**2 + 29 * 21.11**2  # mm^2
    assert ours < original
    # and it is the cost the solver reports (0.5 * sum of squares, in m^2)
    assert r.cost == pytest.approx(0.5 * ours * MM**2, rel=1e-9)


def test_the_original_tools_fcpe_result_is_a_higher_cost_local_minimum(real_dataset, real_calibration):
    """The FCPE cost has two minima on this data, differing in the 2D radar's tilt (which only
    the elevation field of view bounds). Started with the radar pitched the other way, our FCPE
    lands exactly on the original tool's numbers (15.25 / 14.27 / 21.11 mm) - at a higher total
    cost than the minimum rigcal returns from its default start."""
    from rigcal.problem.configurations import build_pairwise
    from rigcal.problem.evaluate import evaluate_pairs
    from rigcal.problem.solver import solve

    best = real_calibration("fcpe")
    init = initial_poses(real_dataset, "lidar1")
    start = dict(init)
    start["radar1"] = init["radar1"] @ se3_exp(np.radians([0.0, 4.0, 0.0, 0, 0, 0]))
    sol = solve(build_pairwise(real_dataset, start, "lidar1", pairs_for_mode(real_dataset, "fcpe", "lidar1")))
    assert sol.converged
    rmse, _ = evaluate_pairs(real_dataset, sol.poses)
    for pair, mm in zip(PAIRS, (15.25, 14.27, 21.11)):
        assert rmse[pair] == pytest.approx(mm * MM, abs=0.005 * MM), pair
    assert best.cost < sol.cost
    # the RMSE alone (what the studies use) is the same numbers, on every board or a subset
    from rigcal.problem.evaluate import pair_rmses

    assert pair_rmses(real_dataset, sol.poses) == rmse
    some = np.arange(0, real_dataset.num_boards, 3)
    assert pair_rmses(real_dataset, sol.poses, some) == evaluate_pairs(real_dataset, sol.poses, some)[0]


def test_pse_converges_with_estimated_noise(real_calibration):
    r = real_calibration("pse")
    assert r.converged
    assert r.noise_iterations > 1
    assert set(r.noise_sigma_m) == {"lidar1", "camera1", "radar1"}
    for name, sig in r.noise_sigma_m.items():
        assert all(1e-4 <= s < 0.05 for s in sig), (name, sig)
    original = {"lidar1-camera1": 15.25, "lidar1-radar1": 14.20, "camera1-radar1": 20.79}
    for pair, mm in original.items():
        assert r.rmse_m[pair] == pytest.approx(mm * MM, rel=0.10), pair


def _mcpe_pairs(dataset):
    return [pair_data(dataset, a, b) for a, b in pairs_for_mode(dataset, "mcpe", "lidar1")]


def _mcpe_cost(dataset, pairs, poses) -> float:
    return sum(float(np.sum(anchor_errors(p, poses) ** 2)) for p in pairs)


def test_mcpe_is_at_a_constrained_minimum(real_dataset, real_calibration):
    """Small twists of any free sensor never lower the MCPE cost, except those that push a
    reflector (further) out of the radar's elevation field of view."""
    r = real_calibration("mcpe")
    poses = _poses(r)
    pairs = _mcpe_pairs(real_dataset)
    assert {p.label for p in pairs} == {"lidar1-camera1", "lidar1-radar1"}
    refl = reflector_points(real_dataset.sensor("lidar1"), real_dataset)
    max_el = real_dataset.sensor("radar1").max_elevation_rad

    def abs_el(P):
        T = invert(P["radar1"]) @ P["lidar1"]
        return np.abs(elevation(refl @ T[:3, :3].T + T[:3, 3]))

    cost0 = _mcpe_cost(real_dataset, pairs, poses)
    el0 = abs_el(poses)
    assert np.all(el0 <= max_el + 1e-6)
    rng = np.random.default_rng(20240)
    # 20 random unit twists, plus +- each axis: the axis steps catch a residual gradient along a
    # weak direction (a 2D radar's roll / pitch / z) that random steps hide under the curvature
    # of the stiff directions (they flag the Kabsch guess, which random steps do not)
    directions = [v / np.linalg.norm(v) for v in rng.standard_normal((20, 6))]
    directions += [sign * e for e in np.eye(6) for sign in (1.0, -1.0)]
    kept = {"camera1": 0, "radar1": 0}
    lowered_when_infeasible = 0
    for sensor in ("camera1", "radar1"):
        for v in directions:
            P = dict(poses)
            P[sensor] = poses[sensor] @ se3_exp(1e-4 * v)
            el = abs_el(P)
            delta = _mcpe_cost(real_dataset, pairs, P) - cost0
            if np.any((el > max_el) & (el > el0)):
                lowered_when_infeasible += delta < 0
                continue
            kept[sensor] += 1
            assert delta >= 0.0, (sensor, v, delta)
    # the camera is not limited by the radar's field of view
    assert kept["camera1"] == len(directions)
    assert kept["radar1"] >= 10
    # the limit is active: leaving the field of view would lower the cost
    assert lowered_when_infeasible >= 1


def test_mcpe_differs_from_kabsch_initial_guess(real_dataset, real_calibration):
    r = real_calibration("mcpe")
    poses = _poses(r)
    init = initial_poses(real_dataset, "lidar1", robust=True)
    pairs = _mcpe_pairs(real_dataset)
    # the radar's Kabsch guess assumes the reflectors on the radar plane: MCPE moves it
    assert np.linalg.norm(poses["radar1"][:3, 3] - init["radar1"][:3, 3]) > 1 * MM
    assert _mcpe_cost(real_dataset, pairs, poses) < _mcpe_cost(real_dataset, pairs, init)
    # for the lidar-camera pair, Kabsch is already the least-squares optimum MCPE finds
    # (MCPE solves each pair with the reference as its own problem)
    np.testing.assert_allclose(poses["camera1"], init["camera1"], atol=1e-9)


@pytest.mark.parametrize("mode", ["mcpe", "fcpe", "pse"])
def test_no_outliers_on_clean_real_data(real_calibration, mode):
    r = real_calibration(mode)
    assert r.outliers == {}
    assert r.num_boards == 29
    assert all(len(v) == 29 for v in r.per_board_m.values())


@pytest.mark.parametrize("mode", ["fcpe", "pse"])
def test_hold_radar_plane_keeps_z_roll_pitch_of_initial_guess(real_dataset, real_calibration, mode):
    held = real_calibration(mode, hold_radar_plane=True)
    assert held.sensors["radar1"].held == RADAR_PLANE_HELD
    init = initial_poses(real_dataset, "lidar1", robust=True)["radar1"]
    D = invert(init) @ held.sensors["radar1"].T_reference_sensor
    assert abs(D[2, 3]) < 1e-9
    np.testing.assert_allclose(D[2, :3], [0.0, 0.0, 1.0], atol=1e-9)
    # roll, pitch and z of the radar's own frame carry no variance (tangent order: rotation first)
    cov = held.sensors["radar1"].covariance
    for i in (0, 1, 5):
        assert np.all(cov[i] == 0.0) and np.all(cov[:, i] == 0.0)
    assert cov[2, 2] > 0 and cov[3, 3] > 0 and cov[4, 4] > 0
    # without holding, the radar tilts away from the initial guess
    free = real_calibration(mode)
    D_free = invert(init) @ free.sensors["radar1"].T_reference_sensor
    assert np.linalg.norm(D_free[2, :2]) > 1e-3 or abs(D_free[2, 3]) > 1e-3


@pytest.mark.parametrize("mode", ["mcpe", "fcpe", "pse"])
def test_real_data_is_consistent_and_the_radar_tilt_is_bounded(real_calibration, mode):
    r = real_calibration(mode)
    assert r.verdict.status == "consistent", r.verdict.failed
    radar = r.sensors["radar1"]
    assert set(radar.bounded) == {"roll", "pitch", "z"}
    # the radar's pitch swings by more than +-9 deg across board subsets (issue #10): the bound
    # must be at least that wide, where the old Gaussian std claimed 0.35 deg
    lo, hi = radar.bounded["pitch"]
    assert hi - lo > 18.0
    # the camera is measured, not bounded, and its std is millimetres
    assert r.sensors["camera1"].bounded == {}
    assert r.sensors["camera1"].std["x_m"] < 0.01


def test_mcpe_with_the_2d_radar_as_reference_is_usable(real_calibration):
    """Paper Table III reports 16.3 mm lidar-camera for MCPE with the radar as reference; with
    the sensors' tilts drifting apart independently it was 696 mm (issue #10)."""
    r = real_calibration("mcpe", reference="radar1")
    assert r.rmse_m["lidar1-camera1"] <= 20 * MM
    assert r.verdict.status == "consistent"
    assert any("2D radar 'radar1' as reference" in w for w in r.warnings)
    # what the radar cannot measure is in the covariance: the lidar 2.6 m behind it moves by
    # decimetres when the radar tilts within its field of view
    assert r.sensors["lidar1"].std["z_m"] > 0.1
    # ... while the lidar-camera relation keeps its own (millimetre) uncertainty
    rel = r.relative["lidar1-camera1"].std
    assert 0.001 < rel["z_m"] < 0.02 and 0.01 < rel["roll_deg"] < 0.5


def test_pse_with_fixed_identity_noise_is_the_original_tools_variant(real_calibration):
    """The original tool's PSE with fixed identity noise: 15.25 / 14.20 / 20.79 mm."""
    r = real_calibration("pse", pse_noise="identity")
    for pair, mm in zip(PAIRS, (15.25, 14.20, 20.79)):
        assert r.rmse_m[pair] == pytest.approx(mm * MM, abs=0.02 * MM), pair
    assert r.noise_sigma_m == {} and r.noise_iterations == 0
