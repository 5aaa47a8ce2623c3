"""docs/api.md: its examples run as written, in order, in one Python session (after the bash
command that makes their data), and say what the comments say."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np

from rigcal.cli.main import run
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.results.urdf import forward_kinematics, parse_urdf

API = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def test_the_api_page_runs_as_written(tmp_path, monkeypatch, capsys):
    text = API.read_text()
    commands = [ln for block in re.findall(r"```bash\n(.*?)```", text, re.S) for ln in block.splitlines()
                if ln.startswith("rigcal ")]
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(commands) == 1 and len(blocks) >= 5
    monkeypatch.chdir(tmp_path)
    for line in commands:
        assert run(shlex.split(line)[1:]) == 0
    capsys.readouterr()
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(API), "exec"), namespace)
    out = capsys.readouterr().out
    assert "('lidar1', 'camera1', 'radar1') 12" in out and "consistent" in out
    assert "unknown calibration option(s) ['folds']" in out and "manifest not found" in out
    assert "report.html" in out and "car_calibrated.urdf ()" in out
    # the URDF now says what calibration.yaml says, relative to the reference's link
    cal = read_calibration_transforms(tmp_path / "results" / "calibration.yaml")
    urdf = parse_urdf((tmp_path / "car_calibrated.urdf").read_text(), "car_calibrated.urdf")
    for frame in ("camera1", "radar1"):
        np.testing.assert_allclose(forward_kinematics(urdf, "lidar1", frame), cal.transforms[frame], atol=1e-9)
    result = namespace["result"]
    np.testing.assert_allclose(namespace["T_radar_camera"],
                               np.linalg.inv(result.sensors["radar1"].T_reference_sensor)
                               @ result.sensors["camera1"].T_reference_sensor)
    # the check section: the demo's clean boards, calibrated on 8 and checked on the other 4
    report, changes = namespace["report"], namespace["changes"]
    assert report.num_boards == 4 and set(report.sensors) == {"lidar1", "camera1", "radar1"}
    assert report.status != "moved" and not report.moved, [s.headline for s in report.sensors.values()]
    assert all(s.headline in out for s in report.sensors.values())
    assert set(changes.sensors) == {"camera1", "radar1"} and not changes.moved
