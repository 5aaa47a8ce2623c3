"""Is a calibrated rig still calibrated? New board detections judged under a stored calibration.

:func:`check` answers per sensor ``unchanged``, ``moved`` (how far, which way, how sure) or
``cannot tell`` (and the smallest change the data could have found), and per sensor pair how
the new residuals compare with the stored noise model.

**Per sensor.** The sensor's pose is estimated again from the new detections with every other
sensor held at its stored pose (the pairwise problem of :mod:`rigcal.problem.configurations`
with one free pose block; screened with one Gauss-Newton step from the stored pose, solved by
:func:`rigcal.problem.solver.solve` where that finds a change; a 2D radar's z, roll and pitch
held too: it does not measure them). The change ``delta`` from the stored pose is tested with a
chi-square test (:mod:`rigcal.problem.movement`) under the sum of

* the re-estimate's covariance: the sandwich of the noise model
  (:func:`rigcal.problem.noise.sandwich`); each pair's rows weighted by the noise model plus what
  the partner's stored uncertainty adds to them (a poorly known partner weighs less); and
* the stored calibration's own uncertainty as it enters the re-estimate: the pair with sensor
  ``o`` pulls the estimate by ``W_o r_o``, ``r_o`` the stored error of the relative pose
  ``T_o_s`` and ``W_o`` (k, 6) its share of the information (all six directions: a 2D radar's
  stored z, roll and pitch errors move its in-plane re-estimate); see :func:`_stored_term`.

The noise model is, per component, the larger of the stored one and one estimated from the new
detections (every pose refitted to them): the stored model tells a pair's noise apart between
its two sensors only through loops of pairs, and can put one sensor's component at its floor.
When the residuals of a re-estimate scatter more than the model says, the test becomes an F-test
with their variance.

Only directions the new boards determine are tested (a sensor paired only with a 2D radar
is not tested in the directions the radar does not see); a 2D radar's z, roll and pitch never
are. The tests are Bonferroni-corrected over the sensors (``alpha`` is the chance of a false
alarm on a rig where nothing moved). When sensors are significant, the most significant one is
declared moved and every other sensor is tested again without the pairs it shares with it -
a sensor that only looked moved because its partner moved is then unchanged. If the data
cannot tell two sensors apart (each one's change explains the data as well as the other's:
a rig of two sensors, or directions only their own pair sees), both are named.

**Per pair.** The residuals at the stored poses against the noise model and the stored
relative pose's uncertainty (reduced chi-square; ~1 when nothing moved), and again after the
moved sensors' re-estimates. Pairs whose residuals stay far above the model although neither
sensor moved are reported as a warning.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import adjoint, invert, se3_exp, se3_log
from rigcal.problem.configurations import RADAR_PLANE_FREE, build_pairwise
from rigcal.problem.movement import (
    MoveTest,
    change_std,
    change_summary,
    finite_or_none,
    format_deg,
    format_mm,
    format_p,
    format_vector,
    move_test_fields,
    move_test,
    determined_basis,
)
from rigcal.problem.noise import (
    COMPONENT_UNITS,
    detection_units,
    estimate_theta,
    group_design,
    noise_map,
    row_batches,
    sandwich,
)
from rigcal.problem.numerics import chi2_sf, single_threaded
from rigcal.problem.pairs import all_pairs
from rigcal.problem.solver import ALL_FREE, PoseBlock, Problem, linearise, solve
from rigcal.problem.stored import StoredCalibration, untestable_directions

if TYPE_CHECKING:
    from rigcal.problem.result import CalibrationResult

UNCHANGED, MOVED, CANNOT_TELL = "unchanged", "moved", "cannot tell"
#: verdicts from the worst to the best
STATUS_ORDER = (MOVED, CANNOT_TELL, UNCHANGED)


@dataclass(frozen=True)
class CheckOptions:
    """How to check.

    ``alpha``: the chance of a false alarm on a rig where nothing moved (0.05: the 95 % level),
    shared among the sensors tested. ``power``: the probability at which the smallest detectable
    change is quoted. A sensor that shares fewer than ``min_boards`` boards with the others, or
    whose smallest detectable change is above ``max_detectable_m`` or ``max_detectable_deg``, is
    ``cannot tell`` rather than ``unchanged`` (too few boards to say).
    """

    alpha: float = 0.05
    power: float = 0.8
    max_detectable_m: float = 0.2
    max_detectable_deg: float = 5.0
    min_boards: int = 3
    max_iterations: int = 50

    def __post_init__(self) -> None:
        for name, lo, hi in (("alpha", 0.0, 0.5), ("power", 0.0, 1.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and lo < v < hi):
                raise InputError(f"check: {name} must be in ({lo:g}, {hi:g}), got {v!r}")
        for name in ("max_detectable_m", "max_detectable_deg", "min_boards"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise InputError(f"check: {name} must be > 0, got {v!r}")


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class SensorCheck:
    """One sensor's verdict.

    ``status``: ``unchanged``, ``moved`` or ``cannot tell``; ``reason``: why it cannot be told
    (else empty). ``partners``: the sensors its re-estimate was held against, ``boards`` how
    many boards it shares with them. ``test``: the chi-square test of the change (None without
    data). ``T_stored`` / ``T_estimate``: the stored and re-estimated ``T_reference_sensor``.
    ``step``: for a moved sensor, the order in which it was found (1 first); ``alternatives``:
    sensors whose own change would explain the data as well (the data cannot tell them apart).
    ``untested``: directions not tested (a 2D radar's z, roll, pitch; directions the boards do
    not determine)."""

    name: str
    kind: str
    status: str
    reason: str
    partners: tuple[str, ...]
    boards: int
    test: MoveTest | None
    T_stored: np.ndarray
    T_estimate: np.ndarray | None
    untested: tuple[str, ...] = ()
    step: int = 0
    alternatives: tuple[str, ...] = ()

    @property
    def change(self) -> dict[str, Any] | None:
        """:func:`rigcal.problem.movement.change_summary` from the stored pose to the re-estimate."""
        return None if self.T_estimate is None else change_summary(self.T_stored, self.T_estimate)

    @property
    def headline(self) -> str:
        """The verdict in one line, e.g. ``moved: 12 mm, 0.40 deg (p < 0.001)``."""
        t = self.test
        if self.status == MOVED and t is not None and self.change is not None:
            c = self.change
            sd_t, sd_r = change_std(t.delta, t.covariance)
            text = (f"moved: {format_mm(c['distance_m'])} +- {format_mm(sd_t)} mm, {c['rotation_deg']:.2f} +- "
                    f"{sd_r:.2f} deg ({format_p(t.p_value)})")
            if self.alternatives:
                text += f" - or {', '.join(self.alternatives)} moved: the data cannot tell which"
            return text
        if self.status == UNCHANGED and t is not None:
            return f"unchanged ({format_p(t.p_value)})"
        return f"cannot tell: {self.reason}"

    @property
    def direction(self) -> str:
        """Which way a change went: the origin's move in the reference frame and the rotation
        axis in the sensor's own axes."""
        c = self.change
        if c is None:
            return ""
        axis = format_vector(c["axis_sensor"], decimals=2)
        return (f"origin {format_vector(c['translation_m'], 1000.0)} mm (reference frame), "
                f"{c['rotation_deg']:.2f} deg about {axis} ({self.name}'s axes)")

    @property
    def detectable(self) -> str:
        """The smallest change this data finds with the test's power, as text."""
        t = self.test
        if t is None or t.dof == 0:
            return "-"
        return (f">= {format_mm(t.detectable_translation_m * 1.0)} mm or {format_deg(t.detectable_rotation_deg)} deg "
                f"({t.power:.0%} of the time)")

    def to_dict(self) -> dict[str, Any]:
        t, c = self.test, self.change
        return {
            "status": self.status,
            "headline": self.headline,
            "reason": self.reason,
            "partners": list(self.partners),
            "boards": int(self.boards),
            "step": int(self.step),
            "alternatives": list(self.alternatives),
            "untested": list(self.untested),
            **move_test_fields(t),
            "power": None if t is None else float(t.power),
            "delta": None if t is None else [float(x) for x in t.delta],
            "covariance": None if t is None else [[float(x) for x in row] for row in t.covariance],
            "translation_m": None if c is None else [float(x) for x in c["translation_m"]],
            "distance_m": None if c is None else float(c["distance_m"]),
            "rotation_deg": None if c is None else float(c["rotation_deg"]),
            "axis_sensor": None if c is None else [float(x) for x in c["axis_sensor"]],
            "T_stored": [[float(x) for x in row] for row in self.T_stored],
            "T_estimate": None if self.T_estimate is None else [[float(x) for x in row] for row in self.T_estimate],
        }


