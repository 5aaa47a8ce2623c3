"""Hostile input to ``rigcal check``, ``rigcal check --batch`` and ``rigcal diff`` (issue #22, item
6): hand-edited calibration.yaml files (missing and extra fields, NaN, huge and 5000-digit
numbers, non-rigid poses, covariances that are not covariances, no noise model, names with
control characters or markup), the wrong files (a mocap calibration, absolute.yaml, the original
tool's YAML, a report, a manifest, a folder, a FIFO, a device), data that does not fit the
calibration, ``--out`` onto an input or a user's file, ``--alpha`` out of range, fleets with
plain files, mistyped and duplicate folders, calibrations missing, schedulers that are not Dask,
and signals in the middle of a fleet.

Each bad input is one ``rigcal: error:`` line naming the file, field or option (control
characters escaped), a documented non-zero exit, within seconds, nothing written and no input
changed; each page escapes every value and fetches nothing."""

from __future__ import annotations

import copy
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.codes import EXIT_CANNOT_TELL, EXIT_PARTIAL
from rigcal.dataset import Dataset
from rigcal.errors import InputError
from rigcal.io.dataset.manifest import load_manifest, write_dataset
from rigcal.io.results.stored import parse_stored_calibration
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

#: a sensor name that a manifest allows (no whitespace, no slash) and that is markup and CSS
EVIL = "cam<style>*{background:url(http:x.png)}<b>\"'&"


def _simulate(root: Path, name: str, seed: int, boards: int) -> Path:
    rng = np.random.default_rng(seed)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, boards, min_fraction=1.0), rng=rng)
    write_dataset(sim.dataset, root / name)
    return root / name


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> Path:
    """cal/ (calibrated on 10 boards, reference lidar1), cal_cam/ (the same boards, reference
    camera1), same/ (5 new boards, nothing moved)."""
    root = tmp_path_factory.mktemp("check")
    _simulate(root, "cal_data", 31, 10)
    from rigcal.cli.main import run

    assert run(["calibrate", str(root / "cal_data"), "--cv-folds", "0", "--out", str(root / "cal")]) == 0
    assert run(["calibrate", str(root / "cal_data"), "--cv-folds", "0", "--out", str(root / "cal_cam"),
                "--reference", "camera1"]) == 0
    _simulate(root, "same", 12, 5)
    return root


@pytest.fixture(scope="module")
def calibration(rig) -> dict:
    return yaml.safe_load((rig / "cal" / "calibration.yaml").read_text())


def _copy(src: Path, to: Path) -> Path:
    shutil.copytree(src, to)
    return to


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _zeros():
    return [[0.0] * 6 for _ in range(6)]


def _diag(v):
    return [[v[i] if i == j else 0.0 for j in range(6)] for i in range(6)]


def _set(path: str, value):
    """An edit of the parsed calibration: ``value`` at ``path`` (dots; [i] for list items)."""
    def edit(d):
        keys = re.findall(r"[^.\[\]]+|\[\d+\]", path)
        for k in keys[:-1]:
            d = d[int(k[1:-1])] if k.startswith("[") else d[k]
        last = keys[-1]
        if last.startswith("["):
            d[int(last[1:-1])] = value
        elif value is _DELETE:
            del d[last]
        else:
            d[last] = value
    return edit


_DELETE = object()


def _rename(old: str, new):
    def edit(d):
        d["sensors"] = {(new if k == old else k): v for k, v in d["sensors"].items()}
        for r in d["relative"].values():
            r["to"] = new if r["to"] == old else r["to"]
            r["from"] = new if r["from"] == old else r["from"]
        d["noise_model"] = {(new if k == old else k): v for k, v in d["noise_model"].items()}
    return edit


def _relative_to(value):
    def edit(d):
        next(iter(d["relative"].values()))["to"] = value
    return edit


def _edited(calibration: dict, edit) -> str:
    d = copy.deepcopy(calibration)
    edit(d)
    return yaml.safe_dump(d, sort_keys=False, allow_unicode=True)


# ---------------------------------------------------------------------------------------------
# calibration.yaml, hand-edited: the reader (fast, in this process)

