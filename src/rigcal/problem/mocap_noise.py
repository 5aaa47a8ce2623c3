"""What one sensor's motion-capture residuals are made of, estimated from the residuals.

At the solution of a motion-capture calibration (:mod:`rigcal.problem.mocap`) a sensor's
residuals ``r`` (n,), whitened by its configured sigma, are modelled as

    r = X b + e_point + sum_f U_f a_f + sum_f u_f j_f + sum_g U_g c_g

* ``X`` (n, p): the fixed effects - the sensor's pose (6 columns) and, when the robot or
  the target moved, the clock offset between the MCS and the sensor (one column);
* ``e_point ~ N(0, s2 I)``: every measured point or pixel on its own (the sensor's noise);
* ``a_f ~ N(0, capture I6)`` per **capture** (sensor frame) f, through ``U_f = Jd_f L_f``: the
  MCS's pose error of the robot and the target at that frame (``L_f L_f'`` its shape: the
  scatter the MCS streams themselves show, or a default shape);
* ``j_f ~ N(0, jitter)`` per capture, through ``u_f = Jd_f xi_f``: a timing error of the
  frame's stamp [s] times the target's velocity relative to the robot ``xi_f``;
* ``c_g ~ N(0, hold I6)`` per **hold** g (the target held still), through ``U_g = Jd_g L_g``,
  shared by every frame of the hold: the MCS's error of the still target and what the
  extractor makes of one view;
* ``k_e ~ N(0, edge)`` per frame and side of a plate's outline, on a lidar's ring ends (rows
  of known variance, see :func:`fit_components`): the ends of one revolution on one straight
  side fall at nearly the same place within their steps;
* ``d_g ~ N(0, view_affine I6)`` per hold of a camera's grid: an affine distortion of the
  grid's image, what a corner detector gets wrong in one view. For a small grid it spans
  nearly the same directions as the hold's pose error but in another shape (a target-pose
  error of the same size in every direction would claim the view's strong directions as
  uncertain as its weak ones); the likelihood chooses between them, and as a *family* the
  per-hold components are kept when dropping them all costs more than the test's level.

``Jd_f`` maps a right perturbation of the frame's ``T_robot_target`` to the residuals. The
variance components ``(s2, capture, jitter, hold)`` are estimated by restricted maximum
likelihood (REML: the likelihood of the residuals with the fixed effects projected out), in
the low-dimensional space the random effects span (Woodbury), so it costs little even for
thousands of lidar points. A component estimated from few groups (four holds) is uncertain:
its degrees of freedom come from the REML curvature, and :func:`sandwich` widens its part of
the covariance so that a 6-DOF region holds the truth as often as it says. The MCS's part of
the per-hold error is one MCS's in every sensor's holds: :func:`fit_shared` estimates it from
all of them together, and :func:`fit_components` holds a component at such a value
(``fixed``) while it estimates the others.

The estimate is by default the solver's least-squares one, with the sandwich covariance ``A^-1
(X' V X / s2 + P) A^-1``, ``A = X' X / s2 + P`` (:func:`sandwich`), where ``P`` is the prior of
the clock offset (a pseudo-observation ``offset / sigma``) - so an offset the data cannot tell
from the pose widens the pose's covariance instead of hiding in it. Every frame is weighted
alike, so where per-hold or per-capture MCS errors dominate it is less accurate than the data
allow and its error grows with the noise the residuals show. ``MocapOptions.estimator = "gls"``
takes the generalised least-squares estimate under the estimated ``V`` instead (:func:`gls`:
one weighted step from the solution) with the covariance ``C = (X' V^-1 X + P)^-1`` plus what
the weights' own uncertainty adds (Kenward-Roger), where :func:`weighting_test` accepts the
model's weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs
from scipy.optimize import minimize, minimize_scalar
from scipy.stats import chi2, f as f_dist

__all__ = ["COMPONENTS", "Components", "SHARED", "Shared", "effective_dof", "fit_components", "fit_shared",
           "NoiseCovariance", "gls", "ls_step", "sandwich", "weighting_test", "widening"]

#: the random effects besides the per-point noise, in the order of the parameters
COMPONENTS = ("capture", "jitter", "hold_rot", "hold", "view_affine", "edge")
#: components that model the same errors in different shapes: the last of a family is kept
#: when dropping the whole family costs more than LIKELIHOOD_RATIO
FAMILIES = {"hold_rot": "hold", "hold": "hold", "view_affine": "hold"}
#: the grouped component (a random offset per keypoint coordinate and hold), after COMPONENTS
VIEW = "view"
#: the loading of the view component's part in the pose directions (taken out of it)
VIEW_POSE = "view_pose"
#: the part of a GLS covariance that the weights' own uncertainty adds (:func:`gls`)
WEIGHTS = "weights"
#: a variance component is kept when dropping it raises -2 log REML by more than this (a test
#: of a variance on the boundary at about the 5 % level)
LIKELIHOOD_RATIO = 2.71
#: components estimated from many groups (one per keypoint coordinate and hold) whose zero
#: estimate is replaced by the largest value
#: the data do not exclude: -2 log L within UPPER_DEVIANCE of the optimum (a one-sided 84 %
#: bound)
UPPER_COMPONENTS = ("view",)
UPPER_DEVIANCE = 1.0
_SWEEPS = 4
#: sweeps stop when one lowers -2 log L by less than this (the tests compare differences of 2.71)
_SWEEP_GAIN = 1e-4


@dataclass(frozen=True)
class Components:
    """Estimated variance components of one sensor (whitened units: ``s2`` multiplies the
    configured sigma squared; the others are the variances of their random effects, in the
    units their loadings were built in). ``dof[c]``: the degrees of freedom of component
    ``c``'s estimate (from the REML curvature; ``inf`` when it is known far better than it
    matters, 0 when it was not estimated); ``floored[c]``: its estimate was below its floor."""

    s2: float
    values: Mapping[str, float]
    dof: Mapping[str, float]
    floored: Mapping[str, bool]
    #: covariance of the logs of the estimated variances (``"point"`` and every component kept
    #: and not floored), from the REML curvature: how uncertain the noise model is
    log_cov: Mapping[tuple[str, str], float] = None  # type: ignore[assignment]
    #: -2 log REML at the estimate (compare fits of the same residuals: nested models)
    deviance: float = float("nan")
    #: components held at a value estimated elsewhere (:func:`fit_shared`), not from these
    #: residuals alone
    fixed: frozenset = frozenset()

    def get(self, name: str) -> float:
        return float(self.values.get(name, 0.0))


def _basis(X: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, k) of the column space of ``X`` (numerically independent
    columns only)."""
    if X.shape[1] == 0:
        return X
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    keep = s > 1e-9 * max(float(s.max()), 1e-300)
    return U[:, keep]


def _chol(a: np.ndarray) -> np.ndarray | None:
    """The lower Cholesky factor of a symmetric ``a`` (LAPACK, without the checks of
    :func:`scipy.linalg.cho_factor`: called thousands of times per fit), or None when ``a`` is
    not positive definite."""
    c, info = dpotrf(a, lower=1, clean=0)
    return c if info == 0 else None