@dataclass(frozen=True)
class PairCheck:
    """One sensor pair's new residuals: ``boards`` shared, ``rms_m`` (RMS residual length at the
    stored poses), the reduced chi-square against the noise model and the stored relative pose's
    uncertainty ``before`` (at the stored poses) and ``after`` (moved sensors at their
    re-estimates), with the p-value of ``before``."""

    label: str
    boards: int
    rows: int
    rms_m: float
    before: float
    after: float
    p_before: float

    def to_dict(self) -> dict[str, Any]:
        return {"boards": self.boards, "rows": self.rows, "rms_m": self.rms_m, "reduced_chi2_before": self.before,
                "reduced_chi2_after": self.after, "p_before": self.p_before}


@dataclass(frozen=True, eq=False)
class CheckResult:
    """What :func:`check` found: per sensor (worst first: moved, cannot tell, unchanged) and per
    pair; ``status`` is the rig's (``moved`` if any sensor moved, else ``cannot tell`` if any
    sensor cannot be told, else ``unchanged``)."""

    reference: str
    sensors: Mapping[str, SensorCheck]
    pairs: Mapping[str, PairCheck]
    num_boards: int
    alpha: float
    power: float
    warnings: tuple[str, ...] = ()
    calibration: str = ""
    data: str = ""
    compute_time_s: float = 0.0

    @property
    def status(self) -> str:
        found = {s.status for s in self.sensors.values()}
        return next((s for s in STATUS_ORDER if s in found), UNCHANGED)

    @property
    def moved(self) -> tuple[str, ...]:
        return tuple(n for n, s in self.sensors.items() if s.status == MOVED)

    @property
    def worst(self) -> SensorCheck:
        return next(iter(self.sensors.values()))

    @property
    def detectable(self) -> tuple[float, float]:
        """(m, deg): the largest smallest-detectable change over the sensors that were told
        (moved or unchanged) - what these boards can promise for every one of them."""
        ts = [s.test for s in self.sensors.values()
              if s.test is not None and s.test.dof > 0 and s.status != CANNOT_TELL]
        if not ts:
            return math.inf, math.inf
        return max(t.detectable_translation_m for t in ts), max(t.detectable_rotation_deg for t in ts)

    def to_dict(self) -> dict[str, Any]:
        dt, dr = self.detectable
        return {
            "status": self.status,
            "reference": self.reference,
            "calibration": self.calibration,
            "data": self.data,
            "num_boards": int(self.num_boards),
            "alpha": float(self.alpha),
            "power": float(self.power),
            "detectable_translation_m": finite_or_none(dt),
            "detectable_rotation_deg": finite_or_none(dr),
            "moved": list(self.moved),
            "sensors": {n: s.to_dict() for n, s in self.sensors.items()},
            "pairs": {k: p.to_dict() for k, p in self.pairs.items()},
            "warnings": list(self.warnings),
            "compute_time_s": float(self.compute_time_s),
        }


