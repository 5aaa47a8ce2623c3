"""`rigcal mocap CONFIG --out DIR` on a real bag (the scene of tests/mocap/test_pipeline.py),
and `rigcal demo --mocap`."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.sim.mocap_scene import two_sensor_rig, write_mocap_scene


def test_mocap_cli_writes_results_diagnostics_and_overlays(tmp_path, capsys):
    scene = write_mocap_scene(tmp_path, two_sensor_rig(), seed=0, holds=3, exclusive=False)
    out = tmp_path / "out"
    assert run(["mocap", str(scene.config_path), "--out", str(out), "--json", "--max-overlays", "2"]) == 0
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
    # report.html: the verdict, every kept measurement's residual, the overlays embedded
    report = json.loads((out / "report.json").read_text())
    assert report["kind"] == "mocap"
    kept = [r for r in (out / "diagnostics.csv").read_text().splitlines()[1:] if ",kept," in r]
    assert len(report["mocap"]["measurements"]) == len(kept)
    assert len(report["mocap"]["overlays"]) == len(pngs)
    html = (out / "report.html").read_text()
    shown = html.split('id="overlays"', 1)[1].split("</div>", 1)[0]
    assert shown.count('src="data:image/png;base64,') == len(pngs) and 'id="holds"' in html
    # stderr (the summary, --json) is not a terminal: progress lines, tables within 80 columns
    assert re.search(r"^extracting: (\d+)/\1 frames \(100%\), [0-9.]+ s$", captured.err, re.M), captured.err
    assert all(len(line) <= 80 for line in captured.err.splitlines()) and "…" not in captured.err


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
    with pytest.raises(SystemExit) as exc:
        run(["study", "mocap", "--target", "sphere"])
    assert exc.value.code == 2


# --------------------------------------------------------------------------------------------
# rigcal demo --mocap


@pytest.mark.slow
def test_demo_mocap_calibrates_three_sensors_with_no_shared_view(tmp_path, capsys):
    out = tmp_path / "demo"
    assert run(["demo", "--mocap", "--out", str(out), "--seed", "2", "--holds", "3"]) == 0
    text = capsys.readouterr().out
    assert "T_robot_sensor against the simulated truth" in text
    # two tables within 80 columns: the errors (sensor, model, initial, final, std), then the
    # measurements (sensor, frames, kept, rejected, reasons)
    rows, counts = {}, {}
    for line in text.splitlines():
        m = re.match(r"│ (lidar1|camera1|camera2) +│", line)
        if m:
            cells = [c.strip() for c in line.strip().strip("│").split("│")]
            (counts if m.group(1) in rows else rows)[m.group(1)] = cells
        if "│" in line or "┃" in line:
            assert len(line) <= 80, line
    assert set(rows) == set(counts) == {"lidar1", "camera1", "camera2"}
    # The demo's lidar has a VLP-16's 15 mm range noise and its MCS a Vicon's capture noise:
    # measured with --seed 2 --holds 3 (initial -> final, reported std as root sum of squares):
    # lidar1 36.8 -> 6.40 mm (std 47 mm / 1.37 deg: three holds of a plate pin a lidar down
    # loosely, and the region is wide - issue #23), camera1 10.3 -> 2.69 mm (std 3.75 mm). The
    # error is within what the reported std says (twice the RSS std, ~97 % for a 3-D Gaussian)
    # and the rotation well below a degree.
    for name, cells in rows.items():
        initial_mm = float(cells[2].split("/")[0])
        final_mm, final_deg = (float(v) for v in cells[3].split("/"))
        std_mm, std_deg = (float(v) for v in cells[4].split("/"))
        frames, kept, rejected = (int(v) for v in counts[name][1:4])
        assert initial_mm > 5.0 and final_deg < 0.5, (name, cells)
        assert final_mm < 2.0 * std_mm and final_deg < 2.0 * std_deg, (name, cells)
        lidar = name == "lidar1"
        assert std_mm < (80.0 if lidar else 15.0) and std_deg < (2.0 if lidar else 0.5), (name, cells)
        assert kept > 0 and kept + rejected == frames, (name, cells)
    assert rows["camera2"][1] == "radtan camera" and rows["lidar1"][1] == "vlp16 lidar"
    for f in ("scene/run.bag", "scene/mocap.yaml", "scene/initial.json", "scene/camera2.yaml",
              "results/calibration.yaml", "results/extrinsics.json", "results/diagnostics.csv"):
        assert (out / f).is_file(), f
    assert f"rigcal mocap {out / 'scene' / 'mocap.yaml'} --out {out / 'results'}" in text  # one line
    # the demo was staged in a hidden folder and renamed: its diagnostics name the bag where it
    # is now (a rejection for a frame before the MCS stream started names it)
    diagnostics = (out / "results" / "diagnostics.csv").read_text()
    assert ".partial" not in diagnostics and f"({out / 'scene' / 'run.bag'})" in diagnostics
    # stdout is not a terminal: progress as plain lines, each stage ending at 100 %
    for stage, unit in (("simulating the session", ""), ("extracting targets", " frames")):
        assert re.search(rf"^{stage}: (\d+)/\1{unit} \(100%\), [0-9.]+ s$", text, re.M), stage


@pytest.mark.parametrize("argv, message", [
    (["--mocap", "--boards", "3"], "--mocap does not take --boards"),
    (["--mocap", "--detections-only", "--keep-bag"], "--mocap does not take --detections-only, --keep-bag"),
    (["--mocap", "--holds", "0"], "holds must be an integer in 1..100"),
    (["--mocap", "--holds", "2"], "give at least 3"),
    (["--mocap", "--seed", "-2"], "seed must be an integer >= 0"),
    (["--holds", "2", "--detections-only"], "--holds applies only to the motion-capture demo"),
])
def test_demo_mocap_bad_options_are_one_line_errors(tmp_path, capsys, argv, message):
    assert run(["demo", *argv, "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_demo_mocap_holds_must_be_an_integer(capsys):
    with pytest.raises(SystemExit) as exc:
        run(["demo", "--mocap", "--holds", "two"])
    assert exc.value.code == 2
    assert "invalid int value" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# hostile and broken input (issue #11): one sensor's trouble, NaN in the mocap streams


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The two-sensor session of the first test (lidar1 sees every hold, camera1 its own 3)."""
    return write_mocap_scene(tmp_path_factory.mktemp("mocap_cli_scene"), two_sensor_rig(), seed=0,
                             holds=3, exclusive=False)


