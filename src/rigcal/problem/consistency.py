"""Does a calibration agree with its own noise model? The verdict every result carries.

Checks (each ``pass``, ``note`` or ``fail``; any ``fail`` flags the result):

* ``pairs``: every comparable sensor pair - also pairs the configuration did not fit (MCPE
  fits only pairs with the reference) - is compared with what the estimated noise model and
  the reported pose uncertainty predict for its residuals. Reduced chi-square far above 1
  (the 1e-4 quantile, and at least 3) means the poses contradict the noise model: **fail**.
* ``boards``: every (pair, board) the same way, with the quantile corrected for the number of
  boards tested; a board far off its pair's prediction (a bad detection kept) is a **fail**.
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
import scipy.stats

from rigcal.dataset import Dataset
from rigcal.problem.noise import DetectionUnits, group_design, noise_map
from rigcal.problem.pairs import all_pairs
from rigcal.problem.solver import linearise

PASS, NOTE, FAIL = "pass", "note", "fail"
#: tail probability of the chi-square tests (Bonferroni-corrected over the items tested)
ALPHA = 1e-4
#: a reduced chi-square at or below this never fails (model slack for real detections)
MIN_FAIL_RATIO = 3.0


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
    q = scipy.stats.chi2.isf(ALPHA / max(tests, 1), max(dof, 1)) / max(dof, 1)
    return max(float(q), MIN_FAIL_RATIO)


def pair_checks(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    reference: str,
    units: DetectionUnits,
    theta: np.ndarray,
    joint_covariance,
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
    D = noise_map(problem, dataset, units)
    var = group_design(D, units) @ theta
    names = [n for n in layout.names if np.any(layout.cols[layout.index[n]] >= 0)]
    if names:
        C6 = joint_covariance(names)
        cols = np.concatenate([layout.cols[layout.index[n]] for n in names])
        keep = cols >= 0
        C = np.zeros((layout.n_free, layout.n_free))
        C[np.ix_(cols[keep], cols[keep])] = C6[np.ix_(keep, keep)]
        var = var + np.einsum("ij,jk,ik->i", J, C, J)
    z2 = r**2 / np.maximum(var, 1e-30)
    ratios: dict[str, float] = {}
    bad_pairs, bad_boards = [], []
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
        for k in np.unique(b.board):
            zk = zb[b.board == k]
            rk = float(np.mean(zk))
            if rk > _limit(zk.size, max(n_boards, 1)):
                bad_boards.append(f"board {int(k)} in {b.label} ({np.sqrt(rk):.1f} sigma)")
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
        else Check("boards", PASS, "no board far off its pair's prediction")
    )
    return pair_check, board_check, ratios


def verdict(
    pair_check: Check,
    board_check: Check,
    rank_deficient: bool,
    bounded: Mapping[str, Mapping[str, tuple[float, float]]],
    weak: Mapping[str, list[str]],
) -> Verdict:
    checks = [pair_check, board_check]
    checks.append(
        Check("rank", FAIL, "the problem is rank deficient: some directions are not determined "
              "by the boards") if rank_deficient else Check("rank", PASS, "every direction determined")
    )
    if bounded:
        checks.append(Check("bounded", NOTE, "; ".join(
            f"{s}: " + ", ".join(f"{d} {lo:+.3g}..{hi:+.3g} {'m' if d == 'z' else 'deg'}" for d, (lo, hi) in iv.items())
            for s, iv in bounded.items()) + " (set by the elevation field of view, not by measurements)"))
    weak_items = {s: w for s, w in weak.items() if w}
    if weak_items:
        checks.append(Check("weak", NOTE, "; ".join(f"{s}: {', '.join(w)}" for s, w in weak_items.items())))
    return Verdict(tuple(checks))


__all__ = ["Check", "FAIL", "NOTE", "PASS", "Verdict", "pair_checks", "verdict"]
