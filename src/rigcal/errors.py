"""One error hierarchy for the whole library.

Every message names the file, field, sensor or frame at fault and what was expected.
The CLI turns any :class:`RigcalError` into one line on stderr and exit code 1.
"""

from __future__ import annotations


class RigcalError(Exception):
    """Base class of every error rigcal raises on purpose."""


class InputError(RigcalError):
    """A user's file, field or argument is missing, malformed or inconsistent."""


class ConfigError(InputError):
    """A configuration value (mode, reference sensor, option) is not allowed."""


class GeometryError(RigcalError):
    """A geometric estimate is impossible (degenerate points, too few correspondences)."""


class ConvergenceError(RigcalError):
    """An optimisation did not converge; no result is returned.

    ``sensor`` names the one sensor at fault when the failure is that sensor's alone (its
    measurements leave its pose undetermined), so a caller may go on without it; None when
    the problem as a whole failed."""

    def __init__(self, *args: object, sensor: str | None = None) -> None:
        super().__init__(*args)
        self.sensor = sensor


def printable(text: object) -> str:
    """``str(text)`` on one line: control characters (newline, tab, carriage return, NUL, escape
    and the other C0/C1 codes, line and paragraph separators) written as Python escapes
    (``\\n``, ``\\t``, ``\\x00``, ...), so that a message quoting a hostile file or folder name
    stays one line and shows what is really there."""
    s = str(text)
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in s)
