"""``mocap.yaml``: every pose source, target definition and sensor kind, and every error path
with the file and key it names."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.io.config.vicon_json import write_vicon_target
from rigcal.mocap import Extrinsics, write_extrinsics_json
from rigcal.mocap.config import (
    ExtractionSettings,
    load_mocap_config,
    parse_mocap_config,
    read_initial_calibration,
)
from rigcal.sensors.camera.radtan import RadtanCamera
from rigcal.targets.definition import TargetKind
from rigcal.targets.templates import cylinder_target, diamond_target

T_BL = from_rt(matrix_from_rpy(np.radians([1.0, -2.0, 3.0])), [0.2, 0.0, 0.35])
T_BC = from_rt(matrix_from_rpy(np.radians([-90.0, 0.0, -90.0])), [0.3, 0.1, 0.2])

CONFIG = """\
recording: run.bag
mocap:
  robot: {topic: /vicon/robot/robot}
  targets:
    diamond: {topic: /vicon/diamond/diamond, definition: CheckerboardTargetSim.json}
    board: {tf_child: board, tf_parent: world,
            analytic: {kind: checkerboard_diamond, side_m: 0.6, square_m: 0.03, rows: 5, cols: 6}}
    cylinder: {csv: cyl.csv, time_unit: s, definition: CylinderTarget.json, template: cyl.pcd,
               dims: {radius_m: 0.0564, height_m: 0.4956}}
  max_gap_s: 0.04
initial_calibration: initial.json
robot_frame: base_link
sensors:
  - {name: lidar1, kind: lidar, topic: /velodyne_points, frame_id: velodyne_link, sigma_m: 0.01,
     elevation_fov_deg: [-15, 15], horizontal_step_deg: 0.4}
  - {name: camera1, kind: camera, topic: /F1/image_raw, frame_id: camera_link,
     intrinsics: F1_sim.json, sigma_px: 0.5}
extraction: {max_linear_mps: 0.1, max_angular_dps: 5, motion_window_s: 0.5,
             sigma_translation_m: 0.03, sigma_rotation_deg: 5}
options: {loss: huber, target_pose_sigma: [0.0005, 0.00015]}
report: {overlays_per_sensor: 5}
"""

INTRINSICS = {"date": "2018_12_20", "method": "matlab", "camera_type": "RADTAN",
              "image_width": 2048, "image_height": 1536, "frame_id": "F1_link",
              "intrinsics": [2352.7, 2352.6, 1023.6, 766.1, -0.1, 0.05, 0.001, -0.002]}


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    (tmp_path / "run.bag").write_bytes(b"#ROSBAG V2.0\n")  # only its existence is checked here
    write_vicon_target(tmp_path / "CheckerboardTargetSim.json", diamond_target())
    write_vicon_target(tmp_path / "CylinderTarget.json", cylinder_target(0.0564, 0.4956),
                       template_cloud="cyl.pcd")
    (tmp_path / "cyl.csv").write_text(
        "t,x,y,z,qx,qy,qz,qw\n0.0,1,2,0,0,0,0,1\n0.01,1,2,0,0,0,0,1\n")
    (tmp_path / "F1_sim.json").write_text(json.dumps(INTRINSICS))
    write_extrinsics_json(tmp_path / "initial.json", Extrinsics({
        ("base_link", "velodyne_link"): T_BL,
        ("velodyne_link", "camera_link"): invert(T_BL) @ T_BC}))
    (tmp_path / "mocap.yaml").write_text(CONFIG)
    return tmp_path


def _parse(folder: Path, text: str):
    return parse_mocap_config(text, str(folder / "mocap.yaml"), folder)


def test_reads_every_source_and_definition(folder):
    cfg = load_mocap_config(folder / "mocap.yaml")
    assert cfg.source == str(folder / "mocap.yaml") and cfg.recording == folder / "run.bag"
    assert cfg.robot.kind == "topic" and cfg.robot.topic == "/vicon/robot/robot"
    assert list(cfg.targets) == ["diamond", "board", "cylinder"]
    d, b, c = (cfg.targets[n] for n in ("diamond", "board", "cylinder"))
    assert d.target.kind is TargetKind.CHECKERBOARD_DIAMOND and d.target.name == "diamond"
    assert d.definition == str(folder / "CheckerboardTargetSim.json")
    assert (b.pose.kind, b.pose.child, b.pose.parent) == ("tf", "board", "world")
    assert b.definition == "analytic" and b.target.dims["side_m"] == 0.6
    assert b.target.camera_keypoints.shape == (30, 3)
    assert (c.pose.kind, c.pose.path, c.pose.time_unit) == ("csv", folder / "cyl.csv", "s")
    assert c.target.kind is TargetKind.CYLINDER and c.target.dims["radius_m"] == 0.0564
    assert cfg.max_gap_s == 0.04 and cfg.robot_frame == "base_link"
    lidar, cam = cfg.sensors
    assert (lidar.kind, lidar.frame_id, lidar.sigma) == (SensorKind.LIDAR, "velodyne_link", 0.01)
    assert math.isclose(lidar.lidar.horizontal_step_rad, math.radians(0.4))
    assert lidar.lidar.vertical_step_rad == math.radians(2.0)  # VLP-16 default kept
    assert cam.kind is SensorKind.CAMERA and isinstance(cam.camera, RadtanCamera)
    assert (cam.camera.width, cam.camera.height, cam.sigma) == (2048, 1536, 0.5)
    assert cfg.extraction.sigma_rotation_deg == 5 and cfg.extraction.motion_window_s == 0.5
    assert math.isclose(cfg.extraction.uncertainty.sigma_rotation_rad, math.radians(5))
    assert cfg.options.loss == "huber" and cfg.options.target_pose_sigma == (0.0005, 0.00015)
    assert cfg.overlays_per_sensor == 5
    init = cfg.initial_T_robot_sensor()
    np.testing.assert_allclose(init["lidar1"], T_BL, atol=1e-12)
    np.testing.assert_allclose(init["camera1"], T_BC, atol=1e-12)  # composed along the graph


def test_lidar_points_and_correspondences_are_chosen_in_the_config(folder):
    cfg = load_mocap_config(folder / "mocap.yaml")
    assert cfg.targets["diamond"].target.use_lidar_keypoints  # the definition file's choice
    assert cfg.options.correspondences == "surface"
    text = CONFIG.replace("definition: CheckerboardTargetSim.json}",
                          "definition: CheckerboardTargetSim.json, use_lidar_keypoints: false}")
    text = text.replace("loss: huber", "loss: huber, correspondences: centroid, estimator: gls")
    cfg = _parse(folder, text)
    assert not cfg.targets["diamond"].target.use_lidar_keypoints
    assert cfg.options.correspondences == "centroid"
    assert cfg.options.estimator == "gls" and load_mocap_config(folder / "mocap.yaml").options.estimator == "ls"


def test_defaults_and_a_folder_recording(folder):
    (folder / "rec").mkdir()
    text = """\
