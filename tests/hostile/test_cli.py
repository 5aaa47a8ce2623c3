"""Hostile input to the command line as a whole: YAML bombs, non-regular files, long names,
malformed calibration files, an output that is also the input, nonsense counts, interrupts.

Each case runs ``rigcal`` in a subprocess under a memory and time limit (see conftest.py) and
expects a non-zero exit, one error line naming the culprit, no traceback and no output left.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

BOMB = "".join(
    f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]\n"
    for p, c in zip("abcdefgh", "bcdefghi")
)
BOMB = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + BOMB  # 9^9 = 387 M strings
# the same bomb as one value (for a key a reader accepts, so it gets past the key checks)
BOMB_VALUE = "[&a [lol, lol, lol, lol, lol, lol, lol, lol, lol], " + ", ".join(
    f"&{c} [" + ", ".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefgh", "bcdefghi")
) + "]"


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory) -> Path:
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("data") / "data").parent


def _no_output(tmp_path: Path, out: Path) -> None:
    assert not out.exists()
    leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    assert not leftovers, leftovers


def _relative_calibration(dataset_dir: Path, tmp_path: Path, cli) -> Path:
    out = tmp_path / "cal"
    proc = cli("calibrate", dataset_dir / "rig.yaml", "--mode", "fcpe", "--out", out, "--no-plot")
    assert proc.returncode == 0, proc.stderr
    return out / "calibration.yaml"


# ---------------------------------------------------------------------------------------------
# YAML bombs and deep nesting, in every kind of YAML the CLI reads


@pytest.mark.parametrize("doc", [BOMB, "reference: BOMB\n", "reference: &a [*a]\n",
                                 "[" * 5000 + "]" * 5000])
def test_yaml_bomb_manifest(tmp_path, cli, refused, dataset_dir, doc):
    manifest = tmp_path / "rig.yaml"
    for p in dataset_dir.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    valid = (dataset_dir / "rig.yaml").read_text()
    if doc.startswith("reference:"):  # a valid manifest whose reference is the bomb
        valid = "\n".join(ln for ln in valid.splitlines() if not ln.startswith("reference:"))
        doc = valid + "\n" + doc.replace("BOMB", BOMB_VALUE)
    manifest.write_text(doc)
    out = tmp_path / "out"
    refused(cli("calibrate", manifest, "--out", out, memory_mb=700, seconds=30), "rig.yaml", code=1)
    _no_output(tmp_path, out)


def test_yaml_bomb_initial_guess(tmp_path, cli, refused, dataset_dir):
    guess = tmp_path / "initial.yaml"
    guess.write_text(BOMB)
    out = tmp_path / "out"
    proc = cli("calibrate", dataset_dir / "rig.yaml", "--initial", guess, "--out", out,
               memory_mb=700, seconds=30)
    refused(proc, "initial.yaml", "expands to more than")
    _no_output(tmp_path, out)


@pytest.mark.parametrize("command", ["export", "urdf"])
def test_yaml_bomb_calibration_file(tmp_path, cli, refused, command):
    cal = tmp_path / "calibration.yaml"
    cal.write_text(BOMB)
    urdf = tmp_path / "robot.urdf"
    urdf.write_text('<robot name="r"><link name="base_link"/></robot>')
    out = tmp_path / "out.x"
    args = ["export", cal, "--format", "yaml", "--out", out] if command == "export" else ["urdf", urdf, cal, "--out", out]
    refused(cli(*args, memory_mb=700, seconds=30), "calibration.yaml", "expands to more than")
    assert not out.exists()


def test_yaml_bomb_mocap_config(tmp_path, cli, refused):
    cfg = tmp_path / "mocap.yaml"
    cfg.write_text(BOMB)
    out = tmp_path / "out"
    refused(cli("mocap", cfg, "--out", out, memory_mb=700, seconds=30), "mocap.yaml")
    _no_output(tmp_path, out)


def test_yaml_merge_keys_are_standard_yaml(tmp_path, cli, dataset_dir):
    """``<<: *base`` was refused as a duplicate key; now a manifest may share settings."""
    text = (dataset_dir / "rig.yaml").read_text()
    assert "sensors:" in text
    text = "defaults: &defaults {}\n" + text.replace("sensors:", "x-shared:\n  <<: *defaults\nsensors:", 1)
    manifest = dataset_dir.parent / "merge" / "rig.yaml"
    manifest.parent.mkdir(exist_ok=True)
    for p in dataset_dir.iterdir():
        (manifest.parent / p.name).write_bytes(p.read_bytes())
    manifest.write_text(text)
    proc = cli("calibrate", manifest, "--out", tmp_path / "out", "--no-plot")
    err = proc.stderr.decode()
    # unknown top-level keys may be refused by the manifest reader, but not as a YAML error
    assert "duplicate key" not in err and "invalid YAML" not in err, err


# ---------------------------------------------------------------------------------------------
# files that are not regular files, and names the file system cannot hold


@pytest.fixture
def fifo(tmp_path) -> Path:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this system")
    p = tmp_path / "pipe.yaml"
    os.mkfifo(p)
    return p


def test_fifo_manifest_is_refused_without_blocking(tmp_path, cli, refused, fifo):
    out = tmp_path / "out"
    refused(cli("calibrate", fifo, "--out", out, seconds=30), "pipe.yaml", "FIFO")
    _no_output(tmp_path, out)


def test_fifo_calibration_file(tmp_path, cli, refused, fifo):
    refused(cli("export", fifo, "--format", "yaml", seconds=30), "pipe.yaml", "FIFO")


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_dev_zero_as_detections(tmp_path, cli, refused):
    lidar = tmp_path / "lidar.csv"
    lidar.symlink_to("/dev/zero")
    out = tmp_path / "out"
    proc = cli("calibrate", "--lidar", lidar, "--camera", lidar, "--out", out,
               memory_mb=700, seconds=30)
    refused(proc, "lidar.csv", "character device")
    _no_output(tmp_path, out)


def test_directory_as_calibration_file(tmp_path, cli, refused):
    refused(cli("export", tmp_path, "--format", "yaml"), str(tmp_path), "directory")


def test_long_input_file_name(tmp_path, cli, refused):
    name = "x" * 300 + ".yaml"
    refused(cli("export", tmp_path / name, "--format", "yaml"), "file name too long")


def test_long_output_folder_name(tmp_path, cli, refused, dataset_dir):
    out = tmp_path / ("o" * 300)
    proc = cli("calibrate", dataset_dir / "rig.yaml", "--out", out, "--no-plot")
    refused(proc, "o" * 40)
    assert not any(p.name.startswith(".o") for p in tmp_path.iterdir())


# ---------------------------------------------------------------------------------------------
# malformed calibration files (sensors null, a list, an entry null, a list as reference)


@pytest.mark.parametrize("text, expected", [
    ("reference: a\nsensors: null\n", "not a calibration file"),
    ("reference: a\nsensors: [a, b]\n", "not a calibration file"),
    ("reference: a\nsensors:\n  a: null\n  b: {}\n", "sensors.a: expected a mapping"),
    ("reference: [a]\nsensors:\n  a: {}\n", "reference ['a'] is not one of the sensors"),
    ("body_frame: base\nsensors:\n  a: [1]\n", "sensors.a: expected a mapping"),
    ("body_frame: [x]\nsensors:\n  a: {T_body_sensor: 1}\n", "body_frame: expected a frame name"),
    ("reference: a\nsensors:\n  a: {frame_id: [1]}\n", "sensors.a.frame_id"),
    ("reference: a\nsensors:\n  a: {}\n  b:\n    T_reference_sensor: [[1,0,0,1e300],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n",
     "sensors.b.T_reference_sensor: entry[0, 3] is 1e+300"),
])
@pytest.mark.parametrize("command", ["export", "urdf"])
def test_malformed_calibration_file(tmp_path, cli, refused, text, expected, command):
    cal = tmp_path / "calibration.yaml"
    cal.write_text(text)
    urdf = tmp_path / "robot.urdf"
    urdf.write_text('<robot name="r"><link name="base_link"/><link name="a"/><link name="b"/></robot>')
    out = tmp_path / "out.urdf"
    args = ["export", cal, "--format", "yaml", "--out", out] if command == "export" else ["urdf", urdf, cal, "--out", out]
    refused(cli(*args), "calibration.yaml", expected)
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# an output that is also the input; nonsense counts


def test_export_refuses_to_overwrite_its_input(tmp_path, cli, refused, dataset_dir):
    cal = _relative_calibration(dataset_dir, tmp_path, cli)
    before = cal.read_bytes()
    for out in (cal, cal.parent / "." / cal.name):
        refused(cli("export", cal, "--out", out, "--format", "yaml"), "is the input calibration file")
    assert cal.read_bytes() == before


@pytest.mark.parametrize("argv, expected", [
    (["demo", "--detections-only", "--boards", "0"], "--boards 0"),
    (["demo", "--boards", "-3"], "--boards -3"),
    (["demo", "--detections-only", "--boards", "100000000"], "--boards 100000000"),
])
def test_demo_counts(tmp_path, cli, refused, argv, expected):
    out = tmp_path / "out"
    refused(cli(*argv, "--out", out, seconds=30), expected, code=1)
    _no_output(tmp_path, out)


@pytest.mark.parametrize("argv, expected", [
    (["--cv-folds", "-1"], "--cv-folds"),
    (["--cv-folds", "1e9"], "--cv-folds"),
])
def test_calibrate_counts(tmp_path, cli, refused, dataset_dir, argv, expected):
    out = tmp_path / "out"
    refused(cli("calibrate", dataset_dir / "rig.yaml", *argv, "--out", out), expected, code=2)
    _no_output(tmp_path, out)


def test_output_folder_with_foreign_files_is_not_replaced(tmp_path, cli, refused, dataset_dir):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    refused(cli("calibrate", dataset_dir / "rig.yaml", "--out", out, "--no-plot"),
            str(out), "did not write")
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


# ---------------------------------------------------------------------------------------------
# interrupts


def _start(args: list[str]) -> subprocess.Popen:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "rigcal.cli.main", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)


#: the signals the CLI handles: name, exit code, the word of its one line
SIGNALS = [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")]


@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_interrupt_leaves_nothing_half_written(tmp_path, sig, code, word):
    """The detections-only demo on 60 boards writes several folders over ~5 s; interrupted
    while it runs, it exits 130/143 with one line, no traceback and no demo folder (whole or
    partial)."""
    out = tmp_path / "demo"
    proc = _start(["demo", "--detections-only", "--boards", "60", "--out", out])
    deadline = time.monotonic() + 60
    # wait until it is writing (the staging folder appears), then interrupt
    while time.monotonic() < deadline and not any(
        p.name.startswith(".demo.") for p in tmp_path.iterdir()
    ):
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    assert proc.returncode == code, err
    assert word in err and "Traceback" not in err, err
    assert not out.exists()
    assert not list(tmp_path.iterdir()), list(tmp_path.iterdir())


# Where the signal lands, code may rewrite the handler's exception (a C extension being imported
# reports "ImportError: initialization failed": seen with matplotlib's _backend_agg under SIGTERM)
# or drop it (a weakref callback, a library's except). The child runs `rigcal report` with its
# command replaced by one that raises {trigger} inside such a wrapper, then may write output.
_CHILD = """
import atexit, os, signal, sys, time
from rigcal.cli import report
from rigcal.io.atomic import atomic_write_text, staged_folder
{setup}

