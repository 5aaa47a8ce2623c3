"""Is a pose difference more than noise? The chi-square test ``rigcal check`` and ``rigcal diff``
make on a sensor's 6-DOF change, and the smallest change a test can find.

A change ``delta`` (6,) is a right perturbation (rotation [rad] first, then translation [m],
both in the sensor's frame): ``T_new = T_old exp(delta)``. Under "nothing moved" it is zero-mean
with covariance ``C`` (the sum of the two estimates' covariances); the test statistic is the
squared Mahalanobis length ``delta' C^-1 delta`` over the *tested* directions - a basis ``U``
of the directions both the data and the model say something about (a 2D radar's z, roll and
pitch are never among them: only its field of view bounds them) - chi-square with ``dim U``
degrees of freedom.

The smallest detectable change (Baarda's minimal detectable bias): the non-centrality
``lambda0`` at which the test at level ``alpha`` finds a change with probability ``power``; a
pure translation (rotation) of length ``t`` along the worst tested direction ``u`` has
non-centrality ``t^2 u'Qu`` with ``Q = U (U'CU)^-1 U'``, so the smallest one always found (at
that power) is ``sqrt(lambda0 / min eig Q_tt)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rigcal.problem.numerics import chi2_sf

#: tangent order (rotation first), as in the solver
TANGENT = ("roll", "pitch", "yaw", "x", "y", "z")
#: relative eigenvalue below which a direction counts as not determined
RANK_RCOND = 1e-9


def noncentral_chi2_sf(x: float, dof: int, nc: float) -> float:
    """P(X > x) for X ~ non-central chi-square(``dof``, ``nc``): a Poisson(nc / 2) mixture of
    central chi-squares with ``dof + 2j`` degrees of freedom."""
    if nc <= 0.0:
        return chi2_sf(x, dof)
    half = 0.5 * nc
    centre = int(half)

    def term(j: int) -> tuple[float, float]:
        w = math.exp(-half + j * math.log(half) - math.lgamma(j + 1.0))
        return w, w * chi2_sf(x, dof + 2 * j)

    total = 0.0
    # from the Poisson mode outwards, each way until the weights no longer add anything
    for j in range(centre, centre + 100_000):
        w, t = term(j)
        total += t
        if w < 1e-17:
            break
    for j in range(centre - 1, -1, -1):
        w, t = term(j)
        total += t
        if w < 1e-17:
            break
    return min(total, 1.0)


def _betacf(a: float, b: float, x: float) -> float:
    """The continued fraction of the incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (tiny if abs(d) < tiny else d)
    h = d
    for m in range(1, 10000):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + aa * d
            d = 1.0 / (tiny if abs(d) < tiny else d)
            c = 1.0 + aa / c
            c = tiny if abs(c) < tiny else c
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def beta_inc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def f_sf(x: float, d1: float, d2: float) -> float:
    """P(X > x) for X ~ F(``d1``, ``d2``)."""
    if x <= 0.0:
        return 1.0
    return beta_inc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x))


@lru_cache(maxsize=256)
def detectable_noncentrality(dof: int, alpha: float, power: float) -> float:
    """The non-centrality a chi-square test with ``dof`` degrees of freedom at level ``alpha``
    detects with probability ``power`` (bisection)."""
    from rigcal.problem.numerics import chi2_isf

    crit = chi2_isf(alpha, dof)
    lo, hi = 0.0, 1.0
    while noncentral_chi2_sf(crit, dof, hi) < power:
        lo, hi = hi, 2.0 * hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if noncentral_chi2_sf(crit, dof, mid) < power:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-6 * hi:
            break
    return hi


