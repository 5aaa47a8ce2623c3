"""Does a calibration agree with its own noise model? The verdict every result carries.

Checks (each ``pass``, ``note``, ``fail`` or ``undetermined``; any ``fail`` flags the result,
otherwise any ``undetermined`` makes it undetermined):

* ``inputs``: cheap checks of the detections before the solve - a mirrored hole order, a
  sensor in the wrong units, a camera's file that is not a camera's view
  (:mod:`rigcal.problem.mistakes`). A mistake found here is a **fail** named as such.
* ``pairs``: every comparable sensor pair - also pairs the configuration did not fit (MCPE
  fits only pairs with the reference) - is compared with what the noise model and the
  reported pose uncertainty predict for its residuals. The noise model is estimated from every
  pair's residuals at the result's poses (not from the pairs the mode fitted: MCPE's pairs
  with the reference alone leave a sensor's share of the noise to the arithmetic, which put
  it at the floor), each row at the largest variance the data support
  (:class:`rigcal.problem.noise.NoiseRegion`: a sensor whose share of a pair's noise the data
  do not tell may carry all of it). Reduced chi-square above the 1e-4 quantile (Bonferroni
  over the pairs) and above 3 is a **fail**.
* ``boards``: every (pair, board) the same way, against the noise estimated *without* that
  board (a bad board inflates the estimate it would be judged by; each row at the largest
  variance the other boards support), with the quantile corrected
  for the number of boards tested; a board far off its pair's prediction (and more than 3
  sigma RMS) *and* beyond the outlier rule's physical floor (10 cm, radar pairs 20 cm: a bad
  detection kept) is a **fail**; one only beyond the noise model is a **note**.
* ``noise``: every sensor's noise against what that kind of sensor can plausibly have
  (:data:`PLAUSIBLE_NOISE`); a **fail** only when even the *smallest* noise the data support
  is above it (a board in the wrong units, a wrong pose the noise estimate absorbed).
* named mistakes after the solve (:mod:`rigcal.problem.mistakes`): ``scale`` (a sensor's
  detections too large or small), ``reflector`` (the configured reflector offset, globally or
  on some boards), ``spacing`` (the configured hole spacing), ``placements`` (a board's
  detection from another placement), ``swapped`` (two sensors' files, against ``initial``).
* ``determined``: every sensor's pose determined to the bound of its kind
  (:data:`DETERMINED_BOUND`): **undetermined** otherwise (also a rank-deficient problem),
  naming the directions and the placements that would fix them.
* ``bounded``: directions set by an inequality constraint (a 2D radar's z, roll, pitch) are
  reported as intervals: **note** - never undetermined.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset
from rigcal.problem.numerics import chi2_isf
from rigcal.problem.noise import (
    COMPONENT_UNITS,
    DetectionUnits,
    NoiseRegion,
    estimate_theta,
    estimate_theta_best,
    group_design,
    noise_map,
    noise_region,
    row_batches,
)
from rigcal.problem.outliers import OutlierRule
from rigcal.problem.pairs import all_pairs
from rigcal.problem.residuals import MODEL_RADAR2D
from rigcal.problem.solver import linearise

PASS, NOTE, FAIL, UNDETERMINED = "pass", "note", "fail", "undetermined"
#: tail probability of the chi-square tests (Bonferroni-corrected over the items tested)
ALPHA = 1e-4
#: a reduced chi-square at or below this never fails (model slack for real detections)
MIN_FAIL_RATIO = 3.0
#: a board fails only when its residuals are also more than 3 sigma RMS off (a bad detection
#: kept is typically 5-10 sigma; far boards of a stereo camera reach 2-2.5 sigma when clean)
MIN_FAIL_BOARD_RATIO = 9.0


#: largest plausible noise std per sensor kind and component (m; camera depth: m at 1 m range;
#: radar angles: deg) - a calibration board's detections noisier than this are not noise
PLAUSIBLE_NOISE = {
    "lidar": {"x": 0.05, "y": 0.05, "z": 0.05},
    "camera": {"lateral": 0.05, "depth": 0.02},
    "radar": {"range": 0.2, "azimuth": 3.0},
    "radar3d": {"range": 0.2, "azimuth": 3.0, "elevation": 5.0},
}


@dataclass(frozen=True)
class Evidence:
    """One number a check judged: ``item`` (a pair, a sensor, a board), its ``statistic``, the
    ``threshold`` it was held to and ``what`` they are (e.g. ``reduced chi-square``)."""

    item: str
    statistic: float
    threshold: float
    what: str

    def to_dict(self) -> dict:
        return {"item": self.item, "statistic": float(self.statistic), "threshold": float(self.threshold),
                "what": self.what}


@dataclass(frozen=True)
class Check:
    """One consistency check: its ``name``, ``status`` (pass / note / fail / undetermined),
    what it found (``detail``) and the numbers it judged (``evidence``)."""

    name: str
    status: str
    detail: str
    evidence: tuple[Evidence, ...] = ()

    def to_dict(self) -> dict:
        out = {"name": self.name, "status": self.status, "detail": self.detail}
        if self.evidence:
            out["evidence"] = [e.to_dict() for e in self.evidence]
        return out


@dataclass(frozen=True)
class Verdict:
    """``status``: ``flagged`` (a check failed), ``undetermined`` (no check failed, but some
    sensor's pose is not determined to its bound) or ``consistent``; ``checks`` in order;
    ``noise``: the noise model the checks used, ``{sensor: {component: {"estimate", "low",
    "high", "identified"}}}`` (std: m; camera depth: m at 1 m; angles: deg)."""

    checks: tuple[Check, ...] = ()
    noise: Mapping[str, Mapping[str, Mapping[str, object]]] = field(default_factory=dict)

    @property
    def status(self) -> str:
        if self.failed:
            return "flagged"
        return "undetermined" if self.undetermined else "consistent"

    @property
    def failed(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if c.status == FAIL)

    @property
    def undetermined(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if c.status == UNDETERMINED)

    def to_dict(self) -> dict:
        out: dict = {"status": self.status, "checks": [c.to_dict() for c in self.checks]}
        if self.noise:
            out["noise"] = {s: {c: dict(v) for c, v in comps.items()} for s, comps in self.noise.items()}
        return out


@functools.lru_cache(maxsize=4096)
def _limit(dof: int, tests: int) -> float:
    """Reduced chi-square above which ``dof`` rows fail, ``tests`` such tests made."""
    q = chi2_isf(ALPHA / max(tests, 1), max(dof, 1)) / max(dof, 1)
    return max(float(q), MIN_FAIL_RATIO)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PairResiduals:
    """Every comparable pair's residuals at a result's poses, linearised, with the noise model
    estimated from them: what every check after the solve judges.

    ``r`` (rows,) metric residuals in the solver's row order, ``J`` (rows, n) their Jacobian
    w.r.t. the free pose parameters, ``D`` the noise map, ``M`` the group design,
    ``pose_var`` (rows,) what the reported pose covariance adds to each row's variance,
    ``theta`` the group variances estimated from these residuals and ``region`` what the data
    support (:class:`~rigcal.problem.noise.NoiseRegion`)."""

    dataset: Dataset
    poses: Mapping[str, np.ndarray]
    reference: str
    units: DetectionUnits
    problem: object
    layout: object
    r: np.ndarray
    J: np.ndarray
    D: object
    M: np.ndarray
    batches: np.ndarray
    row_board: np.ndarray
    pose_var: np.ndarray
    theta: np.ndarray
    region: NoiseRegion

    @property
    def predicted(self) -> np.ndarray:
        """(rows,) each row's variance under the estimated noise, pose uncertainty included."""
        return self.M @ self.theta + self.pose_var


def pair_residuals(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    reference: str,
    units: DetectionUnits,
    joint_covariance,
    theta: np.ndarray | None = None,
) -> PairResiduals | None:
    """:class:`PairResiduals` of ``dataset`` at ``poses`` (None: no comparable pair).
    ``joint_covariance(names)``: the result's joint covariance of those sensors' right
    perturbations; ``theta``: use these group variances instead of estimating them."""
    from rigcal.problem.configurations import build_pairwise

    problem = build_pairwise(dataset, poses, reference, all_pairs(dataset))
    if not problem.observations:
        return None
    r, J, _, _, layout = linearise(problem)  # unit sigma: r is metric
    D = noise_map(problem, dataset, units)
    M = group_design(D, units)
    pose_var = np.zeros(r.size)
    names = [n for n in layout.names if np.any(layout.cols[layout.index[n]] >= 0)]
    if names:
        C6 = joint_covariance(names)
        cols = np.concatenate([layout.cols[layout.index[n]] for n in names])
        keep = cols >= 0
        C = np.zeros((layout.n_free, layout.n_free))
        C[np.ix_(cols[keep], cols[keep])] = C6[np.ix_(keep, keep)]
        pose_var = np.maximum(np.einsum("ij,jk,ik->i", J, C, J), 0.0)
    batches = row_batches(problem)
    m, n = J.shape
    if theta is None:
        # the poses absorbed up to n of the m residual degrees of freedom; the reweighting
        # round whose estimate the residuals' likelihood prefers (the rounds can wander along a
        # weak split: 3 lidars with random yaw, two lidars' y noise at the floor after three)
        theta = estimate_theta_best(r, M, m / max(m - n, 1), batches=batches)
    row_board = np.concatenate([np.repeat(b.board, b.dim) for b in problem.observations])
    return PairResiduals(dataset, poses, reference, units, problem, layout, r, J, D, M, batches, row_board,
                         pose_var, np.asarray(theta, dtype=float), noise_region(M, theta))


def pair_checks(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    reference: str,
    units: DetectionUnits,
    theta: np.ndarray | None,
    joint_covariance,
    rule: OutlierRule = OutlierRule(),
    residuals: PairResiduals | None = None,
) -> tuple[Check, Check, dict[str, float]]:
    """The ``pairs`` and ``boards`` checks, and the reduced chi-square per pair.

    ``theta``: the noise model's group variances over ``units`` (None: estimated from every
    pair's residuals at ``poses``); ``joint_covariance(names)``: the result's joint covariance
    of those sensors' right perturbations; ``residuals``: already linearised."""
    res = residuals if residuals is not None else pair_residuals(dataset, poses, reference, units,
                                                                 joint_covariance, theta)
    if res is None:
        return Check("pairs", PASS, "no comparable pairs"), Check("boards", PASS, "-"), {}
    problem, r, M, pose_var = res.problem, res.r, res.M, res.pose_var
    m, n = res.J.shape
    z2 = r**2 / np.maximum(res.predicted, 1e-30)
    # each board against the noise estimated without it (a bad board inflates the noise
    # estimate it would otherwise be judged by)
    # each row at the largest variance the data support (a sensor's weak share of a pair's
    # noise may be all of it)
    row_upper = res.region.upper_rows(M)
    z2_deleted = np.empty_like(z2)
    for k in np.unique(res.row_board):
        out = res.row_board == k
        theta_k = estimate_theta(r[~out], M[~out], m / max(m - n, 1), batches=res.batches[~out])
        var_k = noise_region(M[~out], theta_k).upper_rows(M[out]) + pose_var[out]
        z2_deleted[out] = r[out] ** 2 / np.maximum(var_k, 1e-30)
    ratios: dict[str, float] = {}
    evidence: list[Evidence] = []
    bad_pairs, bad_boards, odd_boards = [], [], []
    n_boards = sum(len(np.unique(b.board)) for b in problem.observations)
    row0 = 0
    for b in problem.observations:
        rows = slice(row0, row0 + b.size * b.dim)
        row0 += b.size * b.dim
        # the pair against the largest noise the data support: the noise is estimated from
        # every pair's residuals (a pair the mode did not fit included), so the pair's own sum
        # of squares is fitted directly - how it splits between the sensors does not matter
        z2_pair = r[rows] ** 2 / np.maximum(row_upper[rows] + pose_var[rows], 1e-30)
        ratio = float(np.mean(z2_pair))
        limit = _limit(int(z2_pair.size), len(problem.observations))
        ratios[b.label] = ratio
        evidence.append(Evidence(b.label, ratio, limit, "reduced chi-square"))
        if ratio > limit:
            bad_pairs.append(f"{b.label} (reduced chi-square {ratio:.1f}, limit {limit:.1f})")
        zdel = z2_deleted[rows].reshape(b.size, b.dim)
        rb = r[rows].reshape(b.size, b.dim)
        floor = rule.floor_radar_m if b.model == MODEL_RADAR2D or b.dim == 2 else rule.floor_3d_m
        for k in np.unique(b.board):
            zk = zdel[b.board == k]
            rk = float(np.mean(zk))
            if rk > _limit(zk.size, max(n_boards, 1)):
                # beyond the noise model; a failure only beyond the outlier rule's physical
                # floor too (real detections are heavier-tailed than a Gaussian)
                err = float(np.sqrt(np.mean(np.sum(rb[b.board == k] ** 2, axis=1))))
                text = f"board {int(k)} in {b.label} ({np.sqrt(rk):.1f} sigma, {err * 1000:.0f} mm)"
                gross = err > floor and rk > MIN_FAIL_BOARD_RATIO
                (bad_boards if gross else odd_boards).append(text)
    pair_check = (
        Check("pairs", FAIL, "residuals far above the noise model: " + "; ".join(bad_pairs)
              + " - the poses contradict the sensors' noise (a wrong pose, or a reference that "
              "cannot determine it)", tuple(evidence))
        if bad_pairs
        else Check("pairs", PASS, "every pair within its noise model: reduced chi-square "
                   + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()), tuple(evidence))
    )
    board_check = (
        Check("boards", FAIL, "boards far off their pair's prediction: " + "; ".join(bad_boards[:8])
              + (f" (+{len(bad_boards) - 8} more)" if len(bad_boards) > 8 else "")
              + " - bad detections were kept (--keep-outliers?) or the noise model does not fit")
        if bad_boards
        else Check("boards", NOTE, "boards beyond the noise model but within the outlier rule's "
                   "physical floors (kept): " + "; ".join(odd_boards[:8])
                   + (f" (+{len(odd_boards) - 8} more)" if len(odd_boards) > 8 else ""))
        if odd_boards
        else Check("boards", PASS, "no board far off its pair's prediction")
    )
    return pair_check, board_check, ratios


