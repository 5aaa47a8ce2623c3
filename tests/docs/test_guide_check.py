"""docs/guide.md's "Re-check your vehicle": its commands run as written on the shared Prius
detections and give what the guide says."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import pytest

from rigcal.cli.codes import EXIT_MOVED
from rigcal.cli.main import run

REPO = Path(__file__).resolve().parents[2]
GUIDE = REPO / "docs" / "guide.md"
SHARED = REPO.parent / "shared"


def recheck_example() -> list[list[str]]:
    text = GUIDE.read_text()
    block = re.search(r"<!-- recheck-example.*?-->\s*```bash\n(.*?)```\s*<!-- /recheck-example -->", text, re.S)
    assert block, "docs/guide.md lost its recheck-example block"
    lines = [ln.strip() for ln in block.group(1).splitlines() if ln.strip().startswith("rigcal ")]
    assert [ln.split()[1] for ln in lines] == ["calibrate", "check", "calibrate", "diff"]
    return [shlex.split(ln)[1:] for ln in lines]


def test_recheck_example_runs_as_written(tmp_path, monkeypatch, capsys):
    if not (SHARED / "data" / "tudelft_prius" / "detections" / "lidar.csv").is_file():
        pytest.skip("../shared/data (beside the repository) not present")
    root = tmp_path / "checkout"
    root.mkdir()
    shutil.copytree(REPO / "examples", root / "examples")  # a copy: its ../shared is tmp_path/shared
    (tmp_path / "shared").symlink_to(SHARED)
    monkeypatch.chdir(root)
    monkeypatch.setenv("COLUMNS", "80")  # the tables as the guide shows them
    calibrate_first, check, calibrate_last, diff = recheck_example()
    assert run(calibrate_first) == 0
    capsys.readouterr()
    assert run(check) == EXIT_MOVED
    out = " ".join(capsys.readouterr().out.split())  # (the console folds lines at 80 columns)
    assert "(9 boards): MOVED: camera1" in out
    data = json.loads((root / "prius_check" / "check.json").read_text())
    cam, lidar, radar = (data["sensors"][n] for n in ("camera1", "lidar1", "radar1"))
    assert cam["status"] == "moved" and cam["alternatives"] == ["lidar1"] and round(cam["p_value"], 3) == 0.010
    assert cam["headline"] == ("moved: 19 +- 8.3 mm, 0.38 +- 0.16 deg (p = 0.010) - or lidar1 moved: the data "
                               "cannot tell which")
    assert lidar["status"] == "cannot tell" and round(lidar["p_value"], 3) == 0.015
    assert radar["status"] == "cannot tell" and "shared only with sensors that moved" in radar["reason"]
    assert round(cam["detectable_translation_m"] * 1000) == 10 and round(cam["detectable_rotation_deg"], 1) == 0.7
    assert (root / "prius_check" / "check.html").is_file()
    assert run(calibrate_last) == 0
    capsys.readouterr()
    assert run(diff) == EXIT_MOVED
    out = capsys.readouterr().out
    cell = " ".join(re.findall(r"│ camera1 │ (.*?)│", out) + re.findall(r"│ {9}│ (.*?)│", out)[:1])
    assert "MOVED: camera1" in out and " ".join(cell.split()) == "moved: 17 +- 10 mm, 0.38 +- 0.17 deg (p = 0.017)"