def z_score(statistic: float, dof: int) -> float:
    """A chi-square statistic as a standard normal score (Wilson-Hilferty): comparable across
    degrees of freedom, and monotone in the p-value where the p-value underflows."""
    if dof <= 0:
        return -math.inf
    k = float(dof)
    return ((max(statistic, 0.0) / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MoveTest:
    """A chi-square test of a pose change (see the module docstring).

    ``delta`` (6,): the change (right perturbation); ``covariance`` (6, 6): its covariance under
    "nothing moved"; ``tested``: the directions tested (names of :data:`TANGENT` spanned by the
    tested subspace; a partial subspace lists the directions it touches), ``dof`` its dimension;
    ``statistic`` and ``p_value``; ``detectable_translation_m`` / ``detectable_rotation_deg``: the
    smallest pure translation / rotation along the worst tested direction found with probability
    ``power`` at level ``alpha`` (inf where a direction is not tested)."""

    delta: np.ndarray
    covariance: np.ndarray
    tested: tuple[str, ...]
    dof: int
    statistic: float
    p_value: float
    alpha: float
    power: float
    detectable_translation_m: float
    detectable_rotation_deg: float
    #: the residuals' variance over the model's (at least 1), and their degrees of freedom: a
    #: factor above 1 scales the covariance and makes the test an F-test
    variance_factor: float = 1.0
    redundancy: int = 0

    @property
    def significant(self) -> bool:
        return self.dof > 0 and self.p_value < self.alpha

    @property
    def z(self) -> float:
        return z_score(self.statistic, self.dof)

    @property
    def sigma(self) -> float:
        """The change's length in standard deviations (square root of the statistic)."""
        return math.sqrt(max(self.statistic, 0.0))


def determined_basis(information: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(6, k) orthonormal basis of the directions among ``directions`` (indices into the 6
    tangent coordinates) on which the (6, 6) ``information`` (or any PSD matrix whose null space
    is the untested directions) is not zero; the scale of rotations and translations is
    equalised first, so that a rank is not decided by units."""
    idx = np.asarray(directions, dtype=int)
    if idx.size == 0:
        return np.zeros((6, 0))
    H = np.asarray(information, dtype=float)[np.ix_(idx, idx)]
    d = np.sqrt(np.maximum(np.diag(H), 0.0))
    live = d > 0
    if not np.any(live):
        return np.zeros((6, 0))
    scale = np.where(live, 1.0 / np.where(live, d, 1.0), 1.0)
    Hs = scale[:, None] * H * scale[None, :]
    w, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    keep = w > RANK_RCOND * max(float(w.max()), 1e-300)
    if np.all(keep):
        U = np.zeros((6, idx.size))
        U[idx, np.arange(idx.size)] = 1.0
        return U
    # the determined subspace: the orthogonal complement of H's null space (scaled back)
    null = scale[:, None] * V[:, ~keep]
    left, sv, _ = np.linalg.svd(null, full_matrices=True)
    rank_null = int(np.sum(sv > 1e-12 * max(float(sv.max()), 1e-300)))
    comp = left[:, rank_null:]
    U = np.zeros((6, comp.shape[1]))
    U[idx] = comp
    return U


def _detectable(Q: np.ndarray, idx: list[int], nc: float) -> float:
    if not idx:
        return math.inf
    q = Q[np.ix_(idx, idx)]
    lo = float(np.linalg.eigvalsh(0.5 * (q + q.T))[0])
    scale = float(np.max(np.abs(np.diag(q)))) if q.size else 0.0
    if lo <= RANK_RCOND * max(scale, 1e-300):
        return math.inf
    return math.sqrt(nc / lo)


def move_test(delta: np.ndarray, covariance: np.ndarray, basis: np.ndarray, alpha: float,
              power: float = 0.8, variance_factor: float = 1.0, redundancy: int = 0) -> MoveTest:
    """The chi-square test of the change ``delta`` (6,) with covariance ``covariance`` (6, 6)
    over the tested subspace ``basis`` (6, k) (:func:`determined_basis`), at level ``alpha``;
    detectable changes at ``power``.

    ``variance_factor`` > 1 (residuals scattering more than the noise model says, estimated with
    ``redundancy`` degrees of freedom) scales the covariance and turns the test into an F-test
    (the statistic reported is then the scaled one)."""
    d = np.asarray(delta, dtype=float)
    C = 0.5 * (np.asarray(covariance, dtype=float) + np.asarray(covariance, dtype=float).T)
    U = np.asarray(basis, dtype=float)
    k = U.shape[1]
    names = tuple(TANGENT[i] for i in range(6) if k and np.any(np.abs(U[i]) > 1e-12))
    vf = max(float(variance_factor), 1.0) if redundancy > 0 else 1.0
    if k == 0:
        return MoveTest(d, C, (), 0, 0.0, 1.0, alpha, power, math.inf, math.inf, vf, int(redundancy))
    C = C * vf
    S = U.T @ C @ U
    Sinv = np.linalg.pinv(0.5 * (S + S.T), rcond=1e-12, hermitian=True)
    x = U.T @ d
    stat = float(x @ Sinv @ x)
    p = f_sf(stat / k, k, redundancy) if vf > 1.0 else chi2_sf(stat, k)
    Q = U @ Sinv @ U.T
    nc = detectable_noncentrality(k, float(alpha), float(power))
    rot = [i for i in range(3) if TANGENT[i] in names]
    trans = [i for i in range(3, 6) if TANGENT[i] in names]
    return MoveTest(d, C, names, k, stat, p, alpha, power, _detectable(Q, trans, nc),
                    math.degrees(_detectable(Q, rot, nc)), vf, int(redundancy))


def change_summary(T_old: np.ndarray, T_new: np.ndarray) -> dict:
    """A change from ``T_old`` to ``T_new`` (both ``T_reference_sensor``) as a person reads it:
    ``translation_m`` (3,) - the origin's move in the reference frame, ``distance_m`` its
    length, ``rotation_deg`` the rotation angle, ``axis_sensor`` / ``axis_reference`` its unit
    axis in the sensor's own and in the reference frame (zeros for no rotation)."""
    from rigcal.geometry.se3 import invert
    from rigcal.geometry.so3 import so3_log

    T_old = np.asarray(T_old, dtype=float)
    T_new = np.asarray(T_new, dtype=float)
    t = T_new[:3, 3] - T_old[:3, 3]
    w = so3_log((invert(T_old) @ T_new)[:3, :3])
    angle = float(np.linalg.norm(w))
    axis = w / angle if angle > 1e-15 else np.zeros(3)
    return {
        "translation_m": t,
        "distance_m": float(np.linalg.norm(t)),
        "rotation_deg": math.degrees(angle),
        "axis_sensor": axis,
        "axis_reference": T_old[:3, :3] @ axis,
    }


def change_std(delta: np.ndarray, covariance: np.ndarray) -> tuple[float, float]:
    """(m, deg): first-order standard deviations of the length of a change's translation and of
    its rotation angle, from the (6, 6) covariance of the change ``delta`` (right perturbation)."""
    d = np.asarray(delta, dtype=float)
    C = np.asarray(covariance, dtype=float)
    out = []
    for sl in (slice(3, 6), slice(0, 3)):
        v = d[sl]
        n = float(np.linalg.norm(v))
        block = C[sl, sl]
        if n > 1e-15:
            u = v / n
            var = float(u @ block @ u)
        else:  # no change: the largest std of any direction
            var = float(np.max(np.linalg.eigvalsh(0.5 * (block + block.T))))
        out.append(math.sqrt(max(var, 0.0)))
    return out[0], math.degrees(out[1])


def format_p(p: float) -> str:
    """A p-value for people: ``p < 0.001`` below a thousandth, else ``p = 0.012``."""
    if not math.isfinite(p):
        return "p = -"
    return "p < 0.001" if p < 1e-3 else f"p = {p:.3f}"


def format_mm(x_m: float) -> str:
    """A length in millimetres: no decimals from 10 mm, one below; ``inf`` when infinite."""
    if not math.isfinite(x_m):
        return "inf"
    mm = x_m * 1000.0
    return f"{mm:.0f}" if abs(mm) >= 10 else f"{mm:.1f}"


def format_deg(x: float) -> str:
    return "inf" if not math.isfinite(x) else f"{x:.2f}"


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, None when infinite or NaN (strict JSON)."""
    return float(x) if math.isfinite(x) else None


def move_test_fields(t: "MoveTest | None") -> dict:
    """A test's numbers as check.json / diff --json write them (None without a test)."""
    return {
        "tested": list(t.tested) if t else [],
        "statistic": None if t is None else float(t.statistic),
        "dof": 0 if t is None else int(t.dof),
        "p_value": None if t is None else float(t.p_value),
        "alpha": None if t is None else float(t.alpha),
        "sigma": None if t is None else float(t.sigma),
        "detectable_translation_m": None if t is None else finite_or_none(t.detectable_translation_m),
        "detectable_rotation_deg": None if t is None else finite_or_none(t.detectable_rotation_deg),
    }


def format_vector(v, scale: float = 1.0, decimals: int = 0) -> str:
    return "(" + ", ".join(f"{x * scale:+.{decimals}f}" for x in np.asarray(v, dtype=float)) + ")"


__all__ = [
    "MoveTest",
    "TANGENT",
    "change_std",
    "change_summary",
    "detectable_noncentrality",
    "finite_or_none",
    "format_deg",
    "format_mm",
    "format_p",
    "format_vector",
    "move_test_fields",
    "move_test",
    "noncentral_chi2_sf",
    "determined_basis",
    "z_score",
]
