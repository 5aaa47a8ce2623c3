"""`rigcal mocap CONFIG --out DIR` on a real bag (the scene of tests/mocap/test_pipeline.py)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from rigcal.cli.main import run


def _pipeline_test_module():
    path = Path(__file__).resolve().parents[1] / "mocap" / "test_pipeline.py"
    spec = importlib.util.spec_from_file_location("_mocap_pipeline_scene", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_mocap_cli_writes_results_diagnostics_and_overlays(tmp_path, capsys):
    m = _pipeline_test_module()
    scene = m.write_scene(tmp_path / "run.bag", seed=0, lidar_holds=3, camera_holds=3)
    m.write_inputs(tmp_path, scene)
    (tmp_path / "mocap.yaml").write_text(m.config_text())
    out = tmp_path / "out"
    assert run(["mocap", str(tmp_path / "mocap.yaml"), "--out", str(out), "--json", "--max-overlays", "2"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["mode"] == "mocap" and data["reference"] == "robot"
    assert set(data["sensors"]) == {"lidar1", "camera1"}
    T = np.asarray(data["sensors"]["camera1"]["T_reference_sensor"])
    assert T.shape == (4, 4)
    assert (out / "calibration.yaml").is_file() and (out / "diagnostics.csv").is_file()
    pngs = list((out / "overlays").glob("*.png"))
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    assert "measurements per sensor" in captured.err and "target_moving" in captured.err


def test_mocap_cli_bad_config_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "mocap.yaml"
    cfg.write_text("recording: nope.bag\nsensors: []\n")
    assert run(["mocap", str(cfg), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_study_mocap_prints_the_table_next_to_the_paper(capsys):
    assert run(["study", "mocap", "--trials", "1", "--measurements", "5"]) == 0
    out = capsys.readouterr().out
    assert "Table I" in out and "paper trans" in out


def test_study_mocap_bad_option_is_a_usage_error(capsys):
    import pytest

    with pytest.raises(SystemExit) as exc:
        run(["study", "mocap", "--target", "sphere"])
    assert exc.value.code == 2
