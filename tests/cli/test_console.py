"""The command line's shell: a light start (no numpy, scipy, OpenCV, ... before a command runs),
-v anywhere, tables within 80 columns, plain progress lines when stdout is not a terminal, and
the help's exit codes and --keep-bag."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rigcal
from rigcal.cli import main as cli_main
from rigcal.cli.main import run
from rigcal.cli.output import PlainProgress
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

#: what `rigcal --help` and every `rigcal COMMAND --help` must not import
HEAVY = ("numpy", "scipy", "cv2", "matplotlib", "rosbags", "rich", "yaml", "rigcal.problem", "rigcal.study",
         "rigcal.detect", "rigcal.mocap", "rigcal.io", "jinja2", "plotly", "rigcal.report")

COMMANDS = ("calibrate", "check", "diff", "detect", "absolute", "mocap", "report", "study", "urdf", "export", "demo")


def _imported_modules(*argv: str) -> set[str]:
    """The modules ``python -X importtime -m rigcal.cli.main ARGV`` imports."""
    env = {**os.environ, "PYTHONPATH": str(Path(rigcal.__file__).resolve().parents[1])}
    env.pop("PYTHONWARNINGS", None)
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "rigcal.cli.main", *argv],
                          capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return {line.rsplit("|", 1)[1].strip() for line in proc.stderr.splitlines()
            if line.startswith("import time:") and line.count("|") == 2}


@pytest.mark.parametrize("argv", [["--version"], ["--help"], *([c, "--help"] for c in COMMANDS),
                                  ["study", "mocap", "--help"]], ids=" ".join)
def test_start_imports_nothing_heavy(argv):
    modules = _imported_modules(*argv)
    # the listing is real: the parser's modules are in it
    assert {"argparse", "rigcal.cli.calibrate", "rigcal.cli.demo"} <= modules, sorted(modules)
    heavy = sorted(m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert not heavy, heavy


def test_study_options_match_the_study():
    from rigcal.cli import study as cli_study
    from rigcal.problem.mocap import CORRESPONDENCES
    from rigcal.study import mocap_study

    assert cli_study.TARGETS == mocap_study.TARGETS
    assert cli_study.SENSORS == mocap_study.SENSORS
    assert cli_study.CORRESPONDENCES == CORRESPONDENCES


# --------------------------------------------------------------------------------------------
# -v anywhere

MINIMAL = {
    "calibrate": ["rig.yaml", "--out", "o"],
    "check": ["calibration.yaml", "rig.yaml"],
    "diff": ["old.yaml", "new.yaml"],
    "detect": ["rec.bag", "--rig", "rig.yaml", "--out", "o"],
    "absolute": ["rig.yaml", "--external", "e", "--scan", "s.pcd", "--labels", "l.yaml", "--out", "o"],
    "mocap": ["mocap.yaml", "--out", "o"],
    "report": ["results"],
    "urdf": ["in.urdf", "cal.yaml", "--out", "out.urdf"],
    "export": ["cal.yaml", "--format", "yaml"],
    "demo": ["--detections-only"],
}


@pytest.mark.parametrize("command", [*MINIMAL, "study mocap"])
def test_verbose_before_or_after_the_command(command):
    parser = cli_main._parser()
    words = command.split()
    rest = MINIMAL.get(command, [])
    assert parser.parse_args([*words, *rest]).verbose is False
    for argv in (["-v", *words, *rest], [*words, "-v", *rest], [*words, *rest, "--verbose"],
                 ["--verbose", *words, "-v", *rest]):
        args = parser.parse_args(argv)
        assert args.verbose is True, argv
        assert args.command == words[0]


def test_every_command_is_covered():
    modules = {m.__name__.rsplit(".", 1)[1] for m in cli_main.COMMANDS}
    assert modules == set(COMMANDS) == {*MINIMAL, "study"}


# --------------------------------------------------------------------------------------------
# help


def test_top_help_lists_the_exit_codes(capsys):
    with pytest.raises(SystemExit) as exc:
        run(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "exit codes:" in text
    codes = {line.split()[0] for line in text.split("exit codes:")[1].splitlines() if re.match(r"  \d+ ", line)}
    assert codes == {"0", "1", "2", "3", "4", "6", "7", "130", "143"}
    assert "flagged" in text and "partial" in text and "moved (rigcal check / diff)" in text


def test_demo_help_says_the_bag_is_deleted_unless_keep_bag(capsys):
    with pytest.raises(SystemExit):
        run(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--keep-bag" in text and "230-570 MB" in text and "deleted" in text


# --------------------------------------------------------------------------------------------
# 80 columns


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(5)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)


def assert_fits_80_columns(text: str) -> None:
    assert text.strip()
    for line in text.splitlines():
        assert len(line) <= 80, f"{len(line)} columns: {line!r}"
    assert "…" not in text


def _renamed(dataset, names: dict[str, str]):
    return dataclasses.replace(dataset, sensors=tuple(
        dataclasses.replace(s, name=names.get(s.name, s.name)) for s in dataset.sensors))


@pytest.mark.parametrize("mode", ["fcpe", "pse"])
@pytest.mark.parametrize("long_names", [False, True], ids=["names", "long names"])
def test_calibrate_tables_fit_80_columns(tmp_path, sim, capsys, monkeypatch, mode, long_names):
    monkeypatch.setenv("COLUMNS", "80")
    dataset = sim.dataset
    if long_names:
        dataset = _renamed(dataset, {"lidar1": "roof_lidar_velodyne_hdl64e_centre",
                                     "camera1": "front_stereo_camera_left_1936x1216",
                                     "radar1": "front_bumper_radar_continental_2d"})
    manifest = write_dataset(dataset, tmp_path / "data")
    code = run(["calibrate", str(manifest), "--mode", mode, "--no-plot", "--cv-folds", "2",
                "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert_fits_80_columns(out)
    assert "errors between sensors" in out and "standard deviations" in out
    if not long_names:  # short names are not even folded
        assert all(f"│ {s.name} " in out for s in dataset.sensors)


def test_calibrate_json_summary_on_stderr_fits_80_columns(tmp_path, sim, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    assert run(["calibrate", str(manifest), "--no-plot", "--cv-folds", "0", "--json",
                "--out", str(tmp_path / "out")]) == 0
    assert_fits_80_columns(capsys.readouterr().err)


def test_demo_tables_fit_80_columns(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    assert run(["demo", "--detections-only", "--boards", "12", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    report = str(tmp_path / "demo" / "fcpe" / "report.html")
    assert out.splitlines()[-1] == report  # the page to open, whole, to copy (however long)
    assert_fits_80_columns(out.replace(report, "report.html"))
    assert "errors against the simulated truth" in out and "FCPE RMSE between sensors (mm)" in out
    assert "open this page in a browser (the other modes: mcpe/, pse/):" in out


# --------------------------------------------------------------------------------------------
# progress when stdout is not a terminal


class _Console:
    def __init__(self):
        self.lines: list[str] = []

    def print(self, text, **_):
        self.lines.append(text)


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_plain_progress_prints_each_tenth_and_a_final_line():
    console, clock = _Console(), _Clock()
    with PlainProgress(console, clock=clock) as bar:
        task = bar.add_task("detecting", total=None, unit="frames")
        for done in range(1, 481):
            clock.t += 0.001
            bar.update(task, completed=done, total=480)
    assert console.lines[0] == "detecting: 1/480 frames (0%)"
    assert console.lines[1:10] == [f"detecting: {48 * k}/480 frames ({10 * k}%)" for k in range(1, 10)]
    assert console.lines[10].startswith("detecting: 480/480 frames (100%), 0.5 s")
    assert len(console.lines) == 11


def test_plain_progress_prints_every_5_s_when_slow_and_when_total_unknown():
    console, clock = _Console(), _Clock()
    with PlainProgress(console, every_s=5.0, clock=clock) as bar:
        slow = bar.add_task("extracting", total=1000)
        unknown = bar.add_task("simulating")
        for done in range(1, 61):
            clock.t += 1.0
            bar.update(slow, completed=done)
            bar.update(unknown, completed=done)
    slow_lines = [ln for ln in console.lines if ln.startswith("extracting")]
    unknown_lines = [ln for ln in console.lines if ln.startswith("simulating")]
    # 60 s at 1 % a second: a line every 5 s (none reaches another 10 %), then the final one
    assert slow_lines[:3] == ["extracting: 1/1000 (0%)", "extracting: 6/1000 (0%)", "extracting: 11/1000 (1%)"]
    assert len(slow_lines) == 13 and slow_lines[-1] == "extracting: 60/1000 (6%), 60.0 s"
    assert unknown_lines[:3] == ["simulating: 1", "simulating: 6", "simulating: 11"]
    assert len(unknown_lines) == 13 and unknown_lines[-1] == "simulating: 60, 60.0 s"


def test_plain_progress_of_a_stage_says_when_it_starts():
    console, clock = _Console(), _Clock()
    with PlainProgress(console, clock=clock) as bar:
        task = bar.add_task("simulating raw data")
        bar.update(task, completed=0, total=None)
        clock.t = 42.0
        bar.update(task, completed=1, total=1)
    assert console.lines == ["simulating raw data: started", "simulating raw data: 1/1 (100%), 42.0 s"]


def test_plain_progress_has_no_final_line_after_an_error():
    console = _Console()
    with pytest.raises(KeyboardInterrupt), PlainProgress(console) as bar:
        task = bar.add_task("detecting", total=10)
        bar.update(task, completed=3)
        raise KeyboardInterrupt
    assert console.lines == ["detecting: 3/10 (30%)"]


def test_progress_is_a_live_bar_on_a_terminal_and_lines_elsewhere(monkeypatch):
    from rich.progress import Progress

    from rigcal.cli.output import make_console, progress_bar

    assert isinstance(progress_bar(make_console()), PlainProgress)  # pytest's stdout is captured
    monkeypatch.setenv("FORCE_COLOR", "1")  # rich's own override: a terminal
    assert isinstance(progress_bar(make_console()), Progress)


# --------------------------------------------------------------------------------------------
# help wrapped to the terminal, -v stages


def _help(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        run([*argv, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("width", [60, 100])
@pytest.mark.parametrize("command", ["", *COMMANDS, "study prius", "study mocap"])
def test_help_is_wrapped_to_the_terminal_width(command, width, monkeypatch, capsys):
    """Every line fits the terminal (COLUMNS), except an example command, which is kept whole
    to be copied; the description says all it said before, in the same words."""
    monkeypatch.setenv("COLUMNS", str(width))
    argv = command.split()
    text = _help(argv, capsys)
    for line in text.splitlines():
        # kept whole: an example command, a single token (choices), one option of the usage
        whole = line.lstrip().startswith("rigcal ") or " " not in line.strip() or re.fullmatch(
            r"\[[^\[\]]*\]", line.strip())
        assert len(line) <= width or whole, (command, line)
    parser = cli_main._parser()
    for word in argv:
        parser = next(a for a in parser._actions if isinstance(a, type(parser._subparsers._group_actions[0]))
                      ).choices[word]
    for paragraph in (parser.description or "").split("\n\n"):
        assert " ".join(paragraph.split()) in " ".join(text.split()), (command, paragraph[:60])


def test_verbose_logs_each_stage_with_its_time_to_stderr(tmp_path, sim, capsys):
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    assert run(["calibrate", str(manifest), "--out", str(tmp_path / "quiet")]) == 0
    assert capsys.readouterr().err == ""  # without -v: nothing on stderr
    assert run(["-v", "calibrate", str(manifest), "--out", str(tmp_path / "loud"), "--mode", "pse"]) == 0
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    timed = [ln for ln in lines if re.match(r"^\[ *\d+\.\d\d s\] ", ln)]
    assert timed == lines and len(lines) >= 8, captured.err
    stages = [re.sub(r"^\[ *\d+\.\d\d s\] ", "", ln) for ln in lines]
    expected = ["rigcal calibrate ...", r"reading 3 sensors x \d+ boards: \d+\.\d\d s",
                r"PSE fit with outlier screening \(\d+ noise iterations\): \d+\.\d\d s",
                r"cross-validation \(5 folds\): \d+\.\d\d s", r"covariance: \d+\.\d\d s",
                r"consistency checks \((consistent|flagged)\): \d+\.\d\d s",
                r"calibration \(PSE, reference lidar1, verdict \w+\): \d+\.\d\d s",
                rf"writing {re.escape(str(tmp_path / 'loud'))}/: \d+\.\d\d s", r"rigcal calibrate: \d+\.\d\d s"]
    found = iter(stages)
    for pattern in expected:  # in this order (other lines may come between)
        assert any(re.fullmatch(pattern, s) for s in found), (pattern, stages)
    elapsed = [float(re.match(r"^\[ *(\d+\.\d\d) s\]", ln).group(1)) for ln in lines]
    assert elapsed == sorted(elapsed)
    assert "errors between sensors" in captured.out  # the summary is unchanged, on stdout