def _show(comp: str, std: float) -> str:
    return f"{std:.2f} deg" if COMPONENT_UNITS[comp] == "deg" else f"{std * 1000:.0f} mm"


def noise_summary(units: DetectionUnits, region: NoiseRegion) -> dict[str, dict[str, dict[str, object]]]:
    """The noise model per sensor and component: estimate, the lowest and highest std the data
    support, and whether the data identify it (its std known within a factor of 2, or below
    1 mm / 0.01 deg)."""
    low, high = region.group_bounds()
    out: dict[str, dict[str, dict[str, object]]] = {}
    for (sensor, comp), th, lo, hi in zip(units.groups, region.theta, low, high):
        deg = COMPONENT_UNITS[comp] == "deg"
        conv = (lambda v: float(np.degrees(np.sqrt(max(v, 0.0))))) if deg else (lambda v: float(np.sqrt(max(v, 0.0))))
        est, lo_s, hi_s = conv(th), conv(lo), conv(hi)
        small = 0.01 if deg else 0.001
        identified = bool(hi_s <= max(2.0 * est, small))
        out.setdefault(sensor, {})[comp] = {"estimate": est, "low": lo_s, "high": hi_s, "identified": identified}
    return out


def noise_check(
    dataset: Dataset,
    noise_model: Mapping[str, Mapping[str, object]],
) -> Check:
    """The ``noise`` check: the smallest noise the data support per sensor and component
    (``noise_model``: :func:`noise_summary`, or plain ``{sensor: {component: std}}``) against
    :data:`PLAUSIBLE_NOISE`."""
    bad, evidence = [], []
    for name, comps in noise_model.items():
        limits = PLAUSIBLE_NOISE[dataset.sensor(name).kind.value]
        for comp, value in comps.items():
            if comp not in limits:
                continue
            low = float(value["low"]) if isinstance(value, Mapping) else float(value)
            evidence.append(Evidence(f"{name} {comp}", low, limits[comp],
                                     "smallest supported std (" + ("deg" if COMPONENT_UNITS[comp] == "deg" else "m")
                                     + (" at 1 m" if comp == "depth" else "") + ")"))
            if low > limits[comp]:
                bad.append(f"{name} {comp} at least {_show(comp, low)} (plausible: up to {_show(comp, limits[comp])})")
    if bad:
        return Check("noise", FAIL, "noise implausible for the sensor: " + "; ".join(bad)
                     + " - bad detections absorbed by the noise estimate, wrong units, or a wrong pose",
                     tuple(evidence))
    return Check("noise", PASS, "every sensor's noise is plausible for its kind", tuple(evidence))


