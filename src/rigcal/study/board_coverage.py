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
  bounded direction inside its interval;
* **relative**: every pair's ``T_a_b`` (:attr:`CalibrationResult.relative`) the same way: its
  6-DOF error under the relative covariance - where bounded directions enter, the error they
  cannot explain (profiled out in the covariance's metric, 6 - k dof) and every bounded
  quantity's true value inside its interval.

With ``priors`` (:class:`PriorSpec`) every non-reference sensor gets a mounting prior: its
nominal pose is the truth moved by a draw of the stated tolerances (and, as a start only, its
other directions by as much again), given as ``initial`` with the tolerances as ``priors``.

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
from rigcal.geometry.se3 import adjoint, invert, se3_exp, se3_log
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


@dataclass(frozen=True)
class PriorSpec:
    """Mounting tolerances (1 sigma, :mod:`rigcal.problem.priors` keys) per sensor kind of the
    coverage trials with priors; a kind missing gets none."""

    lidar: dict = field(default_factory=lambda: {"x_m": 0.02, "y_m": 0.02, "z_m": 0.02,
                                                 "roll_deg": 1.0, "pitch_deg": 1.0, "yaw_deg": 1.0})
    camera: dict = field(default_factory=lambda: {"x_m": 0.02, "y_m": 0.02, "z_m": 0.02,
                                                  "roll_deg": 1.0, "pitch_deg": 1.0, "yaw_deg": 1.0})
    radar: dict = field(default_factory=lambda: {"z_m": 0.02, "roll_deg": 1.0, "pitch_deg": 1.0})

    def for_kind(self, kind: SensorKind) -> dict:
        return dict(getattr(self, kind.value, None) or {})


def nominal_poses(rng: np.random.Generator, truth: dict[str, np.ndarray], reference: str,
                  tolerances: dict[str, dict]) -> dict[str, np.ndarray]:
    """``T_reference_sensor`` nominal poses: the truth moved by a draw of each sensor's
    tolerances in its named directions (and by as much again in the others, a start only)."""
    from rigcal.problem.priors import prior_sigma

    out = {reference: np.eye(4)}
    for name, T in truth.items():
        if name == reference:
            continue
        sig = prior_sigma(tolerances.get(name, {}))
        named = np.isfinite(sig)
        scale = np.where(named, sig, np.where(np.arange(6) < 3, np.radians(1.0), 0.02))
        if not named.any():
            scale = np.zeros(6)
        out[name] = T @ se3_exp(rng.normal(size=6) * scale)
    return out


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
    relative_inside: int = 0
    relatives: int = 0

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
            "relative": self.relative_inside / max(self.relatives, 1),
            "relatives": self.relatives,
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


def _wrapped_inside(value: float, lo: float, hi: float, angle: bool) -> bool:
    if angle:  # the interval may run past +-180 deg: compare with the value turned next to it
        value = (value - 0.5 * (lo + hi) + 180.0) % 360.0 - 180.0 + 0.5 * (lo + hi)
    return lo <= value <= hi


def judge_relative(result: CalibrationResult, key: str, T_true_to_from: np.ndarray) -> bool:
    """Whether the true ``T_to_from`` of ``result.relative[key]`` lies inside its reported 95 %
    region: the 6-DOF error under the relative covariance; where the sensors' bounded
    directions enter, the part of the error they cannot explain (the directions profiled out
    in the covariance's metric: 6 - k dof; for the sensor itself this is :func:`judge_sensor`'s
    test of its free directions) and each bounded quantity inside its interval."""
    from rigcal.geometry.so3 import rpy_from_matrix
    from rigcal.problem.uncertainty import TABLE_KEYS

    from rigcal.problem.uncertainty import BOUNDED_RADAR_DIRECTIONS

    rel = result.relative[key]
    xi = se3_log(invert(rel.T_to_from) @ T_true_to_from)
    W = np.linalg.pinv(rel.covariance, rcond=1e-12, hermitian=True)
    moves = []
    T_rel = rel.T_to_from
    for name, sign in ((rel.to, -1.0), (rel.frm, 1.0)):
        dirs = list(result.sensors[name].bounded)
        if not dirs:
            continue
        # the bounded directions themselves (as judge_sensor leaves them out): what they move
        # besides (the in-plane pose following a tilt) is in the covariance and stays judged
        M = np.eye(6)[:, [BOUNDED_RADAR_DIRECTIONS[d] for d in dirs]]
        moves.append(M if sign > 0 else -adjoint(invert(T_rel)) @ M)
    d2 = float(xi @ W @ xi)
    dof = 6
    if moves:
        M = np.hstack(moves)
        g = M.T @ W @ xi
        H = M.T @ W @ M
        d2 -= float(g @ np.linalg.pinv(H, rcond=1e-9, hermitian=True) @ g)
        dof -= int(np.linalg.matrix_rank(M, tol=1e-9))
    ok = dof <= 0 or d2 <= (CHI2_95[dof] if dof in CHI2_95 else _chi2_95(dof))
    truth = np.concatenate([T_true_to_from[:3, 3], np.degrees(rpy_from_matrix(T_true_to_from[:3, :3]))])
    for q, (lo, hi, _) in rel.bounded.items():
        k = TABLE_KEYS.index(q)
        ok &= _wrapped_inside(float(truth[k]), lo, hi, k >= 3)
    return bool(ok)


def _chi2_95(dof: int) -> float:
    from rigcal.problem.numerics import chi2_isf

    return float(chi2_isf(0.05, dof))


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
    priors: PriorSpec | None = None,
) -> dict[str, dict]:
    """Coverage of the reported 95 % regions per mode over ``trials`` simulated rigs (with
    ``priors``: mounting priors around nominal poses drawn with those tolerances).

    Returns ``{mode: {"position": fraction, "pose": fraction, "relative": fraction,
    "sensors": n, "relatives": n, "runs": n, "failures": n, "flagged": n, "by_kind": {...}}}``.
    A run that raises counts as a failure (no sensors); ``flagged``: runs the consistency check
    flagged (the data are clean).
    """
    from rigcal.problem.calibrate import CalibrationOptions, calibrate

    tallies = {m: CoverageTally() for m in modes}
    for t in range(trials):
        rng = np.random.default_rng([seed, t])
        sensors = _with_noise(random_rig(rng, n_lidar, n_camera, n_radar), noise)
        T_rig_board = make_rig_placements(rng, sensors, boards)
        sim = simulate(sensors, T_rig_board, rng=rng)
        extra = dict(calibrate_options or {})
        if priors is not None:
            ref0 = sensors[0].name
            tol = {s.name: priors.for_kind(s.kind) for s in sensors[1:] if priors.for_kind(s.kind)}
            truth = {s.name: sim.truth_T(ref0, s.name) for s in sensors}
            extra.update(initial=nominal_poses(rng, truth, ref0, tol), priors=tol)
        for mode in modes:
            tally = tallies[mode]
            tally.runs += 1
            try:
                result = calibrate(
                    sim.dataset,
                    CalibrationOptions(mode=mode, **extra),
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
            for key, rel in result.relative.items():
                if ref in (rel.to, rel.frm):
                    continue  # the sensor's own pose, judged above
                tally.relatives += 1
                tally.relative_inside += int(judge_relative(result, key, sim.truth_T(rel.to, rel.frm)))
        if progress is not None:
            progress(t + 1, trials)
    return {m: t.fractions() for m, t in tallies.items()}


__all__ = ["CHI2_95", "CoverageTally", "NoiseSpec", "PriorSpec", "board_coverage", "judge_relative", "judge_sensor",
           "nominal_poses"]
