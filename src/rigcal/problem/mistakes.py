"""Name the mistake: the usual errors in a calibration's input, each tested for directly.

**Before the solve** (:func:`input_checks`, cheap, from the detections alone):

* *hole order*: the four circle centres of a board, in the documented order TL, TR, BL, BR as
  seen from the sensor, go round the square clockwise for a sensor in front of the board (the
  loop TL, TR, BR, BL's area vector points away from the sensor). A file whose boards go round
  the other way has a mirrored order; which mirror (TR, TL, BR, BL or another) is the one that
  makes the centres agree with another sensor's.
* *units*: a sensor whose detections are ~1000 x the others' (ranges to the boards, or the
  hole spacing against ``board.spacing_m``) is in millimetres (100 x: centimetres).
* *kind*: a camera's detections lie in front of it (optical frame, +z forward); a lidar sees
  the boards near its horizon. A camera's file that is not, and a lidar's file that looks
  like a camera's, are two files swapped.

**After the solve** (:func:`named_checks`): each mistake is one extra parameter of the model -
a sensor's scale, the reflector offset (for all boards, and per board), the hole spacing - and
its value is estimated from every pair's residuals at the result's poses, the poses re-fitted
with it (one Gauss-Newton step, so the estimate is that of a joint fit). Its variance comes from
the noise model, at the largest noise the data support (:class:`rigcal.problem.noise.
NoiseRegion`). A mistake is named when its parameter is far from zero both statistically
(:data:`ALPHA`, Bonferroni over the parameters tested) and physically (:data:`TOLERANCE`).
Also: a board's detection that is another placement's (an outlier, or a bad board kept). With
``initial`` poses (a previous calibration), before the solve: two sensors whose detections put
them where the other one was (files swapped).
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.geometry.align import kabsch_batch
from rigcal.geometry.se3 import invert, se3_log
from rigcal.problem.consistency import FAIL, NOTE, PASS, Check, Evidence, PairResiduals
from rigcal.problem.numerics import chi2_isf
from rigcal.problem.noise import COMPONENTS
from rigcal.sensors.radar import project_2d
from rigcal.targets.circle_board import reflectors_from_centres

#: tail probability of each family of named-mistake tests (Bonferroni over its parameters)
ALPHA = 1e-3
#: a mistake is named only when its parameter is at least this far off (physical tolerance):
#: a sensor's scale (relative), the reflector offset [m] (a corner reflector's phase centre is
#: not known much better; and with noisy cameras and noisy radars together the estimate
#: itself is biased: -25 +- 5 mm on the coverage benchmark's rig 46 - 20 mm camera noise, 30 mm
#: radar range noise - and unbiased when either is precise; its cause is not found), the hole
#: spacing [m] (a detector's circle centres need not sit exactly on the holes' centres)
TOLERANCE = {"scale": 0.003, "offset": 0.06, "spacing": 0.003}

#: the documented hole order and its names
HOLE_NAMES = ("TL", "TR", "BL", "BR")
#: the orders whose loop goes round the square the other way (mirror images of the documented
#: one), as column permutations: file column i holds documented hole ``perm[i]``
MIRRORS = {
    "TR, TL, BR, BL (mirrored left-right)": (1, 0, 3, 2),
    "BL, BR, TL, TR (mirrored upside down)": (2, 3, 0, 1),
    "TL, BL, TR, BR (transposed)": (0, 2, 1, 3),
    "BR, TR, BL, TL (transposed the other way)": (3, 1, 2, 0),
}


def z_critical(alpha: float, tests: int = 1) -> float:
    """Two-sided normal quantile for a family of ``tests`` tests at total level ``alpha``."""
    return math.sqrt(chi2_isf(alpha / max(tests, 1), 1.0))


def file_label(s: SensorDetections) -> str:
    """The sensor's detection file (its name) for messages, else the sensor's name."""
    return os.path.basename(s.source) if s.source and s.source != "simulated" else s.name


# --------------------------------------------------------------------------------------------
# before the solve


def handedness(points: np.ndarray) -> np.ndarray:
    """(K,) signed area of each board's hole loop (file columns 0, 1, 3, 2) seen from the
    sensor, divided by the square of the mean side: about +cos(incidence) for the documented
    order, about -cos(incidence) for a mirrored one; NaN for undetected boards."""
    c = np.asarray(points, dtype=float)
    loop = c[:, [0, 1, 3, 2]]
    area = 0.5 * np.sum(np.cross(loop, np.roll(loop, -1, axis=1)), axis=1)
    centroid = c.mean(axis=1)
    u = centroid / np.maximum(np.linalg.norm(centroid, axis=1, keepdims=True), 1e-12)
    side = np.mean(np.linalg.norm(loop - np.roll(loop, -1, axis=1), axis=2), axis=1)
    return np.einsum("ki,ki->k", area, u) / np.maximum(side**2, 1e-12)


def _kabsch_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance after the best rigid fit of points a (n, 3) onto b (n, 3)."""
    T = kabsch_batch(a[None], b[None])[0]
    if not np.all(np.isfinite(T)):
        return math.inf
    return float(np.sqrt(np.mean(np.sum((a @ T[:3, :3].T + T[:3, 3] - b) ** 2, axis=1))))


def _which_mirror(dataset: Dataset, s: SensorDetections, good: Sequence[str]) -> str:
    """The mirror whose reordering makes ``s``'s centres agree best with a correctly ordered
    sensor's on their shared boards (left-right when none can tell)."""
    names = list(MIRRORS)
    for other in good:
        o = dataset.sensor(other)
        shared = s.valid & o.valid
        if np.sum(shared) < 2:
            continue
        rms = [_kabsch_rms(s.points[shared][:, list(np.argsort(MIRRORS[n]))].reshape(-1, 3),
                           o.points[shared].reshape(-1, 3)) for n in names]
        return names[int(np.argmin(rms))]
    return names[0]


def hole_order_findings(dataset: Dataset) -> tuple[list[str], list[str]]:
    """(failures, notes) about the hole order of every lidar and camera."""
    fails, notes = [], []
    h = {s.name: handedness(s.points[s.valid]) for s in dataset.sensors if s.kind.is_point_cloud}
    good = [n for n, v in h.items() if v.size and np.mean(v < 0) <= 0.5]
    for s in dataset.sensors:
        v = h.get(s.name)
        if v is None or v.size == 0:
            continue
        negative = v < 0
        boards = np.flatnonzero(s.valid)[negative]
        if v.size >= 2 and np.mean(negative) > 0.5:
            order = _which_mirror(dataset, s, good)
            fails.append(
                f"{file_label(s)}: holes ordered {order} on {int(np.sum(negative))} of {v.size} boards "
                f"(the documented order is TL, TR, BL, BR as seen from the sensor); reorder the columns, "
                f"or set `hole_order: [{order.split(' (')[0]}]` for {s.name} in rig.yaml"
            )
        elif np.any(v < -0.3):
            notes.append(f"{s.name}: holes mirrored on board(s) {', '.join(map(str, boards[v[negative] < -0.3]))} only")
    return fails, notes


