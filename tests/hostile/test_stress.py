"""Concurrent writers: 50 ``rigcal calibrate`` runs into distinct folders and 10 into the same
folder, some killed part-way; every folder holds a complete, consistent set of files or nothing."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

pytestmark = pytest.mark.slow  # long: run in CI (CI=1 make test) and make test-all

SET = {".rigcal-output", "calibration.yaml", "calibration.launch", "lidar1.yaml", "camera1.yaml",
       "radar1.yaml", "report.json", "report.html"}


@pytest.fixture(scope="module")
def manifest(tmp_path_factory) -> Path:
    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("stress") / "data")


def _start(manifest: Path, out: Path, plot: bool) -> subprocess.Popen:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    args = [sys.executable, "-m", "rigcal.cli.main", "calibrate", str(manifest), "--mode", "fcpe",
            "--out", str(out)] + (["--plot"] if plot else [])
    return subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)


def _check_complete(folder: Path, plot: bool) -> None:
    names = {p.name for p in folder.iterdir()}
    assert names == SET | ({"calibration.png"} if plot else set()), (folder, names)
    cal = yaml.safe_load((folder / "calibration.yaml").read_text())
    assert set(cal["sensors"]) == {"lidar1", "camera1", "radar1"}
    for name in ("lidar1", "camera1", "radar1"):
        assert yaml.safe_load((folder / f"{name}.yaml").read_text())  # complete, parseable
    if plot:
        assert (folder / "calibration.png").read_bytes().startswith(b"\x89PNG")


def test_concurrent_calibrations(tmp_path, manifest):
    rnd = random.Random(7)
    distinct = [tmp_path / f"out{k:02d}" for k in range(50)]
    same = tmp_path / "shared"
    procs = [(_start(manifest, out, plot=False), out, False) for out in distinct]
    procs += [(_start(manifest, same, plot=True), same, True) for _ in range(10)]
    # kill five runs of each group part-way (SIGKILL: no chance to clean up)
    victims = set(rnd.sample(range(50), 5)) | set(rnd.sample(range(50, 60), 5))
    time.sleep(1.0)
    for k in sorted(victims):
        time.sleep(rnd.uniform(0.0, 0.4))
        procs[k][0].send_signal(signal.SIGKILL)
    codes = []
    for proc, _, _ in procs:
        _, err = proc.communicate(timeout=600)
        codes.append((proc.returncode, err.decode()))
    for k, (code, err) in enumerate(codes):
        if k not in victims:
            assert code == 0, err
            assert "Traceback" not in err, err
    for k, out in enumerate(distinct):
        if k in victims and not out.exists():
            continue  # killed before it published: nothing, as it should be
        _check_complete(out, plot=False)
    _check_complete(same, plot=True)
    # only a SIGKILLed run can leave its staging folder behind, never a visible partial set
    for p in tmp_path.iterdir():
        if p.name.startswith("."):
            assert p.name.endswith(".partial"), p
