"""The calibration problem as data, and a Levenberg-Marquardt solver on SE(3).

A :class:`Problem` is a set of named pose blocks (``T_W_name``; each with a mask of which of its
six local degrees of freedom are free) and batches of residuals bound to those names by value.
Configurations (MCPE, FCPE, PSE, ...) differ only in which blocks and batches they create.
:func:`solve` returns a :class:`Solution` value; it never prints.

Sparsity follows from the bindings: each residual row touches at most two pose blocks. Small
problems use dense normal equations in numpy (:mod:`rigcal.problem.numerics`), large ones
scipy.sparse, imported only then.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from rigcal.errors import ConfigError
from rigcal.geometry.se3 import se3_exp, se3_log
from rigcal.problem.numerics import assemble, block_diag, issparse, nnls, null_space, spd_solver
from rigcal.problem.residuals import (
    MEASURED_DIM,
    MODEL_CAMERA,
    MODEL_SURFACE,
    RESIDUAL_DIM,
    elevation_limit_residuals,
    observation_residuals,
)

log = logging.getLogger(__name__)

#: local degrees of freedom of a pose block, in tangent order (rotation first)
DOF_NAMES = ("roll", "pitch", "yaw", "x", "y", "z")
ALL_FREE = (True,) * 6
SPARSE_ABOVE = 600  # free parameters above which sparse linear algebra is used
LOSSES = ("linear", "huber", "cauchy")


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PoseBlock:
    """A pose ``T_W_name`` (4, 4) to estimate; ``free[i]`` says whether local DOF i may move."""

    name: str
    T: np.ndarray
    free: tuple[bool, ...] = ALL_FREE

    def __post_init__(self) -> None:
        T = np.array(self.T, dtype=float)
        T.setflags(write=False)
        object.__setattr__(self, "T", T)
        object.__setattr__(self, "free", tuple(bool(f) for f in self.free))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Observations:
    """A batch of n point observations (see :mod:`rigcal.problem.residuals`).

    Item i: point ``points[i]`` (3,) fixed in pose block ``frame[i]`` is measured by the sensor
    whose pose block is ``observer[i]`` as ``measured[i]`` (d,) with std ``sigma[i]`` (d,).
    MODEL_SURFACE turns this around: ``measured[i]`` (3,) is a point measured by the observer
    on the surface of frame ``frame[i]``, ``points[i]`` its closest surface point and
    ``normals[i]`` (3,) the surface normal there (both in that frame); ``sigma[i]`` (1,) is the
    std of the point-to-plane distance; with ``surface`` set the closest points follow the
    poses (point-to-surface distance). ``board[i]`` is the board placement the item belongs to; ``label`` names the batch
    (a sensor pair such as ``"lidar1-camera1"`` or a sensor); ``sensor`` names the observer.
    """

    label: str
    sensor: str
    model: str
    frame: tuple[str, ...]
    observer: tuple[str, ...]
    points: np.ndarray
    measured: np.ndarray
    sigma: np.ndarray
    board: np.ndarray
    camera: object | None = None  # a rigcal.sensors.camera model, for MODEL_CAMERA
    normals: np.ndarray | None = None  # (n, 3) unit surface normals, for MODEL_SURFACE
    #: for MODEL_SURFACE: ``closest(points) -> (points, normals)`` in the frame's coordinates;
    #: given, the closest points and normals are found again at every evaluation
    surface: object | None = None

    def __post_init__(self) -> None:
        if self.model not in MEASURED_DIM:
            raise ConfigError(f"unknown measurement model {self.model!r}")
        if self.model == MODEL_CAMERA and self.camera is None:
            raise ConfigError(f"observations '{self.label}': a camera model is needed for pixels")
        if (self.model == MODEL_SURFACE) != (self.normals is not None):
            raise ConfigError(f"observations '{self.label}': surface normals go with (and only with) "
                              f"the {MODEL_SURFACE!r} model")
        n = len(self.frame)
        checks = [
            ("points", self.points, (n, 3)),
            ("measured", self.measured, (n, MEASURED_DIM[self.model])),
            ("sigma", self.sigma, (n, RESIDUAL_DIM[self.model])),
            ("board", self.board, (n,)),
        ]
        if self.normals is not None:
            checks.append(("normals", self.normals, (n, 3)))
        for name, arr, shape in checks:
            a = np.array(arr, dtype=int if name == "board" else float)
            if a.shape != shape:
                raise ConfigError(f"observations '{self.label}': {name} shape {a.shape} != {shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "frame", tuple(self.frame))
        object.__setattr__(self, "observer", tuple(self.observer))

    @property
    def size(self) -> int:
        return len(self.frame)

    @property
    def dim(self) -> int:
        """Residual rows per item."""
        return RESIDUAL_DIM[self.model]

    def with_sigma(self, sigma: np.ndarray) -> "Observations":
        return replace(self, sigma=np.broadcast_to(sigma, (self.size, self.dim)).copy())


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class ElevationLimits:
    """Hinge constraints |elevation(point in observer)| <= max_elevation_rad (paper eq. 4)."""

    label: str
    frame: tuple[str, ...]
    observer: tuple[str, ...]
    points: np.ndarray
    max_elevation_rad: np.ndarray
    board: np.ndarray

    @property
    def size(self) -> int:
        return len(self.frame)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PosePriors:
    """Soft priors on poses: residual ``log(T_prior^-1 T) / sigma`` (6,) per block, rotation
    first (e.g. a motion-capture pose known to 0.15 mm, or a mounting from CAD)."""

    label: str
    blocks: tuple[str, ...]
    T_prior: np.ndarray  # (n, 4, 4)
    sigma: np.ndarray  # (6,) [rad, rad, rad, m, m, m]

    @property
    def size(self) -> int:
        return len(self.blocks)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Problem:
    poses: tuple[PoseBlock, ...]
    observations: tuple[Observations, ...]
    limits: tuple[ElevationLimits, ...] = ()
    priors: tuple[PosePriors, ...] = ()
    #: largest violation of a field-of-view constraint accepted at the solution [rad]
    fov_tolerance_rad: float = 1e-7

    def __post_init__(self) -> None:
        names = [p.name for p in self.poses]
        if len(set(names)) != len(names):
            raise ConfigError(f"duplicate pose blocks: {names}")
        known = set(names)
        for pr in self.priors:
            missing = set(pr.blocks) - known
            if missing:
                raise ConfigError(f"priors '{pr.label}' refer to unknown poses {sorted(missing)}")
        for batch in (*self.observations, *self.limits):
            missing = (set(batch.frame) | set(batch.observer)) - known
            if missing:
                raise ConfigError(f"batch '{batch.label}' refers to unknown poses {sorted(missing)}")

    @property
    def pose_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.poses)

    def pose(self, name: str) -> PoseBlock:
        for p in self.poses:
            if p.name == name:
                return p
        raise KeyError(name)

    def with_poses(self, values: Mapping[str, np.ndarray]) -> "Problem":
        return replace(
            self,
            poses=tuple(replace(p, T=values[p.name]) if p.name in values else p for p in self.poses),
        )

    def with_observations(self, observations: tuple[Observations, ...]) -> "Problem":
        return replace(self, observations=tuple(observations))

    def with_sigmas(self, sigma_by_sensor: Mapping[str, np.ndarray]) -> "Problem":
        """Same structure, observation noise replaced per observing sensor."""
        return replace(
            self,
            observations=tuple(
                b.with_sigma(sigma_by_sensor[b.sensor]) if b.sensor in sigma_by_sensor else b
                for b in self.observations
            ),
        )


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Solution:
    """What :func:`solve` found.

    ``covariance`` is over the free local DOFs (``columns`` maps pose name -> 6 column indices,
    -1 for held DOFs), scaled by the a-posteriori variance factor ``sigma0_sq``.
    ``residuals[i]`` are the whitened residuals (n, d) of ``problem.observations[i]``.
    """

    poses: dict[str, np.ndarray]
    converged: bool
    status: str
    iterations: int
    cost: float
    covariance: np.ndarray
    columns: dict[str, np.ndarray]
    residuals: tuple[np.ndarray, ...]
    limit_residuals: tuple[np.ndarray, ...]
    sigma0_sq: float
    dof: int
    gradient_norm: float
    rank_deficient: bool = False
    #: per observation batch, (n, d) redundancy numbers 1 - h_ii (leverage) of each residual,
    #: from the covariance without the field-of-view limits
    redundancy: tuple[np.ndarray, ...] = ()
    extra: dict = field(default_factory=dict)
    #: 0.5 * the sum of the squared whitened prior residuals at the solution (``cost`` is the
    #: observations' alone); the objective minimised is ``cost + prior_cost``
    prior_cost: float = 0.0

    def pose_covariance(self, name: str) -> np.ndarray:
        """(6, 6) covariance of a pose's local perturbation; zero rows/cols for held DOFs."""
        return self.joint_covariance([name])

    def joint_covariance(self, names) -> np.ndarray:
        """(6k, 6k) joint covariance of the local perturbations of poses ``names`` (in that
        order), cross terms included; zero rows/cols for held DOFs."""
        cols = np.concatenate([self.columns[n] for n in names])
        out = np.zeros((len(cols), len(cols)))
        idx = np.flatnonzero(cols >= 0)
        if idx.size:
            c = cols[idx]
            out[np.ix_(idx, idx)] = self.covariance[np.ix_(c, c)]
        return out


