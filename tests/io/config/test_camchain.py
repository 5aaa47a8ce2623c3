"""Kalibr camchain YAML and the original tool's intrinsics JSON -> camera models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.config.camchain import (
    Camchain,
    format_camchain,
    parse_camchain_text,
    parse_camera_file_text,
    parse_intrinsics_json_text,
    read_camchain,
    read_camera_file,
    read_intrinsics_json,
)
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.kannala_brandt import KannalaBrandtCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera

VICON = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "vicon_sim"

CAMCHAIN = """\
cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [0.9999972564, 0.0023117893, 0.0003760563, -0.1101133]
  - [-0.0023119000, 0.9999970000, 0.0002944000, 0.0003991]
  - [-0.0003753751, -0.0002952688, 0.9999998860, -0.0008536]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [0.0034823894, 0.0007150348, -0.0020532361, 0.0002029367]
  distortion_model: equidistant
  intrinsics: [190.978477, 190.973307, 254.931706, 256.897442]
  resolution: [512, 512]
  rostopic: /cam1/image_raw
cam2:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 0.0, -1.0, 0.25]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: ds
  intrinsics: [-0.17, 0.59, 158.28, 158.27, 254.96, 256.90]
  distortion_model: none
  distortion_coeffs: []
  resolution: [512, 512]
cam3:
  camera_model: pinhole
  intrinsics: [500, 510, 320, 240]
  distortion_model: none
  resolution: [640, 480]
  T_cam_imu:
  - [0.0, -1.0, 0.0, 0.05]
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, -0.02]
  - [0.0, 0.0, 0.0, 1.0]
