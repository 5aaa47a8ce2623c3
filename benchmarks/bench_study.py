"""Wall time of the Prius study's Table III (``rigcal study prius --table III``): in this process
vs on a Dask LocalCluster, with the draws per second.

In-process, the same library calls the command makes (reading the manifest once); the Dask run
includes starting and closing the cluster (one single-threaded worker process per core) and
checks that its rows equal the serial run's exactly. Timings on a shared machine are noisy:
repeat with --repeat and quote the median.
Usage: python benchmarks/bench_study.py [--draws 200] [--boards 10] [--repeat 1] [--workers N]
(needs ../shared beside the repository)
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

MANIFEST = Path(__file__).resolve().parents[1] / "examples" / "prius" / "rig.yaml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--boards", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--workers", type=int, default=None, help="local cluster workers (default: cores)")
    ap.add_argument("--skip-serial", action="store_true")
    args = ap.parse_args()
    if not (MANIFEST.parents[3] / "shared" / "data").is_dir():
        print("../shared/data not found beside the repository")
        return 1
    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.study import prius
    from rigcal.study.scale import task_runner

    dataset = load_manifest(MANIFEST)
    calibrations = args.draws * len(prius.configurations(dataset))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"python {platform.python_version()}, {os.cpu_count()} cpu(s), {platform.processor() or platform.machine()}, "
          f"load average {load:.1f}")
    print(f"Table III: {args.draws} draws x {len(prius.configurations(dataset))} configurations = "
          f"{calibrations} calibrations of {args.boards} boards")
    times: dict[str, list[float]] = {}
    rows: dict[str, list] = {}
    kinds = (["serial"] if not args.skip_serial else []) + ["local"]
    for _ in range(args.repeat):
        for kind in kinds:
            t0 = time.perf_counter()
            with task_runner(kind, workers=args.workers) as runner:
                rows[kind] = prius.table_iii(dataset, draws=args.draws, k=args.boards, runner=runner)
                where = runner.description
            times.setdefault(kind, []).append(time.perf_counter() - t0)
            print(f"  {where:<40} {times[kind][-1]:7.1f} s  {calibrations / times[kind][-1]:6.2f} calibrations/s  "
                  f"{args.draws / times[kind][-1]:5.2f} draws/s", flush=True)
    if "serial" in rows and rows["serial"] != rows["local"]:
        print("DIFFERENT rows serial vs Dask")
        return 1
    for kind in kinds:
        t = statistics.median(times[kind])
        print(f"median {kind:<7} {t:7.1f} s ({args.draws / t:.2f} draws/s)")
    if "serial" in times:
        speedup = statistics.median(times["serial"]) / statistics.median(times["local"])
        print(f"Dask speed-up {speedup:.2f}x; rows identical to the serial run's")
    return 0


if __name__ == "__main__":
    sys.exit(main())