def _ranges(s: SensorDetections, dataset: Dataset) -> np.ndarray:
    """(K,) distance from the sensor to each board (centroid of the centres, or reflector)."""
    if s.kind.is_point_cloud:
        p = s.points.mean(axis=1)
    else:
        p = s.points
    return np.linalg.norm(p, axis=1)


def _unit_name(ratio: float) -> str | None:
    if 300.0 <= ratio <= 3000.0:
        return "millimetres read as metres"
    if 30.0 <= ratio < 300.0:
        return "centimetres read as metres"
    return None


def units_findings(dataset: Dataset) -> list[str]:
    """A sensor whose detections are ~1000 x (or ~100 x) the others', or whose holes are
    ~1000 x ``board.spacing_m`` apart."""
    out = []
    ranges = {s.name: _ranges(s, dataset) for s in dataset.sensors}
    med = {n: float(np.nanmedian(np.where(dataset.sensor(n).valid, r, np.nan)))
           for n, r in ranges.items() if np.any(dataset.sensor(n).valid)}
    named = set()
    for s in dataset.sensors:
        if s.name not in med:
            continue
        others = [v for n, v in med.items() if n != s.name and v > 0]
        if others and med[s.name] > 0:
            ratio = med[s.name] / float(np.median(others))
            unit = _unit_name(ratio)
            if unit is not None:
                named.add(s.name)
                out.append(f"{file_label(s)}: {s.name}'s detections are about {10 ** round(math.log10(ratio)):.0f} x "
                           "the other sensors' "
                           f"(median range {med[s.name]:.4g} m against {float(np.median(others)):.3g} m): "
                           f"{unit} - give them in metres")
    for s in dataset.sensors:
        if not s.kind.is_point_cloud or s.name in named or not np.any(s.valid):
            continue
        c = s.points[s.valid]
        side = float(np.median(np.linalg.norm(c[:, [0, 1, 3, 2]] - c[:, [1, 3, 2, 0]], axis=2)))
        ratio = side / dataset.board.spacing_m
        unit = _unit_name(ratio)
        if unit is not None:
            out.append(f"{file_label(s)}: {s.name}'s holes are {side:.3g} m apart, {ratio:.0f} x the board's "
                       f"spacing {dataset.board.spacing_m:g} m: {unit} - give them in metres")
    return out


#: a camera's boards lie within this angle of its optical axis (+z); a lidar's within
#: ``90 - this`` of its horizon
CAMERA_CONE_DEG = 60.0


def _off_axis_deg(s: SensorDetections) -> np.ndarray:
    p = s.points[s.valid]
    p = p.mean(axis=1) if s.kind.is_point_cloud else p
    n = np.maximum(np.linalg.norm(p, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(p[:, 2] / n, -1.0, 1.0)))


def kind_findings(dataset: Dataset) -> tuple[list[str], list[str]]:
    """(failures, notes): cameras whose detections are not in front of them (+z), and lidars
    whose detections look like a camera's - two files swapped."""
    not_camera, camera_like = [], []
    for s in dataset.sensors:
        if not s.kind.is_point_cloud or np.sum(s.valid) < 2:
            continue
        inside = _off_axis_deg(s) <= CAMERA_CONE_DEG
        if s.kind is SensorKind.CAMERA and np.mean(inside) < 0.5:
            not_camera.append((s, int(np.sum(~inside)), int(inside.size)))
        elif s.kind is SensorKind.LIDAR and np.mean(inside) > 0.8:
            camera_like.append(s)
    fails, notes = [], []
    for cam, off, n in not_camera:
        text = (f"{cam.name}: {off} of {n} boards are not in front of it (a camera's detections are in "
                f"its optical frame, +z forward: within {CAMERA_CONE_DEG:g} deg of it)")
        if camera_like:
            lid = " or ".join(f"{s.name} ({file_label(s)})" for s in camera_like)
            fails.append(f"{file_label(cam)} and {lid}: detection files swapped? {text}, while the boards in "
                         f"{lid} all lie within {CAMERA_CONE_DEG:g} deg of its z axis, as a camera's do")
        else:
            fails.append(f"{file_label(cam)}: {text} - a lidar's file, or a camera frame with x forward "
                         "(give the optical frame)")
    if not not_camera:
        for s in camera_like:
            notes.append(f"{s.name}: every board lies within {CAMERA_CONE_DEG:g} deg of its z axis (a lidar "
                         "usually sees them near its horizon) - a camera's file?")
    return fails, notes


def input_checks(dataset: Dataset, initial: Mapping[str, np.ndarray] | None = None) -> Check:
    """The ``inputs`` check: hole order, units and kinds of the detections, before the solve;
    with ``initial`` poses (a previous calibration), two sensors' files swapped."""
    fails, notes = hole_order_findings(dataset)
    units = units_findings(dataset)
    fails += units
    kf, kn = kind_findings(dataset)
    fails += kf
    notes += kn
    if initial and not units:
        fails += initial_swap_findings(dataset, initial)
    if fails:
        return Check("inputs", FAIL, "; ".join(fails + notes))
    if notes:
        return Check("inputs", NOTE, "; ".join(notes))
    return Check("inputs", PASS, "hole order, units and kinds of every detection file as documented")


# --------------------------------------------------------------------------------------------
# after the solve: one extra parameter per mistake


def _residuals_of(dataset: Dataset, res: PairResiduals) -> np.ndarray:
    """Every pair's metric residuals of ``dataset`` (the same rows as ``res``) at res's poses."""
    from rigcal.problem.configurations import build_pairwise
    from rigcal.problem.pairs import all_pairs
    from rigcal.problem.solver import _evaluate, prepare

    problem = build_pairwise(dataset, res.poses, res.reference, all_pairs(dataset))
    layout = prepare(problem)
    T = np.stack([p.T for p in problem.poses]).astype(float)
    r = _evaluate(problem, layout, T, "linear", 1.0, False)[0][: layout.m_obs]
    if r.shape != res.r.shape:
        raise ValueError("named checks: perturbed dataset changed the residual rows")
    return r


