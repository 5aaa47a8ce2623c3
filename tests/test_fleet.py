"""rigcal.fleet: entries named from the arguments as given, and run_fleet's outcomes (load, task
and write failures of one entry never stop the others; each result written as it arrives)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from rigcal.errors import InputError, printable
from rigcal.fleet import FAILED, FleetEntry, fleet_entries, run_fleet


@pytest.fixture
def fleet(tmp_path) -> Path:
    for name in ("car1", "car2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "rig.yaml").write_text("sensors: []\n")
    (tmp_path / "README.md").write_text("x")
    return tmp_path


def test_entries_are_named_from_the_argument_as_given(fleet, tmp_path):
    (tmp_path / "link").symlink_to(fleet / "car2", target_is_directory=True)
    args = [str(fleet / "car1") + "/", str(fleet / "README.md"), str(tmp_path / "link"), str(fleet / "car1" / "rig.yaml"),
            str(fleet / "car9"), str(fleet / "car2")]
    entries, notes = fleet_entries(args)
    assert [(e.name, e.problem is None) for e in entries] == [("car1", True), ("link", True), ("car9", False)]
    assert "no such folder" in entries[2].problem
    assert notes == [f"{fleet / 'README.md'}: not a folder, skipped (a dataset is a folder holding rig.yaml)",
                     f"{fleet / 'car1' / 'rig.yaml'}: the same folder as {fleet / 'car1'}/, run once",
                     f"{fleet / 'car2'}: the same folder as {tmp_path / 'link'}, run once"]


def test_a_name_given_twice_fails_the_later_entry(fleet, tmp_path):
    other = tmp_path / "elsewhere" / "car1"
    other.mkdir(parents=True)
    entries, _ = fleet_entries([str(fleet / "car1"), str(other), "."])
    assert entries[0].problem is None
    assert "has the name of" in entries[1].problem and "OUT/car1/" in entries[1].problem
    assert entries[2].name == Path.cwd().name


def test_nul_and_control_characters_become_entries_with_printable_problems(fleet):
    entries, notes = fleet_entries([str(fleet / "a\x00b"), str(fleet / "c\nd")])
    assert "NUL byte" in entries[0].problem and entries[0].name == "a\\x00b"
    assert "no such folder" in entries[1].problem
    assert "\n" not in printable(entries[1].problem) and not notes


def _double(factor, x):
    if x < 0:
        raise InputError(f"negative: {x}")
    return factor * x


def test_run_fleet_keeps_going_past_every_kind_of_failure(tmp_path):
    entries = [FleetEntry(str(i), f"d{i}", tmp_path / f"d{i}") for i in range(5)]
    entries.append(FleetEntry("bad", "bad", tmp_path / "bad", "no such folder"))
    loads = {0: 1, 1: -1, 2: 3, 3: "unreadable", 4: 5}
    written: list[str] = []

    def load(e):
        v = loads[int(e.argument)]
        if v == "unreadable":
            raise InputError(f"{e.path}: cannot read")
        return v

    def write(e, item, value):
        if value == 10:
            raise InputError("disk full")
        written.append(e.name)
        return "written"

    run = run_fleet(entries, load, _double, write, shared=2, scheduler="serial")
    got = [(o.entry.name, o.status, o.value, o.error) for o in run.outcomes]
    assert got == [("d0", "written", 2, None), ("d1", FAILED, None, "negative: -1"), ("d2", "written", 6, None),
                   ("d3", FAILED, None, f"{tmp_path / 'd3'}: cannot read"), ("d4", FAILED, 10, "disk full"),
                   ("bad", FAILED, None, "no such folder")]
    assert written == ["d0", "d2"] and run.lost is None and run.missing == [] and run.where == "serial"


def test_run_fleet_on_dask_writes_each_result_as_it_arrives(dask_cluster, tmp_path):
    entries = [FleetEntry(str(i), f"d{i}", tmp_path) for i in range(6)]
    seen: list[int] = []

    def write(e, item, value):
        seen.append(item)
        assert os.getpid() == pid  # in this process, not on a worker
        return "written"

    pid = os.getpid()
    run = run_fleet(entries, lambda e: int(e.argument), _double, write, shared=3,
                    scheduler=dask_cluster.scheduler_address)
    assert sorted(seen) == list(range(6))
    assert [o.value for o in run.outcomes] == [0, 3, 6, 9, 12, 15]
    assert run.where.startswith("Dask scheduler tcp://")
