"""Calibration files read back (rigcal.io.results.calibration_files): nominal poses from the
robot's URDF or a calibration.yaml (`--initial`), and the motion-capture calibration.yaml."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, matrix_from_rpy
from rigcal.io.results.calibration_files import (
    parse_calibration_transforms,
    read_initial_poses,
)
from rigcal.io.results.frames import T_BODY_OPTICAL

ROBOT = """<?xml version="1.0"?>
<robot name="car">
  <link name="base_link"/>
  <link name="lidar_link"/>
  <joint name="lidar_joint" type="fixed">
    <parent link="base_link"/><child link="lidar_link"/>
    <origin xyz="1.2 0 1.9" rpy="0.01 -0.02 0.03"/>
  </joint>
  <link name="cam_link"/>
  <joint name="cam_joint" type="fixed">
    <parent link="base_link"/><child link="cam_link"/>
    <origin xyz="1.6 0.27 1.3" rpy="0 0.05 -0.01"/>
  </joint>
  <link name="cam_optical_frame"/>
  <joint name="cam_optical_joint" type="fixed">
    <parent link="cam_link"/><child link="cam_optical_frame"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
  <link name="radar_link"/>
  <joint name="radar_joint" type="fixed">
    <parent link="base_link"/><child link="radar_link"/>
    <origin xyz="3.7 -0.05 0.5" rpy="0 0 0"/>
  </joint>
  <link name="arm"/>
  <joint name="arm_joint" type="revolute">
    <parent link="base_link"/><child link="arm"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <link name="arm_cam"/>
  <joint name="arm_cam_joint" type="fixed">
    <parent link="arm"/><child link="arm_cam"/>
  </joint>
