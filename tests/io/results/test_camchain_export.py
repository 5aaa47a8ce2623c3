"""Kalibr camchains both ways (issue 19, item 6): `rigcal export --format kalibr` writes a
calibration's cameras as a camchain that the camchain parser reads back exactly (1e-12), and a
camchain is accepted as a board-detection camera's intrinsics."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.dataset import SensorKind
from rigcal.geometry import from_rt, invert, so3_exp
from rigcal.io.config.camchain import parse_camchain_text, read_camera_file
from rigcal.io.results.calibration import write_results
from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate

# two cameras of a Kalibr run (one camchain), a third from the original tool's JSON
CAMCHAIN = """\
cam0:
  camera_model: pinhole
  intrinsics: [461.629, 460.152, 362.680, 246.049]
  distortion_model: radtan
  distortion_coeffs: [-0.27695497, 0.06712482, 0.00087538, 0.00011556]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  camera_model: pinhole
  intrinsics: [460.576, 459.455, 379.996, 255.238]
  distortion_model: equidistant
  distortion_coeffs: [-0.0128, 0.0191, -0.0149, 0.0051]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
  T_cn_cnm1:
  - [0.8, -0.6, 0.0, -0.1101]
  - [0.6, 0.8, 0.0, 0.0004]
  - [0.0, 0.0, 1.0, -0.0009]
  - [0.0, 0.0, 0.0, 1.0]
