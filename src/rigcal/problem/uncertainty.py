"""From a pose covariance to standard deviations a person reads, and observability warnings."""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset
from rigcal.geometry.se3 import adjoint, invert, se3_exp
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.problem.pairs import pair_data, reflector_points
from rigcal.problem.result import STD_KEYS, BoundedSet, RelativeEstimate

#: std above which a direction is reported as weakly observable
WEAK_TRANSLATION_M = 0.05
WEAK_ROTATION_DEG = 1.0


def _xyz_rpy(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], rpy_from_matrix(T[:3, :3])])


#: the quantities of a pose table, in :func:`table_jacobian` order (x, y, z [m]; roll, pitch,
#: yaw [deg] of ``rpy_from_matrix``)
TABLE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")
#: |pitch| [deg] beyond which roll and yaw of a relative rotation are reported near gimbal lock
GIMBAL_LOCK_PITCH_DEG = 75.0


def table_jacobian(T: np.ndarray) -> np.ndarray:
    """(6, 6) derivative of x, y, z [m], roll, pitch, yaw [rad] of ``T`` w.r.t. its right
    perturbation (omega, v) (central differences)."""
    eps = 1e-6
    Ts = np.asarray(T, dtype=float) @ _FD_STEPS  # (12, 4, 4): +eps, then -eps along each direction
    f = np.concatenate([Ts[:, :3, 3], rpy_from_matrix(Ts[:, :3, :3])], axis=1)
    diff = f[:6] - f[6:]
    diff[:, 3:] = (diff[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    return diff.T / (2 * eps)


_FD_STEPS = se3_exp(np.concatenate([np.eye(6), -np.eye(6)]) * 1e-6)


def pose_std(T: np.ndarray, covariance: np.ndarray) -> dict[str, float]:
    """Std of x, y, z [m] and roll, pitch, yaw [deg] of ``T`` given the (6, 6) covariance of its
    right perturbation (first-order propagation through a central-difference Jacobian)."""
    J = table_jacobian(T)
    C = J @ covariance @ J.T
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    std[3:] = np.degrees(std[3:])
    return dict(zip(STD_KEYS, (float(s) for s in std)))


def relative_covariance(T_W_a: np.ndarray, T_W_b: np.ndarray, joint_covariance: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of ``T_a_b = T_W_a^-1 T_W_b`` (right perturbation) from the (12, 12)
    joint covariance of the right perturbations of ``T_W_a`` and ``T_W_b`` (in that order).

    First order: ``(T_W_a e^xa)^-1 T_W_b e^xb = T_a_b e^(xb - Ad(T_b_a) xa)``."""
    T_a_b = invert(np.asarray(T_W_a, dtype=float)) @ np.asarray(T_W_b, dtype=float)
    J = np.hstack([-adjoint(invert(T_a_b)), np.eye(6)])
    C = J @ np.asarray(joint_covariance, dtype=float) @ J.T
    return 0.5 * (C + C.T)


def box_set(bounded: Mapping[str, tuple[float, float]]) -> BoundedSet:
    """The :class:`BoundedSet` of a sensor's ``bounded`` intervals alone (offsets, deg / m): a
    box, the pose moving only along the directions (a superset of the real set)."""
    dirs = tuple(bounded)
    conv = np.array([math.radians(1.0) if d != "z" else 1.0 for d in dirs])
    lo = np.array([bounded[d][0] for d in dirs]) * conv
    hi = np.array([bounded[d][1] for d in dirs]) * conv
    k = len(dirs)
    return BoundedSet(dirs, np.vstack([np.eye(k), -np.eye(k)]), np.concatenate([hi, -lo]),
                      np.maximum(np.abs(lo), np.abs(hi)), np.eye(6)[:, [BOUNDED_RADAR_DIRECTIONS[d] for d in dirs]])


def _table_value(T: np.ndarray, k: int) -> float:
    v = _xyz_rpy(T)[k]
    return float(v if k < 3 else math.degrees(v))


def bounded_quantities(
    T: np.ndarray, std: Mapping[str, float], parts, always: tuple[str, ...] = ()
) -> dict[str, tuple[float, float, float]]:
    """The pose-table quantities of ``T`` (x, y, z [m]; roll, pitch, yaw [deg]) that bounded
    directions move by more than their reported ``std`` (and those in ``always``):
    ``{key: (low, high, estimate)}``, the extremes over the bounded sets to first order.
    ``parts``: ``(BoundedSet, M)`` pairs, ``M`` (6, k) the move of ``T``'s right perturbation
    per unit offset of the set's directions."""
    parts = list(parts)
    if not parts:
        return {}
    Jt = table_jacobian(T)
    Gs = [(bset, Jt @ M) for bset, M in parts]
    out = {}
    for k, key in enumerate(TABLE_KEYS):
        scale = 1.0 if k < 3 else math.degrees(1.0)
        lo = hi = 0.0
        for bset, G in Gs:
            a, b = bset.extremes(G[k])
            lo, hi = lo + scale * a, hi + scale * b
        if key in always or 0.5 * (hi - lo) > std[STD_KEYS[k]]:
            e = _table_value(T, k)
            out[key] = (e + lo, e + hi, e)
    return out


def sensor_bounded_values(
    T: np.ndarray, std: Mapping[str, float], bounded: Mapping[str, tuple[float, float]],
    bounded_set: BoundedSet | None = None,
) -> dict[str, tuple[float, float, float]]:
    """A sensor's bounded directions (offsets ``bounded``; their set ``bounded_set``, else the
    box of the offsets) as absolute values of its pose table ``T``: the quantities named like
    the directions (z [m] of its origin, roll, pitch [deg]: those directions for a sensor
    mounted level or upside down) and any other they move by more than its ``std``:
    ``{key: (low, high, estimate)}``."""
    if not bounded:
        return {}
    bset = bounded_set if bounded_set is not None else box_set(bounded)
    return bounded_quantities(T, std, [(bset, bset.move_map)], tuple(bounded))


def relative_bounded_quantities(
    T_W_a: np.ndarray, T_W_b: np.ndarray, std: Mapping[str, float],
    set_a: BoundedSet | None, set_b: BoundedSet | None,
) -> dict[str, tuple[float, float, float]]:
    """:func:`bounded_quantities` of ``T_a_b = T_W_a^-1 T_W_b`` under the bounded sets of ``a``
    and ``b`` (None: none): ``b``'s moves enter ``T_a_b``'s right perturbation as they are,
    ``a``'s through ``-Ad(T_b_a)``."""
    T = invert(np.asarray(T_W_a, dtype=float)) @ np.asarray(T_W_b, dtype=float)
    parts = []
    if set_a is not None:
        parts.append((set_a, -adjoint(invert(T)) @ set_a.move_map))
    if set_b is not None:
        parts.append((set_b, set_b.move_map))
    return bounded_quantities(T, std, parts)


def format_bounded(direction: str, low: float, high: float, estimate: float) -> str:
    """``roll -22.60 .. +14.30 deg (estimate -22.60)``: a bounded direction as absolute values."""
    if direction in ("x", "y", "z"):
        return f"{direction} {low:+.3f} .. {high:+.3f} m (estimate {estimate:+.3f})"
    return f"{direction} {low:+.2f} .. {high:+.2f} deg (estimate {estimate:+.2f})"


def near_gimbal_lock(T: np.ndarray) -> bool:
    """True when the pitch of ``T``'s rotation is within 15 deg of +-90 deg, where roll and yaw
    (and their std) are ill defined."""
    return abs(math.degrees(float(rpy_from_matrix(np.asarray(T, dtype=float)[:3, :3])[1]))) > GIMBAL_LOCK_PITCH_DEG


def relative_estimates(names, poses, joint_covariance, bounded: Mapping[str, BoundedSet] | None = None) -> dict:
    """:class:`~rigcal.problem.result.RelativeEstimate` ``"a-b"`` (``T_a_b``) for every pair of
    ``names`` (a before b): ``poses[name]`` is ``T_W_name``, ``joint_covariance([a, b])`` the
    (12, 12) joint covariance of the two poses' right perturbations; ``bounded[name]``: a
    sensor's bounded set, which makes the quantities it moves bounded."""
    out = {}
    names = list(names)
    bounded = bounded or {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            T = invert(poses[a]) @ poses[b]
            cov = relative_covariance(poses[a], poses[b], joint_covariance([a, b]))
            std = pose_std(T, cov)
            q = relative_bounded_quantities(poses[a], poses[b], std, bounded.get(a), bounded.get(b))
            out[f"{a}-{b}"] = RelativeEstimate(a, b, T, cov, std, q)
    return out


def weak_directions(std: dict[str, float]) -> list[str]:
    out = []
    for k in ("x_m", "y_m", "z_m"):
        if std[k] > WEAK_TRANSLATION_M:
            out.append(f"{k[0]} (std {std[k] * 1000:.0f} mm)")
    for k in ("roll_deg", "pitch_deg", "yaw_deg"):
        if std[k] > WEAK_ROTATION_DEG:
            out.append(f"{k[:-4]} (std {std[k]:.2f} deg)")
    return out


def geometry_warnings(dataset: Dataset, pairs: list[tuple[str, str]]) -> list[str]:
    """Warnings about board layouts that leave a pair weakly determined."""
    out = []
    for a, b in pairs:
        p = pair_data(dataset, a, b)
        if p is None:
            continue
        if p.num_boards < 3:
            out.append(
                f"pair {p.label} shares only {p.num_boards} board(s); use at least 3 (better 10+)"
            )
            continue
        frame = dataset.sensor(p.frame)
        refl = reflector_points(frame, dataset)[p.boards]
        sv = np.linalg.svd(refl - refl.mean(axis=0), compute_uv=False)
        if sv[1] < 0.10 * np.sqrt(len(refl)):
            out.append(
                f"pair {p.label}: the {p.num_boards} shared boards are nearly collinear "
                "(rotation about their line is weakly determined); spread boards left-right and "
                "near-far"
            )
        elif frame.kind.is_point_cloud and p.per_board == 4:
            from rigcal.targets.circle_board import board_normals

            n = board_normals(frame.points[p.boards])
            spread = np.degrees(np.arccos(np.clip(np.min(n @ n.mean(axis=0) / np.linalg.norm(n.mean(axis=0))), -1, 1)))
            if sv[2] < 0.05 * np.sqrt(len(refl)) and spread < 5.0:
                out.append(
                    f"pair {p.label}: the shared boards lie nearly in one plane with parallel "
                    "normals; vary board heights or tilts"
                )
    return out


#: local directions of a 2D radar that only its elevation field of view bounds (tangent index)
BOUNDED_RADAR_DIRECTIONS = {"roll": 0, "pitch": 1, "z": 5}
#: limits of the search for a bound [rad, m]: a direction no board bounds reports these
_BOUND_LIMIT = {"roll": np.pi / 2, "pitch": np.pi / 2, "z": 10.0}


def fov_bounds(
    problem, radar: str, directions: tuple[str, ...] = tuple(BOUNDED_RADAR_DIRECTIONS)
) -> tuple[dict[str, tuple[float, float]], list[np.ndarray]]:
    return fov_bounds_joint([problem], radar, directions)


def fov_bounds_joint(
    problems, radar: str, directions: tuple[str, ...] = tuple(BOUNDED_RADAR_DIRECTIONS)
) -> tuple[dict[str, tuple[float, float]], list[np.ndarray]]:
    """The offsets of a 2D radar's roll, pitch [deg] (about its own x, y axes) and z [m] (along
    its own z axis) - those of them in ``directions`` - from the estimate that keep every
    board's reflector inside its elevation field of view - the other parameters at the
    estimate, these directions jointly free (vertices: offsets in ``directions`` order).

    Linear programs on the field-of-view constraints ``-max <= el_i + g_i . d <= max``
    linearised at the estimate; each interval is the projection of the feasible set on one
    direction (so a tilt compensated by a height change is allowed). A direction no board
    bounds gets the search limits (+-90 deg, +-10 m). ``problems``: each with the radar as a
    pose block (the constraints of all of them hold at once)."""
    from rigcal.problem.numerics import maximise_in_polytope

    A_ub, b_ub, lim = fov_polytope(problems, radar, directions)
    names = list(directions)
    k = len(names)
    vertices: list[np.ndarray] = []
    out_lim = {}
    for i, n in enumerate(names):
        ends = []
        for sign in (-1.0, 1.0):  # the lowest, then the highest offset
            x = maximise_in_polytope(sign * np.eye(k)[i], A_ub, b_ub, lim)
            ends.append(float(x[i]))
            vertices.append(x)
        out_lim[n] = (min(ends[0], 0.0), max(ends[1], 0.0))
    return {
        n: ((float(np.degrees(lo)), float(np.degrees(hi))) if n != "z" else (lo, hi))
        for n, (lo, hi) in out_lim.items()
    }, vertices


def fov_polytope(
    problems, radar: str, directions: tuple[str, ...] = tuple(BOUNDED_RADAR_DIRECTIONS)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, b, limit): the offsets ``d`` of a 2D radar's ``directions`` (rad / m) with
    ``A d <= b`` (the field-of-view constraints of every board, linearised at the estimate) and
    ``|d| <= limit`` (the search limits, +-90 deg, +-10 m) - see :func:`fov_bounds_joint`."""
    from rigcal.problem.residuals import point_in_observer
    from rigcal.sensors.radar import elevation, elevation_jacobian

    el, grad, mx = [], [], []
    for problem, b in ((pr, b) for pr in problems for b in pr.limits):
        T = {p.name: p.T for p in problem.poses}
        sel = [i for i, o in enumerate(b.observer) if o == radar]
        if not sel:
            continue
        TA = np.stack([T[b.frame[i]] for i in sel])
        TB = np.stack([T[radar]] * len(sel))
        x, _, JB = point_in_observer(TA, TB, b.points[sel])
        e = elevation(x)
        g = np.einsum("ni,nij->nj", elevation_jacobian(x), JB)
        el.append(e)
        grad.append(g[:, [BOUNDED_RADAR_DIRECTIONS[d] for d in directions]])
        mx.append(b.max_elevation_rad[sel])
    k = len(directions)
    lim = np.array([_BOUND_LIMIT[n] for n in directions])
    if not el:
        return np.zeros((0, k)), np.zeros(0), lim
    e, g, m = np.concatenate(el), np.concatenate(grad), np.concatenate(mx)
    A_ub = np.vstack([g, -g])
    b_ub = np.concatenate([m - e, m + e])
    # the estimate itself may sit a hair outside (solver tolerance): never an empty set
    return A_ub, np.maximum(b_ub, 0.0), lim


def radar_fov_edge_boards(values: np.ndarray, tol_rad: float = 1e-4) -> int:
    """How many boards sit on the edge of a 2D radar's elevation field of view."""
    return int(np.sum(values > -tol_rad))


__all__ = [
    "BOUNDED_RADAR_DIRECTIONS",
    "GIMBAL_LOCK_PITCH_DEG",
    "TABLE_KEYS",
    "bounded_quantities",
    "box_set",
    "format_bounded",
    "fov_polytope",
    "near_gimbal_lock",
    "relative_bounded_quantities",
    "sensor_bounded_values",
    "table_jacobian",
    "fov_bounds",
    "fov_bounds_joint",
    "geometry_warnings",
    "pose_std",
    "radar_fov_edge_boards",
    "relative_covariance",
    "relative_estimates",
    "weak_directions",
]