class _Layout:
    """Index bookkeeping shared by every evaluation of one problem."""

    def __init__(self, problem: Problem):
        self.names = problem.pose_names
        self.index = {n: i for i, n in enumerate(self.names)}
        cols = -np.ones((len(self.names), 6), dtype=int)
        k = 0
        for i, p in enumerate(problem.poses):
            for j in range(6):
                if p.free[j]:
                    cols[i, j] = k
                    k += 1
        self.cols = cols
        self.n_free = k
        self.obs_idx = [
            (
                np.array([self.index[f] for f in b.frame], dtype=int),
                np.array([self.index[o] for o in b.observer], dtype=int),
            )
            for b in problem.observations
        ]
        self.lim_idx = [
            (
                np.array([self.index[f] for f in b.frame], dtype=int),
                np.array([self.index[o] for o in b.observer], dtype=int),
            )
            for b in problem.limits
        ]
        self.dense = self.n_free <= SPARSE_ABOVE
        # precomputed scatter of every batch's Jacobian blocks into the dense Jacobian
        self.obs_scatter = []
        row0 = 0
        for b, (ia, ib) in zip(problem.observations, self.obs_idx):
            n, d = b.size, b.dim
            rr = row0 + np.arange(n * d).reshape(n, d)
            slots = []
            for idx in (ia, ib):
                cc = np.broadcast_to(self.cols[idx][:, None, :], (n, d, 6))
                keep = cc >= 0
                rows = np.broadcast_to(rr[:, :, None], (n, d, 6))[keep]
                slots.append((keep, rows, cc[keep], rows * max(self.n_free, 1) + cc[keep]))
            self.obs_scatter.append(slots)
            row0 += n * d
        # per residual row, the (<= 12) columns it can touch; padded with column n_free
        rc = []
        for b, (ia, ib) in zip(problem.observations, self.obs_idx):
            cc = np.concatenate([self.cols[ia], self.cols[ib]], axis=1)  # (n, 12)
            cc = np.where(cc >= 0, cc, self.n_free)
            rc.append(np.repeat(cc, b.dim, axis=0))
        self.row_cols = np.concatenate(rc) if rc else np.zeros((0, 12), dtype=int)
        self.lim_scatter = []
        row0 = 0
        for b, (ia, ib) in zip(problem.limits, self.lim_idx):
            n = b.size
            rr = row0 + np.arange(n)
            slots = []
            for idx in (ia, ib):
                cc = self.cols[idx]
                keep = cc >= 0
                rows = np.broadcast_to(rr[:, None], (n, 6))[keep]
                slots.append((keep, rows, cc[keep], rows * max(self.n_free, 1) + cc[keep]))
            self.lim_scatter.append(slots)
            row0 += n
        # all field-of-view limits as flat arrays
        if problem.limits:
            self.lim_ia = np.concatenate([ia for ia, _ in self.lim_idx])
            self.lim_ib = np.concatenate([ib for _, ib in self.lim_idx])
            self.lim_points = np.concatenate([b.points for b in problem.limits])
            self.lim_max = np.concatenate([b.max_elevation_rad for b in problem.limits])
        self.prior_idx = [np.array([self.index[b] for b in pr.blocks], dtype=int) for pr in problem.priors]
        self.m_obs = sum(b.size * b.dim for b in problem.observations)
        self.m = self.m_obs + sum(b.size for b in problem.limits)


