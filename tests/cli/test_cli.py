"""Smoke tests of the ``rigcal`` command line, and its behaviour on bad input: one line on
stderr, a non-zero exit code, no traceback, no output folder."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import rigcal
from rigcal.cli.main import run
from rigcal.geometry.se3 import invert
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tudelft_prius"
SENSORS = ("lidar1", "camera1", "radar1")


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(5)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)


@pytest.fixture
def manifest(tmp_path, sim) -> Path:
    return write_dataset(sim.dataset, tmp_path / "data")


def real_files() -> dict[str, Path]:
    files = {k: REAL / "detections" / f"{k}.csv" for k in ("lidar", "camera", "radar")}
    if not all(p.is_file() for p in files.values()):
        pytest.skip("../shared/data not present")
    return files


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        run(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"rigcal {rigcal.__version__}"


def test_no_command_prints_help(capsys):
    assert run([]) == 2
    assert "calibrate" in capsys.readouterr().out


def test_calibrate_manifest_json(tmp_path, manifest, sim, capsys):
    out = tmp_path / "out"
    code = run(["calibrate", str(manifest), "--mode", "fcpe", "--out", str(out), "--json", "--plot"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    data = json.loads(captured.out)  # stdout is only the JSON
    for key in ("reference", "mode", "converged", "sensors", "rmse_m", "per_board_m", "outliers"):
        assert key in data
    assert data["reference"] == "lidar1" and data["mode"] == "fcpe" and data["converged"] is True
    assert set(data["sensors"]) == set(SENSORS)
    for name, s in data["sensors"].items():
        T = np.array(s["T_reference_sensor"], dtype=float)
        assert T.shape == (4, 4)
        np.testing.assert_allclose(T[3], [0, 0, 0, 1])
        assert set(s["std"]) == {"x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg"}
        if name != "radar1":  # the CLI result is a calibration, not just any matrix
            T_true = invert(sim.truth["lidar1"]) @ sim.truth[name]
            assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.05
    np.testing.assert_allclose(data["sensors"]["lidar1"]["T_reference_sensor"], np.eye(4))
    assert set(data["rmse_m"]) == {"lidar1-camera1", "lidar1-radar1", "camera1-radar1"}
    assert all(0 < v < 0.1 for v in data["rmse_m"].values())
    assert set(data["per_board_m"]) == set(data["rmse_m"])
    assert data["outliers"] == {}
    written = ("calibration.yaml", "calibration.launch", "calibration.png")
    for f in (*written, *(f"{s}.yaml" for s in SENSORS)):
        assert (out / f).is_file(), f
    # the human summary went to stderr, not into the JSON
    assert "lidar1-camera1" in captured.err


def test_calibrate_original_cli_shape_on_real_csvs(tmp_path, capsys):
    files = real_files()
    out = tmp_path / "out"
    argv = ["calibrate", "--lidar", str(files["lidar"]), "--camera", str(files["camera"])]
    argv += ["--radar", str(files["radar"]), "--mode", "fcpe", "--out", str(out), "--json"]
    code = run(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    data = json.loads(captured.out)
    assert set(data["sensors"]) == set(SENSORS)
    assert data["num_boards"] == 29
    assert data["rmse_m"]["lidar1-camera1"] <= 15.26e-3
    assert data["rmse_m"]["lidar1-radar1"] <= 14.30e-3
    assert data["rmse_m"]["camera1-radar1"] <= 21.11e-3
    assert (out / "radar1.yaml").is_file() and (out / "calibration.yaml").is_file()


def test_calibrate_hold_radar_plane_flag(tmp_path, manifest, capsys):
    out = tmp_path / "out"
    argv = ["calibrate", str(manifest), "--hold-radar-plane", "--out", str(out), "--json"]
    argv.append("--no-plot")
    assert run(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["sensors"]["radar1"]["held"] == ["z", "roll", "pitch"]
    assert data["sensors"]["camera1"]["held"] == []
    assert not (out / "calibration.png").exists()


def test_calibrate_with_a_missed_camera_board(tmp_path, sim, capsys):
    """Regression: a NaN camera board in a rig with a radar escaped run() as a numpy
    LinAlgError traceback."""
    cam = sim.dataset.sensor("camera1")
    points = np.array(cam.points)
    points[0] = np.nan
    dataset = dataclasses.replace(
        sim.dataset,
        sensors=tuple(
            dataclasses.replace(s, points=points) if s.name == "camera1" else s
            for s in sim.dataset.sensors
        ),
    )
    manifest = write_dataset(dataset, tmp_path / "data")
    out = tmp_path / "out"
    assert run(["calibrate", str(manifest), "--out", str(out), "--no-plot", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert "0" not in data["per_board_m"]["lidar1-camera1"]  # board 0 left camera pairs only
    assert "0" in data["per_board_m"]["lidar1-radar1"]


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo"
    assert run(["demo", "--detections-only", "--out", str(out), "--boards", "15"]) == 0
    assert (out / "dataset" / "rig.yaml").is_file()
    for mode in ("mcpe", "fcpe", "pse"):
        for f in ("calibration.yaml", "calibration.launch", "calibration.png"):
            assert (out / mode / f).is_file(), (mode, f)
    assert "errors against the simulated truth" in capsys.readouterr().out


# --------------------------------------------------------------------------- bad input

# 2 boards (8 columns), 3 rows
LIDAR_OK = "\n".join(",".join(["1.0", "1.5", "2.0", "2.5"] * 2) for _ in range(3)) + "\n"
CAMERA_OK = LIDAR_OK


def _write(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return str(p)


def _files_case(lidar_text: str | None, camera_text: str = CAMERA_OK):
    def make(tmp_path):
        if lidar_text is None:
            lidar = str(tmp_path / "nope.csv")
        else:
            lidar = _write(tmp_path, "lidar.csv", lidar_text)
        camera = _write(tmp_path, "camera.csv", camera_text)
        return ["calibrate", "--lidar", lidar, "--camera", camera]

    return make


def _manifest_case(text: str):
    def make(tmp_path):
        _write(tmp_path, "lidar1.csv", LIDAR_OK)
        return ["calibrate", _write(tmp_path, "rig.yaml", text)]

    return make


BAD = {
    # id: (argv builder, substrings the error line must contain)
    "missing file": (_files_case(None), ["nope.csv", "not found"]),
    "empty file": (_files_case(""), ["lidar.csv", "empty"]),
    "ragged csv": (_files_case("1,2,3,4\n1,2,3\n1,2,3,4\n"), ["lidar.csv", "line 2"]),
    "non-numeric csv": (_files_case("1,2,3,4\n1,abc,3,4\n1,2,3,4\n"), ["lidar.csv", "'abc'"]),
    "wrong number of rows": (_files_case("1,2,3,4\n1,2,3,4\n"), ["lidar.csv", "3 rows"]),
    "different board counts": (
        _files_case(LIDAR_OK, "\n".join(",".join(["1.0"] * 12) for _ in range(3))),
        ["different numbers of board", "camera1: 3", "lidar1: 2", "lidar.csv", "camera.csv"],
    ),
    "unknown sensor kind": (
        _manifest_case("sensors:\n  - {name: lidar1, kind: sonar, detections: lidar1.csv}\n"),
        ["rig.yaml", "sensors[0].kind", "sonar"],
    ),
    "malformed yaml": (
        _manifest_case("sensors:\n  - {name: lidar1, kind: lidar, detections: lidar1.csv\n"),
        ["rig.yaml", "YAML"],
    ),
    "no input": (lambda tmp_path: ["calibrate"], ["no input"]),
}


def _assert_one_line_error(err: str, needles) -> None:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("rigcal: error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_exit_1(tmp_path, capsys, case):
    make, needles = BAD[case]
    out = tmp_path / "out"
    code = run([*make(tmp_path), "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    _assert_one_line_error(captured.err, needles)
    assert not out.exists()


def test_unknown_reference(tmp_path, manifest, capsys):
    out = tmp_path / "out"
    code = run(["calibrate", str(manifest), "--reference", "radar7", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    _assert_one_line_error(captured.err, ["radar7", "reference"])
    assert not out.exists()


def test_unknown_mode_is_a_usage_error(tmp_path, manifest, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        run(["calibrate", str(manifest), "--mode", "bogus", "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    # argparse's usage error: a usage line, then one 'error:' line naming the option
    error_lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(error_lines) == 1
    assert "--mode" in error_lines[0] and "bogus" in error_lines[0]
    assert not out.exists()


def test_a_flagged_result_is_not_written_and_exits_3(tmp_path, sim, capsys):
    from rigcal.sim.rig import move_boards

    bad = write_dataset(move_boards(sim.dataset, "lidar1", [3], [0.8, 0.0, 0.0]), tmp_path / "bad")
    out = tmp_path / "out"
    code = run(["calibrate", str(bad), "--keep-outliers", "--cv-folds", "0", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 3
    assert captured.out.lstrip().startswith("FLAGGED")  # the verdict comes first
    assert "board 3" in captured.out and "--force" in captured.out
    assert not out.exists()
    # --force writes it, with the verdict in calibration.yaml; the exit code stays 3
    code = run(["calibrate", str(bad), "--keep-outliers", "--cv-folds", "0", "--no-plot", "--force", "--out", str(out)])
    assert code == 3
    import yaml

    data = yaml.safe_load((out / "calibration.yaml").read_text())
    assert data["verdict"]["status"] == "flagged"
    assert any(c["name"] == "boards" and c["status"] == "fail" for c in data["verdict"]["checks"])


def test_consistent_result_carries_its_verdict_and_bounds(tmp_path, manifest, capsys):
    out = tmp_path / "out"
    code = run(["calibrate", str(manifest), "--cv-folds", "0", "--no-plot", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0
    data = json.loads(captured.out)
    assert data["verdict"]["status"] == "consistent"
    radar = data["sensors"]["radar1"]
    assert list(radar["bounded_offsets"]) == ["roll", "pitch", "z"]
    # absolute values of the pose table, with the estimate inside
    assert {"roll", "pitch", "z"} <= set(radar["bounded"])
    for key, v in radar["bounded"].items():
        k = ("x", "y", "z", "roll", "pitch", "yaw").index(key)
        assert v["low"] <= v["estimate"] <= v["high"]
        assert v["estimate"] == pytest.approx((radar["xyz_m"] + radar["rpy_deg"])[k])
    assert data["sensors"]["camera1"]["bounded"] == {}
    assert set(data["noise_model"]["camera1"]) == {"lateral", "depth"}
    assert captured.err.lstrip().startswith("consistent")
    # the terminal marks the bounded directions instead of printing a std for them
    assert "bnd" in captured.err


def test_pse_identity_noise_from_the_command_line(tmp_path, manifest, capsys):
    code = run(["calibrate", str(manifest), "--mode", "pse", "--pse-noise", "identity", "--cv-folds", "0",
                "--no-plot", "--out", str(tmp_path / "o"), "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0 and data["mode"] == "pse" and data["noise_iterations"] == 0


def test_calibrate_draws_the_plot_only_when_asked(tmp_path, manifest):
    """calibration.png costs about a second (matplotlib); it is off the default path."""
    assert run(["calibrate", str(manifest), "--mode", "fcpe", "--out", str(tmp_path / "a")]) == 0
    assert not (tmp_path / "a" / "calibration.png").exists()
    assert (tmp_path / "a" / "calibration.yaml").is_file()
    assert run(["calibrate", str(manifest), "--mode", "fcpe", "--plot", "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "calibration.png").read_bytes().startswith(b"\x89PNG")
