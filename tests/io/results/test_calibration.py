"""Result writers: calibration YAML/JSON, the original per-sensor YAML, the ROS 1 launch file."""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

import rigcal
from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry import matrix_from_rpy, so3_exp
from rigcal.io.results.calibration import (
    original_sensor_yaml_text,
    result_to_json_text,
    result_to_yaml_text,
    ros1_launch_text,
    write_results,
)
from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate


def estimate(name, kind, frame_id, T, rng) -> SensorEstimate:
    A = rng.normal(size=(6, 6))
    return SensorEstimate(
        name=name,
        kind=kind,
        frame_id=frame_id,
        T_reference_sensor=T,
        covariance=A @ A.T * 1e-6,
        std={k: float(v) for k, v in zip(STD_KEYS, rng.uniform(0.001, 0.1, size=6))},
        held=("z_m", "roll_deg", "pitch_deg") if kind is SensorKind.RADAR else (),
    )


def random_pose(rng) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = so3_exp(rng.normal(size=3))
    T[:3, 3] = rng.normal(scale=2.0, size=3)
    return T


def make_result(extra: dict[str, SensorEstimate] | None = None, seed: int = 3) -> CalibrationResult:
    rng = np.random.default_rng(seed)
    gimbal = np.eye(4)
    gimbal[:3, :3] = matrix_from_rpy(np.array([0.0, math.pi / 2, 0.7]))  # pitch = +90 deg
    gimbal[:3, 3] = [0.1, -0.2, 0.3]
    sensors = {
        "lidar1": estimate("lidar1", SensorKind.LIDAR, "velodyne", np.eye(4), rng),
        "camera1": estimate("camera1", SensorKind.CAMERA, "left", random_pose(rng), rng),
        "radar1": estimate("radar1", SensorKind.RADAR, "radar", random_pose(rng), rng),
        "radar3d_1": estimate("radar3d_1", SensorKind.RADAR3D, "radar_3d", gimbal, rng),
    }
    sensors.update(extra or {})
    return CalibrationResult(
        mode="fcpe",
        reference="lidar1",
        converged=True,
        sensors=sensors,
        rmse_m={"lidar1-camera1": 0.015, "lidar1-radar1": 0.0142, "camera1-radar1": float("nan")},
        per_board_m={"lidar1-camera1": {0: 0.01, 3: 1 / 3}},
        outliers={"radar1": (4,)},
        ignored={"lidar1": (0, 28)},
        warnings=("radar1: 2 boards outside the field of view",),
        iterations=12,
        cost=0.123456789012345678,
        num_boards=29,
        noise_sigma_m={"lidar1": (0.01, 0.02)},
        noise_iterations=2,
        solve_time_s=0.5,
    )


def test_yaml_text_round_trips_to_dict_exactly():
    result = make_result()
    text = result_to_yaml_text(result)
    loaded = yaml.safe_load(text)
    expected = result.to_dict()
    frames = loaded.pop("frames")  # the frame contract's block, beside to_dict()
    assert frames["reference_frame"] == "velodyne" and frames["root"] == "velodyne"
    assert frames["sensors"]["camera1"]["measured_frame"] == result.sensors["camera1"].frame_id
    assert math.isnan(loaded["rmse_m"].pop("camera1-radar1"))
    expected["rmse_m"].pop("camera1-radar1")
    assert loaded == expected  # floats bit for bit
    assert list(loaded) == list(expected)  # key order kept (sort_keys=False)
    assert not re.search(r"\[[^\]]|\{[^}]", text)  # block style (only empty [] / {} inline)


def test_json_text_is_strict_and_exact():
    result = make_result()
    text = result_to_json_text(result)
    loaded = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))
    assert loaded["rmse_m"]["camera1-radar1"] is None
    assert loaded["per_board_m"]["lidar1-camera1"] == {"0": 0.01, "3": 1 / 3}
    T = np.array(loaded["sensors"]["camera1"]["T_reference_sensor"])
    np.testing.assert_array_equal(T, result.sensors["camera1"].T_reference_sensor)
    assert loaded["cost"] == result.cost


def test_original_sensor_yaml_is_the_inverse_pose():
    result = make_result()
    for name, est in result.sensors.items():
        data = yaml.safe_load(original_sensor_yaml_text(result, name))
        assert list(data) == ["target", "source", "transform"]
        assert data["target"] == est.frame_id
        assert data["source"] == "velodyne"
        T_sensor_reference = np.array(data["transform"])
        assert T_sensor_reference.shape == (4, 4)
        np.testing.assert_allclose(T_sensor_reference @ est.T_reference_sensor, np.eye(4), atol=1e-12)
        # p_target = transform @ p_source: a point in the reference frame maps into the sensor
        p_ref = np.array([1.0, 2.0, 3.0, 1.0])
        np.testing.assert_allclose(
            est.T_reference_sensor @ (T_sensor_reference @ p_ref), p_ref, atol=1e-12
        )
    ref = yaml.safe_load(original_sensor_yaml_text(result, "lidar1"))
    np.testing.assert_array_equal(ref["transform"], np.eye(4))


