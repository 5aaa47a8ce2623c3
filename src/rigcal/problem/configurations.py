"""The three configurations of Domhof et al. as choices of pose blocks and residual batches.

* **MCPE** - minimally connected: every sensor against the reference sensor only.
* **FCPE** - fully connected: every comparable pair. All sensors are posed in one common
  frame (the reference's), so every loop ``T_a_b T_b_c T_c_a = I`` closes by construction -
  the paper's loop constraints hold exactly without a constrained solver.
* **PSE** - pose and structure: sensor poses plus one latent pose per board; residuals are
  Mahalanobis distances with per-sensor diagonal noise (re-estimated by the caller).

A 2D radar's field of view bounds the elevation of the reflector (paper eq. 4) in every mode.
``hold_radar_plane`` holds a 2D radar's z, roll and pitch (in its own frame) at their initial
values: a 2D radar observes them only through second-order range effects. ``priors``
(:class:`rigcal.problem.priors.SensorPrior` per sensor) add a soft prior residual block per
sensor around its nominal pose, whitened by its tolerances divided by ``prior_scale`` (the
observations' noise scale in the problem's units); a tolerance of 0 holds the direction.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import ConfigError
from rigcal.geometry.align import kabsch_batch
from rigcal.problem.pairs import PairData, all_pairs, pair_data, reflector_points
from rigcal.problem.residuals import MODEL_POINT, MODEL_RADAR2D
from rigcal.problem.priors import SensorPrior
from rigcal.problem.solver import ALL_FREE, ElevationLimits, Observations, PoseBlock, PosePriors, Problem
from rigcal.targets.circle_board import board_centres, reflector_in_board

MODES = ("mcpe", "fcpe", "pse")
RADAR_PLANE_FREE = (False, False, True, True, True, False)  # yaw, x, y free; roll, pitch, z held
RADAR_PLANE_HELD = ("z", "roll", "pitch")


def board_block(k: int) -> str:
    return f"board:{k}"


def sensor_free(
    dataset: Dataset, name: str, reference: str, hold_radar_plane: bool, prior: SensorPrior | None = None
):
    if name == reference:
        return (False,) * 6
    free = ALL_FREE
    if hold_radar_plane and dataset.sensor(name).kind == SensorKind.RADAR:
        free = RADAR_PLANE_FREE
    if prior is not None:
        free = tuple(f and not h for f, h in zip(free, prior.held))
    return free


def prior_batches(
    priors: Mapping[str, SensorPrior] | None, names, prior_scale: float | None = 1.0
) -> tuple[PosePriors, ...]:
    """One :class:`PosePriors` per sensor of ``names`` with a finite, positive tolerance: sigma
    = tolerance / ``prior_scale`` (inf where there is none or where it is 0: held by the pose
    block instead). ``prior_scale`` None: no soft priors (held directions only)."""
    if not priors or prior_scale is None:
        return ()
    out = []
    for name in names:
        pr = priors.get(name)
        if pr is None or not pr.soft:
            continue
        s = pr.sigma
        sigma = np.where(np.isfinite(s) & (s > 0), s / float(prior_scale), np.inf)
        out.append(PosePriors(f"prior:{name}", (name,), pr.T_nominal[None], sigma))
    return tuple(out)


def keep_poses(problem: Problem, names) -> Problem:
    """``problem`` with only the pose blocks ``names`` (and the priors bound to them)."""
    keep = set(names)
    return replace(
        problem,
        poses=tuple(p for p in problem.poses if p.name in keep),
        priors=tuple(pr for pr in problem.priors if set(pr.blocks) <= keep),
    )


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
    priors: Mapping[str, SensorPrior] | None = None,
    prior_scale: float | None = 1.0,
) -> Problem:
    """MCPE or FCPE: sensor poses in the reference frame, residuals over ``pairs``; ``priors``
    as the module says (``prior_scale`` None: their held directions only)."""
    priors = priors or {}
    blocks = tuple(
        PoseBlock(s, poses[s], sensor_free(dataset, s, reference, hold_radar_plane, priors.get(s)))
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
    return Problem(blocks, tuple(obs), tuple(lims), prior_batches(priors, dataset.names, prior_scale))


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
    priors: Mapping[str, SensorPrior] | None = None,
    prior_scale: float | None = 1.0,
) -> Problem:
    """PSE: sensors and boards in the reference frame; Mahalanobis residuals with per-sensor,
    per-axis noise ``sigmas[sensor]`` ((3,) for 3D sensors, (2,) for 2D radars); ``priors`` as
    the module says."""
    priors = priors or {}
    blocks = [
        PoseBlock(s, poses[s], sensor_free(dataset, s, reference, hold_radar_plane, priors.get(s)))
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
    return Problem(tuple(blocks), tuple(obs), tuple(lims), prior_batches(priors, dataset.names, prior_scale))


def measurement_dim(dataset: Dataset, name: str) -> int:
    return 2 if dataset.sensor(name).kind == SensorKind.RADAR else 3


__all__ = [
    "MODES",
    "RADAR_PLANE_HELD",
    "board_block",
    "build_pairwise",
    "build_pse",
    "initial_board_poses",
    "keep_poses",
    "measurement_dim",
    "pairs_for_mode",
    "prior_batches",
    "pse_boards",
    "reflector_points",
]
