"""Bad detections found by consensus across sensors, with no ignore file.

After a robust (Cauchy) solve, every sensor pair's per-board error is compared with a threshold
``max(floor, k * 1.4826 * median)`` of that pair. An inconsistent (pair, board) implicates both
sensors; on each board the sensor involved in the most inconsistent pairs is blamed first
(a detection that disagrees with every other sensor). When only two sensors see a board and
disagree, neither can be trusted, so both detections are excluded. Floors are physical: a good
board detection is never centimetres-accurate enough to be dropped at a few centimetres, so good
boards are not dropped to lower an RMSE.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset
from rigcal.problem.evaluate import board_errors
from rigcal.problem.pairs import all_pairs, pair_data


@dataclass(frozen=True)
class OutlierRule:
    floor_3d_m: float = 0.10
    floor_radar_m: float = 0.20
    k_mad: float = 6.0


def find_outliers(
    dataset: Dataset, poses: Mapping[str, np.ndarray], rule: OutlierRule = OutlierRule()
) -> dict[str, set[int]]:
    """Sensor -> board indices whose detection disagrees with the other sensors."""
    bad: dict[int, dict[tuple[str, str], float]] = defaultdict(dict)
    seen: dict[int, list[tuple[str, str]]] = defaultdict(list)
    for a, b in all_pairs(dataset):
        p = pair_data(dataset, a, b)
        if p is None or p.num_boards == 0:
            continue
        errs = board_errors(p, poses)
        vals = np.array(list(errs.values()))
        floor = rule.floor_3d_m if p.per_board == 4 else rule.floor_radar_m
        thr = max(floor, rule.k_mad * 1.4826 * float(np.median(vals)))
        for k, e in errs.items():
            seen[k].append((a, b))
            if e > thr:
                bad[k][(a, b)] = e / thr
    out: dict[str, set[int]] = defaultdict(set)
    for k, bad_pairs in bad.items():
        pairs = list(seen[k])
        bad_pairs = dict(bad_pairs)
        while bad_pairs:
            count: dict[str, int] = defaultdict(int)
            excess: dict[str, float] = defaultdict(float)
            total: dict[str, int] = defaultdict(int)
            for a, b in pairs:
                total[a] += 1
                total[b] += 1
            for (a, b), ratio in bad_pairs.items():
                for s in (a, b):
                    count[s] += 1
                    excess[s] += ratio
            ranked = sorted(count, key=lambda s: (count[s], count[s] / total[s], excess[s]), reverse=True)
            top = ranked[0]
            ties = [s for s in ranked if count[s] == count[top] and count[s] == total[s]]
            if count[top] == 1 and len(ties) >= 2 and all(total[s] == 1 for s in ties[:2]):
                blamed = ties[:2]  # two sensors, one disagreeing pair: both untrustworthy
            else:
                blamed = [top]
            for s in blamed:
                out[s].add(int(k))
            pairs = [pr for pr in pairs if not set(pr) & set(blamed)]
            bad_pairs = {pr: r for pr, r in bad_pairs.items() if not set(pr) & set(blamed)}
    return dict(out)