def _column(res: PairResiduals, perturbed: Dataset, h: float) -> np.ndarray:
    """d residuals / d parameter, by a forward difference of step ``h``."""
    return (_residuals_of(perturbed, res) - res.r) / h


def _with_points(dataset: Dataset, name: str, points: np.ndarray) -> Dataset:
    return replace(dataset, sensors=tuple(replace(s, points=points) if s.name == name else s
                                          for s in dataset.sensors))


def scale_columns(res: PairResiduals, h: float = 1e-6) -> dict[str, np.ndarray]:
    """Per sensor: d residuals / d (relative scale of its detections)."""
    out = {}
    for s in res.dataset.sensors:
        col = _column(res, _with_points(res.dataset, s.name, s.points * (1.0 + h)), h)
        if np.any(col):
            out[s.name] = col
    return out


def offset_column(res: PairResiduals, h: float = 1e-6) -> np.ndarray:
    """d residuals / d (reflector offset) [per m]."""
    board = replace(res.dataset.board, reflector_offset_m=res.dataset.board.reflector_offset_m + h)
    return _column(res, replace(res.dataset, board=board), h)


def usable_rows(res: PairResiduals, skip: Sequence[str] = ()) -> np.ndarray:
    """(rows,) bool: rows of pairs that involve none of the sensors ``skip`` (undetermined
    sensors: a linearisation about a pose the data do not fix says nothing)."""
    keep = np.ones(res.r.size, dtype=bool)
    row0 = 0
    for b in res.problem.observations:
        n = b.size * b.dim
        if set(b.frame) & set(skip) or set(b.observer) & set(skip):
            keep[row0:row0 + n] = False
        row0 += n
    return keep


def _sensor_rows(res: PairResiduals, name: str) -> np.ndarray:
    """(rows,) bool: rows of the pairs that involve sensor ``name``."""
    return ~usable_rows(res, (name,))


