"""Does the motion-capture calibration's reported uncertainty hold the truth as often as it says?

:func:`mocap_coverage` runs seeded simulated sessions of :func:`rigcal.sim.mocap.paper_rig` (a
VLP-16 looking forward, a camera looking left, no shared view) with a checkerboard diamond held
still ``holds`` times in each sensor's view, ``frames_per_hold`` frames per hold. The target
poses come from the raw simulator's placement (:func:`rigcal.sim.mocap.sample_target_pose`);
the measurements are drawn directly (no ray casting or rendering, so a trial takes a fraction
of a second) with the errors a real session has:

* every frame: independent noise on the lidar's diamond corners [m] and the camera's corner
  pixels [px], each sensor with its own level drawn per trial (lidar 2-8 mm, camera
  0.3-3 px) while the calibration is told 10 mm and 1 px (so one shared noise scale is wrong);
* every hold: an MCS error of the still target's pose (1 mm and 2 mrad std, as a 0.5 m marker
  baseline with 1 mm marker noise gives) and, for the lidar, a bias of each corner (2 mm std)
  - shared by every frame of the hold, so the frames are not independent.

The calibration (:func:`rigcal.problem.mocap.calibrate_mocap_fit`, default options) starts
from the truth perturbed by 2 cm / 2 deg. A sensor's truth is inside its reported 95 % region
when ``e' C^-1 e <= chi2_6(0.95) = 12.59`` for the right-perturbation error
``e = log(T_est^-1 T_true)`` and the reported covariance ``C``; the translation-only check
uses the translation part of ``e`` and ``C`` with ``chi2_3(0.95) = 7.81``. The same checks on
the naive covariance (one noise scale for all sensors, every frame independent) are reported
next to them.
"""

from __future__ import annotations

import math
import time

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError, RigcalError
from rigcal.geometry.se3 import from_rt, invert, se3_exp, se3_log
from rigcal.geometry.so3 import matrix_from_rpy

__all__ = ["CHI2_95_3", "CHI2_95_6", "mocap_coverage"]

#: chi-square quantiles at 0.95 for 6 and 3 degrees of freedom
CHI2_95_6 = 12.591587243743977
CHI2_95_3 = 7.814727903251178

_MCS_TRANSLATION_M = 0.001
_MCS_ROTATION_RAD = 0.002
_LIDAR_BIAS_M = 0.002
_LIDAR_NOISE_M = (0.002, 0.008)
_CAMERA_NOISE_PX = (0.3, 3.0)


def _inside(T_est: np.ndarray, T_true: np.ndarray, cov: np.ndarray) -> tuple[bool, bool]:
    e = se3_log(invert(T_est) @ T_true)
    try:
        d6 = float(e @ np.linalg.solve(cov, e))
        d3 = float(e[3:] @ np.linalg.solve(cov[3:, 3:], e[3:]))
    except np.linalg.LinAlgError:
        return False, False
    return d6 <= CHI2_95_6, d3 <= CHI2_95_3


