"""SO(3): hat, exp/log (rotation vectors), roll-pitch-yaw. Batched over leading axes."""

from __future__ import annotations

import numpy as np

_SMALL = 1e-8


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of vectors ``v`` (..., 3) -> (..., 3, 3), ``hat(a) @ b = a x b``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3) [rad] (Rodrigues)."""
    w = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-4
    t2 = theta * theta
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) from rotation matrices (..., 3, 3); angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    batch = R.shape[:-2]
    Rf = R.reshape(-1, 3, 3)
    cos = np.clip((np.trace(Rf, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack(
        [Rf[:, 2, 1] - Rf[:, 1, 2], Rf[:, 0, 2] - Rf[:, 2, 0], Rf[:, 1, 0] - Rf[:, 0, 1]], axis=-1
    )
    small = theta < 1e-4
    near_pi = np.pi - theta < 1e-3
    sin = np.sin(np.where(small | near_pi, 1.0, theta))
    scale = np.where(small, 0.5 * (1.0 + theta * theta / 6.0), theta / (2.0 * sin))
    out = scale[:, None] * vee
    for i in np.flatnonzero(near_pi):
        # near pi the skew part vanishes: axis from the symmetric part, sign from the skew part
        S = (Rf[i] + Rf[i].T) / 2.0 - cos[i] * np.eye(3)
        k = int(np.argmax(np.diag(S)))
        axis = S[:, k] / np.sqrt(max(S[k, k], _SMALL))
        axis /= np.linalg.norm(axis)
        if np.dot(axis, vee[i]) < 0:
            axis = -axis
        out[i] = axis * theta[i]
    return out.reshape(batch + (3,))


def matrix_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from (..., 3) = (roll, pitch, yaw) [rad]."""
    rpy = np.asarray(rpy, dtype=float)
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty(rpy.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) [rad] (..., 3) with R = Rz(yaw) Ry(pitch) Rx(roll).

    Roll and yaw in (-pi, pi], pitch in [-pi/2, pi/2]. Roll comes from the last row; pitch and
    yaw from ``R @ Rx(-roll)`` with atan2 only, so :func:`matrix_from_rpy` of the result
    reproduces ``R`` to rounding even next to gimbal lock (|pitch| = pi/2, where roll is 0).
    """
    R = np.asarray(R, dtype=float)
    r21, r22 = R[..., 2, 1], R[..., 2, 2]
    roll = np.where(np.hypot(r21, r22) < 1e-12, 0.0, np.arctan2(r21, r22))
    cr, sr = np.cos(roll), np.sin(roll)
    m01 = cr * R[..., 0, 1] - sr * R[..., 0, 2]
    m11 = cr * R[..., 1, 1] - sr * R[..., 1, 2]
    m22 = sr * r21 + cr * r22
    pitch = np.arctan2(-R[..., 2, 0], m22)
    yaw = np.arctan2(-m01, m11)
    return np.stack([roll, pitch, yaw], axis=-1) + 0.0  # + 0.0: no negative zeros