def test_original_sensor_yaml_unknown_sensor():
    with pytest.raises(InputError, match=r"unknown sensor 'sonar1' \(calibrated sensors: lidar1, camera1, radar1, radar3d_1\)"):
        original_sensor_yaml_text(make_result(), "sonar1")


def pose_from_args(numbers: list[float]) -> np.ndarray:
    """x y z qx qy qz qw (tf2_ros's quaternion form) -> 4x4, with the formula written out."""
    x, y, z, qx, qy, qz, qw = numbers
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    T[:3, 3] = [x, y, z]
    return T


def test_launch_reconstructs_T_reference_sensor():
    result = make_result()
    text = ros1_launch_text(result)
    root = ET.fromstring(text)  # well-formed XML
    assert root.tag == "launch"
    nodes = root.findall("node")
    assert len(nodes) == 3  # every sensor but the reference
    names = set()
    for node, sensor in zip(nodes, ["camera1", "radar1", "radar3d_1"]):
        assert node.get("pkg") == "tf2_ros" and node.get("type") == "static_transform_publisher"
        names.add(node.get("name"))
        args = node.get("args").split()
        assert len(args) == 9  # x y z qx qy qz qw parent child: no period (/tf_static)
        assert args[7:] == ["velodyne", result.sensors[sensor].frame_id]
        T = pose_from_args([float(a) for a in args[:7]])
        # full float precision: the published pose is the calibrated one to rounding
        np.testing.assert_allclose(T, result.sensors[sensor].T_reference_sensor, atol=1e-12)
    assert len(names) == 3
    assert f"rigcal {rigcal.__version__}" in text
    assert "x y z [m] qx qy qz qw parent child" in text


def test_launch_node_names_are_valid_and_unique():
    rng = np.random.default_rng(0)
    extra = {
        "cam-1": estimate("cam-1", SensorKind.CAMERA, "c1", random_pose(rng), rng),
        "cam_1": estimate("cam_1", SensorKind.CAMERA, "c2", random_pose(rng), rng),
    }
    nodes = ET.fromstring(ros1_launch_text(make_result(extra))).findall("node")
    names = [n.get("name") for n in nodes]
    assert len(set(names)) == len(names)
    assert all(n.replace("_", "a").isalnum() for n in names)


def test_launch_refuses_frame_ids_with_spaces():
    rng = np.random.default_rng(0)
    extra = {"cam2": estimate("cam2", SensorKind.CAMERA, "left camera", random_pose(rng), rng)}
    with pytest.raises(InputError, match=r"sensor 'cam2': frame_id 'left camera' cannot be used in a launch file"):
        ros1_launch_text(make_result(extra))


def test_write_results(tmp_path):
    result = make_result()
    paths = write_results(result, tmp_path / "out")
    assert [p.name for p in paths] == [
        "calibration.yaml", "lidar1.yaml", "camera1.yaml", "radar1.yaml", "radar3d_1.yaml",
        "calibration.launch",
    ]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        [".rigcal-output"] + [p.name for p in paths]
    )
    assert paths[0].read_text() == result_to_yaml_text(result)
    assert paths[2].read_text() == original_sensor_yaml_text(result, "camera1")
    assert paths[-1].read_text() == ros1_launch_text(result)


def test_write_results_refuses_clashing_names(tmp_path):
    rng = np.random.default_rng(0)
    clash = {"Calibration": estimate("Calibration", SensorKind.CAMERA, "c", random_pose(rng), rng)}
    with pytest.raises(InputError, match=r"sensor 'Calibration': its file Calibration\.yaml would overwrite calibration\.yaml"):
        write_results(make_result(clash), tmp_path)
    case = {"Camera1": estimate("Camera1", SensorKind.CAMERA, "c", random_pose(rng), rng)}
    with pytest.raises(InputError, match=r"sensors 'camera1' and 'Camera1' would write the same file"):
        write_results(make_result(case), tmp_path)
    slash = {"a/b": estimate("a/b", SensorKind.CAMERA, "c", random_pose(rng), rng)}
    with pytest.raises(InputError, match=r"sensor name 'a/b' must not contain"):
        write_results(make_result(slash), tmp_path)
    assert list(tmp_path.iterdir()) == []
