"""Every command a user would type in README.md and docs/*.md is run by a test, or its block
says why not - and every `rigcal` line parses with rigcal's own parser.

A ```bash block holding a `rigcal` line is preceded by a marker comment:

* `<!-- run: FIXTURE[, slow] -->`: run here. The blocks of one page with one fixture run in
  document order in one folder (```python blocks with the same marker too, in one namespace);
  a line's `# exit N` comment gives its expected exit code (default 0). Fixtures: `empty` (an
  empty folder), `shared` (a checkout's root: a copy of examples/ with ../shared beside it;
  skipped when ../shared is absent), `recording` (an empty folder with a small simulated
  `recording.bag`, `run.bag` the same, and their `detect_rig.yaml`; slow).
* `<!-- not run: REASON -->`: illustrative, or too long; the lines are still parsed.
* any other `<!-- NAME: ... tests/docs/test_X.py ... -->`: run by that module, which names
  the page.

Where a page quotes what its commands give (RMSEs, verdicts, files), a check below compares.
"""

from __future__ import annotations

import dataclasses
import re
import shlex
import shutil
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
import pytest
import yaml

from rigcal.cli.main import _parser, run

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
SHARED = REPO.parent / "shared"
PAGES = (REPO / "README.md", *sorted(DOCS.glob("*.md")))
FIXTURES = ("empty", "shared", "recording")

_FENCE = re.compile(r"^```(bash|python)\n(.*?)^```", re.S | re.M)
_MARKER = re.compile(r"<!--\s*(.*?)\s*-->\s*$")


class Block(NamedTuple):
    page: str
    line: int
    lang: str
    body: str
    marker: str  # the comment right above the fence ("" when none)

    @property
    def kind(self) -> str:
        return self.marker.split(":", 1)[0].strip() if ":" in self.marker else ""

    @property
    def options(self) -> list[str]:
        return [w.strip() for w in self.marker.split(":", 1)[1].split(",")] if ":" in self.marker else []

    def commands(self) -> list[tuple[list[str], int]]:
        """The `rigcal ...` lines: (argv without `rigcal`, expected exit code)."""
        out = []
        for raw in self.body.splitlines():
            if not raw.strip().startswith("rigcal "):
                continue
            code = re.search(r"#.*\bexit (\d+)\b", raw)
            out.append((shlex.split(raw, comments=True)[1:], int(code.group(1)) if code else 0))
        return out


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    name = "README.md" if page.parent == REPO else f"docs/{page.name}"
    found = []
    for m in _FENCE.finditer(text):
        before = text[: m.start()].rstrip().splitlines()
        marker = _MARKER.fullmatch(before[-1].strip()) if before else None
        found.append(Block(name, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(2),
                           marker.group(1) if marker else ""))
    return found


ALL = [b for page in PAGES for b in blocks(page)]


def _groups() -> dict[tuple[str, str], list[Block]]:
    groups: dict[tuple[str, str], list[Block]] = {}
    for b in ALL:
        if b.kind == "run":
            groups.setdefault((b.page, b.options[0]), []).append(b)
    return groups


GROUPS = _groups()


# ----------------------------------------------------------------------------- every block


def test_every_command_block_is_run_or_says_why_not():
    assert len([b for b in ALL if b.kind == "run"]) >= 15  # the harness still finds its blocks
    for b in ALL:
        where = f"{b.page}:{b.line}"
        if b.lang == "bash" and not b.commands():
            continue  # pip, make, ...: no rigcal line
        if b.kind == "run":
            assert b.options[0] in FIXTURES, f"{where}: unknown fixture {b.options[0]!r}"
            assert set(b.options[1:]) <= {"slow"}, f"{where}: unknown option in {b.marker!r}"
        elif b.kind == "not run":
            assert len(b.marker.split(":", 1)[1].strip()) > 10, f"{where}: say why it is not run"
            assert b.lang == "bash", f"{where}: a Python block is run (api.md) or not marked"
        elif b.lang == "bash":
            module = re.search(r"tests/docs/test_\w+\.py", b.marker)
            assert module, f"{where}: a rigcal block needs <!-- run: FIXTURE --> or <!-- not run: why -->"
            assert Path(b.page).name in (REPO / module.group(0)).read_text(), \
                f"{where}: {module.group(0)} does not run {b.page}"


def test_every_rigcal_line_parses():
    parser = _parser()
    lines = [(b, argv) for b in ALL if b.lang == "bash" for argv, _ in b.commands()]
    assert len(lines) >= 80
    for b, argv in lines:
        try:
            parser.parse_args(argv)
        except SystemExit as exc:  # argparse's way of refusing (0 for --help / --version)
            assert exc.code == 0, f"{b.page}:{b.line}: `rigcal {shlex.join(argv)}` does not parse"


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def recording_source(tmp_path_factory) -> Path:
    """A small simulated recording of a VLP-16-like lidar, a 640 x 480 stereo pair and a 2D radar
    (6 placements, lidar and stereo at 2 Hz) as a ROS 1 bag, with its detection rig."""
    from rigcal.demo import frames_by_topic, raw_rig_yaml
    from rigcal.io.recordings.bag import write_recording
    from rigcal.sim.raw import raw_rig_placements, simulate_recording, small_raw_rig

    sensors = tuple(s if s.name == "radar1" else dataclasses.replace(s, rate_hz=2.0) for s in small_raw_rig())
    rng = np.random.default_rng(3)
    rec = simulate_recording(sensors, raw_rig_placements(rng, sensors, 6), rng, dwell_s=2.0, transition_s=1.0)
    folder = tmp_path_factory.mktemp("recording")
    write_recording(folder / "recording.bag", frames_by_topic(rec.frames), "rosbag1")
    (folder / "detect_rig.yaml").write_text(raw_rig_yaml(sensors))
    return folder