# --------------------------------------------------------------------------------------------


def _theta(stored: StoredCalibration, units) -> np.ndarray:
    """The stored noise model as the group variances of ``units`` (angles back to radians)."""
    theta = np.zeros(len(units.groups))
    for g, (sensor, comp) in enumerate(units.groups):
        try:
            std = float(stored.noise_model[sensor][comp])
        except (KeyError, TypeError, ValueError):
            raise InputError(
                f"{stored.source}: noise_model.{sensor}.{comp}: missing - the calibration has no noise model "
                "for this sensor (written by an older rigcal, or a motion-capture calibration?): run "
                "rigcal calibrate again") from None
        if not (math.isfinite(std) and std > 0):
            raise InputError(f"{stored.source}: noise_model.{sensor}.{comp}: expected a positive std, got {std!r}")
        if COMPONENT_UNITS[comp] == "deg":
            std = math.radians(std)
        theta[g] = std * std
    return theta


def check_sensors(stored: StoredCalibration, dataset: Dataset) -> None:
    """InputError when the data's sensors do not belong to the calibration: a sensor the
    calibration lacks, or one of another kind (both named)."""
    where = dataset.source or "data"
    extra = [s.name for s in dataset.sensors if s.name not in stored.sensors]
    if extra:
        raise InputError(
            f"{where}: sensor(s) {', '.join(extra)} are not in the calibration {stored.source} "
            f"(its sensors: {', '.join(stored.names)}); the data and the calibration must name the same sensors")
    for s in dataset.sensors:
        kind = stored.sensors[s.name].kind
        if s.kind != kind:
            raise InputError(f"{where}: sensor '{s.name}' is a {s.kind.value} in the data but a {kind.value} "
                             f"in the calibration {stored.source}")


