"""`rigcal urdf` and `rigcal export` on the shared example and on a rigcal calibration."""

from __future__ import annotations

import difflib
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.geometry.se3 import invert
from rigcal.io.results.urdf import forward_kinematics, parse_urdf, read_original_calibration_yaml

URDF = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tudelft_prius" / "urdf"


@pytest.fixture
def shared():
    if not (URDF / "vehicle.urdf").is_file():
        pytest.skip("../shared/data not present")
    return URDF


def test_urdf_from_the_original_yaml_reproduces_it_by_forward_kinematics(shared, tmp_path, capsys):
    out = tmp_path / "out.urdf"
    assert run(["urdf", str(shared / "vehicle.urdf"), str(shared / "calibration.yaml"), "--out", str(out)]) == 0
    cal = read_original_calibration_yaml((shared / "calibration.yaml").read_text(), "calibration.yaml")
    urdf = parse_urdf(out.read_text(), str(out))
    # p_target = transform @ p_source: the target's pose in the source frame is the inverse
    T = forward_kinematics(urdf, cal.source, cal.target)
    np.testing.assert_allclose(T, invert(cal.T_target_source), atol=1e-9)
    diff = [
        ln for ln in difflib.unified_diff(
            (shared / "vehicle.urdf").read_text().splitlines(), out.read_text().splitlines(), lineterm="", n=0
        ) if ln.startswith(("+", "-")) and not ln.startswith(("+++", "---"))
    ]
    assert len(diff) == 2 and all("<origin" in ln for ln in diff), diff


def test_in_place_keeps_a_backup(shared, tmp_path):
    work = tmp_path / "vehicle.urdf"
    work.write_text((shared / "vehicle.urdf").read_text())
    assert run(["urdf", str(work), str(shared / "calibration.yaml"), "--in-place"]) == 0
    assert (tmp_path / "vehicle.urdf.bak").read_text() == (shared / "vehicle.urdf").read_text()
    assert work.read_text() != (shared / "vehicle.urdf").read_text()


def test_refuses_to_overwrite_the_input_without_in_place(shared, tmp_path, capsys):
    work = tmp_path / "vehicle.urdf"
    work.write_text((shared / "vehicle.urdf").read_text())
    assert run(["urdf", str(work), str(shared / "calibration.yaml"), "--out", str(work)]) == 1
    assert "rigcal: error:" in capsys.readouterr().err
    assert work.read_text() == (shared / "vehicle.urdf").read_text()


def test_unknown_link_is_one_clear_line(shared, tmp_path, capsys):
    cal = tmp_path / "c.yaml"
    cal.write_text("source: camera\ntarget: lidar_top\ntransform: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n")
    assert run(["urdf", str(shared / "vehicle.urdf"), str(cal), "--out", str(tmp_path / "o.urdf")]) == 1
    err = capsys.readouterr().err
    assert "lidar_top" in err and "Traceback" not in err
    assert not (tmp_path / "o.urdf").exists()


@pytest.mark.parametrize("fmt", ["ros1-launch", "ros2-launch", "ros2-run", "yaml", "json"])
def test_export_formats_from_the_original_yaml(shared, tmp_path, fmt):
    out = tmp_path / f"tf.{fmt}"
    assert run(["export", str(shared / "calibration.yaml"), "--format", fmt, "--out", str(out)]) == 0
    text = out.read_text()
    assert "laser_link" in text and "camera" in text
    if fmt == "json":
        data = json.loads(text)
        assert data  # parses


def test_export_json_round_trips_the_matrix(shared, tmp_path, capsys):
    assert run(["export", str(shared / "calibration.yaml"), "--format", "json"]) == 0
    text = capsys.readouterr().out
    data = json.loads(text)
    cal = read_original_calibration_yaml((shared / "calibration.yaml").read_text(), "c")
    found = [np.asarray(v) for v in _matrices(data)]
    assert any(np.allclose(m, invert(cal.T_target_source), atol=1e-12) for m in found)


