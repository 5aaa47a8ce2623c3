"""The coverage study: the truth falls inside the reported 95 % region about 95 % of the time
on simulated rigs with unequal noise per sensor kind (lidar 4 mm, camera 20 mm, radar 30 mm)."""

from __future__ import annotations

import numpy as np

from rigcal.geometry.se3 import se3_exp
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate
from rigcal.study.board_coverage import board_coverage, judge_sensor


def test_coverage_of_fcpe_is_near_95_percent():
    # 6 trials x 5 calibrated sensors; the benchmark runs 60 trials per mode
    out = board_coverage(trials=6, seed=1, modes=("fcpe",))["fcpe"]
    assert out["failures"] == 0 and out["sensors"] == 30
    assert out["position"] >= 0.8
    assert out["pose"] >= 0.8


def test_judge_rejects_a_truth_far_outside_the_reported_region():
    rng = np.random.default_rng(2)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)
    r = calibrate(sim.dataset, CalibrationOptions(mode="fcpe"))
    truth = sim.truth_T("lidar1", "camera1")
    assert judge_sensor(r, "camera1", truth) == (True, True)
    off = truth @ se3_exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.1]))
    assert judge_sensor(r, "camera1", off) == (False, False)


def test_coverage_with_priors_and_of_relative_transforms():
    from rigcal.study.board_coverage import PriorSpec

    out = board_coverage(trials=3, seed=1, modes=("fcpe",), priors=PriorSpec())["fcpe"]
    assert out["failures"] == 0 and out["sensors"] == 15 and out["relatives"] == 30
    assert out["pose"] >= 0.8 and out["relative"] >= 0.8


def test_judge_relative_accepts_the_truth_and_rejects_a_far_one():
    from rigcal.study.board_coverage import judge_relative

    rng = np.random.default_rng(2)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)
    r = calibrate(sim.dataset, CalibrationOptions(mode="fcpe"))
    truth = sim.truth_T("camera1", "radar1")
    assert r.relative["camera1-radar1"].bounded  # the radar's tilt enters: bounded quantities
    assert judge_relative(r, "camera1-radar1", truth)
    # 10 cm along the radar's own x (in its plane, measured): outside
    assert not judge_relative(r, "camera1-radar1", truth @ se3_exp(np.array([0, 0, 0, 0.1, 0, 0])))