def _theta_refit(ctx_J: np.ndarray, r: np.ndarray, cols: Mapping[str, np.ndarray], dataset: Dataset,
                 anchor: str, M: np.ndarray, batches: np.ndarray) -> np.ndarray:
    """The noise model estimated from the new detections alone: every pose but ``anchor``'s
    fitted to them (one Gauss-Newton step of FCPE from the stored poses, metric rows; a 2D
    radar's z, roll and pitch held), so that no sensor's move is in the residuals. The stored
    model's split of a pair's noise between its two sensors is told apart only through loops of
    pairs and can be far off for one sensor (a component at its floor); the larger of the two
    estimates per component keeps the check from trusting such a split (zeros when there are no
    more rows than parameters)."""
    free = []
    for name, c in cols.items():
        if name == anchor:
            continue
        mask = np.asarray(RADAR_PLANE_FREE if dataset.sensor(name).kind == SensorKind.RADAR else ALL_FREE)
        free.extend(c[mask])
    J = ctx_J[:, free]
    m, n = J.shape
    if m <= n:
        return np.zeros(M.shape[1])
    step = np.linalg.lstsq(J, r, rcond=None)[0]
    return estimate_theta(r - J @ step, M, m / (m - n), batches=batches)


@dataclass(frozen=True, eq=False)
class _Context:
    """Everything the per-sensor tests share: the pairwise problem at the stored poses (rows
    weighted by the noise model), its noise map and where each batch's rows are."""

    dataset: Dataset
    stored: StoredCalibration
    options: CheckOptions
    poses: dict[str, np.ndarray]
    problem: Problem
    pairs: tuple[tuple[str, str], ...]  # the two sensors of each batch
    rows: tuple[np.ndarray, ...]  # row indices of each batch
    D: np.ndarray  # metric noise map (rows, units)
    sigma: np.ndarray  # (rows,) noise model std per row
    units: Any
    theta: np.ndarray
    r: np.ndarray  # (rows,) metric residuals at the stored poses
    J: np.ndarray  # (rows, 6 * sensors) metric Jacobian at the stored poses, every pose free
    cols: dict[str, np.ndarray]  # each sensor's six columns of J
    relative: dict = field(default_factory=dict)  # relative covariances computed so far


def _context(stored: StoredCalibration, dataset: Dataset, options: CheckOptions) -> _Context:
    poses = {s.name: stored.sensors[s.name].T_reference_sensor for s in dataset.sensors}
    problem = build_pairwise(dataset, poses, stored.reference, all_pairs(dataset))
    obs = tuple(b for b in problem.observations if b.size > 0)
    if not obs:
        raise InputError(
            f"{dataset.source or 'data'}: no board is seen by two sensors (each board is detected by one "
            "sensor at most): nothing to compare the calibration with; place boards where several sensors "
            "see them")
    problem = Problem(tuple(replace(p, free=ALL_FREE) for p in problem.poses), obs)
    r, J, _, _, layout = linearise(problem)  # unit sigma: metric
    cols = {n: layout.cols[layout.index[n]] for n in layout.names}
    units = detection_units(dataset)
    D = noise_map(problem, dataset, units)
    D = D if isinstance(D, np.ndarray) else D.toarray()
    M = group_design(D, units)
    anchor = stored.reference if stored.reference in cols else dataset.names[0]
    theta = np.maximum(_theta(stored, units), _theta_refit(J, r, cols, dataset, anchor, M, row_batches(problem)))
    sigma = np.sqrt(np.maximum(M @ theta, 1e-30))
    rows, pairs, start = [], [], 0
    weighted = []
    for b in obs:
        n = b.size * b.dim
        rows.append(np.arange(start, start + n))
        pairs.append((b.frame[0], b.observer[0]))
        weighted.append(b.with_sigma(sigma[start:start + n].reshape(b.size, b.dim)))
        start += n
    return _Context(dataset, stored, options, poses, Problem(problem.poses, tuple(weighted)), tuple(pairs),
                    tuple(rows), D, sigma, units, theta, r, J, cols)


