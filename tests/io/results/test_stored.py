"""rigcal.io.results.stored: calibration.yaml read back as the value check and diff compare with."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.results.calibration import result_to_yaml_text, write_results
from rigcal.io.results.stored import parse_stored_calibration, read_stored_calibration
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.stored import StoredCalibration
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def result():
    rng = np.random.default_rng(3)
    s = prius_like_rig()
    return calibrate(simulate(s, make_rig_placements(rng, s, 12, min_fraction=1.0), rng=rng).dataset,
                     CalibrationOptions(cross_validation_folds=0))


def test_round_trip_equals_the_result_in_memory(result, tmp_path):
    write_results(result, tmp_path)
    st = read_stored_calibration(tmp_path)  # the folder: its calibration.yaml
    mem = StoredCalibration.from_result(result)
    assert st.reference == "lidar1" and st.names == mem.names and st.source.endswith("calibration.yaml")
    for n in st.names:
        assert np.array_equal(st.sensors[n].T_reference_sensor, mem.sensors[n].T_reference_sensor)
        assert np.allclose(st.sensors[n].covariance, mem.sensors[n].covariance, rtol=1e-12, atol=1e-20)
        assert st.sensors[n].bounded == mem.sensors[n].bounded
    assert st.noise_model == mem.noise_model and st.num_boards == 12
    for a in st.names:
        for b in st.names:
            assert np.allclose(st.relative_covariance(a, b), mem.relative_covariance(a, b), atol=1e-20)


def test_relative_covariance_inverts_the_pair(result):
    st = StoredCalibration.from_result(result)
    C_ab = st.relative_covariance("camera1", "radar1")
    C_ba = st.relative_covariance("radar1", "camera1")
    from rigcal.geometry.se3 import adjoint

    Ad = adjoint(st.T("camera1", "radar1"))
    assert np.allclose(C_ba, Ad @ C_ab @ Ad.T, rtol=1e-9, atol=1e-18)
    assert np.allclose(st.relative_covariance("lidar1", "camera1"), st.sensors["camera1"].covariance)


@pytest.mark.parametrize("edit,match", [
    (lambda t: "source: a\ntarget: b\ntransform: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n",
     "original tool's per-sensor file has no uncertainty"),
    (lambda t: "body_frame: base_link\nsensors: {}\n", "an absolute.yaml"),
    (lambda t: t.replace("reference: lidar1", "reference: lidar7"), "reference: expected one of the sensors"),
    (lambda t: t.replace("kind: camera", "kind: sonar"), "sensors.camera1.kind: unknown sensor kind 'sonar'"),
    (lambda t: t.replace("    covariance:", "    covariancex:", 1), "sensors.lidar1: missing covariance"),
    (lambda t: "[1, 2]\n", "expected rigcal's calibration.yaml"),
])
def test_bad_files_are_named(result, edit, match):
    with pytest.raises(InputError, match=match):
        parse_stored_calibration(edit(result_to_yaml_text(result)), "cal.yaml")


def test_a_covariance_that_is_not_one_is_refused(result):
    text = result_to_yaml_text(result)
    data = __import__("yaml").safe_load(text)
    data["sensors"]["camera1"]["covariance"][0][0] = -1.0
    with pytest.raises(InputError, match="sensors.camera1.covariance: not a covariance"):
        parse_stored_calibration(__import__("yaml").safe_dump(data), "cal.yaml")
    data["sensors"]["camera1"]["covariance"] = [[1.0]]
    with pytest.raises(InputError, match=r"covariance: expected a 6x6 matrix, got shape \(1, 1\)"):
        parse_stored_calibration(__import__("yaml").safe_dump(data), "cal.yaml")


def test_the_joint_covariance_round_trips_and_agrees_with_every_pair(result, tmp_path):
    """calibration.yaml's joint_covariance: each sensor's block is its own covariance, each pair's
    relative covariance follows from it, and read back it equals the result's."""
    from rigcal.geometry.se3 import adjoint

    J = result.joint_covariance
    names = list(result.sensors)
    assert J.shape == (6 * len(names), 6 * len(names))
    write_results(result, tmp_path)
    st = read_stored_calibration(tmp_path)
    assert np.allclose(st.joint, J, rtol=1e-12, atol=1e-22)
    for i, a in enumerate(names):
        assert np.allclose(J[6 * i:6 * i + 6, 6 * i:6 * i + 6], result.sensors[a].covariance, atol=1e-22)
        for j, b in enumerate(names[i + 1:], i + 1):
            # T_a_b's right perturbation: e_b - Ad(T_b_a) e_a
            A = np.hstack([-adjoint(st.T(b, a)), np.eye(6)])
            idx = np.r_[6 * i:6 * i + 6, 6 * j:6 * j + 6]
            assert np.allclose(A @ J[np.ix_(idx, idx)] @ A.T, result.relative[f"{a}-{b}"].covariance,
                               rtol=1e-6, atol=1e-16)


def test_a_hand_edited_file_keeps_the_joint_only_where_it_still_holds(result):
    import yaml

    data = yaml.safe_load(result_to_yaml_text(result))
    # a sensor removed by hand: the joint's block of the others
    less = dict(data, sensors={k: v for k, v in data["sensors"].items() if k != "radar1"}, relative={})
    st = parse_stored_calibration(yaml.safe_dump(less), "less.yaml")
    assert st.joint.shape == (6 * (len(data["sensors"]) - 1),) * 2
    # a sensor's covariance edited by hand: the joint no longer describes the file
    edited = yaml.safe_load(result_to_yaml_text(result))
    edited["sensors"]["camera1"]["covariance"] = (4 * np.array(edited["sensors"]["camera1"]["covariance"])).tolist()
    assert parse_stored_calibration(yaml.safe_dump(edited), "edited.yaml").joint is None
    broken = yaml.safe_load(result_to_yaml_text(result))
    broken["joint_covariance"]["matrix"][0][1] += 1.0
    with pytest.raises(InputError, match=r"joint_covariance\.matrix: expected a finite symmetric matrix"):
        parse_stored_calibration(yaml.safe_dump(broken), "broken.yaml")
    broken["joint_covariance"] = {"sensors": ["lidar1", "lidar1"], "matrix": []}
    with pytest.raises(InputError, match=r"joint_covariance\.sensors: expected distinct sensor names"):
        parse_stored_calibration(yaml.safe_dump(broken), "broken.yaml")