def run(args, console):
    try:
        {trigger}
        time.sleep(10)
    except BaseException as exc:
        {handler}
    with staged_folder("{out}") as stage:
        atomic_write_text(stage / "calibration.yaml", "x")
    return 0

report.run = run
sys.argv = ["rigcal", "report", "{out}"]
from rigcal.cli.main import entry
entry()
"""
_REWRITE = 'raise ImportError("initialization failed") from exc'
_DROP = "pass"


def _child(tmp_path: Path, trigger: str, handler: str, setup: str = "") -> tuple[int, str]:
    script = _CHILD.format(trigger=trigger, handler=handler, out=tmp_path / "out", setup=setup)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    return done.returncode, done.stderr.decode()



@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_interrupt_turned_into_another_exception_is_still_an_interrupt(tmp_path, sig, code, word):
    rc, err = _child(tmp_path, f"os.kill(os.getpid(), signal.{sig})", _REWRITE)
    assert rc == code, err
    assert word in err and "Traceback" not in err and "ImportError" not in err, err
    assert not list(tmp_path.iterdir()), list(tmp_path.iterdir())


def test_internal_error_without_a_signal_still_shows_its_traceback(tmp_path):
    """The rule above applies only once a signal was received: a real bug is not hidden."""
    rc, err = _child(tmp_path, "raise ValueError('a bug')", _REWRITE)
    assert rc == 1, err
    assert "Traceback" in err and "ImportError: initialization failed" in err, err


@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_swallowed_interrupt_still_publishes_nothing(tmp_path, sig, code, word):
    """The run goes on after its interrupt was dropped, but its output is not published and it
    still ends as interrupted."""
    rc, err = _child(tmp_path, f"os.kill(os.getpid(), signal.{sig})", _DROP)
    assert rc == code, err
    assert word in err and "Traceback" not in err, err
    assert not list(tmp_path.iterdir()), list(tmp_path.iterdir())


@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_interrupted_run_skips_the_interpreters_teardown(tmp_path, sig, code, word):
    """A teardown that would crash (an extension module interrupted mid-import; here an exit
    handler that aborts) does not turn the interrupt's exit code into a crash."""
    rc, err = _child(tmp_path, f"os.kill(os.getpid(), signal.{sig})", "raise", setup="atexit.register(os.abort)")
    assert rc == code, err
    assert word in err and "Traceback" not in err, err