#: (id, edit, expected message); "was" says what the current main did with it
HAND_EDITS = [
    # was: accepted (YAML true/false taken as 1/0), then a verdict on that pose
    ("T of booleans", _set("sensors.camera1.T_reference_sensor", [[True, False, False, False], [False, True, False, False],
                                                                   [False, False, True, False], [False] * 3 + [True]]),
     r"sensors\.camera1\.T_reference_sensor\[0\]\[0\]: expected a number, got a boolean"),
    # was: OverflowError traceback (an integer too large for a float)
    ("400-digit integer in T", _set("sensors.camera1.T_reference_sensor[0][3]", 10 ** 400),
     r"sensors\.camera1\.T_reference_sensor\[0\]\[3\]: an integer of 401 digits is too large"),
    # was: LinAlgError traceback ("SVD did not converge") in the check
    ("covariance entry 1e300", _set("sensors.camera1.covariance[0][0]", 1e300),
     r"sensors\.camera1\.covariance: variance of roll is 1e\+300, expected at most 1e\+06"),
    # was: accepted; every sensor "cannot tell" (exit 7)
    ("covariance 1e200 everywhere", lambda d: [s.update(covariance=_diag([1e200] * 6)) for s in d["sensors"].values()],
     r"covariance: variance of roll is 1e\+200"),
    # was: accepted; camera1 called moved on an unchanged rig (a calibration without uncertainty)
    ("covariance of zeros", lambda d: [s.update(covariance=_zeros()) for s in d["sensors"].values()],
     r"sensors\.camera1\.covariance: no uncertainty in roll, pitch, yaw, x, y, z"),
    ("covariance of denormals", _set("sensors.camera1.covariance", _diag([5e-324] * 6)),
     r"sensors\.camera1\.covariance: no uncertainty in roll"),
    # was: accepted (made symmetric without a word)
    ("covariance not symmetric", lambda d: d["sensors"]["camera1"]["covariance"][0].__setitem__(
        1, d["sensors"]["camera1"]["covariance"][0][1] + 1e-4),
     r"sensors\.camera1\.covariance: not symmetric \(entry \[0\]\[1\]"),
    # was: TypeError traceback (unhashable type: 'list')
    ("relative 'to' a list", _relative_to(["lidar1"]), r"relative\.lidar1-camera1: expected 'to' and 'from' naming"),
    # was: LinAlgError traceback
    ("noise std 1e300", _set("noise_model.lidar1.x", 1e300),
     r"noise_model\.lidar1\.x: expected a positive std of at most 100000 m, got 1e\+300"),
    # was: ValueError / OverflowError tracebacks (int(nan), int(inf)); a string or 10**40 accepted
    ("num_boards NaN", _set("num_boards", float("nan")), r"num_boards: expected a count of boards .* got nan"),
    ("num_boards inf", _set("num_boards", float("inf")), r"num_boards: expected a count of boards .* got inf"),
    ("num_boards a word", _set("num_boards", "many"), r"num_boards: expected a count of boards .* got 'many'"),
    ("num_boards 10**40", _set("num_boards", 10 ** 40), r"num_boards: expected a count of boards"),
    # was: accepted (str() of the list)
    ("mode a list", _set("mode", ["fcpe"]), r"mode: expected a calibration mode"),
    # was: accepted
    ("bounded NaN", _set("sensors.radar1.bounded", {"z": [float("nan"), 1.0]}),
     r"sensors\.radar1\.bounded\.z: expected \[low, high\] \(finite numbers, low <= high\)"),
    ("bounded low > high", _set("sensors.radar1.bounded", {"z": [1.0, -1.0]}), r"sensors\.radar1\.bounded\.z"),
    # was: accepted; the names reach terminals and pages
    ("frame_id with a newline", _set("sensors.camera1.frame_id", "cam\nera"),
     r"sensors\.camera1\.frame_id: expected a frame name .* got 'cam\\nera'"),
    ("sensor name with escapes", _rename("camera1", "cam\x1b[31m\tera"),
     r"sensors: a sensor's name: sensor name 'cam\\x1b\[31m\\tera' must not contain"),
    ("sensor name an integer", _rename("camera1", 5), r"sensors: a sensor's name: expected a sensor name \(a string\), "
                                                      r"got an integer 5"),
    ("sensor name 300 characters", _rename("camera1", "c" * 300), r"is 300 characters long; expected at most 100"),
    # was: accepted; diff of the file with itself said "moved"
    ("reference not at the identity", _set("sensors.lidar1.T_reference_sensor[0][3]", 1.0),
     r"sensors\.lidar1\.T_reference_sensor: the reference sensor's pose in its own frame must be the identity"),
    # was: "reference: expected one of the sensors [...], got 'robot'"
    ("a mocap calibration", lambda d: d.update(mode="mocap", reference="robot"),
     r"a motion-capture calibration \(mode: mocap, poses in the robot body's frame 'robot'\)"),
    # refused before too (regressions)
    ("T with NaN", _set("sensors.camera1.T_reference_sensor[0][3]", float("nan")), r"expected finite numbers"),
    ("T with inf", _set("sensors.camera1.T_reference_sensor[1][3]", float("inf")), r"expected finite numbers"),
    ("T 1e300 m away", _set("sensors.camera1.T_reference_sensor[0][3]", 1e300), r"expected a finite value within"),
    ("T not rigid", _set("sensors.camera1.T_reference_sensor[0][0]", 2.0), r"T_reference_sensor: not rigid"),
    ("T a reflection", lambda d: [r.__setitem__(0, -r[0]) for r in d["sensors"]["camera1"]["T_reference_sensor"][:3]],
     r"not rigid: .* det = -1"),
    ("T 3x3", _set("sensors.camera1.T_reference_sensor", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]), r"expected a 4x4 matrix"),
    ("covariance with NaN", _set("sensors.camera1.covariance[2][2]", float("nan")), r"expected finite numbers"),
    ("covariance not PSD", _set("sensors.camera1.covariance[0][0]", -1.0), r"not a covariance \(negative eigenvalue\)"),
    ("covariance 5x5", lambda d: d["sensors"]["camera1"].update(
        covariance=[r[:5] for r in d["sensors"]["camera1"]["covariance"][:5]]), r"expected a 6x6 matrix"),
    ("covariance flat", lambda d: d["sensors"]["camera1"].update(covariance=sum(d["sensors"]["camera1"]["covariance"], [])),
     r"expected a 6x6 matrix"),
    ("relative covariance not PSD", lambda d: next(iter(d["relative"].values()))["covariance"][0].__setitem__(0, -1.0),
     r"relative\.lidar1-camera1\.covariance: not a covariance"),
    ("no kind", _set("sensors.camera1.kind", _DELETE), r"sensors\.camera1: missing kind"),
    ("no covariance", _set("sensors.camera1.covariance", _DELETE), r"sensors\.camera1: missing covariance"),
    ("unknown kind", _set("sensors.camera1.kind", "sonar"), r"unknown sensor kind 'sonar'"),
    ("no sensors", _set("sensors", _DELETE), r"sensors: expected a mapping of sensors"),
    ("reference not a sensor", _set("reference", "ghost"), r"reference: expected one of the sensors"),
    ("noise std zero", _set("noise_model.lidar1.x", 0.0), r"noise_model\.lidar1\.x: expected a positive std"),
    ("noise std NaN", _set("noise_model.lidar1.x", float("nan")), r"noise_model\.lidar1\.x: expected a positive std"),
]