def _folder(fixture: str, tmp_path: Path, request) -> Path:
    if fixture == "empty":
        return tmp_path
    if fixture == "shared":
        if not (SHARED / "data" / "tudelft_prius" / "detections" / "lidar.csv").is_file():
            pytest.skip("../shared/data (beside the repository) not present")
        root = tmp_path / "checkout"
        shutil.copytree(REPO / "examples", root / "examples")  # its ../../../shared is tmp_path/shared
        (tmp_path / "shared").symlink_to(SHARED)
        return root
    source = request.getfixturevalue("recording_source")
    for name in ("recording.bag", "detect_rig.yaml"):
        (tmp_path / name).symlink_to(source / name)
    (tmp_path / "run.bag").symlink_to(source / "recording.bag")
    return tmp_path


# ----------------------------------------------------------------------------- what pages say


def _rmse_mm(folder: Path, out: str) -> dict[str, float]:
    cal = yaml.safe_load((folder / out / "calibration.yaml").read_text())
    assert cal["verdict"]["status"] == "consistent", out
    return {pair: value * 1000 for pair, value in cal["rmse_m"].items()}


def _results_table(folder: Path, out: str) -> None:
    """docs/results.md: every RMSE of the first table is what its command writes."""
    text = (DOCS / "results.md").read_text()
    rows = {"FCPE": "prius_fcpe", "PSE, iterated noise (converges)": "prius_pse",
            "PSE, fixed identity noise (`--pse-noise identity`)": "prius_pse_identity",
            "MCPE (reference lidar1)": "prius_mcpe", "MCPE (reference radar1, 2D)": "prius_mcpe_radar"}
    for label, folder_name in rows.items():
        row = re.search(rf"^\| {re.escape(label)} \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|", text, re.M)
        assert row, f"docs/results.md lost its row {label!r}"
        got = _rmse_mm(folder, folder_name)
        for quoted, pair in zip(row.groups(), ("lidar1-camera1", "lidar1-radar1", "camera1-radar1")):
            decimals = len(quoted.split(".")[1])
            assert f"{got[pair]:.{decimals}f}" == quoted, (label, pair, got[pair], quoted)
    assert "Every row's verdict is `consistent`" in text


def _modes(folder: Path, out: str) -> None:
    """docs/modes.md: "(Prius data: lidar-radar 19.6 mm held vs 14.3 mm free)", every run consistent."""
    quoted = re.search(r"\(Prius data: lidar-radar ([\d.]+) mm held vs\s+([\d.]+) mm free\)",
                       (DOCS / "modes.md").read_text())
    assert quoted, "docs/modes.md lost the held-vs-free figures"
    held, free = (_rmse_mm(folder, name)["lidar1-radar1"] for name in ("prius_held", "prius_fcpe"))
    assert (f"{held:.1f}", f"{free:.1f}") == quoted.groups()
    for name in ("prius_mcpe", "prius_mcpe_radar", "prius_pse_identity", "prius_again", "prius_every_board"):
        _rmse_mm(folder, name)  # each consistent


def _readme(folder: Path, out: str) -> None:
    assert "consistent [[" in " ".join(out.split())  # the Python example's print
    assert (folder / "calib.launch.py").is_file() and (folder / "results" / "report.html").is_file()


def _detect(folder: Path, out: str) -> None:
    assert "6 board placements found" in " ".join(out.split())
    for name in ("detections/rig.yaml", "results/calibration.yaml", "kept/rig.yaml", "results_bag/report.html"):
        assert (folder / name).is_file(), name


def _absolute(folder: Path, out: str) -> None:
    body = yaml.safe_load((folder / "absolute" / "absolute.yaml").read_text())
    assert set(body["sensors"]) >= {"lidar1", "camera1", "radar1"}
    assert (folder / "vehicle_calibrated.urdf").is_file()


def _urdf(folder: Path, out: str) -> None:
    assert (folder / "absolute_demo" / "scene" / "vehicle.urdf.bak").is_file()  # --in-place keeps a copy
    assert "ros2 run tf2_ros static_transform_publisher" in out


CHECKS: dict[tuple[str, str], Callable[[Path, str], None]] = {
    ("docs/results.md", "shared"): _results_table,
    ("docs/modes.md", "shared"): _modes,
    ("README.md", "empty"): _readme,
    ("docs/detect.md", "recording"): _detect,
    ("docs/absolute.md", "empty"): _absolute,
    ("docs/urdf.md", "empty"): _urdf,
}


# ----------------------------------------------------------------------------- running the pages


def _params():
    for (page, fixture), group in sorted(GROUPS.items()):
        slow = fixture == "recording" or any("slow" in b.options for b in group)
        yield pytest.param(page, fixture, marks=[pytest.mark.slow] if slow else [], id=f"{page}-{fixture}")


@pytest.mark.parametrize(("page", "fixture"), list(_params()))
def test_page_runs_as_written(page, fixture, tmp_path, monkeypatch, capsys, request):
    folder = _folder(fixture, tmp_path, request)
    monkeypatch.chdir(folder)
    monkeypatch.setenv("COLUMNS", "80")
    namespace: dict = {}
    out = []
    for b in GROUPS[(page, fixture)]:
        if b.lang == "python":
            exec(compile(b.body, f"{page}:{b.line}", "exec"), namespace)
            continue
        for argv, code in b.commands():
            assert run(argv) == code, (f"{page}:{b.line}", argv, capsys.readouterr().err[-2000:])
            out.append(capsys.readouterr().out)
    out.append(capsys.readouterr().out)
    check = CHECKS.get((page, fixture))
    if check is not None:
        check(folder, "".join(out))