@dataclass(frozen=True, eq=False)
class _Test:
    test: MoveTest
    T_estimate: np.ndarray
    partners: tuple[str, ...]
    boards: int
    converged: bool
    expected: int  # directions that should be tested (6, or 3 for a 2D radar)
    exact: bool  # re-estimated by the solver (else one Gauss-Newton step from the stored pose)


def _relative_covariance(ctx: _Context, to: str, frm: str) -> np.ndarray:
    """:meth:`StoredCalibration.relative_covariance`, computed once per check."""
    key = (to, frm)
    if key not in ctx.relative:
        ctx.relative[key] = ctx.stored.relative_covariance(to, frm)
    return ctx.relative[key]


def _sensor_test(ctx: _Context, s: str, partners: Sequence[str], alpha: float, exact: bool = False) -> _Test | None:
    """Sensor ``s`` re-estimated with ``partners`` held at their stored poses, and the test of
    its change (None when it shares no board with any of them). ``exact``: solved to convergence
    (:func:`rigcal.problem.solver.solve`); else one Gauss-Newton step from the stored pose (what
    the search for moved sensors screens with: exact where nothing moved)."""
    sel = [i for i, (a, b) in enumerate(ctx.pairs) if s in (a, b) and (b if a == s else a) in partners]
    if not sel:
        return None
    kind = ctx.dataset.sensor(s).kind
    free = RADAR_PLANE_FREE if kind == SensorKind.RADAR else ALL_FREE
    fi = np.flatnonzero(free)
    k = fi.size
    other = [b if a == s else a for a, b in (ctx.pairs[i] for i in sel)]
    used = tuple(dict.fromkeys(other))
    C_rel = {o: _relative_covariance(ctx, o, s) for o in used}
    rows = [ctx.rows[i] for i in sel]
    rows_all = np.concatenate(rows)
    J6 = ctx.J[np.ix_(rows_all, ctx.cols[s])]
    # rows weighted by the noise model plus what the partner's stored pose uncertainty adds to
    # them (a poorly known partner weighs less); any weights give a valid test, these more power
    offsets = np.cumsum([0] + [x.size for x in rows])
    pose_var = np.concatenate([
        np.einsum("ij,jk,ik->i", J6[offsets[j]:offsets[j + 1]], C_rel[o], J6[offsets[j]:offsets[j + 1]])
        for j, o in enumerate(other)])
    sig = np.sqrt(ctx.sigma[rows_all] ** 2 + pose_var)
    converged = True
    if exact:
        batches = tuple(ctx.problem.observations[i].with_sigma(
            sig[offsets[j]:offsets[j + 1]].reshape(ctx.problem.observations[i].size, -1)) for j, i in enumerate(sel))
        problem = Problem(tuple(PoseBlock(n, ctx.poses[n], free if n == s else (False,) * 6) for n in (s, *used)),
                          batches)
        sol = solve(problem, max_iterations=ctx.options.max_iterations)
        T_new, converged, cost = sol.poses[s], bool(sol.converged), sol.cost
        # Jacobian of every row in all six directions of s (the held ones too: a 2D radar's
        # stored z, roll and pitch errors move its in-plane re-estimate)
        six = Problem(tuple(replace(p, free=ALL_FREE if p.name == s else (False,) * 6) for p in problem.poses),
                      problem.observations)
        _, Jw6, _, _, _ = linearise(six.with_poses({s: T_new}))
    else:
        Jw6 = J6 / sig[:, None]
        rw = ctx.r[rows_all] / sig
        step = -np.linalg.lstsq(Jw6[:, fi], rw, rcond=None)[0]
        xi = np.zeros(6)
        xi[fi] = step
        T_new = ctx.poses[s] @ se3_exp(xi)
        after = rw + Jw6[:, fi] @ step
        cost = 0.5 * float(after @ after)
    J = Jw6[:, fi]
    Dw = ctx.D[rows_all] / sig[:, None]
    Ainv, C_new = sandwich(J, Dw, ctx.units, ctx.theta)
    # the stored calibration's uncertainty as it enters the re-estimate (module docstring)
    W = {}
    for o in used:
        part = np.concatenate([np.arange(offsets[j], offsets[j + 1]) for j, x in enumerate(other) if x == o])
        W[o] = Ainv @ (J[part].T @ Jw6[part])
    C_stored = _stored_term(ctx.stored, s, W, C_rel)
    C6 = np.zeros((6, 6))
    C6[np.ix_(fi, fi)] = C_new + C_stored
    H6 = np.zeros((6, 6))
    H6[np.ix_(fi, fi)] = J.T @ J
    delta = se3_log(invert(ctx.poses[s]) @ T_new)
    delta[np.flatnonzero(~np.asarray(free))] = 0.0
    # the residuals' scatter over the noise model's: the stored model can be off for one
    # sensor (its noise is told apart from its partners' only through loops of pairs)
    redundancy = J.shape[0] - k
    factor = 2.0 * cost / redundancy if redundancy > 0 else 1.0
    test = move_test(delta, C6, determined_basis(H6, fi), alpha, ctx.options.power, factor, redundancy)
    boards = len(np.unique(np.concatenate([ctx.problem.observations[i].board for i in sel])))
    return _Test(test, T_new, used, boards, converged, k, exact)