"""


def _write(tmp_path: Path, text: str, name: str = "camchain.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _vicon(name: str) -> Path:
    path = VICON / name
    if not path.exists():
        pytest.skip(f"shared data {path} is not present")
    return path


# ---------------------------------------------------------------------------- Kalibr camchain
def test_camchain_cameras(tmp_path):
    chain = read_camchain(_write(tmp_path, CAMCHAIN))
    assert list(chain.cameras) == ["cam0", "cam1", "cam2", "cam3"]
    cam0, cam1, cam2, cam3 = chain.cameras.values()
    assert type(cam0) is RadtanCamera and cam0.size_wh == (752, 480)
    np.testing.assert_array_equal(
        cam0.params,
        [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0],
    )
    assert type(cam1) is KannalaBrandtCamera and cam1.size_wh == (512, 512)
    np.testing.assert_array_equal(cam1.fisheye_coeffs, [0.0034823894, 0.0007150348, -0.0020532361, 0.0002029367])
    # Kalibr's ds order is (xi, alpha, fu, fv, pu, pv)
    assert type(cam2) is DoubleSphereCamera
    np.testing.assert_array_equal(cam2.params, [158.28, 158.27, 254.96, 256.90, -0.17, 0.59])
    assert type(cam3) is PinholeCamera and cam3.params.tolist() == [500, 510, 320, 240]
    assert chain.topics == {"cam0": "/cam0/image_raw", "cam1": "/cam1/image_raw"}


def test_camchain_transforms_are_t_to_from(tmp_path):
    chain = parse_camchain_text(CAMCHAIN, "camchain.yaml")
    assert set(chain.T_to_from) == {("cam1", "cam0"), ("cam2", "cam1"), ("cam3", "imu0")}
    T_cam2_cam1 = chain.T_to_from[("cam2", "cam1")]
    # T_cn_cnm1 maps a point in cam(n-1) into cam(n): cam1's optical axis is cam2's -y axis
    p_cam1 = np.array([0.0, 0.0, 1.0, 1.0])
    np.testing.assert_allclose(T_cam2_cam1 @ p_cam1, [0.0, -0.75, 0.0, 1.0])
    assert chain.T_to_from[("cam1", "cam0")][0, 3] == -0.1101133
    with pytest.raises(ValueError):
        T_cam2_cam1[0, 0] = 2.0  # read-only


def test_camchain_write_read_round_trip(tmp_path):
    chain = parse_camchain_text(CAMCHAIN, "camchain.yaml")
    text = format_camchain(chain)
    again = read_camchain(_write(tmp_path, text, "again.yaml"))
    assert again.cameras == chain.cameras and again.topics == chain.topics
    assert again.T_to_from.keys() == chain.T_to_from.keys()
    for key, T in chain.T_to_from.items():
        np.testing.assert_array_equal(again.T_to_from[key], T)


def test_format_camchain_refuses_what_kalibr_cannot_hold():
    radtan_k3 = RadtanCamera.from_intrinsics(640, 480, 500, 500, 320, 240, k3=0.01)
    with pytest.raises(InputError, match="Kalibr's radtan has no k3"):
        format_camchain(Camchain({"cam0": radtan_k3}, {}, {}))
    pinhole = PinholeCamera.from_intrinsics(640, 480, 500, 500, 320, 240)
    with pytest.raises(InputError, match=r"must be named \['cam0'\]"):
        format_camchain(Camchain({"left": pinhole}, {}, {}))
    with pytest.raises(InputError, match="Kalibr stores only"):
        format_camchain(Camchain({"cam0": pinhole}, {("cam0", "lidar"): np.eye(4)}, {}))


def test_minimal_camchain_without_distortion_keys():
    text = "cam0:\n  camera_model: pinhole\n  intrinsics: [500, 500, 320, 240]\n  resolution: [640, 480]\n"
    chain = parse_camchain_text(text, "min.yaml")
    assert type(chain.cameras["cam0"]) is PinholeCamera
    assert chain.T_to_from == {} and chain.topics == {}


def test_exponents_without_a_dot_are_numbers():
    # PyYAML (YAML 1.1) reads 1e-5 as a string; Kalibr itself writes 1.0e-05
    text = CAMCHAIN.replace("1.76187114e-05", "1.76187114e-5").replace("0.00019359", "1.9359E-4")
    cam0 = parse_camchain_text(text, "c.yaml").cameras["cam0"]
    assert cam0.param("p2") == 1.76187114e-05 and cam0.param("p1") == 1.9359e-4


def _cam0(**changes: object) -> str:
    node = {
        "camera_model": "pinhole",
        "intrinsics": [500, 500, 320, 240],
        "distortion_model": "radtan",
        "distortion_coeffs": [0.1, 0.01, 0.0, 0.0],
        "resolution": [640, 480],
    }
    for key, value in changes.items():
        if value is None:
            node.pop(key)
        else:
            node[key] = value
    return json.dumps({"cam0": node})  # JSON is YAML


@pytest.mark.parametrize(
    "text, message",
    [
        (_cam0(camera_model="omni"), r"c\.yaml: cam0\.camera_model: unknown camera model 'omni' \(supported: pinhole, ds\)"),
        (_cam0(camera_model=None), r"c\.yaml: cam0: missing 'camera_model'"),
        (_cam0(distortion_model="fov"), r"cam0\.distortion_model: 'fov' is not supported with camera_model 'pinhole' \(supported: none, radtan, equidistant\)"),
        (_cam0(camera_model="ds", intrinsics=[0, 0.5, 1, 1, 1, 1]), r"cam0\.distortion_model: 'radtan' is not supported with camera_model 'ds' \(supported: none\)"),
        (_cam0(distortion_model=None), r"cam0: missing 'distortion_model' \(distortion_coeffs are given\)"),
        (_cam0(intrinsics=[500, 500, 320]), r"c\.yaml: cam0\.intrinsics: camera_model 'pinhole' expects 4 values \(fu fv pu pv\), got 3"),
        (_cam0(camera_model="ds", distortion_model="none", distortion_coeffs=[], intrinsics=[500, 500, 320, 240]), r"cam0\.intrinsics: camera_model 'ds' expects 6 values \(xi alpha fu fv pu pv\), got 4"),
        (_cam0(distortion_coeffs=[0.1, 0.2, 0.3]), r"cam0\.distortion_coeffs: distortion_model 'radtan' expects 4 values \(k1 k2 r1 r2\), got 3"),
        (_cam0(distortion_model="none"), r"cam0\.distortion_coeffs: distortion_model 'none' expects none, got 4"),
        (_cam0(resolution=None), r"c\.yaml: cam0: missing 'resolution' \(\[width, height\] in px\)"),
        (_cam0(resolution=[640]), r"cam0\.resolution: expected \[width, height\] in px, got \[640\]"),
        (_cam0(resolution=[640, -480]), r"cam0\.resolution\[1\] \(height\): expected a positive integer \[px\], got -480"),
        (_cam0(intrinsics=[500, "abc", 320, 240]), r"c\.yaml: cam0\.intrinsics\[1\]: expected a finite number, got 'abc' \(a string\)"),
        (_cam0(intrinsics=[500, True, 320, 240]), r"cam0\.intrinsics\[1\]: expected a finite number, got True \(a boolean\)"),
        (_cam0(intrinsics="500 500 320 240"), r"cam0\.intrinsics: expected a list of numbers, got a string"),
        (_cam0(distortion_coeffs=[0.1, None, 0, 0]), r"cam0\.distortion_coeffs\[1\]: expected a finite number, got None"),
        (_cam0(intrinsics=[-500, 500, 320, 240]), r"c\.yaml: cam0\.intrinsics: radtan camera: fx and fy must be > 0"),
        (_cam0(colour="red"), r"cam0: unknown key 'colour'"),
        (_cam0(T_cn_cnm1=np.eye(4).tolist()), r"cam0\.T_cn_cnm1: cam0 is the first camera"),
        ('{"cam0": [1, 2]}', r"c\.yaml: cam0: expected a mapping \(camera_model, intrinsics, \.\.\.\), got a list"),
        ('{"camera0": {}}', r"c\.yaml: unexpected top-level key 'camera0' \(a Kalibr camchain has cam0, cam1, \.\.\.\)"),
        ("[1, 2]", r"c\.yaml: expected a Kalibr camchain mapping \(cam0, cam1, \.\.\.\), got a list"),
        ("{}", r"c\.yaml: no cameras"),
        ("cam0: {camera_model: pinhole\n", r"c\.yaml: line \d+, column \d+: invalid YAML"),
    ],
)
def test_camchain_errors_name_the_file_and_key(text, message):
    with pytest.raises(InputError, match=message):
        parse_camchain_text(text, "c.yaml")


def test_camchain_numbering_and_transform_errors():
    cam0 = CAMCHAIN.split("cam1:")[0]
    cam2 = "cam2:" + CAMCHAIN.split("cam2:")[1].split("cam3:")[0]
    with pytest.raises(InputError, match=r"numbered from cam0 without gaps; missing \['cam1'\]"):
        parse_camchain_text(cam0 + cam2, "c.yaml")
    bad_rotation = CAMCHAIN.replace("[0.0, 0.0, -1.0, 0.25]", "[0.0, 0.1, -1.0, 0.25]")
    with pytest.raises(InputError, match=r"c\.yaml: cam2\.T_cn_cnm1: the upper-left 3x3 block is not a rotation"):
        parse_camchain_text(bad_rotation, "c.yaml")
    reflection = CAMCHAIN.replace("[0.0, 1.0, 0.0, 0.0]\n", "[0.0, -1.0, 0.0, 0.0]\n", 1)
    with pytest.raises(InputError, match=r"cam2\.T_cn_cnm1: the upper-left 3x3 block is not a rotation .*det = -1"):
        parse_camchain_text(reflection, "c.yaml")
    bad_row = CAMCHAIN.replace("  - [0.0, 0.0, 0.0, 1.0]\n  camera_model: ds", "  - [0.0, 0.0, 1.0, 1.0]\n  camera_model: ds")
    with pytest.raises(InputError, match=r"cam2\.T_cn_cnm1: last row must be \[0, 0, 0, 1\]"):
        parse_camchain_text(bad_row, "c.yaml")
    short = CAMCHAIN.replace("  - [0.0, 0.0, 0.0, 1.0]\n  camera_model: ds", "  camera_model: ds")
    with pytest.raises(InputError, match=r"cam2\.T_cn_cnm1: expected a 4x4 matrix"):
        parse_camchain_text(short, "c.yaml")
    text_entry = CAMCHAIN.replace("[0.0, 0.0, -1.0, 0.25]", "[0.0, 0.0, -1.0, x]")
    with pytest.raises(InputError, match=r"cam2\.T_cn_cnm1\[1\]\[3\]: expected a finite number, got 'x'"):
        parse_camchain_text(text_entry, "c.yaml")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_camchain(tmp_path / "nope.yaml")


# ---------------------------------------------------------------------------- original tool JSON
def test_shared_f1_sim_json():
    cam = read_intrinsics_json(_vicon("F1_sim.json"))
    assert type(cam) is RadtanCamera and cam.size_wh == (2048, 1536)
    np.testing.assert_array_equal(
        cam.params,
        [
            2352.65873010560,
            2352.63261236703,
            1023.59896018009,
            766.135645001119,
            0.004238488421659,
            -0.042211993616096,
            0.115656913319717,
            -0.00038041825236,
            0.0,
        ],
    )


@pytest.mark.parametrize(
    "name, fx, cx, frame", [
        ("intrinsics_EXAMPLE.json", 1773.6150118117985, 1024.5, "camera_link"),
        ("CamFactorIntrinsics.json", 2352.19427, 945.77417, "F1_link"),
        ("F1_sim.json", 2352.65873010560, 1023.59896018009, "F1_link"),
    ],
)
def test_shared_intrinsics_files_by_content(name, fx, cx, frame):
    chain = read_camera_file(_vicon(name))
    assert list(chain.cameras) == [frame] and chain.T_to_from == {}
    cam = chain.cameras[frame]
    assert type(cam) is RadtanCamera and cam.size_wh == (2048, 1536)
    assert cam.param("fx") == fx and cam.param("cx") == cx
    # the gazebo example is an undistorted camera: the principal ray hits the principal point
    uv, valid = cam.project(np.array([0.0, 0.0, 5.0]))
    assert valid[0] and np.allclose(uv[0], [cx, cam.param("cy")])


TOOL = {
    "date": "2019-05-29",
    "method": "opencv",
    "camera_type": "KANNALABRANDT",
    "image_width": 2048,
    "image_height": 1536,
    "frame_id": "F1_link",
    "intrinsics": [783.44, 783.68, 996.34, 815.47, 0.0053, 0.0069, -0.0025, -0.0014],
}


@pytest.mark.parametrize(
    "camera_type, intrinsics, cls",
    [
        ("KANNALABRANDT", TOOL["intrinsics"], KannalaBrandtCamera),
        ("DOUBLESPHERE", [300.0, 301.0, 1024.0, 768.0, -0.2, 0.6], DoubleSphereCamera),
        ("RADTAN", [500.0, 500.0, 1024.0, 768.0, 0.1, 0.01, 0.0, 0.0], RadtanCamera),
        ("pinhole", [500.0, 500.0, 1024.0, 768.0], PinholeCamera),
    ],
)
def test_tool_json_models(camera_type, intrinsics, cls):
    doc = dict(TOOL, camera_type=camera_type, intrinsics=intrinsics)
    cam = parse_intrinsics_json_text(json.dumps(doc), "cam.json")
    assert type(cam) is cls
    np.testing.assert_array_equal(cam.params[: len(intrinsics)], intrinsics)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"camera_type": "LADYBUG"}, r"cam\.json: camera_type: unknown camera model 'LADYBUG' \(known: pinhole, radtan"),
        ({"camera_type": 3}, r"cam\.json: camera_type: expected a model name such as 'RADTAN', got an integer"),
        ({"camera_type": None}, r"cam\.json: missing 'camera_type'"),
        ({"intrinsics": [1.0] * 7, "camera_type": "RADTAN"}, r"cam\.json: intrinsics: radtan expects 8 or 9 parameters \(fx fy cx cy k1 k2 p1 p2 \[k3\]\), got 7"),
        ({"intrinsics": [1.0] * 6}, r"cam\.json: intrinsics: kannala_brandt expects 8 parameters .*got 6"),
        ({"intrinsics": None}, r"cam\.json: missing 'intrinsics'"),
        ({"intrinsics": [783.4, "783.6", 996, 815, 0, 0, 0, 0]}, r"cam\.json: intrinsics\[1\]: expected a finite number, got '783\.6' \(a string\)"),
        ({"image_width": None}, r"cam\.json: missing 'image_width' \(the image resolution in px\)"),
        ({"image_height": None}, r"cam\.json: missing 'image_height'"),
        ({"image_height": "1536"}, r"cam\.json: image_height: expected a positive integer \[px\], got '1536'"),
        ({"image_width": 0}, r"cam\.json: image_width: expected a positive integer \[px\], got 0"),
        ({"frame_id": 7}, r"cam\.json: frame_id: expected a frame name, got 7"),
        ({"intrinsics": [-1.0, 1, 1, 1, 0, 0, 0, 0]}, r"cam\.json: intrinsics: kannala_brandt camera: fx and fy must be > 0"),
    ],
)
def test_tool_json_errors_name_the_file_and_key(changes, message):
    doc = dict(TOOL)
    for key, value in changes.items():
        if value is None:
            doc.pop(key)
        else:
            doc[key] = value
    with pytest.raises(InputError, match=message):
        parse_intrinsics_json_text(json.dumps(doc), "cam.json")


def test_tool_json_syntax_and_layout_errors():
    with pytest.raises(InputError, match=r"cam\.json: line 2, column \d+: invalid JSON"):
        parse_intrinsics_json_text('{"camera_type": "RADTAN",\n "intrinsics": [1, 2,]}', "cam.json")
    with pytest.raises(InputError, match=r"cam\.json: intrinsics\[0\]: expected a finite number, got nan"):
        parse_intrinsics_json_text(json.dumps(dict(TOOL, intrinsics=[float("nan")] * 8)), "cam.json")
    with pytest.raises(InputError, match=r"expected an intrinsics object .*got a list"):
        parse_intrinsics_json_text("[1, 2]", "cam.json")
    old = {"camera_type": "pinhole", "calibration": [{"image_width": 2048, "intrinsics": [1, 2, 3, 4]}]}
    with pytest.raises(InputError, match=r"cam\.json: the older layout with a 'calibration' list is not supported"):
        parse_intrinsics_json_text(json.dumps(old), "cam.json")


# ---------------------------------------------------------------------------- any camera file
def test_read_camera_file_chooses_by_content(tmp_path):
    # a camchain in a .json-less file, the tool's JSON in a .yaml: content decides, not the name
    chain = read_camera_file(_write(tmp_path, CAMCHAIN, "chain.txt"))
    assert list(chain.cameras) == ["cam0", "cam1", "cam2", "cam3"]
    tool = read_camera_file(_write(tmp_path, json.dumps(TOOL, indent=2), "tool.yaml"))
    assert list(tool.cameras) == ["F1_link"] and type(tool.cameras["F1_link"]) is KannalaBrandtCamera
    no_frame = {k: v for k, v in TOOL.items() if k != "frame_id"}
    assert list(read_camera_file(_write(tmp_path, json.dumps(no_frame), "front.json")).cameras) == ["front"]
    # the tool's layout written as YAML works as well
    yaml_tool = "camera_type: RADTAN\nimage_width: 640\nimage_height: 480\nintrinsics: [500, 500, 320, 240, 0, 0, 0, 0]\n"
    assert type(parse_camera_file_text(yaml_tool, "t.yaml").cameras["t"]) is RadtanCamera


def test_read_camera_file_ros_formats(tmp_path):
    info = (
        "image_width: 640\nimage_height: 480\ncamera_name: narrow_stereo/left\n"
        "camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 510, 240, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0, 0, 0]}\n"
    )
    chain = read_camera_file(_write(tmp_path, info, "left.yaml"))
    assert list(chain.cameras) == ["narrow_stereo/left"]
    assert chain.cameras["narrow_stereo/left"].param("fy") == 510
    ini = (
        "# oST version 5.0 parameters\n[image]\nwidth\n640\nheight\n480\n\n[narrow_stereo]\n"
        "camera matrix\n500 0 320\n0 510 240\n0 0 1\n\ndistortion\n-0.1 0.01 0 0 0\n"
    )
    chain = read_camera_file(_write(tmp_path, ini, "ost.txt"))
    assert list(chain.cameras) == ["ost"] and type(chain.cameras["ost"]) is RadtanCamera


def test_read_camera_file_unknown_content(tmp_path):
    with pytest.raises(InputError, match=r"other\.yaml: not a camera file rigcal knows; expected a Kalibr camchain"):
        read_camera_file(_write(tmp_path, "sensor: lidar\nrate_hz: 10\n", "other.yaml"))
    with pytest.raises(InputError, match=r"bad\.json: line 1, column \d+: invalid JSON"):
        read_camera_file(_write(tmp_path, '{"camera_type": }', "bad.json"))
    with pytest.raises(InputError, match="camera file not found"):
        read_camera_file(tmp_path / "missing.json")
