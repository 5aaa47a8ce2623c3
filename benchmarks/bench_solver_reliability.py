"""How often does calibration finish? Random subsets of the real Prius boards, per mode and K.

For each mode and number of boards K: ``--draws`` seeded random subsets of the 29 boards, each
calibrated with default options; prints failures/draws, the median calibrate() CPU time, and the
refusal messages. If casadi is importable, the same FCPE problems (same subsets, same Kabsch
start, no outlier screening) are also solved with IPOPT on a casadi formulation (rotation by a
Cayley vector, the elevation limits as two-sided smooth constraints), next to our solver from
the same start: failures, median solve CPU time (IPOPT: solve only; building the casadi
function is shown apart), and how the costs compare.

Usage: python benchmarks/bench_solver_reliability.py [--draws 200] [--K 3,4,6,10,20]
           [--modes mcpe,fcpe,pse] [--ipopt-draws 50]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
from prius_data import prius_dataset
from threadpoolctl import threadpool_limits

from rigcal.errors import RigcalError
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.configurations import build_pairwise
from rigcal.problem.globalise import solve_global
from rigcal.problem.initialise import initial_poses
from rigcal.problem.observability import check_observable
from rigcal.problem.pairs import all_pairs
from rigcal.problem.residuals import MODEL_POINT, MODEL_RADAR2D
from rigcal.problem.solver import _constraints, _evaluate, prepare, solve



def draws(K: int, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(29, K, replace=False)) for _ in range(n)]


def reliability(ds, modes, Ks, n, seed) -> None:
    print(f"{'mode':5} {'K':>3} {'failed':>9} {'flagged':>9} {'median CPU [ms]':>12}  refusals, flags")
    for mode in modes:
        for K in Ks:
            fails, flagged, times, msgs = 0, 0, [], {}
            for boards in draws(K, n, seed):
                t = time.process_time()
                try:
                    r = calibrate(ds.select_boards(boards), CalibrationOptions(mode=mode))
                    if r.flagged:  # clean data: the consistency check should not object
                        flagged += 1
                        key = "flagged: " + "; ".join(c.detail[:100] for c in r.verdict.failed)
                        msgs[key] = msgs.get(key, 0) + 1
                except RigcalError as exc:
                    fails += 1
                    key = f"{type(exc).__name__}: {str(exc)[:110]}"
                    msgs[key] = msgs.get(key, 0) + 1
                times.append(time.process_time() - t)
            print(f"{mode:5} {K:3d} {fails:4d}/{n:<4d} {flagged:4d}/{n:<4d} "
                  f"{1000 * statistics.median(times):12.1f}", flush=True)
            for m, c in sorted(msgs.items(), key=lambda x: -x[1]):
                print(f"{'':32}{c} x {m}")


# --------------------------------------------------------------------------- IPOPT (casadi)


def ipopt_fcpe(problem, ca):
    """(solve(), build seconds): IPOPT on the FCPE problem; solve() -> (poses, ok, seconds)."""
    layout = prepare(problem)
    x = ca.SX.sym("x", layout.n_free)
    R, t = {}, {}
    for i, p in enumerate(problem.poses):
        cols = layout.cols[i]
        xi = [x[int(c)] if c >= 0 else 0 for c in cols]
        g = ca.vertcat(*xi[:3]) / 2  # Cayley (Gibbs) vector: R = I + 2 (G + G^2) / (1 + g'g)
        G = ca.skew(g)
        dR = ca.SX.eye(3) + 2 * (G + G @ G) / (1 + ca.dot(g, g))
        R0, t0 = ca.DM(p.T[:3, :3]), ca.DM(p.T[:3, 3])
        R[p.name] = R0 @ dR
        t[p.name] = t0 + R0 @ ca.vertcat(*xi[3:])

    def in_observer(f, o, pts):
        P = ca.DM(pts.T)  # (3, n)
        q = R[f] @ P + ca.repmat(t[f] - t[o], 1, pts.shape[0])
        return R[o].T @ q

    cost = 0
    for b in problem.observations:
        X = in_observer(b.frame[0], b.observer[0], b.points)  # one frame/observer per batch here
        if b.model == MODEL_POINT:
            h = X
        elif b.model == MODEL_RADAR2D:
            rho = ca.sqrt(X[0, :] ** 2 + X[1, :] ** 2)
            rng = ca.sqrt(X[0, :] ** 2 + X[1, :] ** 2 + X[2, :] ** 2)
            h = ca.vertcat(X[0, :] * rng / rho, X[1, :] * rng / rho)
        else:
            raise ValueError(b.model)
        r = (h - ca.DM(b.measured.T)) / ca.DM(b.sigma.T)
        cost = cost + 0.5 * ca.sumsqr(r)
    cons, bounds = [], []
    for lim in problem.limits:
        X = in_observer(lim.frame[0], lim.observer[0], lim.points)
        el = ca.atan2(X[2, :], ca.sqrt(X[0, :] ** 2 + X[1, :] ** 2))
        cons.append(el.T)
        bounds.append(lim.max_elevation_rad)
    t0 = time.process_time()
    nlp = {"x": x, "f": cost, "g": ca.vertcat(*cons) if cons else ca.SX(0, 1)}
    opts = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10}
    solver = ca.nlpsol("fcpe", "ipopt", nlp, opts)
    ub = np.concatenate(bounds) if bounds else np.zeros(0)
    build = time.process_time() - t0

    def run():
        t1 = time.process_time()
        sol = solver(x0=np.zeros(layout.n_free), lbg=-ub, ubg=ub)
        secs = time.process_time() - t1
        ok = solver.stats()["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        xs = np.asarray(sol["x"]).ravel()
        poses = {}
        f = ca.Function("poses", [x], [ca.vertcat(*[ca.horzcat(R[p.name], t[p.name]) for p in problem.poses])])
        M = np.asarray(f(xs))
        for i, p in enumerate(problem.poses):
            T = np.eye(4)
            T[:3, :4] = M[3 * i : 3 * i + 3]
            poses[p.name] = T
        return poses, ok, secs

    return run, build


def compare_ipopt(ds, Ks, n, seed) -> None:
    try:
        import casadi as ca
    except ImportError:
        print("\ncasadi not importable: IPOPT comparison skipped")
        return
    print(f"\nFCPE, same subsets and start, no outlier screening: ours (solve: local; "
          f"solve_global: + mirrored radar tilt) vs IPOPT {ca.__version__} via casadi (local)")
    print(f"{'K':>3} {'ours fail':>10} {'ours ms':>8} {'global fail':>12} {'global ms':>10} "
          f"{'ipopt fail':>11} {'ipopt ms':>9} {'build ms':>9}  cost ipopt vs local / vs global "
          "(lower / same / higher)")
    for K in Ks:
        stats = {k: [] for k in ("ours_t", "glob_t", "ip_t", "build")}
        fails = {"ours": 0, "glob": 0, "ip": 0}
        cmp_local, cmp_glob = [0, 0, 0], [0, 0, 0]
        used = 0
        for boards in draws(K, n, seed):
            sub = ds.select_boards(boards)
            try:
                check_observable(sub, "fcpe", "lidar1")
                start = initial_poses(sub, "lidar1", robust=True)
            except RigcalError:
                continue
            used += 1
            problem = build_pairwise(sub, start, "lidar1", all_pairs(sub))
            layout = prepare(problem)
            t0 = time.process_time()
            ours = solve(problem, layout=layout)
            stats["ours_t"].append(time.process_time() - t0)
            t0 = time.process_time()
            glob = solve_global(problem, layout=layout)
            stats["glob_t"].append(time.process_time() - t0)
            fails["ours"] += not ours.converged
            fails["glob"] += not glob.converged
            run, build = ipopt_fcpe(problem, ca)
            poses, ok, secs = run()
            stats["ip_t"].append(secs)
            stats["build"].append(build)
            T = np.stack([poses[p.name] for p in problem.poses])
            cost = _evaluate(problem, layout, T, "linear", 1.0, False)[2]
            feasible = float(np.max(_constraints(problem, layout, T, want_jac=False)[0], initial=0)) <= 1e-7
            if not (ok and feasible):
                fails["ip"] += 1
                continue
            for ref, tally in ((ours, cmp_local), (glob, cmp_glob)):
                rel = (cost - ref.cost) / ref.cost
                tally[0 if rel < -1e-7 else 1 if rel <= 1e-7 else 2] += 1
        med = {k: 1000 * statistics.median(v) if v else float("nan") for k, v in stats.items()}
        print(f"{K:3d} {fails['ours']:4d}/{used:<5d} {med['ours_t']:8.1f} {fails['glob']:5d}/{used:<6d} "
              f"{med['glob_t']:10.1f} {fails['ip']:5d}/{used:<5d} {med['ip_t']:9.1f} {med['build']:9.1f}  "
              f"{'/'.join(map(str, cmp_local))}  {'/'.join(map(str, cmp_glob))}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--K", default="3,4,6,10,20")
    ap.add_argument("--modes", default="mcpe,fcpe,pse")
    ap.add_argument("--ipopt-draws", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    ds = prius_dataset()
    if ds is None:
        return 1
    Ks = [int(k) for k in args.K.split(",")]
    with threadpool_limits(limits=1):
        if args.draws:
            reliability(ds, args.modes.split(","), Ks, args.draws, args.seed)
        if args.ipopt_draws:
            compare_ipopt(ds, Ks, args.ipopt_draws, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
