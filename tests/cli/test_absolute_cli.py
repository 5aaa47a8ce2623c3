"""`rigcal absolute`: files in, body-frame calibration out (simulated vehicle with truth)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.absolute.labels import format_labels_yaml
from rigcal.cli.main import run
from rigcal.dataset import SensorKind
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.dataset.manifest import write_dataset
from rigcal.io.clouds import write_pcd
from rigcal.recording import PointCloudFrame
from rigcal.sim.rig import SimSensor, make_rig_placements, simulate
from rigcal.sim.vehicle import ExternalScanner, SimVehicle, simulate_external_scan, simulate_rim_labels

VEHICLE = SimVehicle()
SCANNER = ExternalScanner()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("absolute")
    ext = SimSensor(
        "leica", SensorKind.LIDAR, SCANNER.T_body_stations[0], sigma_m=0.002,
        max_azimuth_deg=180.0, max_elevation_deg=60.0, min_elevation_deg=-60.0, max_range_m=30.0,
    )
    boards = make_rig_placements(0, VEHICLE.sensors, 20)
    sim = simulate(VEHICLE.sensors + (ext,), boards, rng=0)
    manifest = write_dataset(sim.dataset, tmp / "dataset")
    scan = simulate_external_scan(VEHICLE, SCANNER, rng=1)
    write_pcd(tmp / "scan.pcd", PointCloudFrame("leica", 0, scan.points_external), data="binary")
    labels = simulate_rim_labels(VEHICLE, scan.T_external_body, 0, n_points=10, sigma_m=0.002)
    (tmp / "labels.yaml").write_text(format_labels_yaml(labels))
    return tmp, manifest, sim


def test_absolute_writes_body_frame_calibration_close_to_truth(inputs, capsys):
    tmp, manifest, sim = inputs
    out = tmp / "out"
    code = run([
        "absolute", str(manifest), "--external", "leica", "--scan", str(tmp / "scan.pcd"),
        "--labels", str(tmp / "labels.yaml"), "--out", str(out),
    ])
    assert code == 0, capsys.readouterr().err
    cal = read_calibration_transforms(out / "absolute.yaml")
    assert cal.kind == "absolute" and cal.parent_frame == "base_link"
    truth = {s.name: s.T_rig_sensor for s in VEHICLE.sensors}  # rig frame = body frame here
    for name in ("lidar1", "camera1"):
        T = cal.transforms[name]
        assert np.linalg.norm(T[:3, 3] - truth[name][:3, 3]) < 0.02, name
    text = capsys.readouterr().out
    assert "T_body_sensor" in text and "wheelbase" in text
    import yaml

    data = yaml.safe_load((out / "absolute.yaml").read_text())
    assert data["verdict"]["status"] == "consistent" and text.lstrip().startswith("consistent")
    radar2d = [n for n, s in data["sensors"].items() if s["kind"] == "radar"]
    assert radar2d and all(list(data["sensors"][n]["bounded_offsets"]) == ["roll", "pitch", "z"] for n in radar2d)
    for n in radar2d:  # absolute values in the body frame, the estimate inside
        s = data["sensors"][n]
        assert {"roll", "pitch", "z"} <= set(s["bounded"])
        assert s["bounded"]["z"]["estimate"] == pytest.approx(s["xyz_m"][2])
        assert s["bounded"]["z"]["low"] <= s["xyz_m"][2] <= s["bounded"]["z"]["high"]


def test_labels_missing_a_wheel_is_one_line_and_writes_nothing(inputs, capsys):
    tmp, manifest, _ = inputs
    data = yaml.safe_load((tmp / "labels.yaml").read_text())
    data.pop(next(k for k in data if "rear_left" in k))
    bad = tmp / "bad_labels.yaml"
    bad.write_text(yaml.safe_dump(data))
    out = tmp / "out_bad"
    code = run([
        "absolute", str(manifest), "--external", "leica", "--scan", str(tmp / "scan.pcd"),
        "--labels", str(bad), "--out", str(out),
    ])
    err = capsys.readouterr().err
    assert code == 1 and "rear_left" in err and "Traceback" not in err
    assert not out.exists()


def test_unknown_external_sensor(inputs, capsys):
    tmp, manifest, _ = inputs
    code = run([
        "absolute", str(manifest), "--external", "faro", "--scan", str(tmp / "scan.pcd"),
        "--labels", str(tmp / "labels.yaml"), "--out", str(tmp / "o2"),
    ])
    assert code == 1 and "faro" in capsys.readouterr().err


def test_absolute_takes_the_radar_plane_options_its_warning_recommends(inputs, tmp_path, capsys):
    """The relative calibration's warning recommends --initial and --hold-radar-plane; rigcal
    absolute accepts both (it used to refuse them)."""
    tmp, manifest, _ = inputs
    common = [str(manifest), "--external", "leica", "--scan", str(tmp / "scan.pcd"),
              "--labels", str(tmp / "labels.yaml")]
    assert run(["absolute", *common, "--out", str(tmp_path / "plain")]) == 0
    assert "--hold-radar-plane" in capsys.readouterr().out.replace("\n", " ")
    assert run(["calibrate", str(manifest), "--reference", "leica", "--out", str(tmp_path / "ref"),
                "--no-plot"]) == 0
    capsys.readouterr()
    assert run(["absolute", *common, "--hold-radar-plane", "--initial",
                str(tmp_path / "ref" / "calibration.yaml"), "--out", str(tmp_path / "held")]) == 0
    held = yaml.safe_load((tmp_path / "held" / "absolute.yaml").read_text())
    assert held["sensors"]["radar1"]["held"]


def test_demo_absolute_runs_the_absolute_path_into_a_urdf(tmp_path, capsys):
    import shlex

    out = tmp_path / "demo"
    assert run(["demo", "--absolute", "--out", str(out), "--seed", "2"]) == 0
    text = capsys.readouterr().out
    assert "T_body_sensor against the simulated truth" in text
    for name in ("scene/scan.pcd", "scene/wheels.yaml", "absolute/absolute.yaml",
                 "vehicle_calibrated.urdf"):
        assert (out / name).is_file(), name
    again = next(line for line in text.splitlines() if line.startswith("run it again with: "))
    argv = shlex.split(again.split(": ", 1)[1])
    assert argv[0] == "rigcal" and run(argv[1:]) == 0  # the printed command works as printed
