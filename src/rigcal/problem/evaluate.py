"""Errors between sensor pairs under a calibration: per board and RMSE (the original tool's
definition: root of the mean squared distance over common anchors; 2D radar pairs compare the
projected reflector with the radar's (x, y))."""

from __future__ import annotations

from typing import Iterator, Mapping

import numpy as np

from rigcal.dataset import Dataset
from rigcal.geometry.se3 import invert
from rigcal.problem.pairs import PairData, all_pairs, pair_data
from rigcal.problem.residuals import MODEL_RADAR2D
from rigcal.sensors.radar import project_2d


def anchor_errors(pair: PairData, poses: Mapping[str, np.ndarray]) -> np.ndarray:
    """(n,) distance [m] of each anchor between prediction and measurement."""
    T_obs_frame = invert(poses[pair.observer]) @ poses[pair.frame]
    x = pair.points @ T_obs_frame[:3, :3].T + T_obs_frame[:3, 3]
    h = project_2d(x) if pair.model == MODEL_RADAR2D else x
    return np.linalg.norm(h - pair.measured, axis=1)


def board_errors(pair: PairData, poses: Mapping[str, np.ndarray]) -> dict[int, float]:
    """Board index -> RMS anchor error [m] of that board for the pair."""
    e = anchor_errors(pair, poses)
    out = {}
    for k in pair.boards:
        sel = pair.board == k
        out[int(k)] = float(np.sqrt(np.mean(e[sel] ** 2)))
    return out


def rmse(pair: PairData, poses: Mapping[str, np.ndarray]) -> float:
    e = anchor_errors(pair, poses)
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def _shared_pairs(dataset: Dataset, boards: np.ndarray | None) -> Iterator[PairData]:
    """Every comparable pair that shares a board (of ``boards``, if given)."""
    for a, b in all_pairs(dataset):
        p = pair_data(dataset, a, b, boards)
        if p is not None and p.num_boards:
            yield p


def pair_rmses(
    dataset: Dataset, poses: Mapping[str, np.ndarray], boards: np.ndarray | None = None
) -> dict[str, float]:
    """The RMSE of :func:`evaluate_pairs` alone (no per-board errors)."""
    return {p.label: rmse(p, poses) for p in _shared_pairs(dataset, boards)}


def evaluate_pairs(
    dataset: Dataset, poses: Mapping[str, np.ndarray], boards: np.ndarray | None = None
) -> tuple[dict[str, float], dict[str, dict[int, float]]]:
    """RMSE and per-board errors for every comparable pair that shares a board."""
    rm, per = {}, {}
    for p in _shared_pairs(dataset, boards):
        rm[p.label] = rmse(p, poses)
        per[p.label] = board_errors(p, poses)
    return rm, per
