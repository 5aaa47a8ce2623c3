"""Time the start of the ``rigcal`` command line (a fresh interpreter per run).

Prints the min / median / max wall time of ``rigcal --version``, ``rigcal --help`` and
``rigcal calibrate --help`` over ``--runs`` runs (default 10), each a new process running
``python -m rigcal.cli.main`` with this interpreter (so the sources on PYTHONPATH are timed, not
whatever ``rigcal`` is first on PATH).
Usage: python benchmarks/bench_cli_start.py [--runs N]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys

from timing import compile_bytecode, process_wall_times

COMMANDS = (["--version"], ["--help"], ["calibrate", "--help"])


def wall_times(argv: list[str], runs: int) -> list[float]:
    return process_wall_times([sys.executable, "-m", "rigcal.cli.main", *argv], runs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    compile_bytecode()
    print(f"python {platform.python_version()}, {os.cpu_count()} cpu(s), {platform.processor() or platform.machine()}")
    print(f"{'command':<26} {'min':>7} {'median':>7} {'max':>7}  (s, {args.runs} runs)")
    for argv in COMMANDS:
        wall_times(argv, 1)  # warm the file cache and the bytecode
        t = wall_times(argv, args.runs)
        name = "rigcal " + " ".join(argv)
        print(f"{name:<26} {min(t):7.3f} {statistics.median(t):7.3f} {max(t):7.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