def fit_alternatives(res: PairResiduals, columns: np.ndarray, rows: np.ndarray | None = None,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each column j = d residuals / d beta (rows, q) of an extra parameter beta (0 as
    configured): the value of beta that fits the data, with the poses re-fitted (one weighted
    Gauss-Newton step from the result: ``r + J dx + j beta ~ 0``), and the variance of that
    estimate at the estimated noise and at the largest noise the data support. Returns (beta,
    var, var_upper), each (q,). ``rows``: the residual rows to use (default all)."""
    cols = np.asarray(columns, dtype=float).reshape(res.r.size, -1)
    w = 1.0 / np.maximum(res.M @ res.theta, 1e-8)
    if rows is not None:
        w = np.where(rows, w, 0.0)
    J = res.J
    if J.shape[1]:
        A = J.T @ (J * w[:, None])
        proj = np.linalg.lstsq(A, J.T @ (cols * w[:, None]), rcond=1e-12)[0]
        perp = cols - J @ proj
    else:
        perp = cols
    den = np.einsum("iq,iq->q", perp * w[:, None], perp)
    # a column the poses explain (almost) entirely leaves nothing to estimate it from
    ok = den > 1e-9 * np.einsum("iq,iq->q", cols * w[:, None], cols)
    beta = np.zeros(cols.shape[1])
    beta[ok] = -((perp[:, ok] * w[:, None]).T @ res.r) / den[ok]
    a = perp * w[:, None] / np.where(ok, den, 1.0)[None, :]
    Da = np.asarray(res.D.T @ a)  # (units, q)
    units = res.units
    var = np.zeros(cols.shape[1])
    var_up = np.zeros(cols.shape[1])
    for q in range(cols.shape[1]):
        c = np.bincount(units.group, weights=Da[:, q] ** 2 * units.scale**2, minlength=len(units.groups))
        var[q] = float(c @ res.theta)
        var_up[q] = res.region.upper(c)
    var[~ok] = var_up[~ok] = np.inf
    return beta, var, var_up


def _row_pairs(res: PairResiduals) -> list[tuple[str, str, np.ndarray]]:
    """(frame sensor, observer sensor, row indices) of every pair block of ``res``."""
    out, row0 = [], 0
    for b in res.problem.observations:
        n = b.size * b.dim
        out.append((b.frame[0], b.observer[0], np.arange(row0, row0 + n)))
        row0 += n
    return out


def star_rows(res: PairResiduals, rows: np.ndarray) -> np.ndarray:
    """(rows,) bool: of the ``rows`` a non-redundant set - per board, the pairs of one hub
    sensor (the first lidar or camera that saw it, else the first sensor) with each other
    sensor that saw it. Every pair of the board is a difference of two of these (to first
    order): they carry the same information, with a residual covariance of full rank."""
    order = {n: i for i, n in enumerate(res.dataset.names)}
    point = {s.name for s in res.dataset.sensors if s.kind.is_point_cloud}
    pairs = [(a, b, idx[rows[idx]]) for a, b, idx in _row_pairs(res)]
    hubs: dict[int, str] = {}
    for a, b, idx in pairs:
        for k in np.unique(res.row_board[idx]):
            for n in (a, b):
                h = hubs.get(int(k))
                if h is None or (n in point, -order[n]) > (h in point, -order[h]):
                    hubs[int(k)] = n
    keep = np.zeros(res.r.size, dtype=bool)
    for a, b, idx in pairs:
        hub = np.array([hubs[int(k)] for k in res.row_board[idx]])
        keep[idx[(hub == a) | (hub == b)]] = True
    return keep


def fit_efficient(res: PairResiduals, columns: np.ndarray, rows: np.ndarray | None = None,
                  unit_variances: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`fit_alternatives`, but weighted with the residuals' full covariance (pairs that
    share a sensor's detections are correlated): generalised least squares on
    :func:`star_rows`, whose covariance is block diagonal by board - the best linear unbiased
    estimate of the linearised pair model, its variance the Cramer-Rao bound of that model.
    ``unit_variances`` (units,): every noise unit's variance (default: the noise model's; the
    truth in a simulation, for the bound). Returns (beta, var, var_upper) as
    :func:`fit_alternatives` does (var_upper: at the largest noise the data support; with
    ``unit_variances``, var again)."""
    cols = np.asarray(columns, dtype=float).reshape(res.r.size, -1)
    idx = np.flatnonzero(star_rows(res, np.ones(res.r.size, dtype=bool) if rows is None else rows))
    D = res.D[idx]
    D = D.toarray() if hasattr(D, "toarray") else np.asarray(D)
    units = res.units
    var_u = (np.maximum(res.theta[units.group], 1e-12) * units.scale**2 if unit_variances is None
             else np.asarray(unit_variances, dtype=float))
    n, q = res.J.shape[1], cols.shape[1]
    X = np.column_stack([res.J[idx], cols[idx]])
    boards = res.row_board[idx]
    blocks = []  # (rows of the board, L^-1 with L L' its residual covariance)
    WX, Wr = np.zeros_like(X), np.zeros(idx.size)
    for k in np.unique(boards):
        sel = np.flatnonzero(boards == k)
        S = (D[sel] * var_u) @ D[sel].T
        Li = np.linalg.inv(np.linalg.cholesky(S + 1e-12 * np.trace(S) / sel.size * np.eye(sel.size)))
        blocks.append((sel, Li))
        WX[sel], Wr[sel] = Li @ X[sel], Li @ res.r[idx[sel]]
    beta, var, var_up = np.zeros(q), np.full(q, np.inf), np.full(q, np.inf)
    for j in range(q):
        x = WX[:, n + j]
        perp = x - WX[:, :n] @ np.linalg.lstsq(WX[:, :n], x, rcond=1e-12)[0] if n else x
        den = float(perp @ perp)
        if den <= 1e-9 * float(x @ x):
            continue  # a column the poses explain (almost) entirely
        beta[j] = -float(perp @ Wr) / den
        a = np.zeros(idx.size)  # the estimator as weights on the (unwhitened) rows
        for sel, Li in blocks:
            a[sel] = Li.T @ perp[sel] / den
        Da = D.T @ a
        if unit_variances is not None:
            var[j] = var_up[j] = float(np.sum(Da**2 * var_u))
            continue
        c = np.bincount(units.group, weights=Da**2 * units.scale**2, minlength=len(units.groups))
        var[j] = float(c @ res.theta)
        var_up[j] = res.region.upper(c)
    return beta, var, var_up


def under_alternative(res: PairResiduals, column: np.ndarray, rows: np.ndarray, sensor: str,
                      rounds: int = 2) -> PairResiduals:
    """``res`` with the noise model estimated as if the extra parameter of ``column`` (d residuals
    / d beta) - a mistake of ``sensor`` - were free: the residuals with beta and the poses fitted
    (weighted least squares, repeated ``rounds`` times with the noise they give). The residuals
    and poses stay those of ``res``; only ``theta`` and ``region`` change. A mistake left in the
    residuals inflates the noise estimate of the sensor it concerns - a radar's 1 % range scale
    read as 22 mm range noise where the truth is 3 mm - and a test judged with that noise hides
    it (the noise a likelihood-ratio test compares against is that of the better of the two
    models). Only ``sensor``'s noise may come out lower than in ``res``, and each of its
    components by no more than the variance the alternative explains in its residuals (their
    drop in squared size when it is fitted under the null's weights, weighted as in that
    component's likelihood equation); the other sensors keep the larger of the two estimates.
    A split of a pair's noise the data hardly tell wanders under the alternative: on the real
    Prius data a camera's lateral noise went to the floor, and with that kept, lidar1's x noise
    did."""
    from rigcal.problem.noise import estimate_theta_best, noise_region

    X = np.column_stack([res.J, np.asarray(column, dtype=float)])
    m, n = X.shape
    own = np.array([g[0] == sensor for g in res.units.groups])
    # each of the sensor's components: the weights of its likelihood equation under the null
    # (d theta_g = sum_i a_ig d r_i^2 / sum_i a_ig M_ig)
    M = np.asarray(res.M)
    v0 = np.maximum(M @ res.theta, 1e-8)
    a = np.where(rows[:, None], M[:, own] / v0[:, None] ** 2, 0.0)
    per_unit = np.maximum(np.sum(a * M[:, own], axis=0), 1e-300)

    def fitted(v: np.ndarray) -> np.ndarray:
        # the residuals with the poses and the parameter fitted, weighted by 1 / v
        w = np.where(rows, 1.0 / v, 0.0)
        return res.r + X @ np.linalg.lstsq(X.T @ (X * w[:, None]), -(X.T @ (w * res.r)), rcond=1e-12)[0]

    # what the parameter explains, fitted under the null's weights: each of the sensor's
    # components drops by that, no more (else it re-splits a pair's noise: on the real Prius
    # data lidar1's x noise went from 7.4 mm to the floor while its residuals hardly changed, and
    # a 0.5 % scale was flagged); not under the lowered noise, whose refit pulls the poses
    # towards that sensor and shrinks its residuals by itself
    r = fitted(v0)
    least = res.theta.copy()
    least[own] = np.maximum(res.theta[own] - np.maximum(a.T @ (res.r**2 - r**2), 0.0) / per_unit, 0.0)
    out = res
    for k in range(rounds):
        if k:
            r = fitted(np.maximum(out.M @ out.theta, 1e-8))
        theta = estimate_theta_best(r[rows], res.M[rows], m / max(m - n, 1), batches=res.batches[rows])
        theta = np.maximum(theta, least)
        out = replace(res, theta=theta, region=noise_region(res.M[rows], theta))
    return out


#: a sensor whose scale is this many std off under the noise estimated without it is judged
#: again with the noise estimated with its scale free (:func:`under_alternative`)
SCALE_SCREEN_Z = 2.0


def scale_check(res: PairResiduals, skip: Sequence[str] = ()) -> Check | None:
    """``scale``: a sensor whose detections are too large or too small relative to the others'
    (wrong units in part, a stereo baseline or focal length off, a lidar's range scale).
    Sensors in ``skip`` (undetermined) are not judged."""
    rows = usable_rows(res, skip)
    cols = {n: c for n, c in scale_columns(res).items() if n not in skip and np.any(c[rows])}
    if len(cols) < 2:
        return None
    names = list(cols)
    X = np.column_stack([cols[n] for n in names])
    beta, _, var_up = fit_alternatives(res, X, rows)
    limit = z_critical(ALPHA, len(names))
    # the (at most two) sensors that look off, but not beyond the limit, are judged again
    # under the noise estimated with their scale free
    z0 = np.abs(beta) / np.sqrt(var_up)
    for j in [int(i) for i in np.argsort(-z0)[:2] if SCALE_SCREEN_Z < z0[i] <= limit]:
        b, _, v = fit_alternatives(under_alternative(res, X[:, j], rows, names[j]), X, rows)
        beta[j], var_up[j] = b[j], v[j]
    # beta: the correction (the detections times 1 + beta fit); how far off they are: 1 / (1 + beta)
    beta = 1.0 / (1.0 + beta) - 1.0
    sd = np.sqrt(var_up)
    z = beta / sd
    evidence = tuple(Evidence(f"{n} scale - 1", float(b), float(limit * s), "estimate (threshold: "
                              f"{limit:.1f} std)") for n, b, s in zip(names, beta, sd))
    order = np.argsort(-np.abs(z))
    top = int(order[0])
    if abs(z[top]) > limit and abs(beta[top]) > TOLERANCE["scale"]:
        # two sensors alone: either one's scale explains the pair
        also = [names[i] for i in order[1:] if abs(z[i]) >= 0.8 * abs(z[top]) and abs(beta[i]) > TOLERANCE["scale"]]
        who = " or ".join([names[top]] + also[:1])
        s = res.dataset.sensor(names[top])
        return Check("scale", FAIL, (
            f"{who}: detections {1 + beta[top]:.4f} x too {'large' if beta[top] > 0 else 'small'} against the "
            f"other sensors' (scale {beta[top] * 100:+.2f} % +- {sd[top] * 100:.2f} %, {abs(z[top]):.1f} std) - "
            f"wrong units, or a scale error of {file_label(s)}'s detector (a stereo baseline, a focal length, a "
            "lidar's range calibration)"), evidence)
    return Check("scale", PASS, "every sensor's detections agree in scale with the others' "
                 f"(largest {abs(beta[top]) * 100:.2f} %, {abs(z[top]):.1f} std)", evidence)


def _board_columns(res: PairResiduals, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The column split per board: (boards, (rows, boards))."""
    rows = np.flatnonzero(col != 0)
    boards = np.unique(res.row_board[rows])
    out = np.zeros((col.size, boards.size))
    for i, k in enumerate(boards):
        sel = res.row_board == k
        out[sel, i] = col[sel]
    return boards, out


def _excluded_offsets(dataset: Dataset, full: Dataset, res: PairResiduals) -> dict[int, float]:
    """Boards excluded for a radar (outliers): the change of the reflector offset that puts
    each back on its partners' prediction (least squares over its pairs with lidars and
    cameras, at the result's poses)."""
    from rigcal.problem.pairs import pair_data
    from rigcal.targets.circle_board import board_normals

    rows: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for s in dataset.sensors:
        if not s.kind.is_radar:
            continue
        gone = np.flatnonzero(full.sensor(s.name).valid & ~s.valid)
        for t in dataset.sensors if gone.size else ():
            if not t.kind.is_point_cloud:
                continue
            p = pair_data(full, t.name, s.name, gone)
            if p is None or p.num_boards == 0:
                continue
            T_s_t = invert(res.poses[s.name]) @ res.poses[t.name]
            normal = board_normals(full.sensor(t.name).points[p.board]) @ T_s_t[:3, :3].T
            x = p.points @ T_s_t[:3, :3].T + T_s_t[:3, 3]
            if s.kind is SensorKind.RADAR:
                h, d = project_2d(x), (project_2d(x + 1e-4 * normal) - project_2d(x)) / 1e-4
            else:
                h, d = x, normal
            for k, rr, dd in zip(p.board, h - p.measured, d):
                rows.setdefault(int(k), []).append((rr, dd))
    est = {}
    for k, items in rows.items():
        r = np.concatenate([i[0] for i in items])
        d = np.concatenate([i[1] for i in items])
        est[k] = float(-(d @ r) / max(float(d @ d), 1e-12))
    return est


def _judged_without(res: PairResiduals, rows: np.ndarray, col: np.ndarray, per: np.ndarray,
                    boards: np.ndarray, leave: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every board's offset estimate and its std (at the largest noise the data support) with
    the noise estimated and the poses re-fitted without the radar rows of the boards ``leave``;
    each board judged with its own rows added back."""
    from rigcal.problem.noise import estimate_theta_best, noise_region

    bad = np.isin(res.row_board, leave) & (col != 0)
    clean = rows & ~bad
    m, n = res.J.shape
    # the poses re-fitted without those rows (one Gauss-Newton step), then the noise
    w = np.where(clean, 1.0 / np.maximum(res.M @ res.theta, 1e-8), 0.0)
    step = np.linalg.lstsq(res.J.T @ (res.J * w[:, None]), -(res.J.T @ (w * res.r)), rcond=1e-12)[0]
    r = res.r + res.J @ step
    theta = estimate_theta_best(r[clean], res.M[clean], m / max(m - n, 1), batches=res.batches[clean])
    judged = replace(res, r=r, theta=theta, region=noise_region(res.M[clean], theta))
    out_b, out_sd = np.zeros(boards.size), np.zeros(boards.size)
    b, _, v = fit_alternatives(judged, per, clean)  # the boards not left out
    out_b[:], out_sd[:] = b, np.sqrt(v)
    for i, k in enumerate(boards):
        if k in leave:
            b, _, v = fit_alternatives(judged, per[:, i:i + 1], clean | (bad & (res.row_board == k)))
            out_b[i], out_sd[i] = float(b[0]), float(np.sqrt(v[0]))
    return out_b, out_sd


def reflector_check(res: PairResiduals, full: Dataset | None = None, skip: Sequence[str] = (),
                    held_guess: Sequence[str] = ()) -> Check | None:
    """``reflector``: the configured reflector offset against what the radar pairs show, for
    all boards together and board by board (a reflector in front of the plate on some boards:
    2 x the offset nearer). Pairs with a sensor in ``skip`` (undetermined) are left out.
    ``held_guess``: 2D radars whose z, roll and pitch are held at the automatic guess (every
    reflector on the radar plane): a wrong guess looks like an offset common to all boards, so
    that finding is a note naming both causes (one that differs board by board still fails)."""
    rows = usable_rows(res, skip)
    col = np.where(rows, offset_column(res), 0.0)
    if not np.any(col):
        return None
    offset = res.dataset.board.reflector_offset_m
    beta, _, var_up = fit_alternatives(res, col[:, None], rows)
    sd = float(np.sqrt(var_up[0]))
    boards, per = _board_columns(res, col)
    b_k, _, v_k = fit_alternatives(res, per, rows)
    sd_k = np.sqrt(v_k)
    limit = z_critical(ALPHA, 1)
    limit_k = z_critical(ALPHA, boards.size)
    # boards whose own estimate leans to the other side of the plate are judged again against
    # the noise and poses of the other boards (a third of the boards on the wrong side inflate
    # the noise estimate and pull the poses they would otherwise be judged by); repeated with
    # the boards that lean that way then, until they stay the same
    side = np.zeros(boards.size, dtype=bool)
    if offset > 0:
        left: set[int] = set()
        for _ in range(4):
            leave = set(boards[b_k < -0.5 * offset].tolist())
            if not leave or len(leave) >= boards.size or leave == left:
                break
            b_k, sd_k = _judged_without(res, rows, col, per, boards, np.array(sorted(leave)))
            side = np.abs(b_k + 2.0 * offset) < np.maximum(3.0 * sd_k, 0.5 * offset)
            left = leave
    z_k = b_k / sd_k
    wrong = (np.abs(z_k) > limit_k) & (np.abs(b_k) > TOLERANCE["offset"])
    excluded = _excluded_offsets(res.dataset, full, res) if full is not None else {}
    far = {k: v for k, v in excluded.items() if offset > 0 and abs(v + 2.0 * offset) < 0.5 * offset}
    evidence = (Evidence("reflector offset - configured", float(beta[0]), float(limit * sd),
                         f"estimate [m] (threshold: {limit:.1f} std)"),) + tuple(
        Evidence(f"board {int(k)}", float(b), float(limit_k * s), "offset estimate - configured [m]")
        for k, b, s in zip(boards, b_k, sd_k))
    if np.any(wrong & side) or (far and np.any(wrong)):
        ks = sorted(set(boards[wrong & side].tolist()) | set(far))
        others = [int(k) for k in boards[wrong & ~side]]
        return Check("reflector", FAIL, (
            f"on board(s) {', '.join(map(str, ks))} the radars see the reflector about {2 * offset:.2f} m nearer "
            f"than the configured offset ({offset:.3f} m behind the front face) says: the reflector in front of "
            "the plate (mounted on the wrong side) on those placements - fix them, or exclude those boards"
            + (f" (boards {', '.join(map(str, sorted(far)))} were already excluded as outliers)" if far else "")
            + (f"; boards {', '.join(map(str, others))} are off too" if others else "")), evidence)
    held = [n for n in held_guess if np.any(rows & _sensor_rows(res, n))]
    radars = [s.name for s in res.dataset.sensors
              if s.kind in (SensorKind.RADAR, SensorKind.RADAR3D) and np.any(rows & _sensor_rows(res, s.name))]
    if abs(beta[0]) > limit * sd and abs(beta[0]) > TOLERANCE["offset"] and held:
        return Check("reflector", NOTE, (
            f"the radar pairs put the reflector {offset + beta[0]:.3f} +- {sd:.3f} m behind the front face, the "
            f"configured offset is {offset:.3f} m - but {', '.join(held)}'s z, roll and pitch are held at the "
            "automatic guess (every reflector on the radar plane), and a wrong guess looks the same: give its "
            "mounting with --initial, or calibrate without --hold-radar-plane; if the offset is wrong, set "
            f"board.reflector_offset_m: {max(offset + beta[0], 0.0):.3f}"), evidence)
    if abs(beta[0]) > limit * sd and abs(beta[0]) > TOLERANCE["offset"] and len(radars) == 1:
        # one radar: an offset common to all boards and a bias of that radar's ranges look alike
        # (boards face the rig); two radars tell them apart
        return Check("reflector", NOTE, (
            f"the radar pairs put the reflector {offset + beta[0]:.3f} +- {sd:.3f} m behind the front face, the "
            f"configured offset is {offset:.3f} m: a wrong offset (set board.reflector_offset_m: "
            f"{max(offset + beta[0], 0.0):.3f}) or a bias of {radars[0]}'s ranges of about {beta[0]:+.2f} m - with one "
            "radar the two look alike"), evidence)
    if abs(beta[0]) > limit * sd and abs(beta[0]) > TOLERANCE["offset"]:
        return Check("reflector", FAIL, (
            f"board geometry: the radar pairs put the reflector {offset + beta[0]:.3f} +- {sd:.3f} m behind the "
            f"front face, the configured reflector offset is {offset:.3f} m - set board.reflector_offset_m: "
            f"{max(offset + beta[0], 0.0):.3f} in rig.yaml (the corner reflector's phase centre)"), evidence)
    if np.any(wrong):
        ks = ", ".join(str(int(k)) for k in boards[wrong])
        return Check("reflector", NOTE, f"board(s) {ks}: the radars see the reflector off the configured offset "
                     f"by {', '.join(f'{b * 1000:+.0f} mm' for b in b_k[wrong])}", evidence)
    if far:
        return Check("reflector", NOTE, f"board(s) {', '.join(map(str, sorted(far)))} (excluded as outliers): the "
                     f"radars saw the reflector about {2 * offset:.2f} m nearer than configured - in front of "
                     "the plate on those placements?", evidence)
    return Check("reflector", PASS, f"the radar pairs agree with the reflector offset {offset:.3f} m "
                 f"({beta[0] * 1000:+.1f} +- {sd * 1000:.1f} mm)", evidence)


def _point_covariances(res: PairResiduals, s: SensorDetections, pts: np.ndarray,
                       theta_all: np.ndarray | None = None) -> np.ndarray:
    """(n, 3, 3) covariance of detected points ``pts`` (n, 3) of ``s`` under the estimated
    noise model (or the group variances ``theta_all``)."""
    from rigcal.problem.noise import _point_units

    comps, dirs, scales = _point_units(s.kind, pts)
    th = res.theta if theta_all is None else theta_all
    theta = {c: th[res.units.groups.index((s.name, c))] for c in COMPONENTS[s.kind]}
    var = np.stack([theta[c] * scales[:, i] ** 2 for i, c in enumerate(comps)], axis=1)  # (n, c)
    return np.einsum("nc,nci,ncj->nij", var, dirs, dirs)


#: a board's two pairs of parallel sides (file order TL, TR, BL, BR): top TR - TL and bottom
#: BR - BL, left BL - TL and right BR - TR. The two sides of a pair share no hole, so their
#: noises are independent and the dot product of the two measured sides is an unbiased
#: estimate of the squared spacing, whatever the noise (a squared length is not: noise
#: lengthens every distance by an amount only a noise model could say)
_PARALLEL_SIDES = (((1, 0), (3, 2)), ((2, 0), (3, 1)))


def _board_spacings(C: np.ndarray, cov: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per board (``C`` (k, 4, 3) centres, ``cov`` (k, 4, 3, 3) their covariances): the squared
    spacing the board shows - the mean of its two parallel-side dot products (unbiased, no noise
    model in it) - and that mean's variance under ``cov``. The variance is evaluated at sides of
    the configured length ``spacing_m`` along the measured directions, not at the measured
    lengths: a weight that grows as a board's sides come out short would bias the weighted mean
    (the measured length and its error go together)."""
    lin, quad = [], 0.0
    for (a, b), (c, d) in _PARALLEL_SIDES:
        d1, d2 = C[:, a] - C[:, b], C[:, c] - C[:, d]
        u = d1 + d2
        u = spacing_m * u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        # first order: u . (e_a - e_b + e_c - e_d); second order: (e_a - e_b) . (e_c - e_d)
        lin.append((u, (a, b, c, d)))
        C1, C2 = cov[:, a] + cov[:, b], cov[:, c] + cov[:, d]
        quad = quad + np.einsum("kij,kji->k", C1, C2)
    q = 0.5 * sum(np.sum((C[:, a] - C[:, b]) * (C[:, c] - C[:, d]), axis=1) for (a, b), (c, d) in _PARALLEL_SIDES)
    # the linear parts of the two products as loadings on each hole's error: (k, 4, 3)
    load = np.zeros(C.shape)
    for u, (a, b, c, d) in lin:
        load[:, a] += 0.5 * u
        load[:, b] -= 0.5 * u
        load[:, c] += 0.5 * u
        load[:, d] -= 0.5 * u
    var = np.einsum("khi,khij,khj->k", load, cov, load) + 0.25 * quad
    return q, var


def spacing_check(res: PairResiduals) -> Check | None:
    """``spacing``: the hole spacing the lidars' and cameras' centres show against
    ``board.spacing_m`` - from each board's shape alone (no pose or other sensor enters): the
    dot products of its parallel sides (:func:`_board_spacings`), unbiased whatever the noise.
    Boards are weighted by the noise model; the variance is the larger of the noise model's and
    the boards' own scatter (robust to a noise model that does not fit).

    Measured on 300 clean rigs of the verdict population (FCPE poses, seed 0): (estimate -
    truth) / std has mean -0.07 and std 0.90. The squared hole distances corrected by the noise
    model that this replaced kept only the distances whose noise was below 1 % of their squared
    length *as measured*: with 10-15 mm lidar noise only the diagonals that came out long
    passed, and two clean rigs read 0.253 and 0.258 m for 0.24."""
    board = res.dataset.board
    s0 = board.spacing_m
    per, all_q, all_v = {}, [], []
    # a lidar's noise per axis is often a weak split (which axis carries it depends on the
    # other sensors' directions): its board shapes are weighted with the mean of its axes
    theta = np.array(res.theta)
    for s in res.dataset.sensors:
        if s.kind is SensorKind.LIDAR:
            g = [res.units.groups.index((s.name, c)) for c in COMPONENTS[s.kind]]
            theta[g] = np.mean(theta[g])
    for s in res.dataset.sensors:
        if not s.kind.is_point_cloud or np.sum(s.valid) == 0:
            continue
        C = s.points[s.valid]
        # plus (1 mm)^2 per coordinate: no centre is known better than that
        cov = _point_covariances(res, s, C.reshape(-1, 3), theta).reshape(C.shape[0], 4, 3, 3) + 1e-6 * np.eye(3)
        q, v = _board_spacings(C, cov, s0)
        all_q.append(q)
        all_v.append(v)
        per[s.name] = _combine(q, v)
    if not per:
        return None
    s2, var2 = _combine(np.concatenate(all_q), np.concatenate(all_v))
    spacing = math.sqrt(max(s2, 0.0))
    beta = spacing - s0
    sd = math.sqrt(var2) / (2.0 * max(spacing, 1e-9))
    per = {n: (math.sqrt(max(q2, 0.0)) - s0, math.sqrt(v2) / (2.0 * max(math.sqrt(max(q2, 0.0)), 1e-9)))
           for n, (q2, v2) in per.items()}
    limit = z_critical(ALPHA, 1)
    evidence = (Evidence("spacing - configured", beta, limit * sd,
                         f"estimate [m] (threshold: {limit:.1f} std)"),) + tuple(
        Evidence(f"{n} spacing - configured", b, limit * v, "estimate [m]") for n, (b, v) in per.items())
    if abs(beta) > limit * sd and abs(beta) > TOLERANCE["spacing"]:
        # every sensor must agree (one sensor off is its own scale, not the board's)
        chi = sum(((b - beta) / v) ** 2 for b, v in per.values())
        if len(per) == 1 or chi <= chi2_isf(ALPHA, max(len(per) - 1, 1)):
            return Check("spacing", FAIL, (
                f"board geometry: the lidars' and cameras' circle centres are {spacing:.4f} +- {sd:.4f} m apart, "
                f"the configured hole spacing is {s0:.4f} m - set board.spacing_m: {spacing:.3f} in rig.yaml "
                "(and check the detectors' board)"), evidence)
    return Check("spacing", PASS, f"the centres agree with the hole spacing {s0:.3f} m "
                 f"({beta * 1000:+.1f} +- {sd * 1000:.1f} mm)", evidence)


def _combine(q: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """Inverse-variance mean of per-board estimates ``q`` (model variances ``v``) and its
    variance: the larger of the model's and the boards' own scatter (widened for few boards)."""
    w = 1.0 / v
    mean = float(np.sum(w * q) / np.sum(w))
    var_model = float(1.0 / np.sum(w))
    N = q.size
    var_emp = float(np.sum(w**2 * (q - mean) ** 2) / np.sum(w) ** 2) * N / max(N - 1, 1) * (1.0 + 4.0 / max(N - 1, 1))
    return mean, max(var_model, var_emp if N > 1 else var_model)


# --------------------------------------------------------------------------------------------
# a board from another placement; two files swapped (against initial poses)


def _predicted(dataset: Dataset, poses: Mapping[str, np.ndarray], s: SensorDetections) -> np.ndarray:
    """(K, ...) what ``s`` should have measured on every board, from the other sensors (mean
    over them; NaN where none saw the board)."""
    acc, cnt = None, np.zeros(dataset.num_boards)
    for t in dataset.sensors:
        if t.name == s.name or not t.valid.any():
            continue
        T = invert(poses[s.name]) @ poses[t.name]
        if s.kind.is_point_cloud:
            if not t.kind.is_point_cloud:
                continue
            x = t.points @ T[:3, :3].T + T[:3, 3]
        else:
            if t.kind is SensorKind.RADAR:
                continue
            refl = reflectors_from_centres(t.points, dataset.board) if t.kind.is_point_cloud else t.points
            x = refl @ T[:3, :3].T + T[:3, 3]
            if s.kind is SensorKind.RADAR:
                x = project_2d(x)
        ok = t.valid
        if acc is None:
            acc = np.zeros_like(x)
        acc[ok] += x[ok]
        cnt[ok] += 1
    if acc is None:
        return np.full((dataset.num_boards,) + s.kind.point_shape, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        return acc / cnt.reshape((-1,) + (1,) * (acc.ndim - 1))


def placement_findings(full: Dataset, poses: Mapping[str, np.ndarray], suspects: Mapping[str, Sequence[int]],
                       ) -> list[str]:
    """For each suspect (sensor, board): the other placement whose prediction its detection
    matches, when one does far better than its own."""
    out = []
    for name, boards in suspects.items():
        s = full.sensor(name)
        pred = _predicted(full, poses, s)
        seen = np.all(np.isfinite(pred.reshape(full.num_boards, -1)), axis=1)
        for k in sorted(boards):
            if not s.detected[k]:
                continue
            d = s.points[k]
            err = np.sqrt(np.mean(np.sum((pred - d) ** 2, axis=-1).reshape(full.num_boards, -1), axis=1))
            err[~seen] = np.inf
            own = err[k]
            err[k] = np.inf
            j = int(np.argmin(err))
            if np.isfinite(err[j]) and err[j] < 0.1 and (not np.isfinite(own) or own > 3.0 * err[j] + 0.05):
                out.append(f"{name}'s detection of board {k} is that of placement {j} ({err[j] * 1000:.0f} mm from "
                           f"it, {own * 1000:.0f} mm from board {k}'s) - a frame or file from another placement")
    return out


def _pose_difference(E: np.ndarray, I: np.ndarray, radar_a: bool, radar_b: bool) -> float:
    """How far relative pose ``E`` (T_a_b) is from ``I``: |translation| [m] + |rotation| [rad]
    x 1 m; with a 2D radar in the pair only the position along the radar's plane (its height
    and tilt are not measured)."""
    if radar_a and radar_b:
        return math.nan
    if radar_b:  # b's position in a's frame, without b's own z
        d = E[:3, 3] - I[:3, 3]
        z = I[:3, 2]
        return float(np.linalg.norm(d - (d @ z) * z))
    if radar_a:  # b's position in the radar's frame, x and y only
        return float(np.linalg.norm((E[:3, 3] - I[:3, 3])[:2]))
    xi = se3_log(invert(I) @ E)
    return float(np.linalg.norm(xi[3:]) + np.linalg.norm(xi[:3]))


#: a sensor at least this far from its initial pose (m + rad x 1 m, median over its pairs) and
#: within it of the other's after exchanging the two is named as swapped with it
SWAP_M = 0.05


def swap_findings(poses: Mapping[str, np.ndarray], initial: Mapping[str, np.ndarray], dataset: Dataset,
                  ) -> list[str]:
    """Two sensors whose ``poses`` (``T_X_sensor`` in any common frame X: estimates, or the
    poses the detections imply) came out at each other's ``initial`` poses (a previous
    calibration): their detection files are swapped."""
    names = [n for n in dataset.names if n in initial and n in poses]
    if len(names) < 2:
        return []
    est = {n: np.asarray(poses[n], float) for n in names}
    ini = {n: np.asarray(initial[n], float) for n in names}
    radar = {n: dataset.sensor(n).kind is SensorKind.RADAR for n in names}

    def per_sensor(perm: Mapping[str, str]) -> dict[str, float]:
        """Per sensor: the median over its partners of the pair's pose difference."""
        errs: dict[str, list[float]] = {n: [] for n in names}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                e = _pose_difference(invert(est[perm[a]]) @ est[perm[b]], invert(ini[a]) @ ini[b], radar[a], radar[b])
                if np.isfinite(e):
                    errs[a].append(e)
                    errs[b].append(e)
        return {n: float(np.median(v)) if v else 0.0 for n, v in errs.items()}

    ident = {n: n for n in names}
    base = per_sensor(ident)
    shape = {n: dataset.sensor(n).kind.point_shape for n in names}
    best, pair = None, None
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if shape[a] != shape[b] or min(base[a], base[b]) < SWAP_M:
                continue
            after = per_sensor(dict(ident, **{a: b, b: a}))
            worst = max(after[a], after[b])
            if worst <= min(SWAP_M, min(base[a], base[b]) / 3.0) and (best is None or worst < best):
                best, pair = worst, (a, b)
    if pair is None:
        return []
    a, b = pair
    return [f"{file_label(dataset.sensor(a))} and {file_label(dataset.sensor(b))}: detection files swapped? "
            f"{a} and {b} "
            f"are where the other was in the initial poses ({base[a]:.2f} and {base[b]:.2f} from their own, "
            f"{best:.3f} exchanged; m + rad) - give each sensor its own file"]


def initial_swap_findings(dataset: Dataset, initial: Mapping[str, np.ndarray]) -> list[str]:
    """:func:`swap_findings` before the solve, on the poses the detections imply (Kabsch per
    pair, robust), so that a solve started from the swapped initial poses cannot hide it."""
    from rigcal.errors import RigcalError
    from rigcal.problem.initialise import default_reference, initial_poses

    try:
        implied = initial_poses(dataset, default_reference(dataset), robust=True)
    except RigcalError:
        return []
    return swap_findings(implied, initial, dataset)


def named_checks(
    res: PairResiduals | None,
    full: Dataset,
    outliers: Mapping[str, Sequence[int]] = {},  # noqa: B006 - read only
    bad_boards: Mapping[str, Sequence[int]] = {},  # noqa: B006
    skip: Sequence[str] = (),
    held_guess: Sequence[str] = (),
) -> tuple[Check, ...]:
    """The named-mistake checks after the solve: ``scale``, ``reflector``, ``spacing``,
    ``placements`` (suspects: ``outliers`` excluded and ``bad_boards`` kept, per sensor).
    ``full``: the dataset before outliers were excluded;
    ``skip``: undetermined sensors, whose pairs the tests of an extra parameter leave out;
    ``held_guess``: 2D radars held at the automatic guess (:func:`reflector_check`)."""
    if res is None:
        return ()
    checks = [c for c in (scale_check(res, skip), reflector_check(res, full, skip, held_guess), spacing_check(res))
              if c is not None]
    suspects: dict[str, set[int]] = {}
    for src in (outliers, bad_boards):
        for s, ks in src.items():
            suspects.setdefault(s, set()).update(int(k) for k in ks)
    found = placement_findings(full, res.poses, suspects) if suspects else []
    if found:
        kept = any(int(k) in set(bad_boards.get(s, ())) for s, ks in suspects.items() for k in ks)
        checks.append(Check("placements", FAIL if kept else NOTE, "; ".join(found)))
    return tuple(checks)


__all__ = [
    "ALPHA",
    "HOLE_NAMES",
    "MIRRORS",
    "TOLERANCE",
    "file_label",
    "fit_alternatives",
    "handedness",
    "initial_swap_findings",
    "input_checks",
    "named_checks",
    "placement_findings",
    "reflector_check",
    "scale_check",
    "spacing_check",
    "swap_findings",
    "z_critical",
]
