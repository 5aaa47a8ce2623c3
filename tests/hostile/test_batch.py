"""Hostile fleets for ``rigcal calibrate --batch`` (issue #22): a glob that also matches plain
files, mistyped folders, symlinked folders, folder names with control characters, an ``--out``
that is a file, an input, or holds a user's files. One bad entry never refuses the fleet; a bad
``--out`` is refused before anything is computed."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from rigcal.io.dataset.manifest import load_manifest, write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

SET = {".rigcal-output", "calibration.yaml", "calibration.launch", "lidar1.yaml", "camera1.yaml", "radar1.yaml",
       "report.json", "report.html"}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    """fleet/car0, fleet/car1 (8 simulated boards each), and fleet/README.md, fleet/notes.txt."""
    root = tmp_path_factory.mktemp("h") / "fleet"
    sensors = prius_like_rig()
    for k in range(2):
        rng = np.random.default_rng(60 + k)
        sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
        write_dataset(sim.dataset, root / f"car{k}")
    (root / "README.md").write_text("# our fleet\n")
    (root / "notes.txt").write_text("car1 had a loose radar bracket\n")
    return root


def _batch(cli, *dirs, out, extra=()):
    return cli("calibrate", "--batch", *dirs, "--out", out, "--scheduler", "serial", "--cv-folds", "0", *extra)


def _written(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) if out.is_dir() else []


def test_a_glob_with_plain_files_calibrates_the_folders_and_notes_the_files(cli, fleet, tmp_path):
    """Was: "fleet/README.md and fleet/notes.txt would both write to OUT/fleet/", nothing done."""
    out = tmp_path / "out"
    proc = _batch(cli, *sorted(fleet.iterdir()), out=out)
    text = proc.stdout.decode()
    assert proc.returncode == 0, proc.stderr.decode()
    assert _written(out) == ["car0", "car1"]
    assert {p.name for p in (out / "car0").iterdir()} == SET
    for name in ("README.md", "notes.txt"):
        assert f"note: {fleet / name}: not a folder, skipped" in text


def test_mistyped_folders_are_their_entries_failures(cli, fleet, tmp_path):
    """Was: two mistyped folders refused the whole fleet ("would both write to OUT/fleet/")."""
    out = tmp_path / "out"
    proc = _batch(cli, fleet / "car0", fleet / "car_1", fleet / "car2", out=out, extra=("--json",))
    err = proc.stderr.decode()
    assert proc.returncode == 4, err  # partial
    assert _written(out) == ["car0"]
    errors = [line for line in err.splitlines() if line.startswith("rigcal: error:")]
    assert len(errors) == 1 and "car_1, car2" in errors[0] and "1 of 3 datasets written" in errors[0], err
    status = {d["dataset"]: (d["status"], d["error"]) for d in json.loads(proc.stdout)}
    assert status["car0"][0] == "written"
    assert status["car_1"][0] == "failed" and "no such folder" in status["car_1"][1]


def test_all_entries_bad_is_exit_1_with_one_line(cli, refused, fleet, tmp_path):
    out = tmp_path / "out"
    refused(_batch(cli, fleet / "nope1", fleet / "nope2", out=out), "nope1, nope2", "0 of 2 datasets written", code=1)
    assert not out.exists()


def test_symlinked_folders_keep_their_own_names(cli, fleet, tmp_path):
    """Was: named after their targets (both 'data') and refused as duplicates."""
    links = tmp_path / "links"
    links.mkdir()
    for k, name in enumerate(("vehicle_a", "vehicle_b")):
        target = tmp_path / f"store{k}" / "data"
        target.parent.mkdir()
        target.symlink_to(fleet / f"car{k}", target_is_directory=True)
        (links / name).symlink_to(target, target_is_directory=True)
    out = tmp_path / "out"
    proc = _batch(cli, links / "vehicle_a", links / "vehicle_b", tmp_path / "store0" / "data", out=out)
    assert proc.returncode == 0, proc.stderr.decode()
    assert _written(out) == ["vehicle_a", "vehicle_b"]
    assert "the same folder as" in proc.stdout.decode()  # store0/data is vehicle_a: run once


def test_same_name_twice_fails_the_second_only(cli, fleet, tmp_path):
    other = tmp_path / "elsewhere" / "car0"
    write_dataset(load_manifest(fleet / "car1"), other)
    out = tmp_path / "out"
    proc = _batch(cli, fleet / "car0", other, out=out, extra=("--json",))
    assert proc.returncode == 4, proc.stderr.decode()
    assert _written(out) == ["car0"]
    doc = json.loads(proc.stdout)
    assert [d["status"] for d in doc] == ["written", "failed"]
    assert doc[0]["folder"] == str(fleet / "car0") and "both would write to OUT/car0/" in doc[1]["error"]


@pytest.mark.parametrize("what", ["file", "input", "foreign"])
def test_unusable_out_is_refused_before_any_calibration(cli, refused, fleet, tmp_path, what):
    """Was (--out onto a file): every dataset calibrated, then exit 1 with the reason only in the
    stdout table."""
    if what == "file":
        out = tmp_path / "results"
        out.write_text("mine")
        expect = ("--out", "exists and is not a folder")
    elif what == "input":
        out = fleet
        expect = ("--out", "is the dataset folder")
    else:  # OUT/car0 holds a user's file: that entry fails, the other is written
        out = tmp_path / "results"
        (out / "car0").mkdir(parents=True)
        (out / "car0" / "mine.txt").write_text("mine")
    t0 = time.monotonic()
    proc = _batch(cli, fleet / "car0", fleet / "car1", out=out)
    if what == "foreign":
        assert proc.returncode == 4, proc.stderr.decode()
        assert sorted(p.name for p in (out / "car0").iterdir()) == ["mine.txt"]
        assert {p.name for p in (out / "car1").iterdir()} == SET
        return
    refused(proc, *expect, code=1)
    assert time.monotonic() - t0 < 20  # nothing calibrated (each takes about a second)
    assert "calibrating" not in proc.stdout.decode()
    if what == "file":
        assert out.read_text() == "mine"
    else:
        assert sorted(p.name for p in fleet.iterdir()) == ["README.md", "car0", "car1", "notes.txt"]


@pytest.mark.skipif(os.name != "posix", reason="control characters in folder names")
@pytest.mark.parametrize("char", ["\n", "\t", "\r", "\x1b"])
def test_control_characters_in_a_folder_name_stay_on_one_line(cli, refused, tmp_path, char):
    """Was: printed raw, so the one-line error became two."""
    bad = tmp_path / f"car{char}x"
    bad.mkdir()
    (bad / "rig.yaml").write_text("sensors: 7\n")
    line = refused(_batch(cli, bad, out=tmp_path / "out"), "car" + repr(char)[1:-1] + "x", code=1)
    assert char not in line


def test_control_characters_in_a_manifest_path_stay_on_one_line(cli, refused, tmp_path):
    bad = tmp_path / "a\nb"
    bad.mkdir()
    refused(cli("calibrate", bad / "rig.yaml", "--out", tmp_path / "out"), "a\\nb", code=1)


def test_plain_calibrate_checks_out_before_any_work(cli, refused, fleet, tmp_path):
    """The same checks for one dataset. Its own folder as --out is an input: a dataset folder that
    rigcal wrote (marked as its output) was replaced by the results - the input lost."""
    before = {p.name: p.read_bytes() for p in (fleet / "car0").iterdir()}
    refused(cli("calibrate", fleet / "car0", "--out", fleet / "car0"), "--out", "an input of this run", code=1)
    assert {p.name: p.read_bytes() for p in (fleet / "car0").iterdir()} == before
    (tmp_path / "f").write_text("mine")
    refused(cli("calibrate", fleet / "car0", "--out", tmp_path / "f"), "--out", "exists and is not a folder", code=1)
    assert (tmp_path / "f").read_text() == "mine"
