"""Argument types that check the range of command-line numbers (argparse turns a refusal into a
usage error, exit code 2, naming the option)."""

from __future__ import annotations

import argparse
import math
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
                        help="log progress to stderr (also before the command's name)")


def subcommand(sub, name: str, **kwargs) -> argparse.ArgumentParser:
    """``sub.add_parser(name, ...)`` with the description and epilog printed as written and
    ``-v/--verbose``."""
    kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
    parser = sub.add_parser(name, **kwargs)
    add_verbose(parser)
    return parser
