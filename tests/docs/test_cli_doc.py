"""docs/cli.md and the README's table keep up with the command: every exit code `rigcal --help`
lists is in cli.md's table (and nothing else), and every subcommand is in both tables."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from rigcal.cli.codes import EXIT_CODES_HELP
from rigcal.cli.main import _parser

REPO = Path(__file__).resolve().parents[2]
CLI = REPO / "docs" / "cli.md"


def _section(text: str, heading: str) -> str:
    start = text.index(f"\n## {heading}\n")
    end = text.find("\n## ", start + 1)
    return text[start: end if end > 0 else None]


def test_the_exit_code_table_lists_every_code():
    listed = {int(c) for c in re.findall(r"^  (\d+) ", EXIT_CODES_HELP, re.M)}
    assert {0, 1, 2, 3, 130, 143} <= listed
    table = {int(c) for c in re.findall(r"^\| (\d+) \|", _section(CLI.read_text(), "Exit codes"), re.M)}
    assert table == listed


def test_every_command_is_in_the_tables():
    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    commands = set(sub.choices)
    assert {"calibrate", "detect", "check", "diff", "demo"} <= commands
    for page, section in ((CLI, "The commands"), (REPO / "README.md", "What it does")):
        named = set(re.findall(r"`rigcal (\w+)`", _section(page.read_text(), section)))
        assert named == commands, (page.name, commands ^ named)
