"""Small dense numerics the solver needs, in numpy alone; scipy only for large sparse problems.

Why: importing scipy.sparse / scipy.linalg / scipy.optimize / scipy.special costs 0.3-0.6 s
(scipy 1.17 rewrites hundreds of docstrings at import), more than a whole 29-board calibration.
The problems rigcal solves on the command line are small (tens to hundreds of parameters), so
the dense path here keeps scipy out of ``rigcal calibrate``; problems above the sparse threshold
import scipy.sparse lazily, where it pays for itself.

* :func:`nnls` - non-negative least squares (Lawson & Hanson's active-set method);
* :func:`maximise_in_polytope` - a small linear program with the origin feasible (simplex with
  Bland's rule, so it terminates on degenerate constraints);
* :func:`chi2_isf` - the chi-square quantile (regularised incomplete gamma, inverted by
  bisection);
* :func:`spd_solver`, :func:`null_space`, :func:`block_diag`, and the dense-or-sparse helpers
  :func:`issparse`, :func:`assemble`, :func:`scale_rows`, :func:`to_dense`.

Every function is pure: inputs are never modified.
"""

from __future__ import annotations

import math
import sys
from typing import Callable

import numpy as np

_EPS = np.finfo(float).eps


# --- dense or sparse -----------------------------------------------------------------------


def issparse(x) -> bool:
    """True for a scipy.sparse matrix, without importing scipy."""
    return not isinstance(x, np.ndarray) and hasattr(x, "tocsr") and hasattr(x, "nnz")


def to_dense(x) -> np.ndarray:
    return x.toarray() if issparse(x) else np.asarray(x)


def assemble(rows, cols, vals, shape: tuple[int, int], dense: bool):
    """The matrix with ``vals`` summed at (``rows``, ``cols``) (duplicates add up, as COO):
    a numpy array when ``dense``, else a scipy CSR matrix."""
    rows = np.asarray(rows, dtype=np.intp).ravel()
    cols = np.asarray(cols, dtype=np.intp).ravel()
    vals = np.asarray(vals, dtype=float).ravel()
    if dense:
        m, n = shape
        flat = np.bincount(rows * n + cols, weights=vals, minlength=m * n)
        return flat.reshape(m, n)
    import scipy.sparse

    return scipy.sparse.coo_matrix((vals, (rows, cols)), shape=shape).tocsr()


def scale_rows(M, s: np.ndarray):
    """``diag(s) @ M`` for a dense or sparse ``M`` (a new matrix)."""
    s = np.asarray(s, dtype=float)
    if issparse(M):
        return M.multiply(s[:, None]).tocsr()
    return np.asarray(M) * s[:, None]


def block_diag(*blocks: np.ndarray) -> np.ndarray:
    """The block-diagonal matrix of square or rectangular 2-D ``blocks``."""
    mats = [np.atleast_2d(np.asarray(b, dtype=float)) for b in blocks]
    out = np.zeros((sum(m.shape[0] for m in mats), sum(m.shape[1] for m in mats)))
    r = c = 0
    for m in mats:
        out[r : r + m.shape[0], c : c + m.shape[1]] = m
        r, c = r + m.shape[0], c + m.shape[1]
    return out


# --- threads ----------------------------------------------------------------------------------

_THREADPOOLS = None


def single_threaded():
    """A context manager limiting the BLAS/OpenMP thread pools to one thread (small dense
    problems: threads cost more than they bring, and study workers run one per core). The
    thread pools are looked up once per process (threadpoolctl's lookup costs about a
    millisecond, as much as a small solve)."""
    global _THREADPOOLS
    from threadpoolctl import ThreadpoolController

    # scipy brings its own BLAS when it is first imported (large sparse problems): look again
    scipy_loaded = "scipy" in sys.modules
    if _THREADPOOLS is None or _THREADPOOLS[1] != scipy_loaded:
        _THREADPOOLS = (ThreadpoolController(), scipy_loaded)
    return _THREADPOOLS[0].limit(limits=1)


# --- dense linear algebra --------------------------------------------------------------------


