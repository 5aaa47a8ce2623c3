"""Hostile options of ``rigcal study`` (issue #22): out-of-range seeds, measurements and trials,
and an ``--out`` that a study would refuse only after running (minutes). Each is one error line
naming the option or the folder, before any computation."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def manifest(tmp_path_factory) -> Path:
    rng = np.random.default_rng(17)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("study") / "data")


#: studies that would run for many minutes if they started
LONG = {"prius": ["--table", "III", "--draws", "100000", "--boards", "3", "--scheduler", "serial"],
        "mocap": ["--trials", "10000", "--measurements", "30", "--scheduler", "serial"]}


def _study(kind: str, manifest: Path) -> list:
    return ["study", kind, manifest] if kind == "prius" else ["study", kind]


@pytest.mark.parametrize("kind", ["prius", "mocap"])
@pytest.mark.parametrize("argv, expected", [
    (["--seed", "-1"], "argument --seed: expected 0 to"),
    (["--seed", "1e3"], "argument --seed: expected an integer"),
])
def test_seed_out_of_range(cli, refused, manifest, tmp_path, kind, argv, expected):
    """Was: a traceback (numpy's SeedSequence refuses negative seeds)."""
    out = tmp_path / "out"
    refused(cli(*_study(kind, manifest), *argv, "--out", out, seconds=60), expected, code=2)
    assert not out.exists()


@pytest.mark.parametrize("argv, expected", [
    (["--measurements", "1000000000"], "argument --measurements: expected 1 to 200, got 1000000000"),
    (["--measurements", "5", "0"], "argument --measurements: expected 1 to 200, got 0"),
    (["--trials", "1000000000"], "argument --trials: expected 1 to 10000, got 1000000000"),
    (["--trials", "0"], "argument --trials: expected 1 to 10000, got 0"),
])
def test_mocap_counts(cli, refused, tmp_path, argv, expected):
    """Was: --measurements 1e9 ran without bound; --trials 1e9 ended in "out of memory" without
    naming the option."""
    out = tmp_path / "out"
    refused(cli("study", "mocap", *argv, "--out", out, seconds=60), expected, code=2)
    assert not out.exists()


@pytest.mark.parametrize("kind", ["prius", "mocap"])
@pytest.mark.parametrize("what", ["file", "foreign", "input"])
def test_unusable_out_is_refused_before_the_study(cli, refused, manifest, tmp_path, kind, what):
    """Was: refused only after the whole study had run (8 min for the full Prius study)."""
    if what == "input" and kind == "mocap":
        pytest.skip("the mocap study reads no input")
    if what == "file":
        out = tmp_path / "study.json"
        out.write_text("mine")
        expected = "exists and is not a folder"
    elif what == "foreign":
        out = tmp_path / "mine"
        out.mkdir()
        (out / "thesis.tex").write_text("mine")
        expected = "holds files rigcal did not write (thesis.tex)"
    else:
        out = manifest.parent
        expected = f"holds an input of this run ({manifest})"
    before = sorted(p.name for p in out.parent.iterdir())
    t0 = time.monotonic()
    proc = cli(*_study(kind, manifest), *LONG[kind], "--out", out, seconds=120)
    refused(proc, f"--out {out}", expected, code=1)
    assert time.monotonic() - t0 < 60
    assert sorted(p.name for p in out.parent.iterdir()) == before