# `rigcal report` replaced by a command that publishes its output and returns 0; an exit handler
# then sends the signal, as a user's Ctrl-C or a supervisor's SIGTERM may land while it ends
_PUBLISH_THEN_SIGNAL = """
import atexit, os, signal, sys, time
from rigcal.cli import report
from rigcal.io.atomic import atomic_write_text, staged_folder

def run(args, console):
    with staged_folder("{out}") as stage:
        atomic_write_text(stage / "calibration.yaml", "x")
    atexit.register(lambda: (os.kill(os.getpid(), signal.{sig}), time.sleep(0.5)))
    return 0

report.run = run
sys.argv = ["rigcal", "report", "{out}"]
from rigcal.cli.main import entry
entry()
"""


@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_signal_after_publishing_still_exits_with_its_line(tmp_path, sig, code, word):
    """Issue #22: a signal that lands after the output is published, while the process ends (here
    from an exit handler), exits 130/143 with the one line; the output stays, complete. Was: the
    interpreter's teardown had put the default handler back - killed, exit -15, no line."""
    script = _PUBLISH_THEN_SIGNAL.format(out=tmp_path / "out", sig=sig)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    rc, err = done.returncode, done.stderr.decode()
    assert rc == code, err
    assert f"rigcal: {word}" in err and "Traceback" not in err and "Exception ignored" not in err, err
    assert (tmp_path / "out" / "calibration.yaml").read_text() == "x"  # published, complete