def prepare(problem: Problem) -> "_Layout":
    """Index bookkeeping of a problem's structure; reusable (``solve(..., layout=)``) by any
    problem with the same pose blocks and bindings (e.g. after ``with_poses`` / new sigmas)."""
    return _Layout(problem)


def _robust(s: np.ndarray, loss: str, c: float) -> tuple[np.ndarray, np.ndarray]:
    """rho(s) and rho'(s) for squared norms s."""
    if loss == "linear":
        return s, np.ones_like(s)
    c2 = c * c
    if loss == "huber":
        root = np.sqrt(s)
        inside = s <= c2
        return np.where(inside, s, 2 * c * root - c2), np.where(inside, 1.0, c / np.maximum(root, 1e-300))
    if loss == "cauchy":
        return c2 * np.log1p(s / c2), 1.0 / (1.0 + s / c2)
    raise ConfigError(f"unknown robust loss {loss!r} (expected one of {LOSSES})")


def _evaluate(problem: Problem, layout: _Layout, T: np.ndarray, loss: str, c: float, want_jac: bool):
    """Robustly weighted residual vector, Jacobian and cost of the observations."""
    r_parts, parts = [], []
    raw = []
    cost = 0.0
    for batch, (ia, ib), slots in zip(problem.observations, layout.obs_idx, layout.obs_scatter):
        if batch.size == 0:
            raw.append(np.zeros((0, batch.dim)))
            continue
        r, JA, JB = observation_residuals(
            T[ia], T[ib], batch.points, batch.measured, batch.sigma, batch.model, batch.camera,
            batch.normals, batch.surface,
        )
        raw.append(r)
        s = np.sum(r * r, axis=1)
        if loss == "linear":
            cost += 0.5 * float(np.sum(s))
            r_parts.append(r.ravel())
            if want_jac:
                parts.append((JA, slots[0]))
                parts.append((JB, slots[1]))
            continue
        rho, drho = _robust(s, loss, c)
        cost += 0.5 * float(np.sum(rho))
        w = np.sqrt(drho)[:, None]
        r_parts.append((r * w).ravel())
        if want_jac:
            parts.append((JA * w[:, :, None], slots[0]))
            parts.append((JB * w[:, :, None], slots[1]))
    row0 = sum(p.size for p in r_parts)
    for pr, idx in zip(problem.priors, layout.prior_idx):
        if pr.size == 0:
            continue
        D = np.linalg.inv(pr.T_prior) @ T[idx]
        r = se3_log(D) / pr.sigma
        cost += 0.5 * float(np.sum(r * r))
        r_parts.append(r.ravel())
        if want_jac:
            # d log(T0^-1 T exp(xi)) / d xi ~ identity for small deviations (right Jacobian ~ I)
            n = pr.size
            cc = layout.cols[idx]  # (n, 6) column of each local DOF, -1 if held
            vals = np.broadcast_to(1.0 / pr.sigma, (n, 6)).copy()[:, :, None] * np.eye(6)[None]
            diag = np.broadcast_to(np.eye(6, dtype=bool)[None], (n, 6, 6))
            keep = diag & (np.broadcast_to(cc[:, None, :], (n, 6, 6)) >= 0)
            rows = np.broadcast_to((row0 + np.arange(n * 6).reshape(n, 6))[:, :, None], (n, 6, 6))[keep]
            cols = np.broadcast_to(cc[:, None, :], (n, 6, 6))[keep]
            parts.append((vals, (keep, rows, cols, rows * max(layout.n_free, 1) + cols)))
        row0 += pr.size * 6
    rvec = np.concatenate(r_parts) if r_parts else np.zeros(0)
    J = _scatter(parts, rvec.size, layout) if want_jac else None
    return rvec, J, cost, raw


def _scatter(parts, m, layout):
    n = layout.n_free
    if layout.dense:
        J = np.zeros((m, n))
        flat = J.reshape(-1)
        for vals, (keep, _rows, _cols, idx) in parts:
            flat[idx] = vals[keep]
        return J
    return _assemble(
        [p[1][1] for p in parts], [p[1][2] for p in parts], [p[0][p[1][0]] for p in parts], m, n
    )


def _assemble(rows, cols, vals, m, n):
    return assemble(
        np.concatenate(rows) if rows else np.zeros(0, int),
        np.concatenate(cols) if cols else np.zeros(0, int),
        np.concatenate(vals) if vals else np.zeros(0),
        (m, n),
        dense=n <= SPARSE_ABOVE,
    )


def _constraints(problem: Problem, layout: _Layout, T: np.ndarray, want_jac: bool = True):
    """Field-of-view constraint values c = |elevation| - max (<= 0 is feasible) and dc/dx."""
    if not problem.limits:
        return np.zeros(0), (np.zeros((0, layout.n_free)) if want_jac else None)
    big = 1e6  # shift so the hinge is always active: gives |e| - max and its gradient
    r, JA, JB = elevation_limit_residuals(
        T[layout.lim_ia], T[layout.lim_ib], layout.lim_points, layout.lim_max - big, 1.0
    )
    c = r[:, 0] - big
    if not want_jac:
        return c, None
    G = np.zeros((c.size, layout.n_free))
    flat = G.reshape(-1)
    off = 0
    for b, slots in zip(problem.limits, layout.lim_scatter):
        for J, (keep, _rows, _cols, idx) in zip((JA, JB), slots):
            flat[idx] = J[off : off + b.size, 0, :][keep]
        off += b.size
    return c, G