def verdict(
    pair_check: Check,
    board_check: Check,
    rank_deficient: bool,
    bounded: Mapping[str, Mapping[str, tuple[float, float, float]]],
    weak: Mapping[str, list[str]],
    noise: Check | None = None,
    *,
    inputs: Check | None = None,
    named: tuple[Check, ...] = (),
    determined: Check | None = None,
    noise_model: Mapping | None = None,
) -> Verdict:
    """The verdict from its checks, in order: inputs, pairs, boards, noise, the named mistakes,
    rank (undetermined when deficient), determined, bounded (a note), weak (a note; directions
    the ``determined`` check did not already judge). ``bounded``: per sensor, its bounded
    directions as absolute ``(low, high, estimate)`` (:func:`rigcal.problem.uncertainty.absolute_bounds`)."""
    checks = ([inputs] if inputs is not None else []) + [pair_check, board_check]
    checks += ([noise] if noise is not None else []) + list(named)
    only = ", ".join(s for s, iv in bounded.items() if iv)
    checks.append(
        Check("rank", UNDETERMINED, "the problem is rank deficient: some directions are not "
              "determined by the boards") if rank_deficient
        else Check("rank", PASS, f"every direction determined except those of {only} that the field of "
                   "view only bounds (see bounded)")
        if only else Check("rank", PASS, "every direction determined")
    )
    if determined is not None:
        checks.append(determined)
    if bounded:
        from rigcal.problem.uncertainty import format_bounded

        checks.append(Check("bounded", NOTE, "; ".join(
            f"{s}: " + ", ".join(format_bounded(d, *v) for d, v in iv.items())
            for s, iv in bounded.items()) + " (set by the elevation field of view, not by measurements)"))
    weak_items = {s: w for s, w in weak.items() if w}
    if weak_items:
        checks.append(Check("weak", NOTE, "; ".join(f"{s}: {', '.join(w)}" for s, w in weak_items.items())))
    return Verdict(tuple(checks), dict(noise_model or {}))