def _copy_scene(scene, folder, edit=None):
    """The scene's files in ``folder``, its bag rewritten message by message: ``edit(topic,
    msgtype, t_ns, msg)`` may change ``msg`` in place."""
    import shutil

    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    folder.mkdir()
    for p in scene.folder.iterdir():
        if p != scene.bag_path:
            shutil.copy(p, folder / p.name)
    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(scene.bag_path) as reader, Writer(folder / scene.bag_path.name) as writer:
        conns = {}
        for conn, t_ns, raw in reader.messages():
            if conn.topic not in conns:
                conns[conn.topic] = writer.add_connection(conn.topic, conn.msgtype, typestore=store)
            if edit is not None:
                msg = store.deserialize_ros1(raw, conn.msgtype)
                if edit(conn.topic, conn.msgtype, t_ns, msg):
                    raw = store.serialize_ros1(msg, conn.msgtype)
            writer.write(conns[conn.topic], t_ns, raw)
    return folder / scene.config_path.name


@pytest.mark.slow
def test_mocap_cli_a_camera_that_never_sees_the_target_is_not_calibrated(scene, tmp_path, capsys, caplog):
    # camera1's images are blank: it never sees the target, whatever the search window; the
    # lidar still sees every hold and is calibrated; three robot poses are NaN (mocap dropouts)
    nan_robot = set(range(500, 503))
    counter = {"robot": 0}

    def edit(topic, msgtype, t_ns, msg):
        if topic == "/F1/image_raw":
            msg.data = np.full_like(msg.data, 128)
            return True
        if topic == scene.robot_topic:
            counter["robot"] += 1
            if counter["robot"] in nan_robot:
                msg.transform.rotation.x = float("nan")
                return True
        return False

    cfg = _copy_scene(scene, tmp_path / "blind", edit)
    out = tmp_path / "out"
    with caplog.at_level("WARNING"):
        assert run(["mocap", str(cfg), "--out", str(out), "--json"]) == 4  # EXIT_PARTIAL
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert set(data["sensors"]) == {"lidar1"}
    reason = data["not_calibrated"]["camera1"]
    assert reason.startswith("every measurement was rejected (") and "nothing to calibrate it with" in reason
    T = np.asarray(data["sensors"]["lidar1"]["T_reference_sensor"])
    assert np.abs(T[:3, 3] - scene.truth["lidar1"][:3, 3]).max() < 0.002
    # the terminal says which sensor is missing and why, and that it is a partial result
    err = " ".join(captured.err.split())
    assert "not calibrated: camera1: every measurement was rejected" in err
    assert "partial: 1 of 2 sensors not calibrated (camera1), exit code 4" in err
    assert "Traceback" not in err
    assert "topic /vicon/robot/robot: dropped 3 samples (of" in caplog.text  # a warning
    # the outputs are complete for the calibrated part, the missing sensor listed with its reason
    import yaml

    doc = yaml.safe_load((out / "calibration.yaml").read_text())
    assert set(doc["sensors"]) == {"lidar1"} and doc["not_calibrated"] == {"camera1": reason}
    for name in ("lidar1.yaml", "calibration.launch", "extrinsics.json", "diagnostics.csv"):
        assert (out / name).is_file(), name
    assert not (out / "camera1.yaml").exists()
    ext = json.loads((out / "extrinsics.json").read_text())
    assert "camera_link" not in json.dumps(ext) and "velodyne_link" in json.dumps(ext)
    rows = (out / "diagnostics.csv").read_text().splitlines()
    cam_rows = [r for r in rows if r.startswith("camera1,")]
    assert len(cam_rows) == len(scene.frames["camera1"]) and not any(",kept," in r for r in cam_rows)
    assert all(p.name.startswith("lidar1") for p in (out / "overlays").glob("*.png"))


