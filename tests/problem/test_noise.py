"""The detection noise model: units, the noise map against finite differences, the noise
estimate against the simulated truth, and the sandwich covariance against Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.problem.configurations import build_pairwise
from rigcal.problem.initialise import initial_poses
from rigcal.problem.noise import (
    COMPONENTS,
    detection_units,
    estimate_theta,
    group_design,
    noise_map,
    theta_by_sensor,
)
from rigcal.problem.numerics import to_dense
from rigcal.problem.pairs import all_pairs
from rigcal.problem.solver import linearise, solve
from rigcal.sim.rig import make_rig_placements, random_rig, simulate


@pytest.fixture(scope="module")
def rig():
    rng = np.random.default_rng(11)
    sensors = random_rig(rng, 1, 2, 1)
    return sensors, make_rig_placements(rng, sensors, 20)


def _truth_poses(sim, reference="lidar1"):
    return {n: sim.truth_T(reference, n) for n in sim.dataset.names}


def test_every_valid_detection_has_its_kinds_units(rig):
    sensors, boards = rig
    ds = simulate(sensors, boards, rng=0).dataset
    units = detection_units(ds)
    for s in ds.sensors:
        per = 4 if s.kind.is_point_cloud else 1
        per_point = 2 if s.kind is SensorKind.RADAR else 3
        assert units.count(s.name) == int(s.valid.sum()) * per * per_point
        assert {c for n, c in units.groups if n == s.name} == set(COMPONENTS[s.kind])
    np.testing.assert_allclose(np.linalg.norm(units.basis, axis=1), 1.0, atol=1e-12)


def test_noise_map_is_the_residuals_derivative(rig):
    """Moving one detection along one unit's direction changes the metric residuals by D's
    column (finite differences through the whole pair construction, reflectors included)."""
    sensors, boards = rig
    ds = simulate(sensors, boards, rng=1).dataset
    poses = initial_poses(ds, "lidar1")
    problem = build_pairwise(ds, poses, "lidar1", all_pairs(ds))
    units = detection_units(ds)
    D = noise_map(problem, ds, units)
    assert isinstance(D, np.ndarray)  # small: dense, no scipy
    r0 = linearise(problem)[0]
    rng = np.random.default_rng(0)
    for u in rng.choice(units.size, 25, replace=False):
        sensor, _ = units.groups[units.group[u]]
        key = next(k for k, v in units.first.items() if k[0] == sensor and v <= u < v + (2 if ds.sensor(sensor).kind is SensorKind.RADAR else 3))
        _, k, m = key
        det = ds.sensor(sensor)
        h = 1e-6
        pts = np.array(det.points)
        step = units.basis[u][: pts.shape[-1]] * h
        if det.kind.is_point_cloud:
            pts[k, m] += step
        else:
            pts[k] += step
        from dataclasses import replace

        moved = replace(ds, sensors=tuple(replace(s, points=pts) if s.name == sensor else s for s in ds.sensors))
        r1 = linearise(build_pairwise(moved, poses, "lidar1", all_pairs(moved)))[0]
        np.testing.assert_allclose((r1 - r0) / h, D[:, u], atol=1e-5)


def test_noise_estimate_recovers_the_simulated_noise(rig):
    """FCPE residuals of a rig with very different noise per sensor tell the sensors apart."""
    sensors, boards = rig
    from dataclasses import replace

    noisy = tuple(
        replace(s, sigma_m=0.004) if s.kind is SensorKind.LIDAR
        else replace(s, sigma_m=0.02, depth_sigma_at_1m_m=0.0) if s.kind is SensorKind.CAMERA
        else replace(s, range_sigma_m=0.03, azimuth_sigma_deg=0.3)
        for s in sensors
    )
    ds = simulate(noisy, boards, rng=3).dataset
    problem = build_pairwise(ds, _truth_poses(simulate(noisy, boards, rng=3)), "lidar1", all_pairs(ds))
    sol = solve(problem)
    problem = problem.with_poses(sol.poses)
    units = detection_units(ds)
    r, J = linearise(problem)[:2]
    theta = estimate_theta(r, group_design(noise_map(problem, ds, units), units), r.size / (r.size - J.shape[1]))
    est = theta_by_sensor(units, theta)
    # the lidar's share of a lidar-camera pair is small: it is told apart, not measured finely
    lidar = np.sqrt(np.mean([est["lidar1"][c] ** 2 for c in "xyz"]))
    assert lidar < 0.01
    for cam in ("camera1", "camera2"):
        assert est[cam]["lateral"] == pytest.approx(0.02, rel=0.25)
    assert est["radar1"]["range"] == pytest.approx(0.03, rel=0.35)


def test_estimate_theta_is_exact_on_expected_squares():
    M = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [3.0, 0.5]])
    theta = np.array([4e-4, 1e-4])
    r = np.sqrt(M @ theta)
    np.testing.assert_allclose(estimate_theta(r, M, 1.0), theta, rtol=1e-6)
    # a group no residual depends on keeps the floor
    M0 = np.hstack([M, np.zeros((4, 1))])
    assert estimate_theta(r, M0, 1.0)[2] == pytest.approx(1e-10)


def test_large_noise_maps_are_sparse_with_the_same_entries(rig, monkeypatch):
    """Above DENSE_MAX_ENTRIES the map is a scipy CSR matrix with exactly the dense entries, and
    the group design built from either is the same."""
    import rigcal.problem.noise as noise

    sensors, boards = rig
    ds = simulate(sensors, boards, rng=1).dataset
    problem = build_pairwise(ds, initial_poses(ds, "lidar1"), "lidar1", all_pairs(ds))
    units = detection_units(ds)
    dense = noise_map(problem, ds, units)
    monkeypatch.setattr(noise, "DENSE_MAX_ENTRIES", 0)
    sparse = noise_map(problem, ds, units)
    assert not isinstance(sparse, np.ndarray) and sparse.format == "csr"
    np.testing.assert_array_equal(to_dense(sparse), dense)
    np.testing.assert_allclose(group_design(sparse, units), group_design(dense, units), rtol=1e-12)


def test_noise_region_bounds_a_split_the_data_do_not_tell():
    """Two groups seen only as a sum (one pair, two sensors): each may carry all of it, so its
    upper bound is the sum and its lower bound 0; a group seen alone is tight."""
    from rigcal.problem.noise import noise_region

    rng = np.random.default_rng(0)
    n = 400
    M = np.zeros((n, 3))
    M[:200, 0] = M[:200, 1] = 1.0  # rows that see group 0 + group 1 only
    M[200:, 2] = 1.0  # rows that see group 2 only
    theta = np.array([4e-4, 1e-10, 1e-4])  # the estimate put the pair's noise on group 0
    region = noise_region(M, theta)
    low, high = region.group_bounds()
    assert high[1] == pytest.approx(4e-4, rel=0.05)  # group 1 may carry the pair's whole noise
    assert low[0] == pytest.approx(0.0, abs=1e-6) and low[1] == 0.0
    assert 1e-4 < high[2] < 1.5e-4 and 0.6e-4 < low[2] < 1e-4  # seen alone: within ~30 %
    # the pair's sum itself is determined
    assert region.upper(np.array([1.0, 1.0, 0.0])) == pytest.approx(4e-4, rel=0.35)
    assert rng is not None


def test_noise_region_of_a_loop_is_determined():
    from rigcal.problem.noise import noise_region

    # three sensors in a loop: rows see a+b, b+c, a+c - with enough rows each is determined
    M = np.zeros((6000, 3))
    M[:2000, [0, 1]] = 1.0
    M[2000:4000, [1, 2]] = 1.0
    M[4000:, [0, 2]] = 1.0
    theta = np.array([1e-4, 2e-4, 3e-4])
    region = noise_region(M, theta)
    low, high = region.group_bounds()
    assert region.weak.shape[1] == 0
    assert np.all(high < 2.0 * theta) and np.all(low > 0.3 * theta)
    # with a tenth of the rows the split of the smallest is no longer told (relative standard
    # error about 0.5): it may be anywhere from 0 to what its pairs allow
    low, high = noise_region(M[::10], theta).group_bounds()
    assert low[0] == 0.0 and high[0] > 3 * theta[0]
