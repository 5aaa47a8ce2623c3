"""`rigcal detect` and `rigcal calibrate --rig` on real bags written with rosbags."""

from __future__ import annotations

import re

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.io.recordings.bag import write_recording
from rigcal.recording import RadarFrame

NS = 1_000_000_000
RIG = """
sensors:
  - {name: radar1, kind: radar, topic: /r1, detector: {rcs_min_dbsm: 5}}
  - {name: radar2, kind: radar3d, topic: /r2, detector: {rcs_min_dbsm: 5}}
"""


def _radar_bag(path, placements=4, rcs=15.0, frame_ids=None):
    rng = np.random.default_rng(0)
    frames = {"/r1": [], "/r2": []}
    t = 1.0
    for k in range(placements):
        target = np.array([4.0 + k, (-1) ** k * 0.5, 0.1])
        for topic, sensor, rate, dim in (("/r1", "radar1", 13.0, 2), ("/r2", "radar2", 10.0, 3)):
            for i in range(int(3 * rate)):
                clutter = rng.uniform([1, -3, -0.5], [8, 3, 0.5], (5, 3))[:, :dim]
                pts = np.vstack([target[:dim] + rng.normal(0, 0.02, dim), clutter])
                r = np.concatenate([[rcs], rng.uniform(-10, 3, 5)])
                frames[topic].append(RadarFrame(sensor, int((t + i / rate) * NS), pts, r,
                                                frame_id=(frame_ids or {}).get(sensor, "")))
        t += 4.5
    return write_recording(path, frames, "rosbag1")


@pytest.fixture
def rig(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text(RIG)
    return p


def _one_error_line(capsys):
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("rigcal: error:"), err
    return lines[0]


def test_detect_writes_a_dataset_and_calibrate_reads_a_recording(tmp_path, rig, capsys):
    bag = _radar_bag(tmp_path / "rec.bag")
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "det")]) == 0
    out = capsys.readouterr().out
    assert "4 board placements found" in out and "radar1" in out
    # stdout is not a terminal: the progress is plain lines, the last at 100 % with the time
    lines = [ln for ln in out.splitlines() if ln.startswith("detecting: ")]
    assert 2 <= len(lines) <= 12, lines
    assert re.fullmatch(r"detecting: (\d+)/\1 frames \(100%\), [0-9.]+ s", lines[-1]), lines
    assert all(len(line) <= 80 for line in out.splitlines()) and "…" not in out
    assert (tmp_path / "det" / "rig.yaml").is_file() and (tmp_path / "det" / "radar2.csv").is_file()


def test_corrupt_bag_is_one_line(tmp_path, rig, capsys):
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"not a bag at all")
    assert run(["detect", str(bad), "--rig", str(rig), "--out", str(tmp_path / "o")]) == 1
    assert "bad.bag" in _one_error_line(capsys)
    assert not (tmp_path / "o").exists()


def test_missing_topic_names_the_sensor(tmp_path, rig, capsys):
    bag = _radar_bag(tmp_path / "rec.bag")
    rig.write_text(RIG.replace("/r2", "/radar_front"))
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "o")]) == 1
    line = _one_error_line(capsys)
    assert "sensor 'radar2'" in line and "/radar_front" in line and "/r1" in line
    assert not (tmp_path / "o").exists()


def test_board_never_found_says_what_was_seen(tmp_path, rig, capsys):
    bag = _radar_bag(tmp_path / "rec.bag", rcs=-20.0)  # the reflector is filtered out
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "o")]) == 1
    line = _one_error_line(capsys)
    assert "no board placement found" in line and "radar1: 0 detections" in line


def test_cloud_without_xyz_names_the_topic(tmp_path, capsys):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    PointCloud2 = ts.types["sensor_msgs/msg/PointCloud2"]
    PointField = ts.types["sensor_msgs/msg/PointField"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    msg = PointCloud2(
        header=Header(seq=0, stamp=Time(sec=1, nanosec=0), frame_id="lidar"),
        height=1, width=2,
        fields=[PointField(name="intensity", offset=0, datatype=7, count=1)],
        is_bigendian=False, point_step=4, row_step=8,
        data=np.zeros(8, dtype=np.uint8), is_dense=True,
    )
    bag = tmp_path / "noxyz.bag"
    with Writer(bag) as w:
        conn = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(conn, NS, ts.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    rig = tmp_path / "rig.yaml"
    rig.write_text("sensors:\n  - {name: lidar1, kind: lidar, topic: /points}\n")
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "o")]) == 1
    line = _one_error_line(capsys)
    assert "/points" in line and "intensity" in line and "x, y, z" in line, line


