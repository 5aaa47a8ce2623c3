"""`rigcal urdf` and `rigcal export` on the shared example and on a rigcal calibration."""

from __future__ import annotations

import difflib
import json
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