def _robot_csv_config(scene, tmp_path, rows):
    import yaml

    csv_path = tmp_path / "robot.csv"
    csv_path.write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(",".join(str(v) for v in r) + "\n" for r in rows))
    doc = yaml.safe_load(scene.config_path.read_text())
    folder = scene.folder
    for key in ("recording", "initial_calibration"):
        doc[key] = str(folder / doc[key])
    for t in doc["mocap"]["targets"].values():
        t["definition"] = str(folder / t["definition"])
    for s in doc["sensors"]:
        if "intrinsics" in s:
            s["intrinsics"] = str(folder / s["intrinsics"])
    doc["mocap"]["robot"] = {"csv": str(csv_path)}
    cfg = tmp_path / "mocap.yaml"
    cfg.write_text(yaml.safe_dump(doc, sort_keys=False))
    return cfg, csv_path


def _robot_rows(scene, times_ns):
    from rigcal.mocap import matrix_to_quat_xyzw

    out = []
    for t in times_ns:
        T = scene.T_map_robot_at(t)
        out.append((int(t), *T[:3, 3], *matrix_to_quat_xyzw(T[:3, :3])))
    return out


def test_mocap_cli_no_sensor_calibrated_is_one_line_naming_every_reason(scene, tmp_path, capsys):
    NS = 1_000_000_000
    end = int(scene.frames["camera1"][-1]) + NS
    cfg, _ = _robot_csv_config(scene, tmp_path, _robot_rows(scene, range(scene.t0_ns, end, NS)))  # 1 Hz
    out = tmp_path / "out"
    assert run(["mocap", str(cfg), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert "no sensor can be calibrated: sensor 'lidar1': every measurement was rejected" in err
    assert "; sensor 'camera1': every measurement was rejected" in err and "no_pose_data" in err
    assert not out.exists()


@pytest.mark.parametrize("spoil, what", [
    (lambda r: (*r[:4], "nan", "nan", "nan", "nan"), "column qx: expected a finite number, got 'nan'"),
    (lambda r: (*r[:4], "inf", *r[5:]), "infinite pose value in column qx"),
    (lambda r: (*r[:4], 0.0, 0.0, 0.0, 0.0), "quaternion (qx, qy, qz, qw) has norm 0"),
    (lambda r: (*r[:4], 0.0, 0.0, 0.0, 2.0), "quaternion (qx, qy, qz, qw) has norm 2"),
])
def test_mocap_cli_a_nan_quaternion_row_in_a_pose_csv_is_one_line(scene, tmp_path, capsys, spoil, what):
    NS = 1_000_000_000
    rows = _robot_rows(scene, range(scene.t0_ns, scene.t0_ns + NS, NS // 100))
    rows[42] = spoil(rows[42])
    cfg, csv_path = _robot_csv_config(scene, tmp_path, rows)
    out = tmp_path / "out"
    assert run(["mocap", str(cfg), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert f"{csv_path}: line 44: {what}" in err  # row 42 after the header on line 1
    assert not out.exists()


def test_mocap_cli_a_non_unit_quaternion_in_a_bag_pose_stream_is_one_line(scene, tmp_path, capsys):
    counter = {"n": 0}

    def edit(topic, msgtype, t_ns, msg):
        if topic != scene.target_topic:
            return False
        counter["n"] += 1
        if counter["n"] == 101:  # message 100 of the target's topic
            msg.transform.rotation.w *= 1.5
            return True
        return False

    cfg = _copy_scene(scene, tmp_path / "bad", edit)
    out = tmp_path / "out"
    assert run(["mocap", str(cfg), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert f"run.bag: topic {scene.target_topic}: message 100 (stamp " in err
    assert "expected a unit quaternion" in err
    assert not out.exists()


def test_study_mocap_out_writes_markdown_json_and_plot(tmp_path, capsys):
    out = tmp_path / "mocap"
    assert run(["study", "mocap", "--trials", "1", "--measurements", "5", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["mocap.png", "study.html",
                                                                                   "study.json", "study.md"]
    doc = json.loads((out / "study.json").read_text())
    assert doc["meta"]["trials"] == 1 and doc["meta"]["scheduler"] == "serial"  # 1 trial: no cluster
    rows = {r["metric"]: r for r in doc["rows"]}
    assert rows["translation_norm_diff_mm"]["paper_mean"] == 0.3 and rows["residual"]["paper_mean"] == 2.2
    assert rows["translation_mm"]["measurements"] == 5 and rows["translation_mm"]["mean"] is not None
    md = (out / "study.md").read_text()
    assert "| 5 | 1/1 |" in md and "![mocap](mocap.png)" in md