#: largest rotation [rad] / translation [m] of one pose in one step (a trust region that saves
#: rejected trial steps along weakly observed directions)
MAX_STEP_ROT = 0.1
MAX_STEP_TRANS = 0.5


def _cap_step(delta: np.ndarray, layout: _Layout) -> np.ndarray:
    xi = np.zeros(layout.cols.shape)
    mask = layout.cols >= 0
    xi[mask] = delta[layout.cols[mask]]
    rot = float(np.max(np.linalg.norm(xi[:, :3], axis=1)))
    trans = float(np.max(np.linalg.norm(xi[:, 3:], axis=1)))
    scale = min(1.0, MAX_STEP_ROT / max(rot, 1e-300), MAX_STEP_TRANS / max(trans, 1e-300))
    return (delta * scale, True) if scale < 1.0 else (delta, False)


def _retract(T: np.ndarray, layout: _Layout, delta: np.ndarray) -> np.ndarray:
    xi = np.zeros((T.shape[0], 6))
    mask = layout.cols >= 0
    xi[mask] = delta[layout.cols[mask]]
    moved = np.flatnonzero(np.any(mask, axis=1))
    out = T.copy()
    out[moved] = T[moved] @ se3_exp(xi[moved])
    return out


def _normal(J, r):
    if issparse(J):
        A = (J.T @ J).tocsc()
        g = J.T @ r
        return A, np.asarray(g).ravel()
    return J.T @ J, J.T @ r


def _factor(M):
    """A solver ``b -> M^-1 b`` for the (damped, positive definite) step matrix."""
    if issparse(M):
        import scipy.sparse.linalg

        return scipy.sparse.linalg.splu(M.tocsc()).solve
    try:
        return spd_solver(M)
    except np.linalg.LinAlgError:
        pinv = np.linalg.pinv(M)
        return lambda b: pinv @ b


class _StepQP:
    """The step subproblem ``argmin 0.5 d'Md + g'd  s.t.  c + G d <= 0`` for one M and g,
    reusable for several right-hand sides c (the step and its second-order correction).

    Solved exactly through its dual, ``min_{nu >= 0} 0.5 nu'S nu - nu'(c + G d0)`` with
    ``S = G M^-1 G'`` and ``d0 = -M^-1 g``: a least-distance problem (Lawson & Hanson, ch. 23)
    reduced to one non-negative least-squares problem, which terminates finitely and cannot
    cycle on degenerate or redundant constraints. Infeasible linearisations are relaxed.
    """

    def __init__(self, M, g, G):
        self._solve_m = _factor(M)
        self.d0 = -np.asarray(self._solve_m(g)).ravel()
        self.G = G
        self.E = None

    def _dual(self):
        """The dual's matrices, on the first call that needs them."""
        if self.E is None:
            G = self.G
            MiGt = np.asarray(self._solve_m(G.T)).reshape(G.shape[1], G.shape[0])
            S = G @ MiGt
            s = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))  # rows scaled to unit dual norm
            self.scale = s
            self.MiGt = MiGt * s[None, :]
            Ss = 0.5 * (S + S.T) * np.outer(s, s)
            w, V = np.linalg.eigh(Ss)
            self.E = V * np.sqrt(np.maximum(w, 0.0))[None, :]  # E E' = S (scaled)
            self.S = Ss

    def solve(self, c):
        """(d, multipliers >= 0) of the QP with constraint values ``c``."""
        m = c.size
        if m == 0:
            return self.d0, np.zeros(0)
        f = c + self.G @ self.d0  # violation of the unconstrained step
        if np.all(f <= 0.0):
            return self.d0, np.zeros(m)
        self._dual()
        f = f * self.scale
        shift = 0.0
        for _ in range(30):
            ff = f - shift
            A = np.vstack([self.E.T, ff[None, :]])
            b = np.zeros(m + 1)
            b[-1] = 1.0
            u, _ = nnls(A, b, maxiter=50 * (m + 1))
            denom = 1.0 - float(ff @ u)
            if denom > 1e-10:
                nu = u / denom
                nu = self._polish(nu, ff)
                break
            # the linearised constraints admit no step: relax them, ever more
            shift = max(2.0 * shift, 1e-6 * (1.0 + float(np.max(np.abs(f)))))
        else:
            nu = np.zeros(m)
        d = self.d0 - self.MiGt @ nu
        return d, nu * self.scale

    def _polish(self, nu, f):
        """Solve the equality system on the support of nu exactly, if that stays optimal."""
        P = np.flatnonzero(nu > 1e-14 * max(1.0, float(nu.max())))
        if P.size == 0:
            return nu
        sol = np.linalg.lstsq(self.S[np.ix_(P, P)], f[P], rcond=1e-13)[0]
        if np.all(sol > 0.0):
            out = np.zeros_like(nu)
            out[P] = sol
            slack = self.S @ out - f  # = -(c + G d) scaled: must be >= 0
            if float(np.min(slack)) >= -1e-12 * max(1.0, float(np.max(np.abs(f)))):
                return out
        return nu


def _constrained_step(M, g, c, G):
    """argmin 0.5 d'Md + g'd  s.t.  c + G d <= 0. Returns (d, active mask, multipliers)."""
    d, mult = _StepQP(M, g, G).solve(c)
    return d, mult > 0.0, mult


def _leverage(J: np.ndarray, C: np.ndarray, row_cols: np.ndarray) -> np.ndarray:
    """diag(J C J') using only each row's possible non-zero columns (<= 2 poses per row)."""
    m, n = J.shape
    if m == 0:
        return np.zeros(0)
    Jp = np.concatenate([J, np.zeros((m, 1))], axis=1)
    Cp = np.zeros((n + 1, n + 1))
    Cp[:n, :n] = C
    vals = np.take_along_axis(Jp, row_cols, axis=1)
    Csub = Cp[row_cols[:, :, None], row_cols[:, None, :]]
    return np.einsum("mi,mij,mj->m", vals, Csub, vals)