@pytest.mark.parametrize("edit, expected", [pytest.param(e, m, id=i) for i, e, m in HAND_EDITS])
def test_a_hand_edited_calibration_is_refused_naming_the_field(calibration, edit, expected):
    with pytest.raises(InputError, match=r"^calibration\.yaml: .*" + expected):
        parse_stored_calibration(_edited(calibration, edit), "calibration.yaml")


@pytest.mark.parametrize("text, expected", [
    # was: a ValueError traceback from PyYAML ("Exceeds the limit (4300 digits)")
    (lambda t: t.replace("num_boards: 10", "num_boards: " + "9" * 5000), "an integer of 5000 digits"),
    (lambda t: t.replace("  - - 0.0\n", "  - - " + "9" * 5000 + "\n", 1), "an integer of 5000 digits"),
    # refused before too
    (lambda t: "", "got nothing"),
    (lambda t: "- 1\n- 2\n", "got a list"),
    (lambda t: "a: " + "[" * 100000 + "]" * 100000 + "\n", "nesting depth"),
    (lambda t: "a: &a [1,1,1,1,1,1,1,1,1,1]\n" + "".join(
        f"{c}: &{c} [" + ",".join([f"*{p}"] * 10) + "]\n" for p, c in zip("abcdef", "bcdefg")), "YAML expands to more"),
    (lambda t: "source: lidar1\ntarget: camera1\ntransform: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n",
     "the original tool's per-sensor file has no uncertainty"),
    (lambda t: "body_frame: base_link\nsensors: {}\n", "an absolute.yaml; give the calibration.yaml"),
    (lambda t: "!!python/object/apply:os.system ['true']\n", "could not determine a constructor"),
    (lambda t: t[:2000], ""),
], ids=["5000-digit num_boards", "5000-digit matrix entry", "empty", "a list", "deep nesting", "alias bomb",
        "original tool", "absolute.yaml", "python tag", "truncated"])
def test_a_broken_calibration_text_is_refused_naming_the_file(rig, text, expected):
    source = str(rig / "cal" / "calibration.yaml")
    edited = text((rig / "cal" / "calibration.yaml").read_text())
    assert edited != (rig / "cal" / "calibration.yaml").read_text()
    with pytest.raises(InputError, match=f"^{re.escape(source)}: .*{re.escape(expected)}"):
        parse_stored_calibration(edited, source)


