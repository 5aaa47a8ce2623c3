"""docs/studies.md: the commands a user would type. The quick ones run as written on the shared
Prius detections (from a checkout's root, ../shared beside it); the full study (8 min) and the
cluster examples are too long or need a cluster, so they are parsed by rigcal's own parser."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from rigcal.cli.main import _parser, run

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "studies.md"
SHARED = REPO.parent / "shared"


def commands(text: str) -> list[list[str]]:
    """The ``rigcal ...`` lines of the bash blocks of ``text`` (``#`` comments dropped)."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for ln in block.splitlines():
            ln = ln.split(" #", 1)[0].strip()
            if ln.startswith("rigcal "):
                lines.append(shlex.split(ln)[1:])
    return lines


def quick_commands() -> list[list[str]]:
    block = re.search(r"<!-- quick-study.*?-->\s*(```bash\n.*?```)\s*<!-- /quick-study -->", DOC.read_text(), re.S)
    assert block, "docs/studies.md lost its quick-study block"
    return commands(block.group(1))


def test_quick_commands_run_as_written(tmp_path, monkeypatch, capsys):
    if not (SHARED / "data" / "tudelft_prius" / "detections" / "lidar.csv").is_file():
        pytest.skip("../shared/data (beside the repository) not present")
    monkeypatch.chdir(tmp_path)
    argvs = quick_commands()
    assert [a[:2] for a in argvs] == [["study", "prius"], ["study", "prius"], ["report", "prius_study/"]]
    for argv in argvs:
        assert run(argv) == 0, (argv, capsys.readouterr().err)
    out = capsys.readouterr().out
    assert "| MCPE single board | 1 (each of 29) | 39.3 +- 10.4 |" in out  # Table II, as the doc says
    study = json.loads((tmp_path / "prius_study" / "study.json").read_text())
    assert study["meta"]["draws"] == {"III": 2} and study["meta"]["manifest"] == "examples/prius/rig.yaml"
    page = (tmp_path / "prius_study" / "study.html").read_text()
    assert str(REPO) not in page and str(tmp_path) not in page  # no absolute path on the page
    assert "<td class=\"text\">III: 2</td>" in page and '<section id="notes">' in page


def test_every_command_of_the_page_parses():
    argvs = commands(DOC.read_text())
    assert len(argvs) >= 6
    parser = _parser()
    for argv in argvs:
        try:
            parser.parse_args(argv)
        except SystemExit as exc:  # argparse's way of refusing a command line
            pytest.fail(f"docs/studies.md: `rigcal {shlex.join(argv)}` does not parse (exit {exc.code})")
