"""docs/guide.md: its worked example runs as written on the shared Prius detections, and the
sample configurations in examples/ are valid (each parsed by the reader its command uses)."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, matrix_from_rpy
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.dataset.manifest import load_manifest
from rigcal.io.config.rig_config import load_rig_config
from rigcal.io.results.urdf import forward_kinematics, parse_urdf

REPO = Path(__file__).resolve().parents[2]
GUIDE = REPO / "docs" / "guide.md"
SHARED = REPO.parent / "shared"


def worked_example() -> list[list[str]]:
    text = GUIDE.read_text()
    block = re.search(r"<!-- worked-example.*?-->\s*```bash\n(.*?)```\s*<!-- /worked-example -->",
                      text, re.S)
    assert block, "docs/guide.md lost its worked-example block"
    lines = [ln.strip() for ln in block.group(1).splitlines() if ln.strip().startswith("rigcal ")]
    assert len(lines) >= 4
    return [shlex.split(ln)[1:] for ln in lines]


def test_worked_example_runs_as_written(tmp_path, monkeypatch, capsys):
    if not (SHARED / "data" / "tudelft_prius" / "detections" / "lidar.csv").is_file():
        pytest.skip("../shared/data (beside the repository) not present")
    # the commands run from a checkout's root with ../shared beside it
    root = tmp_path / "checkout"
    root.mkdir()
    (root / "examples").symlink_to(REPO / "examples")
    (tmp_path / "shared").symlink_to(SHARED)
    monkeypatch.chdir(root)
    for argv in worked_example():
        assert run(argv) == 0, (argv, capsys.readouterr().err)
    out = capsys.readouterr().out
    # what the guide says you should see
    assert "consistent" in out and "15.25" in out and "14.30" in out and "20.90" in out
    assert "no link 'front_radar'" in out.replace("\n", "")
    cal = read_calibration_transforms(root / "prius_fcpe" / "calibration.yaml")
    for name, frames in (("prius.urdf", ["camera"]), ("prius_radar.urdf", ["camera", "front_radar"])):
        urdf = parse_urdf((root / name).read_text(), name)
        for frame in frames:
            assert np.abs(forward_kinematics(urdf, "laser_link", frame) - cal.transforms[frame]).max() < 1e-6
    original = (SHARED / "data" / "tudelft_prius" / "urdf" / "vehicle.urdf").read_text().splitlines()
    changed = [a for a, b in zip(original, (root / "prius.urdf").read_text().splitlines()) if a != b]
    assert len(changed) == 1 and "0 1 0" in changed[0]  # only camera_joint's origin line
    assert (root / "prius_tf.launch.py").is_file() and (root / "prius_pse" / "calibration.yaml").is_file()
    # the URDF-in flow: the optical child of the body-convention camera link gets the pose
    nominal = read_calibration_transforms(root / "prius_nominal" / "calibration.yaml")
    urdf = parse_urdf((root / "prius_calibrated.urdf").read_text(), "prius_calibrated.urdf")
    T = forward_kinematics(urdf, "laser_link", "camera_optical_frame")
    assert np.abs(T - nominal.transforms["camera"]).max() < 1e-9
    assert "19.65" in out


def test_sample_manifest_and_detection_rig_are_valid():
    rig = load_rig_config(REPO / "examples" / "bag" / "detect_rig.yaml")
    assert [s.name for s in rig.sensors] == ["lidar1", "camera1", "radar1"]
    if (SHARED / "data" / "tudelft_prius" / "detections" / "lidar.csv").is_file():
        ds = load_manifest(REPO / "examples" / "prius" / "rig.yaml")
        assert [s.frame_id for s in ds.sensors] == ["laser_link", "camera", "front_radar"]


def test_sample_mocap_configuration_is_valid(tmp_path):
    from rigcal.mocap.config import parse_mocap_config
    from rigcal.mocap.extrinsics import Extrinsics, write_extrinsics_json

    (tmp_path / "run.bag").write_bytes(b"#ROSBAG V2.0\n")  # only its existence is checked here
    (tmp_path / "camera1.json").write_text(json.dumps({
        "camera_type": "RADTAN", "image_width": 2048, "image_height": 1536,
        "intrinsics": [2352.7, 2352.6, 1023.6, 766.1, -0.1, 0.05, 0.001, -0.002]}))
    T_bl = from_rt(matrix_from_rpy(np.radians([0.0, 0.0, 0.0])), [0.2, 0.0, 0.35])
    T_bc = from_rt(matrix_from_rpy(np.radians([-90.0, 0.0, -90.0])), [0.3, 0.1, 0.2])
    write_extrinsics_json(tmp_path / "initial.json", Extrinsics({
        ("base_link", "velodyne_link"): T_bl,
        ("velodyne_link", "camera_optical_frame"): invert(T_bl) @ T_bc}))
    text = (REPO / "examples" / "mocap" / "mocap.yaml").read_text()
    config = parse_mocap_config(text, str(tmp_path / "mocap.yaml"), tmp_path)
    assert [s.name for s in config.sensors] == ["lidar1", "camera1"]


def test_the_two_rig_files_are_told_apart(tmp_path):
    """A detection rig where a manifest is expected (and the other way round) says which it is
    and which command takes it."""
    manifest = tmp_path / "rig.yaml"
    manifest.write_text("sensors:\n  - {name: lidar1, kind: lidar, detections: lidar1.csv}\n")
    with pytest.raises(InputError, match="is a dataset manifest.*rigcal calibrate"):
        load_rig_config(manifest)
    with pytest.raises(InputError, match="looks like a detection rig.*--rig"):
        load_manifest(REPO / "examples" / "bag" / "detect_rig.yaml")