</robot>
"""

SENSORS = [("lidar1", SensorKind.LIDAR, "lidar_link"), ("camera1", SensorKind.CAMERA, "cam_link"),
           ("radar1", SensorKind.RADAR, "radar_link")]


def _T(xyz, rpy):
    return from_rt(matrix_from_rpy(np.array(rpy, dtype=float)), xyz)


@pytest.fixture
def robot(tmp_path):
    p = tmp_path / "robot.urdf"
    p.write_text(ROBOT)
    return p


def test_nominal_poses_from_the_robots_urdf(robot):
    poses = read_initial_poses(robot, SENSORS, "lidar1")
    T_base_lidar = _T([1.2, 0, 1.9], [0.01, -0.02, 0.03])
    T_base_cam = _T([1.6, 0.27, 1.3], [0, 0.05, -0.01])
    T_base_radar = _T([3.7, -0.05, 0.5], [0, 0, 0])
    np.testing.assert_allclose(poses["lidar1"], np.eye(4), atol=1e-15)
    # a camera's nominal pose is its optical frame's (REP 103), as its calibration is
    np.testing.assert_allclose(poses["camera1"], invert(T_base_lidar) @ T_base_cam @ T_BODY_OPTICAL, atol=1e-12)
    np.testing.assert_allclose(poses["radar1"], invert(T_base_lidar) @ T_base_radar, atol=1e-12)
    # another reference: the same rig seen from the camera's optical frame
    from_cam = read_initial_poses(robot, SENSORS, "camera1")
    np.testing.assert_allclose(from_cam["radar1"], invert(poses["camera1"]) @ poses["radar1"], atol=1e-12)


def test_the_same_poses_from_a_calibration_yaml_are_re_expressed_in_the_reference(robot, tmp_path):
    poses = read_initial_poses(robot, SENSORS, "lidar1")
    doc = {"reference": "camera1", "sensors": {
        n: {"T_reference_sensor": (invert(poses["camera1"]) @ T).tolist()} for n, T in poses.items()}}
    p = tmp_path / "calibration.yaml"
    p.write_text(yaml.safe_dump(doc))
    again = read_initial_poses(p, reference="lidar1")
    for name in poses:
        np.testing.assert_allclose(again[name], poses[name], atol=1e-12)
    with pytest.raises(InputError, match=r"the reference sensor 'sonar' is not in this calibration"):
        read_initial_poses(p, reference="sonar")


def test_urdf_refusals_name_the_sensor_frame_and_links(robot):
    with pytest.raises(InputError, match=r"robot.urdf: sensor 'radar2' \(radar\): its frame_id "
                                         r"'rear_radar' is not a link of the URDF \(links: base_link, "
                                         r"lidar_link, cam_link"):
        read_initial_poses(robot, SENSORS + [("radar2", SensorKind.RADAR, "rear_radar")], "lidar1")
    with pytest.raises(InputError, match=r"sensor 'cam2': no nominal pose relative to the reference "
                                         r"'lidar1' from the URDF: .*non-fixed joint\(s\) 'arm_joint'"):
        read_initial_poses(robot, SENSORS + [("cam2", SensorKind.CAMERA, "arm_cam")], "lidar1")
    with pytest.raises(InputError, match=r"needs the rig's sensors"):
        read_initial_poses(robot)


def test_calibrate_initial_urdf_from_the_command_line(tmp_path, capsys):
    """`rigcal calibrate --initial robot.urdf`: a sensor whose frame_id the URDF lacks is one
    error line naming it; with every link there, the run takes the URDF's nominal poses and
    calibration.yaml records the URDF the frames were named in."""
    from rigcal.io.dataset.manifest import write_dataset
    from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate
    import dataclasses

    rng = np.random.default_rng(7)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 10, min_fraction=1.0), rng=rng)
    frames = {"lidar1": "lidar_link", "camera1": "cam_link", "radar1": "front_radar"}
    ds = dataclasses.replace(sim.dataset, sensors=tuple(
        dataclasses.replace(s, frame_id=frames[s.name]) for s in sim.dataset.sensors))
    manifest = write_dataset(ds, tmp_path / "data")
    robot = tmp_path / "robot.urdf"
    robot.write_text(ROBOT)
    assert run(["calibrate", str(manifest), "--initial", str(robot), "--out", str(tmp_path / "a")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sensor 'radar1' (radar): its frame_id 'front_radar'" in err
    assert not (tmp_path / "a").exists()
    # nominal poses at the truth (a URDF written from it): the radar's z, roll, pitch held there
    rig = "".join(
        f'  <link name="{f}"/>\n  <joint name="{f}_joint" type="fixed">\n    <parent link="base_link"/>'
        f'<child link="{f}"/>\n    <origin xyz="{" ".join(map(repr, sim.truth[n][:3, 3].tolist()))}" '
        f'rpy="{" ".join(map(repr, _rpy(sim.truth[n] @ (invert(T_BODY_OPTICAL) if n == "camera1" else np.eye(4)))))}"/>\n  </joint>\n'
        for n, f in frames.items())
    rig += ('  <link name="cam_optical"/>\n  <joint name="cam_optical_joint" type="fixed">\n'
            '    <parent link="cam_link"/><child link="cam_optical"/>\n'
            '    <origin rpy="-1.5707963267948966 0 -1.5707963267948966"/>\n  </joint>\n')
    robot.write_text(f'<?xml version="1.0"?>\n<robot name="prius">\n  <link name="base_link"/>\n{rig}</robot>\n')
    assert run(["calibrate", str(manifest), "--initial", str(robot), "--hold-radar-plane",
                "--out", str(tmp_path / "b")]) == 0
    data = yaml.safe_load((tmp_path / "b" / "calibration.yaml").read_text())
    assert data["frames"]["urdf"] == str(robot)
    assert data["frames"]["sensors"]["camera1"]["measured_frame"] == "cam_optical"
    T_radar = np.array(data["sensors"]["radar1"]["T_reference_sensor"])
    truth = invert(sim.truth["lidar1"]) @ sim.truth["radar1"]
    # held at the nominal (here: true) mounting: the radar's own z, roll and pitch as the URDF
    # says (x, y and yaw move along the radar plane)
    D = invert(truth) @ T_radar
    assert abs(D[2, 3]) < 1e-9 and np.abs(D[:3, 2] - [0, 0, 1]).max() < 1e-9
    assert np.abs(D[:2, 3]).max() > 1e-6  # not held everywhere: the plane's directions moved


def _rpy(T):
    R = T[:3, :3]
    return [math.atan2(R[2, 1], R[2, 2]), math.asin(-R[2, 0]), math.atan2(R[1, 0], R[0, 0])]


def test_a_mocap_calibration_yaml_is_relative_to_the_recorded_robot_frame():
    doc = {"reference": "robot", "mode": "mocap",
           "frames": {"reference_frame": "base_link", "sensors": {}},
           "sensors": {"lidar1": {"kind": "lidar", "frame_id": "velodyne", "T_reference_sensor": np.eye(4).tolist()}}}
    cal = parse_calibration_transforms(yaml.safe_dump(doc), "cal.yaml")
    assert (cal.kind, cal.parent_frame, list(cal.transforms)) == ("mocap", "base_link", ["velodyne"])
    doc["mode"] = "fcpe"
    with pytest.raises(InputError, match=r"reference 'robot' is not one of the sensors"):
        parse_calibration_transforms(yaml.safe_dump(doc), "cal.yaml")


def test_batch_refuses_a_urdf_as_initial_guesses(robot, tmp_path, capsys):
    for d in ("car01", "car02"):
        (tmp_path / d).mkdir()
    assert run(["calibrate", "--batch", str(tmp_path / "car01"), str(tmp_path / "car02"),
                "--initial", str(robot), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a URDF needs one rig's sensors" in err
