"""Interrupts requested from outside the computation (the command line's signal handlers).

A signal handler raises its exception wherever the main thread happens to be, and some code
there does not let it through: a weakref callback or a ``__del__`` reports it as "ignored",
a C extension being imported turns it into ``ImportError``, a library's ``except`` may drop
it. So the handler also records it here, and every commit of output (:mod:`rigcal.io.atomic`,
the bag writer) calls :func:`raise_if_requested` before its rename: a swallowed interrupt
still stops the output from being published. Light module: the standard library only.

Code that must not be cut in half - starting or stopping a Dask cluster, where an interrupt
raised part-way leaves worker processes that nothing closes - runs in :func:`deferred`: a
signal arriving there is only recorded, and raised when the block ends.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

_requested: list[type[BaseException]] = []
_deferring: list[bool] = []


def request(exc_type: type[BaseException]) -> None:
    """Record that the run was interrupted; later commits raise ``exc_type()``."""
    _requested.append(exc_type)


def requested() -> type[BaseException] | None:
    """The first interrupt recorded (its exception type), or None."""
    return _requested[0] if _requested else None


def clear() -> None:
    """Forget recorded interrupts (at the start of a command-line run)."""
    _requested.clear()


def raise_if_requested() -> None:
    """Raise the recorded interrupt again, if there is one (call before publishing output)."""
    if _requested:
        raise _requested[0]()


def deferring() -> bool:
    """True inside :func:`deferred`: a signal handler should only :func:`request`, not raise."""
    return bool(_deferring)


@contextmanager
def deferred(raise_after: bool = True) -> Iterator[None]:
    """Run the block without being interrupted part-way: a signal received in it is recorded
    (the command line's handlers check :func:`deferring`) and, with ``raise_after``, raised when
    the block ends normally; without it the run stops at its next commit, as for a swallowed
    interrupt (for clean-up code that runs while an exception is already on its way)."""
    _deferring.append(True)
    try:
        yield
    finally:
        _deferring.pop()
    if raise_after:
        raise_if_requested()