def test_extra_fields_are_ignored(calibration):
    """Fields a comparison does not read (rmse_m, verdict, a user's notes, an unknown noise
    component) are left alone: calibration.yaml holds many, and later versions may add more."""
    def edit(d):
        d["notes"] = {"who": "me", "deep": [[[[1]]]]}
        d["sensors"]["camera1"]["comment"] = "re-mounted in March"
        d["noise_model"]["lidar1"]["w"] = 0.1
    stored = parse_stored_calibration(_edited(calibration, edit), "calibration.yaml")
    assert stored.names == ("lidar1", "camera1", "radar1")


def test_the_reader_s_limits_leave_a_check_that_runs(rig, calibration):
    """Values at the edge of what the reader accepts (variances of 1e6 rad^2 and 1e10 m^2, a
    noise std of 100 km) still give a verdict, not a traceback or a warning."""
    import warnings

    from rigcal.problem.check import check
    from rigcal.problem.diff import diff

    def edit(d):
        for n in ("camera1", "radar1"):
            d["sensors"][n]["covariance"] = _diag([1e6] * 3 + [1e10] * 3)
        for c in d["noise_model"].values():
            c.update({k: 1e5 for k in c})

    stored = parse_stored_calibration(_edited(calibration, edit), "calibration.yaml")
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        result = check(stored, load_manifest(rig / "same"))
        assert diff(stored, stored).status == "unchanged"
    assert result.status == "cannot tell"


# ---------------------------------------------------------------------------------------------
# rigcal check and diff on the command line


def test_a_5000_digit_integer_is_one_line_on_the_command_line(cli, refused, rig, tmp_path):
    """Was: a PyYAML ValueError traceback."""
    bad = tmp_path / "calibration.yaml"
    bad.write_text((rig / "cal" / "calibration.yaml").read_text().replace("num_boards: 10", "num_boards: " + "9" * 5000))
    for argv in (("check", bad, rig / "same"), ("diff", rig / "cal", bad)):
        refused(cli(*argv), str(bad), "an integer of 5000 digits", code=1)


@pytest.mark.parametrize("what", ["calibration folder", "calibration.yaml", "data folder", "rig.yaml"])
def test_out_onto_an_input_is_refused_and_the_input_kept(cli, refused, rig, tmp_path, what):
    """Was: exit 0 with the result folder (or the dataset rigcal wrote) replaced by check.json
    and check.html - calibration.yaml gone."""
    cal, data = _copy(rig / "cal", tmp_path / "cal"), _copy(rig / "same", tmp_path / "same")
    before = _files(tmp_path)
    out = {"calibration folder": cal, "calibration.yaml": cal / "calibration.yaml", "data folder": data,
           "rig.yaml": data / "rig.yaml"}[what]
    expected = "exists and is not a folder" if what == "calibration.yaml" else "an input of this run"
    refused(cli("check", cal, data / "rig.yaml", "--out", out), f"--out {out}", expected, code=1)
    assert _files(tmp_path) == before