def spd_solver(M: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``b -> M^-1 b`` for the symmetric positive definite ``M`` (checked by its Cholesky
    factor); raises ``numpy.linalg.LinAlgError`` when ``M`` is not positive definite."""
    M = np.array(M, dtype=float)  # a copy: the solver keeps it
    L = np.linalg.cholesky(M)
    if not np.all(np.isfinite(L)):
        raise np.linalg.LinAlgError("Cholesky factor is not finite")

    # the Cholesky factor proves M positive definite; numpy has no triangular solve (two
    # np.linalg.solve calls on L would factor it twice), so one LU solve of M itself - half
    # the work, and backward stable for a positive definite M
    def solve(b: np.ndarray) -> np.ndarray:
        return np.linalg.solve(M, b)

    return solve


def null_space(A: np.ndarray, rcond: float | None = None) -> np.ndarray:
    """An orthonormal basis (n, k) of the null space of ``A`` (m, n), from its SVD."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    m, n = A.shape
    if m == 0:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    if rcond is None:
        rcond = _EPS * max(m, n)
    tol = (s.max() if s.size else 0.0) * rcond
    rank = int(np.sum(s > tol))
    return Vt[rank:].T.copy()


# --- non-negative least squares ---------------------------------------------------------------


def nnls(A: np.ndarray, b: np.ndarray, maxiter: int | None = None) -> tuple[np.ndarray, float]:
    """``argmin ||A x - b||`` subject to ``x >= 0``: (x, residual norm).

    Lawson & Hanson's active-set method: columns join the passive set by largest gradient;
    an infeasible subproblem solution is pulled back to the boundary, dropping the columns
    that reach zero. ``maxiter`` bounds the subproblem solves (default 3 n)."""
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float).ravel()
    m, n = A.shape
    if A.ndim != 2 or b.size != m:
        raise ValueError(f"nnls: A is {A.shape} but b has {b.size} entries")
    maxiter = 3 * n if maxiter is None else int(maxiter)
    x = np.zeros(n)
    if n == 0 or m == 0:
        return x, float(np.linalg.norm(b))
    tol = 10.0 * _EPS * float(np.abs(A).sum(axis=0).max()) * max(m, n)
    AtA, Atb = A.T @ A, A.T @ b
    solve = _PassiveSolver(A, b, AtA, Atb)
    w = Atb.copy()
    passive: list[int] = []
    open_ = np.ones(n, dtype=bool)  # neither passive nor blocked
    iterations = 0
    while True:
        ws = np.where(open_, w, -np.inf)
        j = int(ws.argmax())
        if not ws[j] > tol:
            break
        passive.append(j)
        open_[j] = False
        first = True
        while True:
            iterations += 1
            if iterations > maxiter:
                return x, float(np.linalg.norm(A @ x - b))
            P = np.array(passive)
            zP = solve(P)
            if zP.min() > 0.0:
                x = np.zeros(n)
                x[P] = zP
                open_ = np.ones(n, dtype=bool)
                open_[P] = False
                break
            if first and zP[-1] <= 0.0:
                passive.pop()  # the entering column cannot move off zero: blocked this round
                break
            first = False
            xP = x[P]
            bad = zP <= 0.0
            ratios = xP[bad] / (xP[bad] - zP[bad])
            k = int(ratios.argmin())
            xP = xP + float(ratios[k]) * (zP - xP)
            xP[np.flatnonzero(bad)[k]] = 0.0
            x = np.zeros(n)
            x[P] = xP
            keep = xP > 0.0
            passive = [int(i) for i in P[keep]]
            open_[P[~keep]] = True
            if not passive:
                break
        w = Atb - AtA @ x
    return x, float(np.linalg.norm(A @ x - b))


class _PassiveSolver:
    """Least squares on a set of columns: the normal equations (cheap: the passive set is
    small), an SVD solve when they are singular or badly conditioned."""

    def __init__(self, A, b, AtA, Atb):
        self.A, self.b, self.AtA, self.Atb = A, b, AtA, Atb
        self.diag = np.diag(AtA)

    def __call__(self, P: np.ndarray) -> np.ndarray:
        d = self.diag[P]
        if d.min() > 1e-10 * d.max():
            try:
                AtA_P = self.AtA[np.ix_(P, P)]
                ld = np.diag(np.linalg.cholesky(AtA_P))
                if ld.min() > 1e-6 * ld.max():  # cond(A_P) below about 1e6 (for the pivots)
                    return np.linalg.solve(AtA_P, self.Atb[P])
            except np.linalg.LinAlgError:
                pass
        return np.linalg.lstsq(self.A[:, P], self.b, rcond=None)[0]


# --- the vertices of a small polytope ----------------------------------------------------------


def _clip_polygon(poly: np.ndarray, a: np.ndarray, b: float, tol: float) -> tuple[list, list]:
    """Sutherland-Hodgman: the part of the polygon ``poly`` (n, d) (vertices in order) with
    ``a.x <= b``, and its points on the plane ``a.x = b``."""
    dist = poly @ a - b
    out: list = []
    on: list = []
    n = len(poly)
    for i in range(n):
        j = (i + 1) % n
        p, q, dp, dq = poly[i], poly[j], dist[i], dist[j]
        if dp <= tol:
            out.append(p)
            if dp >= -tol:
                on.append(p)
        if (dp < -tol and dq > tol) or (dp > tol and dq < -tol):
            x = p + (q - p) * (dp / (dp - dq))
            out.append(x)
            on.append(x)
    return out, on


