"""``rigcal`` command line: parse -> run(args) -> int. Known errors become one line, exit 1.

Each subcommand is a module of :mod:`rigcal.cli` (``calibrate``, ``check``, ``diff``,
``detect``, ``absolute``, ``mocap``, ``report``, ``study``, ``urdf``, ``export``, ``demo``) with
``add_parser(subparsers)`` and ``run(args, console)``; a module imports numpy, scipy, OpenCV,
rosbags, matplotlib and rich only inside ``run``, so ``rigcal --help`` and ``rigcal COMMAND
--help`` start fast.

Exit codes: 0 calibrated and consistent; 1 error (bad input, or the data cannot determine the
result); 2 command-line usage; 3 the result contradicts its own noise model (flagged by the
consistency check): nothing is written unless --force, which writes it with the verdict;
4 partial (``rigcal mocap``): the other sensors were calibrated and written, but at least one
sensor could not be and is reported as not calibrated with its reason (3 takes precedence);
5 undetermined: a sensor's pose is not determined to its kind's bound (nothing written unless
--force; 3 takes precedence); 6 moved (``rigcal check`` / ``diff``: a sensor moved since it was
calibrated); 7 cannot tell (``check`` / ``diff``: no sensor moved, but some could not be told);
130 interrupted (Ctrl-C); 143 terminated (SIGTERM).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from typing import Sequence

from rigcal import __version__, interrupts
from rigcal.cli.args import WrappedHelpFormatter
from rigcal.cli import absolute, calibrate, check, demo, detect, diff, export, mocap, report, study, urdf
from rigcal.cli.codes import (
    EXIT_CODES_HELP,
    EXIT_FLAGGED,
    EXIT_INTERRUPTED,
    EXIT_PARTIAL,
    EXIT_TERMINATED,
    Terminated,
)
from rigcal.errors import RigcalError, printable

__all__ = ["EXIT_FLAGGED", "EXIT_INTERRUPTED", "EXIT_PARTIAL", "EXIT_TERMINATED", "Terminated", "entry", "run"]

#: the subcommands, in the order ``rigcal --help`` lists them
COMMANDS = (calibrate, check, diff, detect, absolute, mocap, report, study, urdf, export, demo)

EPILOG = f"""Run `rigcal COMMAND --help` for a command's options; -v/--verbose may come before or
after COMMAND.

{EXIT_CODES_HELP}"""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rigcal",
        description="Joint extrinsic calibration of lidar, camera and radar rigs.",
        epilog=EPILOG,
        formatter_class=WrappedHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"rigcal {__version__}")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="log each stage of the command with its time to stderr")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def run(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code.

    A :class:`RigcalError` is one line on stderr and exit code 1; Ctrl-C and SIGTERM print
    "interrupted" and return 130 / 143 (outputs are written as whole sets, so nothing
    half-written is left). numpy's floating-point RuntimeWarnings are not shown (each result
    carries its own checks); with ``-v`` an unexpected internal error shows its traceback.
    """
    import warnings

    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    if args.command is None:
        parser.print_help()
        return 2
    try:
        from rigcal.cli.output import make_console

        if getattr(args, "out", None):  # refuse an unusable --out before any work
            from rigcal.io.limits import path_stat

            path_stat(args.out, "--out")

        # with --json, stdout carries only the JSON; the human summary goes to stderr
        console = make_console(to_stderr=bool(getattr(args, "json", False)))
        from rigcal.stages import stage, verbose_logging

        with warnings.catch_warnings(), verbose_logging(args.verbose):
            if not args.verbose:
                warnings.simplefilter("ignore", RuntimeWarning)
            with stage(f"rigcal {args.command}"):
                code = args.func(args, console)
        if interrupts.requested():  # the interrupt was swallowed, yet the command finished
            return _interrupted(interrupts.requested())
        return code
    except RigcalError as exc:
        sys.stderr.write(f"rigcal: error: {printable(exc)}\n")
        return 1
    except KeyboardInterrupt:
        return _interrupted(KeyboardInterrupt)
    except Terminated:
        return _interrupted(Terminated)
    except MemoryError:
        sys.stderr.write(f"rigcal: error: out of memory in '{args.command}' (an input too large?)\n")
        return 1
    except RecursionError:
        sys.stderr.write(f"rigcal: error: input nested too deeply for '{args.command}'\n")
        return 1
    except ModuleNotFoundError as exc:
        # an optional package (rigcal.extras) imported where no early check named it
        from rigcal.extras import missing_extra_message

        if interrupts.requested():
            return _interrupted(interrupts.requested())
        message = missing_extra_message(exc.name or "", f"'rigcal {args.command}'")
        if message is None:
            raise
        sys.stderr.write(f"rigcal: error: {message}\n")
        return 1
    except Exception:
        # The interrupt can arrive inside code that turns any exception into its own: a C
        # extension being imported reports "ImportError: initialization failed". Once a signal
        # has been received, whatever surfaces is the interrupt, not an internal error.
        if interrupts.requested():
            return _interrupted(interrupts.requested())
        raise