#: a motion-capture sensor whose residuals scatter by more than this many times its configured
#: sigma is flagged (beyond rigcal.mocap.pipeline's refusal ratio it is refused outright)
MOCAP_NOISE_RATIO = 3.0
#: share of a target's measurements within 3 configured sigma below which the match is suspect
MOCAP_MIN_MATCH = 0.5


def mocap_verdict(fit, weak: Mapping[str, list[str]] = {},  # noqa: B006 - read only
                  unseen: Mapping[str, str] = {}) -> Verdict:  # noqa: B006 - read only
    """The verdict of a motion-capture calibration from its per-sensor fit statistics
    (:class:`rigcal.problem.mocap.MocapFit`): ``noise`` (each sensor's residual scatter against
    its configured sigma), ``matches`` (per target, the share of measurements the fitted model
    explains within 3 configured sigma), ``time_offset`` (the clock offset between the MCS and
    each sensor whose target moved relative to the robot: estimated, or - when it could not
    be told from the pose and it matters - a failure), ``errors`` (the error components
    estimated per sensor: a note), ``holds`` (sensors whose region was widened a lot for the few
    holds their errors were estimated from, with how many more would help: a note), ``thin``
    (lidars whose range noise is large against the radius of a cylinder they measured: a note),
    ``targets`` (configured targets never seen: a note) and ``weak`` directions (a note)."""
    noisy, poor, errors = [], [], []
    for name, f in fit.sensors.items():
        ratio = f.noise_sigma / f.sigma_nominal if f.sigma_nominal > 0 else float("inf")
        if ratio > MOCAP_NOISE_RATIO:
            noisy.append(f"{name} {f.noise_sigma:.3g} {f.unit} = {ratio:.1f} x its configured sigma")
        for target, (within, total) in f.matches.items():
            if total and within / total < MOCAP_MIN_MATCH:
                poor.append(f"{name} on {target}: {within} of {total} measurements within 3 sigma")
        errors.append(mocap_error_text(f))
    checks = [
        Check("noise", FAIL, "residuals far above the configured noise: " + "; ".join(noisy)
              + " - a wrong match of the target, wrong intrinsics or a too small sigma")
        if noisy else Check("noise", PASS, "every sensor within "
                            f"{MOCAP_NOISE_RATIO:g} x its configured noise: " + ", ".join(
                                f"{n} {f.noise_sigma / f.sigma_nominal:.2f}" for n, f in fit.sensors.items())),
        Check("matches", FAIL, "targets the fitted model does not explain: " + "; ".join(poor))
        if poor else Check("matches", PASS, "every target's measurements explained"),
    ]
    offset = _offset_check(fit)
    if offset is not None:
        checks.append(offset)
    checks.append(Check("errors", NOTE, "error components estimated from the residuals (the "
                        "covariance holds them): " + "; ".join(errors)))
    few = _few_holds_check(fit)
    if few is not None:
        checks.append(few)
    thin = _thin_check(fit)
    if thin is not None:
        checks.append(thin)
    if unseen:
        checks.append(Check("targets", NOTE, "; ".join(f"target '{t}' {why}" for t, why in unseen.items())))
    weak_items = {s: w for s, w in weak.items() if w}
    if weak_items:
        checks.append(Check("weak", NOTE, "; ".join(f"{s}: {', '.join(w)}" for s, w in weak_items.items())))
    return Verdict(tuple(checks))


