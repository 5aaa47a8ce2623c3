"""absolute.yaml / absolute.json and the body-frame launch files: write -> read round trips."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import yaml

from rigcal.absolute.pipeline import absolute_calibration
from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.results.absolute import (
    ABSOLUTE_JSON_NAME,
    ABSOLUTE_YAML_NAME,
    LAUNCH_NAMES,
    AbsoluteTransforms,
    absolute_to_json_text,
    absolute_to_yaml_text,
    body_transforms,
    parse_absolute_yaml,
    read_absolute_yaml,
    write_absolute,
    write_absolute_launch,
)
from rigcal.sim.rig import SimSensor, make_rig_placements, simulate
from rigcal.sim.vehicle import (
    ExternalScanner,
    SimVehicle,
    simulate_external_scan,
    simulate_rim_labels,
)


@pytest.fixture(scope="module")
def result():
    vehicle, scanner = SimVehicle(), ExternalScanner()
    ext = SimSensor(
        "leica", SensorKind.LIDAR, scanner.T_body_stations[0], sigma_m=0.002,
        max_azimuth_deg=180.0, max_elevation_deg=60.0, min_elevation_deg=-60.0,
    )
    boards = make_rig_placements(4, vehicle.sensors, 12)
    sim = simulate(vehicle.sensors + (ext,), boards, rng=4)
    scan = simulate_external_scan(vehicle, scanner, rng=2)
    labels = simulate_rim_labels(vehicle, scan.T_external_body, 4)
    return absolute_calibration(sim.dataset, "leica", labels, scan.points_external)


def _from_quaternion_args(x, y, z, qx, qy, qz, qw):
    R = np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, (x, y, z)
    return T


def test_write_read_round_trip_is_exact(result, tmp_path):
    paths = write_absolute(result, tmp_path / "out")
    names = [p.name for p in paths]
    assert names == [
        ABSOLUTE_YAML_NAME, ABSOLUTE_JSON_NAME, "absolute.launch", "absolute.launch.py"
    ]
    back = read_absolute_yaml(tmp_path / "out" / ABSOLUTE_YAML_NAME)
    assert isinstance(back, AbsoluteTransforms)
    assert back.body_frame == "base_link"
    want = result.transforms()
    assert list(back.transforms) == list(want) == ["lidar1", "camera1", "radar1"]
    for frame, T in want.items():
        assert np.array_equal(back.transforms[frame], T)  # bit-exact
    # the JSON says the same (JSON is YAML)
    js = read_absolute_yaml(tmp_path / "out" / ABSOLUTE_JSON_NAME)
    assert js.body_frame == "base_link"
    for frame, T in want.items():
        assert np.array_equal(js.transforms[frame], T)


def test_yaml_holds_the_plain_dict(result):
    data = yaml.safe_load(absolute_to_yaml_text(result))
    frames = data.pop("frames")  # the frame contract's block (rigcal.io.results.frames)
    assert data == result.to_dict()  # the same plain data, floats exact
    assert frames["reference_frame"] == "base_link" and frames["urdf"] is None
    edges = {e["child"]: e for e in frames["static_transforms"]}
    for est in result.sensors.values():
        assert edges[est.frame_id]["parent"] == "base_link"
        assert np.array_equal(edges[est.frame_id]["T_parent_child"], est.T_body_sensor)
    body = data["body_frame"]
    assert body["name"] == "base_link" and body["origin"] == "rear_axle"
    assert "rear axle" in body["definition"]
    assert body["wheelbase_m"] == pytest.approx(2.7, abs=0.005)
    lidar = data["sensors"]["lidar1"]
    assert lidar["xyz_m"] == pytest.approx([1.2, 0.0, 1.9], abs=0.03)
    assert lidar["rpy_deg"] == pytest.approx([0.4, -0.8, 1.5], abs=0.3)
    assert set(lidar["std"]) == {"x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg"}
    json.loads(absolute_to_json_text(result))  # strict JSON


def test_parent_frame_renames_the_body_frame_everywhere(result, tmp_path):
    paths = write_absolute(result, tmp_path, parent_frame="vehicle", launch=("ros1", "ros2", "sh"))
    assert [p.name for p in paths][2:] == [LAUNCH_NAMES[f] for f in ("ros1", "ros2", "sh")]
    assert read_absolute_yaml(tmp_path / ABSOLUTE_YAML_NAME).body_frame == "vehicle"
    doc = json.loads((tmp_path / ABSOLUTE_JSON_NAME).read_text())
    assert doc["body_frame"]["name"] == "vehicle"
    ros2 = (tmp_path / "absolute.launch.py").read_text()
    assert '"--frame-id", "vehicle"' in ros2
    assert "--frame-id vehicle" in (tmp_path / "absolute_tf.sh").read_text()
    root = ET.fromstring((tmp_path / "absolute.launch").read_text())
    nodes = root.findall("node")
    assert len(nodes) == 3
    for node in nodes:
        assert node.get("pkg") == "tf2_ros"
        args = node.get("args").split()
        assert args[7] == "vehicle"
        T = _from_quaternion_args(*(float(v) for v in args[:7]))
        assert np.allclose(T, result.sensors[args[8]].T_body_sensor, atol=1e-12)
    assert result.body_frame == "base_link"  # the result itself is unchanged


def test_write_one_launch_file(result, tmp_path):
    p = write_absolute_launch(tmp_path / "tf.launch", result)
    root = ET.fromstring(p.read_text())
    assert {n.get("args").split()[7] for n in root.findall("node")} == {"base_link"}
    p = write_absolute_launch(tmp_path / "tf.yaml", result, parent_frame="chassis")
    doc = yaml.safe_load(p.read_text())
    assert doc["parent_frame"] == "chassis"
    T = np.array(doc["transforms"]["camera1"]["T_parent_child"])
    assert np.array_equal(T, result.sensors["camera1"].T_body_sensor)


def test_bad_results_refused_before_writing(result, tmp_path):
    with pytest.raises(InputError, match="frame name must be a non-empty string"):
        write_absolute(result, tmp_path / "a", parent_frame="base link")
    assert not (tmp_path / "a").exists()
    clash = dict(result.sensors)
    clash["radar1"] = replace(clash["radar1"], frame_id="lidar1")
    bad = replace(result, sensors=clash)
    with pytest.raises(InputError, match="'lidar1' and 'radar1' share the frame id 'lidar1'"):
        write_absolute(bad, tmp_path / "b")
    assert not (tmp_path / "b").exists()
    with pytest.raises(InputError, match="is the body frame's name"):
        body_transforms(result, parent_frame="camera1")
    with pytest.raises(InputError, match=r"launch formats \['ros3'\] unknown"):
        write_absolute(result, tmp_path / "c", launch=("ros3",))
    with pytest.raises(InputError, match="expected an AbsoluteResult"):
        absolute_to_yaml_text({"sensors": {}})  # type: ignore[arg-type]


GOOD = """
body_frame: {name: base_link}
sensors:
  lidar1:
    frame_id: velodyne
    T_body_sensor: [[1, 0, 0, 1.2], [0, 1, 0, 0], [0, 0, 1, 1.9], [0, 0, 0, 1]]
