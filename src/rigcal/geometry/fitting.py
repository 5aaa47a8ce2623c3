"""Robust fitting of planes, circles and a rigid square of four circles. Pure, batched numpy.

Conventions:

* a plane is ``normal . p + d = 0`` with a unit ``normal``; fits orient it so that the origin
  (the sensor) lies on its positive side, ``d >= 0`` (the normal points toward the sensor);
* 2D points are (N, 2) arrays in a plane's coordinates (see :func:`plane_basis`);
* RANSAC takes a seeded ``numpy.random.Generator`` (or an int seed) and scores every hypothesis
  at once with a truncated quadratic (MSAC) cost, then refines by least squares on the inliers;
* the four-circle square template is ordered top-left, top-right, bottom-left, bottom-right in a
  2D frame with x right and y up (the board's order, :mod:`rigcal.targets.circle_board`).

Every estimator returns a value or raises :class:`~rigcal.errors.GeometryError` with the reason;
bad arguments raise :class:`~rigcal.errors.InputError`. No function mutates its inputs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rigcal.errors import GeometryError, InputError

__all__ = [
    "CircleFit",
    "CircleRansacFit",
    "PlaneFit",
    "SquareCirclesFit",
    "circle_angular_gap",
    "fit_circle_2d",
    "fit_plane_lstsq",
    "fit_square_circles_2d",
    "from_plane_2d",
    "intersect_rays_plane",
    "plane_basis",
    "project_to_plane",
    "ransac_circle_2d",
    "ransac_plane",
    "square_template_2d",
    "to_plane_2d",
]


class PlaneFit(NamedTuple):
    """A plane ``normal . p + d = 0``: ``normal`` (3,) unit, ``d`` [m], ``inliers`` (N,) bool mask
    of the fitted points, ``rms`` [m] RMS orthogonal distance of the inliers."""

    normal: np.ndarray
    d: float
    inliers: np.ndarray
    rms: float


class CircleFit(NamedTuple):
    """A 2D circle: ``centre`` (2,), ``radius`` and ``rms`` (RMS of ``|p - c| - r``), metres."""

    centre: np.ndarray
    radius: float
    rms: float


class CircleRansacFit(NamedTuple):
    """:class:`CircleFit` plus the ``inliers`` (N,) bool mask it was refined on."""

    centre: np.ndarray
    radius: float
    rms: float
    inliers: np.ndarray


class SquareCirclesFit(NamedTuple):
    """Four circles of one radius on a rigid square of known side.

    ``centre`` (2,) square centre, ``angle_rad`` its rotation in [-pi/4, pi/4), ``radius``,
    ``centres`` (4, 2) circle centres TL, TR, BL, BR, ``labels`` (N,) circle index of each
    point (-1: outlier, not used), ``rms`` of the used points' ``|p - c_k| - r`` [m].
    """

    centre: np.ndarray
    angle_rad: float
    radius: float
    centres: np.ndarray
    labels: np.ndarray
    rms: float


# ----------------------------------------------------------------------------- validation


def _points(points: np.ndarray, dim: int, what: str, minimum: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != dim:
        raise InputError(f"{what}: expected an (N, {dim}) point array, got shape {p.shape}")
    if p.shape[0] < minimum:
        raise GeometryError(f"{what}: needs at least {minimum} points, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        bad = int(np.sum(~np.isfinite(p).all(axis=1)))
        raise GeometryError(f"{what}: got {bad} non-finite points")
    return p


def _positive(value: float, name: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} must be a positive number, got {value!r}")
    return v


def _generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)):
        return np.random.default_rng(int(rng))
    raise InputError(f"rng must be a numpy Generator or an int seed, got {type(rng).__name__}")


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected a finite 3-vector, got {np.asarray(v).shape}")
    n = float(np.linalg.norm(a))
    if n < 1e-12:
        raise InputError(f"{what}: the zero vector has no direction")
    return a / n


def _orient(normal: np.ndarray, d: float) -> tuple[np.ndarray, float]:
    """Flip ``(normal, d)`` so that the origin lies on the positive side (d >= 0)."""
    if d < 0 or (d == 0 and normal[np.argmax(np.abs(normal))] < 0):
        return -normal, -d
    return normal, d


# ----------------------------------------------------------------------------- planes


def fit_plane_lstsq(points: np.ndarray) -> PlaneFit:
    """Least-squares (orthogonal) plane through (N, 3) points, N >= 3; all points are inliers.

    Raises GeometryError for fewer than 3, non-finite or collinear points.
    """
    p = _points(points, 3, "plane fit", 3)
    return _plane_from(p, np.ones(p.shape[0], dtype=bool))


def _plane_from(p: np.ndarray, mask: np.ndarray) -> PlaneFit:
    q = p[mask]
    c = np.ones(q.shape[0]) @ q / q.shape[0]  # the centroid (a matrix product: much faster
    qc = q - c  # than a column mean of an (N, 3) array)
    w, v = np.linalg.eigh(qc.T @ qc)  # ascending; 3x3 scatter is cheap for large N
    if w[1] <= 1e-12 * max(w[2], 1e-300):
        raise GeometryError(f"plane fit: the {q.shape[0]} points are (nearly) collinear")
    n = v[:, 0] / np.linalg.norm(v[:, 0])
    d = -float(n @ c)
    n, d = _orient(n, d)
    dist = qc @ n
    rms = float(np.sqrt(np.mean(dist * dist)))
    return PlaneFit(n, d, mask, rms)


def ransac_plane(
    points: np.ndarray,
    threshold_m: float,
    rng,
    max_iterations: int = 200,
    normal_hint: np.ndarray | None = None,
    max_angle_deg: float | None = None,
    *,
    score_sample: int = 4096,
    min_inliers: int = 3,
) -> PlaneFit:
    """Robust plane of (N, 3) points [m]: MSAC over ``max_iterations`` 3-point hypotheses.

    All hypotheses are scored at once on a random subset of at most ``score_sample`` points;
    the best is refined twice by least squares on its inliers (``|distance| < threshold_m``) over
    all points. With ``normal_hint`` and ``max_angle_deg`` only planes whose normal is within
    that angle of the hint (either sign) are accepted (e.g. the ground: hint = up, 30 deg).
    Raises GeometryError when no acceptable plane has ``min_inliers`` inliers.
    """
    p = _points(points, 3, "RANSAC plane", 3)
    thr = _positive(threshold_m, "threshold_m")
    gen = _generator(rng)
    iters = int(max_iterations)
    if iters < 1:
        raise InputError(f"max_iterations must be >= 1, got {max_iterations!r}")
    cos_max = None
    hint = None
    if max_angle_deg is not None:
        if normal_hint is None:
            raise InputError("ransac_plane: max_angle_deg needs a normal_hint")
        hint = _unit(normal_hint, "normal_hint")
        cos_max = math.cos(math.radians(float(max_angle_deg)))
    n_pts = p.shape[0]
    idx = gen.integers(0, n_pts, size=(iters, 3))
    a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    scale = np.maximum(np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - a, axis=1), 1e-300)
    ok = norm > 1e-6 * scale
    normals = normals[ok] / norm[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, a[ok])
    if cos_max is not None:
        keep = np.abs(normals @ hint) >= cos_max
        normals, offsets = normals[keep], offsets[keep]
    if normals.shape[0] == 0:
        raise GeometryError(
            f"RANSAC plane: none of {iters} hypotheses is a valid plane"
            + (f" within {max_angle_deg} deg of {hint.tolist()}" if hint is not None else "")
        )
    if n_pts > score_sample:
        sub = p[gen.integers(0, n_pts, size=int(score_sample))]
    else:
        sub = p
    cost = np.zeros(normals.shape[0])
    thr2 = thr * thr
    chunk = max(1, 2_000_000 // max(sub.shape[0], 1))
    for s in range(0, normals.shape[0], chunk):
        dist = sub @ normals[s : s + chunk].T + offsets[s : s + chunk]
        cost[s : s + chunk] = np.minimum(dist * dist, thr2).sum(axis=0)
    best = int(np.argmin(cost))
    n, d = normals[best], float(offsets[best])
    mask = np.abs(p @ n + d) < thr
    for _ in range(2):
        if mask.sum() < 3:
            break
        try:
            fit = _plane_from(p, mask)
        except GeometryError:
            break
        if cos_max is not None and abs(float(fit.normal @ hint)) < cos_max:
            break
        n, d = fit.normal, fit.d
        new = np.abs(p @ n + d) < thr
        if np.array_equal(new, mask):
            break
        mask = new
    count = int(mask.sum())
    if count < max(3, int(min_inliers)):
        raise GeometryError(
            f"RANSAC plane: best plane has {count} inliers within {thr} m, "
            f"need {max(3, min_inliers)}"
        )
    n, d = _orient(np.asarray(n, float), float(d))
    rms = float(np.sqrt(np.mean((p[mask] @ n + d) ** 2)))
    return PlaneFit(n, d, mask, rms)


def plane_basis(normal: np.ndarray, up_hint: np.ndarray | None = None) -> np.ndarray:
    """(2, 3) orthonormal in-plane axes ``(e1, e2)`` with ``e1 x e2 = normal``.

    With ``up_hint``, ``e2`` is the hint projected into the plane ("up") and ``e1 = e2 x normal``
    ("right" seen from the side the normal points to). Raises GeometryError when the hint is
    (nearly) parallel to the normal (less than ~1 deg away).
    """
    n = _unit(normal, "plane normal")
    if up_hint is None:
        helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    else:
        helper = _unit(up_hint, "up hint")
    e2 = helper - (helper @ n) * n
    norm = float(np.linalg.norm(e2))
    if norm < 0.02:
        raise GeometryError(
            f"plane basis: the up direction {helper.tolist()} is (nearly) perpendicular to "
            "the plane"
        )
    e2 = e2 / norm
    e1 = np.cross(e2, n)
    return np.stack([e1, e2])


def to_plane_2d(points: np.ndarray, origin: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(N, 2) in-plane coordinates of (N, 3) points, given ``origin`` (3,) and ``basis`` (2, 3)."""
    return (np.asarray(points, float) - np.asarray(origin, float)) @ np.asarray(basis, float).T