def mocap_error_text(f) -> str:
    """One sensor's estimated error components in words (``MocapSensorFit``)."""
    c = dict(f.components)
    unit = f.unit
    scale, shown = (1000.0, "mm") if unit == "m" else (1.0, "px")
    parts = [f"{f.noise_sigma * scale:.3g} {shown} per point"]
    view = c.get(f"view_{unit}", 0.0)
    if view > 0:
        parts.append(f"{view * scale:.2g} {shown} per keypoint and hold")
    if c.get("view_affine_px", 0.0) > 0:
        parts.append(f"{c['view_affine_px']:.2g} px affine distortion of the grid per hold")
    if c.get("capture_m", 0.0) > 0 or c.get("capture_rad", 0.0) > 0:
        parts.append(f"{1000 * c.get('capture_m', 0.0):.2g} mm / {1000 * c.get('capture_rad', 0.0):.2g} mrad "
                     "per capture")
    if c.get("ring_end", 0.0) > 0:
        parts.append(f"{c['ring_end']:.2g} x a ring end's std shared by the ends on one side per revolution")
    if c.get("jitter_s", 0.0) > 0:
        parts.append(f"{1000 * c['jitter_s']:.2g} ms stamp jitter")
    if c.get("hold_m", 0.0) > 0 or c.get("hold_rad", 0.0) > 0:
        parts.append(f"{1000 * c.get('hold_m', 0.0):.2g} mm / {1000 * c.get('hold_rad', 0.0):.2g} mrad per hold"
                     + (" (the MCS's, pooled over the sensors' holds)" if getattr(f, "hold_pooled", False) else ""))
    return f"{f.name} " + ", ".join(parts) + f" ({f.holds} holds)"


