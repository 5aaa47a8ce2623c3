"""Closed-form point-set alignment: Kabsch (rigid) and Umeyama (similarity)."""

from __future__ import annotations

import numpy as np

from rigcal.errors import GeometryError
from rigcal.geometry.se3 import from_rt


#: Largest coordinate magnitude aligned: far beyond any rig (readers already refuse more than
#: rigcal.io.limits.MAX_ABS["m"]), far below what overflows the cross-covariance; LAPACK's SVD
#: of a matrix holding inf/NaN or values near the float limit may never return.
MAX_COORDINATE = 1.0e8


def _usable(x: np.ndarray, axes: tuple[int, ...] | None = None) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.all(np.abs(x) <= MAX_COORDINATE, axis=axes)


def _check_pairs(points_from: np.ndarray, points_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(points_from, dtype=float)
    b = np.asarray(points_to, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape:
        raise GeometryError(
            f"alignment needs two (N, 3) point arrays of equal shape, got {a.shape} and {b.shape}"
        )
    if a.shape[0] < 3:
        raise GeometryError(f"alignment needs at least 3 point pairs, got {a.shape[0]}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise GeometryError("alignment got non-finite points")
    if not (_usable(a) and _usable(b)):
        raise GeometryError(f"alignment got coordinates beyond ±{MAX_COORDINATE:g} m")
    return a, b


def _weighted_svd(a, b, weights):
    if weights is None:
        w = np.ones(a.shape[0])
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (a.shape[0],):
            raise GeometryError(f"alignment weights must have shape ({a.shape[0]},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
            raise GeometryError("alignment weights must be finite, >= 0 and not all zero")
    w = w / w.sum()
    ca = w @ a
    cb = w @ b
    A = a - ca
    B = b - cb
    H = (A * w[:, None]).T @ B
    U, S, Vt = np.linalg.svd(H)
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise GeometryError(
            "alignment is degenerate: the points are collinear (rotation about their line is free)"
        )
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d if d != 0 else 1.0])
    R = Vt.T @ D @ U.T
    return R, ca, cb, A, w, S, D


def kabsch(
    points_from: np.ndarray, points_to: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Rigid ``T_to_from`` minimising sum w_i |T p_from_i - p_to_i|^2.

    points_from, points_to: (N, 3), N >= 3, not collinear. Raises GeometryError otherwise.
    """
    a, b = _check_pairs(points_from, points_to)
    R, ca, cb, *_ = _weighted_svd(a, b, weights)
    return from_rt(R, cb - R @ ca)


def umeyama(
    points_from: np.ndarray, points_to: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, np.ndarray]:
    """Similarity ``p_to = s R p_from + t``; returns (s, T) with T holding R and t."""
    a, b = _check_pairs(points_from, points_to)
    R, ca, cb, A, w, S, D = _weighted_svd(a, b, weights)
    var_a = float(w @ np.sum(A * A, axis=1))
    s = float(np.sum(S * np.diag(D)) / var_a)
    return s, from_rt(R, cb - s * R @ ca)


def kabsch_batch(points_from: np.ndarray, points_to: np.ndarray) -> np.ndarray:
    """Rigid ``T_to_from`` for a batch of point-set pairs (B, N, 3) -> (B, 4, 4).

    Degenerate sets (collinear points) and sets with non-finite or absurd coordinates (beyond
    :data:`MAX_COORDINATE`) give NaN transforms instead of raising, so a caller
    scoring many hypotheses (RANSAC) can drop them.
    """
    a = np.asarray(points_from, dtype=float)
    b = np.asarray(points_to, dtype=float)
    if a.ndim != 3 or a.shape[-1] != 3 or a.shape != b.shape or a.shape[1] < 3:
        raise GeometryError(
            f"kabsch_batch needs two (B, N>=3, 3) arrays of equal shape, got {a.shape} and {b.shape}"
        )
    usable = _usable(a, (1, 2)) & _usable(b, (1, 2))  # NaN, inf, absurd sizes: NaN result
    if not usable.all():
        a = np.where(usable[:, None, None], a, 0.0)
        b = np.where(usable[:, None, None], b, 0.0)
    ca = a.mean(axis=1)
    cb = b.mean(axis=1)
    H = np.einsum("bni,bnj->bij", a - ca[:, None], b - cb[:, None])
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    D = np.zeros((a.shape[0], 3, 3))
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)
    T = from_rt(R, cb - np.einsum("bij,bj->bi", R, ca))
    bad = (S[:, 1] < 1e-12 * np.maximum(S[:, 0], 1e-300)) | ~usable
    T[bad] = np.nan
    return T