def _stored_term(stored: StoredCalibration, s: str, W: Mapping[str, np.ndarray],
                 C_rel: Mapping[str, np.ndarray]) -> np.ndarray:
    """Covariance of ``sum_o W_o r_o``: how the stored relative poses' errors ``r_o`` (of
    ``T_o_s``, covariance ``C_rel[o]``) move the re-estimate of ``s``, ``W_o`` (k, 6) the share
    of partner ``o``.

    With the file's joint covariance (``joint_covariance``, written since 2026-11-27) the sum's
    covariance is exact. Else, when the file's relative covariances are the joint covariance's,
    their cross-correlations are unknown: ``Cov(sum W_o r_o) <= sum W_o C_o W_o' / t_o`` for weights ``t`` summing to 1
    (Cauchy-Schwarz; ``t_o`` proportional to the root of the trace of ``W_o C_o W_o'``, the
    tightest such bound in the scalar case). Otherwise the relative covariances are the
    sensors' own combined as independent (:meth:`StoredCalibration.relative_covariance`),
    ``r_o = e_s - Ad(T_s_o) e_o``, and the same model gives the sum exactly: ``s``'s own stored
    error enters every pair alike, the partners' errors average."""
    k = next(iter(W.values())).shape[0]
    if stored.joint is not None:
        # exact: sum_o W_o r_o = (sum_o W_o) e_s - sum_o W_o Ad(T_s_o) e_o, e the sensors' stored
        # errors with the file's joint covariance (cross terms included)
        names = [s, *W]
        M = [sum(W.values())] + [-w @ adjoint(stored.T(s, o)) for o, w in W.items()]
        out = np.zeros((k, k))
        for a, Ma in zip(names, M):
            for b, Mb in zip(names, M):
                out = out + Ma @ stored.joint_block(a, b) @ Mb.T
        return 0.5 * (out + out.T)
    if stored.relative_is_joint:
        V = {o: w @ C_rel[o] @ w.T for o, w in W.items()}
        roots = {o: math.sqrt(max(float(np.trace(v)), 0.0)) for o, v in V.items()}
        total = sum(roots.values())
        return sum((v * (total / roots[o]) for o, v in V.items() if roots[o] > 0), np.zeros((k, k)))
    W_sum = sum(W.values())
    out = W_sum @ stored.sensors[s].covariance @ W_sum.T
    for o, w in W.items():
        A = w @ adjoint(stored.T(s, o))
        out = out + A @ stored.sensors[o].covariance @ A.T
    return 0.5 * (out + out.T)


