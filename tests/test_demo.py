"""rigcal.demo: the absolute-calibration demo writes a complete scene, runs the `rigcal absolute`
path on it and lands near the simulated truth (its URDF reproduces it); the raw demo's reports
show the lidar on the camera images."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.demo import absolute_demo
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.results.urdf import forward_kinematics, parse_urdf


def test_absolute_demo(tmp_path):
    report = absolute_demo(tmp_path / "demo", seed=3)
    for name in ("scene/dataset/rig.yaml", "scene/scan.pcd", "scene/wheels.yaml",
                 "scene/vehicle.urdf", "absolute/absolute.yaml", "vehicle_calibrated.urdf"):
        assert (tmp_path / "demo" / name).is_file(), name
    # lidar/camera: cm-level against the truth (2 mm scanner, 1 cm rig noise, 20 boards)
    for name in ("lidar1", "camera1"):
        e = report.errors[name]
        assert e.translation_m < 0.03 and e.rotation_deg < 0.3, (name, e)
    # a 2D radar: its plane is measured, its tilt only bounded
    radar = report.errors["radar1"]
    assert radar.in_plane_m < 0.03 and radar.yaw_deg < 0.5, radar
    cal = read_calibration_transforms(report.results_dir / "absolute.yaml")
    urdf = parse_urdf(report.urdf_path.read_text(), "out")
    for frame, T in cal.transforms.items():
        assert np.abs(forward_kinematics(urdf, "base_link", frame) - T).max() < 1e-6


@pytest.mark.slow  # ~40 s: renders, writes and detects a raw bag
def test_raw_demo_reports_show_the_lidar_on_the_images(tmp_path, capsys):
    """The raw demo calibrates while its bag still exists, so each mode's report.html carries
    the lidar-on-camera overlays of raw data (the bag is deleted afterwards). Piped (stdout not a
    terminal), it prints plain progress while it simulates, writes, detects and calibrates, and
    ends with the page to open."""
    import json
    import re

    from rigcal.cli.main import run

    assert run(["demo", "--seed", "3", "--boards", "4", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out.splitlines()
    sim = [ln for ln in out if ln.startswith("simulating raw data: ")]
    assert len(sim) >= 5 and re.fullmatch(r"simulating raw data: (\d+)/\1 frames \(100%\), [0-9.]+ s", sim[-1]), sim
    percent = [int(m.group(1)) for ln in sim if (m := re.search(r"\((\d+)%\)", ln))]
    assert percent == sorted(percent) and percent[0] < 20, sim
    for stage in (r"writing the rosbag1 bag: 1/1 \(100%\), [0-9.]+ s", r"detecting: (\d+)/\1 frames \(100%\), [0-9.]+ s",
                  r"calibrating MCPE, FCPE, PSE: 3/3 modes \(100%\), [0-9.]+ s"):
        assert any(re.fullmatch(stage, ln) for ln in out), (stage, out)
    assert out[-2:] == ["open this page in a browser (the other modes: mcpe/, pse/):",
                        str(tmp_path / "demo" / "fcpe" / "report.html")]
    for mode in ("mcpe", "fcpe", "pse"):
        data = json.loads((tmp_path / "demo" / mode / "report.json").read_text())
        images = data["raw"]["images"]
        assert images and all(img["camera"] == "camera1" and img["jpeg_base64"] for img in images), mode
        html = (tmp_path / "demo" / mode / "report.html").read_text()
        assert '<section id="raw">' in html and html.count("data:image/jpeg;base64,") == len(images)
    assert not list((tmp_path / "demo").glob("*.bag"))  # deleted after detection and calibration
