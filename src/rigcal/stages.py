"""The stages of a run, logged with their times (what ``rigcal -v`` shows on stderr).

The library logs at INFO on the ``rigcal`` loggers and never prints; the command line shows
those records with ``-v`` (:func:`verbose_logging`). A stage is timed either as a block
(:func:`stage`) or as a lap of a :class:`StageClock` (one line at each stage's end, so that a
long function needs no extra indentation)::

    clock = StageClock(log)
    fit = ...
    clock.lap("fit")              # "fit: 0.41 s"
"""

from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager
from typing import Iterator

log = logging.getLogger("rigcal")


class StageClock:
    """Logs each stage's time since the previous one (or since the clock was made)."""

    def __init__(self, logger: logging.Logger = log) -> None:
        self.logger = logger
        self.last = time.perf_counter()

    def lap(self, what: str) -> float:
        """Log ``what: <seconds> s`` at INFO; returns the seconds."""
        now = time.perf_counter()
        seconds, self.last = now - self.last, now
        self.logger.info("%s: %.2f s", what, seconds)
        return seconds


@contextmanager
def stage(what: str, logger: logging.Logger = log) -> Iterator[None]:
    """Log ``what ...`` when the block starts and ``what: <seconds> s`` when it ends (also
    when it fails: ``what: stopped after <seconds> s``)."""
    logger.info("%s ...", what)
    t0 = time.perf_counter()
    try:
        yield
    except BaseException:
        logger.info("%s: stopped after %.2f s", what, time.perf_counter() - t0)
        raise
    logger.info("%s: %.2f s", what, time.perf_counter() - t0)


class _Elapsed(logging.Formatter):
    """INFO records as ``[  1.23 s] message`` (seconds since the run started); warnings as
    ``warning: message``."""

    def __init__(self, start: float) -> None:
        super().__init__()
        self.start = start

    def format(self, record: logging.LogRecord) -> str:
        message = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"{record.levelname.lower()}: {message}"
        return f"[{time.perf_counter() - self.start:7.2f} s] {message}"


@contextmanager
def verbose_logging(enabled: bool, stream=None) -> Iterator[None]:
    """While the block runs, with ``enabled``: rigcal's INFO records (its stages) and warnings
    go to ``stream`` (default: stderr), each with the seconds since the block started; other
    libraries' records are left to the root logger's handlers. Without ``enabled``: nothing
    changes."""
    if not enabled:
        yield
        return
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler.setFormatter(_Elapsed(time.perf_counter()))
    level, propagate = log.level, log.propagate
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.setLevel(level)
        log.propagate = propagate


__all__ = ["StageClock", "stage", "verbose_logging"]