_FD_STEPS: dict[float, np.ndarray] = {}


def _fd_steps(h: float) -> np.ndarray:
    if h not in _FD_STEPS:
        _FD_STEPS[h] = se3_exp(np.eye(6) * h)
    return _FD_STEPS[h]


def _constraint_hessian(problem, layout, T, mult, h=1e-6):
    """sum_i mult_i * Hessian(c_i) over the active limits (finite differences of analytic
    gradients, vectorised over the 12 local DOFs of each item's two poses)."""
    n = layout.n_free
    H = np.zeros((n, n))
    act = np.flatnonzero(mult > 0)
    if act.size == 0:
        return H
    ia, ib = layout.lim_ia[act], layout.lim_ib[act]
    pts, mx = layout.lim_points[act], layout.lim_max[act] - 1e6
    TA, TB = T[ia], T[ib]
    steps = _fd_steps(h)  # (6, 4, 4)
    k = act.size
    # 13 configurations per item: unperturbed, 6 perturbations of A, 6 of B
    TA_all = np.concatenate([TA[:, None], TA[:, None] @ steps[None], np.repeat(TA[:, None], 6, 1)], 1)
    TB_all = np.concatenate([TB[:, None], np.repeat(TB[:, None], 6, 1), TB[:, None] @ steps[None]], 1)
    _, JA, JB = elevation_limit_residuals(
        TA_all.reshape(-1, 4, 4), TB_all.reshape(-1, 4, 4), np.repeat(pts, 13, 0), np.repeat(mx, 13), 1.0
    )
    grad = np.concatenate([JA[:, 0, :], JB[:, 0, :]], axis=1).reshape(k, 13, 12)
    Hi = (grad[:, 1:, :] - grad[:, :1, :]) / h  # (k, 12 perturbations, 12 gradient entries)
    Hi = 0.5 * (Hi + np.swapaxes(Hi, 1, 2)) * mult[act][:, None, None]
    cols = np.concatenate([layout.cols[ia], layout.cols[ib]], axis=1)  # (k, 12)
    # add every item's block where both columns are free (np.add.at: in item order, repeated
    # entries accumulate)
    keep = (cols[:, :, None] >= 0) & (cols[:, None, :] >= 0)
    flat = cols[:, :, None] * n + cols[:, None, :]
    np.add.at(H.reshape(-1), flat[keep], Hi[keep])
    return H


def _solve_dense_or_sparse(M, rhs):
    if issparse(M):
        import scipy.sparse.linalg

        return scipy.sparse.linalg.spsolve(M.tocsc(), rhs)
    try:
        return spd_solver(M)(rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M, rhs, rcond=None)[0]


def _damped(A, lam):
    if issparse(A):
        import scipy.sparse

        d = A.diagonal()
        return (A + scipy.sparse.diags(lam * np.maximum(d, 1e-12 * max(d.max(), 1e-300)) + 1e-300)).tocsc()
    d = np.diag(A)
    dmax = max(float(d.max()) if d.size else 0.0, 1e-300)
    return A + np.diag(lam * np.maximum(d, 1e-12 * dmax) + 1e-300)


def _try_step(problem, layout, T, delta, loss, loss_scale, merit, rho):
    """Evaluate a trial step: (merit, T, r, J, cost, c, G, capped delta, capped?)."""
    delta, capped = _cap_step(delta, layout)
    T_new = _retract(T, layout, delta)
    r_new, J_new, cost_new, _ = _evaluate(problem, layout, T_new, loss, loss_scale, True)
    c_new, G_new = _constraints(problem, layout, T_new)
    return merit(cost_new, c_new, rho), T_new, r_new, J_new, cost_new, c_new, G_new, delta, capped


def _model_hessian(problem, layout, T, A, mult, Ssec):
    """The step model's Hessian: Gauss-Newton A, plus the constraint curvature sum mult_i
    Hess(c_i) and the secant estimate of the residual curvature where they keep it positive
    definite (the step QP is solved through its convex dual; an indefinite model would give
    an unbounded step). Sparse problems (no secant) get A alone."""
    if issparse(A):
        return A
    parts = []
    if mult is not None and np.any(mult > 0):
        parts.append(_constraint_hessian(problem, layout, T, mult))
    if Ssec is not None and np.any(Ssec):
        parts.append(Ssec)
    for k in range(len(parts), 0, -1):  # all extras, then fewer
        M = A + sum(parts[:k])
        try:
            np.linalg.cholesky(M)
            return M
        except np.linalg.LinAlgError:
            continue
    return A


def _weakest(A, layout: _Layout) -> str:
    """Why a solve may not finish: the least determined direction of the normal matrix, named
    by its pose and degrees of freedom, with the condition number."""
    A = A.toarray() if issparse(A) else np.asarray(A)
    if A.shape[0] == 0 or A.shape[0] > SPARSE_ABOVE:
        return ""
    w, V = np.linalg.eigh(A)
    if w[-1] <= 0:
        return ""
    v = np.abs(V[:, 0])
    k = int(np.argmax(v))
    i = int(np.argwhere(layout.cols == k)[0][0])
    dofs = [DOF_NAMES[j] for j in range(6) if layout.cols[i, j] >= 0 and v[layout.cols[i, j]] > 0.3 * v[k]]
    cond = f"{w[-1] / w[0]:.2g}" if w[0] > w[-1] * 1e-300 else "infinite"  # no overflow warning
    return (
        f"; the least determined direction is {layout.names[i]} {'/'.join(dofs)} (condition number "
        f"{cond}): the boards barely fix it"
    )