recording: rec
mocap:
  robot: {csv: cyl.csv}
  targets: {d: {csv: cyl.csv, definition: CheckerboardTargetSim.json}}
initial_calibration: initial.json
robot_frame: base_link
sensors: [{name: velodyne_link, kind: lidar, topic: lidar}]
"""
    cfg = _parse(folder, text)
    assert cfg.extraction == ExtractionSettings() and cfg.overlays_per_sensor == 3
    assert cfg.sensors[0].frame_id == "velodyne_link" and cfg.sensors[0].sigma == 0.01
    with pytest.raises(InputError, match=r"mocap\.robot: the recording .*rec is a folder, which "
                                         r"holds no topic /r; give a csv source"):
        _parse(folder, text.replace("{csv: cyl.csv}\n", "{topic: /r}\n", 1))
    with pytest.raises(InputError, match=r"initial_calibration: required with a folder"):
        _parse(folder, text.replace("initial_calibration: initial.json\n", ""))


def test_initial_calibration_from_a_calibration_yaml(tmp_path):
    # the original tool's per-sensor YAML: transform = T_target_source
    (tmp_path / "velodyne.yaml").write_text(yaml.safe_dump({
        "source": "base_link", "target": "velodyne_link",
        "transform": invert(T_BL).tolist()}))
    ext = read_initial_calibration(tmp_path / "velodyne.yaml")
    np.testing.assert_allclose(ext.lookup("base_link", "velodyne_link"), T_BL, atol=1e-12)


def _replace(old: str, new: str):
    return lambda text: text.replace(old, new, 1) if old in text else pytest.fail(old)


ERRORS = [
    ("unknown top key", _replace("robot_frame:", "bogus: 1\nrobot_frame:"),
     r"mocap\.yaml: unknown key\(s\) 'bogus' \(allowed: recording, mocap, "),
    ("missing key", _replace("robot_frame: base_link\n", ""),
     r"missing required key 'robot_frame'"),
    ("no recording", _replace("recording: run.bag", "recording: gone.bag"),
     r"recording: not found: .*gone\.bag"),
    ("no definition", _replace("definition: CheckerboardTargetSim.json", "definition: x.json"),
     r"mocap\.targets\.diamond\.definition: target definition not found: .*x\.json"),
    ("no template", _replace("template: cyl.pcd", "template: gone.pcd"),
     r"mocap\.targets\.cylinder\.template: template cloud not found"),
    ("no intrinsics", _replace("intrinsics: F1_sim.json", "intrinsics: F9.json"),
     r"sensors\[1\] \('camera1'\)\.intrinsics: intrinsics file not found: .*F9\.json"),
    ("no initial", _replace("initial_calibration: initial.json", "initial_calibration: no.json"),
     r"initial_calibration: initial calibration not found"),
    ("no csv", _replace("csv: cyl.csv", "csv: none.csv"),
     r"mocap\.targets\.cylinder\.csv: pose CSV not found"),
    ("unknown target kind", _replace("kind: checkerboard_diamond", "kind: triangle"),
     r"mocap\.targets\.board\.analytic\.kind: unknown target kind 'triangle' \(expected one of "),
    ("missing dims", _replace(", rows: 5, cols: 6", ""),
     r"mocap\.targets\.board\.analytic: analytic checkerboard_diamond target needs dims .*"
     r"missing rows, cols"),
    ("two pose sources", _replace("{topic: /vicon/diamond/diamond,", "{topic: /d, csv: cyl.csv,"),
     r"mocap\.targets\.diamond: give exactly one pose source: .*got \['topic', 'csv'\]"),
    ("no pose source", _replace("{topic: /vicon/robot/robot}", "{}"),
     r"mocap\.robot: give exactly one pose source"),
    ("definition and analytic", _replace("definition: CheckerboardTargetSim.json}",
                                         "definition: CheckerboardTargetSim.json, analytic: {}}"),
     r"mocap\.targets\.diamond: give exactly one of 'definition'"),
    ("unknown target key", _replace("template: cyl.pcd", "template: cyl.pcd, colour: green"),
     r"mocap\.targets\.cylinder: unknown key\(s\) 'colour'"),
    ("unknown sensor kind", _replace("kind: lidar", "kind: radar"),
     r"sensors\[0\] \('lidar1'\)\.kind: unknown sensor kind 'radar' for mocap calibration "
     r"\(expected lidar or camera\)"),
    ("camera key on a lidar", _replace("sigma_m: 0.01", "sigma_px: 0.01"),
     r"sensors\[0\] \('lidar1'\): unknown key\(s\) 'sigma_px' \(allowed: "),
    ("bad sigma", _replace("sigma_px: 0.5", "sigma_px: -1"),
     r"sensors\[1\] \('camera1'\)\.sigma_px: expected a number > 0"),
    ("bad fov", _replace("[-15, 15]", "[15, -15]"),
     r"sensors\[0\] \('lidar1'\)\.elevation_fov_deg: expected low < high"),
    ("duplicate names", _replace("name: camera1", "name: lidar1"),
     r"sensors: duplicate sensor names \['lidar1'\]"),
    ("unknown extraction key", _replace("motion_window_s: 0.5", "window: 0.5"),
     r"extraction: unknown key\(s\) 'window' \(allowed: max_linear_mps, "),
    ("bad extraction value", _replace("motion_window_s: 0.5", "motion_window_s: 0"),
     r"extraction\.motion_window_s: expected a number > 0"),
    ("bad loss", _replace("loss: huber", "loss: tukey"),
     r"options\.loss: expected one of linear, huber, cauchy, got 'tukey'"),
    ("bad target pose sigma", _replace("[0.0005, 0.00015]", "[0.0005]"),
     r"options\.target_pose_sigma: expected \[rotation_rad, translation_m\]"),
    ("bad correspondences", _replace("loss: huber", "loss: huber, correspondences: magic"),
     r"options\.correspondences: expected one of surface, centroid, got 'magic'"),
    ("bad estimator", _replace("loss: huber", "loss: huber, estimator: wls"),
     r"options\.estimator: expected one of gls, ls, got 'wls'"),
    ("bad use_lidar_keypoints", _replace("definition: CheckerboardTargetSim.json}",
                                         "definition: CheckerboardTargetSim.json, use_lidar_keypoints: 1}"),
     r"mocap\.targets\.diamond\.use_lidar_keypoints: expected true or false, got 1"),
    ("cylinder has no lidar keypoints", _replace("template: cyl.pcd", "template: cyl.pcd, use_lidar_keypoints: true"),
     r"mocap\.targets\.cylinder\.use_lidar_keypoints: target 'cylinder' has no lidar keypoints"),
    ("unknown option", _replace("loss: huber", "loss: huber, speed: 3"),
     r"options: unknown key\(s\) 'speed'"),
    ("unconnected frame", _replace("frame_id: camera_link", "frame_id: camera_optical"),
     r"initial calibration for sensor 'camera1' \(robot_frame 'base_link' <- frame_id "
     r"'camera_optical'\): .*unknown from frame 'camera_optical'"),
    ("bad overlays", _replace("overlays_per_sensor: 5", "overlays_per_sensor: -1"),
     r"report\.overlays_per_sensor: expected an integer >= 0"),
]


@pytest.mark.parametrize("edit, pattern", [e[1:] for e in ERRORS], ids=[e[0] for e in ERRORS])
def test_errors_name_the_file_and_key(folder, edit, pattern):
    with pytest.raises(InputError, match=pattern) as info:
        _parse(folder, edit(CONFIG))
    assert str(folder / "mocap.yaml") in str(info.value)


@pytest.mark.parametrize("doc, pattern", [
    ({**INTRINSICS, "camera_type": "FISHEYE9"},
     r"sensors\[1\] \('camera1'\)\.intrinsics \(sensor 'camera1'\): .*F1_sim\.json: "
     r"camera_type: unknown camera model 'FISHEYE9' \(known: "),
    ({**INTRINSICS, "intrinsics": [2352.7, 2352.6, 1023.6, 766.1, -0.1]},
     r"sensors\[1\] \('camera1'\)\.intrinsics \(sensor 'camera1'\): .*F1_sim\.json: "
     r"intrinsics: radtan expects 8 or 9 parameters \(fx fy cx cy k1 k2 p1 p2 \[k3\]\), got 5"),
], ids=["unknown camera model", "wrong intrinsics length"])
def test_camera_file_errors_propagate_with_context(folder, doc, pattern):
    (folder / "F1_sim.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=pattern):
        load_mocap_config(folder / "mocap.yaml")


def test_a_target_without_a_camera_extractor_is_refused_with_cameras(folder):
    text = CONFIG.replace("kind: checkerboard_diamond, side_m: 0.6, square_m: 0.03, rows: 5, "
                          "cols: 6", "kind: circle_board")
    with pytest.raises(InputError, match=r"mocap\.targets\.board: a circle_board target has no "
                                         r"camera extractor"):
        _parse(folder, text)
    lidar_only = text[:text.index("  - {name: camera1")] + text[text.index("extraction:"):]
    cfg = _parse(folder, lidar_only)
    assert cfg.targets["board"].target.kind is TargetKind.CIRCLE_BOARD


def test_yaml_errors_name_the_file(folder):
    with pytest.raises(InputError, match=r"mocap\.yaml: line \d+, column \d+: invalid YAML"):
        _parse(folder, "recording: [\n")
    with pytest.raises(InputError, match=r"mocap\.yaml: expected a mapping with recording"):
        _parse(folder, "- 1\n")
    with pytest.raises(InputError, match=r"mocap\.yaml: mocap configuration not found"):
        load_mocap_config(folder / "missing" / "mocap.yaml")


def test_hold_sigma_floor_is_read_and_checked(tmp_path):
    from rigcal.mocap.config import _options

    assert _options({"hold_sigma_floor": [0.0, 0.001]}, "m.yaml").hold_sigma_floor == (0.0, 0.001)
    with pytest.raises(InputError, match="hold_sigma_floor"):
        _options({"hold_sigma_floor": [-1.0, 0.001]}, "m.yaml")


def test_curved_ranges_is_a_boolean(tmp_path):
    from rigcal.mocap.config import _options

    assert _options({}, "m.yaml").curved_ranges is True
    assert _options({"curved_ranges": False}, "m.yaml").curved_ranges is False
    with pytest.raises(InputError, match=r"m\.yaml: options\.curved_ranges: expected true or false, got 0"):
        _options({"curved_ranges": 0}, "m.yaml")


def test_dropouts_holds_and_the_clock_offset_are_configured(folder):
    text = CONFIG.replace("max_gap_s: 0.04", "max_gap_s: 0.04\n  max_dropout_s: 0.3").replace(
        "loss: huber", "loss: huber, min_holds: 4, time_offset_sigma_s: 0.02")
    cfg = _parse(folder, text)
    assert cfg.max_dropout_s == 0.3
    assert cfg.options.min_holds == 4 and cfg.options.time_offset_sigma_s == 0.02
    assert _parse(folder, CONFIG).max_dropout_s is None  # default: 25 sample periods
    with pytest.raises(InputError, match=r"mocap\.yaml: mocap\.max_dropout_s: expected a number > 0"):
        _parse(folder, CONFIG.replace("max_gap_s: 0.04", "max_gap_s: 0.04\n  max_dropout_s: 0"))
    with pytest.raises(InputError, match=r"mocap\.yaml: options: mocap options: min_holds must be an integer >= 1"):
        _parse(folder, CONFIG.replace("loss: huber", "loss: huber, min_holds: 0"))
