"""``rigcal check`` and ``rigcal diff`` end to end: unchanged, moved, cannot tell, bad input (one
line, exit 1), the report pages, and ``check --batch`` over a fleet - serially, on Dask, and with
the Dask scheduler lost in the middle."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.codes import EXIT_CANNOT_TELL, EXIT_MOVED
from rigcal.cli.main import run
from rigcal.dataset import Dataset
from rigcal.geometry.se3 import se3_exp
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

CAMERA_MOVE = np.r_[0.0, 0.01, 0.0, 0.03, 0.0, 0.0]  # 0.57 deg and 30 mm


def _moved(name, xi):
    return tuple(s.with_pose(s.T_rig_sensor @ se3_exp(xi)) if s.name == name else s for s in prius_like_rig())


def _write(root: Path, name: str, sensors, seed: int, boards: int) -> Path:
    rng = np.random.default_rng(seed)
    sim = simulate(sensors, make_rig_placements(rng, prius_like_rig(), boards, min_fraction=1.0), rng=rng)
    write_dataset(sim.dataset, root / name)
    return root / name


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    """A Prius-like rig calibrated on 20 boards, new detections on 5 boards: unchanged, with the
    camera moved, without the radar; and the calibration of the moved rig."""
    root = tmp_path_factory.mktemp("vehicle")
    _write(root, "cal_data", prius_like_rig(), 1, 20)
    assert run(["calibrate", str(root / "cal_data"), "--cv-folds", "0", "--out", str(root / "cal")]) == 0
    _write(root, "same", prius_like_rig(), 12, 5)  # (a seed among the 95 % without a false alarm)
    _write(root, "moved", _moved("camera1", CAMERA_MOVE), 3, 5)
    _write(root, "moved_cal_data", _moved("camera1", CAMERA_MOVE), 4, 20)
    assert run(["calibrate", str(root / "moved_cal_data"), "--cv-folds", "0", "--out", str(root / "moved_cal")]) == 0
    return root


def test_unchanged(vehicle, tmp_path, capsys):
    code = run(["check", str(vehicle / "cal" / "calibration.yaml"), str(vehicle / "same"), "--out", str(tmp_path / "c")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "unchanged: every sensor where it was calibrated" in out and "power: these 5 boards" in out
    data = json.loads((tmp_path / "c" / "check.json").read_text())
    assert data["status"] == "unchanged" and set(data["sensors"]) == {"lidar1", "camera1", "radar1"}
    html = (tmp_path / "c" / "check.html").read_text()
    assert "default-src 'none'" in html and "<script" not in html and 'id="sensors"' in html


def test_moved_names_the_camera_with_its_direction(vehicle, capsys):
    code = run(["check", str(vehicle / "cal"), str(vehicle / "moved"), "--json"])
    captured = capsys.readouterr()
    assert code == EXIT_MOVED, captured.err
    data = json.loads(captured.out)  # stdout is only the JSON
    assert data["status"] == "moved" and data["moved"] == ["camera1"]
    cam = data["sensors"]["camera1"]
    assert cam["headline"].startswith("moved: ") and cam["p_value"] < 1e-3
    assert 0.2 < cam["rotation_deg"] < 1.0
    assert "MOVED: camera1" in captured.err and "camera1: origin (" in captured.err  # the summary on stderr


def test_cannot_tell_a_sensor_missing_from_the_data(vehicle, tmp_path, capsys):
    from rigcal.io.dataset.manifest import load_manifest

    ds = load_manifest(vehicle / "same")
    write_dataset(Dataset(ds.sensors[:2], ds.board, source="two"), tmp_path / "two")
    code = run(["check", str(vehicle / "cal"), str(tmp_path / "two")])
    out = capsys.readouterr().out
    assert code == EXIT_CANNOT_TELL
    assert re.search(r"radar1\s+│\s+cannot tell: not in the data", out), out


@pytest.mark.parametrize("case,match", [
    ("extra sensor", r"sensor\(s\) lidar2 are not in the calibration"),
    ("no shared boards", "no board is seen by two sensors"),
    ("not a calibration", "an absolute.yaml"),
    ("batch with positionals", "--batch takes vehicle folders only"),
])
def test_bad_input_is_one_line(vehicle, tmp_path, capsys, case, match):
    from rigcal.io.dataset.manifest import load_manifest

    ds = load_manifest(vehicle / "same")
    cal = str(vehicle / "cal")
    if case == "extra sensor":
        write_dataset(Dataset(ds.sensors + (replace(ds.sensors[0], name="lidar2"),), ds.board), tmp_path / "d")
        argv = ["check", cal, str(tmp_path / "d")]
    elif case == "no shared boards":
        lonely = []
        for i, s in enumerate(ds.sensors):
            pts = np.array(s.points)
            pts[[k for k in range(ds.num_boards) if k % 3 != i]] = np.nan
            lonely.append(replace(s, points=pts))
        write_dataset(Dataset(tuple(lonely), ds.board), tmp_path / "d")
        argv = ["check", cal, str(tmp_path / "d")]
    elif case == "not a calibration":
        (tmp_path / "absolute.yaml").write_text("body_frame: base_link\nsensors: {}\n")
        argv = ["check", str(tmp_path / "absolute.yaml"), str(vehicle / "same")]
    else:
        argv = ["check", cal, str(vehicle / "same"), "--batch", str(vehicle / "same"), "--out", str(tmp_path / "o")]
    assert run(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rigcal: error: ") and re.search(match, err), err
    assert not (tmp_path / "o").exists()


def test_diff_unchanged_and_moved(vehicle, tmp_path, capsys):
    assert run(["diff", str(vehicle / "cal"), str(vehicle / "cal" / "calibration.yaml")]) == 0
    assert "unchanged: every difference within the uncertainty" in capsys.readouterr().out
    code = run(["diff", str(vehicle / "cal"), str(vehicle / "moved_cal"), "--json"])
    captured = capsys.readouterr()
    assert code == EXIT_MOVED
    data = json.loads(captured.out)
    assert data["moved"] == ["camera1"] and data["sensors"]["radar1"]["untested"] == ["roll", "pitch", "z"]
    assert "camera1: origin" in captured.err
    assert run(["diff", str(vehicle / "cal"), str(tmp_path / "missing.yaml")]) == 1
    assert capsys.readouterr().err.startswith("rigcal: error: ")


@pytest.fixture(scope="module")
def fleet(vehicle, tmp_path_factory):
    """Four vehicles' new detections and their calibrations (as calibrate --batch writes them):
    car_b's camera moved, car_c's calibration is missing, car_d saw the board with one sensor at a
    time; the vehicle names need escaping in HTML."""
    root = tmp_path_factory.mktemp("fleet")
    for car in ("car_a", "car_b", "car_c", "car<d>&"):
        if car != "car_c":
            shutil.copytree(vehicle / "cal", root / "calib" / car)
    shutil.copytree(vehicle / "same", root / "week" / "car_a")
    shutil.copytree(vehicle / "moved", root / "week" / "car_b")
    shutil.copytree(vehicle / "same", root / "week" / "car_c")
    from rigcal.io.dataset.manifest import load_manifest

    ds = load_manifest(vehicle / "same")
    lonely = []
    for i, s in enumerate(ds.sensors):
        pts = np.array(s.points)
        pts[[k for k in range(ds.num_boards) if k % 3 != i]] = np.nan
        lonely.append(replace(s, points=pts))
    write_dataset(Dataset(tuple(lonely), ds.board), root / "week" / "car<d>&")
    return root


def _check_fleet(out, fleet, capsys):
    vehicles = json.loads((out / "fleet.json").read_text())["vehicles"]
    assert [v["vehicle"] for v in vehicles][:1] == ["car_b"]  # worst first
    by = {v["vehicle"]: v for v in vehicles}
    assert by["car_b"]["status"] == "moved" and by["car_b"]["sensor"] == "camera1"
    assert by["car_a"]["status"] == "unchanged" and by["car_c"]["status"] == "failed"
    assert "calibration.yaml" in by["car_c"]["headline"] and by["car<d>&"]["status"] == "failed"
    for car in ("car_a", "car_b"):
        assert (out / car / "check.html").is_file() and by[car]["report"] == f"./{car}/check.html"
    html = (out / "fleet.html").read_text()
    assert "car&lt;d&gt;&amp;" in html and "car<d>&" not in html and "<script" not in html
    assert html.index("car_b") < html.index("car_a")


def test_batch_serial(fleet, tmp_path, capsys):
    out = tmp_path / "out"
    code = run(["check", "--batch", *sorted(str(p) for p in (fleet / "week").iterdir()),
                "--calibrations", str(fleet / "calib"), "--out", str(out), "--scheduler", "serial"])
    captured = capsys.readouterr()
    assert code == EXIT_MOVED, captured.err
    assert "checking: 3/3 vehicles (100%)" in captured.err  # progress on stderr
    assert "about" in captured.err and "s left" in captured.err
    _check_fleet(out, fleet, capsys)


@pytest.mark.slow
def test_batch_on_dask(fleet, dask_cluster, tmp_path, capsys):
    out = tmp_path / "out"
    code = run(["check", "--batch", *sorted(str(p) for p in (fleet / "week").iterdir()),
                "--calibrations", str(fleet / "calib"), "--out", str(out), "--scheduler", dask_cluster.scheduler_address])
    assert code == EXIT_MOVED
    _check_fleet(out, fleet, capsys)


def _dask(*args) -> subprocess.Popen:
    return subprocess.Popen([str(Path(sys.executable).parent / "dask"), *args, "--no-dashboard"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


@pytest.mark.slow
def test_a_lost_scheduler_is_one_line_and_the_finished_vehicles_are_written(vehicle, tmp_path):
    pytest.importorskip("distributed")
    if shutil.which("dask", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("the dask command is not installed beside the interpreter")
    week, calib = tmp_path / "week", tmp_path / "calib"
    for i in range(60):
        (week / f"car{i:03d}").parent.mkdir(exist_ok=True)
        shutil.copytree(vehicle / "moved", week / f"car{i:03d}")
        shutil.copytree(vehicle / "cal", calib / f"car{i:03d}")
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    scheduler = _dask("scheduler", "--host", "127.0.0.1", "--port", str(port))
    worker = None
    try:
        time.sleep(2.0)
        worker = _dask("worker", address, "--nthreads", "1", "--nworkers", "1")
        time.sleep(3.0)
        out = tmp_path / "out"
        cmd = [sys.executable, "-m", "rigcal.cli.main", "check", "--batch", *sorted(str(p) for p in week.iterdir()),
               "--calibrations", str(calib), "--out", str(out), "--scheduler", address]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "COLUMNS": "200"})
        deadline = time.monotonic() + 120
        while not (out / "car002").exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        os.killpg(scheduler.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        for p in (worker, scheduler):
            if p is not None and p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    assert proc.returncode == 1, stderr
    errors = [ln for ln in stderr.splitlines() if ln.startswith("rigcal: error:")]
    assert len(errors) == 1 and "scheduler was lost after" in errors[0], stderr
    assert "Traceback" not in stderr and "distributed" not in stderr.replace(errors[0], "")
    summary = json.loads((out / "fleet.json").read_text())
    done = [v for v in summary["vehicles"] if v["status"] == "moved"]
    lost = [v for v in summary["vehicles"] if v["status"] == "not checked"]
    assert done and lost and len(done) + len(lost) == 60
    for v in done:  # every vehicle finished before the loss is written
        assert (out / v["vehicle"] / "check.json").is_file()
    assert "scheduler was lost" in (out / "fleet.html").read_text()


RADAR_RIG = """
sensors:
  - {name: radar1, kind: radar, topic: /r1, detector: {rcs_min_dbsm: 5}}
  - {name: radar2, kind: radar3d, topic: /r2, detector: {rcs_min_dbsm: 5}}
