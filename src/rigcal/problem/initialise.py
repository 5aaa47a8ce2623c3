"""Initial sensor poses without a user guess: Kabsch per pair (2D radar detections assumed on
the radar plane, as in the paper), RANSAC over boards when outliers may be present, chained
along a maximum spanning tree of the co-visibility graph from the reference sensor."""

from __future__ import annotations

import itertools
import logging
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import GeometryError, InputError
from rigcal.geometry.align import kabsch, kabsch_batch
from rigcal.geometry.se3 import invert
from rigcal.problem.observability import check_observable
from rigcal.problem.pairs import PairData, all_pairs, pair_data
from rigcal.problem.residuals import MODEL_RADAR2D
from rigcal.sensors.radar import project_2d

log = logging.getLogger(__name__)

#: per-board error [m] under which a board supports a RANSAC hypothesis
INLIER_M = {"point3d": 0.15, "radar2d": 0.30}
MAX_HYPOTHESES = 80


def _targets(pair: PairData) -> np.ndarray:
    if pair.model == MODEL_RADAR2D:
        return np.column_stack([pair.measured, np.zeros(len(pair.measured))])
    return pair.measured


def _per_board_error(pair: PairData, T_obs_frame: np.ndarray) -> np.ndarray:
    x = pair.points @ T_obs_frame[:3, :3].T + T_obs_frame[:3, 3]
    h = project_2d(x) if pair.model == MODEL_RADAR2D else x
    e2 = np.sum((h - pair.measured) ** 2, axis=1).reshape(-1, pair.per_board)
    return np.sqrt(e2.mean(axis=1))


def pair_transform(pair: PairData, robust: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``T_observer_frame`` by Kabsch over the pair's anchors, and the inlier board mask.

    With ``robust``, hypotheses from minimal sets of boards (2 boards of 4 centres, or 3
    reflectors) are scored by how many boards they explain; the best is refit on its inliers.
    """
    targets = _targets(pair)
    nb = pair.num_boards
    min_boards = 2 if pair.per_board == 4 else 3
    if nb < (1 if pair.per_board == 4 else 3):
        raise GeometryError(
            f"pair {pair.label} shares {nb} board(s); at least "
            f"{1 if pair.per_board == 4 else 3} needed"
        )
    all_in = np.ones(nb, dtype=bool)
    if not robust or nb <= min_boards:
        return kabsch(pair.points, targets), all_in
    pts = pair.points.reshape(nb, pair.per_board, 3)
    tgt = targets.reshape(nb, pair.per_board, 3)
    combos = list(itertools.combinations(range(nb), min_boards))
    rng = np.random.default_rng(seed)
    if len(combos) > MAX_HYPOTHESES:
        pick = rng.choice(len(combos), size=MAX_HYPOTHESES, replace=False)
        combos = [combos[i] for i in pick]
    thr = INLIER_M[pair.model]
    idx = np.array(combos)  # (H, min_boards)
    Ts = kabsch_batch(
        pts[idx].reshape(len(combos), -1, 3), tgt[idx].reshape(len(combos), -1, 3)
    )
    ok = np.all(np.isfinite(Ts.reshape(len(combos), -1)), axis=1)
    best = None
    if np.any(ok):
        Ts = Ts[ok]
        x = np.einsum("hij,nj->hni", Ts[:, :3, :3], pair.points) + Ts[:, None, :3, 3]
        h = project_2d(x) if pair.model == MODEL_RADAR2D else x
        e2 = np.sum((h - pair.measured[None]) ** 2, axis=2).reshape(len(Ts), nb, pair.per_board)
        err = np.sqrt(e2.mean(axis=2))  # (H, nb)
        inl = err < thr
        counts = inl.sum(axis=1)
        spread = -np.sum(np.minimum(err, thr), axis=1)
        order = np.lexsort((-spread, -counts))  # most inliers, then smallest errors
        k = int(order[0])
        best = ((int(counts[k]), float(spread[k])), inl[k])
    if best is None or best[0][0] < min_boards:
        return kabsch(pair.points, targets), all_in
    inl = best[1]
    for _ in range(3):
        sel = np.repeat(inl, pair.per_board)
        T = kabsch(pair.points[sel], targets[sel])
        new = _per_board_error(pair, T) < thr
        if new.sum() < min_boards or np.array_equal(new, inl):
            break
        inl = new
    return T, inl


def default_reference(dataset: Dataset) -> str:
    """The dataset's reference, else the first lidar, else the first 3D sensor."""
    if dataset.reference:
        return dataset.reference
    for kind in (SensorKind.LIDAR, SensorKind.CAMERA, SensorKind.RADAR3D):
        for s in dataset.sensors:
            if s.kind == kind:
                return s.name
    return dataset.sensors[0].name


def initial_poses(
    dataset: Dataset,
    reference: str,
    *,
    robust: bool = False,
    given: Mapping[str, np.ndarray] | None = None,
    pairs: list[tuple[str, str]] | None = None,
) -> dict[str, np.ndarray]:
    """``T_reference_sensor`` for every sensor.

    ``given`` poses (in the reference frame) are used as they are; the others come from a
    maximum spanning tree over ``pairs`` (default: every comparable pair), preferring links
    between 3D sensors and links with many shared boards.
    """
    given = dict(given or {})
    poses: dict[str, np.ndarray] = {reference: np.eye(4)}
    poses.update({k: np.asarray(v, dtype=float) for k, v in given.items()})
    edges = []
    for a, b in pairs if pairs is not None else all_pairs(dataset):
        p = pair_data(dataset, a, b)
        if p is None:
            continue
        need = 1 if p.per_board == 4 else 3
        if p.num_boards < need:
            continue
        weight = p.num_boards + (1000 if p.per_board == 4 else 0)
        edges.append((weight, p))
    edges.sort(key=lambda e: -e[0])
    cache: dict[str, np.ndarray] = {}
    changed = True
    while changed:
        changed = False
        for _, p in edges:
            known_f, known_o = p.frame in poses, p.observer in poses
            if known_f == known_o:
                continue
            if p.label not in cache:
                try:
                    cache[p.label] = pair_transform(p, robust)[0]
                except GeometryError as exc:
                    log.info("no initial estimate from pair %s: %s", p.label, exc)
                    cache[p.label] = None  # type: ignore[assignment]
            T_obs_frame = cache[p.label]
            if T_obs_frame is None:
                continue
            if known_f:
                poses[p.observer] = poses[p.frame] @ invert(T_obs_frame)
            else:
                poses[p.frame] = poses[p.observer] @ T_obs_frame
            changed = True
            break
    missing = [s for s in dataset.names if s not in poses]
    if missing:
        why = ""
        try:
            check_observable(dataset, "fcpe", reference)
        except GeometryError as exc:
            why = f" ({exc})"
        raise InputError(
            f"cannot relate sensor(s) {missing} to reference '{reference}': they share too few "
            f"valid boards with the other sensors (a 3D pair needs 1, a radar pair 3 non-collinear){why}"
        )
    return {name: poses[name] for name in dataset.names}