def _trial(rng: np.random.Generator, holds: int, frames: int):
    from rigcal.problem.mocap import MocapSensor, TargetObservation, calibrate_mocap_fit
    from rigcal.sim.mocap import CAMERA, LIDAR, Placement, paper_rig, sample_target_pose
    from rigcal.targets.templates import diamond_target

    rig = paper_rig()
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    sigma_l = rng.uniform(*_LIDAR_NOISE_M)
    sigma_c = rng.uniform(*_CAMERA_NOISE_PX)
    placement = Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0)
    obs = []
    truth = {"lidar": rig.T_robot_lidar, "camera": rig.T_robot_camera}
    t = 0
    for kind, name in ((LIDAR, "lidar"), (CAMERA, "camera")):
        T_rs = truth[name]
        for h in range(holds):
            yaw = rng.uniform(-math.pi, math.pi)
            T_mr = from_rt(matrix_from_rpy(np.array([0.0, 0.0, yaw])), [*rng.uniform(-2, 2, 2), 0.0])
            T_mt = sample_target_pose(rig, kind, target, T_mr, rng, placement)
            T_rt = invert(T_mr) @ T_mt
            xi = np.concatenate([rng.normal(0, _MCS_ROTATION_RAD, 3), rng.normal(0, _MCS_TRANSLATION_M, 3)])
            T_rt_mcs = T_rt @ se3_exp(xi)
            T_st = invert(T_rs) @ T_rt
            if kind == LIDAR:
                kp = target.lidar_keypoints
                bias = rng.normal(0, _LIDAR_BIAS_M, kp.shape)
                base = kp @ T_st[:3, :3].T + T_st[:3, 3] + bias
            else:
                kp = target.camera_keypoints
                base, _ = rig.camera.project(kp @ T_st[:3, :3].T + T_st[:3, 3])
            for _ in range(frames):
                t += 250_000_000
                noise = rng.normal(0, sigma_l if kind == LIDAR else sigma_c, base.shape)
                obs.append(TargetObservation(name, "diamond", t, T_rt_mcs, base + noise, kp, hold=str(h)))
    sensors = [MocapSensor("lidar", SensorKind.LIDAR, sigma=0.01),
               MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)]
    initial = {}
    for name, T in truth.items():
        d = rng.normal(size=6)
        d[:3] *= math.radians(2.0) / np.linalg.norm(d[:3])
        d[3:] *= 0.02 / np.linalg.norm(d[3:])
        initial[name] = T @ se3_exp(d)
    fit = calibrate_mocap_fit(sensors, obs, initial)
    out = {}
    for name in truth:
        est = fit.result.sensors[name]
        out[name] = (_inside(est.T_reference_sensor, truth[name], est.covariance),
                     _inside(est.T_reference_sensor, truth[name], fit.sensors[name].covariance_naive),
                     fit.sensors[name].noise_sigma, sigma_l if name == "lidar" else sigma_c)
    return out


def mocap_coverage(trials: int = 50, seed: int = 0, *, holds: int = 4, frames_per_hold: int = 5) -> dict:
    """Fractions of ``trials`` seeded simulated sessions (see the module docstring) whose true
    ``T_robot_sensor`` lies inside the reported 95 % region, over both sensors.

    Returns a dict: ``trials``, ``seed``, ``holds``, ``frames_per_hold``, ``checks`` (sensor
    estimates checked), ``failed`` (trials whose calibration raised), ``inside_6dof`` and
    ``inside_3dof_translation`` (the reported covariance), ``naive_inside_6dof`` and
    ``naive_inside_3dof_translation`` (one shared noise scale, independent frames),
    ``per_sensor`` (``{"lidar"|"camera": {those four fractions, "noise_ratio_median": the
    estimated over the true noise sigma}}``), ``thresholds`` and ``time_s``. Each trial draws
    from ``numpy.random.default_rng([seed, trial])``, so a seed reproduces the numbers.
    """
    for what, v, lo in (("trials", trials, 1), ("holds", holds, 2), ("frames_per_hold", frames_per_hold, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise InputError(f"mocap_coverage: {what} must be an integer >= {lo}, got {v!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"mocap_coverage: seed must be an integer >= 0, got {seed!r}")
    t0 = time.perf_counter()
    per: dict[str, list] = {"lidar": [], "camera": []}
    failed = 0
    for k in range(int(trials)):
        rng = np.random.default_rng([int(seed), k])
        try:
            res = _trial(rng, int(holds), int(frames_per_hold))
        except RigcalError:
            failed += 1
            continue
        for name, v in res.items():
            per[name].append(v)

    def frac(rows, i, j):
        return float(np.mean([r[i][j] for r in rows])) if rows else float("nan")

    every = per["lidar"] + per["camera"]
    return {
        "trials": int(trials),
        "seed": int(seed),
        "holds": int(holds),
        "frames_per_hold": int(frames_per_hold),
        "checks": len(every),
        "failed": failed,
        "inside_6dof": frac(every, 0, 0),
        "inside_3dof_translation": frac(every, 0, 1),
        "naive_inside_6dof": frac(every, 1, 0),
        "naive_inside_3dof_translation": frac(every, 1, 1),
        "per_sensor": {
            name: {
                "inside_6dof": frac(rows, 0, 0),
                "inside_3dof_translation": frac(rows, 0, 1),
                "naive_inside_6dof": frac(rows, 1, 0),
                "naive_inside_3dof_translation": frac(rows, 1, 1),
                "noise_ratio_median": float(np.median([r[2] / r[3] for r in rows])) if rows else float("nan"),
            }
            for name, rows in per.items()
        },
        "thresholds": {"chi2_6dof_95": CHI2_95_6, "chi2_3dof_95": CHI2_95_3},
        "time_s": time.perf_counter() - t0,
    }
