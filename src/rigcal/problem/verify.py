"""Independent checks of a constrained solution (tests, benchmarks): how far poses are from a
KKT point of the problem, and a reference optimum from a general-purpose solver (scipy SLSQP)
on the same cost and field-of-view limits."""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.optimize

from rigcal.problem.solver import Problem, _constraints, _evaluate, _retract, prepare


def _stack(problem: Problem, poses: Mapping[str, np.ndarray] | None) -> np.ndarray:
    poses = poses or {}
    return np.stack([np.asarray(poses.get(p.name, p.T), dtype=float) for p in problem.poses])


def kkt_violations(
    problem: Problem, poses: Mapping[str, np.ndarray], active_tol: float = 1e-7
) -> dict[str, object]:
    """How far ``poses`` are from a KKT point of min cost s.t. c <= 0 (the field-of-view limits).

    Multipliers lambda >= 0 of the limits within ``active_tol`` [rad] of binding come from
    non-negative least squares on the stationarity of the Lagrangian; the others are zero.
    Returns ``stationarity`` |g + G'lambda| / |g|, ``complementarity`` max lambda_i |c_i|,
    ``violation`` max(c, 0), ``gradient`` |g| and ``multipliers`` lambda.
    """
    layout = prepare(problem)
    T = _stack(problem, poses)
    r, J, _, _ = _evaluate(problem, layout, T, "linear", 1.0, True)
    g = np.asarray(J.T @ r).ravel()
    c, G = _constraints(problem, layout, T)
    near = c > -active_tol
    lam = np.zeros(c.size)
    if np.any(near):
        lam[near] = scipy.optimize.nnls(G[near].T, -g, maxiter=1000)[0]
    return {
        "stationarity": float(np.linalg.norm(g + G.T @ lam)) / max(float(np.linalg.norm(g)), 1e-300),
        "complementarity": float(np.max(lam * np.abs(c), initial=0.0)),
        "violation": float(np.max(c, initial=0.0)),
        "gradient": float(np.linalg.norm(g)),
        "multipliers": lam,
    }


def reference_solve(
    problem: Problem, start: Mapping[str, np.ndarray] | None = None, h: float = 1e-6
) -> tuple[float, dict[str, np.ndarray], bool]:
    """scipy SLSQP on the same cost (linear loss) and limits, over one tangent vector
    (T = T0 exp(xi) for every free pose, held DOFs fixed) with central-difference gradients.
    Returns (cost, poses, success). Slow; for checks only."""
    layout = prepare(problem)
    T0 = _stack(problem, start)

    def cost(x):
        return _evaluate(problem, layout, _retract(T0, layout, x), "linear", 1.0, False)[2]

    def cons(x):
        return -_constraints(problem, layout, _retract(T0, layout, x), want_jac=False)[0]

    def central(f):
        def jac(x):
            return np.stack(
                [(np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h) for e in np.eye(x.size) * h],
                axis=-1,
            )

        return jac

    res = scipy.optimize.minimize(
        cost, np.zeros(layout.n_free), jac=central(cost), method="SLSQP",
        constraints=[{"type": "ineq", "fun": cons, "jac": central(cons)}] if problem.limits else [],
        options={"ftol": 1e-16, "maxiter": 1000},
    )
    T = _retract(T0, layout, res.x)
    return float(res.fun), {p.name: T[i] for i, p in enumerate(problem.poses)}, bool(res.success)