#: a sensor's 95 % region widened by more than this (in variance) for the few holds its error
#: model was estimated from gets a note saying how many more holds would narrow it
MOCAP_WIDENING_NOTE = 2.0
#: the degrees of freedom at which the widening is at most MOCAP_WIDENING_NOTE (F over chi2)
_DOF_FOR_NOTE = 7.0
#: fewer holds than this show a per-hold error of the MCS (1 mm / 2 mrad) only when it is
#: large against the sensor's own noise (the coverage benchmark: 4 holds 0.85 inside, 8 holds
#: 0.95, docs/mocap.md)
MOCAP_SURE_HOLDS = 8


def _few_holds_check(fit) -> Check | None:
    """The ``holds`` note: sensors whose error components (per hold) rest on so few holds that
    their 95 % region had to be widened by more than MOCAP_WIDENING_NOTE, with the holds that
    would bring it under that (the degrees of freedom grow about as the holds do); and sensors
    with no per-hold error found when the sensors together have fewer than MOCAP_SURE_HOLDS
    holds, which so few may have missed (the MCS's per-hold error is estimated from every
    sensor's holds together: :func:`rigcal.problem.mocap._components`)."""
    wide, unseen = [], []
    # the MCS's per-hold error is looked for in every sensor's holds together (pooled)
    every = sum(f.holds for f in fit.sensors.values())
    for name, f in fit.sensors.items():
        k = float(getattr(f, "region_widening", 1.0))
        nu = float(getattr(f, "noise_dof", float("inf")))
        if k > MOCAP_WIDENING_NOTE and np.isfinite(nu) and nu > 0:
            more = max(int(np.ceil(f.holds * _DOF_FOR_NOTE / nu)) - f.holds, 1)
            wide.append(f"{name} ({f.holds} holds, {nu:.1f} degrees of freedom: std x {np.sqrt(k):.1f}; "
                        f"about {more} more hold{'s' if more > 1 else ''} would bring it under "
                        f"x {np.sqrt(MOCAP_WIDENING_NOTE):.1f})")
        elif every < MOCAP_SURE_HOLDS and not any(
                f.components.get(c, 0.0) > 0 for c in ("hold_m", "hold_rad", "view_affine_px")):
            unseen.append(f"{name} ({f.holds})")
    parts = []
    if wide:
        parts.append("error model estimated from few holds, 95 % region widened for it: " + "; ".join(wide)
                     + " - hold the target at other distances, places and tilts")
    if unseen:
        parts.append(f"no per-hold error seen in {', '.join(unseen)} holds ({every} over the sensors together), "
                     f"but fewer than {MOCAP_SURE_HOLDS} show the MCS's error of a still target only when it "
                     f"is large: hold the targets {MOCAP_SURE_HOLDS} times or more in all, or set "
                     "options.hold_sigma_floor to the MCS's accuracy for a still body")
    return Check("holds", NOTE, "; ".join(parts)) if parts else None


