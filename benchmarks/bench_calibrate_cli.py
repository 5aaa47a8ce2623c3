"""End-to-end time of ``rigcal calibrate`` on the shared Prius detections (29 boards).

Each run is a new process (interpreter start, imports, reading the manifest, calibrating with
cross-validation, the consistency check, writing the result set), as a user runs it. Prints
min / median / max wall time per mode, without and with ``--plot``.
Usage: python benchmarks/bench_calibrate_cli.py [--runs N]   (needs ../shared beside the repo)
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path

from timing import compile_bytecode, process_wall_times

MANIFEST = Path(__file__).resolve().parents[1] / "examples" / "prius" / "rig.yaml"


def wall_times(argv: list[str], runs: int) -> list[float]:
    with tempfile.TemporaryDirectory() as tmp:
        return process_wall_times(
            lambda k: [sys.executable, "-m", "rigcal.cli.main", *argv, "--out", f"{tmp}/out{k}"], runs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    if not (MANIFEST.parent.parents[2] / "shared" / "data").is_dir():
        print("../shared/data not found beside the repository")
        return 1
    compile_bytecode()
    print(f"python {platform.python_version()}, {os.cpu_count()} cpu(s), {platform.processor() or platform.machine()}")
    print(f"{'rigcal calibrate (29 boards)':<36} {'min':>6} {'median':>6} {'max':>6}  (s, {args.runs} runs)")
    for mode in ("fcpe", "mcpe", "pse"):
        for extra in ([], ["--plot"]):
            argv = ["calibrate", str(MANIFEST), "--mode", mode, *extra]
            wall_times(argv, 1)  # warm the file cache and the bytecode
            t = wall_times(argv, args.runs)
            name = f"--mode {mode} {' '.join(extra)}"
            print(f"{name:<36} {min(t):6.2f} {statistics.median(t):6.2f} {max(t):6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
