"""The usual mistakes, end to end through ``rigcal calibrate``: each is named with what to do,
the exit code says what happened (3 flagged, 5 undetermined, 1 when the solve cannot even
run), nothing is written unless --force - and the fix makes the same data pass."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.codes import EXIT_FLAGGED, EXIT_UNDETERMINED
from rigcal.cli.main import run
from rigcal.dataset import BoardGeometry
from rigcal.geometry.se3 import from_rt
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate
from rigcal.study.verdict import three_radar_rig

ARGS = ["--cv-folds", "0", "--no-plot"]


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    """One message per line (the console folds at 80 columns otherwise)."""
    monkeypatch.setenv("COLUMNS", "2000")


@pytest.fixture(scope="module")
def rig():
    rng = np.random.default_rng(20)
    sensors = prius_like_rig()
    T = make_rig_placements(rng, sensors, 20, min_fraction=1.0)
    return sensors, T, simulate(sensors, T, rng=rng)


def _with_points(dataset, name, points):
    return replace(dataset, sensors=tuple(replace(s, points=points) if s.name == name else s
                                          for s in dataset.sensors))


def _calibrate(capsys, path, out, *extra):
    code = run(["calibrate", str(path), *ARGS, "--out", str(out), *extra])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def _set_manifest(path: Path, change) -> None:
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def test_clean_data_is_consistent(tmp_path, rig, capsys):
    code, text = _calibrate(capsys, write_dataset(rig[2].dataset, tmp_path / "d"), tmp_path / "out")
    assert code == 0, text
    assert text.lstrip().startswith("consistent")


def test_a_mirrored_hole_order_is_named_and_the_manifest_key_fixes_it(tmp_path, rig, capsys):
    ds = rig[2].dataset
    mirrored = _with_points(ds, "camera1", ds.sensor("camera1").points[:, [1, 0, 3, 2]])
    path = write_dataset(mirrored, tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_FLAGGED, text
    assert "camera1.csv: holes ordered TR, TL, BR, BL (mirrored left-right) on 20 of 20 boards" in text
    assert "hole_order: [TR, TL, BR, BL]" in text
    assert not (tmp_path / "out").exists()

    def declare(data):
        data["sensors"][1]["hole_order"] = "mirrored"

    _set_manifest(path, declare)
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == 0, text
    assert "holes ordered" not in text


def test_a_sensor_in_millimetres_is_named(tmp_path, rig, capsys):
    ds = rig[2].dataset
    path = write_dataset(_with_points(ds, "radar1", ds.sensor("radar1").points * 1000.0), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code in (1, EXIT_FLAGGED), text
    assert "radar1.csv: radar1's detections are about 1000 x the other sensors'" in text
    assert "millimetres read as metres" in text
    assert not (tmp_path / "out").exists()


def test_a_one_percent_scale_error_is_named(tmp_path, rig, capsys):
    ds = rig[2].dataset
    path = write_dataset(_with_points(ds, "camera1", ds.sensor("camera1").points * 1.01), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_FLAGGED, text
    assert "scale: camera1" in text and "1.01" in text


def test_a_wrong_hole_spacing_is_named_with_the_estimate(tmp_path, rig, capsys):
    sensors, T, _ = rig
    sim = simulate(sensors, T, board=BoardGeometry(spacing_m=0.25), rng=np.random.default_rng(1))
    path = write_dataset(replace(sim.dataset, board=BoardGeometry(spacing_m=0.24)), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_FLAGGED, text
    found = re.search(r"circle centres are (0\.\d+) \+- (0\.\d+) m apart, the configured hole spacing is "
                      r"0.2400 m - set board.spacing_m: (0\.\d+) in rig.yaml", text)
    assert found, text
    estimate, sd = float(found.group(1)), float(found.group(2))
    # the true 0.25 within 4 of the reported std, and that std small enough to tell 0.24 from it
    assert abs(estimate - 0.25) <= 4.0 * sd and sd < 0.002
    assert float(found.group(3)) == pytest.approx(estimate, abs=0.0005)

    _set_manifest(path, lambda data: data["board"].update(spacing_m=0.25))
    assert _calibrate(capsys, path, tmp_path / "out")[0] == 0


def test_a_reflector_offset_configured_as_zero_is_named(tmp_path, capsys):
    sim = three_radar_rig(20)
    path = write_dataset(replace(sim.dataset, board=BoardGeometry(reflector_offset_m=0.0)), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out", "--mode", "mcpe")
    assert code == EXIT_FLAGGED, text
    found = re.search(r"configured reflector offset is 0.000 m - set board.reflector_offset_m: (0\.\d+) in", text)
    assert found and float(found.group(1)) == pytest.approx(0.105, abs=0.03)


def test_a_reflector_on_the_wrong_side_of_some_boards_is_named(tmp_path, rig, capsys):
    sensors, T, sim = rig
    boards = [1, 5, 9, 13, 17]
    moved = np.array(T)
    moved[boards] = moved[boards] @ from_rt(np.eye(3), [0.0, 0.0, 0.21])
    front = simulate(sensors, moved, rng=np.random.default_rng(2)).dataset
    pts = np.array(sim.dataset.sensor("radar1").points)
    pts[boards] = front.sensor("radar1").points[boards]
    path = write_dataset(_with_points(sim.dataset, "radar1", pts), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_FLAGGED, text
    assert "the reflector in front of the plate" in text
    named = text.split("on board(s) ", 1)[1].split(" the radars", 1)[0]
    assert {int(k) for k in named.split(", ")} <= set(boards)


def test_a_lidar_and_a_camera_file_swapped_are_named(tmp_path, rig, capsys):
    ds = rig[2].dataset
    lid, cam = ds.sensor("lidar1").points, ds.sensor("camera1").points
    path = write_dataset(_with_points(_with_points(ds, "lidar1", cam), "camera1", lid), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_FLAGGED, text
    assert "camera1.csv and lidar1 (lidar1.csv): detection files swapped?" in text


def test_two_files_of_one_kind_swapped_are_named_against_the_initial_poses(tmp_path, capsys):
    from rigcal.sim.rig import SimSensor
    from rigcal.dataset import SensorKind

    rng = np.random.default_rng(4)
    base = prius_like_rig()
    lidar2 = SimSensor("lidar2", SensorKind.LIDAR, from_rt(np.eye(3), [0.5, -0.6, 1.2]), sigma_m=0.01)
    sensors = base + (lidar2,)
    T = make_rig_placements(rng, sensors, 15, min_fraction=1.0)
    sim = simulate(sensors, T, rng=rng)
    good = write_dataset(sim.dataset, tmp_path / "good")
    assert run(["calibrate", str(good), *ARGS, "--out", str(tmp_path / "prev")]) == 0
    capsys.readouterr()
    ds = sim.dataset
    swapped = _with_points(_with_points(ds, "lidar1", ds.sensor("lidar2").points), "lidar2",
                           ds.sensor("lidar1").points)
    path = write_dataset(swapped, tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out", "--initial", str(tmp_path / "prev" / "calibration.yaml"))
    assert code == EXIT_FLAGGED, text
    assert "lidar1.csv and lidar2.csv: detection files swapped?" in text


def test_a_board_from_another_placement_is_named(tmp_path, rig, capsys):
    ds = rig[2].dataset
    pts = np.array(ds.sensor("lidar1").points)
    pts[6] = pts[11]
    path = write_dataset(_with_points(ds, "lidar1", pts), tmp_path / "d")
    code = run(["calibrate", str(path), *ARGS, "--out", str(tmp_path / "out"), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err  # excluded as an outlier: the result stands, the cause is named
    data = json.loads(captured.out)
    assert data["outliers"]["lidar1"] == [6]
    note = next(c for c in data["verdict"]["checks"] if c["name"] == "placements")
    assert note["status"] == "note"
    assert "lidar1's detection of board 6 is that of placement 11" in note["detail"]
    # kept (--keep-outliers): flagged, with the same name
    code, text = _calibrate(capsys, path, tmp_path / "out2", "--keep-outliers")
    assert code == EXIT_FLAGGED
    assert "lidar1's detection of board 6 is that of placement 11" in text


def test_an_undetermined_radar_ends_with_its_own_exit_code(tmp_path, rig, capsys):
    ds = rig[2].dataset
    pts = np.array(ds.sensor("radar1").points)
    pts[3:] = np.nan  # the radar saw 3 boards
    path = write_dataset(_with_points(ds, "radar1", pts), tmp_path / "d")
    code, text = _calibrate(capsys, path, tmp_path / "out")
    assert code == EXIT_UNDETERMINED, text
    assert "UNDETERMINED" in text and "determined: radar1:" in text
    assert "radar1 saw only 3 boards: place more boards" in text
    assert "camera1" in text  # the other sensors' results are still shown
    assert "exit code 5" in text and not (tmp_path / "out").exists()
    code, text = _calibrate(capsys, path, tmp_path / "out", "--force")
    assert code == EXIT_UNDETERMINED
    data = yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())
    assert data["verdict"]["status"] == "undetermined"
    # a looser bound for 2D radars accepts it
    assert _calibrate(capsys, path, tmp_path / "out3", "--max-std", "radar:2000/90")[0] == 0


def test_max_std_is_checked(tmp_path, rig, capsys):
    path = write_dataset(rig[2].dataset, tmp_path / "d")
    code = run(["calibrate", str(path), *ARGS, "--out", str(tmp_path / "o"), "--max-std", "sonar:1/1"])
    assert code == 1
    assert "--max-std 'sonar:1/1': unknown sensor kind 'sonar'" in capsys.readouterr().err


def test_help_lists_the_exit_codes(capsys):
    with pytest.raises(SystemExit):
        run(["--help"])
    out = capsys.readouterr().out
    assert "  5    undetermined" in out and "  3    flagged" in out


def test_batch_reports_an_undetermined_dataset_with_its_exit_code(tmp_path, rig, capsys):
    ds = rig[2].dataset
    pts = np.array(ds.sensor("radar1").points)
    pts[3:] = np.nan
    write_dataset(ds, tmp_path / "car_a")
    write_dataset(_with_points(ds, "radar1", pts), tmp_path / "car_b")
    out = tmp_path / "out"
    code = run(["calibrate", "--batch", str(tmp_path / "car_a"), str(tmp_path / "car_b"), *ARGS, "--out", str(out),
                "--scheduler", "serial", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == EXIT_UNDETERMINED
    assert {d["dataset"]: d["status"] for d in doc} == {"car_a": "written", "car_b": "undetermined, not written"}
    assert (out / "car_a" / "calibration.yaml").is_file() and not (out / "car_b").exists()