def _newton_sigma(A, g, c, G, cost, dof) -> float:
    """Length of the undamped constrained Gauss-Newton step in units of its standard deviation
    (Mahalanobis, covariance A^-1 scaled by the variance factor): ~0 at a KKT point."""
    d, _, _ = _constrained_step(_damped(A, 1e-12), g, c, G)
    return float(np.sqrt(max(float(d @ (A @ d)), 0.0) / max(2.0 * cost / dof, 1e-300)))


def _lm(problem, layout, T, loss, loss_scale, max_iterations, ftol, xtol, gtol, fov_tol, step_sigma, warm=None):
    """Levenberg-Marquardt with linearised field-of-view constraints: per trial step a convex
    QP (solved exactly through its dual, :class:`_StepQP`), an exact l1 merit function whose
    weight exceeds the QP multipliers, a second-order correction when the merit rejects a step
    that the limits' curvature spoilt (Maratos effect), gain-ratio damping, and a restart with
    fresh state from a stall. Returns (T, iterations, converged, status, active mask, LM state,
    last linearisation).

    A small cost change or step ends the iterations only if the undamped constrained
    Gauss-Newton step from there is negligible too (so heavy damping is not taken for
    convergence).

    Besides the usual tolerances it stops when a step is statistically negligible: its
    Mahalanobis length under the current covariance estimate is below ``step_sigma``.
    """

    def merit(cost, c, rho):
        return cost + rho * float(np.sum(np.maximum(c, 0.0)))

    dof = max(layout.m_obs - layout.n_free, 1)
    r, J, cost, _ = _evaluate(problem, layout, T, loss, loss_scale, True)
    J_prev = J
    c, G = _constraints(problem, layout, T)
    A, g = _normal(J, r)
    warm = warm or {}
    lam = warm.get("lam", 1e-4)
    nu_grow = 2.0
    rho = 0.0
    active = np.zeros(c.size, dtype=bool)
    mult = np.zeros(c.size)
    # secant estimate of the residual curvature sum r_i Hess(r_i) that Gauss-Newton drops
    # (Dennis-Gay-Welsch update, as in NL2SOL); dense problems only
    Ssec = np.zeros((layout.n_free, layout.n_free)) if layout.dense else None
    if Ssec is not None and warm.get("secant") is not None and warm["secant"].shape == Ssec.shape:
        Ssec = warm["secant"].copy()
    state = {"lam": lam, "secant": Ssec}
    linz = {}
    it = 0
    resets = 0
    restarts = 0
    for it in range(1, max_iterations + 1):
        linz.update(r=r, J=J, A=A, g=g, c=c, G=G, cost=cost)
        # Hessian of the Lagrangian: Gauss-Newton part, secant correction, active constraints
        AL = _model_hessian(problem, layout, T, A, mult if c.size else None, Ssec)
        feasible = c.size == 0 or float(np.max(c)) <= fov_tol
        if c.size == 0:
            gnorm = float(np.max(np.abs(g))) if g.size else 0.0
            if gnorm <= gtol * max(1.0, cost):
                state.update(lam=lam, secant=Ssec)
                return T, it - 1, True, "gradient below tolerance", active, state, linz
        accepted = False
        while lam < 1e16:
            qp = _StepQP(_damped(AL, lam), g, G)
            delta, mult_new = qp.solve(c)
            act = mult_new > 0.0
            # exact l1 penalty: the weight must exceed every multiplier of the step
            if c.size:
                rho = max(rho, 2.0 * float(np.max(mult_new, initial=0.0)))
            m_old = merit(cost, c, rho)
            tried = _try_step(problem, layout, T, delta, loss, loss_scale, merit, rho)
            if c.size and not tried[0] < m_old and np.any(mult_new > 0.0):
                # Maratos effect: the step's curvature along the binding limits violated them;
                # a second-order correction (the same QP at the limits' values after the step)
                # pulls it back onto them
                c_soc = tried[5] - G @ tried[7]
                soc, mult_soc = qp.solve(c_soc)
                tried_soc = _try_step(problem, layout, T, soc, loss, loss_scale, merit, rho)
                if tried_soc[0] < tried[0]:
                    tried, mult_new = tried_soc, mult_soc
                    act = mult_new > 0.0
            m_new, T_new, r_new, J_new, cost_new, c_new, G_new, delta, capped = tried
            step = float(np.linalg.norm(delta))
            Ad = A @ delta
            # decrease predicted by the model the step minimised (Gauss-Newton, secant and
            # constraint curvature): with the Gauss-Newton part alone a secant-shaped step can
            # look uphill and end the trials before any damping is tried
            predicted = -(g @ delta + 0.5 * delta @ (AL @ delta))
            if c.size:
                lin = c + G @ delta
                predicted += rho * float(np.sum(np.maximum(c, 0)) - np.sum(np.maximum(lin, 0)))
            if m_new < m_old or (m_new <= m_old and step <= xtol):
                accepted = True
                rel = (m_old - m_new) / max(m_old, 1e-300)
                sigma0_sq = max(2.0 * cost / dof, 1e-300)
                # only an (almost) undamped, uncapped step measures distance to the optimum
                maha = (
                    np.inf
                    if capped or lam > 1e-6
                    else float(np.sqrt(max(delta @ Ad, 0.0) / sigma0_sq))
                )
                T, cost, c, G, active, mult = T_new, cost_new, c_new, G_new, act, mult_new
                r, J = r_new, J_new
                # gain ratio: damp more when the quadratic model predicted the decrease badly
                gain = (m_old - m_new) / predicted if predicted > 0 else 0.0
                lam = min(max(lam * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-12), 1e12)
                nu_grow = 2.0
                resets = 0
                break
            if (predicted <= ftol * max(cost, 1e-300) or step <= xtol) and feasible:
                break
            lam *= nu_grow
            nu_grow *= 2.0
        if not accepted:
            if Ssec is not None and np.any(Ssec) and resets < 3:
                # the secant curvature estimate may have spoiled the model: drop it, retry
                Ssec = np.zeros_like(Ssec)
                lam = 1e-3
                nu_grow = 2.0
                resets += 1
                continue
            if not feasible:
                return T, it, False, "cannot satisfy the field-of-view constraints", active, state, linz
            # no decrease possible: a minimum only if the undamped step is negligible
            maha0 = _newton_sigma(A, g, c, G, cost, dof)
            # (or when the decrease that step promises, maha0^2 sigma0^2 / 2, is below the
            # cost's rounding: no merit comparison can resolve it)
            if (
                maha0 <= 10.0 * step_sigma
                or 2.0 * cost / dof <= 1e-20
                or maha0**2 * cost / dof <= ftol * cost
            ):
                return T, it, True, "no further decrease possible (at a minimum)", active, state, linz
            if restarts < 2:
                # restart from here with fresh state (damping, penalty, curvature, multipliers)
                restarts += 1
                lam, nu_grow, rho, resets = 1e-4, 2.0, 0.0, 0
                mult = np.zeros(c.size)
                if Ssec is not None:
                    Ssec = np.zeros_like(Ssec)
                continue
            return (
                T, it, False,
                f"stalled: no decrease possible although the Newton step is {maha0:.3g} sigma",
                active, state, linz,
            )
        g_old, J_old_t_r = g, None
        if Ssec is not None:
            J_old_t_r = J_prev.T @ r
        A, g = _normal(J, r)
        if Ssec is not None:
            y = g - g_old
            y_sharp = g - J_old_t_r
            sy = float(delta @ y)
            if sy > 1e-300:
                Ss = Ssec @ delta
                sSs = float(delta @ Ss)
                tau = min(1.0, abs(float(delta @ y_sharp)) / sSs) if sSs > 0 else 1.0
                Ssec = tau * Ssec
                v = y_sharp - Ssec @ delta
                Ssec = Ssec + (np.outer(v, y) + np.outer(y, v)) / sy - float(v @ delta) * np.outer(y, y) / sy**2
        J_prev = J
        state.update(lam=lam, secant=Ssec)
        linz.update(r=r, J=J, A=A, g=g, c=c, G=G, cost=cost)
        feasible = c.size == 0 or float(np.max(c)) <= fov_tol
        if feasible and maha <= step_sigma and 2.0 * cost / dof > 1e-20:
            return T, it, True, f"step below {step_sigma:g} sigma", active, state, linz
        small = (
            "relative cost change below tolerance" if rel <= ftol
            else "step below tolerance" if step <= xtol * (1.0 + float(np.linalg.norm(T[:, :3, 3])))
            else None
        )
        if feasible and small:
            # a small change may only mean heavy damping: stop only if the undamped
            # (constrained Newton) step from here is statistically negligible too
            if _newton_sigma(A, g, c, G, cost, dof) <= 10.0 * step_sigma or 2.0 * cost / dof <= 1e-20:
                return T, it, True, small, active, state, linz
            lam = min(lam, 1e-4)
    linz.update(r=r, J=J, A=A, g=g, c=c, G=G, cost=cost)
    return T, it, False, "iteration limit reached", active, state, linz


