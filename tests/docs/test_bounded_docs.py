"""docs/uncertainty.md (mounting priors) and docs/urdf.md (bounded directions kept): their tested
command blocks run as written on the simulated rig of ``rigcal demo --detections-only``, with the
example nominal mounting of examples/demo/, and give what the text says."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.io.results.calibration_files import read_calibration_transforms
from rigcal.io.results.urdf import forward_kinematics, parse_urdf

REPO = Path(__file__).resolve().parents[2]
DOCS = (REPO / "docs" / "uncertainty.md", REPO / "docs" / "urdf.md")


def docs_commands() -> list[list[str]]:
    """Every ``rigcal`` line of the docs' tested blocks, in order, each once."""
    lines: list[str] = []
    for doc in DOCS:
        blocks = re.findall(r"<!-- tested: tests/docs/test_bounded_docs\.py.*?-->\s*```bash\n(.*?)```\s*<!-- /tested -->",
                            doc.read_text(), re.S)
        assert blocks, f"{doc.name} lost its tested block"
        for block in blocks:
            lines += [ln.strip() for ln in block.splitlines() if ln.strip().startswith("rigcal ")]
    return [shlex.split(ln)[1:] for ln in dict.fromkeys(lines)]


@pytest.mark.slow
def test_docs_commands_run_as_written(tmp_path, monkeypatch, capsys):
    (tmp_path / "examples").symlink_to(REPO / "examples")
    monkeypatch.chdir(tmp_path)
    out = ""
    for argv in docs_commands():
        assert run(argv) == 0, (argv, capsys.readouterr().err)
        out += capsys.readouterr().out
    text = out.replace("\n", " ")
    free = yaml.safe_load(Path("cal_free/calibration.yaml").read_text())["sensors"]["radar1"]
    assert list(free["bounded_offsets"]) == ["roll", "pitch", "z"]
    # the numbers the docs quote
    for quoted in ("z -1.784 .. -0.701 m (estimate -1.547)", "roll -10.07 .. +12.44 deg (estimate -0.37)",
                   "pitch -8.29 .. +15.03 deg (estimate +0.45)"):
        assert quoted in text
    prior = yaml.safe_load(Path("cal_prior/calibration.yaml").read_text())
    radar = prior["sensors"]["radar1"]
    assert radar["bounded"] == {} and prior["verdict"]["status"] == "consistent"
    assert radar["std"]["roll_deg"] == pytest.approx(0.99, abs=0.01)
    assert radar["std"]["pitch_deg"] == pytest.approx(1.02, abs=0.01)
    assert radar["std"]["z_m"] == pytest.approx(0.0193, abs=0.001)
    held = yaml.safe_load(Path("cal_held/calibration.yaml").read_text())["sensors"]["radar1"]
    assert held["held"] == ["z", "roll", "pitch"]
    # rigcal urdf: the URDF's plane kept; --write-bounded: the estimate
    assert "radar1: roll, pitch, z kept from examples/demo/robot.urdf" in text
    nominal = parse_urdf(Path("examples/demo/robot.urdf").read_text(), "robot.urdf")
    kept = parse_urdf(Path("robot_calibrated.urdf").read_text(), "kept")
    N, W = forward_kinematics(nominal, "base_link", "radar1"), forward_kinematics(kept, "base_link", "radar1")
    np.testing.assert_allclose(W[:3, 2], N[:3, 2], atol=1e-12)
    assert W[2, 3] == pytest.approx(N[2, 3], abs=1e-12)
    joint = re.search(r'<joint name="radar1_joint".*?<origin xyz="([^"]+)" rpy="([^"]+)"', Path("robot_calibrated.urdf").read_text(), re.S)
    assert joint.group(1).startswith("3.678") and " -0.130" in joint.group(1) and joint.group(1).endswith(" 0.5")
    assert joint.group(2).startswith("0 0 -0.0457")
    cal = read_calibration_transforms("cal_free/calibration.yaml")
    estimate = parse_urdf(Path("robot_estimate.urdf").read_text(), "estimate")
    np.testing.assert_allclose(forward_kinematics(estimate, "lidar1", "radar1"), cal.transforms["radar1"], atol=1e-9)