#: a lidar whose range noise is more than this fraction of the radius of a cylinder it ranged
#: gets the ``thin`` note: so thin a tube's ranges are too curved at that noise for the
#: linearised covariance (benchmarks/mocap_lidar_plate.py --target cylinder, docs/mocap.md)
MOCAP_THIN_TUBE = 0.2


def _thin_check(fit) -> Check | None:
    """The ``thin`` note: lidars whose points on a cylinder were tied by their range along the
    ray while their range noise is more than MOCAP_THIN_TUBE of its radius."""
    thin = []
    for name, f in fit.sensors.items():
        radius = float(getattr(f, "curved_radius_m", float("nan")))
        if np.isfinite(radius) and radius > 0 and f.noise_sigma / radius > MOCAP_THIN_TUBE:
            thin.append(f"{name} ({1000 * f.noise_sigma:.1f} mm of range noise on '{f.curved_target}', "
                        f"{1000 * radius:.1f} mm in radius: {f.noise_sigma / radius:.2f})")
    if not thin:
        return None
    return Check("thin", NOTE, "range noise large against the radius of the cylinder it measures: "
                 + "; ".join(thin) + f" - above {MOCAP_THIN_TUBE:g} of the radius the tube's ranges "
                 "are too curved for the linearised covariance and its 95 % region can be too narrow "
                 "(simulated, 4 holds: 0.875 of the truths inside at 0.27, 0.94 at 0.18); hold a "
                 "flat target (the diamond) for this lidar, or a thicker cylinder")


