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


def tilting_radars(problem: Problem) -> tuple[str, ...]:
    """Observers of field-of-view limits whose roll or pitch is free (the tilt is estimated)."""
    names = []
    for lim in problem.limits:
        for name in dict.fromkeys(lim.observer):
            free = problem.pose(name).free
            if (free[0] or free[1]) and name not in names:
                names.append(name)
    return tuple(names)


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
    field of view. Empty when the problem has no tilting radar."""
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
    if not small:
        return [mirrored]
    out = []
    for sign in (1.0, -1.0):
        alt = dict(mirrored)
        for name in small:
            half = 0.5 * max(
                float(np.max(lim.max_elevation_rad)) for lim in problem.limits if name in lim.observer
            )
            R = base[name][:3, :3] @ so3_exp(np.array([0.0, sign * half, 0.0]))
            alt[name] = from_rt(R, found[name][:3, 3])
        out.append(alt)
    return out


def solve_global(problem: Problem, start: Mapping[str, np.ndarray] | None = None, **kwargs) -> Solution:
    """:func:`solve` from the problem's poses (or ``start``) and from the alternative radar
    tilts of :func:`alternative_starts`; the lowest-cost converged solution (else the first).

    ``solution.extra["starts"]`` lists (cost, converged) per start, the chosen one first.
    """
    first = solve(problem, start=start, **kwargs)
    alternatives = alternative_starts(problem, first.poses, start)
    if not alternatives:
        return first
    tried = [first] + [solve(problem, start=alt, **kwargs) for alt in alternatives]
    converged = [s for s in tried if s.converged]
    best = min(converged, key=lambda s: s.cost) if converged else first
    record = [(best.cost, best.converged)] + [(s.cost, s.converged) for s in tried if s is not best]
    return replace(best, extra={**best.extra, "starts": tuple(record)})
