"""SE(3) on (..., 4, 4) arrays: build, invert, compose, apply, exp/log. Batched, pure."""

from __future__ import annotations

from typing import Any

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.so3 import hat, so3_exp, so3_log


def from_rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) from rotations (..., 3, 3) and translations (..., 3)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4): ``invert(T_a_b) = T_b_a``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return from_rt(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def compose(*Ts: np.ndarray) -> np.ndarray:
    """Product ``Ts[0] @ Ts[1] @ ...``; frames must chain: ``compose(T_a_b, T_b_c) = T_a_c``."""
    out = np.asarray(Ts[0], dtype=float)
    for T in Ts[1:]:
        out = out @ np.asarray(T, dtype=float)
    return out


def transform_points(T_to_from: np.ndarray, points_from: np.ndarray) -> np.ndarray:
    """Map points (N, 3) given in ``from`` into ``to``; returns a new (N, 3) array."""
    T = np.asarray(T_to_from, dtype=float)
    p = np.asarray(points_from, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    t2 = theta * theta
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (safe - np.sin(safe)) / (safe**3))
    return np.eye(3) + b * K + c * (K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Transforms (..., 4, 4) from twists xi = (omega, v) (..., 6) (rotation first)."""
    xi = np.asarray(xi, dtype=float)
    w, v = xi[..., :3], xi[..., 3:]
    return from_rt(so3_exp(w), np.einsum("...ij,...j->...i", _left_jacobian(w), v))


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twists (..., 6) = (omega, v) with ``se3_exp(se3_log(T)) == T``."""
    T = np.asarray(T, dtype=float)
    w = so3_log(T[..., :3, :3])
    V = _left_jacobian(w)
    v = np.linalg.solve(V, T[..., :3, 3][..., None])[..., 0]
    return np.concatenate([w, v], axis=-1)


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of ``T`` for twists ``xi = (omega, v)``: ``T exp(xi) T^-1 = exp(Ad_T xi)``,
    ``Ad_T = [[R, 0], [hat(t) R, R]]``."""
    T = np.asarray(T, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[3:, :3] = tx @ R
    out[3:, 3:] = R
    return out


def as_rigid(T: Any, what: str, tol: float = 1e-6) -> np.ndarray:
    """A read-only rigid (4, 4) float copy of a transform given by a user or a file, or
    InputError naming ``what`` and saying what was expected: a finite 4x4 matrix of numbers
    (translations within the metre limit of :mod:`rigcal.io.limits`), last row [0, 0, 0, 1],
    the 3x3 block orthonormal within ``tol`` with det +1.

    A block that is orthonormal only to print precision (error above 1e-12, e.g. written with
    6 decimals) is replaced by the nearest rotation (SVD), so that compositions stay rigid and
    the angles written out describe exactly the matrix returned; exact rotations are kept bit
    for bit. The one validator for transforms: result files, URDF, mocap and simulators."""
    try:
        m = np.array(T, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a 4x4 matrix of numbers, got {type(T).__name__}") from None
    if m.shape != (4, 4):
        raise InputError(f"{what}: expected a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise InputError(f"{what}: expected finite numbers, got NaN or infinity")
    from rigcal.io.limits import check_finite

    check_finite(m, what, "entry", "m")  # a translation of 1e300 m is no rig
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9, rtol=0.0):
        raise InputError(f"{what}: not rigid: last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    R = m[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    det = float(np.linalg.det(R))
    if err > tol or det <= 0:
        raise InputError(
            f"{what}: not rigid: the 3x3 block must be a rotation (orthonormal within {tol:g}, "
            f"det +1), got |R^T R - I| = {err:.3g}, det = {det:.6g}"
        )
    if err > 1e-12:
        U, _, Vt = np.linalg.svd(R)
        m[:3, :3] = U @ Vt
    m[3] = (0.0, 0.0, 0.0, 1.0)
    m.setflags(write=False)
    return m
