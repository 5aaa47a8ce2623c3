"""Interrupts requested from outside the computation (the command line's signal handlers).

A signal handler raises its exception wherever the main thread happens to be, and some code
there does not let it through: a weakref callback or a ``__del__`` reports it as "ignored",
a C extension being imported turns it into ``ImportError``, a library's ``except`` may drop
it. So the handler also records it here, and every commit of output (:mod:`rigcal.io.atomic`,
the bag writer) calls :func:`raise_if_requested` before its rename: a swallowed interrupt
still stops the output from being published. Light module: the standard library only.
"""

from __future__ import annotations

_requested: list[type[BaseException]] = []


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