def _pair_checks(ctx: _Context, after: Mapping[str, np.ndarray]) -> dict[str, PairCheck]:
    """Every pair's reduced chi-square at the stored poses and with ``after``'s poses."""
    out = {}
    r_after = ctx.r
    if after:
        r_after = linearise(ctx.problem.with_poses(after))[0] * ctx.sigma
    var = ctx.sigma ** 2
    for (frame, observer), rows, b in zip(ctx.pairs, ctx.rows, ctx.problem.observations):
        Jm = ctx.J[np.ix_(rows, ctx.cols[observer])]
        C = _relative_covariance(ctx, frame, observer)
        total = var[rows] + np.einsum("ij,jk,ik->i", Jm, C, Jm)
        z2 = ctx.r[rows] ** 2 / np.maximum(total, 1e-30)
        z2_after = r_after[rows] ** 2 / np.maximum(total, 1e-30)
        lengths = np.sqrt(np.sum(ctx.r[rows].reshape(b.size, b.dim) ** 2, axis=1))
        out[b.label] = PairCheck(
            b.label, int(np.unique(b.board).size), int(rows.size), float(np.sqrt(np.mean(lengths ** 2))),
            float(np.mean(z2)), float(np.mean(z2_after)), float(chi2_sf(float(np.sum(z2)), rows.size)))
    return out


def check(
    calibration: StoredCalibration | CalibrationResult,
    dataset: Dataset,
    options: CheckOptions = CheckOptions(),
) -> CheckResult:
    """Judge new board detections ``dataset`` under a stored calibration (a
    :class:`~rigcal.problem.stored.StoredCalibration`, or a
    :class:`~rigcal.problem.result.CalibrationResult`); see the module docstring.

    Raises InputError when the data's sensors are not the calibration's (names, kinds), when no
    board is seen by two sensors, or when the calibration has no noise model."""
    t0 = time.perf_counter()
    stored = calibration if isinstance(calibration, StoredCalibration) else StoredCalibration.from_result(calibration)
    check_sensors(stored, dataset)
    try:
        with single_threaded():
            ctx = _context(stored, dataset, options)
            verdicts = _verdicts(ctx)
            after = {n: v.T_estimate for n, v in verdicts.items() if v.status == MOVED and v.T_estimate is not None}
            pairs = _pair_checks(ctx, after)
    except np.linalg.LinAlgError as exc:  # values within every input limit that still defeat the algebra
        raise InputError(f"{stored.source} against {dataset.source or 'the data'}: the check's linear algebra "
                         f"failed ({exc}); expected a calibration and detections of ordinary size") from None
    warnings = []
    moved = {n for n, v in verdicts.items() if v.status == MOVED}
    clean = [p for (a, b), p in zip(ctx.pairs, pairs.values()) if a not in moved and b not in moved]
    for p in clean:
        if p.p_before < options.alpha / max(len(pairs), 1) and p.before > 3.0:
            warnings.append(
                f"pair {p.label}: residuals {math.sqrt(p.before):.1f} x what the calibration's noise model "
                "predicts although neither sensor was found moved - noisier detections than at calibration time, "
                "or a bad board: the verdicts assume the stored noise model")
    for name in stored.names:  # the calibration's sensors the data lacks
        if name not in verdicts:
            verdicts[name] = SensorCheck(name, stored.sensors[name].kind.value, CANNOT_TELL, "not in the data", (),
                                         0, None, stored.sensors[name].T_reference_sensor, None,
                                         untestable_directions(stored.sensors[name].kind))
    ordered = dict(sorted(verdicts.items(), key=lambda kv: _rank(kv[1])))
    used = int(np.unique(np.concatenate([b.board for b in ctx.problem.observations])).size)
    return CheckResult(stored.reference, ordered, pairs, used, options.alpha, options.power,
                       tuple(warnings), stored.source, dataset.source, time.perf_counter() - t0)


def _rank(v: SensorCheck) -> tuple:
    z = v.test.z if v.test is not None else -math.inf
    return (STATUS_ORDER.index(v.status), v.step if v.status == MOVED else 0, -z)


