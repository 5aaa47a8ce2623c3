"""rigcal.problem.check: new detections judged under a stored calibration, on simulated rigs with
known ground truth - unchanged, one sensor moved (found, named, measured), a 2D radar moved only
in the directions it does not measure, too little data, bad input."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rigcal.dataset import Dataset, SensorDetections
from rigcal.errors import InputError
from rigcal.geometry.se3 import se3_exp
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.check import CANNOT_TELL, MOVED, UNCHANGED, CheckOptions, check
from rigcal.problem.stored import StoredCalibration
from rigcal.sim.rig import make_rig_placements, prius_like_rig, random_rig, simulate
from rigcal.study.board_coverage import NoiseSpec, _with_noise


@pytest.fixture(scope="module")
def rig():
    """A 6-sensor rig of the coverage population and its calibration on 15 boards."""
    rng = np.random.default_rng([21, 3])
    sensors = _with_noise(random_rig(rng, 2, 2, 2), NoiseSpec())
    sim = simulate(sensors, make_rig_placements(rng, sensors, 15), rng=rng)
    result = calibrate(sim.dataset, CalibrationOptions(cross_validation_folds=0))
    return sensors, result


def _moved(sensors, name, xi):
    return tuple(s.with_pose(s.T_rig_sensor @ se3_exp(np.asarray(xi, dtype=float))) if s.name == name else s
                 for s in sensors)


def _data(sensors, seed, boards, like=None):
    rng = np.random.default_rng(seed)
    return simulate(sensors, make_rig_placements(rng, like or sensors, boards), rng=rng).dataset


def test_unchanged_rig_every_sensor_unchanged_with_its_power(rig):
    sensors, result = rig
    res = check(result, _data(sensors, 1, 10))
    assert res.status == UNCHANGED and res.moved == ()
    for s in res.sensors.values():
        assert s.status == UNCHANGED, s.headline
        assert 0.0 < s.test.p_value <= 1.0 and s.test.dof == (3 if s.kind == "radar" else 6)
        # the power is quoted: a lidar with 4 mm noise finds a few-cm move on 10 boards
        assert s.test.detectable_translation_m < (0.2 if s.kind != "lidar" else 0.02)
    dt, dr = res.detectable
    assert 0 < dt < 0.2 and 0 < dr < 5
    for p in res.pairs.values():
        assert p.before < 3.0 and p.after == p.before  # nothing moved, nothing re-estimated
    assert list(res.to_dict()["sensors"]) == list(res.sensors)


def test_a_moved_camera_is_found_named_and_measured(rig):
    sensors, result = rig
    xi = np.r_[np.radians([0.8, -0.5, 0.6]), 0.025, -0.015, 0.02]
    res = check(StoredCalibration.from_result(result), _data(_moved(sensors, "camera1", xi), 2, 10, sensors))
    assert res.status == MOVED and res.moved == ("camera1",)
    cam = res.worst
    assert cam.name == "camera1" and cam.step == 1 and cam.test.p_value < 1e-3
    assert cam.headline.startswith("moved: ") and "p < 0.001" in cam.headline
    # the re-estimated change is the true move, to within its reported uncertainty
    truth_deg = math.degrees(np.linalg.norm(xi[:3]))
    assert abs(cam.change["rotation_deg"] - truth_deg) < 4 * math.degrees(math.sqrt(np.trace(cam.test.covariance[:3, :3])))
    for name, s in res.sensors.items():
        if name != "camera1":
            assert s.status != MOVED, (name, s.headline)
    # the camera's pairs agree with the noise model once it is re-estimated
    for label, p in res.pairs.items():
        if "camera1" in label:
            assert p.before > p.after


def test_the_reference_moving_is_named_as_the_reference(rig):
    sensors, result = rig
    xi = np.r_[np.radians([0.0, 0.4, 0.3]), 0.01, 0.02, -0.015]
    res = check(result, _data(_moved(sensors, "lidar1", xi), 3, 10, sensors))
    assert res.moved[:1] == ("lidar1",) or "lidar1" in res.worst.alternatives, res.worst.headline


def test_a_radar_moved_only_in_its_unmeasured_directions_is_not_called_moved(rig):
    sensors, result = rig
    xi = np.r_[np.radians([0.5, -0.6, 0.0]), 0.0, 0.0, 0.03]  # roll, pitch, z: what it does not measure
    res = check(result, _data(_moved(sensors, "radar1", xi), 4, 10, sensors))
    radar = res.sensors["radar1"]
    assert radar.status != MOVED and set(radar.untested) >= {"roll", "pitch", "z"}
    assert set(radar.test.tested) == {"yaw", "x", "y"}


def test_a_sensor_missing_from_the_data_or_seeing_no_board_cannot_be_told(rig):
    sensors, result = rig
    data = _data(sensors, 5, 5)
    blind = Dataset(tuple(replace(s, points=np.full_like(s.points, np.nan)) if s.name == "radar2" else s
                          for s in data.sensors if s.name != "camera2"), data.board, source="new")
    res = check(result, blind)
    assert res.status == CANNOT_TELL
    assert res.sensors["camera2"].reason == "not in the data" and res.sensors["camera2"].test is None
    assert "shares no board" in res.sensors["radar2"].reason
    assert res.sensors["lidar2"].status == UNCHANGED


def test_two_boards_are_too_few(rig):
    sensors, result = rig
    res = check(result, _data(sensors, 6, 2))
    assert all(s.status == CANNOT_TELL for s in res.sensors.values())
    assert any("too few boards" in s.reason for s in res.sensors.values())


def test_two_sensors_cannot_tell_which_moved():
    rng = np.random.default_rng(8)
    sensors = prius_like_rig()[:2]  # lidar and camera only
    sim = simulate(sensors, make_rig_placements(rng, sensors, 15, min_fraction=1.0), rng=rng)
    result = calibrate(sim.dataset, CalibrationOptions(cross_validation_folds=0))
    moved = _moved(sensors, "camera1", np.r_[0.0, 0.02, 0.0, 0.05, 0.0, 0.0])
    res = check(result, _data(moved, 9, 6, sensors))
    assert res.status == MOVED and len(res.moved) == 1
    other = next(s for s in res.sensors.values() if s.status != MOVED)
    assert other.status == CANNOT_TELL and res.worst.alternatives == (other.name,)
    assert "cannot tell which" in res.worst.headline


def test_bad_input_names_the_sensor(rig):
    sensors, result = rig
    data = _data(sensors, 7, 4)
    extra = Dataset(data.sensors + (replace(data.sensors[0], name="lidar9"),), data.board, source="new.yaml")
    with pytest.raises(InputError, match=r"new.yaml: sensor\(s\) lidar9 are not in the calibration"):
        check(result, extra)
    swapped = Dataset(tuple(SensorDetections("camera1", s.kind, s.points) if s.name == "lidar2" else s
                            for s in data.sensors if s.name != "camera1"), data.board, source="new.yaml")
    with pytest.raises(InputError, match="sensor 'camera1' is a lidar in the data but a camera"):
        check(result, swapped)
    lonely = []
    for i, s in enumerate(data.sensors):  # each board seen by one sensor only
        pts = np.array(s.points)
        pts[[k for k in range(data.num_boards) if k % len(data.sensors) != i]] = np.nan
        lonely.append(replace(s, points=pts))
    with pytest.raises(InputError, match="no board is seen by two sensors"):
        check(result, Dataset(tuple(lonely), data.board, source="lonely.yaml"))
    no_noise = replace(StoredCalibration.from_result(result), noise_model={})
    with pytest.raises(InputError, match="noise_model.lidar1.x: missing"):
        check(no_noise, data)
    with pytest.raises(InputError, match="alpha must be in"):
        CheckOptions(alpha=0.7)


def test_the_stored_term_with_the_joint_covariance_is_exact():
    """``sum_o W_o r_o``'s covariance from the joint covariance equals a Monte Carlo estimate
    over sampled stored errors, and the bound used without it is at least as large."""
    from rigcal.geometry.se3 import adjoint
    from rigcal.problem.check import _stored_term

    rng = np.random.default_rng(11)
    s = prius_like_rig()
    res = calibrate(simulate(s, make_rig_placements(rng, s, 10, min_fraction=1.0), rng=rng).dataset,
                    CalibrationOptions(cross_validation_folds=0))
    st = StoredCalibration.from_result(res)
    W = {o: rng.normal(size=(6, 6)) for o in ("lidar1", "radar1")}
    exact = _stored_term(st, "camera1", W, {})
    names = list(st.sensors)
    e = rng.multivariate_normal(np.zeros(6 * len(names)), st.joint, size=200_000, method="eigh")
    part = {n: e[:, 6 * i:6 * i + 6] for i, n in enumerate(names)}
    total = sum((part["camera1"] - part[o] @ adjoint(st.T("camera1", o)).T) @ w.T for o, w in W.items())
    assert np.allclose(exact, np.cov(total.T), rtol=0.03, atol=0.03 * np.max(np.abs(exact)))
    bound = _stored_term(replace(st, joint=None), "camera1", W, {
        o: st.relative_covariance(o, "camera1") for o in W})
    assert np.min(np.linalg.eigvalsh(bound - exact)) > -1e-12 * np.max(np.abs(exact))