def _matrices(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _matrices(v)
    elif isinstance(obj, list):
        a = np.asarray(obj, dtype=object)
        if a.shape == (4, 4):
            yield np.asarray(obj, dtype=float)
        else:
            for v in obj:
                yield from _matrices(v)


def test_not_a_calibration_file(tmp_path, capsys):
    bad = tmp_path / "x.yaml"
    bad.write_text("hello: world\n")
    assert run(["export", str(bad), "--format", "yaml"]) == 1
    assert "not a calibration file" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# motion-capture results into the robot (issue 19, item 5)

MOCAP_ROBOT = """<?xml version="1.0"?>
<robot name="husky">
  <link name="base_link"/>
  <link name="velodyne_link"/>
  <joint name="velodyne_joint" type="fixed">
    <parent link="base_link"/><child link="velodyne_link"/>
    <origin xyz="0.2 0 0.4" rpy="0 0 0"/>
  </joint>
  <link name="camera_link"/>
  <joint name="camera_joint" type="fixed">
    <parent link="base_link"/><child link="camera_link"/>
    <origin xyz="0.3 0.1 0.3" rpy="0 0 1.5"/>
  </joint>
  <link name="camera_optical_frame"/>
  <joint name="camera_optical_joint" type="fixed">
    <parent link="camera_link"/><child link="camera_optical_frame"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
</robot>
"""


def _mocap_result(reference_frame: str = "base_link"):
    from rigcal.dataset import SensorKind
    from rigcal.geometry import from_rt, so3_exp
    from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate

    rng = np.random.default_rng(23)

    def est(name, kind, frame, T):
        return SensorEstimate(name, kind, frame, T, np.eye(6) * 1e-8, {k: 1e-4 for k in STD_KEYS})

    T_lidar = from_rt(so3_exp(rng.normal(0, 0.05, 3)), [0.21, 0.01, 0.41])
    T_cam = from_rt(so3_exp(np.array([-1.2, 0.0, 0.1])) @ so3_exp(rng.normal(0, 0.05, 3)), [0.31, 0.09, 0.3])
    return CalibrationResult(
        mode="mocap", reference="robot", converged=True,
        sensors={"lidar1": est("lidar1", SensorKind.LIDAR, "velodyne_link", T_lidar),
                 "camera1": est("camera1", SensorKind.CAMERA, "camera_link", T_cam)},
        rmse_m={}, per_board_m={}, outliers={}, reference_frame=reference_frame,
    )


def test_a_mocap_calibration_goes_into_the_urdf_and_exports_from_robot_frame(tmp_path, capsys):
    """`rigcal mocap` results are relative to the robot body: the link is mocap.yaml's
    robot_frame (recorded in calibration.yaml), or --body-link; calibration.launch publishes
    from it; a camera_link with an optical child gets its optical pose there (REP 103)."""
    from rigcal.io.results.calibration import write_results

    result = _mocap_result()
    write_results(result, tmp_path / "res")
    cal = tmp_path / "res" / "calibration.yaml"
    launch = ET.fromstring((tmp_path / "res" / "calibration.launch").read_text())
    assert {n.get("args").split()[7] for n in launch.findall("node")} == {"base_link"}
    robot = tmp_path / "husky.urdf"
    robot.write_text(MOCAP_ROBOT)
    assert run(["urdf", str(robot), str(cal), "--out", str(tmp_path / "out.urdf")]) == 0
    out = parse_urdf((tmp_path / "out.urdf").read_text(), "out")
    T_lidar = result.sensors["lidar1"].T_reference_sensor
    T_cam = result.sensors["camera1"].T_reference_sensor
    np.testing.assert_allclose(forward_kinematics(out, "base_link", "velodyne_link"), T_lidar, atol=1e-9)
    np.testing.assert_allclose(forward_kinematics(out, "base_link", "camera_optical_frame"), T_cam, atol=1e-9)
    assert "relative to 'base_link'" in capsys.readouterr().out
    assert run(["export", str(cal), "--urdf", str(robot), "--format", "json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["parent_frame"] == "base_link"
    assert doc["transforms"]["camera_optical_frame"]["parent"] == "camera_link"
    T = np.array(doc["transforms"]["camera_link"]["T_parent_child"]) @ np.array(
        doc["transforms"]["camera_optical_frame"]["T_parent_child"])
    np.testing.assert_allclose(T, T_cam, atol=1e-9)
    # --body-link names another frame for the body
    assert run(["export", str(cal), "--format", "yaml", "--body-link", "chassis"]) == 0
    assert "parent_frame: chassis" in capsys.readouterr().out


def test_an_old_mocap_calibration_without_robot_frame_names_the_way_out(tmp_path, capsys):
    import yaml

    from rigcal.io.results.calibration import write_results

    write_results(_mocap_result(reference_frame=""), tmp_path / "res")
    cal = tmp_path / "res" / "calibration.yaml"
    data = yaml.safe_load(cal.read_text())
    del data["frames"]
    cal.write_text(yaml.safe_dump(data))
    robot = tmp_path / "husky.urdf"
    robot.write_text(MOCAP_ROBOT)
    assert run(["urdf", str(robot), str(cal), "--out", str(tmp_path / "o.urdf")]) == 1
    err = capsys.readouterr().err
    assert "no link named 'robot'" in err and "--body-link" in err and err.count("\n") == 1
    assert run(["urdf", str(robot), str(cal), "--out", str(tmp_path / "o.urdf"), "--body-link", "base_link"]) == 0


@pytest.mark.slow
def test_rigcal_mocap_output_into_the_urdf_export_and_camchain(tmp_path, capsys):
    """The whole path: `rigcal mocap` on a simulated recording, then `rigcal urdf`, `rigcal
    export` and `rigcal export --format kalibr --rig mocap.yaml` on its calibration.yaml."""
    import yaml

    from rigcal.io.config.camchain import read_camchain
    from rigcal.sim.mocap_scene import two_sensor_rig, write_mocap_scene

    scene = write_mocap_scene(tmp_path, two_sensor_rig(), seed=0, holds=3, exclusive=False)
    out = tmp_path / "out"
    assert run(["mocap", str(scene.config_path), "--out", str(out), "--max-overlays", "0"]) == 0
    cal = out / "calibration.yaml"
    data = yaml.safe_load(cal.read_text())
    assert data["frames"]["reference_frame"] == "base_link"  # mocap.yaml's robot_frame
    launch = ET.fromstring((out / "calibration.launch").read_text())
    assert {n.get("args").split()[7] for n in launch.findall("node")} == {"base_link"}
    robot = tmp_path / "husky.urdf"
    robot.write_text(MOCAP_ROBOT)
    assert run(["urdf", str(robot), str(cal), "--out", str(tmp_path / "out.urdf")]) == 0
    urdf = parse_urdf((tmp_path / "out.urdf").read_text(), "out")
    for name, link in (("lidar1", "velodyne_link"), ("camera1", "camera_optical_frame")):
        T = np.array(data["sensors"][name]["T_reference_sensor"])
        np.testing.assert_allclose(forward_kinematics(urdf, "base_link", link), T, atol=1e-9)
    assert run(["export", str(cal), "--format", "kalibr", "--rig", str(scene.config_path),
                "--out", str(tmp_path / "camchain.yaml")]) == 0
    chain = read_camchain(tmp_path / "camchain.yaml")
    assert list(chain.cameras) == ["cam0"] and chain.topics == {"cam0": "/F1/image_raw"}