def _verdicts(ctx: _Context) -> dict[str, SensorCheck]:
    """The sequential search for moved sensors (module docstring) and every sensor's verdict."""
    names = list(ctx.dataset.names)
    testable = [s for s in names if any(s in p for p in ctx.pairs)]
    alpha = ctx.options.alpha / max(len(testable), 1)
    active = list(names)
    out: dict[str, SensorCheck] = {}
    step = 0
    tests: dict[str, _Test | None] = {}
    while True:
        tests = {s: _sensor_test(ctx, s, [o for o in active if o != s], alpha) for s in active}
        # what the one-step screening finds significant, solved to convergence
        for s in [s for s, t in tests.items() if t is not None and t.test.significant]:
            tests[s] = _sensor_test(ctx, s, [o for o in active if o != s], alpha, exact=True)
        significant = [s for s, t in tests.items() if t is not None and t.test.significant]
        if not significant:
            break
        step += 1
        worst = max(significant, key=lambda s: tests[s].test.z)
        # another significant sensor whose removal explains the worst one's change as well
        alternatives = []
        for other in significant:
            if other == worst:
                continue
            alt = _sensor_test(ctx, worst, [o for o in active if o not in (worst, other)], alpha)
            if alt is None or not alt.test.significant:
                alternatives.append(other)
        t = tests[worst]
        out[worst] = _verdict(ctx, worst, t, MOVED, "", step, tuple(alternatives))
        for other in alternatives:
            out[other] = _verdict(ctx, other, tests[other], CANNOT_TELL,
                                  f"the data cannot tell whether it or {worst} moved", step, (worst,))
        active = [s for s in active if s != worst and s not in alternatives]
    # the moved sensors' change against the sensors that did not move (when they share boards and
    # that comparison finds the move too; else the comparison that found it stays)
    for name, v in list(out.items()):
        if v.status != MOVED:
            continue
        final = _sensor_test(ctx, name, active, alpha, exact=True)
        if final is not None and final.test.dof == v.test.dof and final.test.significant:
            out[name] = _verdict(ctx, name, final, MOVED, "", v.step, v.alternatives)
    for s in active:
        t = tests.get(s)
        out[s] = _verdict(ctx, s, t, None, "", 0, ())
    return out


def _verdict(ctx: _Context, s: str, t: _Test | None, status: str | None, reason: str, step: int,
             alternatives: tuple[str, ...]) -> SensorCheck:
    kind = ctx.dataset.sensor(s).kind
    stored = ctx.stored.sensors[s]
    fixed = untestable_directions(kind)
    if t is None:
        partners = [o for p in ctx.pairs if s in p for o in p if o != s]
        why = ("its boards are shared only with sensors that moved" if partners
               else "it shares no board with another sensor in the data")
        return SensorCheck(s, kind.value, CANNOT_TELL, reason or why, (), 0, None, stored.T_reference_sensor, None,
                           fixed, step, alternatives)
    untested = tuple(d for d in ("roll", "pitch", "yaw", "x", "y", "z") if d not in t.test.tested)
    if status is None:
        opts = ctx.options
        if not t.converged:
            status, reason = CANNOT_TELL, "its re-estimate did not converge"
        elif t.test.dof < t.expected:
            missing = [d for d in untested if d not in fixed]
            status, reason = CANNOT_TELL, (f"the boards it shares with {', '.join(t.partners)} do not determine "
                                           f"its {', '.join(missing)}")
        elif t.boards < opts.min_boards:
            status, reason = CANNOT_TELL, (f"too few boards: it shares {t.boards} with the other sensors "
                                           f"(a check needs at least {opts.min_boards})")
        elif (t.test.detectable_translation_m > opts.max_detectable_m
              or t.test.detectable_rotation_deg > opts.max_detectable_deg):
            status, reason = CANNOT_TELL, (f"the {t.boards} boards it shares with {', '.join(t.partners)} "
                                           "determine its pose too weakly: only changes >= "
                                           f"{format_mm(t.test.detectable_translation_m)} mm or "
                                           f"{format_deg(t.test.detectable_rotation_deg)} deg would be found")
        else:
            status = UNCHANGED
    return SensorCheck(s, kind.value, status, reason, t.partners, t.boards, t.test, stored.T_reference_sensor,
                       t.T_estimate, untested, step, alternatives)


__all__ = [
    "CANNOT_TELL",
    "MOVED",
    "UNCHANGED",
    "CheckOptions",
    "CheckResult",
    "PairCheck",
    "SensorCheck",
    "check",
    "check_sensors",
]
