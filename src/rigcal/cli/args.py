"""Argument types that check the range of command-line numbers (argparse turns a refusal into a
usage error, exit code 2, naming the option)."""

from __future__ import annotations

import argparse
import math
import re
import textwrap
from collections.abc import Callable


def count(lo: int, hi: int) -> Callable[[str], int]:
    """An integer option within ``[lo, hi]``."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= n <= hi:
            raise argparse.ArgumentTypeError(f"expected {lo} to {hi}, got {n}")
        return n

    parse.__name__ = "integer"
    return parse


def number(lo: float = 0.0, hi: float = math.inf) -> Callable[[str], float]:
    """A finite number within ``[lo, hi]``."""

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (math.isfinite(x) and lo <= x <= hi):
            raise argparse.ArgumentTypeError(f"expected a finite number from {lo:g} to {hi:g}, got {text}")
        return x

    parse.__name__ = "number"
    return parse


def add_verbose(parser: argparse.ArgumentParser) -> None:
    """``-v/--verbose`` on a subcommand too, so it may follow the subcommand's name; the default
    is left to the top-level parser (``rigcal -v calibrate ...`` stays verbose)."""
    parser.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="log each stage with its time to stderr (also before the command's name)")


class WrappedHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help wrapped to the terminal's width (argparse reads it, ``COLUMNS`` too): the
    description's and epilog's prose paragraphs (runs of lines that do not start with a space)
    are re-wrapped; indented lines - examples, tables - and blank lines stay as written, so that
    a command can be copied whole."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        out: list[str] = []
        paragraph: list[str] = []

        def flush() -> None:
            if paragraph:
                out.append(textwrap.fill(" ".join(paragraph), width, initial_indent=indent,
                                         subsequent_indent=indent, break_on_hyphens=False,
                                         break_long_words=False))
                paragraph.clear()

        for line in text.splitlines():
            if line.strip() and not line[0].isspace() and not line.rstrip().endswith(":"):
                paragraph.append(line.strip())
                continue
            flush()
            if not line.strip():
                out.append("")
            elif line[0].isspace() and not line.lstrip().startswith(("rigcal ", "python ", "make ", "pip ")):
                # an indented row ("  3    flagged: ..."): wrapped under its second column
                head = re.match(r"\s+\S+\s{2,}|\s+", line).group(0)
                out.append(textwrap.fill(line[len(head):], width, initial_indent=indent + head,
                                         subsequent_indent=indent + " " * len(head), break_on_hyphens=False,
                                         break_long_words=False))
            else:  # a command to copy, or a heading: as written
                out.append(indent + line)
        flush()
        return "\n".join(out)


def subcommand(sub, name: str, **kwargs) -> argparse.ArgumentParser:
    """``sub.add_parser(name, ...)`` with the description and epilog wrapped to the terminal
    (:class:`WrappedHelpFormatter`) and ``-v/--verbose``."""
    kwargs.setdefault("formatter_class", WrappedHelpFormatter)
    parser = sub.add_parser(name, **kwargs)
    add_verbose(parser)
    return parser
