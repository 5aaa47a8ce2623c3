"""Coverage of the reported uncertainty: how often the truth lies inside the reported 95 % region.

Board modes: random 6-sensor rigs (2 lidars, 2 cameras, 2 2D radars) with unequal noise per
sensor kind (lidar 4 mm, camera 20 mm lateral + 2 mm depth at 1 m growing with range squared,
radar 30 mm range, 0.3 deg azimuth), 15 boards; the reference is the first lidar, so 5 sensors
are judged per trial and mode (:mod:`rigcal.study.board_coverage`), and every relative transform
between two of them. With priors (the default runs both): every non-reference sensor's nominal
mounting is drawn around the truth with the stated tolerance (lidar and camera 2 cm / 1 deg in
every direction, 2D radar z 2 cm, roll and pitch 1 deg) and calibrated with that prior
(``--initial`` + ``prior``). Motion capture: simulated
sessions with sensor noise unlike what the sensors are told, per-hold MCS errors and corner
biases (:func:`rigcal.study.coverage.mocap_coverage`), next to the old covariance.

Goal: 0.90 - 0.98 everywhere.
Motion capture is run under every error model of :data:`rigcal.study.coverage.ERROR_MODELS`
(errors drawn from other models than the calibration's own: MCS noise per capture, per-hold
bias, pixel noise, lidar range noise, timing jitter, a clock offset, all at once); the goal
there is 0.90 - 0.98 inside and a median NEES per degree of freedom within 0.5 - 2, per sensor
kind.
Usage: python benchmarks/coverage.py [--trials N] [--seed S] [--modes mcpe,fcpe,pse] [--priors both|off|only]
       [--mocap-trials N] [--mocap-models pixel,...] [--mocap-holds N] [--mocap-hold-floor R,T]
       [--mocap-json PATH] (--trials 0: mocap only)
       python benchmarks/coverage.py --pool RUN.json [RUN.json ...] (the runs' coverage pooled)
Each motion-capture fraction is also printed as a count with its 95 % Wilson interval: what that
many sessions can tell of the coverage.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from rigcal.errors import InputError
from rigcal.io.atomic import atomic_write_text
from rigcal.study.board_coverage import PriorSpec, board_coverage
from rigcal.problem.mocap import ESTIMATORS, MocapOptions
from rigcal.study.coverage import ERROR_MODELS, pool_mocap, wilson


def _row(label: str, f: dict) -> str:
    kinds = "  ".join(
        f"{k} {v['position']:.2f}/{v['pose']:.2f} (n={v['sensors']})" for k, v in f["by_kind"].items()
    )
    return (f"{label:12} {f['position']:9.3f} {f['pose']:9.3f} {f['relative']:9.3f} {f['sensors']:8d} "
            f"{f['relatives']:5d} {f['failures']:5d}/{f['runs']:<4d} {f['flagged']:5d}/{f['runs']:<4d}  {kinds}")


def _floor(text: str) -> tuple[float, float]:
    try:
        r, t = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected rotation_rad,translation_m, got {text!r}") from None
    return r, t


def _count(v: dict) -> str:
    """How many truths of how many lie inside, and the fraction's 95 % Wilson interval: what a
    sample of this size can tell of the coverage."""
    n = int(v["checks"])
    if not n:
        return "0 of 0"
    k = round(v["inside_6dof"] * n)
    lo, hi = wilson(k, n)
    return f"{k} of {n}, 95 % interval {lo:.3f}-{hi:.3f}"


def _offsets(v: dict) -> str:
    """The clock offsets told from the pose: how many, and the largest error among them."""
    if not v["offsets_determined"]:
        return "none determined"
    return (f"{v['offsets_determined']} determined, the largest error "
            f"{1000 * v['offset_error_max_s']:.2f} ms")


def _pool(paths: list[str]) -> int:
    """The table of docs/mocap.md's measured coverage, from the runs' --mocap-json files."""
    dumps = []
    try:
        for path in paths:
            try:
                dumps.append((path, json.loads(Path(path).read_text())))
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise InputError(f"{path}: cannot read a --mocap-json file ({exc})") from None
        pooled = pool_mocap(dumps)
    except InputError as exc:
        print(f"error: --pool: {exc}", file=sys.stderr)
        return 2
    print(f"motion capture ({pooled['estimator']}), {pooled['holds']} holds per sensor, pooled over seeds "
          f"{', '.join(map(str, pooled['seeds']))}: inside the 95 % region (6-DOF: count and 95 % Wilson "
          "interval; translation only, of the runs that wrote it), median NEES per degree of freedom (each "
          "run's in brackets) and median translation error (of the runs that wrote it)")
    print("| error model | lidar inside 6-DOF | lidar translation | lidar NEES/dof | lidar error "
          "| camera inside 6-DOF | camera translation | camera NEES/dof | camera error |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for model, kinds in pooled["models"].items():
        cells = []
        for kind in ("lidar", "camera"):
            v = kinds.get(kind)
            if v is None:
                cells += ["-"] * 4
                continue
            n, k = v["checks"], v["inside_6dof"]
            lo, hi = v["interval"]
            t, n3 = v["inside_3dof_translation"], v["checks_3dof"]
            cells += [f"{k / n:.3f} ({k} of {n}; {lo:.3f}-{hi:.3f})",
                      "-" if not n3 else f"{t / n3:.3f}" + ("" if n3 == n else f" (of {n3})"),
                      f"{v['nees_median']:.2f} ({', '.join(f'{m:.2f}' for m in v['nees_median_by_run'])})",
                      "-" if not v["checks_error"] else f"{1000 * v['error_median_m']:.2f} mm"
                      + ("" if v["checks_error"] == n else f" (of {v['checks_error']})")]
        print(f"| `{model}` | " + " | ".join(cells) + " |")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--modes", default="mcpe,fcpe,pse")
    ap.add_argument("--mocap-trials", type=int, default=100, help="0 skips motion capture")
    ap.add_argument("--mocap-models", default=",".join(ERROR_MODELS),
                    help="motion capture: error models (default: all)")
    ap.add_argument("--mocap-holds", type=int, default=8,
                    help="motion capture: holds per sensor (default 8: fewer cannot show a per-hold "
                         "MCS error well, docs/mocap.md)")
    ap.add_argument("--mocap-hold-floor", default="0,0", type=_floor,
                    help="motion capture: the MCS's per-hold accuracy the calibration is told, "
                         "rotation_rad,translation_m (MocapOptions.hold_sigma_floor; default none)")
    ap.add_argument("--mocap-estimator", default=MocapOptions.estimator, choices=ESTIMATORS,
                    help=f"motion capture: MocapOptions.estimator (default {MocapOptions.estimator}; ls: the "
                         "least-squares solution, gls: weighted by the estimated noise model)")
    ap.add_argument("--mocap-json", default=None,
                    help="motion capture: write every estimate's NEES (6-DOF and translation) per model and "
                         "sensor kind, and whether it took the pooled per-hold value, to this JSON file, to "
                         "pool seeds (--pool)")
    ap.add_argument("--pool", nargs="+", default=None, metavar="JSON",
                    help="motion capture: print the coverage pooled over runs written by --mocap-json "
                         "(one per seed) as a table, and run nothing")
    ap.add_argument("--priors", default="both", choices=["both", "off", "only"],
                    help="board modes without mounting priors, with them, or both (default)")
    args = ap.parse_args()
    if args.pool:
        return _pool(args.pool)
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()}, "
          f"python {platform.python_version()}")
    print("fraction of true poses inside the reported 95 % region "
          "(position: 3D ellipsoid; pose: 6-DOF; 2D radars: in-plane ellipse + bounded intervals; "
          "relative: every pair of non-reference sensors, T_a_b)")
    print(f"{'mode':12} {'position':>9} {'pose':>9} {'relative':>9} {'sensors':>8} {'pairs':>5} "
          f"{'fail/runs':>10} {'flagged':>10}  by kind (position/pose)")
    scenarios = {"both": (None, PriorSpec()), "off": (None,), "only": (PriorSpec(),)}[args.priors] if args.trials else ()
    for priors in scenarios:
        t0 = time.perf_counter()
        with threadpool_limits(limits=1):
            res = board_coverage(trials=args.trials, seed=args.seed, modes=tuple(args.modes.split(",")),
                                 priors=priors)
        for mode, f in res.items():
            print(_row(mode + (" +prior" if priors else ""), f))
        print(f"board modes{' with priors' if priors else ''}: {args.trials} trials, "
              f"{time.perf_counter() - t0:.0f} s")
    if args.mocap_trials:
        from rigcal.study.coverage import mocap_coverage

        floor = args.mocap_hold_floor
        print(f"motion capture, {args.mocap_holds} holds per sensor, per-hold floor {floor[0]:g} rad / "
              f"{floor[1]:g} m: fraction inside the 95 % region "
              "(6-DOF / translation) and median NEES per degree of freedom (0.89 when right), per "
              "sensor kind; goal 0.90-0.98 and 0.5-2")
        dump: dict = {}
        dump3: dict = {}
        pooled: dict = {}
        errors: dict = {}

        def write_json() -> None:  # after every model: a long run stopped early keeps what it measured
            if args.mocap_json:
                atomic_write_text(args.mocap_json, json.dumps(
                    {"seed": args.seed, "holds": args.mocap_holds, "hold_sigma_floor": list(floor),
                     "estimator": args.mocap_estimator, "nees_6dof": dump, "nees_3dof": dump3,
                     "pooled": pooled, "errors_m": errors}))

        try:  # the path checked before the runs, not after the first model's hour
            write_json()
        except InputError as exc:
            print(f"error: --mocap-json: {exc}", file=sys.stderr)
            return 2
        for model in args.mocap_models.split(","):
            t0 = time.perf_counter()
            with threadpool_limits(limits=1):
                m = mocap_coverage(trials=args.mocap_trials, seed=args.seed, error_model=model,
                                   holds=args.mocap_holds, hold_sigma_floor=floor,
                                   estimator=args.mocap_estimator)
            kinds = "  ".join(
                f"{k} {v['inside_6dof']:.2f}/{v['inside_3dof_translation']:.2f} NEES {v['nees_median']:.2f}"
                f" error {1000 * v['error_median_m']:.2f} mm"
                f" [{_count(v)}]"
                + (f" (took the pooled per-hold value {v['pooled']}, {v['pooled_inside_6dof']} of them inside)"
                   if v["pooled"] else "")
                + (f" (offset flagged {v['flagged']}, {_offsets(v)})"
                   if model in ("clock_offset", "mixed", "timing_jitter") else "")
                for k, v in m["per_sensor"].items())
            print(f"  {model:14} {kinds}  (naive 6-DOF {m['naive_inside_6dof']:.2f}; {m['failed']} failed; "
                  f"{time.perf_counter() - t0:.0f} s)", flush=True)
            for k, why in m["failures"]:
                print(f"    trial {k} failed: {why}", flush=True)
            dump[model] = {k: v["nees_6dof"] for k, v in m["per_sensor"].items()}
            dump3[model] = {k: v["nees_3dof"] for k, v in m["per_sensor"].items()}
            pooled[model] = {k: v["pooled_6dof"] for k, v in m["per_sensor"].items()}
            errors[model] = {k: v["errors_m"] for k, v in m["per_sensor"].items()}
            write_json()
    return 0


if __name__ == "__main__":
    sys.exit(main())
