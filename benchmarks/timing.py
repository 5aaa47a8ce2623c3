"""Shared timing helper of the benchmark scripts (run as ``python benchmarks/<script>.py``)."""

from __future__ import annotations

import statistics
import subprocess
import time
from pathlib import Path
from typing import Callable, Sequence


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what ``platform`` knows: for the machine line
    every benchmark prints."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def median_ms(fn: Callable[[], object], runs: int) -> float:
    """Median wall time of ``fn()`` over ``runs`` calls after one warm-up call [ms]."""
    fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1000


def compile_bytecode() -> None:
    """Compile rigcal's modules to bytecode, as a normal ``pip install`` does: an editable install
    under ``PYTHONDONTWRITEBYTECODE=1`` (set on some machines) would otherwise compile every
    module again in every process, ~0.2 s the user never pays."""
    import compileall

    import rigcal

    compileall.compile_dir(str(Path(rigcal.__file__).parent), quiet=1)


def process_wall_times(cmd: Sequence[str] | Callable[[int], Sequence[str]], runs: int) -> list[float]:
    """Wall times [s] of ``runs`` runs of the command ``cmd`` (or ``cmd(k)`` for run ``k``),
    each a new process with its output discarded; a failing run raises."""
    times = []
    for k in range(runs):
        argv = cmd(k) if callable(cmd) else cmd
        t0 = time.perf_counter()
        subprocess.run(list(argv), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times
