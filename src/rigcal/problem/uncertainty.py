"""From a pose covariance to standard deviations a person reads, and observability warnings."""

from __future__ import annotations

import numpy as np

from rigcal.dataset import Dataset
from rigcal.geometry.se3 import adjoint, invert, se3_exp
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.problem.pairs import pair_data, reflector_points
from rigcal.problem.result import STD_KEYS, RelativeEstimate

#: std above which a direction is reported as weakly observable
WEAK_TRANSLATION_M = 0.05
WEAK_ROTATION_DEG = 1.0


def _xyz_rpy(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], rpy_from_matrix(T[:3, :3])])


def pose_std(T: np.ndarray, covariance: np.ndarray) -> dict[str, float]:
    """Std of x, y, z [m] and roll, pitch, yaw [deg] of ``T`` given the (6, 6) covariance of its
    right perturbation (first-order propagation through a central-difference Jacobian)."""
    eps = 1e-6
    J = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        diff = _xyz_rpy(T @ se3_exp(d)) - _xyz_rpy(T @ se3_exp(-d))
        diff[3:] = (diff[3:] + np.pi) % (2 * np.pi) - np.pi
        J[:, i] = diff / (2 * eps)
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


def relative_estimates(names, poses, joint_covariance) -> dict:
    """:class:`~rigcal.problem.result.RelativeEstimate` ``"a-b"`` (``T_a_b``) for every pair of
    ``names`` (a before b): ``poses[name]`` is ``T_W_name``, ``joint_covariance([a, b])`` the
    (12, 12) joint covariance of the two poses' right perturbations."""
    out = {}
    names = list(names)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            T = invert(poses[a]) @ poses[b]
            cov = relative_covariance(poses[a], poses[b], joint_covariance([a, b]))
            out[f"{a}-{b}"] = RelativeEstimate(a, b, T, cov, pose_std(T, cov))
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


def fov_bounds(problem, radar: str) -> tuple[dict[str, tuple[float, float]], list[np.ndarray]]:
    return fov_bounds_joint([problem], radar)


def fov_bounds_joint(problems, radar: str) -> tuple[dict[str, tuple[float, float]], list[np.ndarray]]:
    """The offsets of a 2D radar's roll, pitch [deg] (about its own x, y axes) and z [m] (along
    its own z axis) from the estimate that keep every board's reflector inside its elevation
    field of view - the other parameters at the estimate, the three directions jointly free.

    Linear programs on the field-of-view constraints ``-max <= el_i + g_i . d <= max``
    linearised at the estimate; each interval is the projection of the feasible set on one
    direction (so a tilt compensated by a height change is allowed). A direction no board
    bounds gets the search limits (+-90 deg, +-10 m). ``problems``: each with the radar as a
    pose block (the constraints of all of them hold at once)."""
    from rigcal.problem.numerics import maximise_in_polytope
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
        grad.append(g[:, list(BOUNDED_RADAR_DIRECTIONS.values())])
        mx.append(b.max_elevation_rad[sel])
    names = list(BOUNDED_RADAR_DIRECTIONS)
    lim = np.array([_BOUND_LIMIT[n] for n in names])
    vertices: list[np.ndarray] = []
    if not el:
        out_lim = {n: (-float(lim[i]), float(lim[i])) for i, n in enumerate(names)}
        vertices = [s * lim * np.eye(3)[i] for i in range(3) for s in (-1.0, 1.0)]
    else:
        e, g, m = np.concatenate(el), np.concatenate(grad), np.concatenate(mx)
        A_ub = np.vstack([g, -g])
        b_ub = np.concatenate([m - e, m + e])
        # the estimate itself may sit a hair outside (solver tolerance): never an empty set
        b_ub = np.maximum(b_ub, 0.0)
        out_lim = {}
        for i, n in enumerate(names):
            ends = []
            for sign in (-1.0, 1.0):  # the lowest, then the highest offset
                x = maximise_in_polytope(sign * np.eye(3)[i], A_ub, b_ub, lim)
                ends.append(float(x[i]))
                vertices.append(x)
            out_lim[n] = (min(ends[0], 0.0), max(ends[1], 0.0))
    return {
        n: ((float(np.degrees(lo)), float(np.degrees(hi))) if n != "z" else (lo, hi))
        for n, (lo, hi) in out_lim.items()
    }, vertices


def radar_fov_edge_boards(values: np.ndarray, tol_rad: float = 1e-4) -> int:
    """How many boards sit on the edge of a 2D radar's elevation field of view."""
    return int(np.sum(values > -tol_rad))


__all__ = [
    "BOUNDED_RADAR_DIRECTIONS",
    "fov_bounds",
    "fov_bounds_joint",
    "geometry_warnings",
    "pose_std",
    "radar_fov_edge_boards",
    "relative_covariance",
    "relative_estimates",
    "weak_directions",
]
