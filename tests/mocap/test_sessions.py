"""The motion-capture pipeline on realistic simulated sessions with known truth (issue 23).

Each session is written by :func:`rigcal.sim.mocap_scene.write_mocap_scene` (a real ROS 1 bag)
with the errors a user's MCS session has: a sensor seen in one hold only, MCS noise per capture,
a clock offset between the MCS and a sensor while the robot moves, bursts of dropped MCS samples,
a target configured but never seen, and a hand-measured guess 30 cm / 30 deg off. Sessions are
short (holds of 1 s) to keep the suite fast.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run as cli
from rigcal.geometry.se3 import se3_exp, se3_log, invert
from rigcal.mocap.config import load_mocap_config
from rigcal.mocap.pipeline import run_mocap
from rigcal.sim.mocap_scene import RobotPath, SceneTiming, two_sensor_rig, write_mocap_scene
from rigcal.study.coverage import CHI2_95_6, nees

CHI2_999_6 = 22.457744484825323
QUICK = SceneTiming(hold_s=1.0, move_s=0.6, lead_s=0.4, gap_hold=None)


def _error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    e = se3_log(invert(T) @ T_true)
    return float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1e3), math.degrees(float(np.linalg.norm(e[:3])))


def _nees(run, scene, name: str) -> float:
    est = run.result.sensors[name]
    return nees(est.T_reference_sensor, scene.truth[name], est.covariance)[0]


def _edit(path: Path, edit) -> Path:
    doc = yaml.safe_load(path.read_text())
    edit(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.slow
def test_a_camera_seen_in_one_hold_is_refused_naming_the_holds_it_needs(tmp_path, capsys):
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=3, holds=(4, 1), timing=QUICK, exclusive=False)
    r = run_mocap(load_mocap_config(scene.config_path))
    assert set(r.result.sensors) == {"lidar1"}  # the lidar is still calibrated
    why = r.not_calibrated["camera1"]
    assert "1 distinct hold" in why and "2 more times in its image" in why and "tilts" in why
    # one session's NEES against the 99.9 % quantile (a right covariance fails it once in a
    # thousand; the 95 % coverage is the benchmark's, over populations): the lidar, tied by its
    # points' ranges and ring ends, gives 15.2 here (a 1.4 mm error in z, 2 % tail; seeds 4 and
    # 5 of this session give 5.7 and 7.0)
    assert _nees(r, scene, "lidar1") < CHI2_999_6
    # the CLI writes the lidar and exits 4 (partial), never 0
    code = cli(["mocap", str(scene.config_path), "--out", str(tmp_path / "out")])
    shown = "".join(capsys.readouterr())  # the summary (stdout) and the warnings (stderr)
    assert code == 4 and "camera1" in shown and "2 more" in shown
    text = (tmp_path / "out" / "calibration.yaml").read_text()
    assert "camera1" in yaml.safe_load(text)["not_calibrated"]


@pytest.mark.slow
def test_mcs_noise_per_capture_is_taken_from_the_streams(tmp_path):
    # a Vicon's noise on every sample of the robot and the target, a 15 mm range noise: every
    # sensor near its truth and inside its reported region, the per-capture error estimated
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=5, holds=4, timing=QUICK, exclusive=False,
                              mcs_noise=(0.00015, 0.0003))
    r = run_mocap(load_mocap_config(scene.config_path))
    for name in ("lidar1", "camera1"):
        t, a = _error(r.final[name], scene.truth[name])
        assert t < 6.0 and a < 0.3, (name, t, a)
        assert _nees(r, scene, name) < CHI2_95_6, name
    cam = r.fit.sensors["camera1"]
    # the streams' own scatter: robot and target each 0.15 mm; the target seen from 2-3 m
    assert 0.0001 < cam.components["capture_m"] < 0.002
    obs = [o for o in r.observations if o.sensor == "camera1"]
    assert all(o.pose_cov is not None for o in obs)
    assert r.result.verdict.status == "consistent"


@pytest.mark.slow
def test_a_clock_offset_is_recovered_when_the_robot_turns(tmp_path):
    # the robot creeps and sways about its heading through the holds (a turn rate that
    # changes: under a constant twist an offset is the same as a fixed change of the sensor's
    # pose); the camera stamps its frames 60 ms late, the lidar 25 ms: each recovered to 2 ms,
    # or flagged when it matters, or (not determined, hardly matters) inside the covariance
    path = RobotPath(velocity_mps=(0.02, 0.0, 0.0), sway_deg=6.0, sway_period_s=5.0)
    timing = SceneTiming(hold_s=1.5, move_s=0.6, lead_s=0.4, gap_hold=None)
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(lidar_range_sigma_m=0.005), seed=4,
                              holds=5, timing=timing, exclusive=False, robot=path, robot_still_in_holds=False,
                              stamp_delay_s={"camera1": 0.060, "lidar1": 0.025})

    def faster(doc):  # the targets sweep past at up to 0.3 m/s, 10 deg/s: still used
        doc["extraction"]["max_linear_mps"] = 0.3
        doc["extraction"]["max_angular_dps"] = 10.0
    r = run_mocap(load_mocap_config(_edit(scene.config_path, faster)))
    for name, delay in (("camera1", 0.060), ("lidar1", 0.025)):
        f = r.fit.sensors[name]
        if f.time_offset_status == "determined":
            assert abs(f.time_offset_s - delay) <= 0.002, (name, f.time_offset_s)
        elif f.time_offset_status == "undetermined":
            assert r.result.flagged, name
        else:
            assert f.time_offset_status == "irrelevant", (name, f.time_offset_status)
            assert abs(f.time_offset_s - delay) <= 3 * f.time_offset_std_s, (name, f.time_offset_s)
        assert _nees(r, scene, name) < CHI2_95_6, name
    lidar = r.fit.sensors["lidar1"]
    assert lidar.time_offset_status == "determined"  # this session does tell it (25.2 +- 0.6 ms)
    check = {c.name: c for c in r.result.verdict.checks}["time_offset"]
    assert any(f"lidar1 +{v}." in check.detail for v in (23, 24, 25, 26, 27)), check.detail


@pytest.mark.slow
def test_a_clock_offset_that_cannot_be_told_from_the_pose_is_flagged(tmp_path, capsys):
    # the robot creeps at 5 cm/s in a straight line through the holds: a clock offset shifts
    # every frame's target by the same 5 cm/s x offset, which the sensor's translation absorbs.
    # The 40 ms delay cannot be estimated and matters (2 mm): flagged, not written
    path = RobotPath(velocity_mps=(0.05, 0.0, 0.0))
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=6, holds=4, timing=QUICK, exclusive=False,
                              robot=path, robot_still_in_holds=False, mcs_noise=(0.00015, 0.0003),
                              stamp_delay_s={"camera1": 0.040, "lidar1": 0.040})
    code = cli(["mocap", str(scene.config_path), "--out", str(tmp_path / "out")])
    shown = "".join(capsys.readouterr())  # the summary (stdout) and the warnings (stderr)
    assert code == 3 and "time_offset" in shown and "could not be told from the pose" in shown
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_dropout_bursts_are_interpolated_over(tmp_path):
    # 10 % of the robot's and 15 % of the target's MCS samples dropped, and a 60 ms occlusion
    # in every hold: bridged (25 sample periods), the lidar keeps its holds
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=8, holds=4, timing=QUICK, exclusive=False,
                              dropout_fraction=(0.10, 0.15), glitch_s=0.06)
    r = run_mocap(load_mocap_config(scene.config_path))
    assert set(r.result.sensors) == {"lidar1", "camera1"}
    counts = r.counts
    # only the frames whose +-0.25 s motion window reaches past the session's ends lack poses
    t = scene.frames["lidar1"]
    edge = int(np.sum((t - scene.t0_ns < 250_000_000) | (scene.end_ns - t < 250_000_000)))
    assert counts["lidar1"].get("no_pose_data", 0) == edge and counts["lidar1"]["kept"] >= 8
    # a burst longer than max_dropout_s is a gap again
    def short(doc):
        doc["mocap"]["max_dropout_s"] = 0.03
    r2 = run_mocap(load_mocap_config(_edit(scene.config_path, short)))
    assert r2.counts["lidar1"].get("no_pose_data", 0) > edge


@pytest.mark.slow
def test_from_a_guess_30_cm_and_30_deg_off_every_sensor_reaches_the_good_answer(tmp_path):
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=7, holds=4, timing=QUICK, exclusive=False)
    good = run_mocap(load_mocap_config(scene.config_path))
    rng = np.random.default_rng(2300)
    far = {}
    for name, T in scene.truth.items():
        d = rng.normal(size=6)
        d[:3] *= math.radians(30.0) / np.linalg.norm(d[:3])
        d[3:] *= 0.30 / np.linalg.norm(d[3:])
        far[name] = T @ se3_exp(d)
    from rigcal.mocap import Extrinsics, write_extrinsics_json

    cfg = load_mocap_config(scene.config_path)
    write_extrinsics_json(scene.initial_path, Extrinsics(
        {(cfg.robot_frame, s.frame_id): far[s.name] for s in scene.sensors}))
    r = run_mocap(load_mocap_config(scene.config_path))
    for name in scene.truth:
        if name in r.not_calibrated:
            assert r.not_calibrated[name], name  # refused with a reason
            continue
        t, a = _error(r.final[name], good.final[name])
        assert t < 0.5 and a < 0.02, (name, t, a)
    assert "lidar1" in r.result.sensors  # the global search found it


def test_the_residual_has_one_definition_in_every_output(tmp_path):
    # calibration.yaml's rmse / reprojection, the measurements table and diagnostics.csv
    # report the same measured residual (not the configured sigma)
    import csv

    from rigcal.mocap.pipeline import summary_rows, write_mocap_outputs

    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=1, holds=3, timing=QUICK, exclusive=False)
    r = run_mocap(load_mocap_config(scene.config_path))
    write_mocap_outputs(r, tmp_path / "out", report=False)
    rows = {row[0]: row for row in summary_rows(r)}
    doc = yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())
    with open(tmp_path / "out" / "diagnostics.csv") as fh:
        diag = [d for d in csv.DictReader(fh) if d["status"] == "kept"]
    for name, key, table in (("lidar1", "robot-lidar1", "rmse_m"), ("camera1", "robot-camera1", "reprojection_px")):
        value = doc[table][key]
        assert value == pytest.approx(rows[name][7], rel=1e-6)
        mine = [d for d in diag if d["sensor"] == name]
        w = np.array([float(d["keypoints"]) for d in mine])
        v = np.array([float(d["residual_final"]) for d in mine])
        assert value == pytest.approx(float(np.sqrt(np.sum(w * v * v) / np.sum(w))), rel=1e-6)
        sensor = next(s for s in r.fit.sensors.values() if s.name == name)
        assert value != pytest.approx(sensor.sigma_nominal)  # not the configured sigma
    assert doc["num_boards"] == 0


def _pose_rows(times_ns, T_of):
    from rigcal.mocap import matrix_to_quat_xyzw

    lines = ["t,x,y,z,qx,qy,qz,qw"]
    for t in times_ns:
        T = T_of(int(t))
        lines.append(",".join(str(v) for v in (int(t), *T[:3, 3], *matrix_to_quat_xyzw(T[:3, :3]))))
    return lines


@pytest.mark.slow
def test_a_target_never_seen_is_reported_and_a_corrupt_pose_row_is_an_input_error(tmp_path, capsys):
    # a second target configured whose MCS body stands 40 m away the whole session: the
    # sensors are calibrated from the diamond, the unseen one reported (exit 0, not 1)
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=2, holds=3, timing=QUICK, exclusive=False)
    times = range(scene.t0_ns, scene.end_ns + 1, 10_000_000)
    far = np.eye(4)
    far[:3, 3] = (40.0, 0.0, 1.0)
    (scene.folder / "far.csv").write_text("\n".join(_pose_rows(times, lambda t: far)) + "\n")

    def add(doc):
        doc["mocap"]["targets"]["spare"] = {"csv": "far.csv", "time_unit": "ns",
                                            "definition": scene.target_path.name}
    _edit(scene.config_path, add)
    code = cli(["mocap", str(scene.config_path), "--out", str(tmp_path / "out")])
    shown = "".join(capsys.readouterr())
    assert code == 0, shown
    assert "spare" in shown and "never" in shown
    doc = yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())
    assert {"lidar1", "camera1"} <= set(doc["sensors"])
    # the robot's stream as a CSV with one row whose x is nan (the rest of the row present):
    # an input error naming the file and the line, nothing written
    rows = _pose_rows(times, scene.T_map_robot_at)
    cols = rows[200].split(",")
    cols[1] = "nan"
    rows[200] = ",".join(cols)
    (scene.folder / "robot.csv").write_text("\n".join(rows) + "\n")

    def robot_csv(doc):
        doc["mocap"]["robot"] = {"csv": "robot.csv", "time_unit": "ns"}
    _edit(scene.config_path, robot_csv)
    code = cli(["mocap", str(scene.config_path), "--out", str(tmp_path / "out2")])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert re.search(r"rigcal: error: .*robot\.csv: line 201: column x: expected a finite number, got 'nan'", err), err
    assert not (tmp_path / "out2").exists()


@pytest.mark.slow
def test_captures_stamped_1_ns_apart_share_no_target_pose_by_accident(tmp_path):
    # the camera's frames stamped 1 ns after the lidar's (its clock 125 ms behind; the robot
    # and target stand still in the holds, so that does not move them), with target poses
    # estimated under the MCS's prior: observations 1 ns apart at different places are not
    # one capture - both sensors land where they do without the option
    scene = write_mocap_scene(tmp_path / "s", two_sensor_rig(), seed=9, holds=4, timing=QUICK, exclusive=False,
                              stamp_delay_s={"camera1": -0.125 + 1e-9})
    assert np.min(np.abs(scene.frames["camera1"][:, None] - 125_000_000 + 1
                         - scene.frames["lidar1"][None, :])) == 1  # 1 ns apart
    plain = run_mocap(load_mocap_config(scene.config_path))

    def tied(doc):
        doc["options"]["target_pose_sigma"] = [0.001, 0.001]
    r = run_mocap(load_mocap_config(_edit(scene.config_path, tied)))
    for name in ("lidar1", "camera1"):
        t, a = _error(r.final[name], scene.truth[name])
        t0, _ = _error(plain.final[name], scene.truth[name])
        assert t < max(3 * t0, 3.0) and a < 0.3, (name, t, a, t0)  # was metres off
