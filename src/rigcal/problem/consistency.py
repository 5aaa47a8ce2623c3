"""Does a calibration agree with its own noise model? The verdict every result carries.

Checks (each ``pass``, ``note`` or ``fail``; any ``fail`` flags the result):

* ``pairs``: every comparable sensor pair - also pairs the configuration did not fit (MCPE
  fits only pairs with the reference) - is compared with what the estimated noise model and
  the reported pose uncertainty predict for its residuals. Reduced chi-square far above 1
  (the 1e-4 quantile, and at least 3) means the poses contradict the noise model: **fail**.
* ``boards``: every (pair, board) the same way, against the noise estimated *without* that
  board (a bad board inflates the estimate it would be judged by), with the quantile corrected
  for the number of boards tested; a board far off its pair's prediction (and more than 3
  sigma RMS) *and* beyond the outlier rule's physical floor (10 cm, radar pairs 20 cm: a bad
  detection kept) is a **fail**; one only beyond the noise model is a **note** (real detections are heavier-tailed
  than a Gaussian).
* ``noise``: every sensor's estimated noise against what that kind of sensor can plausibly have
  (:data:`PLAUSIBLE_NOISE`); far above it (a board in the wrong units, a wrong pose the noise
  estimate absorbed) is a **fail**.
* ``rank``: a rank-deficient problem leaves directions undetermined: **fail**.
* ``bounded``: directions set by an inequality constraint (a 2D radar's z, roll, pitch) are
  reported as intervals: **note**.
* ``weak``: directions whose std is above 5 cm / 1 deg: **note**.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset
from rigcal.problem.numerics import chi2_isf
from rigcal.problem.noise import DetectionUnits, estimate_theta, group_design, noise_map, row_batches
from rigcal.problem.outliers import OutlierRule
from rigcal.problem.pairs import all_pairs
from rigcal.problem.residuals import MODEL_RADAR2D
from rigcal.problem.solver import linearise

PASS, NOTE, FAIL = "pass", "note", "fail"
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
class Check:
    """One consistency check: its ``name``, ``status`` (pass / note / fail) and what it found."""

    name: str
    status: str
    detail: str


@dataclass(frozen=True)
class Verdict:
    """``status``: ``consistent`` (no check failed) or ``flagged``; ``checks`` in order."""

    checks: tuple[Check, ...] = ()

    @property
    def status(self) -> str:
        return "flagged" if self.failed else "consistent"

    @property
    def failed(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if c.status == FAIL)

    def to_dict(self) -> dict:
        return {
            "status": self.status,
            "checks": [{"name": c.name, "status": c.status, "detail": c.detail} for c in self.checks],
        }


@functools.lru_cache(maxsize=4096)
def _limit(dof: int, tests: int) -> float:
    """Reduced chi-square above which ``dof`` rows fail, ``tests`` such tests made."""
    q = chi2_isf(ALPHA / max(tests, 1), max(dof, 1)) / max(dof, 1)
    return max(float(q), MIN_FAIL_RATIO)


def pair_checks(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    reference: str,
    units: DetectionUnits,
    theta: np.ndarray,
    joint_covariance,
    rule: OutlierRule = OutlierRule(),
) -> tuple[Check, Check, dict[str, float]]:
    """The ``pairs`` and ``boards`` checks, and the reduced chi-square per pair.

    ``theta``: the noise model's group variances over ``units`` (the dataset's
    :func:`rigcal.problem.noise.detection_units`); ``joint_covariance(names)``: the
    result's joint covariance of those sensors' right perturbations."""
    from rigcal.problem.configurations import build_pairwise

    pairs = all_pairs(dataset)
    problem = build_pairwise(dataset, poses, reference, pairs)
    if not problem.observations:
        return Check("pairs", PASS, "no comparable pairs"), Check("boards", PASS, "-"), {}
    r, J, _, _, layout = linearise(problem)  # unit sigma: r is metric
    M = group_design(noise_map(problem, dataset, units), units)
    pose_var = np.zeros(r.size)
    names = [n for n in layout.names if np.any(layout.cols[layout.index[n]] >= 0)]
    if names:
        C6 = joint_covariance(names)
        cols = np.concatenate([layout.cols[layout.index[n]] for n in names])
        keep = cols >= 0
        C = np.zeros((layout.n_free, layout.n_free))
        C[np.ix_(cols[keep], cols[keep])] = C6[np.ix_(keep, keep)]
        pose_var = np.einsum("ij,jk,ik->i", J, C, J)
    z2 = r**2 / np.maximum(M @ theta + pose_var, 1e-30)
    # each board against the noise estimated without it (a bad board inflates the noise
    # estimate it would otherwise be judged by)
    batches = row_batches(problem)
    row_board = np.concatenate([np.repeat(b.board, b.dim) for b in problem.observations])
    z2_deleted = np.empty_like(z2)
    for k in np.unique(row_board):
        out = row_board == k
        theta_k = estimate_theta(r[~out], M[~out], 1.0, batches=batches[~out])
        z2_deleted[out] = r[out] ** 2 / np.maximum(M[out] @ theta_k + pose_var[out], 1e-30)
    ratios: dict[str, float] = {}
    bad_pairs, bad_boards, odd_boards = [], [], []
    n_boards = sum(len(np.unique(b.board)) for b in problem.observations)
    row0 = 0
    for b in problem.observations:
        rows = slice(row0, row0 + b.size * b.dim)
        zb = z2[rows].reshape(b.size, b.dim)
        row0 += b.size * b.dim
        ratio = float(np.mean(zb))
        ratios[b.label] = ratio
        if ratio > _limit(zb.size, len(problem.observations)):
            bad_pairs.append(f"{b.label} (reduced chi-square {ratio:.1f})")
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
              "cannot determine it)")
        if bad_pairs
        else Check("pairs", PASS, "every pair within its noise model: reduced chi-square "
                   + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
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


def noise_check(dataset: Dataset, noise_model: Mapping[str, Mapping[str, float]]) -> Check:
    """The ``noise`` check: ``noise_model`` (:func:`rigcal.problem.noise.theta_by_sensor`)
    against :data:`PLAUSIBLE_NOISE`."""
    bad = []
    for name, comps in noise_model.items():
        limits = PLAUSIBLE_NOISE[dataset.sensor(name).kind.value]
        for comp, value in comps.items():
            if value > limits[comp]:
                unit = "deg" if comp in ("azimuth", "elevation") else "mm"
                show = (lambda v: f"{v:.2f}") if unit == "deg" else (lambda v: f"{v * 1000:.0f}")
                bad.append(f"{name} {comp} {show(value)} {unit} (plausible: up to {show(limits[comp])} {unit})")
    if bad:
        return Check("noise", FAIL, "noise implausible for the sensor: " + "; ".join(bad)
                     + " - bad detections absorbed by the noise estimate, wrong units, or a wrong pose")
    return Check("noise", PASS, "every sensor's noise is plausible for its kind")


def verdict(
    pair_check: Check,
    board_check: Check,
    rank_deficient: bool,
    bounded: Mapping[str, Mapping[str, tuple[float, float, float]]],
    weak: Mapping[str, list[str]],
    noise: Check | None = None,
) -> Verdict:
    """The checks' verdict; ``bounded``: per sensor, its bounded directions as absolute
    ``(low, high, estimate)`` (:func:`rigcal.problem.uncertainty.absolute_bounds`)."""
    checks = [pair_check, board_check] + ([noise] if noise is not None else [])
    only = ", ".join(s for s, iv in bounded.items() if iv)
    checks.append(
        Check("rank", FAIL, "the problem is rank deficient: some directions are not determined "
              "by the boards") if rank_deficient
        else Check("rank", PASS, f"every direction determined except those of {only} that the field of "
                   "view only bounds (see bounded)")
        if only else Check("rank", PASS, "every direction determined")
    )
    if bounded:
        from rigcal.problem.uncertainty import format_bounded

        checks.append(Check("bounded", NOTE, "; ".join(
            f"{s}: " + ", ".join(format_bounded(d, *v) for d, v in iv.items())
            for s, iv in bounded.items()) + " (set by the elevation field of view, not by measurements)"))
    weak_items = {s: w for s, w in weak.items() if w}
    if weak_items:
        checks.append(Check("weak", NOTE, "; ".join(f"{s}: {', '.join(w)}" for s, w in weak_items.items())))
    return Verdict(tuple(checks))


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
    estimated per sensor: a note), ``targets`` (configured targets never seen: a note) and
    ``weak`` directions (a note)."""
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
    if c.get("capture_m", 0.0) > 0 or c.get("capture_rad", 0.0) > 0:
        parts.append(f"{1000 * c.get('capture_m', 0.0):.2g} mm / {1000 * c.get('capture_rad', 0.0):.2g} mrad "
                     "per capture")
    if c.get("jitter_s", 0.0) > 0:
        parts.append(f"{1000 * c['jitter_s']:.2g} ms stamp jitter")
    if c.get("hold_m", 0.0) > 0 or c.get("hold_rad", 0.0) > 0:
        parts.append(f"{1000 * c.get('hold_m', 0.0):.2g} mm / {1000 * c.get('hold_rad', 0.0):.2g} mrad per hold")
    return f"{f.name} " + ", ".join(parts) + f" ({f.holds} holds)"


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
        elif status == "irrelevant":
            idle.append(name)
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
                     + (f"; {', '.join(idle)}: not determined, no effect" if idle else ""))
    if idle:
        return Check("time_offset", NOTE, f"clock offset of {', '.join(idle)} not determined; at the "
                     "motion seen it hardly changes the result (included in the covariance)")
    return None


__all__ = [
    "Check",
    "FAIL",
    "MOCAP_MIN_MATCH",
    "MOCAP_NOISE_RATIO",
    "NOTE",
    "PASS",
    "PLAUSIBLE_NOISE",
    "Verdict",
    "mocap_error_text",
    "mocap_verdict",
    "noise_check",
    "pair_checks",
    "verdict",
]