def _interrupted(exc_type: type[BaseException]) -> int:
    """The one line and the exit code of an interrupt (KeyboardInterrupt, from SIGINT) or a
    termination (Terminated, from SIGTERM)."""
    if exc_type is KeyboardInterrupt:
        sys.stderr.write("\nrigcal: interrupted (nothing half-written is left)\n")
        return EXIT_INTERRUPTED
    sys.stderr.write("rigcal: terminated (nothing half-written is left)\n")
    return EXIT_TERMINATED


def _on_signal(signum, frame) -> None:
    """Record the signal (:mod:`rigcal.interrupts`: the output commits check it too), then
    raise it in the main thread as KeyboardInterrupt / Terminated."""
    exc_type = KeyboardInterrupt if signum == signal.SIGINT else Terminated
    interrupts.request(exc_type)
    if interrupts.deferring():  # e.g. a Dask cluster starting: raised when it is whole
        return
    raise exc_type()


def _unraisable(hook_args) -> None:
    """An interrupt raised where Python can only ignore it (a weakref callback, ``__del__``) is
    not printed as a traceback: it was recorded, and the run stops at its next commit."""
    if isinstance(hook_args.exc_value, (KeyboardInterrupt, Terminated)) and interrupts.requested():
        return
    sys.__unraisablehook__(hook_args)


def entry() -> None:
    interrupts.clear()
    sys.unraisablehook = _unraisable
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    try:
        code = run()
    except KeyboardInterrupt:  # Ctrl-C while the arguments were parsed
        sys.stderr.write("\nrigcal: interrupted\n")
        code = EXIT_INTERRUPTED
    except Terminated:  # SIGTERM while the arguments were parsed
        sys.stderr.write("rigcal: terminated\n")
        code = EXIT_TERMINATED
    except SystemExit as exc:  # argparse: --help, --version, a usage error (its message printed)
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if not isinstance(exc.code, (int, type(None))):
            sys.stderr.write(f"{exc.code}\n")
    while True:
        try:
            _exit_now(code)  # does not return
        except (KeyboardInterrupt, Terminated) as exc:
            # The signal landed after the run ended but before _exit_now took the signals over
            # (seen in CI: a SIGTERM 20 ms after the output was published printed a traceback).
            # The output is complete; the run ends with the signal's line and code.
            code = _interrupted(type(exc))


def _exit_now(code: int) -> None:
    """End the run without the interpreter's finalization, whose teardown a signal must not
    cut short: Python puts the default signal handlers back there, so a SIGTERM that landed
    after the output was published killed the process with no line (exit -15). From here on
    a signal is only noted; one that arrives before the end makes it exit 130 / 143 with its
    line (the output stays, complete).

    A run that finished runs its exit handlers (``atexit``); an interrupted one only
    multiprocessing's (the semaphores of a Dask cluster's workers, else reported as leaked):
    its outputs were removed or left whole on the way out (staged folders, atomic files, the
    Dask cluster in its ``with``), and an interrupt that landed while an extension module was
    being imported can leave it half initialised - its teardown then aborts the process (seen
    once in CI: "Fatal Python error: PyThreadState_Get" after "rigcal: interrupted", exit -6
    instead of 130)."""
    import atexit
    import os

    late: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, lambda signum, frame: late.append(signum))
        except ValueError:  # not the main thread (an embedding application): nothing to guard
            pass
    if interrupts.requested():
        mp = sys.modules.get("multiprocessing.util")
        if mp is not None:
            try:
                mp._exit_function()
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        logging.shutdown()
    else:
        atexit._run_exitfuncs()
        if late:
            code = _interrupted(KeyboardInterrupt if late[0] == signal.SIGINT else Terminated)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