def solve(
    problem: Problem,
    *,
    loss: str = "linear",
    loss_scale: float = 1.0,
    max_iterations: int = 200,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    gtol: float = 1e-10,
    step_sigma: float = 1e-3,
    want_redundancy: bool = False,
    layout: "_Layout | None" = None,
    warm: dict | None = None,
    start: Mapping[str, np.ndarray] | None = None,
) -> Solution:
    """Minimise the problem's cost with Levenberg-Marquardt on the pose manifold, subject to the
    field-of-view limits (paper eq. 4) as inequality constraints.

    Returns a :class:`Solution`; ``converged`` is False when the iteration limit was reached or
    the constraints could not be met.
    """
    if loss not in LOSSES:
        raise ConfigError(f"unknown robust loss {loss!r} (expected one of {LOSSES})")
    layout = layout if layout is not None else prepare(problem)
    if start is not None:  # starting poses other than the problem's own (same structure)
        T = np.stack([np.asarray(start.get(p.name, p.T), dtype=float) for p in problem.poses])
    else:
        T = np.stack([p.T for p in problem.poses]).astype(float)
    if layout.n_free == 0:
        raise ConfigError("nothing to estimate: every pose is held fixed")
    T, it, converged, status, active, state, lin = _lm(
        problem, layout, T, loss, loss_scale, max_iterations, ftol, xtol, gtol,
        problem.fov_tolerance_rad, step_sigma, warm,
    )
    if not converged and max_iterations > 1 and "A" in lin:
        status += _weakest(lin["A"], layout)
    if loss == "linear" and "J" in lin:
        # the last linearisation of the iterations is at the returned poses
        raw = _evaluate(problem, layout, T, loss, loss_scale, False)[3]
        r, J, A, g, c, G = (lin[k] for k in ("r", "J", "A", "g", "c", "G"))
    else:
        r, J, cost, raw = _evaluate(problem, layout, T, loss, loss_scale, True)
        A, g = _normal(J, r)
        c, G = _constraints(problem, layout, T)
    gnorm = float(np.max(np.abs(g))) if g.size else 0.0
    lim_raw = []
    off = 0
    for b in problem.limits:
        lim_raw.append(c[off : off + b.size].copy())
        off += b.size
    # covariance from the final Jacobian (robust weights at the solution)
    A_dense = A.toarray() if issparse(A) else A
    n = layout.n_free
    binding = np.flatnonzero(c >= -1e-6) if c.size else np.zeros(0, dtype=int)
    dof = layout.m_obs - n + int(binding.size)
    rank_deficient = False
    try:
        cov = spd_solver(A_dense)(np.eye(n))
        if not np.all(np.isfinite(cov)):
            raise np.linalg.LinAlgError
        cov_free = cov
        if binding.size:
            # covariance on the manifold of binding constraints (Schur form of Z (Z'AZ)^-1 Z')
            Gb = G[binding]
            CG = cov @ Gb.T
            S = Gb @ CG
            cov = cov - CG @ np.linalg.lstsq(S, CG.T, rcond=None)[0]
            cov = 0.5 * (cov + cov.T)
    except (np.linalg.LinAlgError, ValueError):
        rank_deficient = True
        if binding.size:
            Z = null_space(G[binding])
            cov = Z @ np.linalg.pinv(Z.T @ A_dense @ Z, rcond=1e-12) @ Z.T
        else:
            cov = np.linalg.pinv(A_dense, rcond=1e-12)
        cov_free = np.linalg.pinv(A_dense, rcond=1e-12) if want_redundancy and binding.size else cov
    # redundancy numbers: 1 - diag(J C J') in the whitened space (unscaled covariance). C ignores
    # the field-of-view limits: an inequality that happens to bind must not make the redundancy
    # (and with it the variance components estimated from it) jump as the weights change
    Jd = J.toarray() if issparse(J) else J
    # (observation rows only: prior rows, after them, have no detections to estimate noise from)
    lev = _leverage(Jd[: layout.m_obs], cov_free, layout.row_cols) if want_redundancy else np.zeros(layout.m_obs)
    redundancy = []
    off = 0
    for x in raw:
        redundancy.append(np.clip(1.0 - lev[off : off + x.size], 0.0, 1.0).reshape(x.shape))
        off += x.size
    obs_sq = float(sum(np.sum(x * x) for x in raw))
    sigma0_sq = obs_sq / dof if dof > 0 else 1.0
    columns = {name: layout.cols[i].copy() for i, name in enumerate(layout.names)}
    prior_sq = 0.0
    for pr, idx in zip(problem.priors, layout.prior_idx):
        if pr.size:
            rp = se3_log(np.linalg.inv(pr.T_prior) @ T[idx]) / pr.sigma
            prior_sq += float(np.sum(rp * rp))
    return Solution(
        poses={name: T[i].copy() for i, name in enumerate(layout.names)},
        converged=converged,
        status=status,
        iterations=it,
        cost=0.5 * obs_sq,
        covariance=cov * sigma0_sq,
        columns=columns,
        residuals=tuple(raw),
        limit_residuals=tuple(lim_raw),
        sigma0_sq=sigma0_sq,
        dof=dof,
        gradient_norm=gnorm,
        rank_deficient=rank_deficient,
        redundancy=tuple(redundancy),
        extra={"lm_state": state},
        prior_cost=0.5 * prior_sq,
    )