def from_plane_2d(uv: np.ndarray, origin: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(N, 3) points of in-plane coordinates ``uv`` (N, 2); inverse of :func:`to_plane_2d`."""
    return np.asarray(origin, float) + np.asarray(uv, float) @ np.asarray(basis, float)


def project_to_plane(points: np.ndarray, normal: np.ndarray, d: float) -> np.ndarray:
    """Orthogonal projection of (N, 3) points onto the plane ``normal . p + d = 0``."""
    n = _unit(normal, "plane normal")
    p = np.asarray(points, float)
    return p - (p @ n + float(d))[:, None] * n


def intersect_rays_plane(
    directions: np.ndarray, normal: np.ndarray, d: float, origin: np.ndarray | None = None
) -> np.ndarray:
    """(N, 3) points where rays ``origin + t * directions`` (t > 0) meet the plane; NaN rows for
    rays parallel to it or pointing away. ``origin`` defaults to (0, 0, 0) (the sensor)."""
    n = _unit(normal, "plane normal")
    dirs = np.asarray(directions, float)
    o = np.zeros(3) if origin is None else np.asarray(origin, float)
    den = dirs @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(o @ n + float(d)) / den
    bad = ~(np.abs(den) > 1e-12) | ~(t > 0)
    out = o + t[:, None] * dirs
    out[bad] = np.nan
    return out


# ----------------------------------------------------------------------------- circles


def _circle_algebraic(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Kasa fit on centred, scaled data: solves ``2 c . p + k = |p|^2`` by least squares."""
    m = p.mean(axis=0)
    q = p - m
    s = float(np.sqrt(np.mean(np.sum(q * q, axis=1))))
    if s <= 1e-12:
        raise GeometryError("circle fit: all points coincide")
    q = q / s
    A = np.column_stack([2 * q, np.ones(q.shape[0])])
    b = np.sum(q * q, axis=1)
    sol, _, rank, sv = np.linalg.lstsq(A, b, rcond=None)
    if rank < 3 or sv[-1] < 1e-9 * sv[0]:
        raise GeometryError(f"circle fit: the {p.shape[0]} points are collinear")
    c = sol[:2]
    r2 = sol[2] + c @ c
    if not r2 > 0:
        raise GeometryError("circle fit: algebraic fit gave no real radius")
    return c * s + m, float(np.sqrt(r2) * s)


def _circle_lm(
    p: np.ndarray,
    centre: np.ndarray,
    radius: float,
    radius_prior: float | None,
    radius_weight: float,
    max_iterations: int,
) -> tuple[np.ndarray, float, float]:
    fixed = radius_prior is not None and math.isinf(radius_weight)
    if fixed:
        radius = float(radius_prior)
    w = math.sqrt(radius_weight) if (radius_prior is not None and not fixed) else 0.0
    x = np.array([centre[0], centre[1], radius], dtype=float)

    m = p.shape[0]
    n_rows = m + 1 if w > 0 else m

    def residuals(x):
        diff = p - x[:2]
        dist = np.maximum(np.sqrt(diff[:, 0] ** 2 + diff[:, 1] ** 2), 1e-12)
        r = np.empty(n_rows)
        r[:m] = dist - x[2]
        J = np.zeros((n_rows, 3))
        J[:m, :2] = -diff / dist[:, None]
        J[:m, 2] = -1.0
        if w > 0:
            r[m] = w * (x[2] - radius_prior)
            J[m, 2] = w
        if fixed:
            J = J[:, :2]
        return r, J

    lam = 1e-3
    r, J = residuals(x)
    cost = float(r @ r)
    for _ in range(int(max_iterations)):
        H = J.T @ J
        g = J.T @ r
        step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
        if fixed:
            step = np.append(step, 0.0)
        x_new = x + step
        r_new, J_new = residuals(x_new)
        cost_new = float(r_new @ r_new)
        if cost_new <= cost:
            x, r, J, cost = x_new, r_new, J_new, cost_new
            lam = max(lam / 10, 1e-12)
            if np.linalg.norm(step) < 1e-10 * (1 + abs(x[2])):
                break
        else:
            lam *= 10
            if lam > 1e10:
                break
    if not (np.all(np.isfinite(x)) and x[2] > 0):
        raise GeometryError("circle fit: geometric refinement diverged")
    res = np.linalg.norm(p - x[:2], axis=1) - x[2]
    return x[:2].copy(), float(x[2]), float(np.sqrt(np.mean(res * res)))


def fit_circle_2d(
    points_2d: np.ndarray,
    *,
    centre0: np.ndarray | None = None,
    radius_prior: float | None = None,
    radius_weight: float = 0.0,
    max_iterations: int = 50,
) -> CircleFit:
    """Circle through (N, 2) points: algebraic (Kasa) start, then geometric Levenberg-Marquardt
    on ``|p - c| - r``.

    ``centre0`` replaces the algebraic start (useful for short arcs). ``radius_prior`` with
    ``radius_weight`` w adds the residual ``sqrt(w) * (r - radius_prior)`` (the prior counts like
    w points measuring the radius; ``math.inf`` fixes the radius). Needs N >= 3 points, or
    N >= 2 with a fixed radius and ``centre0``. Raises GeometryError for degenerate points.
    """
    fixed = radius_prior is not None and math.isinf(radius_weight)
    minimum = 2 if (fixed and centre0 is not None) else 3
    p = _points(points_2d, 2, "circle fit", minimum)
    if radius_weight < 0:
        raise InputError(f"radius_weight must be >= 0, got {radius_weight!r}")
    if centre0 is not None:
        c0 = np.asarray(centre0, float).reshape(2)
        if radius_prior is None:
            r0 = float(np.mean(np.linalg.norm(p - c0, axis=1)))
        else:
            r0 = float(radius_prior)
    else:
        c0, r0 = _circle_algebraic(p)
    if r0 <= 0:
        r0 = float(radius_prior) if radius_prior else 1.0
    c, r, rms = _circle_lm(p, c0, r0, radius_prior, float(radius_weight), max_iterations)
    return CircleFit(c, r, rms)


def circle_angular_gap(points_2d: np.ndarray, centre: np.ndarray) -> float:
    """Largest angular gap [rad] between the points seen from ``centre`` (2*pi for < 2 points).

    A circle's centre is well determined by its points only when the gap is below pi (the points
    are not all on one half of the circle).
    """
    p = np.asarray(points_2d, float)
    if p.shape[0] < 2:
        return 2 * math.pi
    ang = np.sort(np.arctan2(p[:, 1] - centre[1], p[:, 0] - centre[0]))
    gaps = np.diff(np.append(ang, ang[0] + 2 * math.pi))
    return float(gaps.max())


def _circumcircles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres (M, 2) and radii (M,) of the circles through triples; NaN for collinear ones."""
    ba, ca = b - a, c - a
    den = 2.0 * (ba[:, 0] * ca[:, 1] - ba[:, 1] * ca[:, 0])
    nb, nc = np.sum(ba * ba, axis=1), np.sum(ca * ca, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ca[:, 1] * nb - ba[:, 1] * nc) / den
        uy = (ba[:, 0] * nc - ca[:, 0] * nb) / den
    rel = np.column_stack([ux, uy])
    bad = np.abs(den) < 1e-12 * np.maximum(nb * nc, 1e-300) ** 0.5
    rel[bad] = np.nan
    return a + rel, np.linalg.norm(rel, axis=1)


def ransac_circle_2d(
    points: np.ndarray,
    r_min: float,
    r_max: float,
    threshold: float,
    rng,
    max_iterations: int = 500,
    *,
    min_inliers: int = 3,
) -> CircleRansacFit:
    """Robust circle of radius in [r_min, r_max] through (N, 2) points (MSAC, vectorised).

    All 3-point hypotheses with a radius in the bounds are scored at once; the best is refined
    with :func:`fit_circle_2d` on its inliers (``||p - c| - r| < threshold``); a refined radius
    outside the bounds is clamped and the centre refitted with it fixed.
    Raises GeometryError when no circle in the bounds has ``min_inliers`` inliers.
    """
    p = _points(points, 2, "RANSAC circle", 3)
    lo, hi = _positive(r_min, "r_min"), _positive(r_max, "r_max")
    if hi < lo:
        raise InputError(f"r_max ({r_max}) must be >= r_min ({r_min})")
    thr = _positive(threshold, "threshold")
    gen = _generator(rng)
    idx = gen.integers(0, p.shape[0], size=(int(max_iterations), 3))
    centres, radii = _circumcircles(p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]])
    ok = np.isfinite(radii) & (radii >= lo) & (radii <= hi)
    if not np.any(ok):
        raise GeometryError(
            f"RANSAC circle: no 3-point circle with radius in [{lo}, {hi}] m among "
            f"{max_iterations} hypotheses"
        )
    centres, radii = centres[ok], radii[ok]
    cost = np.zeros(radii.shape[0])
    chunk = max(1, 2_000_000 // p.shape[0])
    for s in range(0, radii.shape[0], chunk):
        diff = p[:, None, :] - centres[None, s : s + chunk]
        dist = np.linalg.norm(diff, axis=2) - radii[s : s + chunk]
        cost[s : s + chunk] = np.minimum(dist * dist, thr * thr).sum(axis=0)
    best = int(np.argmin(cost))
    c, r = centres[best], float(radii[best])
    mask = np.abs(np.linalg.norm(p - c, axis=1) - r) < thr
    for _ in range(3):
        if mask.sum() < 3:
            break
        try:
            fit = fit_circle_2d(p[mask], centre0=c)
        except GeometryError:
            break
        if not lo <= fit.radius <= hi:
            fit = fit_circle_2d(
                p[mask], centre0=fit.centre, radius_prior=min(max(fit.radius, lo), hi),
                radius_weight=math.inf,
            )
        c, r = fit.centre, fit.radius
        new = np.abs(np.linalg.norm(p - c, axis=1) - r) < thr
        if np.array_equal(new, mask):
            break
        mask = new
    count = int(mask.sum())
    if count < max(3, int(min_inliers)):
        raise GeometryError(
            f"RANSAC circle: best circle has {count} inliers within {thr} m, "
            f"need {max(3, min_inliers)}"
        )
    res = np.linalg.norm(p[mask] - c, axis=1) - r
    return CircleRansacFit(np.asarray(c, float), float(r), float(np.sqrt(np.mean(res * res))), mask)


# ----------------------------------------------------------------------------- square of circles


def square_template_2d(side: float) -> np.ndarray:
    """(4, 2) circle centres of a square of ``side`` about its centre: TL, TR, BL, BR (y up)."""
    h = float(side) / 2
    return np.array([[-h, h], [h, h], [-h, -h], [h, -h]])


def _rot2(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def _wrap_quarter(angle: float) -> tuple[float, int]:
    """Angle in [-pi/4, pi/4) and the number of quarter turns removed."""
    k = int(math.floor((angle + math.pi / 4) / (math.pi / 2)))
    return angle - k * math.pi / 2, k


def fit_square_circles_2d(
    points_2d: np.ndarray,
    side: float,
    centre0: np.ndarray,
    angle0: float,
    radius0: float,
    *,
    gate: float,
    radius_weight: float = 4.0,
    max_iterations: int = 30,
) -> SquareCirclesFit:
    """Fit four circles of a common radius on a rigid square of known ``side`` to (N, 2) points.

    Unknowns: square centre, rotation and radius, starting at ``centre0``, ``angle0``,
    ``radius0``. Each round assigns every point to its nearest circle (outlier when
    ``||p - c_k| - r| >= gate``) and takes Levenberg-Marquardt steps on ``|p - c_k| - r``; the
    radius is pulled toward ``radius0`` by ``sqrt(radius_weight) * (r - radius0)`` (math.inf
    fixes it). The result's angle is wrapped to [-pi/4, pi/4), relabelling the circles so that
    TL, TR, BL, BR keep their meaning in the 2D frame. Raises GeometryError when fewer than 4
    points on at least 2 circles are within the gate.
    """
    p = _points(points_2d, 2, "square-of-circles fit", 4)
    tmpl = square_template_2d(_positive(side, "side"))
    gate = _positive(gate, "gate")
    r0 = _positive(radius0, "radius0")
    fixed = math.isinf(radius_weight)
    w = 0.0 if fixed else math.sqrt(max(float(radius_weight), 0.0))
    x = np.array([*np.asarray(centre0, float).reshape(2), float(angle0), r0])

    def assign(x):
        cents = x[:2] + tmpl @ _rot2(x[2]).T
        dist = np.linalg.norm(p[:, None, :] - cents[None], axis=2)
        res = np.abs(dist - x[3])
        lab = np.argmin(res, axis=1)
        lab[res[np.arange(p.shape[0]), lab] >= gate] = -1
        return lab

    def residuals(x, q, tq):
        """Residuals and Jacobian of the points ``q`` on their circles' template offsets
        ``tq`` (one row more with the radius prior)."""
        m = q.shape[0]
        off = tq @ _rot2(x[2]).T
        diff = q - (x[:2] + off)
        dist = np.maximum(np.sqrt(diff[:, 0] ** 2 + diff[:, 1] ** 2), 1e-12)
        u = diff / dist[:, None]
        n_rows = m + 1 if w > 0 else m
        r = np.empty(n_rows)
        r[:m] = dist - x[3]
        J = np.zeros((n_rows, 4))
        J[:m, :2] = -u
        J[:m, 2] = u[:, 0] * off[:, 1] - u[:, 1] * off[:, 0]  # -u . d(R o)/d angle
        J[:m, 3] = -1.0
        if w > 0:
            r[m] = w * (x[3] - r0)
            J[m, 3] = w
        if fixed:
            J = J[:, :3]
        return r, J

    lab = assign(x)
    for _ in range(int(max_iterations)):
        if np.sum(lab >= 0) < 4 or np.unique(lab[lab >= 0]).size < 2:
            raise GeometryError(
                f"square-of-circles fit: only {int(np.sum(lab >= 0))} points on "
                f"{np.unique(lab[lab >= 0]).size} circles within {gate} m"
            )
        lam = 1e-3
        use = lab >= 0
        q, tq = p[use], tmpl[lab[use]]
        r, J = residuals(x, q, tq)
        cost = float(r @ r)
        for _ in range(20):
            H = J.T @ J
            step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -J.T @ r)
            if fixed:
                step = np.append(step, 0.0)
            x_new = x + step
            r_new, J_new = residuals(x_new, q, tq)
            c_new = float(r_new @ r_new)
            if c_new <= cost:
                x, r, J, cost = x_new, r_new, J_new, c_new
                lam = max(lam / 10, 1e-12)
                if np.linalg.norm(step) < 1e-10:
                    break
            else:
                lam *= 10
                if lam > 1e10:
                    break
        new = assign(x)
        if np.array_equal(new, lab):
            break
        lab = new
    if not (np.all(np.isfinite(x)) and x[3] > 0):
        raise GeometryError("square-of-circles fit diverged")
    angle, quarters = _wrap_quarter(float(x[2]))
    cents = x[:2] + tmpl @ _rot2(angle).T
    old = x[:2] + tmpl @ _rot2(float(x[2])).T
    if quarters:
        perm = np.argmin(np.linalg.norm(old[:, None] - cents[None], axis=2), axis=1)
        lab = np.where(lab >= 0, perm[np.maximum(lab, 0)], -1)
    use = lab >= 0
    res = np.linalg.norm(p[use] - cents[lab[use]], axis=1) - x[3]
    return SquareCirclesFit(
        x[:2].copy(), angle, float(x[3]), cents, lab, float(np.sqrt(np.mean(res * res)))
    )