"""
TOOL_JSON = {"camera_type": "DOUBLESPHERE", "image_width": 1024, "image_height": 768,
             "intrinsics": [377.1, 377.3, 511.2, 383.9, -0.27, 0.57]}


def _result() -> CalibrationResult:
    rng = np.random.default_rng(6)

    def est(name, kind, frame, T):
        return SensorEstimate(name, kind, frame, T, np.eye(6) * 1e-8, {k: 1e-4 for k in STD_KEYS})

    poses = [from_rt(so3_exp(rng.normal(0, 1, 3)), rng.normal(0, 1, 3)) for _ in range(3)]
    return CalibrationResult(
        mode="fcpe", reference="lidar1", converged=True,
        sensors={"lidar1": est("lidar1", SensorKind.LIDAR, "velodyne", np.eye(4)),
                 "left": est("left", SensorKind.CAMERA, "left_optical", poses[0]),
                 "right": est("right", SensorKind.CAMERA, "right_optical", poses[1]),
                 "fisheye": est("fisheye", SensorKind.CAMERA, "fisheye_optical", poses[2])},
        rmse_m={}, per_board_m={}, outliers={},
    )


@pytest.fixture
def files(tmp_path):
    write_results(_result(), tmp_path / "res")
    (tmp_path / "camchain.yaml").write_text(CAMCHAIN)
    (tmp_path / "fisheye.json").write_text(json.dumps(TOOL_JSON))
    return tmp_path


def test_export_kalibr_round_trips_exactly(files, capsys):
    out = files / "out-camchain.yaml"
    assert run(["export", str(files / "res" / "calibration.yaml"), "--format", "kalibr",
                "--intrinsics", f"left={files / 'camchain.yaml'}#cam0",
                "--intrinsics", f"right_optical={files / 'camchain.yaml'}#cam1",
                "--intrinsics", f"fisheye={files / 'fisheye.json'}", "--out", str(out)]) == 0
    assert "3 camera(s) as a Kalibr camchain" in capsys.readouterr().out
    text = out.read_text()
    chain = parse_camchain_text(text, "out")  # the same parser rigcal mocap uses
    source = read_camera_file(files / "camchain.yaml")
    fisheye = read_camera_file(files / "fisheye.json")
    expected_models = [source.cameras["cam0"], source.cameras["cam1"], next(iter(fisheye.cameras.values()))]
    for name, model in zip(("cam0", "cam1", "cam2"), expected_models):
        got = chain.cameras[name]
        assert type(got) is type(model) and (got.width, got.height) == (model.width, model.height)
        assert np.abs(np.asarray(got.params) - np.asarray(model.params)).max() <= 1e-12
    result = _result()
    T = {n: result.sensors[n].T_reference_sensor for n in ("left", "right", "fisheye")}
    for (to, frm), (a, b) in ((("cam1", "cam0"), ("right", "left")), (("cam2", "cam1"), ("fisheye", "right"))):
        expected = invert(T[a]) @ T[b]  # T_cn_cnm1: points in cam(n-1) into camn
        assert np.abs(chain.T_to_from[(to, frm)] - expected).max() <= 1e-12
    assert chain.topics == {"cam0": "/cam0/image_raw", "cam1": "/cam1/image_raw"}
    assert "# cam2: sensor 'fisheye', frame 'fisheye_optical'" in text
    assert yaml.safe_load(text)["cam2"]["camera_model"] == "ds"


def test_export_kalibr_refusals(files, capsys):
    cal = str(files / "res" / "calibration.yaml")

    def error(*extra):
        assert run(["export", cal, "--format", "kalibr", *extra]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("rigcal: error:")
        return err

    assert "camera 'left' (frame 'left_optical'): no intrinsics; give --intrinsics left=FILE" in error()
    assert "'sonar' is not a camera of the calibration" in error("--intrinsics", f"sonar={files / 'fisheye.json'}")
    assert "holds cameras cam0, cam1" in error("--intrinsics", f"left={files / 'camchain.yaml'}",
                                                 "--intrinsics", f"right={files / 'camchain.yaml'}#cam1",
                                                 "--intrinsics", f"fisheye={files / 'fisheye.json'}")
    assert run(["export", cal, "--format", "yaml", "--intrinsics", "x.json"]) == 1
    assert "--intrinsics and --rig apply to --format kalibr or mcap only" in capsys.readouterr().err
    radtan_k3 = files / "k3.json"
    radtan_k3.write_text(json.dumps({"camera_type": "RADTAN", "image_width": 640, "image_height": 480,
                                     "intrinsics": [500, 500, 320, 240, 0.1, -0.1, 0, 0, 0.01]}))
    assert "Kalibr's radtan has no k3" in error(*(f"--intrinsics={n}={radtan_k3}" for n in ("left", "right", "fisheye")))


def test_a_camchain_is_a_detection_cameras_intrinsics(tmp_path):
    """A detection rig's `intrinsics:` takes a Kalibr camchain (once: "missing field
    'image_width'"); `camera:` or the sensor's topic picks the camera."""
    from rigcal.detect.pipeline import camera_model
    from rigcal.errors import InputError
    from rigcal.io.config.rig_config import parse_rig_config

    (tmp_path / "camchain.yaml").write_text(CAMCHAIN)
    cams = read_camera_file(tmp_path / "camchain.yaml").cameras
    rig = parse_rig_config(
        "sensors:\n"
        "  - {name: a, kind: camera, topic: /cam1/image_raw, intrinsics: camchain.yaml}\n"
        "  - {name: b, kind: camera, topic: /x, intrinsics: camchain.yaml, camera: cam0}\n"
        "  - {name: c, kind: camera, topic: /x, intrinsics: camchain.yaml}\n", "rig.yaml", tmp_path)
    assert np.array_equal(camera_model(rig.sensors[0], rig, None).params, cams["cam1"].params)
    assert np.array_equal(camera_model(rig.sensors[1], rig, None).params, cams["cam0"].params)
    with pytest.raises(InputError, match=r"rig.yaml: sensor 'c': intrinsics: .*camchain.yaml holds "
                                         r"cameras cam0, cam1 .*say which with 'camera'"):
        camera_model(rig.sensors[2], rig, None)
    with pytest.raises(InputError, match=r"sensors\[0\].camera: names a camera of the intrinsics file"):
        parse_rig_config("sensors:\n  - {name: a, kind: camera, topic: /t, camera_info_topic: /i, "
                         "camera: cam0}\n", "rig.yaml", tmp_path)
