"""End to end on a simulated rig with known truth: mounting priors from the command line and the
manifest (``--initial``, ``--prior``), ``rigcal urdf`` keeping the URDF's values for directions a
calibration only bounds (``--write-bounded`` writes the estimate), bounded intervals as absolute
values with the estimate, and the relative-transform table."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.geometry.se3 import invert, se3_exp
from rigcal.io.dataset.manifest import write_dataset
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.results.urdf import add_fixed_links, forward_kinematics, parse_urdf
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

RADAR_TOL = "radar1:z_m=0.02,roll_deg=1,pitch_deg=1"


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 15, min_fraction=1.0), rng=rng, reference="lidar1")


@pytest.fixture
def files(tmp_path, sim):
    """rig.yaml, robot.urdf (the true mounting, but radar1 5 cm and 1 deg off in its plane) and
    nominal.yaml (the same poses as a calibration.yaml, for --initial)."""
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    truth = {s.name: s.T_rig_sensor for s in prius_like_rig()}
    nominal = dict(truth)
    nominal["radar1"] = truth["radar1"] @ se3_exp(np.array([0, 0, np.radians(1.0), 0.05, 0.0, 0.0]))
    urdf = add_fixed_links('<robot name="r">\n  <link name="base_link"/>\n</robot>\n', "robot.urdf", nominal, "base_link")
    (tmp_path / "robot.urdf").write_text(urdf)
    ref = invert(nominal["lidar1"])
    doc = {"reference": "lidar1", "sensors": {n: {"T_reference_sensor": (ref @ T).tolist()} for n, T in nominal.items()}}
    (tmp_path / "nominal.yaml").write_text(yaml.safe_dump(doc))
    return tmp_path, manifest, truth, nominal


def test_urdf_keeps_the_bounded_directions_of_the_urdf(files, capsys):
    tmp, manifest, truth, nominal = files
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--out", str(tmp / "cal")]) == 0
    out = capsys.readouterr().out
    # bounded intervals as absolute values with the estimate; the rank line does not claim them
    assert "note (bounded): radar1:" in out and "(estimate" in out
    checks = {c["name"]: c["detail"] for c in yaml.safe_load((tmp / "cal" / "calibration.yaml").read_text())["verdict"]["checks"]}
    assert checks["rank"].startswith("every direction determined except those of radar1")
    cal = read_calibration_transforms(tmp / "cal" / "calibration.yaml")
    assert cal.bounded == {"radar1": ("roll", "pitch", "z")}
    assert run(["urdf", str(tmp / "robot.urdf"), str(tmp / "cal" / "calibration.yaml"), "--out", str(tmp / "kept.urdf")]) == 0
    out = capsys.readouterr().out.replace("\n", " ")
    assert "radar1: roll, pitch, z kept from" in out and "the calibration only bounds them: z" in out
    written = parse_urdf((tmp / "kept.urdf").read_text(), "kept.urdf")
    T_w = forward_kinematics(written, "base_link", "radar1")
    N, C, T_true = nominal["radar1"], nominal["lidar1"] @ cal.transforms["radar1"], truth["radar1"]
    # the URDF's plane kept exactly (its z axis, its height along it) ...
    np.testing.assert_allclose(T_w[:3, 2], N[:3, 2], atol=1e-9)
    assert abs(N[:3, 2] @ (T_w[:3, 3] - N[:3, 3])) < 1e-9
    # ... where the estimate is tilted away from it; the in-plane pose is the calibrated one,
    # close to the truth although the URDF was 5 cm / 1 deg off there
    assert np.degrees(np.arccos(np.clip(C[:3, 2] @ N[:3, 2], -1, 1))) > 0.3
    assert np.linalg.norm(T_w[:2, 3] - T_true[:2, 3]) < 0.03 < np.linalg.norm(N[:2, 3] - T_true[:2, 3])
    # the camera is measured in every direction: written as calibrated
    np.testing.assert_allclose(forward_kinematics(written, "lidar1", "camera1"), cal.transforms["camera1"], atol=1e-9)
    # every writer given the URDF publishes the same (rule 5 of the frame contract)
    assert run(["export", str(tmp / "cal" / "calibration.yaml"), "--urdf", str(tmp / "robot.urdf"),
                "--format", "yaml", "--out", str(tmp / "tf.yaml")]) == 0
    assert "radar1: roll, pitch, z kept from" in capsys.readouterr().out.replace("\n", " ")
    tf = yaml.safe_load((tmp / "tf.yaml").read_text())["transforms"]
    np.testing.assert_allclose(tf["radar1"]["T_parent_child"], forward_kinematics(written, "lidar1", "radar1"), atol=1e-9)
    # --write-bounded writes the estimate, and says so
    assert run(["urdf", str(tmp / "robot.urdf"), str(tmp / "cal" / "calibration.yaml"), "--write-bounded",
                "--out", str(tmp / "estimate.urdf")]) == 0
    assert "written from the estimate (--write-bounded)" in capsys.readouterr().out.replace("\n", " ")
    est = parse_urdf((tmp / "estimate.urdf").read_text(), "estimate.urdf")
    np.testing.assert_allclose(forward_kinematics(est, "lidar1", "radar1"), cal.transforms["radar1"], atol=1e-9)


def test_prior_from_the_command_line_determines_the_radar_plane(files, capsys):
    tmp, manifest, truth, nominal = files
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--initial", str(tmp / "nominal.yaml"),
                "--prior", RADAR_TOL, "--out", str(tmp / "cal"), "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    radar = data["sensors"]["radar1"]
    assert radar["bounded"] == {} and radar["bounded_offsets"] == {}
    assert radar["prior"] == {"roll_deg": 1.0, "pitch_deg": 1.0, "z_m": 0.02}
    assert 0.5 < radar["std"]["pitch_deg"] <= 1.02 and 0.01 < radar["std"]["z_m"] <= 0.021
    assert {c["name"]: c["detail"] for c in data["verdict"]["checks"]}["rank"] == "every direction determined"
    assert "mounting priors" in captured.err
    # nothing bounded: rigcal urdf writes the calibration as it is
    assert run(["urdf", str(tmp / "robot.urdf"), str(tmp / "cal" / "calibration.yaml"), "--out", str(tmp / "p.urdf")]) == 0
    assert "kept from" not in capsys.readouterr().out
    cal = read_calibration_transforms(tmp / "cal" / "calibration.yaml")
    got = forward_kinematics(parse_urdf((tmp / "p.urdf").read_text(), "p.urdf"), "lidar1", "radar1")
    np.testing.assert_allclose(got, cal.transforms["radar1"], atol=1e-9)


def test_prior_from_the_manifest_and_hold_radar_plane(files, capsys):
    tmp, manifest, truth, nominal = files
    doc = yaml.safe_load(manifest.read_text())
    next(s for s in doc["sensors"] if s["name"] == "radar1")["prior"] = {"z_m": 0.02, "roll_deg": 1, "pitch_deg": 1}
    manifest.write_text(yaml.safe_dump(doc))
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--initial", str(tmp / "nominal.yaml"),
                "--out", str(tmp / "m"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sensors"]["radar1"]["prior"]["z_m"] == 0.02
    # the manifest's prior needs the nominal pose: one line, exit 1, nothing written
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--out", str(tmp / "n")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error: sensor 'radar1': a mounting prior") and "--initial" in err
    assert not (tmp / "n").exists()
    # --hold-radar-plane: the prior's directions held at the nominal pose
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--initial", str(tmp / "nominal.yaml"),
                "--hold-radar-plane", "--out", str(tmp / "h"), "--json"]) == 0
    radar = json.loads(capsys.readouterr().out)["sensors"]["radar1"]
    assert radar["held"] == ["z", "roll", "pitch"]
    cov = np.array(radar["covariance"])
    assert np.all(cov[[0, 1, 5]] == 0.0) and np.all(cov[:, [0, 1, 5]] == 0.0) and cov[2, 2] > 0


@pytest.mark.parametrize("arg, message", [
    ("z_m", r"--prior 'z_m': expected \[SENSOR:\]key=value"),
    ("radar9:z_m=1", r"unknown sensor 'radar9'"),
    ("radar1:tilt_deg=1", r"unknown direction 'tilt_deg'"),
    ("lidar1:z_m=0.1", r"'lidar1' is the reference sensor"),
])
def test_bad_prior_is_one_line(files, capsys, arg, message):
    import re

    tmp, manifest, _, _ = files
    assert run(["calibrate", str(manifest), "--initial", str(tmp / "nominal.yaml"), "--prior", arg,
                "--out", str(tmp / "x")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rigcal: error:") and err.count("\n") == 1 and re.search(message, err), err
    assert not (tmp / "x").exists()


def test_relative_table_takes_the_honest_covariance(files, capsys):
    tmp, manifest, _, _ = files
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--out", str(tmp / "cal"), "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    # a pair with the reference is the sensor's pose: the same covariance, the same std
    rel = data["relative"]["lidar1-camera1"]
    np.testing.assert_allclose(rel["covariance"], data["sensors"]["camera1"]["covariance"], rtol=1e-12, atol=1e-18)
    assert rel["std"] == data["sensors"]["camera1"]["std"]
    # the radar's bounded directions make the camera <- radar transform bounded where they enter
    cr = data["relative"]["camera1-radar1"]
    assert {"roll", "pitch"} & set(cr["bounded"]) and cr["gimbal_lock"] is True
    assert all(v["low"] <= v["estimate"] <= v["high"] for v in cr["bounded"].values())
    assert len(cr["rotation_std_deg"]) == 3
    err = captured.err
    assert "relative transforms (T_to_from)" in err and "near gimbal lock" in err
    table = err.split("relative transforms (T_to_from)")[1].split("errors between sensors")[0]
    assert "bnd" in table


def test_calibrate_with_the_urdf_writes_the_kept_directions(files, capsys):
    """`calibrate --initial robot.urdf` without a prior: the radar's z, roll, pitch stay bounded;
    calibration.launch and the frames block publish the URDF's values for them, and an export
    without the URDF later publishes the same."""
    tmp, manifest, truth, nominal = files
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--initial", str(tmp / "robot.urdf"),
                "--out", str(tmp / "cal")]) == 0
    assert "radar1: roll, pitch, z kept from" in capsys.readouterr().out.replace("\n", " ")
    data = yaml.safe_load((tmp / "cal" / "calibration.yaml").read_text())
    assert list(data["sensors"]["radar1"]["bounded_offsets"]) == ["roll", "pitch", "z"]
    kept = np.array(data["frames"]["sensors"]["radar1"]["kept_from_urdf"]["T_reference_measured"])
    N = invert(nominal["lidar1"]) @ nominal["radar1"]
    np.testing.assert_allclose(kept[:3, 2], N[:3, 2], atol=1e-9)  # the URDF's plane
    assert run(["export", str(tmp / "cal" / "calibration.yaml"), "--format", "yaml", "--out", str(tmp / "tf.yaml")]) == 0
    tf = yaml.safe_load((tmp / "tf.yaml").read_text())["transforms"]
    np.testing.assert_allclose(tf["radar1"]["T_parent_child"], kept, atol=1e-9)
    assert run(["export", str(tmp / "cal" / "calibration.yaml"), "--format", "yaml", "--write-bounded",
                "--out", str(tmp / "est.yaml")]) == 0
    est = yaml.safe_load((tmp / "est.yaml").read_text())["transforms"]
    np.testing.assert_allclose(est["radar1"]["T_parent_child"], data["sensors"]["radar1"]["T_reference_sensor"], atol=1e-9)