def test_calibrate_with_rig_runs_detection_first(tmp_path, rig, capsys):
    # two radars cannot be calibrated to each other in 2D, but a 2D and a 3D radar can
    bag = _radar_bag(tmp_path / "rec.bag")
    code = run(["calibrate", str(bag), "--rig", str(rig), "--out", str(tmp_path / "cal"), "--no-plot",
                "--cv-folds", "0", "--reference", "radar2"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "4 board placements found" in out.out and "radar2-radar1" in out.out.replace("radar1-radar2", "radar2-radar1")
    assert re.search(r"^detecting: (\d+)/\1 frames \(100%\), [0-9.]+ s$", out.out, re.M), out.out
    assert (tmp_path / "cal" / "calibration.yaml").is_file()


def test_frame_ids_default_to_the_messages(tmp_path, rig, capsys):
    """Without a frame_id in the rig, a sensor's frame is its messages' header.frame_id (a ROS 1
    leading slash dropped); a rig frame_id that differs from the messages' is kept, with a note."""
    import yaml

    bag = _radar_bag(tmp_path / "rec.bag", frame_ids={"radar1": "/front_radar", "radar2": "radar_3d_link"})
    rig.write_text(RIG.replace("topic: /r2,", "topic: /r2, frame_id: rear_radar,"))
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "det")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    manifest = yaml.safe_load((tmp_path / "det" / "rig.yaml").read_text())
    frames = {s["name"]: s["frame_id"] for s in manifest["sensors"]}
    assert frames == {"radar1": "front_radar", "radar2": "rear_radar"}
    assert ("note: sensor 'radar2': frame_id 'rear_radar' (rig) differs from its messages' "
            "frame_id 'radar_3d_link'; the rig's is used") in out


def test_calibrate_with_rig_keeps_the_detections_and_says_how_to_rerun(tmp_path, rig, capsys):
    """The detections land in OUT/detections/ with the result; the printed command calibrates
    them in another mode without detecting again, to the same poses as from the recording."""
    import shlex

    import yaml

    bag = _radar_bag(tmp_path / "rec.bag")
    cal = tmp_path / "cal"
    assert run(["calibrate", str(bag), "--rig", str(rig), "--out", str(cal), "--cv-folds", "0",
                "--reference", "radar2"]) == 0
    out = capsys.readouterr().out
    kept = cal / "detections" / "rig.yaml"
    assert kept.is_file() and (cal / "detections" / "radar1.csv").is_file()
    assert f"detections kept in {kept}; another mode without detecting again:" in out
    command = next(ln.strip() for ln in out.splitlines() if ln.strip().startswith("rigcal calibrate "))
    argv = shlex.split(command)[1:]
    # PSE needs a lidar or camera: for these two radars the other mode offered is MCPE
    assert argv[:4] == ["calibrate", str(kept), "--mode", "mcpe"] and argv[-1] == str(tmp_path / "cal_mcpe")
    assert run([*argv, "--cv-folds", "0", "--reference", "radar2"]) == 0
    assert "detecting" not in capsys.readouterr().out  # nothing detected again
    # the kept detections are the recording's: FCPE from them equals FCPE from the recording
    assert run(["calibrate", str(kept), "--out", str(tmp_path / "again"), "--cv-folds", "0",
                "--reference", "radar2"]) == 0
    a = yaml.safe_load((cal / "calibration.yaml").read_text())["sensors"]["radar1"]["T_reference_sensor"]
    b = yaml.safe_load((tmp_path / "again" / "calibration.yaml").read_text())["sensors"]["radar1"]["T_reference_sensor"]
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_keep_detections_dir_is_written_before_calibrating(tmp_path, rig, capsys, monkeypatch):
    """--keep-detections DIR keeps them even when the calibration then fails."""
    from rigcal.cli import calibrate as calibrate_cli
    from rigcal.errors import InputError

    bag = _radar_bag(tmp_path / "rec.bag")

    def fail(*a, **k):
        raise InputError("no calibration today")

    monkeypatch.setattr("rigcal.problem.calibrate.calibrate", fail)
    assert calibrate_cli.DETECTIONS_DIR == "detections"
    code = run(["calibrate", str(bag), "--rig", str(rig), "--out", str(tmp_path / "cal"),
                "--keep-detections", str(tmp_path / "dets")])
    assert code == 1 and "no calibration today" in capsys.readouterr().err
    assert (tmp_path / "dets" / "rig.yaml").is_file() and not (tmp_path / "cal").exists()


def test_keep_detections_needs_a_recording(tmp_path, rig, capsys):
    bag = _radar_bag(tmp_path / "rec.bag")
    assert run(["detect", str(bag), "--rig", str(rig), "--out", str(tmp_path / "det")]) == 0
    capsys.readouterr()
    assert run(["calibrate", str(tmp_path / "det" / "rig.yaml"), "--out", str(tmp_path / "c"),
                "--keep-detections", str(tmp_path / "k")]) == 1
    assert "--keep-detections applies to a recording detected with --rig" in _one_error_line(capsys)


def test_pse_on_radars_alone_is_a_clear_error(tmp_path, rig, capsys):
    bag = _radar_bag(tmp_path / "rec.bag")
    assert run(["calibrate", str(bag), "--rig", str(rig), "--mode", "pse", "--reference", "radar2",
                "--out", str(tmp_path / "c"), "--keep-detections", str(tmp_path / "k")]) == 1
    line = _one_error_line(capsys)
    assert "PSE needs a lidar or camera" in line and "radar1, radar2" in line
    assert (tmp_path / "k" / "rig.yaml").is_file()  # the detection work is not lost