"""


def _radar_bag(path, seed, placements=5):
    """A 2D and a 3D radar seeing a reflector at ``placements`` places (written with rosbags)."""
    from rigcal.io.recordings.bag import write_recording
    from rigcal.recording import RadarFrame

    rng = np.random.default_rng(seed)
    frames = {"/r1": [], "/r2": []}
    t = 1.0
    for k in range(placements):
        target = np.array([4.0 + k, (-1) ** k * (0.5 + 0.2 * k), 0.1])
        for topic, sensor, rate, dim in (("/r1", "radar1", 13.0, 2), ("/r2", "radar2", 10.0, 3)):
            for i in range(int(3 * rate)):
                pts = np.vstack([target[:dim] + rng.normal(0, 0.02, dim), rng.uniform([1, -3, -0.5], [8, 3, 0.5], (5, 3))[:, :dim]])
                frames[topic].append(RadarFrame(sensor, int((t + i / rate) * 1e9), pts,
                                                np.concatenate([[15.0], rng.uniform(-10, 3, 5)])))
        t += 4.5
    return write_recording(path, frames, "rosbag1")


def test_check_a_recording_detected_first(tmp_path, capsys):
    rig = tmp_path / "detect_rig.yaml"
    rig.write_text(RADAR_RIG)
    assert run(["calibrate", str(_radar_bag(tmp_path / "a.bag", 0)), "--rig", str(rig), "--out", str(tmp_path / "cal"),
                "--cv-folds", "0", "--reference", "radar2"]) == 0
    capsys.readouterr()
    code = run(["check", str(tmp_path / "cal"), str(_radar_bag(tmp_path / "b.bag", 1)), "--rig", str(rig)])
    out = capsys.readouterr().out
    assert code in (0, EXIT_CANNOT_TELL), out
    assert "5 board placements found" in out and "check of" in out and "radar1" in out
    assert run(["check", str(tmp_path / "cal"), str(tmp_path / "b.bag")]) == 1  # a bag is not a manifest
    assert capsys.readouterr().err.startswith("rigcal: error: ")