"""


def test_parse_minimal_and_errors():
    out = parse_absolute_yaml(GOOD, "a.yaml")
    assert out.body_frame == "base_link"
    assert list(out.transforms) == ["velodyne"]
    assert out.transforms["velodyne"][2, 3] == 1.9
    cases = [
        ("- 1\n- 2\n", r"a.yaml: expected a mapping with 'body_frame' and 'sensors', got a list"),
        ("sensors: {}\n", r"a.yaml: missing key 'body_frame'"),
        ("body_frame: {name: b}\n", r"a.yaml: missing key 'sensors'"),
        ("body_frame: base_link\nsensors: {}\n", r"a.yaml: body_frame: expected a mapping"),
        ("body_frame: {name: 'a b'}\nsensors: {x: {}}\n", r"a.yaml: body_frame.name: frame name"),
        ("body_frame: {name: b}\nsensors: {}\n", r"a.yaml: sensors: expected a non-empty mapping"),
        ("body_frame: {name: b}\nsensors: {x: 3}\n", r"a.yaml: sensors.x: expected a mapping"),
        ("body_frame: {name: b}\nsensors: {x: {}}\n", r"sensors.x: missing key 'T_body_sensor'"),
        (GOOD.replace("[0, 0, 0, 1]]", "[0, 0, 0, 2]]"), r"sensors.lidar1.T_body_sensor: not rigid: last row"),
        (GOOD.replace("[[1, 0, 0, 1.2]", "[[2, 0, 0, 1.2]"), r"T_body_sensor: not rigid: the 3x3 block"),
        (GOOD.replace("[[1, 0, 0, 1.2], [0, 1, 0, 0], ", "["), r"T_body_sensor: expected a 4x4"),
        (GOOD.replace("velodyne", "base_link"), r"frame 'base_link' is the body frame itself"),
        (GOOD + "  lidar2:\n    frame_id: velodyne\n    T_body_sensor: "
         "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
         r"sensors.lidar2: frame 'velodyne' appears twice"),
        ("body_frame: {name: b}\nbody_frame: {name: c}\nsensors: {}\n", r"duplicate key"),
    ]
    for text, match in cases:
        with pytest.raises(InputError, match=match):
            parse_absolute_yaml(text, "a.yaml")


def test_read_missing_file(tmp_path):
    with pytest.raises(InputError, match="absolute calibration file not found"):
        read_absolute_yaml(tmp_path / "nope.yaml")


def test_nan_is_null_in_json(result):
    body = result.body._replace(track_front_m=math.nan)
    text = absolute_to_json_text(replace(result, body=body))
    assert json.loads(text)["body_frame"]["track_front_m"] is None
    assert "track_front_m: .nan" in absolute_to_yaml_text(replace(result, body=body))
