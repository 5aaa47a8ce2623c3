"""Globalisation over the tilt of 2D radars.

A 2D radar measures range and azimuth only: its roll and pitch are bounded by the elevation
field of view (paper eq. 4) more than they are measured, and the calibration cost can have one
local minimum with the radar tilted up and another with it tilted down (the Prius data has
both, 0.5 % apart in cost). :func:`solve` (a local method) finds the one its start leads to;
:func:`solve_global` also starts from the radars' tilt mirrored about the start and keeps the
lowest-cost converged solution.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping

import numpy as np

from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import so3_exp, so3_log
from rigcal.problem.solver import Problem, Solution, solve

#: a mirrored tilt closer than this to the first solution's is no new start [rad]
MIN_TILT_CHANGE_RAD = math.radians(0.5)
#: radars seeing fewer reflectors than this also get starts pitched and rolled either way
FEW_REFLECTORS = 12


def tilting_radars(problem: Problem) -> tuple[str, ...]:
    """Observers of field-of-view limits whose roll or pitch is free (the tilt is estimated)."""
    names = []
    for lim in problem.limits:
        for name in dict.fromkeys(lim.observer):
            free = problem.pose(name).free
            if (free[0] or free[1]) and name not in names:
                names.append(name)
    return tuple(names)


def _half_fov(problem: Problem, name: str) -> float:
    return 0.5 * max(float(np.max(lim.max_elevation_rad)) for lim in problem.limits if name in lim.observer)


def _reflectors(problem: Problem, name: str) -> int:
    """Distinct boards whose reflector radar ``name`` sees (over all its limit batches)."""
    boards = [lim.board[np.asarray(lim.observer) == name] for lim in problem.limits]
    return int(np.unique(np.concatenate(boards)).size) if boards else 0


def _mirrored(T_start: np.ndarray, T_found: np.ndarray) -> np.ndarray:
    """``T_found`` with its roll and pitch relative to ``T_start`` (in the radar's own frame)
    negated; yaw and position kept."""
    w = so3_log(T_start[:3, :3].T @ T_found[:3, :3])
    w[:2] = -w[:2]
    return from_rt(T_start[:3, :3] @ so3_exp(w), T_found[:3, 3])


def alternative_starts(
    problem: Problem, found: Mapping[str, np.ndarray], start: Mapping[str, np.ndarray] | None = None
) -> list[dict[str, np.ndarray]]:
    """Starts with every tilting radar's tilt mirrored about its start (``start``, else the
    problem's poses) - or, where the solution kept the start's tilt, pitched by +- half the
    field of view; and for radars that see fewer than FEW_REFLECTORS reflectors, the start with
    them pitched and rolled by +- half the field of view. Empty without a tilting radar."""
    radars = tilting_radars(problem)
    if not radars:
        return []
    start = start or {}
    base = {p.name: np.asarray(start.get(p.name, p.T)) for p in problem.poses}
    mirrored, small = dict(found), []
    for name in radars:
        T = _mirrored(base[name], found[name])
        tilt = so3_log(found[name][:3, :3].T @ T[:3, :3])
        if float(np.linalg.norm(tilt)) < MIN_TILT_CHANGE_RAD:
            small.append(name)
        mirrored[name] = T
    out = [mirrored] if not small else []
    # few reflectors: the tilt minima multiply (Prius subsets of 4 boards: the local solution
    # and its mirror reach the lowest known minimum in 31 of 40 draws; with these four starts
    # too, 39 of 40; 10 boards: 23 and 25 of 25) - also start from the radar pitched and rolled
    # by half the field of view either way
    few = [name for name in radars if _reflectors(problem, name) < FEW_REFLECTORS]
    for axis in (1, 0):
        for sign in (1.0, -1.0):
            if not few:
                break
            alt = dict(base)
            for name in few:
                w = np.zeros(3)
                w[axis] = sign * _half_fov(problem, name)
                alt[name] = from_rt(base[name][:3, :3] @ so3_exp(w), base[name][:3, 3])
            out.append(alt)
    if not small or set(small) <= set(few):
        return out
    for sign in (1.0, -1.0):
        alt = dict(mirrored)
        for name in small:
            R = base[name][:3, :3] @ so3_exp(np.array([0.0, sign * _half_fov(problem, name), 0.0]))
            alt[name] = from_rt(R, found[name][:3, 3])
        out.append(alt)
    return out


def solve_global(problem: Problem, start: Mapping[str, np.ndarray] | None = None, **kwargs) -> Solution:
    """:func:`solve` from the problem's poses (or ``start``) and from the alternative radar
    tilts of :func:`alternative_starts`; the converged solution of the lowest objective
    (observations and priors; else the first).

    ``solution.extra["starts"]`` lists (cost, converged) per start, the chosen one first.
    """
    first = solve(problem, start=start, **kwargs)
    alternatives = alternative_starts(problem, first.poses, start)
    if not alternatives:
        return first
    tried = [first] + [solve(problem, start=alt, **kwargs) for alt in alternatives]
    converged = [s for s in tried if s.converged]
    best = min(converged, key=lambda s: s.cost + s.prior_cost) if converged else first
    record = [(best.cost + best.prior_cost, best.converged)] + [
        (s.cost + s.prior_cost, s.converged) for s in tried if s is not best
    ]
    return replace(best, extra={**best.extra, "starts": tuple(record)})