def test_out_is_checked_before_any_work(cli, refused, rig, tmp_path):
    """A bad --out is named even when the calibration is bad too: it is checked first (was: the
    calibration's error, or the whole check, then the --out error)."""
    bad = tmp_path / "calibration.yaml"
    bad.write_text("reference: [\n")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    user = tmp_path / "mine"
    user.mkdir()
    (user / "todo.txt").write_text("mine")
    refused(cli("check", bad, rig / "same", "--out", notes), f"--out {notes}", "exists and is not a folder", code=1)
    refused(cli("check", bad, rig / "same", "--out", user), f"--out {user}", "holds files rigcal did not write",
            code=1)
    refused(cli("check", bad, rig / "same", "--out", notes / "x"), f"--out {notes / 'x'}", code=1)
    assert notes.read_text() == "mine" and sorted(p.name for p in user.iterdir()) == ["todo.txt"]


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root may write anywhere")
def test_out_that_cannot_be_written_is_refused_first(cli, refused, rig, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        refused(cli("check", rig / "cal", rig / "same", "--out", locked / "c"), "--out", "no permission", code=1)
    finally:
        locked.chmod(0o755)


@pytest.mark.parametrize("alpha", ["0", "1", "nan", "-1", "abc", "0.5", "inf", "", "1e-9"])
@pytest.mark.parametrize("command", ["check", "diff"])
def test_alpha_out_of_range_is_a_usage_error_naming_it(cli, refused, rig, command, alpha):
    """Was: 0.5 passed the parser and was refused later as "check: alpha must be in (0, 0.5)",
    exit 1, without naming --alpha."""
    argv = ("check", rig / "cal", rig / "same") if command == "check" else ("diff", rig / "cal", rig / "cal")
    refused(cli(*argv, "--alpha", alpha), f"rigcal {command}: error: argument --alpha", code=2)


@pytest.mark.parametrize("case, expected", [
    ("a manifest as the calibration", "a dataset manifest (sensors with detections or topics), not a calibration"),
    ("a dataset folder as the calibration", "a dataset folder (rig.yaml), not a result folder"),
    ("the calibration as the data", "a calibration, expected new detections"),
    ("a report as the calibration", "a rigcal-report file, not a calibration"),
    ("a directory as the data", "manifest not found"),
    ("a FIFO as the calibration", "is a FIFO (named pipe), expected a calibration"),
    ("a device as the calibration", "is a character device, expected a calibration"),
    ("an empty calibration", "got nothing (null)"),
    ("binary garbage", "is not UTF-8 text"),
])
def test_the_wrong_file_is_named_with_what_to_give(cli, refused, rig, tmp_path, case, expected):
    """The arguments swapped, a report, a folder, a FIFO, a device, an empty or binary file: one
    line naming it (was: "sensors: expected a mapping ..." for a manifest or a report, "calibration
    not found" for a dataset folder, a manifest error listing calibration.yaml's keys for the
    calibration given as data)."""
    cal, data = rig / "cal", rig / "same"
    if case == "a manifest as the calibration":
        argv, named = (data / "rig.yaml", cal), data / "rig.yaml"
    elif case == "a dataset folder as the calibration":
        argv, named = (data, cal), data
    elif case == "the calibration as the data":
        argv, named = (cal, cal / "calibration.yaml"), cal / "calibration.yaml"
    elif case == "a report as the calibration":
        argv, named = (cal / "report.json", data), cal / "report.json"
    elif case == "a directory as the data":
        (tmp_path / "empty").mkdir()
        argv, named = (cal, tmp_path / "empty"), tmp_path / "empty"
    elif case == "a FIFO as the calibration":
        if not hasattr(os, "mkfifo"):
            pytest.skip("no FIFOs here")
        os.mkfifo(tmp_path / "fifo")
        argv, named = (tmp_path / "fifo", data), tmp_path / "fifo"
    elif case == "a device as the calibration":
        if not Path("/dev/zero").exists():
            pytest.skip("no /dev/zero")
        argv, named = (Path("/dev/zero"), data), "/dev/zero"
    else:
        bad = tmp_path / "calibration.yaml"
        bad.write_bytes(b"" if case == "an empty calibration" else bytes(range(256)) * 8)
        argv, named = (bad, data), bad
    t0 = time.monotonic()
    refused(cli("check", *argv, seconds=30), str(named), expected, code=1)
    assert time.monotonic() - t0 < 20


def _dataset_variant(rig: Path, to: Path, case: str) -> Path:
    ds = load_manifest(rig / "same")
    from dataclasses import replace

    def nan(s, rows):
        pts = np.array(s.points, dtype=float)
        pts[rows] = np.nan
        return replace(s, points=pts)

    n = ds.num_boards
    sensors = {
        "kinds differ": [replace(ds.sensors[0], name="camera1"), replace(ds.sensors[1], name="lidar1"), ds.sensors[2]],
        "a sensor the calibration lacks": [*ds.sensors, replace(ds.sensors[0], name="lidar9")],
        "all detections NaN": [nan(s, list(range(n))) for s in ds.sensors],
        "one board": [nan(s, list(range(1, n))) for s in ds.sensors],
        "a sensor all NaN": [nan(s, list(range(n))) if s.name == "camera1" else s for s in ds.sensors],
    }[case]
    write_dataset(Dataset(tuple(sensors), ds.board), to)
    return to


@pytest.mark.parametrize("case, expected", [
    ("kinds differ", "sensor 'camera1' is a lidar in the data but a camera in the calibration"),
    ("a sensor the calibration lacks", r"sensor(s) lidar9 are not in the calibration"),
    ("all detections NaN", "no board is seen by two sensors"),
])
def test_data_that_does_not_fit_the_calibration_is_one_line(cli, refused, rig, tmp_path, case, expected):
    data = _dataset_variant(rig, tmp_path / "data", case)
    refused(cli("check", rig / "cal", data, "--out", tmp_path / "out"), str(data / "rig.yaml"), expected, code=1)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("case, reason", [("one board", "too few boards: it shares 1"),
                                          ("a sensor all NaN", "it shares no board with another sensor")])
def test_too_little_data_is_cannot_tell(cli, rig, tmp_path, case, reason):
    data = _dataset_variant(rig, tmp_path / "data", case)
    proc = cli("check", rig / "cal", data, "--json")
    assert proc.returncode == EXIT_CANNOT_TELL, proc.stderr.decode()
    result = json.loads(proc.stdout)
    assert result["status"] == "cannot tell"
    assert any(s["reason"].startswith(reason) for s in result["sensors"].values()), result["sensors"]


def test_diff_of_the_same_file_of_other_references_and_other_sensor_sets(rig, tmp_path, capsys):
    """A file with itself (as a file and as its folder), two calibrations of the same boards
    with different reference sensors, a calibration without the radar: unchanged, exit 0."""
    from rigcal.cli.main import run

    cal = rig / "cal"
    for a, b in ((cal, cal), (cal / "calibration.yaml", cal), (cal, rig / "cal_cam"), (rig / "cal_cam", cal)):
        code = run(["diff", str(a), str(b), "--json"])
        captured = capsys.readouterr()
        assert code == 0, captured.err
        result = json.loads(captured.out)
        assert result["status"] == "unchanged" and result["reference"] in ("lidar1", "camera1")
    d = yaml.safe_load((cal / "calibration.yaml").read_text())
    del d["sensors"]["radar1"]
    d["relative"] = {k: r for k, r in d["relative"].items() if "radar1" not in (r["to"], r["from"])}
    (tmp_path / "no_radar").mkdir()
    (tmp_path / "no_radar" / "calibration.yaml").write_text(yaml.safe_dump(d, sort_keys=False))
    code = run(["diff", str(cal), str(tmp_path / "no_radar"), "--json"])
    captured = capsys.readouterr()
    assert code == 0 and json.loads(captured.out)["only_old"] == ["radar1"]
    assert "not compared (only in" in captured.err


def test_diff_of_a_calibration_and_a_dataset_folder_is_one_line(cli, refused, rig):
    refused(cli("diff", rig / "cal", rig / "same"), str(rig / "same"), "a dataset folder", code=1)


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.styles: list[str] = []
        self._in_style = False

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_style = tag == "style"

    def handle_endtag(self, tag):
        self._in_style = False

    def handle_data(self, data):
        if self._in_style:
            self.styles.append(data)


def _inert(html: str, tags: set[str]) -> None:
    """Only the page's own tags; no attribute or style that fetches; a CSP that allows no
    script and no fetch."""
    p = _Tags()
    p.feed(html)
    assert {t for t, _ in p.tags} <= tags, {t for t, _ in p.tags} - tags
    assert len(p.styles) == 1 and "url(" not in p.styles[0]
    for tag, attrs in p.tags:
        assert "style" not in attrs and not any(k.startswith("on") for k in attrs), (tag, attrs)
        if tag == "a":
            assert re.fullmatch(r"\./[A-Za-z0-9._~%-]+/check\.html", attrs["href"]), attrs
    csp = re.search(r'http-equiv="Content-Security-Policy" content="([^"]+)"', html).group(1)
    assert "default-src 'none'" in csp and "script-src" not in csp and "http" not in csp
    assert "base-uri 'none'" in csp and "form-action 'none'" in csp


PAGE_TAGS = {"html", "head", "meta", "title", "style", "body", "h1", "h2", "p", "div", "ul", "li", "table", "tr", "th",
             "td", "a"}


def test_markup_and_control_characters_in_names_are_inert_in_check_and_fleet_pages(cli, rig, tmp_path):
    """A sensor named with markup and a CSS url(), a vehicle folder named with markup and
    control characters: every page shows them as text (escaped, control characters as \\x..),
    fetches nothing, runs nothing; the terminal table shows them escaped (was: a vehicle's
    escape sequence and newline printed raw, splitting its row; the page's CSP without
    base-uri and form-action)."""
    d = yaml.safe_load((rig / "cal" / "calibration.yaml").read_text())
    _rename("camera1", EVIL)(d)
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "calibration.yaml").write_text(yaml.safe_dump(d, sort_keys=False))
    ds = load_manifest(rig / "same")
    from dataclasses import replace

    vehicle = "car<b>\x1b[31m\nx"
    write_dataset(Dataset(tuple(replace(s, name=EVIL) if s.name == "camera1" else s for s in ds.sensors), ds.board),
                  tmp_path / "week" / vehicle)
    shutil.copytree(cal, tmp_path / "calib" / vehicle)
    proc = cli("check", cal, tmp_path / "week" / vehicle, "--out", tmp_path / "one")
    assert proc.returncode == 0, proc.stderr.decode()
    html = (tmp_path / "one" / "check.html").read_text()
    assert EVIL not in html and "\x1b" not in html and "cam&lt;style&gt;*{background:url(http:x.png)}&lt;b&gt;" in html
    _inert(html, PAGE_TAGS)
    proc = cli("check", "--batch", tmp_path / "week" / vehicle, "--calibrations", tmp_path / "calib",
               "--out", tmp_path / "fleet", "--scheduler", "serial")
    assert proc.returncode == 0, proc.stderr.decode()
    fleet = (tmp_path / "fleet" / "fleet.html").read_text()
    assert "car&lt;b&gt;\\x1b[31m\\nx" in fleet and "\x1b" not in fleet
    _inert(fleet, PAGE_TAGS)
    _inert((tmp_path / "fleet" / vehicle / "check.html").read_text(), PAGE_TAGS)
    out = proc.stdout.decode()
    assert "\x1b" not in out and "car<b>\\x1b[31m\\nx" in out


