"""False alarms and power of the verdict on a wide population of simulated rigs.

Clean rigs (:func:`rigcal.study.verdict.draw_rig`: 1-3 lidars, 1-3 cameras stereo-like or
isotropic, 0-2 2D radars with range/azimuth or Cartesian noise, 0-1 3D radar, K = 6..29
boards 2-10 m away, 2-20 mm noise per sensor) are calibrated in every mode: how many are
flagged (goal: at most 1 % per mode, none for a pair the mode did not fit), undetermined or
refused. Then the first ``--fault-rigs`` rigs again with each injected mistake
(:data:`rigcal.study.verdict.FAULTS`): how often the verdict catches it among rigs with at
least 10 boards (goal: 95 % in every mode that can see it) and names it. A 1 % scale is also
tallied over the rigs where a mode can see it: at least
:func:`rigcal.study.verdict.visible_std` Cramer-Rao std of that sensor's scale (the test's
Bonferroni level plus 1.64 for 95 % power; :func:`rigcal.study.verdict.scale_bound`; each run's
bound is in ``--json``).

Usage: python benchmarks/verdict.py [--rigs N] [--fault-rigs M] [--seed S] [--modes mcpe,fcpe,pse]
       [--faults f1,f2,...] [--first I] [--minutes T] [--json FILE]

``--minutes T``: start no rig after T minutes; the tables then cover the rigs run (the sample
sizes say how many).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import traceback
from dataclasses import asdict

from threadpoolctl import threadpool_limits

from timing import cpu_model

from rigcal.study.verdict import FAULT_NAMES, run_rig, summarise


def machine() -> str:
    return f"{cpu_model()}, nproc {os.cpu_count()}, python {platform.python_version()}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", type=int, default=300, help="clean rigs (false alarms)")
    ap.add_argument("--fault-rigs", type=int, default=60, help="rigs that also get every fault (power)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--modes", default="mcpe,fcpe,pse")
    ap.add_argument("--faults", default=",".join(FAULT_NAMES))
    ap.add_argument("--first", type=int, default=0, help="start at rig I (a run split in parts)")
    ap.add_argument("--minutes", type=float, default=None, help="start no rig after this many minutes")
    ap.add_argument("--json", metavar="FILE", help="write every run to FILE")
    args = ap.parse_args()
    modes = tuple(args.modes.split(","))
    faults = tuple(f for f in args.faults.split(",") if f)
    print(f"machine: {machine()}")
    t0 = time.perf_counter()
    runs, crashed = [], []
    with threadpool_limits(limits=1):
        for i in range(args.first, max(args.rigs, args.fault_rigs)):
            if args.minutes is not None and time.perf_counter() - t0 > 60 * args.minutes:
                print(f"time budget of {args.minutes:g} min reached: stopped after {i} rigs", flush=True)
                break
            try:
                rr = run_rig(i, args.seed, modes, faults if i < args.fault_rigs else ())
            except Exception:  # a crash is a bug: shown and counted, the other rigs still run
                traceback.print_exc()
                crashed.append(i)
                print(f"rig {i + 1}: CRASHED", flush=True)
                continue
            if i >= args.rigs:
                rr = [r for r in rr if r.fault != "clean"]
            runs += rr
            odd = [f"{r.mode}:{r.outcome}" for r in rr if r.fault == "clean" and r.outcome != "consistent"]
            print(f"rig {i + 1}/{max(args.rigs, args.fault_rigs)} ({rr[0].boards if rr else '-'} boards) "
                  f"{time.perf_counter() - t0:.0f} s" + (f"  clean: {' '.join(odd)}" if odd else ""), flush=True)
    s = summarise(runs)
    print(f"\nclean rigs (seed {args.seed}): flagged / undetermined / refused, of the rigs run")
    print(f"{'mode':6} {'rigs':>5} {'flagged':>8} {'undet.':>7} {'refused':>8} {'unfitted-pair flags':>20}  failed checks")
    for m, c in s["clean"].items():
        print(f"{m:6} {c['rigs']:5d} {c['flagged']:8d} {c['undetermined']:7d} {c['refused']:8d} "
              f"{c['unfitted_pair_flags']:20d}  {c['checks']}")
    if s["faults"]:
        print("\nfaults (rigs with >= 10 boards): caught (flagged / refused / undetermined; a board from "
              "another placement: excluded or flagged) and named, of the rigs that can carry the fault")
        print(f"{'fault':24} " + " ".join(f"{m:>20}" for m in modes))
        for fault, rows in s["faults"].items():
            cells = []
            for m in modes:
                v = rows.get(m)
                cells.append(f"{v['caught']}/{v['rigs']} ({100 * v['caught'] / v['rigs']:.0f}%) n{v['named']}"
                             if v else "-")
            print(f"{fault:24} " + " ".join(f"{c:>20}" for c in cells))
    print(f"\n{len(runs)} calibrations, {time.perf_counter() - t0:.0f} s; rigs crashed: "
          f"{', '.join(str(i + 1) for i in crashed) or 'none'}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"summary": s, "runs": [asdict(r) for r in runs]}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
