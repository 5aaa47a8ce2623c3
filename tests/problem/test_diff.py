"""rigcal.problem.diff: two calibrations of one rig compared sensor by sensor."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry.se3 import se3_exp
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.diff import diff
from rigcal.problem.stored import StoredCalibration
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


def _calibrate(seed, sensors, like=None):
    rng = np.random.default_rng(seed)
    sim = simulate(sensors, make_rig_placements(rng, like or sensors, 15, min_fraction=1.0), rng=rng)
    return calibrate(sim.dataset, CalibrationOptions(cross_validation_folds=0))


@pytest.fixture(scope="module")
def calibrations():
    sensors = prius_like_rig()
    moved = tuple(s.with_pose(s.T_rig_sensor @ se3_exp(np.r_[0.0, 0.015, 0.0, 0.04, 0.0, 0.0]))
                  if s.name == "camera1" else s for s in sensors)
    return _calibrate(1, sensors), _calibrate(2, sensors), _calibrate(3, moved, sensors)


def test_two_calibrations_of_an_unchanged_rig_agree(calibrations):
    a, b, _ = calibrations
    res = diff(a, b)
    assert res.status == "unchanged" and set(res.sensors) == {"camera1", "radar1"}
    radar = res.sensors["radar1"]
    assert set(radar.untested) == {"roll", "pitch", "z"} and radar.test.dof == 3
    assert "not compared (only bounded)" in radar.headline
    assert radar.change["rotation_deg"] == pytest.approx(abs(np.degrees(radar.test.delta[2])), rel=1e-6)


def test_a_moved_camera_is_significant(calibrations):
    a, _, c = calibrations
    res = diff(a, c)
    assert res.status == "moved" and res.moved == ("camera1",)
    cam = res.sensors["camera1"]
    assert cam.test.p_value < 1e-3 and cam.headline.startswith("moved: ") and "+-" in cam.headline
    assert 0.5 < cam.change["rotation_deg"] < 1.2  # 0.86 deg moved
    d = res.to_dict()
    assert d["moved"] == ["camera1"] and d["sensors"]["camera1"]["p_value"] < 1e-3


def test_another_reference_is_expressed_in_the_old_one(calibrations):
    a, b, _ = calibrations
    b2 = calibrate(simulate(prius_like_rig(), make_rig_placements(np.random.default_rng(4), prius_like_rig(), 15,
                                                                   min_fraction=1.0), rng=4).dataset,
                   CalibrationOptions(reference="camera1", cross_validation_folds=0))
    res = diff(a, b2)
    assert res.reference == "lidar1" and res.status == "unchanged"


def test_refusals(calibrations):
    a, b, _ = calibrations
    sb = StoredCalibration.from_result(b, "b.yaml")
    only_ref = replace(sb, sensors={"lidar1": sb.sensors["lidar1"]}, relative={})
    with pytest.raises(InputError, match="share no sensor besides the reference 'lidar1'"):
        diff(a, only_ref)
    no_ref = replace(sb, reference="camera1", sensors={k: v for k, v in sb.sensors.items() if k != "lidar1"},
                     relative={})
    with pytest.raises(InputError, match="b.yaml: has no sensor 'lidar1'"):
        diff(a, no_ref)
    with pytest.raises(InputError, match="alpha must be in"):
        diff(a, b, alpha=0.0)