def merge_independent(problems: list[Problem], solutions: list[Solution]) -> tuple[Problem, Solution]:
    """One problem/solution from independently solved problems that share only fixed poses
    (e.g. MCPE's pairs, each sharing the held reference). Covariances are block-diagonal."""
    blocks: dict[str, PoseBlock] = {}
    for prob, sol in zip(problems, solutions):
        for p in prob.poses:
            if any(p.free) and p.name in blocks and any(blocks[p.name].free):
                raise ConfigError(f"pose '{p.name}' is free in more than one problem")
            if p.name not in blocks or any(p.free):
                blocks[p.name] = replace(p, T=sol.poses[p.name])
    merged = Problem(
        tuple(blocks.values()),
        tuple(b for p in problems for b in p.observations),
        tuple(b for p in problems for b in p.limits),
        tuple(b for p in problems for b in p.priors),
    )
    cols: dict[str, np.ndarray] = {}
    covs = []
    offset = 0
    for sol in solutions:
        n = sol.covariance.shape[0]
        for name, c in sol.columns.items():
            if np.any(c >= 0):
                cols[name] = np.where(c >= 0, c + offset, -1)
            else:
                cols.setdefault(name, c.copy())
        covs.append(sol.covariance)
        offset += n
    poses: dict[str, np.ndarray] = {}
    for sol in solutions:
        poses.update(sol.poses)
    return merged, combine_solutions(
        solutions,
        poses={name: poses[name] for name in blocks},
        covariance=block_diag(*covs) if covs else np.zeros((0, 0)),
        columns={name: cols[name] for name in blocks},
        status="all sub-problems converged",
    )


def combine_solutions(
    solutions: list[Solution],
    *,
    poses: dict[str, np.ndarray],
    covariance: np.ndarray,
    columns: dict[str, np.ndarray],
    status: str,
    extra: dict | None = None,
) -> Solution:
    """One :class:`Solution` from independently solved sub-problems: their costs, degrees of
    freedom and residuals (in order) added up, converged only if all did (else the first
    failure's status); ``poses``, ``covariance`` and ``columns`` as given."""
    failed = [s for s in solutions if not s.converged]
    return Solution(
        poses=poses,
        converged=not failed,
        status=failed[0].status if failed else status,
        iterations=max(s.iterations for s in solutions),
        cost=sum(s.cost for s in solutions),
        covariance=covariance,
        columns=columns,
        residuals=tuple(r for s in solutions for r in s.residuals),
        limit_residuals=tuple(r for s in solutions for r in s.limit_residuals),
        sigma0_sq=float(np.mean([s.sigma0_sq for s in solutions])),
        dof=sum(s.dof for s in solutions),
        gradient_norm=max(s.gradient_norm for s in solutions),
        rank_deficient=any(s.rank_deficient for s in solutions),
        redundancy=tuple(r for s in solutions for r in s.redundancy),
        extra=dict(extra or {}),
        prior_cost=sum(s.prior_cost for s in solutions),
    )


def linearise(problem: Problem, layout: "_Layout | None" = None):
    """The problem linearised at its own poses: whitened residual vector (m,), whitened Jacobian
    (m, n_free) of the observations (dense), field-of-view constraint values (c,) and their
    Jacobian (c, n_free), and the layout (``layout.cols`` maps pose -> free columns)."""
    layout = layout if layout is not None else prepare(problem)
    T = np.stack([p.T for p in problem.poses]).astype(float)
    r, J, _, _ = _evaluate(problem, layout, T, "linear", 1.0, True)
    J = J.toarray() if issparse(J) else J
    c, G = _constraints(problem, layout, T)
    return r[: layout.m_obs], J[: layout.m_obs], c, G, layout
