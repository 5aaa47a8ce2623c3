"""Does the reported uncertainty hold? Coverage of the board modes on simulated rigs.

Each trial draws a random rig (:func:`rigcal.sim.rig.random_rig`) with unequal noise per sensor
kind, places boards every sensor can see, simulates detections, calibrates and asks, for every
calibrated sensor, whether the truth lies inside the region the result reports at 95 %:

* **position** (the question a user asks first): the true sensor origin inside the reported
  3D ellipsoid of ``T_reference_sensor``'s translation (chi-square, 3 dof, 7.81). For a 2D radar
  whose z is reported *bounded*, the in-plane position (its own x and y, 2 dof, 5.99) must be
  inside the ellipse and the true offset along its z axis inside the reported interval;
* **pose**: the full right-perturbation error ``log(T_est^-1 T_true)`` (6 dof, 12.59) under the
  reported covariance; for a 2D radar the free directions (yaw, x, y: 3 dof, 7.81) and every
  bounded direction inside its interval.

Fractions near 0.95 mean the reported uncertainty is honest; much lower means overconfident.
Every random draw is seeded from ``(seed, trial)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import RigcalError
from rigcal.geometry.se3 import invert, se3_log
from rigcal.problem.result import CalibrationResult
from rigcal.sim.rig import SimSensor, make_rig_placements, random_rig, simulate

#: chi-square 95 % quantiles by degrees of freedom
CHI2_95 = {1: 3.841, 2: 5.991, 3: 7.815, 6: 12.592}
#: tangent order of a right perturbation (rotation first)
TANGENT = ("roll", "pitch", "yaw", "x", "y", "z")


@dataclass(frozen=True)
class NoiseSpec:
    """Per-kind noise of the simulated sensors (defaults: the issue's unequal-noise rig)."""

    lidar_sigma_m: float = 0.004
    camera_sigma_m: float = 0.02
    camera_depth_sigma_at_1m_m: float = 0.002
    radar_range_sigma_m: float = 0.03
    radar_azimuth_sigma_deg: float = 0.3


@dataclass
class CoverageTally:
    """Counts of sensors whose truth was inside the reported 95 % region."""

    position_inside: int = 0
    pose_inside: int = 0
    sensors: int = 0
    failures: int = 0
    flagged: int = 0
    runs: int = 0
    by_kind: dict = field(default_factory=dict)

    def add(self, kind: str, position_ok: bool, pose_ok: bool) -> None:
        self.sensors += 1
        self.position_inside += int(position_ok)
        self.pose_inside += int(pose_ok)
        k = self.by_kind.setdefault(kind, [0, 0, 0])
        k[0] += int(position_ok)
        k[1] += int(pose_ok)
        k[2] += 1

    def fractions(self) -> dict:
        n = max(self.sensors, 1)
        return {
            "position": self.position_inside / n,
            "pose": self.pose_inside / n,
            "sensors": self.sensors,
            "runs": self.runs,
            "failures": self.failures,
            "flagged": self.flagged,
            "by_kind": {k: {"position": v[0] / v[2], "pose": v[1] / v[2], "sensors": v[2]}
                        for k, v in sorted(self.by_kind.items())},
        }


def _with_noise(sensors: Sequence[SimSensor], noise: NoiseSpec) -> tuple[SimSensor, ...]:
    out = []
    for s in sensors:
        if s.kind is SensorKind.LIDAR:
            out.append(replace(s, sigma_m=noise.lidar_sigma_m))
        elif s.kind is SensorKind.CAMERA:
            out.append(replace(s, sigma_m=noise.camera_sigma_m,
                               depth_sigma_at_1m_m=noise.camera_depth_sigma_at_1m_m))
        else:
            out.append(replace(s, range_sigma_m=noise.radar_range_sigma_m,
                               azimuth_sigma_deg=noise.radar_azimuth_sigma_deg))
    return tuple(out)


def _inside(err: np.ndarray, cov: np.ndarray, idx: Sequence[int]) -> bool:
    idx = list(idx)
    e = err[idx]
    C = cov[np.ix_(idx, idx)]
    d2 = float(e @ np.linalg.pinv(C, rcond=1e-12, hermitian=True) @ e)
    return d2 <= CHI2_95[len(idx)]


def judge_sensor(result: CalibrationResult, name: str, T_true_reference_sensor: np.ndarray) -> tuple[bool, bool]:
    """(position inside, pose inside) the reported 95 % region for one calibrated sensor.

    ``T_true_reference_sensor``: the true pose in the result's reference frame."""
    est = result.sensors[name]
    T_est = est.T_reference_sensor
    xi = se3_log(invert(T_est) @ T_true_reference_sensor)  # (omega, v): T_true = T_est exp(xi)
    cov = est.covariance
    bounded = dict(est.bounded)
    free = [i for i, d in enumerate(TANGENT) if d not in bounded and d not in est.held]
    bounded_ok = True
    for d, (lo, hi) in bounded.items():
        i = TANGENT.index(d)
        val = xi[i] if i >= 3 else math.degrees(xi[i])
        bounded_ok &= lo <= val <= hi
    pos_idx = [i for i in free if i >= 3]
    if len(pos_idx) == 3:
        # the origin's error in the reference frame: R v (first order)
        R = T_est[:3, :3]
        e = T_true_reference_sensor[:3, 3] - T_est[:3, 3]
        C = R @ cov[3:, 3:] @ R.T
        position_ok = float(e @ np.linalg.pinv(C, hermitian=True) @ e) <= CHI2_95[3]
    else:
        position_ok = (not pos_idx or _inside(xi, cov, pos_idx)) and bounded_ok
    pose_ok = (not free or _inside(xi, cov, free)) and bounded_ok
    return position_ok, pose_ok


def board_coverage(
    trials: int = 40,
    seed: int = 0,
    modes: Sequence[str] = ("mcpe", "fcpe", "pse"),
    *,
    n_lidar: int = 2,
    n_camera: int = 2,
    n_radar: int = 2,
    boards: int = 15,
    noise: NoiseSpec = NoiseSpec(),
    calibrate_options: dict | None = None,
    progress=None,
) -> dict[str, dict]:
    """Coverage of the reported 95 % regions per mode over ``trials`` simulated rigs.

    Returns ``{mode: {"position": fraction, "pose": fraction, "sensors": n, "runs": n,
    "failures": n, "flagged": n, "by_kind": {...}}}``. A run that raises counts as a failure
    (no sensors); ``flagged``: runs the consistency check flagged (the data are clean).
    """
    from rigcal.problem.calibrate import CalibrationOptions, calibrate

    tallies = {m: CoverageTally() for m in modes}
    for t in range(trials):
        rng = np.random.default_rng([seed, t])
        sensors = _with_noise(random_rig(rng, n_lidar, n_camera, n_radar), noise)
        T_rig_board = make_rig_placements(rng, sensors, boards)
        sim = simulate(sensors, T_rig_board, rng=rng)
        for mode in modes:
            tally = tallies[mode]
            tally.runs += 1
            try:
                result = calibrate(
                    sim.dataset,
                    CalibrationOptions(mode=mode, **(calibrate_options or {})),
                )
            except RigcalError:
                tally.failures += 1
                continue
            tally.flagged += int(result.flagged)  # clean simulated data: should stay rare
            ref = result.reference
            for s in sim.dataset.sensors:
                if s.name == ref:
                    continue
                pos_ok, pose_ok = judge_sensor(result, s.name, sim.truth_T(ref, s.name))
                tally.add(s.kind.value, pos_ok, pose_ok)
        if progress is not None:
            progress(t + 1, trials)
    return {m: t.fractions() for m, t in tallies.items()}


__all__ = ["CHI2_95", "CoverageTally", "NoiseSpec", "board_coverage", "judge_sensor"]
