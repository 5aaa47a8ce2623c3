"""Power and false alarms of ``rigcal check`` on a simulated fleet, and its speed.

The fleet (:mod:`rigcal.study.fleet`): N vehicles from the coverage benchmark's rig population
(2 lidars, 2 cameras, 2 2D radars, unequal noise), each calibrated with FCPE on 15 boards; then
checked on new boards (10, and 4) twice: as it is, and with one sensor moved by 2-30 mm and
0.1-2 deg (half of the 2D radars picked: only along/about the directions they do not measure,
which no check can detect). A fleet with 10 % moved vehicles takes the moved check for those.

Prints, per board count: the false-alarm rate (goal <= 5 % at the 95 % level), the detection
rate of moves larger than 3 sigma of the stored calibration (goal >= 95 %) and by size, the
sensor named right, the unmeasured radar moves flagged, an ROC (thresholds on the smallest
Bonferroni-adjusted p-value against false-alarm and detection rates), the compute time of one
check, and the wall time of ``rigcal check --batch`` over the N-vehicle fleet on a local Dask
cluster (goal: one check on 10 boards <= 0.2 s, 200 vehicles <= 60 s on 2 cores).

Usage: nice python benchmarks/fleet.py [--vehicles 200] [--seed 0] [--workers 2] [--roc-png roc.png]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from timing import cpu_model

THRESHOLDS = (0.001, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


def _calibrate(seed, index):
    from rigcal.errors import RigcalError
    from rigcal.study.fleet import simulate_vehicle

    try:
        return simulate_vehicle(seed, index)
    except RigcalError as exc:
        return str(exc)


def _check(seed, vehicle):
    from rigcal.study.fleet import check_vehicle

    return check_vehicle(vehicle, seed, (10, 4))


def _pct(x: float) -> str:
    return "  -  " if x != x else f"{100 * x:5.1f} %"


def _machine() -> str:
    return f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()}, python {platform.python_version()}"


def fleet_cli_time(vehicles, seed: int, out_root: Path, moved_fraction: float) -> tuple[float, int, dict]:
    """Wall time of ``rigcal check --batch`` (local Dask cluster) over the fleet's data on 10
    boards, written as a user would have it: OUT/calib/<car>/calibration.yaml, OUT/week/<car>/."""
    import json

    from rigcal.cli.main import run
    from rigcal.io.dataset.manifest import write_dataset
    from rigcal.io.results.calibration import write_results
    from rigcal.study.fleet import fleet_dataset, moved_vehicles

    moved = moved_vehicles([v.index for v in vehicles], moved_fraction, seed)
    truth = {}
    for v in vehicles:
        name = f"car{v.index:03d}"
        write_results(v.result, out_root / "calib" / name)
        data, sensor = fleet_dataset(v, seed, 10, v.index in moved)
        write_dataset(data, out_root / "week" / name)
        truth[name] = sensor
    argv = ["check", "--batch", *sorted(str(p) for p in (out_root / "week").iterdir()), "--calibrations",
            str(out_root / "calib"), "--out", str(out_root / "fleet"), "--scheduler", "local"]
    import contextlib
    import io

    import resource

    def cpu() -> float:
        return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                      resource.getrusage(resource.RUSAGE_CHILDREN)))

    t0, c0 = time.perf_counter(), cpu()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = run(argv)
    wall, cpu_s = time.perf_counter() - t0, cpu() - c0
    summary = json.loads((out_root / "fleet" / "fleet.json").read_text())
    found = {v["vehicle"]: v for v in summary["vehicles"]}
    named = sum(1 for n, s in truth.items() if s and found[n]["status"] == "moved" and found[n]["sensor"] == s)
    alarms = sum(1 for n, s in truth.items() if not s and found[n]["status"] == "moved")
    return wall, code, {"cpu_s": cpu_s, "moved": sum(1 for s in truth.values() if s), "moved_named_right": named,
                        "false_alarms": alarms, "unmoved": sum(1 for s in truth.values() if not s)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--moved-fraction", type=float, default=0.1)
    ap.add_argument("--roc-png", help="also draw the ROC into this PNG")
    ap.add_argument("--no-cli", action="store_true", help="skip the timed rigcal check --batch run")
    ap.add_argument("--save", metavar="PICKLE", help="also save the vehicles and every check's record there")
    ap.add_argument("--load", metavar="PICKLE", help="take the vehicles from a --save file instead of calibrating")
    args = ap.parse_args()

    from rigcal.study.fleet import fleet_rates, roc
    from rigcal.study.scale import task_runner

    print(f"machine: {_machine()}; load average at start {os.getloadavg()[0]:.1f}")
    t0 = time.perf_counter()
    import pickle

    with task_runner("local", workers=args.workers) as runner:
        if args.load:
            with open(args.load, "rb") as f:
                vehicles = pickle.load(f)["vehicles"][: args.vehicles]
            print(f"{len(vehicles)} vehicles from {args.load}")
        else:
            made = runner.map(_calibrate, list(range(args.vehicles)), shared=args.seed, name="calibrate")
            vehicles = [v for v in made if not isinstance(v, str)]
            t_cal = time.perf_counter() - t0
            print(f"{len(vehicles)} vehicles calibrated ({len(made) - len(vehicles)} calibrations failed) in "
                  f"{t_cal:.0f} s on {runner.description}")
        t1 = time.perf_counter()
        rows = [r for part in runner.map(_check, vehicles, shared=args.seed, name="check") for r in part]
        print(f"{len(rows)} checks in {time.perf_counter() - t1:.0f} s")
    if args.save:
        with open(args.save, "wb") as f:
            pickle.dump({"vehicles": vehicles, "rows": rows}, f)
    for K in (10, 4):
        f = fleet_rates(rows, K, args.moved_fraction, args.seed)
        print(f"\n--- {K} boards per check ---")
        print(f"false alarms (every vehicle checked unchanged, {f['vehicles']}): {_pct(f['false_alarm'])}   "
              f"(goal <= 5 %); 'cannot tell' somewhere: {_pct(f['clean_cannot_tell'])}")
        print(f"moves > 3 sigma of the stored calibration found: {_pct(f['detection'])} of {f['detectable_moves']}"
              "   (goal >= 95 %)")
        print("  by size (sigma of the stored calibration): " + ", ".join(
            f"{k}: {_pct(v)}" for k, v in f["detection_by_sigma"].items()))
        print(f"  moves larger than the check's own quoted detectable translation found: "
              f"{_pct(f['detection_beyond_quoted'])}   (it quotes 80 % power)")
        print(f"sensor named right (found moves): {_pct(f['named_right'])}; right or among the named alternatives: "
              f"{_pct(f['named_right_or_alternative'])}")
        print(f"2D radars moved only in unmeasured directions: {f['unmeasured_moves']}, called moved: "
              f"{_pct(f['unmeasured_flagged'])}")
        print(f"the fleet ({f['fleet_moved_vehicles']} of {f['vehicles']} moved): false alarms "
              f"{_pct(f['fleet_false_alarm'])}, moves > 3 sigma found {_pct(f['fleet_detection'])}")
        print(f"per check (clean and moved): CPU median {f['cpu_s_median']:.3f} s, max {f['cpu_s_max']:.3f} s; "
              f"wall median {f['compute_s_median']:.3f} s, max {f['compute_s_max']:.3f} s")
        print("ROC (vehicle called moved when its smallest adjusted p-value < threshold):")
        print("  threshold  false alarms  moves > 3 sigma found")
        for r in roc(rows, K, THRESHOLDS):
            print(f"  {r['threshold']:9g}  {_pct(r['false_alarm']):>12}  {_pct(r['detection']):>21}")
    clean10 = sorted(r["cpu_s"] for r in rows if r["boards"] == 10 and r["case"] == "clean" and "cpu_s" in r)
    moved10 = sorted(r["cpu_s"] for r in rows if r["boards"] == 10 and r["case"] == "moved" and "cpu_s" in r)
    print(f"\none check on 10 boards (CPU time in a worker): unchanged rig median {clean10[len(clean10) // 2]:.3f} s, "
          f"moved median {moved10[len(moved10) // 2]:.3f} s, slowest {max(clean10 + moved10):.3f} s   (goal <= 0.2 s)")
    if args.roc_png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 4))
        for K in (10, 4):
            pts = roc(rows, K, [10 ** (e / 10) for e in range(-60, 1)])
            ax.plot([p["false_alarm"] for p in pts], [p["detection"] for p in pts], label=f"{K} boards")
        ax.set_xlabel("false-alarm rate")
        ax.set_ylabel("moves > 3 sigma found")
        ax.legend()
        fig.savefig(args.roc_png, dpi=100, bbox_inches="tight")
        print(f"ROC drawn: {args.roc_png}")
    if not args.no_cli:
        with tempfile.TemporaryDirectory() as tmp:
            wall, code, found = fleet_cli_time(vehicles, args.seed, Path(tmp), args.moved_fraction)
        print(f"load average now {os.getloadavg()[0]:.1f} (the CPU is shared)")
        print(f"rigcal check --batch over {len(vehicles)} vehicles (10 boards, local Dask cluster, {os.cpu_count()} "
              f"workers, reading, checking and writing every report): {wall:.1f} s wall, {found['cpu_s']:.1f} s CPU "
              f"(this process and its workers), exit {code}   (goal <= 60 s on 2 cores); "
              f"{found['moved_named_right']} of {found['moved']} moved vehicles named right, "
              f"{found['false_alarms']} false alarms in {found['unmoved']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
