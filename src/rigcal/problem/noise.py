"""A physical noise model of the detections, its estimation from residuals, and the covariance
of the estimate that follows from it (whatever weights the solve used).

**Noise model.** Every detected point is disturbed by independent noise *units*: a direction
in the sensor's measurement space and a std ``sqrt(theta[group]) * scale``. The groups are per
sensor and per physical component:

=========  ============================  ==================================================
kind       components                    direction and scale
=========  ============================  ==================================================
lidar      ``x``, ``y``, ``z``            sensor axes, constant
camera     ``lateral``, ``depth``         across the ray (2 units, constant); along the
                                          ray, std proportional to (range / 1 m)^2 (stereo
                                          and PnP depth error grow with range squared)
radar      ``range``, ``azimuth``         radial (constant); tangential, std = range x
                                          azimuth std [rad] (2D: in the radar plane)
radar3d    ``range``, ``azimuth``,        as the 2D radar, plus the elevation direction
           ``elevation``                  with std = range x elevation std [rad]
=========  ============================  ==================================================

**Estimation.** A residual row is linear in the units to first order, ``r = D e``; so
``E[r_i^2] = sum_u D_iu^2 scale_u^2 theta_g(u)`` - a linear regression of the squared residuals
on the groups (iteratively weighted, non-negative, corrected for the degrees of freedom the
solve used). Pairwise residuals (FCPE/MCPE) tell every sensor's noise apart as soon as three
sensors form a loop; with two sensors only their sum is determined, which is all their pair
needs.

**Covariance.** With weights ``W`` (the solve's whitening) the estimate's first-order
covariance is the sandwich ``A^-1 (J'W D Theta D' W J) A^-1``, ``A = J'WJ``: it is right even
where the weights are not the inverse noise, and it counts the correlation of pairwise
residuals that share one sensor's detection (FCPE's pairs lidar-camera and lidar-radar both
contain the lidar's error).
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.problem.numerics import assemble, issparse, nnls
from rigcal.problem.residuals import MODEL_POINT, MODEL_RADAR2D
from rigcal.sensors.radar import project_2d_jacobian
from rigcal.targets.circle_board import reflectors_from_centres

COMPONENTS = {
    SensorKind.LIDAR: ("x", "y", "z"),
    SensorKind.CAMERA: ("lateral", "depth"),
    SensorKind.RADAR: ("range", "azimuth"),
    SensorKind.RADAR3D: ("range", "azimuth", "elevation"),
}
#: units of each component's std, for reports
COMPONENT_UNITS = {
    "x": "m", "y": "m", "z": "m", "lateral": "m", "depth": "m at 1 m",
    "range": "m", "azimuth": "deg", "elevation": "deg",
}
#: smallest variance a group may take (its std: 10 micrometres, or microradians)
THETA_FLOOR = 1e-10


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class DetectionUnits:
    """The noise units of every valid detection of a dataset.

    ``groups[g]`` is ``(sensor, component)``; unit ``u`` belongs to group ``group[u]``, moves
    the detection along ``basis[u]`` ((3,), zero-padded for a 2D radar) with std
    ``sqrt(theta[group[u]]) * scale[u]``. ``first[(sensor, k, m)]`` is the index of the first
    unit of point m of board k (its units are consecutive, ``len(COMPONENTS)``-many by kind:
    3 for 3D sensors, 2 for a 2D radar).
    """

    groups: tuple[tuple[str, str], ...]
    group: np.ndarray
    scale: np.ndarray
    basis: np.ndarray
    first: dict

    @property
    def size(self) -> int:
        return int(self.group.size)

    def count(self, sensor: str) -> int:
        return int(np.sum([self.groups[g][0] == sensor for g in self.group]))


def _point_units(kind: SensorKind, p: np.ndarray) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Noise units of detected points ``p`` (n, 3) in the sensor frame: component names (c,),
    directions (n, c, 3) and scales (n, c)."""
    n = p.shape[0]
    if kind is SensorKind.LIDAR:
        return ("x", "y", "z"), np.broadcast_to(np.eye(3), (n, 3, 3)), np.ones((n, 3))
    rng = np.maximum(np.linalg.norm(p, axis=1), 1e-6)
    rho = np.maximum(np.hypot(p[:, 0], p[:, 1]), 1e-6)
    if kind is SensorKind.RADAR:
        u = np.stack([p[:, 0] / rho, p[:, 1] / rho, np.zeros(n)], axis=1)
        t = np.stack([-u[:, 1], u[:, 0], np.zeros(n)], axis=1)
        return ("range", "azimuth"), np.stack([u, t], axis=1), np.stack([np.ones(n), rho], axis=1)
    u = p / rng[:, None]
    if kind is SensorKind.CAMERA:
        helper = np.where((np.abs(u[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        e1 = np.cross(u, helper)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(u, e1)
        return (
            ("lateral", "lateral", "depth"),
            np.stack([e1, e2, u], axis=1),
            np.stack([np.ones(n), np.ones(n), rng**2], axis=1),
        )
    t = np.stack([-p[:, 1] / rho, p[:, 0] / rho, np.zeros(n)], axis=1)
    e = np.cross(t, u)  # up, along the elevation
    return ("range", "azimuth", "elevation"), np.stack([u, t, e], axis=1), np.stack([np.ones(n), rho, rng], axis=1)


def detection_units(dataset: Dataset) -> DetectionUnits:
    """The noise units of every valid detection of ``dataset``."""
    groups: list[tuple[str, str]] = []
    gid, scale, basis = [], [], []
    first: dict = {}
    start = 0
    for s in dataset.sensors:
        index = {}
        for c in COMPONENTS[s.kind]:
            index[c] = len(groups)
            groups.append((s.name, c))
        pts = s.points if s.kind.is_point_cloud else s.points[:, None, :]
        ks = np.flatnonzero(s.valid)
        per = pts.shape[1]
        p = np.zeros((ks.size * per, 3))
        p[:, : pts.shape[2]] = pts[ks].reshape(-1, pts.shape[2])
        comps, directions, scales = _point_units(s.kind, p)
        c = len(comps)
        for j, k in enumerate(ks):
            for m in range(per):
                first[(s.name, int(k), m)] = start + (j * per + m) * c
        gid.append(np.tile([index[x] for x in comps], p.shape[0]))
        scale.append(scales.reshape(-1))
        basis.append(directions.reshape(-1, 3))
        start += p.shape[0] * c
    return DetectionUnits(
        tuple(groups),
        np.concatenate(gid).astype(int) if gid else np.zeros(0, dtype=int),
        np.concatenate(scale) if scale else np.zeros(0),
        np.concatenate(basis) if basis else np.zeros((0, 3)),
        first,
    )


def _units_per_point(kind: SensorKind) -> int:
    return 2 if kind is SensorKind.RADAR else 3


def reflector_jacobians(centres: np.ndarray, dataset: Dataset, h: float = 1e-6) -> np.ndarray:
    """(K, 4, 3, 3) derivative of each board's reflector (paper's g) w.r.t. each hole centre,
    for hole centres (K, 4, 3) (central differences; NaN for undetected boards)."""
    c = np.asarray(centres, dtype=float)
    K = c.shape[0]
    steps = np.zeros((12, 4, 3))
    steps.reshape(12, 12)[np.arange(12), np.arange(12)] = h
    batch = np.concatenate([c[:, None] + steps[None], c[:, None] - steps[None]], axis=1)  # (K, 24, 4, 3)
    g = reflectors_from_centres(batch.reshape(-1, 4, 3), dataset.board).reshape(K, 2, 4, 3, 3)
    d = (g[:, 0] - g[:, 1]) / (2 * h)  # (K, m, j, out)
    return np.swapaxes(d, 2, 3)  # (K, m, out, j)


#: a noise map with more entries than this is a scipy.sparse matrix, otherwise a numpy array
DENSE_MAX_ENTRIES = 4_000_000


def noise_map(problem, dataset: Dataset, units: DetectionUnits):
    """``D`` (residual rows x units; numpy, or scipy CSR above ``DENSE_MAX_ENTRIES``): the first-order effect of each noise unit (at std 1 in
    its direction, before ``scale``) on each *metric* residual row of ``problem``'s
    observation batches (rows in the solver's order). Batches of the pairwise and PSE
    configurations only (point and 2D radar models; frames are sensors or boards)."""
    names = set(dataset.names)
    T = {p.name: p.T for p in problem.poses}
    rows, cols, vals = [], [], []
    row0 = 0
    G_cache: dict[str, np.ndarray] = {}
    for b in problem.observations:
        if b.model not in (MODEL_POINT, MODEL_RADAR2D):
            raise ValueError(f"noise_map: batch '{b.label}' has model {b.model!r}")
        d = b.dim
        # position of each item within its board (0..3 for 4-point batches)
        m_of = np.zeros(b.size, dtype=int)
        seen: dict[int, int] = {}
        for i, k in enumerate(b.board):
            m_of[i] = seen.get(int(k), 0)
            seen[int(k)] = m_of[i] + 1
        for i in range(b.size):
            k, fr, ob = int(b.board[i]), b.frame[i], b.observer[i]
            R_of = T[ob][:3, :3].T @ T[fr][:3, :3]
            x = R_of @ b.points[i] + T[ob][:3, :3].T @ (T[fr][:3, 3] - T[ob][:3, 3])
            H = project_2d_jacobian(x[None])[0] if b.model == MODEL_RADAR2D else np.eye(3)
            rr = row0 + i * d + np.arange(d)
            obs = dataset.sensor(ob)
            m_obs = m_of[i] if obs.kind.is_point_cloud else 0
            u0 = units.first[(ob, k, m_obs)]
            for c in range(_units_per_point(obs.kind)):
                direction = -units.basis[u0 + c][:d]
                rows.extend(rr)
                cols.extend([u0 + c] * d)
                vals.extend(direction)
            if fr not in names:
                continue  # a board pose (PSE): no detection noise on the frame side
            frs = dataset.sensor(fr)
            HR = H @ R_of
            if frs.kind.is_point_cloud and not obs.kind.is_point_cloud:
                if fr not in G_cache:
                    G_cache[fr] = reflector_jacobians(frs.points, dataset)
                for m in range(4):
                    u0 = units.first[(fr, k, m)]
                    for c in range(3):
                        rows.extend(rr)
                        cols.extend([u0 + c] * d)
                        vals.extend(HR @ G_cache[fr][k, m] @ units.basis[u0 + c])
            else:
                u0 = units.first[(fr, k, m_of[i] if frs.kind.is_point_cloud else 0)]
                for c in range(_units_per_point(frs.kind)):
                    rows.extend(rr)
                    cols.extend([u0 + c] * d)
                    vals.extend(HR @ units.basis[u0 + c])
        row0 += b.size * d
    return assemble(rows, cols, vals, (row0, units.size), dense=row0 * units.size <= DENSE_MAX_ENTRIES)


def group_design(D, units: DetectionUnits) -> np.ndarray:
    """(rows, groups): ``sum_u D_iu^2 scale_u^2`` per group - the rows' variance per unit theta
    (``D`` sparse or dense)."""
    w = units.scale**2
    if issparse(D):
        import scipy.sparse

        onehot = scipy.sparse.csr_matrix(
            (np.ones(units.size), (units.group, np.arange(units.size))),
            shape=(len(units.groups), units.size),
        )
        D2 = scipy.sparse.csr_matrix(D.multiply(D).multiply(w[None, :]))
        return np.asarray((onehot @ D2.T).T.todense())
    out = np.zeros((np.asarray(D).shape[0], len(units.groups)))
    weighted = np.asarray(D) ** 2 * w[None, :]
    for g in range(len(units.groups)):
        out[:, g] = weighted[:, units.group == g].sum(axis=1)
    return out


def estimate_theta(
    r_metric: np.ndarray,
    M: np.ndarray,
    dof_factor: float,
    floor: float = THETA_FLOOR,
    batches: np.ndarray | None = None,
    rounds: int = 3,
) -> np.ndarray:
    """Group variances from squared metric residuals: ``r_i^2 * dof_factor ~ M theta``.

    Non-negative least squares, each row weighted by the inverse square of its predicted
    variance (``Var(r^2) = 2 E[r^2]^2``), ``rounds`` rounds (1: each row weighted by its
    batch's mean square alone - the most stable where the data leave splits weak, which
    later rounds let wander). The prediction is clamped from below at a
    tenth of the mean square of the row's batch (``batches[i]``: a pair or sensor; default one
    batch): a group the first rounds set to zero cannot make its rows' weights explode, and a
    precise pair (lidar-lidar) weighs as much as a noisy one (camera-radar) from the start.
    Groups no residual depends on keep the floor."""
    y = r_metric**2 * dof_factor
    used = np.any(M > 0, axis=0)
    theta = np.full(M.shape[1], floor)
    if not np.any(used) or y.size == 0:
        return theta
    b = np.zeros(y.size, dtype=int) if batches is None else np.asarray(batches, dtype=int)
    counts = np.bincount(b)
    level = np.bincount(b, weights=y) / np.maximum(counts, 1)
    low = np.maximum(0.1 * level[b], 1e-30)
    Mu = M[:, used]
    pred = np.maximum(level[b], 1e-30)  # first round: each batch at its own scale
    th = np.zeros(Mu.shape[1])
    for _ in range(max(int(rounds), 1)):
        sw = 1.0 / np.maximum(pred, low)
        A = Mu * sw[:, None]
        col = np.maximum(np.sqrt(np.sum(A**2, axis=0)), 1e-300)
        th_scaled, _ = nnls(A / col, y * sw, maxiter=50 * Mu.shape[1])
        th = th_scaled / col
        pred = Mu @ th
    theta[used] = np.maximum(th, floor)
    return theta


def estimate_theta_best(
    r_metric: np.ndarray,
    M: np.ndarray,
    dof_factor: float,
    batches: np.ndarray | None = None,
    rounds: int = 8,
    floor: float = THETA_FLOOR,
) -> np.ndarray:
    """:func:`estimate_theta` after 1, 2, ... ``rounds`` rounds, keeping the estimate with the
    highest Gaussian likelihood of the residuals (``r_i ~ N(0, M_i theta)``): the reweighting
    can wander along a direction the data hardly tell (three lidars with random yaw: after
    three rounds two lidars' y noise sat at the floor and a third's doubled, a likelihood
    worse than the first round's) - the likelihood says which iterate the data prefer."""
    y = np.asarray(r_metric, dtype=float) ** 2 * dof_factor
    used = np.any(M > 0, axis=0)
    best, best_nll = None, np.inf
    for k in range(1, max(int(rounds), 1) + 1):
        theta = estimate_theta(r_metric, M, dof_factor, floor=floor, batches=batches, rounds=k)
        pred = np.maximum(M[:, used] @ theta[used], 1e-30) if np.any(used) else np.ones(y.size)
        nll = float(np.sum(np.log(pred) + y / pred))
        if nll < best_nll:
            best, best_nll = theta, nll
    return best


def theta_by_sensor(units: DetectionUnits, theta: np.ndarray) -> dict[str, dict[str, float]]:
    """Readable stds: ``{sensor: {component: std}}`` (m; depth: m at 1 m; angles: deg)."""
    out: dict[str, dict[str, float]] = {}
    for (sensor, comp), th in zip(units.groups, theta):
        s = float(np.sqrt(th))
        out.setdefault(sensor, {})[comp] = float(np.degrees(s)) if COMPONENT_UNITS[comp] == "deg" else s
    return out


def sandwich(
    Jw: np.ndarray,
    Dw,
    units: DetectionUnits,
    theta: np.ndarray,
    prior_precision: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(bread^-1, covariance) for whitened Jacobian ``Jw`` (rows, n) and whitened noise map
    ``Dw`` (rows, units): ``A^-1 (Jw' Dw Theta Dw' Jw + P) A^-1`` with ``A = Jw' Jw + P`` and
    ``P = diag(prior_precision)`` (n,) - independent priors on single parameters (0: none)."""
    A = Jw.T @ Jw
    B = np.asarray((Dw.T @ Jw))  # (units, n)
    var = theta[units.group] * units.scale**2
    meat = B.T @ (B * var[:, None])
    if prior_precision is not None:
        A = A + np.diag(prior_precision)
        meat = meat + np.diag(prior_precision)
    Ainv = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    C = Ainv @ meat @ Ainv
    return Ainv, 0.5 * (C + C.T)


#: an estimated noise direction whose relative standard error is above this is *weak*: the
#: data do not tell it (e.g. how a pair's noise splits between its two sensors)
WEAK_RELATIVE_SE = 0.5
#: width of the confidence band of the identified directions, in standard errors
NOISE_BAND_Z = 2.0
#: the squared residuals of pairs that share a detection are correlated: the information of
#: the noise regression is divided by this (its standard errors widened by its square root)
NOISE_INFO_DEFLATION = 2.0


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class NoiseRegion:
    """The group variances the residuals support: the estimate ``theta`` and, for any linear
    function ``c . theta`` (a pair's predicted sum of squares, a test statistic's variance),
    the largest and smallest value the data allow (:meth:`upper`, :meth:`lower`).

    The regression of squared residuals on the groups (:func:`estimate_theta`) has Fisher
    information ``F = M' diag(1 / (2 pred^2)) M``. In relative units (each group scaled by its
    estimate) its eigenvectors are the directions the data determine (eigenvalue ``lam``:
    relative standard error ``1 / sqrt(lam)``) and the *weak* ones (relative standard error
    above :data:`WEAK_RELATIVE_SE`) - typically how the noise of a pair splits between its two
    sensors when no third sensor closes a loop. A determined direction moves within
    :data:`NOISE_BAND_Z` standard errors; a weak one as far as every group stays non-negative
    (so a sensor may carry all of a pair's noise, never more). Never a value at the floor
    that only the arithmetic chose.
    """

    theta: np.ndarray
    scale: np.ndarray  # (groups,) relative units
    values: np.ndarray  # eigenvalues of the scaled information (determined directions)
    vectors: np.ndarray  # (groups, d) their eigenvectors
    weak: np.ndarray  # (groups, w) weak eigenvectors
    weak_range: np.ndarray  # (w, 2) how far (t_lo <= 0 <= t_hi) each may move theta + t s*v

    def _parts(self, c: np.ndarray) -> tuple[float, float, float, float]:
        c = np.asarray(c, dtype=float)
        cs = c * self.scale
        band = 0.0
        if self.values.size:
            band = NOISE_BAND_Z * float(np.sqrt(np.sum((self.vectors.T @ cs) ** 2 / self.values)))
        proj = self.weak.T @ cs if self.weak.size else np.zeros(0)
        lo_t, hi_t = (self.weak_range[:, 0], self.weak_range[:, 1]) if proj.size else (np.zeros(0), np.zeros(0))
        up = float(np.sum(np.maximum(np.maximum(hi_t * proj, lo_t * proj), 0.0)))
        down = float(np.sum(np.maximum(np.maximum(-hi_t * proj, -lo_t * proj), 0.0)))
        return float(c @ self.theta), band, up, down

    def upper(self, c: np.ndarray, weak: bool = True) -> float:
        """The largest ``c . theta`` the data support (``c >= 0``); ``weak=False``: within the
        band of the determined directions only (for ``c`` the data fit directly, e.g. a pair's
        own sum of squares, which no weak split changes much)."""
        mid, band, up, _ = self._parts(c)
        return mid + band + (up if weak else 0.0)

    def lower(self, c: np.ndarray) -> float:
        """The smallest ``c . theta`` the data support (at least 0)."""
        mid, band, _, down = self._parts(c)
        return max(mid - band - down, 0.0)

    def upper_rows(self, C: np.ndarray) -> np.ndarray:
        """:meth:`upper` of every row of ``C`` (rows, groups) at once."""
        C = np.asarray(C, dtype=float)
        Cs = C * self.scale[None, :]
        out = C @ self.theta
        if self.values.size:
            out = out + NOISE_BAND_Z * np.sqrt(np.sum((Cs @ self.vectors) ** 2 / self.values[None, :], axis=1))
        if self.weak.size:
            proj = Cs @ self.weak
            lo, hi = self.weak_range[:, 0], self.weak_range[:, 1]
            out = out + np.sum(np.maximum(np.maximum(hi * proj, lo * proj), 0.0), axis=1)
        return out

    def group_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) variance of every group."""
        eye = np.eye(self.theta.size)
        return (np.array([self.lower(e) for e in eye]), np.array([self.upper(e) for e in eye]))


def noise_region(M: np.ndarray, theta: np.ndarray, floor: float = THETA_FLOOR) -> NoiseRegion:
    """The :class:`NoiseRegion` of the estimate ``theta`` from the group design ``M``
    (rows x groups; :func:`group_design`). Groups no row depends on stay at their value."""
    theta = np.asarray(theta, dtype=float)
    G = theta.size
    used = np.flatnonzero(np.any(np.asarray(M) > 0, axis=0))
    empty = np.zeros((G, 0))
    if used.size == 0:
        return NoiseRegion(theta, np.ones(G), np.zeros(0), empty, empty, np.zeros((0, 2)))
    Mu = np.asarray(M)[:, used]
    th = theta[used]
    pred = np.maximum(Mu @ th, 1e-30)
    # relative units: a group at the floor is scaled like the typical group (its estimate
    # says nothing about its size)
    typical = float(np.median(th[th > 10 * floor])) if np.any(th > 10 * floor) else 1e-6
    s = np.maximum(th, 1e-2 * typical)
    A = Mu * s[None, :] / (np.sqrt(2.0) * pred[:, None])
    F = (A.T @ A) / NOISE_INFO_DEFLATION
    lam, V = np.linalg.eigh(0.5 * (F + F.T))
    strong = lam > 1.0 / WEAK_RELATIVE_SE**2
    scale = np.ones(G)
    scale[used] = s
    vectors = np.zeros((G, int(np.sum(strong))))
    vectors[used] = V[:, strong]
    weak = np.zeros((G, int(np.sum(~strong))))
    weak[used] = V[:, ~strong]
    ranges = []
    for v in V[:, ~strong].T:
        # theta + t s v >= 0 for every group: t between these
        lo, hi = -np.inf, np.inf
        for j in range(v.size):
            step = s[j] * v[j]
            if step > 1e-12 * s[j]:
                lo = max(lo, -th[j] / step)
            elif step < -1e-12 * s[j]:
                hi = min(hi, th[j] / -step)
        # a direction that only adds noise everywhere is bounded by the data, not by zero
        # (it cannot be weak in practice): cap it at 10 relative units
        ranges.append((lo if np.isfinite(lo) else -10.0, hi if np.isfinite(hi) else 10.0))
    weak_range = np.array(ranges, dtype=float).reshape(-1, 2)
    return NoiseRegion(theta, scale, lam[strong], vectors, weak, weak_range)


def row_batches(problem) -> np.ndarray:
    """The observation batch (a pair, or a sensor in PSE) of every residual row of
    ``problem``, in the solver's row order (``estimate_theta``'s ``batches``)."""
    if not problem.observations:
        return np.zeros(0, dtype=int)
    return np.concatenate([np.full(b.size * b.dim, i) for i, b in enumerate(problem.observations)])


__all__ = [
    "COMPONENTS",
    "COMPONENT_UNITS",
    "DetectionUnits",
    "NoiseRegion",
    "detection_units",
    "noise_region",
    "estimate_theta",
    "estimate_theta_best",
    "group_design",
    "noise_map",
    "reflector_jacobians",
    "sandwich",
    "row_batches",
    "theta_by_sensor",
]