def _unique_rows(points, scale: float) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if not len(pts):
        return pts
    key = np.round(pts / (1e-9 * scale))
    _, idx = np.unique(key, axis=0, return_index=True)
    return pts[np.sort(idx)]


def _deepest_cut(V: np.ndarray, A: np.ndarray, b: np.ndarray, tol: float):
    """(a, b_i, A, b): the row that cuts the most off the set with vertices ``V`` and the rows
    left to try (a row that does not cut the set now never will: it only shrinks); a None when
    none cuts."""
    if not len(b) or not len(V):
        return None, None, A[:0], b[:0]
    over = (V @ A.T - b).max(axis=0) / np.linalg.norm(A, axis=1)
    keep = over > tol
    A, b, over = A[keep], b[keep], over[keep]
    if not len(b):
        return None, None, A, b
    i = int(np.argmax(over))
    return A[i], float(b[i]), np.delete(A, i, axis=0), np.delete(b, i)


def polytope_vertices(A: np.ndarray, b: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """(n, k) the vertices of ``{d : A d <= b, |d_i| <= limit_i}`` for k <= 3 and ``b >= 0`` (the
    origin inside): the box clipped by one half-space after the other, the deepest cut first
    (intervals in 1D, polygons in 2D, convex polyhedra as lists of faces in 3D). Then
    ``max c.d`` over the set is ``max(V @ c)`` - what :func:`maximise_in_polytope` finds, for
    any number of ``c`` at once."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    b = np.asarray(b, dtype=float).ravel()
    limit = np.asarray(limit, dtype=float).ravel()
    k = limit.size
    if k == 0 or k > 3 or (A.size and A.shape[1] != k):
        raise ValueError(f"polytope_vertices: k = {k} (1 to 3), A {A.shape}")
    scale = max(1.0, float(np.max(limit)))
    tol = 1e-12 * scale
    A = A.reshape(-1, k)
    nonzero = np.any(A != 0.0, axis=1)
    A, b = A[nonzero], b[nonzero]
    if k == 1:
        col = A[:, 0]
        hi = min([limit[0]] + list(b[col > 0] / col[col > 0]))
        lo = max([-limit[0]] + list(b[col < 0] / col[col < 0]))
        return np.array([[lo], [hi]])
    if k == 2:
        poly = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float) * limit
        while len(poly):
            a, bi, A, b = _deepest_cut(poly, A, b, tol)
            if a is None:
                break
            poly = np.array(_clip_polygon(poly, a, bi, tol)[0]).reshape(-1, 2)
        return _unique_rows(poly, scale)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float) * limit
    # the box's faces, each with its corners in order around it
    faces = [corners[[0, 1, 3, 2]], corners[[4, 5, 7, 6]], corners[[0, 1, 5, 4]],
             corners[[2, 3, 7, 6]], corners[[0, 2, 6, 4]], corners[[1, 3, 7, 5]]]
    while faces:
        a, bi, A, b = _deepest_cut(np.concatenate(faces), A, b, tol)
        if a is None:
            break
        new, cap = [], []
        for f in faces:
            kept, on = _clip_polygon(f, a, bi, tol)
            cap += on
            if len(kept) >= 3:
                new.append(np.array(kept))
        cap = _unique_rows(cap, scale)
        if len(cap) >= 3:
            # the cut face: its points in order around their centre, in the cutting plane
            u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 * np.linalg.norm(a) else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            v = np.cross(a / np.linalg.norm(a), u)
            rel = cap - cap.mean(axis=0)
            new.append(cap[np.argsort(np.arctan2(rel @ v, rel @ u))])
        faces = new
    return _unique_rows(np.concatenate(faces) if faces else np.zeros((0, 3)), scale)


# --- a small linear program -----------------------------------------------------------------


def maximise_in_polytope(
    c: np.ndarray, A: np.ndarray, b: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """``argmax c.d`` subject to ``A d <= b`` and ``|d_i| <= limit_i``, for ``b >= 0`` (the
    origin is feasible; the box keeps the optimum finite).

    Dense tableau simplex on ``d = u - v`` (u, v >= 0) with slack variables: the origin is
    the first basis, and Bland's rule (lowest index enters, lowest index leaves on ties)
    guarantees termination on the degenerate vertices field-of-view constraints produce."""
    c = np.asarray(c, dtype=float).ravel()
    A = np.atleast_2d(np.asarray(A, dtype=float))
    b = np.asarray(b, dtype=float).ravel()
    limit = np.asarray(limit, dtype=float).ravel()
    n = c.size
    if A.shape != (b.size, n) or limit.size != n:
        raise ValueError(f"maximise_in_polytope: A {A.shape}, b {b.shape}, c {c.shape}, limit {limit.shape}")
    if np.any(b < 0) or np.any(limit < 0):
        raise ValueError("maximise_in_polytope: the origin must be feasible (b >= 0, limit >= 0)")
    I = np.eye(n)
    M = np.vstack([np.hstack([A, -A]), np.hstack([I, -I]), np.hstack([-I, I])])  # (r, 2n)
    rhs = np.concatenate([b, limit, limit])
    r = M.shape[0]
    # tableau: [M | I | rhs], objective row: minimise -c.(u - v)
    T = np.zeros((r + 1, 2 * n + r + 1))
    T[:r, : 2 * n] = M
    T[:r, 2 * n : 2 * n + r] = np.eye(r)
    T[:r, -1] = rhs
    T[r, : 2 * n] = np.concatenate([-c, c])
    basis = np.arange(2 * n, 2 * n + r)
    scale = max(1.0, float(np.abs(M).max()), float(np.abs(c).max()) if n else 1.0)
    tol = 1e-11 * scale
    for _ in range(50 * (r + 2 * n) + 100):
        entering = np.flatnonzero(T[r, :-1] < -tol)
        if entering.size == 0:
            break
        j = int(entering[0])
        col = T[:r, j]
        pos = col > tol
        if not np.any(pos):  # cannot happen with the box; guard anyway
            raise ValueError("maximise_in_polytope: unbounded")
        ratios = np.full(r, np.inf)
        ratios[pos] = T[:r, -1][pos] / col[pos]
        best = float(ratios.min())
        ties = np.flatnonzero(ratios <= best + tol * max(1.0, abs(best)))
        i = int(ties[np.argmin(basis[ties])])
        T[i] = T[i] / T[i, j]
        others = np.arange(r + 1) != i
        T[others] -= np.outer(T[others, j], T[i])
        basis[i] = j
    else:
        raise ValueError("maximise_in_polytope: no optimum within the iteration limit")
    y = np.zeros(2 * n + r)
    y[basis] = T[:r, -1]
    d = y[:n] - y[n : 2 * n]
    return np.clip(d, -limit, limit)


# --- chi-square quantile -----------------------------------------------------------------------


def _gamma_q(a: float, x: float) -> float:
    """The regularised upper incomplete gamma function Q(a, x)."""
    if x <= 0.0:
        return 1.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:  # series for P(a, x)
        term = total = 1.0 / a
        k = a
        for _ in range(10000):
            k += 1.0
            term *= x / k
            total += term
            if abs(term) < abs(total) * 1e-16:
                break
        return max(0.0, 1.0 - total * math.exp(log_front))
    # continued fraction for Q(a, x) (modified Lentz)
    tiny = 1e-300
    bb = x + 1.0 - a
    cc = 1.0 / tiny
    dd = 1.0 / bb
    h = dd
    for i in range(1, 10000):
        an = -i * (i - a)
        bb += 2.0
        dd = an * dd + bb
        dd = tiny if abs(dd) < tiny else dd
        cc = bb + an / cc
        cc = tiny if abs(cc) < tiny else cc
        dd = 1.0 / dd
        delta = dd * cc
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(log_front) * h


def chi2_sf(x: float, dof: float) -> float:
    """P(X > x) for X ~ chi-square with ``dof`` degrees of freedom."""
    return _gamma_q(0.5 * dof, 0.5 * x)


def chi2_isf(p: float, dof: float) -> float:
    """The x with P(X > x) = ``p`` for X ~ chi-square(``dof``) (0 < p < 1)."""
    if not 0.0 < p < 1.0 or dof <= 0:
        raise ValueError(f"chi2_isf: need 0 < p < 1 and dof > 0, got p={p}, dof={dof}")
    lo, hi = 0.0, max(1.0, float(dof))
    while chi2_sf(hi, dof) > p:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_sf(mid, dof) > p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-14 * hi:
            break
    return 0.5 * (lo + hi)


__all__ = [
    "assemble",
    "block_diag",
    "chi2_isf",
    "chi2_sf",
    "issparse",
    "maximise_in_polytope",
    "nnls",
    "null_space",
    "polytope_vertices",
    "scale_rows",
    "single_threaded",
    "spd_solver",
    "to_dense",
]
