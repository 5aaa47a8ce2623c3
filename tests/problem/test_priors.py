"""Mounting priors around a nominal pose (rigcal.problem.priors): parsing, merging, and what they
do to a calibration of a simulated rig with known truth - the prior's directions are determined
(std from prior and data together, not bounded), the truth lies inside the region, and
--hold-radar-plane is the limit of a vanishing tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.errors import ConfigError, InputError
from rigcal.geometry.se3 import invert, se3_exp, se3_log
from rigcal.problem.calibrate import CalibrationOptions, calibrate, nominal_poses, sensor_priors
from rigcal.problem.priors import HOLD_RADAR_PLANE, SensorPrior, check_prior, merge_priors, parse_prior_text, prior_sigma
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

TOL = {"z_m": 0.02, "roll_deg": 1.0, "pitch_deg": 1.0}


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 20), rng=rng, reference="lidar1")


@pytest.fixture(scope="module")
def truth(sim):
    return {n: sim.truth_T("lidar1", n) for n in sim.dataset.names}


def nominal(truth, seed=0, tol=TOL):
    """The truth of radar1 moved by a draw of ``tol`` (the mounting drawing's error)."""
    rng = np.random.default_rng(seed)
    sig = prior_sigma(tol)
    xi = rng.normal(size=6) * np.where(np.isfinite(sig), sig, 0.0)
    out = dict(truth)
    out["radar1"] = truth["radar1"] @ se3_exp(xi)
    return out


def test_parse_prior_text():
    assert parse_prior_text("z_m=0.01,roll_deg=0.5") == (None, {"roll_deg": 0.5, "z_m": 0.01})
    assert parse_prior_text("radar1:pitch_deg=0") == ("radar1", {"pitch_deg": 0.0})
    with pytest.raises(InputError, match=r"--prior 'z_m': expected \[SENSOR:\]key=value"):
        parse_prior_text("z_m")
    with pytest.raises(InputError, match=r"z_m: expected a number, got 'high'"):
        parse_prior_text("z_m=high")
    with pytest.raises(InputError, match=r"unknown direction 'height_m'"):
        parse_prior_text("radar1:height_m=1")
    with pytest.raises(InputError, match=r"empty sensor name"):
        parse_prior_text(":z_m=1")


def test_check_prior_refuses_bad_tolerances():
    assert check_prior({"yaw_deg": 2, "x_m": 0.1}, "w") == {"yaw_deg": 2.0, "x_m": 0.1}
    with pytest.raises(InputError, match=r"w\.z_m: expected a tolerance in m >= 0"):
        check_prior({"z_m": -0.1}, "w")
    with pytest.raises(InputError, match=r"w\.roll_deg: expected a tolerance in deg >= 0"):
        check_prior({"roll_deg": True}, "w")
    with pytest.raises(InputError, match=r"w: expected a mapping of tolerances"):
        check_prior({}, "w")


def test_prior_sigma_is_in_tangent_order():
    s = prior_sigma({"roll_deg": 1.0, "z_m": 0.5, "x_m": 0.0})
    assert s[0] == pytest.approx(math.radians(1.0)) and s[5] == 0.5 and s[3] == 0.0
    assert np.all(np.isinf(s[[1, 2, 4]]))


def test_merge_priors_order_of_precedence():
    names = ("lidar1", "camera1", "radar1")
    out = merge_priors(names, "lidar1", {"radar1": {"z_m": 0.1}}, {"yaw_deg": 2.0},
                       {"camera1": {"x_m": 0.01}}, {"radar1": HOLD_RADAR_PLANE})
    assert out == {"camera1": {"x_m": 0.01}, "radar1": {"roll_deg": 0.0, "pitch_deg": 0.0, "z_m": 0.0}}
    with pytest.raises(ConfigError, match=r"unknown sensor 'radar9'"):
        merge_priors(names, "lidar1", {}, None, {"radar9": {"z_m": 1}})
    with pytest.raises(ConfigError, match=r"'lidar1' is the reference sensor"):
        merge_priors(names, "lidar1", {}, None, {"lidar1": {"z_m": 1}})


def test_a_prior_needs_a_nominal_pose(sim):
    with pytest.raises(ConfigError, match=r"sensor 'radar1': a mounting prior \(z_m 0.02.*needs its nominal pose: give --initial"):
        calibrate(sim.dataset, CalibrationOptions(priors={"radar1": {"z_m": 0.02}}))
    # --hold-radar-plane alone holds at the automatic guess, as before
    assert sensor_priors(sim.dataset, "lidar1", CalibrationOptions(hold_radar_plane=True))["radar1"].soft is False


def test_nominal_poses_are_re_expressed_in_the_reference(truth):
    T_w = se3_exp(np.array([0.1, -0.2, 0.3, 1.0, 2.0, 3.0]))
    moved = {k: T_w @ v for k, v in truth.items()}  # relative to some other frame
    got = nominal_poses(CalibrationOptions(initial=moved), "lidar1")
    for k in truth:
        np.testing.assert_allclose(got[k], truth[k], atol=1e-12)


def test_mcpe_with_a_2d_radar_reference_refuses_priors(sim, truth):
    with pytest.raises(ConfigError, match=r"MCPE with the 2D radar 'radar1' as reference.*priors are not used"):
        calibrate(sim.dataset, CalibrationOptions(mode="mcpe", reference="radar1", initial=truth,
                                                  priors={"camera1": {"z_m": 0.01}}))


@pytest.mark.parametrize("mode", ["mcpe", "fcpe", "pse"])
def test_prior_determines_the_radar_tilt_and_holds_the_truth(sim, truth, mode):
    nom = nominal(truth)
    r = calibrate(sim.dataset, CalibrationOptions(mode=mode, initial=nom, priors={"radar1": TOL}))
    assert r.verdict.status == "consistent", r.verdict.failed
    est = r.sensors["radar1"]
    # determined, not bounded: a std instead of an interval, and the prior is recorded
    assert est.bounded == {} and est.prior == {"roll_deg": 1.0, "pitch_deg": 1.0, "z_m": 0.02} and est.held == ()
    sd = np.sqrt(np.diag(est.covariance))
    # the tilt's std is the prior's (the data add little to a 2D radar's tilt), never more
    assert sd[0] == pytest.approx(math.radians(1.0), rel=0.2) and sd[0] <= math.radians(1.0) * 1.01
    assert sd[5] == pytest.approx(0.02, rel=0.2) and sd[5] <= 0.0202
    # the truth is inside the reported 6-DOF region
    xi = se3_log(invert(est.T_reference_sensor) @ truth["radar1"])
    assert float(xi @ np.linalg.solve(est.covariance, xi)) <= 12.59
    # without the prior, the same directions are only bounded
    free = calibrate(sim.dataset, CalibrationOptions(mode=mode, initial=nom))
    assert set(free.sensors["radar1"].bounded) == {"roll", "pitch", "z"}


@pytest.mark.parametrize("mode", ["fcpe", pytest.param("pse", marks=pytest.mark.slow)])
def test_hold_radar_plane_is_the_limit_of_a_vanishing_tolerance(sim, truth, mode):
    nom = nominal(truth, seed=1)
    held = calibrate(sim.dataset, CalibrationOptions(mode=mode, initial=nom, hold_radar_plane=True))
    assert held.sensors["radar1"].held == ("z", "roll", "pitch")
    assert held.sensors["radar1"].prior == {"roll_deg": 0.0, "pitch_deg": 0.0, "z_m": 0.0}
    # held exactly at the nominal pose
    D = invert(nom["radar1"]) @ held.sensors["radar1"].T_reference_sensor
    assert abs(D[2, 3]) < 1e-9 and np.allclose(D[2, :3], [0, 0, 1], atol=1e-9)
    previous = None
    for tol in (1e-2, 1e-4, 1e-6):
        tiny = {"z_m": tol, "roll_deg": math.degrees(tol), "pitch_deg": math.degrees(tol)}
        r = calibrate(sim.dataset, CalibrationOptions(mode=mode, initial=nom, priors={"radar1": tiny}))
        gap = np.abs(se3_log(invert(held.sensors["radar1"].T_reference_sensor) @ r.sensors["radar1"].T_reference_sensor))
        # the answer approaches the held one as the tolerance shrinks, within the tolerance
        assert np.max(gap) <= 3 * tol + 1e-9
        if previous is not None:
            assert np.max(gap) <= previous + 1e-12
        previous = np.max(gap)
        cov_gap = np.sqrt(np.diag(r.sensors["radar1"].covariance)) - np.sqrt(np.diag(held.sensors["radar1"].covariance))
        assert np.all(np.abs(cov_gap) <= 2 * tol + 0.05 * np.sqrt(np.diag(r.sensors["radar1"].covariance)))


def test_sensor_prior_value():
    p = SensorPrior("radar1", np.eye(4), {"z_m": 0.0, "roll_deg": 0.5})
    assert p.held.tolist() == [False] * 5 + [True]
    assert p.soft
    assert not SensorPrior("radar1", np.eye(4), HOLD_RADAR_PLANE).soft