# ---------------------------------------------------------------------------------------------
# rigcal check --batch


@pytest.fixture(scope="module")
def fleet(rig, tmp_path_factory) -> Path:
    """week/car_a, week/car_b (new detections), calib/car_a, calib/car_b (their calibrations),
    week/car_nocal (no calibration), week/README.md, week2/car_a (a second car_a)."""
    root = tmp_path_factory.mktemp("fleet")
    for car in ("car_a", "car_b"):
        shutil.copytree(rig / "same", root / "week" / car)
        shutil.copytree(rig / "cal", root / "calib" / car)
    shutil.copytree(rig / "same", root / "week" / "car_nocal")
    shutil.copytree(rig / "same", root / "week2" / "car_a")
    (root / "week" / "README.md").write_text("# week 12\n")
    os.symlink(root / "week" / "car_b", root / "car_b_link")
    return root


def _batch(cli, *dirs, out, calibrations=None, extra=()):
    cal = ("--calibrations", calibrations) if calibrations else ()
    return cli("check", "--batch", *dirs, *cal, "--out", out, "--scheduler", "serial", *extra, seconds=60)


@pytest.mark.parametrize("where", ["calibrations root", "week", "a vehicle", "a calibration"])
def test_batch_out_onto_an_input_is_refused_and_nothing_changes(cli, refused, fleet, tmp_path, where):
    """Was: exit 0, with every vehicle's calibration folder (or data folder) replaced by its
    check.json and check.html."""
    root = _copy(fleet, tmp_path / "f")
    out = {"calibrations root": root / "calib", "week": root / "week", "a vehicle": root / "week" / "car_a",
           "a calibration": root / "calib" / "car_a"}[where]
    before = _files(root)
    refused(_batch(cli, root / "week" / "car_a", root / "week" / "car_b", out=out, calibrations=root / "calib"),
            f"--out {out}", "an input of this run", code=1)
    assert _files(root) == before


