"""The three configurations of Domhof et al. as choices of pose blocks and residual batches.

* **MCPE** - minimally connected: every sensor against the reference sensor only.
* **FCPE** - fully connected: every comparable pair. All sensors are posed in one common
  frame (the reference's), so every loop ``T_a_b T_b_c T_c_a = I`` closes by construction -
  the paper's loop constraints hold exactly without a constrained solver.
* **PSE** - pose and structure: sensor poses plus one latent pose per board; residuals are
  Mahalanobis distances with per-sensor diagonal noise (re-estimated by the caller).

A 2D radar's field of view bounds the elevation of the reflector (paper eq. 4) in every mode.
``hold_radar_plane`` holds a 2D radar's z, roll and pitch (in its own frame) at their initial
values: a 2D radar observes them only through second-order range effects.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import ConfigError
from rigcal.geometry.align import kabsch_batch
from rigcal.problem.pairs import PairData, all_pairs, pair_data, reflector_points
from rigcal.problem.residuals import MODEL_POINT, MODEL_RADAR2D
from rigcal.problem.solver import ALL_FREE, ElevationLimits, Observations, PoseBlock, Problem
from rigcal.targets.circle_board import board_centres, reflector_in_board

MODES = ("mcpe", "fcpe", "pse")
RADAR_PLANE_FREE = (False, False, True, True, True, False)  # yaw, x, y free; roll, pitch, z held
RADAR_PLANE_HELD = ("z", "roll", "pitch")


def board_block(k: int) -> str:
    return f"board:{k}"


def sensor_free(dataset: Dataset, name: str, reference: str, hold_radar_plane: bool):
    if name == reference:
        return (False,) * 6
    if hold_radar_plane and dataset.sensor(name).kind == SensorKind.RADAR:
        return RADAR_PLANE_FREE
    return ALL_FREE


def pairs_for_mode(dataset: Dataset, mode: str, reference: str) -> list[tuple[str, str]]:
    if mode == "fcpe":
        return all_pairs(dataset)
    if mode == "mcpe":
        out = []
        for s in dataset.names:
            if s == reference:
                continue
            pair = (reference, s) if dataset.names.index(reference) < dataset.names.index(s) else (s, reference)
            if pair not in all_pairs(dataset):
                raise ConfigError(
                    f"MCPE: sensor '{s}' cannot be compared with reference '{reference}' "
                    "(two 2D radars share no 3D point); choose a 3D reference sensor"
                )
            out.append(pair)
        return out
    raise ConfigError(f"no pairwise configuration for mode '{mode}'")


def _pair_batches(pair: PairData, dataset: Dataset):
    n = pair.points.shape[0]
    obs = Observations(
        label=pair.label,
        sensor=pair.observer,
        model=pair.model,
        frame=(pair.frame,) * n,
        observer=(pair.observer,) * n,
        points=pair.points,
        measured=pair.measured,
        sigma=np.ones_like(pair.measured),
        board=pair.board,
    )
    lim = None
    if pair.model == MODEL_RADAR2D:
        max_el = dataset.sensor(pair.observer).max_elevation_rad
        lim = ElevationLimits(
            label=pair.label,
            frame=(pair.frame,) * n,
            observer=(pair.observer,) * n,
            points=pair.points,
            max_elevation_rad=np.full(n, max_el),
            board=pair.board,
        )
    return obs, lim


def build_pairwise(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    reference: str,
    pairs: list[tuple[str, str]],
    hold_radar_plane: bool = False,
) -> Problem:
    """MCPE or FCPE: sensor poses in the reference frame, residuals over ``pairs``."""
    blocks = tuple(
        PoseBlock(s, poses[s], sensor_free(dataset, s, reference, hold_radar_plane))
        for s in dataset.names
    )
    obs, lims = [], []
    for a, b in pairs:
        p = pair_data(dataset, a, b)
        if p is None or p.num_boards == 0:
            continue
        o, lim = _pair_batches(p, dataset)
        obs.append(o)
        if lim is not None:
            lims.append(lim)
    return Problem(blocks, tuple(obs), tuple(lims))


def pse_boards(dataset: Dataset) -> list[int]:
    """Boards whose pose is determined: seen by a lidar/camera (4 centres fix all 6 DOF)."""
    seen = np.zeros(dataset.num_boards, dtype=bool)
    for s in dataset.sensors:
        if s.kind.is_point_cloud:
            seen |= s.valid
    return [int(k) for k in np.flatnonzero(seen)]


def initial_board_poses(dataset: Dataset, poses: Mapping[str, np.ndarray]) -> dict[int, np.ndarray]:
    """``T_reference_board`` per board: the mean over 3D sensors of Kabsch fits of the board."""
    model = board_centres(dataset.board)
    ks = pse_boards(dataset)
    if not ks:
        return {}
    total = np.zeros((dataset.num_boards, 4, 3))
    count = np.zeros(dataset.num_boards)
    for s in dataset.sensors:
        if s.kind.is_point_cloud:
            T = poses[s.name]
            v = s.valid
            total[v] += s.points[v] @ T[:3, :3].T + T[:3, 3]
            count[v] += 1
    mean = total[ks] / count[ks, None, None]
    Ts = kabsch_batch(np.broadcast_to(model, mean.shape), mean)
    return {k: Ts[i] for i, k in enumerate(ks)}


def build_pse(
    dataset: Dataset,
    poses: Mapping[str, np.ndarray],
    board_poses: Mapping[int, np.ndarray],
    reference: str,
    sigmas: Mapping[str, np.ndarray],
    hold_radar_plane: bool = False,
) -> Problem:
    """PSE: sensors and boards in the reference frame; Mahalanobis residuals with per-sensor,
    per-axis noise ``sigmas[sensor]`` ((3,) for 3D sensors, (2,) for 2D radars)."""
    blocks = [
        PoseBlock(s, poses[s], sensor_free(dataset, s, reference, hold_radar_plane))
        for s in dataset.names
    ]
    boards = pse_boards(dataset)
    blocks += [PoseBlock(board_block(k), board_poses[k]) for k in boards]
    bset = np.zeros(dataset.num_boards, dtype=bool)
    bset[boards] = True
    centres = board_centres(dataset.board)
    refl = reflector_in_board(dataset.board)
    obs, lims = [], []
    for s in dataset.sensors:
        ks = np.flatnonzero(s.valid & bset)
        if ks.size == 0:
            continue
        if s.kind.is_point_cloud:
            n = ks.size * 4
            pts = np.tile(centres, (ks.size, 1))
            meas = s.points[ks].reshape(-1, 3)
            board = np.repeat(ks, 4)
            model = MODEL_POINT
        else:
            n = ks.size
            pts = np.tile(refl, (n, 1))
            meas = s.points[ks]
            board = ks
            model = MODEL_RADAR2D if s.kind == SensorKind.RADAR else MODEL_POINT
        frames = tuple(board_block(int(k)) for k in board)
        obs.append(
            Observations(
                label=s.name,
                sensor=s.name,
                model=model,
                frame=frames,
                observer=(s.name,) * n,
                points=pts,
                measured=meas,
                sigma=np.broadcast_to(np.asarray(sigmas[s.name], dtype=float), meas.shape).copy(),
                board=board,
            )
        )
        if s.kind == SensorKind.RADAR:
            lims.append(
                ElevationLimits(
                    label=s.name,
                    frame=frames,
                    observer=(s.name,) * n,
                    points=pts,
                    max_elevation_rad=np.full(n, s.max_elevation_rad),
                    board=board,
                )
            )
    return Problem(tuple(blocks), tuple(obs), tuple(lims))


def measurement_dim(dataset: Dataset, name: str) -> int:
    return 2 if dataset.sensor(name).kind == SensorKind.RADAR else 3


__all__ = [
    "MODES",
    "RADAR_PLANE_HELD",
    "board_block",
    "build_pairwise",
    "build_pse",
    "initial_board_poses",
    "measurement_dim",
    "pairs_for_mode",
    "pse_boards",
    "reflector_points",
]
