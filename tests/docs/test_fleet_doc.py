"""docs/fleet.md: its example runs as written and ends with the exit codes its comments give."""

from __future__ import annotations

import glob
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

DOC = Path(__file__).resolve().parents[2] / "docs" / "fleet.md"


def example() -> list[tuple[list[str], int]]:
    block = re.search(r"<!-- fleet-example.*?-->\s*```bash\n(.*?)```\s*<!-- /fleet-example -->", DOC.read_text(), re.S)
    assert block, "docs/fleet.md lost its fleet-example block"
    commands = []
    for line in block.group(1).splitlines():
        command, _, comment = line.partition("#")
        code = re.fullmatch(r"\s*exit (\d+)\s*", comment)
        assert command.strip().startswith("rigcal ") and code, line
        commands.append((shlex.split(command)[1:], int(code.group(1))))
    return commands


@pytest.mark.slow  # three calibrations and the refusals, 5-15 s on the shared machine
def test_fleet_example_runs_as_written(tmp_path, monkeypatch, capsys):
    sensors = prius_like_rig()
    for k in (1, 2):
        rng = np.random.default_rng(70 + k)
        sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
        write_dataset(sim.dataset, tmp_path / "fleet" / f"car0{k}")
    (tmp_path / "fleet" / "README.md").write_text("# the fleet\n")
    monkeypatch.chdir(tmp_path)
    commands = example()
    assert len(commands) == 5
    for argv, code in commands:
        argv = [a for arg in argv for a in (sorted(glob.glob(arg)) if "*" in arg else [arg])]
        assert run(argv + ["--cv-folds", "0"] if argv[0] == "calibrate" else argv) == code, argv
        out, err = capsys.readouterr()
        if argv[:2] == ["calibrate", "--batch"] and code == 0:
            assert "note: fleet/README.md: not a folder, skipped" in out
        if code == 4:
            assert "failed: car_02 (see the table); 1 of 2 datasets written" in err
        if code == 1:
            assert len([ln for ln in err.splitlines() if ln.startswith("rigcal: error:")]) == 1, err
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["car01", "car02"]
    assert (tmp_path / "results" / "car01" / "calibration.yaml").read_text().startswith("reference:")