def test_batch_out_onto_a_file_is_refused_before_any_work(cli, refused, fleet, tmp_path):
    """Was: refused only when the first vehicle was written, naming no option."""
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    refused(_batch(cli, fleet / "week" / "car_a", out=notes, calibrations=fleet / "calib"), f"--out {notes}",
            "exists and is not a folder", code=1)
    assert notes.read_text() == "mine"


def test_batch_out_holding_a_user_s_fleet_html_is_refused(cli, refused, fleet, tmp_path):
    """Was: the user's fleet.html replaced by the fleet's page."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "fleet.html").write_text("<p>my fleet notes</p>")
    refused(_batch(cli, fleet / "week" / "car_a", out=mine, calibrations=fleet / "calib"), f"--out {mine}",
            "holds a fleet.html rigcal did not write", code=1)
    assert sorted(p.name for p in mine.iterdir()) == ["fleet.html"]
    assert (mine / "fleet.html").read_text() == "<p>my fleet notes</p>"


@pytest.mark.parametrize("what", ["missing", "a file"])
def test_batch_calibrations_root_that_is_not_a_folder_is_one_line(cli, refused, fleet, tmp_path, what):
    """Was: every vehicle failed ("calibration not found"), exit 1 without any error line."""
    root = tmp_path / "nope" if what == "missing" else fleet / "calib" / "car_a" / "calibration.yaml"
    out = tmp_path / "out"
    refused(_batch(cli, fleet / "week" / "car_a", out=out, calibrations=root), f"--calibrations {root}",
            "no such folder" if what == "missing" else "not a folder", code=1)
    assert not out.exists()


def test_batch_of_a_messy_fleet_checks_what_it_can(cli, fleet, tmp_path):
    """A plain file (skipped with a note), a mistyped folder, a vehicle without a calibration,
    a second folder of the same name, a symlink to a vehicle given too: the others are checked
    and written, and one error line names the failures (was: exit 4 without any line)."""
    out = tmp_path / "out"
    proc = _batch(cli, *sorted((fleet / "week").iterdir()), fleet / "week2" / "car_a", fleet / "car_b_link",
                  fleet / "week" / "car_x", out=out, calibrations=fleet / "calib")
    err, text = proc.stderr.decode(), proc.stdout.decode()
    assert proc.returncode == EXIT_PARTIAL, err
    assert f"note: {fleet / 'week' / 'README.md'}: not a folder, skipped" in text
    errors = [ln for ln in err.splitlines() if ln.startswith("rigcal: error:")]
    assert len(errors) == 1 and "Traceback" not in err, err
    assert re.search(r"failed: car_a, car_nocal, car_x .*; 2 of 5 vehicles checked and written", errors[0]), errors[0]
    summary = json.loads((out / "fleet.json").read_text())
    by = {}
    for v in summary["vehicles"]:
        by.setdefault(v["vehicle"], []).append(v)
    assert {v["status"] for v in by["car_a"]} == {"unchanged", "failed"}
    assert "calibration not found" in by["car_nocal"][0]["headline"]
    assert "no such folder" in by["car_x"][0]["headline"]
    assert "car_b_link" not in by and f"note: {fleet / 'car_b_link'}: the same folder as" in text
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == sorted(
        v for v, rows in by.items() if any(r["status"] == "unchanged" for r in rows))


def test_batch_with_json_is_refused(cli, refused, fleet, tmp_path):
    """Was: --json silently ignored with --batch."""
    refused(_batch(cli, fleet / "week" / "car_a", out=tmp_path / "o", calibrations=fleet / "calib",
                   extra=("--json",)), "--json applies to one check", code=1)


def _test_cluster():
    """tests/hostile/test_cluster.py as a module (its fake TCP services), loaded by path: the
    suite imports test modules with --import-mode=importlib, not from sys.path."""
    import importlib.util

    pytest.importorskip("distributed")
    spec = importlib.util.spec_from_file_location("hostile_test_cluster", Path(__file__).with_name("test_cluster.py"))
    module = sys.modules.get(spec.name)
    if module is None:
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # (it registers itself with cloudpickle by name)
        spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("service", ["banner", "dead port"])
def test_batch_on_a_service_that_is_not_a_scheduler_is_refused_at_once(cli, refused, fleet, tmp_path, service):
    """A banner service and a dead port on loopback (the silent service is in test_cluster.py
    for calibrate --batch; check --batch runs the same probe before anything is read)."""
    cluster = _test_cluster()
    out = tmp_path / "out"
    argv = ("check", "--batch", fleet / "week" / "car_a", "--calibrations", fleet / "calib", "--out", out)
    if service == "banner":
        with cluster.fake_service(cluster.BANNER) as port:
            t0 = time.monotonic()
            proc = cli(*argv, "--scheduler", f"tcp://127.0.0.1:{port}", seconds=30)
            assert time.monotonic() - t0 < 14.0
        refused(proc, f"--scheduler tcp://127.0.0.1:{port}", "not a Dask scheduler", code=1)
    else:
        port = cluster._closed_port()
        refused(cli(*argv, "--scheduler", f"tcp://127.0.0.1:{port}"), f"127.0.0.1:{port}", "connection refused",
                code=1)
    assert not out.exists()


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_a_signal_in_the_middle_of_a_fleet_leaves_only_whole_vehicles(rig, tmp_path, sig, code, word):
    """Ctrl-C or SIGTERM once a few vehicles are written: exit 130 / 143 with one line, every
    vehicle folder written is complete, no staging folder, no half fleet.json."""
    week, calib = tmp_path / "week", tmp_path / "calib"
    for i in range(30):
        shutil.copytree(rig / "same", week / f"car{i:02d}")
        shutil.copytree(rig / "cal", calib / f"car{i:02d}")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "rigcal.cli.main", "check", "--batch", *map(str, sorted(week.iterdir())),
                             "--calibrations", str(calib), "--out", str(out), "--scheduler", "serial"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    deadline = time.monotonic() + 60
    while not (out.is_dir() and sum(not p.name.startswith(".") for p in out.iterdir()) >= 2):
        assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    if proc.returncode == 0:
        pytest.skip("the fleet finished before the signal")
    assert proc.returncode == code, err
    lines = [ln for ln in err.splitlines() if ln.startswith("rigcal")]
    assert lines == [f"rigcal: {word} (nothing half-written is left)"] and "Traceback" not in err, err
    names = [p.name for p in out.iterdir()]
    assert not [n for n in names if n.startswith(".") and n != ".rigcal-output"], names
    for name in names:
        if (out / name).is_dir():
            assert {p.name for p in (out / name).iterdir()} == {".rigcal-output", "check.json", "check.html"}
            json.loads((out / name / "check.json").read_text())
    if (out / "fleet.json").exists():
        json.loads((out / "fleet.json").read_text())
