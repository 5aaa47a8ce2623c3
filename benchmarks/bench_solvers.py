"""Time each calibration mode in-process on the real Prius detections (../shared/data).

Prints a table of median wall time over several runs for the full `calibrate()` call (Kabsch
initialisation, RANSAC/robust outlier screening, the solve, covariance and per-pair errors;
no cross-validation), and for the bare solve of the configuration.
Usage: python benchmarks/bench_solvers.py [--runs N]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time

from prius_data import DATA, prius_dataset
from threadpoolctl import threadpool_limits

from rigcal.problem.calibrate import CalibrationOptions, _fit, calibrate
from rigcal.problem.initialise import initial_poses



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    ds = prius_dataset()
    if ds is None:
        return 1
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()}, "
          f"python {platform.python_version()}")
    print(f"data: {DATA} ({ds.num_boards} boards, sensors {', '.join(ds.names)})")
    print(f"{'mode':6} {'calibrate() median [ms]':>24} {'solve only median [ms]':>24}  RMSE [mm]")
    for mode in ("mcpe", "fcpe", "pse"):
        full, bare = [], []
        result = None
        for _ in range(args.runs):
            t = time.perf_counter()
            result = calibrate(ds, CalibrationOptions(mode=mode))
            full.append(time.perf_counter() - t)
        opts = CalibrationOptions(mode=mode)
        with threadpool_limits(limits=1):
            init = initial_poses(ds, "lidar1")
            for _ in range(args.runs):
                t = time.perf_counter()
                _fit(ds, mode, "lidar1", init, opts)
                bare.append(time.perf_counter() - t)
        rm = " / ".join(f"{v * 1000:.3f}" for v in result.rmse_m.values())
        print(f"{mode:6} {statistics.median(full) * 1000:24.1f} {statistics.median(bare) * 1000:24.1f}  {rm}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