def _chol_solve(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` from :func:`_chol`'s factor; ``b`` (k,) or (k, m)."""
    x, _ = dpotrs(c, b.reshape(len(b), -1), lower=1)
    return x.reshape(b.shape)


class _Reml:
    """-2 log REML likelihood of ``r`` under ``V = B + sum_c theta_c U_c U_c'`` with
    ``B = s2 I + view Z Z'`` (``Z``: the indicator of each row's group, block diagonal, inverted
    in closed form) and the column space of ``X`` projected out; the low-rank ``U`` part by
    Woodbury, so every evaluation costs O(K^3) for K random effects, whatever the rows."""

    def __init__(self, r: np.ndarray, X: np.ndarray, loadings: Mapping[str, np.ndarray],
                 groups: np.ndarray | None = None, known: np.ndarray | None = None):
        self.n = len(r)
        known = np.zeros(self.n, dtype=bool) if known is None else np.asarray(known, dtype=bool)
        if groups is not None and np.any(known & (np.asarray(groups) >= 0)):
            raise ValueError("rows of known variance cannot be in a view group")
        self.n_known = int(known.sum())
        Q = _basis(X)
        self.p = Q.shape[1]
        self.names = [c for c in COMPONENTS if c in loadings and loadings[c].shape[1] > 0]
        Us = [loadings[c] for c in self.names]
        self.sizes = [u.shape[1] for u in Us]
        # the view component's part in the pose directions, taken out: loaded with the view's
        # variance and the opposite sign
        vp = loadings.get(VIEW_POSE)
        self.vp = 0 if vp is None or groups is None or not np.any(np.asarray(groups) >= 0) else vp.shape[1]
        if self.vp:
            Us = Us + [vp]
        U = np.hstack(Us) if Us else np.zeros((self.n, 0))
        self.K = U.shape[1]
        # every inner product needed: of Y = [U Q r], and of its sums over each group
        Y = np.column_stack([U, Q, r])
        # rows of known (unit) variance - a ring end's, not the sensor's noise - apart
        self.YY = Y[~known].T @ Y[~known]
        self.YYk = Y[known].T @ Y[known]
        self.units = [max(float(np.sum(u * u)) / self.n, 1e-300) for u in Us[:len(self.sizes)]]
        self.by_size: dict[int, np.ndarray] = {}
        self.n_grouped = 0
        if groups is not None and np.any(groups >= 0):
            g = np.asarray(groups)
            ids, inverse, counts = np.unique(g[g >= 0], return_inverse=True, return_counts=True)
            S = np.zeros((len(ids), Y.shape[1]))
            np.add.at(S, inverse, Y[g >= 0])
            for size in np.unique(counts):
                Ss = S[counts == size]
                self.by_size[int(size)] = Ss.T @ Ss
            self.group_counts = counts
            self.n_grouped = int(np.sum(counts))
            self.names.append("view")
            self.units.append(float(np.sum(counts * counts)) / self.n)
        self.unit = np.array(self.units)
        self._blocks(U, groups, K0=self.K - self.vp)

    def _blocks(self, U: np.ndarray, groups: np.ndarray | None, K0: int) -> None:
        """The random effects that share no row (nor a view group) are independent: ``N`` is
        block diagonal over them (one block per hold in a mocap session) and is factored block
        by block - O(sum k_b^3) instead of O(K^3). Each block lists its positive-sign effects
        first, then the view's pose part (negative sign)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        n, K = U.shape
        rows, cols = np.nonzero(U)
        # nodes: the rows, then the effects, then the view groups
        a, b = [rows], [n + cols]
        if groups is not None and np.any(np.asarray(groups) >= 0):
            g = np.asarray(groups)
            a.append(np.flatnonzero(g >= 0))
            b.append(n + K + g[g >= 0])
            n_g = int(g.max()) + 1
        else:
            n_g = 0
        a, b = np.concatenate(a), np.concatenate(b)
        size = n + K + n_g
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(size, size))
        _, label = connected_components(graph, directed=False)
        of = label[n:n + K]
        self.blocks = []
        for lab in np.unique(of):
            idx = np.flatnonzero(of == lab)
            idx = np.concatenate([idx[idx < K0], idx[idx >= K0]])  # positive signs first
            neg = int(np.sum(idx >= K0))
            self.blocks.append((idx, neg, np.r_[np.ones(len(idx) - neg), -np.ones(neg)]))
        # each block's inner products (and their sums over the view groups), and every
        # effect's with the fixed effects and the residuals
        self.YY_tall = self.YY[:, K:]
        self.YYk_tall = self.YYk[:, K:]
        self.W_tall = {size: W[:, K:] for size, W in self.by_size.items()}
        # blocks of one shape (as many effects, as many of them negative: the holds of one
        # sensor usually are) are stacked and factored together
        shapes: dict[tuple[int, int], list[int]] = {}
        for b, (idx, neg, _) in enumerate(self.blocks):
            shapes.setdefault((len(idx), neg), []).append(b)
        self.stacks = []
        for (k, neg), members in shapes.items():
            idx = np.stack([self.blocks[b][0] for b in members])  # (m, k)
            pick = (idx[:, :, None], idx[:, None, :])
            self.stacks.append(_Stack(idx=idx, positive=k - neg, signs=self.blocks[members[0]][2],
                                      YY=self.YY[pick], YYk=self.YYk[pick],
                                      W={size: W[pick] for size, W in self.by_size.items()}))

    def theta(self, phi: np.ndarray) -> tuple[float, np.ndarray]:
        return float(np.exp(phi[0])), np.exp(phi[1:]) / self.unit

    def __call__(self, phi: np.ndarray) -> float:
        s2, th = self.theta(phi)
        K, p = self.K, self.p
        view = th[-1] if self.by_size else 0.0
        th = th[: len(self.sizes)]
        if self.vp:
            th = np.r_[th, view]
            sizes = self.sizes + [self.vp]
        else:
            sizes = self.sizes
        # B = s2 I + view Z Z' in closed form: Y' B^-1 Y = (Y'Y - sum_g view/(s2 + n_g view)
        # S_g S_g') / s2, and log |B|
        coef = {size: view / (s2 + size * view) for size in self.by_size}
        logdetB = (self.n - self.n_grouped - self.n_known) * np.log(s2)
        if self.by_size:
            c = self.group_counts
            logdetB += float(np.sum((c - 1) * np.log(s2) + np.log(s2 + c * view)))
        T = self.YY_tall.copy()
        for size, W in self.W_tall.items():
            T -= coef[size] * W
        T /= s2
        if self.n_known:
            T += self.YYk_tall
        UQ, Ur = T[:K, :p], T[:K, p]
        QQ, Qr, rr = T[K:K + p, :p], T[K:K + p, p], float(T[-1, p])
        g = np.sqrt(np.repeat(th, sizes)) if K else np.zeros(0)
        # V = B + W E W' (W = U g, E the signs): V^-1 = B^-1 - B^-1 W N^-1 W' B^-1 with
        # N = E + W' B^-1 W, and log |V| = log |B| + log |det N|; N block by block
        gUQ = g[:, None] * UQ
        gUr = g * Ur
        rhs = np.column_stack([gUQ, gUr])
        sol = np.empty_like(rhs)
        logdetM = 0.0
        for st in self.stacks:
            G = st.YY.copy()
            for size, W in st.W.items():
                G -= coef[size] * W
            G /= s2
            if self.n_known:
                G += st.YYk
            gb = g[st.idx]
            N = gb[:, :, None] * G * gb[:, None, :]
            k = st.idx.shape[1]
            N[:, np.arange(k), np.arange(k)] += st.signs
            out = _factor_solve(N, st.positive, rhs[st.idx])
            if out is None:
                return 1e300
            logdetM += out[0]
            sol[st.idx] = out[1]
        MiQ, Mir = sol[:, :-1], sol[:, -1]
        QVQ = QQ - gUQ.T @ MiQ
        QVr = Qr - gUQ.T @ Mir
        rVr = rr - float(gUr @ Mir)
        logdetV = logdetB + logdetM
        if not p:
            return float(logdetV + rVr)
        cq = _chol(QVQ)
        if cq is None:
            return 1e300
        logdetQ = 2.0 * float(np.sum(np.log(np.diag(cq))))
        rPr = rVr - float(QVr @ _chol_solve(cq, QVr))
        if not rPr >= 0.0:  # a quadratic form of a covariance: negative only by cancellation
            return 1e300
        return float(logdetV + logdetQ + rPr)


@dataclass(frozen=True)
class _Stack:
    """Blocks of one shape, stacked: ``idx`` (m, k) the effects of each block (its ``positive``
    positive-sign effects first, ``signs`` (k,)), and their inner products ``YY``, ``YYk``
    (m, k, k) and per view-group size ``W[size]`` (m, k, k)."""

    idx: np.ndarray
    positive: int
    signs: np.ndarray
    YY: np.ndarray
    YYk: np.ndarray
    W: Mapping[int, np.ndarray]


def _chol_stack(a: np.ndarray) -> np.ndarray | None:
    """The lower Cholesky factors of a stack of symmetric matrices (m, k, k), or None when one
    of them is not (numerically) positive definite."""
    try:
        c = np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        return None
    return c if np.all(np.isfinite(c)) else None


def _chol_solve_stack(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` for every matrix of a stack from :func:`_chol_stack`'s factors ``c`` (m, k, k);
    ``b`` (m, k, j). LAPACK's triangular solves block by block: numpy solves a stack only by LU,
    several times slower."""
    if c.shape[1] == 1:  # the jitter's lone effects: a division
        return b / np.square(c)
    out = np.empty(b.shape)
    for i in range(len(c)):
        out[i], _ = dpotrs(c[i], b[i], lower=1)
    return out


def _inverse_curvature(H: np.ndarray, checked: int | None = None) -> np.ndarray:
    """The inverse of -2 log L's curvature ``H`` in the log parameters; where it is not finite or
    not positive on the diagonal (its first ``checked`` entries; all when None), the inverse of
    ``H``'s diagonal instead (each parameter as if alone)."""
    try:
        Hi = np.linalg.inv(H)
        d = np.diag(Hi) if checked is None else np.diag(Hi)[:checked]
        if not np.all(np.isfinite(Hi)) or np.any(d <= 0):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        Hi = np.diag(1.0 / np.maximum(np.diag(H), 1e-12))
    return Hi


def _diag(c: np.ndarray) -> np.ndarray:
    """The diagonals (m, k) of a stack of matrices (m, k, k)."""
    return np.diagonal(c, axis1=-2, axis2=-1)


def _factor_solve(N: np.ndarray, P: int, rhs: np.ndarray) -> tuple[float, np.ndarray] | None:
    """``sum log |det N_b|`` and ``N_b^-1 rhs_b`` over a stack of symmetric matrices ``N``
    (m, k, k) whose first ``P`` signs are positive and the rest negative (``rhs`` (m, k, j)),
    or None where one of them has not exactly that inertia.

    The view's pose part enters with a negative sign: V is a covariance only where it stays
    positive definite, i.e. (Haynsworth's inertia) where N has exactly as many negative
    eigenvalues as the signs. Elsewhere log |V| and r' V^-1 r are numbers of no likelihood
    (seen: -2 log L = -3e11 at a point noise of 1e-11, which the search then took). The test by
    blocks: N = [[A, B], [B', D]] with A positive definite and the Schur complement
    D - B' A^-1 B negative definite - two Cholesky factors (an eigendecomposition of N cost
    10x more), all blocks of the stack at once."""
    m, k, _ = N.shape
    if P == k:
        cf = _chol_stack(N)
        if cf is None:
            return None
        return 2.0 * float(np.sum(np.log(_diag(cf)))), _chol_solve_stack(cf, rhs)
    if not np.all(np.isfinite(N)):
        return None
    if P:
        ca = _chol_stack(N[:, :P, :P])
        if ca is None:
            return None
        both = _chol_solve_stack(ca, np.concatenate([N[:, :P, P:], rhs[:, :P]], axis=2))
        AiB, y = both[:, :, :k - P], both[:, :, k - P:]
        pa = _diag(ca) ** 2
    else:
        AiB, y, pa = np.zeros((m, 0, k)), rhs[:, :0], np.zeros((m, 0))
    BT = N[:, P:, :P]
    cs = _chol_stack(BT @ AiB - N[:, P:, P:])
    if cs is None:
        return None
    pivots = np.concatenate([pa, _diag(cs) ** 2], axis=1)
    scale = np.maximum(np.abs(_diag(N)).max(axis=1), 1e-300)
    if not np.all(np.isfinite(pivots)) or np.any(pivots < 1e-12 * scale[:, None]):
        return None
    # the Schur complement is -C C': x_V = -(C C')^-1 (rhs_V - B' y)
    xv = -_chol_solve_stack(cs, rhs[:, P:] - BT @ y)
    return float(np.sum(np.log(pivots))), np.concatenate([y - AiB @ xv, xv], axis=1)


def _search_box(f: _Reml) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The residuals' degrees of freedom and variance ``v0`` (fixed effects projected out), and
    the bounds of the log parameters searched (``[log s2, log theta...]`` around ``v0``)."""
    dof_resid = max(f.n - f.n_known - f.p, 1)
    v0 = max(float(f.YY[-1, -1]) / dof_resid, 1e-300)
    m = len(f.names)
    lo = np.log(v0) + np.r_[-30.0, np.full(m, -30.0)]
    hi = np.log(v0) + np.r_[5.0, np.full(m, 12.0)]
    return dof_resid, v0, lo, hi


def fit_components(r: np.ndarray, X: np.ndarray, loadings: Mapping[str, np.ndarray],
                   floors: Mapping[str, float] | None = None, groups: np.ndarray | None = None,
                   known: np.ndarray | None = None,
                   fixed: Mapping[str, tuple[float, float]] | None = None) -> Components:
    """REML estimates of the variance components of one sensor's whitened residuals ``r``
    (n,) with fixed effects ``X`` (n, p) and random-effect loadings ``loadings[c]`` (n, k_c)
    for ``c`` in :data:`COMPONENTS` (missing or empty: not in the model), and ``groups`` (n,):
    each row's group for the ``"view"`` component (a random offset per group shared by its
    rows: one keypoint coordinate in every frame of one hold; -1: none). ``floors[c]``: the
    least value a component may take (a known lower bound: the MCS's own scatter); the
    estimate is raised to it and its dof set to ``inf`` (a floor is not an estimate).
    ``known`` (n,) bool: rows whose own variance is known (1, whitened: a lidar ring's end,
    whose std is the scan's step) - they share the random effects but not ``s2``.
    ``fixed[c] = (value, dof)``: component ``c`` held at ``value`` (estimated elsewhere with
    ``dof`` degrees of freedom: the per-hold error of an MCS pooled over the sensors,
    :func:`fit_shared`) while the others are estimated around it."""
    r = np.asarray(r, dtype=float)
    n = len(r)
    floors = dict(floors or {})
    f = _Reml(r, X, loadings, groups, known)
    dof_resid, v0, lo, hi = _search_box(f)
    m = len(f.names)
    if groups is None:
        groups = np.full(n, -1)
    # held components: their bounds collapsed onto the value (zero: the lower bound)
    fixed = {c: (float(v), float(d)) for c, (v, d) in (fixed or {}).items() if c in f.names}
    held = frozenset(f.names.index(c) + 1 for c in fixed)
    for c, (v, _) in fixed.items():
        i = f.names.index(c) + 1
        if v > 0:
            lo[i] = hi[i] = float(np.clip(np.log(v * f.unit[i - 1]), lo[i], hi[i]))
        else:
            hi[i] = lo[i]

    def fit(off: frozenset[int], starts):
        """The REML optimum with the components ``off`` held at zero (their lower bound): from
        each start, sweeps of one-dimensional searches over every parameter in turn (robust on
        this surface, whose valleys run along the bounds), then a quasi-Newton polish."""
        b_hi = hi.copy()
        for i in off:
            b_hi[i] = lo[i]
        best_x, best_f = None, np.inf
        for x0 in starts:
            x = np.clip(np.asarray(x0, dtype=float), lo, b_hi)
            fx = f(x)
            for _ in range(_SWEEPS):
                before = fx
                for i in range(len(x)):
                    if b_hi[i] <= lo[i]:
                        continue

                    def along(v, i=i):
                        y = x.copy()
                        y[i] = v
                        return f(y)

                    v, fv = _line_min(along, x[i], fx, lo[i], b_hi[i])
                    if fv < fx:
                        x[i], fx = v, fv
                if before - fx < _SWEEP_GAIN:
                    break
            res = minimize(f, x, method="L-BFGS-B", bounds=list(zip(lo, b_hi)))
            if res.fun < fx:
                x, fx = res.x, float(res.fun)
            if fx < best_f:
                best_x, best_f = x, fx
        return best_x, float(best_f)

    # a component stays only when the residuals need it: dropping it must cost more than
    # LIKELIHOOD_RATIO in -2 log L (backward elimination); a spurious small one would
    # otherwise be estimated from almost nothing (its few degrees of freedom then widen the
    # covariance for nothing)
    off: frozenset[int] = frozenset()
    family_ref: dict[str, float] = {}
    phi, dev = fit(off, [np.log(v0) + np.r_[0.0, np.full(m, start)] for start in (0.5, -3.0)])
    while True:
        live = [i for i in range(1, m + 1)
                if i not in off and i not in held and phi[i] > np.log(v0) - 12.0]
        trials = sorted(((fit(off | {i}, [phi]), i) for i in live), key=lambda t: t[0][1])
        chosen = None
        for (phi_d, dev_d), i in trials:
            # the last one of a family of components (the per-hold errors) is tested against
            # the deviance before any of its family was dropped: two components that explain
            # the same errors each cost little to drop while the other takes over
            family = FAMILIES.get(f.names[i - 1])
            others = [j for j in live if j != i and FAMILIES.get(f.names[j - 1]) == family]
            ref = dev if family is None or others else family_ref.get(family, dev)
            if dev_d - ref <= LIKELIHOOD_RATIO:
                chosen = (phi_d, dev_d, i, family)
                break
        if chosen is None:
            break
        phi_d, dev_d, i, family = chosen
        if family is not None:
            family_ref.setdefault(family, dev)
        off = off | {i}
        phi, dev = phi_d, dev_d
    s2, th = f.theta(phi)
    # a component at (next to) its lower bound is zero: it explains nothing
    values = {c: (0.0 if i + 1 in off or phi[i + 1] <= np.log(v0) - 12.0 else float(v))
              for i, (c, v) in enumerate(zip(f.names, th))}
    values.update({c: v for c, (v, _) in fixed.items()})
    # ... but zero is only what the data cannot tell from zero: a component estimated from many
    # groups (every keypoint of every hold, every capture) takes the largest value the data
    # do not exclude (-2 log L within UPPER_DEVIANCE of its optimum), a bound it knows tightly
    bounded = [i for i, c in enumerate(f.names) if c in UPPER_COMPONENTS and values[c] == 0.0]
    # degrees of freedom from the curvature of -2 log L in the log parameters:
    # var(log theta_c) = 2 [H^-1]_cc, dof = 2 / var. A component estimated at (next to) zero
    # contributes nothing: its dof do not matter (inf)
    dof = {c: float("inf") for c in f.names}
    live = [i for i in range(1, m + 1)
            if i not in off and i not in held and phi[i] > np.log(v0) - 12.0]
    idx = [0] + live
    Hi = _inverse_curvature(_hessian(f, phi, idx))
    labels = ["point"] + [f.names[i - 1] for i in live]
    log_cov = {(a, b): float(2.0 * Hi[ia, ib]) for ia, a in enumerate(labels) for ib, b in enumerate(labels)}
    for k, i in enumerate(idx[1:], start=1):
        var = 2.0 * Hi[k, k]
        dof[f.names[i - 1]] = float(2.0 / var) if var > 0 else 1.0
    dof["point"] = float(2.0 / (2.0 * Hi[0, 0])) if Hi[0, 0] > 0 else float(dof_resid)
    for i in bounded:
        values[f.names[i]] = _upper(f, phi, i + 1, dev, np.log(v0))
        dof[f.names[i]] = float("inf")  # a bound, not an estimate
    for c, (v, d) in fixed.items():
        dof[c] = d if v > 0 else float("inf")
    floored = {}
    for c in (*COMPONENTS, VIEW):
        low = float(floors.get(c, 0.0))
        floored[c] = c in values and values[c] < low
        if floored[c]:
            values[c] = low
            dof[c] = float("inf")
            log_cov = {k: v for k, v in log_cov.items() if c not in k}
        elif c not in values and low > 0:
            values[c] = low
    return Components(s2=s2, values=values, dof=dof, floored=floored, log_cov=log_cov,
                      deviance=float(dev), fixed=frozenset(fixed))


#: the per-hold components an MCS's error of a still target loads (rotation [rad^2],
#: translation [m^2] of the target's pose): the same MCS in every sensor's holds
SHARED = ("hold_rot", "hold")


@dataclass(frozen=True)
class Shared:
    """Variance components common to several sensors' residuals (:func:`fit_shared`):
    ``values[c]`` (0: not needed), ``dof[c]`` (from the joint REML curvature) and ``gain``
    (-2 log L the components gain over none of them)."""

    values: Mapping[str, float]
    dof: Mapping[str, float]
    gain: float

    def kept(self) -> dict[str, tuple[float, float]]:
        return {c: (v, self.dof[c]) for c, v in self.values.items() if v > 0}


def fit_shared(sensors: Sequence[Mapping], names: Sequence[str] = SHARED) -> Shared:
    """REML estimates of the components ``names`` as **one** variance common to every sensor in
    ``sensors`` (each a mapping with ``r``, ``X``, ``loadings`` and optionally ``groups``,
    ``known``: the arguments of :func:`fit_components`), each sensor's other components its own.
    The MCS's error of a still target is the same MCS's in every sensor's holds: four holds per
    sensor cannot show it (2-3 degrees of freedom), the holds of several sensors together can.
    The loadings must be in the same units for every sensor (the target's pose perturbation).
    A sensor's residuals are independent of another's given the components, so -2 log REML is
    the sum of the sensors'. The shared components are kept when dropping them costs more than
    LIKELIHOOD_RATIO (as a family, as in :func:`fit_components`). With fewer than two sensors
    that load them, nothing is estimated (every value 0)."""
    names = tuple(names)
    fs, los, his, v0s = [], [], [], []
    for s in sensors:
        f = _Reml(np.asarray(s["r"], dtype=float), s["X"], s["loadings"], s.get("groups"), s.get("known"))
        if not all(c in f.names for c in names):
            continue
        _, v0, lo, hi = _search_box(f)
        fs.append(f)
        v0s.append(v0)
        los.append(lo)
        his.append(hi)
    none = Shared({c: 0.0 for c in names}, {c: float("inf") for c in names}, 0.0)
    if len(fs) < 2:
        return none
    k = len(names)
    pos = [[f.names.index(c) + 1 for c in names] for f in fs]
    logunit = [np.log([f.unit[i - 1] for i in p]) for f, p in zip(fs, pos)]
    own = [[i for i in range(len(f.names) + 1) if i not in p] for f, p in zip(fs, pos)]
    # the shared log variances' range: every sensor's, in the common units
    s_lo = np.min([lo[p] - u for lo, p, u in zip(los, pos, logunit)], axis=0)
    s_hi = np.max([hi[p] - u for hi, p, u in zip(his, pos, logunit)], axis=0)
    zero = np.array([min(np.log(v0) - 12.0 - u[j] for v0, u in zip(v0s, logunit)) for j in range(k)])

    def full(j: int, psi: np.ndarray, phi: np.ndarray) -> np.ndarray:
        x = phi.copy()
        x[pos[j]] = np.clip(psi + logunit[j], los[j][pos[j]], his[j][pos[j]])
        return x

    def fit(off: frozenset[int], psi: np.ndarray, phis: list[np.ndarray]):
        """Coordinate sweeps: each sensor's own parameters against its own likelihood, the
        shared ones against the sum."""
        psi = np.where([j in off for j in range(k)], s_lo, np.clip(psi, s_lo, s_hi))
        phis = [p.copy() for p in phis]
        parts = [f(full(j, psi, p)) for j, (f, p) in enumerate(zip(fs, phis))]
        for _ in range(3 * _SWEEPS):
            before = sum(parts)
            for j, f in enumerate(fs):
                for i in own[j]:
                    def along(v, j=j, i=i):
                        y = phis[j].copy()
                        y[i] = v
                        return f(full(j, psi, y))

                    v, fv = _line_min(along, phis[j][i], parts[j], los[j][i], his[j][i])
                    if fv < parts[j]:
                        phis[j][i], parts[j] = v, fv
            for c in range(k):
                if c in off:
                    continue

                def total(v, c=c):
                    y = psi.copy()
                    y[c] = v
                    return sum(f(full(j, y, p)) for j, (f, p) in enumerate(zip(fs, phis)))

                v, fv = _line_min(total, psi[c], sum(parts), s_lo[c], s_hi[c])
                if fv < sum(parts):
                    psi[c] = v
                    parts = [f(full(j, psi, p)) for j, (f, p) in enumerate(zip(fs, phis))]
            if before - sum(parts) < _SWEEP_GAIN:
                break
        return psi, phis, float(sum(parts))

    # start: each sensor's own parameters at a common guess, the shared ones where the sensors'
    # residual variance puts them
    phis0 = [np.log(v0) + np.r_[0.0, np.full(len(f.names), -3.0)] for f, v0 in zip(fs, v0s)]
    psi0 = np.mean([np.log(v0) - 3.0 - u for v0, u in zip(v0s, logunit)], axis=0)
    psi, phis, dev = fit(frozenset(), psi0, phis0)
    base_psi, base_phis, base_dev = fit(frozenset(range(k)), psi, phis)
    # backward elimination as in fit_components: one of the two dropped when it costs little
    # while the other takes over; the last against the deviance with both (the family's test)
    full_dev = dev
    off: frozenset[int] = frozenset()
    while True:
        live = [c for c in range(k) if c not in off and psi[c] > zero[c]]
        if not live:
            break
        if len(live) > 1:
            trials = [(fit(off | {c}, psi, phis), c) for c in live]
            (psi_d, phis_d, dev_d), c = min(trials, key=lambda t: t[0][2])
            if dev_d - dev > LIKELIHOOD_RATIO:
                break
        else:
            if base_dev - full_dev > LIKELIHOOD_RATIO:
                break
            (psi_d, phis_d, dev_d), c = (base_psi, base_phis, base_dev), live[0]
        off = off | {c}
        psi, phis, dev = psi_d, phis_d, dev_d
    live = [c for c in range(k) if c not in off and psi[c] > zero[c]]
    if not live:
        return none
    # degrees of freedom: the joint curvature of -2 log L in the shared log variances and every
    # sensor's own live parameters (block by sensor: the sensors share only the shared ones)
    own_live = [[i for i in own[j] if i == 0 or phis[j][i] > np.log(v0s[j]) - 12.0] for j in range(len(fs))]
    size = len(live) + sum(len(o) for o in own_live)
    H = np.zeros((size, size))
    at = len(live)
    for j, f in enumerate(fs):
        idx = list(range(len(live))) + list(range(at, at + len(own_live[j])))

        def sub(x, j=j):
            y = psi.copy()
            y[live] = x[:len(live)]
            z = phis[j].copy()
            z[own_live[j]] = x[len(live):]
            return fs[j](full(j, y, z))

        x0 = np.r_[psi[live], phis[j][own_live[j]]]
        H[np.ix_(idx, idx)] += _hessian(sub, x0, list(range(len(x0))))
        at += len(own_live[j])
    var = 2.0 * np.diag(_inverse_curvature(H, checked=len(live)))[:len(live)]
    values = {c: 0.0 for c in names}
    dof = {c: float("inf") for c in names}
    for a, c in enumerate(live):
        values[names[c]] = float(np.exp(psi[c]))
        dof[names[c]] = float(2.0 / var[a])
    return Shared(values, dof, float(base_dev - dev))


#: the line search's tolerance in a log variance, and its first step
_XATOL = 1e-3
_FIRST_STEP = 0.5


def _line_min(fun, x0: float, f0: float, a: float, b: float) -> tuple[float, float]:
    """The minimum of ``fun`` over ``[a, b]`` near ``x0`` (where it is ``f0``): steps that double
    from ``x0`` downhill until the value rises bracket it (three points, the middle lowest),
    then Brent's parabolic search from that bracket; downhill to a bound (or not lower on the
    one side ``x0``'s bound leaves), :func:`_at_bound`. (A bounded search over the whole range
    cost about twice the evaluations: most sweeps start next to the optimum.)"""
    side = []
    for d in (1.0, -1.0):
        x1 = min(max(x0 + d * _FIRST_STEP, a), b)
        if x1 == x0:
            side.append(None)
            continue
        f1 = fun(x1)
        if f1 < f0:
            break
        side.append((x1, f1))
    else:  # not lower on either side: the minimum is within a step of x0 (or at x0's bound)
        hi, lo = side
        if hi is not None and lo is not None:
            return _brent(fun, lo, (x0, f0), hi)
        other = hi or lo
        return _at_bound(fun, (x0, f0), other)
    prev, cur, step = (x0, f0), (x1, f1), _FIRST_STEP
    while True:
        step *= 2.0
        nxt = min(max(cur[0] + d * step, a), b)
        if nxt == cur[0]:  # downhill to the bound
            return _at_bound(fun, cur, prev)
        f_nxt = fun(nxt)
        if f_nxt >= cur[1]:
            return _brent(fun, prev, cur, (nxt, f_nxt))
        prev, cur = cur, (nxt, f_nxt)


_GOLD = 0.3819660112501051  # (3 - sqrt 5) / 2


def _brent(fun, p, m, q) -> tuple[float, float]:
    """The minimum of ``fun`` inside a bracket of (x, f) points ``p, m, q`` (``m`` between them
    and not higher than either): parabolas through the three best points, a golden-section step
    into the larger side where a parabola's vertex is not well inside, until the bracket is
    narrower than twice the tolerance (Brent's method, from the bracket's known values)."""
    (a, fa), (x, fx), (c, fc) = sorted((p, m, q))
    if not (fx <= fa and fx <= fc):
        return _bounded(fun, a, c, min((a, fa), (x, fx), (c, fc), key=lambda t: t[1]))
    # w, v: the second and third best points
    (w, fw), (v, fv) = sorted(((a, fa), (c, fc)), key=lambda t: t[1])
    for _ in range(100):
        if c - a <= 2.0 * _XATOL:
            break
        u = None
        den = 2.0 * ((x - w) * (fx - fv) - (x - v) * (fx - fw))
        if den != 0.0:
            u = x - ((x - w) ** 2 * (fx - fv) - (x - v) ** 2 * (fx - fw)) / den
            # a vertex that is outside, next to an end, or barely moves is not taken
            if not (a + _XATOL < u < c - _XATOL) or abs(u - x) < 0.5 * _XATOL:
                u = None
        if u is None:
            u = x + _GOLD * (c - x) if c - x > x - a else x - _GOLD * (x - a)
        fu = fun(u)
        if fu <= fx:
            if u < x:
                c = x
            else:
                a = x
            (v, fv), (w, fw), (x, fx) = (w, fw), (x, fx), (u, fu)
        else:
            if u < x:
                a = u
            else:
                c = u
            if fu <= fw or w == x:
                (v, fv), (w, fw) = (w, fw), (u, fu)
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
    return x, fx


def _at_bound(fun, edge, inner) -> tuple[float, float]:
    """A minimum next to a bound ``edge`` (x, f), with ``inner`` a point inside not lower: the
    bound itself when the value rises within the tolerance from it (most often: a variance
    component the residuals do not need, at its lower bound), else the bounded search
    between the two."""
    x, fx = edge
    u = x + np.sign(inner[0] - x) * _XATOL
    if fun(u) >= fx:
        return edge
    return _bounded(fun, min(x, inner[0]), max(x, inner[0]), edge)


def _bounded(fun, lo: float, hi: float, best) -> tuple[float, float]:
    r = minimize_scalar(fun, bounds=(lo, hi), method="bounded", options={"xatol": _XATOL})
    return min(best, (float(r.x), float(r.fun)), key=lambda t: t[1])


def _upper(f: _Reml, phi: np.ndarray, i: int, dev: float, log_v0: float) -> float:
    """The largest value of parameter ``i`` (the others held at ``phi``) whose -2 log REML stays
    within UPPER_DEVIANCE of ``dev``: bisection in the log parameter."""
    lo, hi = log_v0 - 12.0, log_v0 + 12.0
    x = phi.copy()

    def excess(v: float) -> float:
        x[i] = v
        return f(x) - dev - UPPER_DEVIANCE

    if excess(lo) > 0:
        return 0.0
    if excess(hi) < 0:
        x[i] = hi
        return float(f.theta(x)[1][i - 1])
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if excess(mid) > 0:
            hi = mid
        else:
            lo = mid
    x[i] = lo
    return float(f.theta(x)[1][i - 1])


def _hessian(f, phi: np.ndarray, idx: list[int], h: float = 1e-2) -> np.ndarray:
    k = len(idx)
    H = np.zeros((k, k))
    f0 = f(phi)
    for a in range(k):
        for b in range(a, k):
            ea = np.zeros_like(phi)
            eb = np.zeros_like(phi)
            ea[idx[a]] = h
            eb[idx[b]] = h
            if a == b:
                H[a, a] = (f(phi + ea) - 2 * f0 + f(phi - ea)) / h**2
            else:
                H[a, b] = H[b, a] = (f(phi + ea + eb) - f(phi + ea - eb) - f(phi - ea + eb)
                                     + f(phi - ea - eb)) / (4 * h**2)
    return H


def widening(dof: float, dim: int = 6) -> float:
    """How much wider the part of a covariance estimated with ``dof`` degrees of freedom must be
    for a ``dim``-DOF 95 % region to hold the truth 95 % of the time: ``dim F_0.95(dim, dof) /
    chi2_0.95(dim)`` (1 for ``dof`` large or unknown)."""
    if not np.isfinite(dof) or dof <= 0 or dof > 1e6:
        return 1.0
    dof = max(dof, 1.0)
    return float(dim * f_dist.ppf(0.95, dim, dof) / chi2.ppf(0.95, dim))


def sandwich(X: np.ndarray, loadings: Mapping[str, np.ndarray], comp: Components,
             prior: np.ndarray | None = None, groups: np.ndarray | None = None,
             known: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The (p, p) covariance of the least-squares estimate of the fixed effects ``X`` (n, p)
    when the residuals have the covariance of ``comp``, by source: ``"point"``, each random
    component of ``loadings``, and ``"prior"``; their sum is the covariance. ``prior`` (p,):
    per fixed effect the inverse std of a zero-mean prior (0: none) - a pseudo-observation the
    estimate also fits (the truth drawn from it). ``known`` (n,) bool: rows of known unit
    variance (see :func:`fit_components`), their part ``"known"``."""
    s2 = comp.s2
    p = X.shape[1]
    P = np.diag(np.square(prior)) if prior is not None else np.zeros((p, p))
    known = np.zeros(len(X), dtype=bool) if known is None else np.asarray(known, dtype=bool)
    # B^-1 X: every row weighted by its own variance (s2, or 1 where it is known)
    Xw = np.where(known[:, None], X, X / s2)
    XXp = X[~known].T @ X[~known] / s2
    XXk = X[known].T @ X[known]
    A = XXp + XXk + P
    Ai = np.linalg.pinv(A, rcond=1e-13)
    parts = {"point": Ai @ XXp @ Ai}
    if known.any():
        parts["known"] = Ai @ XXk @ Ai
    for c, U in loadings.items():
        if c == VIEW_POSE:
            continue
        v = comp.get(c)
        if U.shape[1] == 0 or v <= 0:
            continue
        UX = U.T @ Xw
        parts[c] = Ai @ (v * (UX.T @ UX)) @ Ai
    v = comp.get("view")
    if groups is not None and v > 0 and np.any(groups >= 0):
        g = np.asarray(groups)
        ids, inverse = np.unique(g[g >= 0], return_inverse=True)
        S = np.zeros((len(ids), p))
        np.add.at(S, inverse, Xw[g >= 0])
        meat = S.T @ S
        vp = loadings.get(VIEW_POSE)
        if vp is not None and vp.shape[1]:
            VX = vp.T @ Xw
            meat = meat - VX.T @ VX
        parts["view"] = Ai @ (v * meat) @ Ai
    if prior is not None:
        parts["prior"] = Ai @ P @ Ai
    return {k: 0.5 * (v + v.T) for k, v in parts.items()}


class NoiseCovariance:
    """The residuals' covariance ``V`` under ``comp`` (see :func:`gls`), factored once:
    ``solve(M)`` is ``V^-1 M`` without forming ``V`` - the view groups' part in closed form
    (each group ``s2 I + view 1 1'``), the low-rank components (sparse: each loads the rows of
    one capture or hold) by Woodbury."""

    def __init__(self, loadings: Mapping[str, np.ndarray], comp: Components, groups: np.ndarray | None,
                 known: np.ndarray | None, n: int):
        from scipy import sparse
        from scipy.linalg import lu_factor

        self.known = np.zeros(n, dtype=bool) if known is None else np.asarray(known, dtype=bool)
        s2 = comp.s2
        self.d = np.where(self.known, 1.0, s2)
        self.view = view = comp.get(VIEW)
        g = None if groups is None else np.asarray(groups)
        self.grouped = g is not None and view > 0 and bool(np.any(g >= 0))
        if self.grouped:
            self.sel = np.flatnonzero(g >= 0)
            self.ids, self.inverse, counts = np.unique(g[self.sel], return_inverse=True, return_counts=True)
            self.coef = view / (s2 * (s2 + counts * view))
            # rows to groups (a sum over each group's rows)
            self.G = sparse.csr_matrix((np.ones(len(self.sel)), (self.inverse, self.sel)), shape=(len(self.ids), n))
        # the low-rank part: every kept component's loading, and the view's pose part (negative)
        self.names, self.Us, weights = [], [], []
        for c, Uc in loadings.items():
            if c == VIEW_POSE:
                continue
            v = comp.get(c)
            if Uc.shape[1] and v > 0:
                self.names.append(c)
                self.Us.append(sparse.csc_matrix(np.asarray(Uc, dtype=float)))
                weights.append(np.full(Uc.shape[1], v))
        vp = loadings.get(VIEW_POSE)
        self.vp = None
        if self.grouped and vp is not None and vp.shape[1]:
            self.vp = np.asarray(vp, dtype=float)
            self.Us.append(sparse.csc_matrix(self.vp))
            weights.append(np.full(vp.shape[1], -view))
        self.U = None
        self.weights = np.concatenate(weights) if weights else np.zeros(0)
        if self.Us:
            self.U = sparse.hstack(self.Us).tocsc()
            self.BiU = self._b_inv_sparse(self.U)
            N = np.diag(1.0 / self.weights) + (self.U.T @ self.BiU).toarray()
            self.N = lu_factor(N)

    def _b_inv_sparse(self, U):
        from scipy import sparse

        out = sparse.diags(1.0 / self.d) @ U
        if self.grouped:
            out = out - self.G.T @ (sparse.diags(self.coef) @ (self.G @ U))
        return out.tocsc()

    def group_sums(self, M: np.ndarray) -> np.ndarray:
        """(groups, k): the sum of ``M``'s rows (n, k) over each view group (``grouped`` only)."""
        return np.asarray(self.G @ M)

    def _b_inv(self, M: np.ndarray) -> np.ndarray:
        out = M / self.d[:, None]
        if self.grouped:
            out[self.sel] -= self.coef[self.inverse, None] * self.group_sums(M)[self.inverse]
        return out

    def solve(self, M: np.ndarray) -> np.ndarray:
        from scipy.linalg import lu_solve

        BiM = self._b_inv(M)
        if self.U is None:
            return BiM
        return BiM - self.BiU @ lu_solve(self.N, self.U.T @ BiM)

    def diagonal(self) -> np.ndarray:
        """``diag(V)``: each row's variance under the model."""
        var = self.d.copy()
        if self.U is not None:
            var += np.asarray(self.U.multiply(self.U) @ self.weights).ravel()
        if self.grouped:
            var[self.sel] += self.view
        return var


def gls(r: np.ndarray, X: np.ndarray, loadings: Mapping[str, np.ndarray], comp: Components,
        prior: np.ndarray | None = None, prior_mean: np.ndarray | None = None,
        groups: np.ndarray | None = None, known: np.ndarray | None = None, robust=None,
        vcov: "NoiseCovariance | None" = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The generalised least-squares step from the fixed effects at which ``r`` was taken, and
    the covariance of the estimate it reaches, by source (as :func:`sandwich`'s parts).

    With ``V`` the residuals' covariance under ``comp`` (the point noise, every random component
    of ``loadings``, the view groups) the step ``d`` minimises ``(r + X d)' V^-1 (r + X d) +
    |P^1/2 (m + d)|^2`` (``P = diag(prior^2)``: the prior of :func:`sandwich`, ``prior_mean``
    (p,) the fixed effects' current values relative to the prior's mean, e.g. the clock offset
    already estimated). The estimate's covariance is ``C = (X' V^-1 X + P)^-1``, split as ``C X'
    V^-1 V_c V^-1 X C`` over the sources ``c`` (and ``C P C``), so that Satterthwaite's degrees
    of freedom (:func:`effective_dof`) count what each estimated component contributes. Unlike
    the least-squares estimate, the GLS one is uncorrelated with the residual contrasts the
    components are estimated from (REML's), so its region's widening for the estimated noise
    holds: where per-hold errors dominate, least squares (every frame weighted alike) lets the
    size of its error move the noise estimate with it.

    ``robust``: a robust loss's derivative ``rho'(u^2)`` (1 inside its scale): a row whose
    residual is far outside its std under ``V`` (``u = r_i / sqrt(V_ii)``: per-hold and
    per-capture errors included, so a view's shift is not an outlier) weighs ``sqrt(rho')`` in
    the step, an outlier as the solver's robust loss would have it.

    ``vcov``: ``V`` already factored (:class:`NoiseCovariance` of the same arguments), to reuse
    for several ``X``."""
    r = np.asarray(r, dtype=float)
    X = np.asarray(X, dtype=float)
    n, p = X.shape
    V = vcov if vcov is not None else NoiseCovariance(loadings, comp, groups, known, n)
    s2, known, view = comp.s2, V.known, V.view
    names, Us, grouped, vp = V.names, V.Us, V.grouped, V.vp
    v_inv = V.solve
    if robust is not None:
        w = np.sqrt(np.asarray(robust(r * r / np.maximum(V.diagonal(), 1e-300)), dtype=float))
        r, X = w * r, w[:, None] * X
    ViM = v_inv(np.column_stack([X, r]))
    ViX, Vir = ViM[:, :p], ViM[:, p]
    P = np.diag(np.square(prior)) if prior is not None else np.zeros((p, p))
    mean = np.zeros(p) if prior_mean is None else np.asarray(prior_mean, dtype=float)
    A = X.T @ ViX + P
    A = 0.5 * (A + A.T)
    C = np.linalg.pinv(A, rcond=1e-13)
    step = -C @ (X.T @ Vir + P @ mean)
    # each source's share V_c V^-1 X of V V^-1 X = X (the rows of known variance apart), and
    # the parts of C by source: C X' V^-1 V_c V^-1 X C
    shares = {"point": np.where(known[:, None], 0.0, s2 * ViX)}
    for c, Uc in zip(names, Us):
        shares[c] = comp.get(c) * (Uc @ (Uc.T @ ViX))
    if grouped:
        F = np.zeros((n, p))
        F[V.sel] = V.group_sums(ViX)[V.inverse]
        if vp is not None and vp.shape[1]:
            F = F - vp @ (vp.T @ ViX)
        shares[VIEW] = view * F
    meats = {c: ViX.T @ F for c, F in shares.items()}  # X' V^-1 V_c V^-1 X
    parts = {c: C @ M @ C for c, M in meats.items()}
    if known.any():
        parts["known"] = C @ (ViX[known].T @ ViX[known]) @ C
    if prior is not None:
        parts["prior"] = C @ P @ C
    # the weights are estimated: the GLS estimate moves with them and C, computed with them,
    # is too small on average (Kackar-Harville; Kenward-Roger's 2 Lambda, V linear in the
    # variances): Lambda = C [sum_ab W_ab (Q_ab - P_a C P_b)] C with W the covariance of the
    # variances' estimates (in logs: comp.log_cov, else 2 / dof), and for each source a its
    # share V_a of V: P_a = -X'V^-1 V_a V^-1 X, Q_ab = X'V^-1 V_a V^-1 V_b V^-1 X
    labels = list(shares)
    lc = comp.log_cov or {}
    m = len(labels)
    W = np.zeros((m, m))
    for a, na in enumerate(labels):
        if comp.floored.get(na) or na in comp.fixed or (na, na) not in lc:
            dof = comp.dof.get(na, float("inf"))
            if np.isfinite(dof) and dof > 0 and not comp.floored.get(na):
                W[a, a] = 2.0 / dof
            continue
        for b, nb in enumerate(labels):
            if nb not in comp.fixed and (na, nb) in lc:
                W[a, b] = lc[(na, nb)]
    if np.any(W):
        Fs = [shares[c] for c in labels]
        ViF = [v_inv(F) for F in Fs]
        Pm = [meats[c] for c in labels]  # -P_a
        inner = np.zeros((p, p))
        for a in range(m):
            for b in range(m):
                if W[a, b]:
                    inner += W[a, b] * (Fs[a].T @ ViF[b] - Pm[a] @ C @ Pm[b])
        parts[WEIGHTS] = 2.0 * C @ (0.5 * (inner + inner.T)) @ C
    return step, {k: 0.5 * (v + v.T) for k, v in parts.items()}


def ls_step(r: np.ndarray, X: np.ndarray, comp: Components, prior: np.ndarray | None = None,
            prior_mean: np.ndarray | None = None, known: np.ndarray | None = None) -> np.ndarray:
    """The least-squares step from the fixed effects at which ``r`` was taken (the estimate
    :func:`sandwich` gives the covariance of: rows weighted by ``1 / s2``, those of ``known``
    variance by 1, the prior as in :func:`gls`). At a solver's solution it is about zero, but not
    quite where a robust loss weighed rows down: the weighting test compares like with like."""
    p = X.shape[1]
    known = np.zeros(len(X), dtype=bool) if known is None else np.asarray(known, dtype=bool)
    w = np.where(known, 1.0, 1.0 / comp.s2)
    P = np.diag(np.square(prior)) if prior is not None else np.zeros((p, p))
    mean = np.zeros(p) if prior_mean is None else np.asarray(prior_mean, dtype=float)
    A = X.T @ (w[:, None] * X) + P
    return -np.linalg.pinv(0.5 * (A + A.T), rcond=1e-13) @ (X.T @ (w * r) + P @ mean)


#: the weighting test (:func:`weighting_test`) rejects the noise model's weights above this
#: quantile of its chi-square
WEIGHTING_LEVEL = 0.99


def weighting_test(step: np.ndarray, ls_cov: np.ndarray, gls_cov: np.ndarray) -> tuple[float, int]:
    """Hausman's test of the noise model's weights: under the model the GLS estimate and the
    least-squares one (:func:`gls` and :func:`ls_step` of the same residuals) differ by ``step``
    with covariance ``ls_cov - gls_cov`` (the GLS one is the
    efficient of the two), so ``step' (ls_cov - gls_cov)^+ step`` is chi-square with as many
    degrees of freedom as the difference has directions. A larger value says the residuals
    hold errors the model does not describe (a template cloud's discretisation, a bias of the
    extractor): weighted by the model the estimate would move by more than its noise allows.
    Returns the statistic and the degrees of freedom (directions in which weighting changes
    the covariance by more than 1e-6 of least squares')."""
    ls_cov = 0.5 * (ls_cov + ls_cov.T)
    w, Q = np.linalg.eigh(ls_cov)
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    if not keep.any():
        return 0.0, 0
    Wh = Q[:, keep] / np.sqrt(w[keep])  # whitens the least-squares covariance
    D = Wh.T @ (ls_cov - gls_cov) @ Wh
    lam, E = np.linalg.eigh(0.5 * (D + D.T))
    on = lam > 1e-6
    if not on.any():
        return 0.0, 0
    u = E[:, on].T @ (Wh.T @ step)
    return float(np.sum(u * u / lam[on])), int(on.sum())


def effective_dof(parts: Mapping[str, np.ndarray], comp: Components, dim: int | None = None) -> float:
    """Satterthwaite's degrees of freedom of a covariance made of ``parts`` (by source,
    :func:`sandwich`), each estimated with ``comp.dof[name]`` degrees of freedom (the point
    noise with ``comp.dof["point"]``; missing or floored: known): ``(sum w)^2 / sum(w^2 /
    dof)`` with ``w`` each part's share ``trace(C^-1 C_part)`` over the first ``dim``
    parameters. The components' correlations are left out: two that trade for each other
    count as uncertain as each is alone (conservative)."""
    total = sum(parts.values())
    k = dim or total.shape[0]
    Ci = np.linalg.pinv(total[:k, :k], rcond=1e-12)
    num, den = 0.0, 0.0
    for name, Cp in parts.items():
        w = float(np.trace(Ci @ Cp[:k, :k]))
        num += w
        d = comp.dof.get(name, float("inf")) if not comp.floored.get(name) else float("inf")
        if np.isfinite(d):
            den += w * w / max(d, 1e-9)
    return float(num * num / den) if den > 0 else float("inf")