def _offset_check(fit) -> Check | None:
    """The ``time_offset`` check: estimated offsets (pass), offsets that matter but could not be
    told from the pose (fail, with what to do), or offsets that could not be estimated and do
    not matter (note). None when nothing moved relative to the robot in any kept frame."""
    det, bad, idle = [], [], []
    for name, f in fit.sensors.items():
        status = getattr(f, "time_offset_status", "none")
        if status == "determined":
            det.append(f"{name} {1000 * f.time_offset_s:+.1f} +- {1000 * f.time_offset_std_s:.1f} ms")
        elif status == "undetermined":
            bad.append(f"{name} (std {1000 * f.time_offset_std_s:.0f} ms: it would widen the pose's "
                       f"uncertainty {np.sqrt(f.time_offset_effect):.1f} times)")
        elif status == "irrelevant":  # estimated all the same: the value and its std, in words
            idle.append(f"{name} {1000 * f.time_offset_s:+.1f} +- {1000 * f.time_offset_std_s:.1f} ms")
    if bad:
        return Check("time_offset", FAIL,
                     "the target moved relative to the robot in the kept frames, and the clock offset "
                     "between the MCS and " + "; ".join(bad) + " could not be told from the pose: "
                     "keep the robot still while the target is held (or vary its motion between holds), "
                     "or synchronise the clocks and set options.time_offset_sigma_s to their accuracy"
                     + (f"; estimated: {', '.join(det)}" if det else ""))
    if det:
        return Check("time_offset", PASS, "clock offset between the MCS and each sensor (its stamps minus "
                     "the capture time): " + ", ".join(det)
                     + (f"; {', '.join(idle)}: not determined, hardly changes the pose "
                        "(included in its covariance)" if idle else ""))
    if idle:
        return Check("time_offset", NOTE, f"clock offset of {', '.join(idle)}: not determined; at "
                     "the motion seen it hardly changes the result (included in the covariance)")
    return None


__all__ = [
    "Check",
    "Evidence",
    "FAIL",
    "MOCAP_MIN_MATCH",
    "MOCAP_NOISE_RATIO",
    "MOCAP_THIN_TUBE",
    "NOTE",
    "PASS",
    "PLAUSIBLE_NOISE",
    "PairResiduals",
    "UNDETERMINED",
    "Verdict",
    "mocap_error_text",
    "mocap_verdict",
    "noise_check",
    "noise_summary",
    "pair_checks",
    "pair_residuals",
    "verdict",
]