_SIGNAL_BEFORE_EXIT_TAKES_OVER = """
import os, signal, sys, time
from rigcal.cli import main, report
from rigcal.io.atomic import atomic_write_text, staged_folder

def run(args, console):
    with staged_folder("{out}") as stage:
        atomic_write_text(stage / "calibration.yaml", "x")
    return 0

real_exit_now, calls = main._exit_now, []

def exit_now(code):
    calls.append(code)
    if len(calls) == 1:  # the signal lands before the exit path has taken the signals over
        os.kill(os.getpid(), signal.{sig})
        time.sleep(0.5)
    real_exit_now(code)

report.run = run
main._exit_now = exit_now
sys.argv = ["rigcal", "report", "{out}"]
main.entry()
"""


@pytest.mark.parametrize("sig, code, word", SIGNALS)
def test_signal_between_the_run_and_its_exit_path_exits_with_its_line(tmp_path, sig, code, word):
    """A signal that lands after the run returned but before the exit path replaced the
    handlers (CI once: SIGTERM 20 ms after a calibration was published printed a traceback from
    the handler, exit 1) ends the run with the one line and 130/143; the output stays."""
    script = _SIGNAL_BEFORE_EXIT_TAKES_OVER.format(out=tmp_path / "out", sig=sig)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    rc, err = done.returncode, done.stderr.decode()
    assert rc == code, err
    assert f"rigcal: {word}" in err and "Traceback" not in err, err
    assert (tmp_path / "out" / "calibration.yaml").read_text() == "x"


@pytest.mark.slow  # five calibrations
def test_sigterm_just_after_a_calibration_is_published(tmp_path, dataset_dir):
    """A real ``rigcal calibrate``, SIGTERM sent at several moments after its output folder
    appears: it exits 0 (done before the signal) or 143 with the line, never killed by the
    signal; the output is complete either way."""
    outcomes = []
    for delay in (0.0, 0.02, 0.05, 0.1, 0.2):
        out = tmp_path / f"out{delay}"
        proc = _start(["calibrate", dataset_dir / "rig.yaml", "--out", out, "--cv-folds", "0"])
        deadline = time.monotonic() + 60
        while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.001)
        time.sleep(delay)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        err = err.decode()
        outcomes.append(proc.returncode)
        assert proc.returncode in (0, 143), (delay, proc.returncode, err)
        if proc.returncode == 143:
            assert "rigcal: terminated" in err and "Traceback" not in err, err
        assert {"calibration.yaml", "report.json", "report.html", ".rigcal-output"} <= {p.name for p in out.iterdir()}
