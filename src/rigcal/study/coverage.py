"""Does the motion-capture calibration's reported uncertainty hold the truth as often as it says?

:func:`mocap_coverage` runs seeded simulated sessions of :func:`rigcal.sim.mocap.paper_rig` (a
VLP-16 looking forward, a camera looking left, no shared view) with a checkerboard diamond held
still ``holds`` times in each sensor's view, ``frames_per_hold`` frames per hold (4 Hz). The
target poses come from the raw simulator's placement
(:func:`rigcal.sim.mocap.sample_target_pose`); the measurements are drawn directly (no ray
casting or rendering, so a trial takes a fraction of a second) under one of the
:data:`ERROR_MODELS` - errors that come from other models than the calibration's own:

* ``pixel``: every point on its own - the lidar's diamond corners 2-8 mm, the camera's corner
  pixels 0.3-3 px per trial, while the calibration is told 10 mm and 1 px;
* ``hold_bias``: those, plus one MCS error of the still target per hold (1 mm / 2 mrad, a
  0.5 m marker baseline with 1 mm marker noise) and, for the lidar, a bias of each corner per
  hold (2 mm): shared by every frame of the hold;
* ``mcs_capture``: the MCS's noise per capture - robot and target each 0.15 mm / 0.3 mrad
  (about a Vicon's), independent at every frame - over small sensor noise (lidar 2 mm,
  camera 0.3 px); the calibration gets each capture's MCS covariance as the pipeline does
  (the streams' own scatter);
* ``lidar_range``: the lidar measures every point on the plate (the pipeline's default) - one
  revolution of the VLP-16 ray-cast at each capture, a random firing phase per revolution -
  with a range noise of 10-20 mm along each ray (told 10 mm), and where each of its rings
  leaves the plate (:func:`rigcal.extract.lidar.ring_edge_rays`); the camera 0.3-3 px;
* ``timing_jitter``: the robot drives at 2-8 cm/s in a random direction during half of the
  holds, and every frame's stamp is off its capture time by 5 ms (std); sensor noise as in
  ``mcs_capture``;
* ``clock_offset``: the same driving, and each sensor's stamps 20-100 ms late on the MCS's
  clock (a constant per sensor, estimated by the calibration);
* ``mixed``: all of it at once (lidar points with range noise, per-hold and per-capture MCS
  errors, jitter and a clock offset).

The calibration (:func:`rigcal.problem.mocap.calibrate_mocap_fit`, default options) starts
from the truth perturbed by 2 cm / 2 deg. A sensor's truth is inside its reported 95 % region
when ``e' C^-1 e <= chi2_6(0.95) = 12.59`` for the right-perturbation error
``e = log(T_est^-1 T_true)`` and the reported covariance ``C``; the translation-only check
uses the translation part of ``e`` and ``C`` with ``chi2_3(0.95) = 7.81``. ``e' C^-1 e / 6``
(NEES per degree of freedom; its median is 0.89 when ``C`` is right) tells a too wide region
from a right one. A run whose clock offset mattered but could not be determined is flagged
(``MocapSensorFit.time_offset_status``), as ``rigcal mocap`` would; flagged estimates are
counted, and their covariance must hold the truth too (they are in the fractions).
"""

from __future__ import annotations

import math
import time

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError, RigcalError
from rigcal.geometry.se3 import from_rt, invert, se3_exp, se3_log
from rigcal.geometry.so3 import matrix_from_rpy

__all__ = ["CHI2_95_3", "CHI2_95_6", "ERROR_MODELS", "mocap_coverage", "nees", "pool_mocap", "wilson"]

#: chi-square quantiles at 0.95 for 6 and 3 degrees of freedom
CHI2_95_6 = 12.591587243743977
CHI2_95_3 = 7.814727903251178

#: the error models :func:`mocap_coverage` draws sessions from (see the module docstring)
ERROR_MODELS = ("pixel", "hold_bias", "mcs_capture", "lidar_range", "timing_jitter", "clock_offset", "mixed")
#: the estimator of a ``--mocap-json`` file without the field: written before the estimator was
#: chosen, by least squares, then the only one
_UNNAMED_ESTIMATOR = "ls"

_MCS_TRANSLATION_M = 0.001
_MCS_ROTATION_RAD = 0.002
_LIDAR_BIAS_M = 0.002
_LIDAR_NOISE_M = (0.002, 0.008)
_CAMERA_NOISE_PX = (0.3, 3.0)
_CAPTURE_M = 0.00015
_CAPTURE_RAD = 0.0003
_RANGE_NOISE_M = (0.010, 0.020)
_JITTER_S = 0.005
_OFFSET_S = (0.020, 0.100)
_SPEED_MPS = (0.02, 0.08)
_FRAME_S = 0.25
#: the paper rig's VLP-16: 2 deg between its rings
_VERTICAL_STEP_RAD = math.radians(2.0)


def nees(T_est: np.ndarray, T_true: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """The normalised estimation error squared of ``T_est`` (the truth ``T_true``) under ``cov``
    (6, 6) over the right perturbation ``log(T_est^-1 T_true)``: over all 6 DOF and over the
    translation alone; ``inf`` when ``cov`` is singular."""
    e = se3_log(invert(T_est) @ T_true)
    try:
        d6 = float(e @ np.linalg.solve(cov, e))
        d3 = float(e[3:] @ np.linalg.solve(cov[3:, 3:], e[3:]))
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    return d6, d3


def _flags(model: str) -> dict[str, bool]:
    mixed = model == "mixed"
    return {
        "hold": model == "hold_bias" or mixed,
        "capture": model in ("mcs_capture", "timing_jitter", "clock_offset") or mixed,
        "surface": model == "lidar_range" or mixed,
        "drive": model in ("timing_jitter", "clock_offset") or mixed,
        "jitter": model == "timing_jitter" or mixed,
        "offset": model == "clock_offset" or mixed,
        "small": model in ("mcs_capture", "timing_jitter", "clock_offset"),
    }


def _capture_cov(T_rt: np.ndarray) -> np.ndarray:
    """Covariance of ``T_robot_target``'s right perturbation when robot and target each have
    the per-capture MCS noise."""
    from rigcal.geometry.se3 import adjoint

    D = np.diag([_CAPTURE_RAD ** 2] * 3 + [_CAPTURE_M ** 2] * 3)
    Ad = adjoint(invert(T_rt))
    return D + Ad @ D @ Ad.T


def _body_noise(rng: np.random.Generator) -> np.ndarray:
    return se3_exp(np.concatenate([rng.normal(0, _CAPTURE_RAD, 3), rng.normal(0, _CAPTURE_M, 3)]))


def _trial(rng: np.random.Generator, holds: int, frames: int, model: str, options=None):
    from rigcal.problem import mocap as _m
    from rigcal.problem.mocap import MocapSensor, TargetObservation
    calibrate_mocap_fit = _m.calibrate_mocap_fit
    from rigcal.extract.lidar import ring_edge_rays
    from rigcal.sim.mocap import CAMERA, LIDAR, SURFACE_TARGET, Placement, cast_lidar, paper_rig, sample_target_pose
    from rigcal.targets.surface import TargetSurface
    from rigcal.targets.templates import diamond_target

    fl = _flags(model)
    rig = paper_rig()
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    if fl["small"]:
        sigma_l, sigma_c = 0.002, 0.3
    else:
        sigma_l, sigma_c = rng.uniform(*_LIDAR_NOISE_M), rng.uniform(*_CAMERA_NOISE_PX)
    if fl["surface"]:
        sigma_l = rng.uniform(*_RANGE_NOISE_M)
    placement = Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0)
    truth = {"lidar": rig.T_robot_lidar, "camera": rig.T_robot_camera}
    offset = {n: (rng.uniform(*_OFFSET_S) if fl["offset"] else 0.0) for n in truth}
    obs = []
    t0 = 0.0
    for kind, name in ((LIDAR, "lidar"), (CAMERA, "camera")):
        T_rs = truth[name]
        for h in range(holds):
            yaw = rng.uniform(-math.pi, math.pi)
            T_mr0 = from_rt(matrix_from_rpy(np.array([0.0, 0.0, yaw])), [*rng.uniform(-2, 2, 2), 0.0])
            T_mt = sample_target_pose(rig, kind, target, T_mr0, rng, placement)
            v = np.zeros(3)
            if fl["drive"] and rng.uniform() < 0.5:
                a = rng.uniform(-math.pi, math.pi)
                v = rng.uniform(*_SPEED_MPS) * np.array([math.cos(a), math.sin(a), 0.0])

            def T_mr(t: float) -> np.ndarray:
                return T_mr0 @ from_rt(np.eye(3), v * (t - t0))

            hold_err = np.eye(4)
            if fl["hold"]:
                hold_err = se3_exp(np.concatenate([rng.normal(0, _MCS_ROTATION_RAD, 3),
                                                   rng.normal(0, _MCS_TRANSLATION_M, 3)]))
            if kind == LIDAR:
                kp = None if fl["surface"] else target.lidar_keypoints
                bias = rng.normal(0, _LIDAR_BIAS_M, (4, 3)) if fl["hold"] and not fl["surface"] else 0.0
            else:
                kp = target.camera_keypoints
            for k in range(frames):
                t_cap = t0 + k * _FRAME_S
                stamp = t_cap + offset[name] + (rng.normal(0, _JITTER_S) if fl["jitter"] else 0.0)
                T_st = invert(T_rs) @ invert(T_mr(t_cap)) @ T_mt  # what the sensor saw
                # what the MCS says at the frame's stamp
                T_mr_mcs, T_mt_mcs = T_mr(stamp), T_mt
                if fl["capture"]:
                    T_mr_mcs, T_mt_mcs = T_mr_mcs @ _body_noise(rng), T_mt_mcs @ _body_noise(rng)
                T_rt_mcs = invert(T_mr_mcs) @ T_mt_mcs @ hold_err
                h_s = 1e-3
                vel = None
                if fl["drive"]:
                    T_a = invert(T_mr(stamp)) @ T_mt
                    T_b = invert(T_mr(stamp + h_s)) @ T_mt
                    vel = se3_log(invert(T_a) @ T_b) / h_s
                pose_cov = _capture_cov(T_rt_mcs) if fl["capture"] else None
                edge_rays = None
                if kind == LIDAR and kp is None:
                    # one revolution of the VLP-16 at the capture, every return from the plate
                    # with range noise along its ray, and where each ring leaves the plate
                    cloud = cast_lidar(rig.lidar, T_mr(t_cap) @ T_rs, target, T_mt, (), rng,
                                       range_sigma_m=sigma_l)
                    meas = cloud.points_xyz[cloud.fields["surface"] == SURFACE_TARGET]
                    edge_rays = ring_edge_rays(meas, _VERTICAL_STEP_RAD, math.radians(rig.lidar.azimuth_step_deg))
                elif kind == LIDAR:
                    meas = kp @ T_st[:3, :3].T + T_st[:3, 3] + bias + rng.normal(0, sigma_l, (4, 3))
                else:
                    uv, _ = rig.camera.project(kp @ T_st[:3, :3].T + T_st[:3, 3])
                    meas = uv + rng.normal(0, sigma_c, uv.shape)
                obs.append(TargetObservation(name, "diamond", int(round(stamp * 1e9)), T_rt_mcs, meas, kp,
                                             hold=str(h), velocity=vel, pose_cov=pose_cov, edge_rays=edge_rays))
            t0 += frames * _FRAME_S + 2.0
    sensors = [MocapSensor("lidar", SensorKind.LIDAR, sigma=0.01),
               MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)]
    initial = {}
    for name, T in truth.items():
        d = rng.normal(size=6)
        d[:3] *= math.radians(2.0) / np.linalg.norm(d[:3])
        d[3:] *= 0.02 / np.linalg.norm(d[3:])
        initial[name] = T @ se3_exp(d)
    templates = {"diamond": TargetSurface.of(target)} if fl["surface"] else None
    fit = calibrate_mocap_fit(sensors, obs, initial, templates, options or _m.MocapOptions())
    out = {}
    for name in truth:
        est = fit.result.sensors[name]
        f = fit.sensors[name]
        status = f.time_offset_status
        # the estimated offset is "stamps minus capture time": the stamps were late by offset
        off_err = abs(f.time_offset_s - offset[name]) if math.isfinite(f.time_offset_s) else math.nan
        out[name] = {
            "nees": nees(est.T_reference_sensor, truth[name], est.covariance),
            "naive": nees(est.T_reference_sensor, truth[name], f.covariance_naive),
            "noise_ratio": f.noise_sigma / (sigma_l if name == "lidar" else sigma_c),
            "flagged": status == "undetermined",
            "offset_status": status,
            "offset_error_s": off_err,
            "offset_std_s": f.time_offset_std_s,
            "pooled": bool(f.hold_pooled),
            "error_m": float(np.linalg.norm(est.T_reference_sensor[:3, 3] - truth[name][:3, 3])),
        }
    return out


def mocap_coverage(trials: int = 50, seed: int = 0, *, holds: int = 4, frames_per_hold: int = 5,
                   error_model: str = "hold_bias", hold_sigma_floor: tuple[float, float] = (0.0, 0.0),
                   estimator: str | None = None) -> dict:
    """Fractions of ``trials`` seeded simulated sessions (see the module docstring) whose true
    ``T_robot_sensor`` lies inside the reported 95 % region, per sensor and over both, under
    ``error_model`` (one of :data:`ERROR_MODELS`).

    Returns a dict: ``trials``, ``seed``, ``holds``, ``frames_per_hold``, ``error_model``,
    ``checks`` (sensor estimates checked), ``failed`` (trials whose calibration raised) and
    ``failures`` (each one's trial index and error), ``hold_sigma_floor`` (rotation [rad],
    translation [m]: the calibration's ``MocapOptions.hold_sigma_floor``, the MCS's per-hold
    accuracy as a user would state it; default none),
    ``flagged`` (estimates whose clock offset mattered but was not determined: counted in the
    fractions all the same, a region must hold the truth flagged or not),
    ``inside_6dof`` and ``inside_3dof_translation`` (the reported covariance), ``nees_median``
    (median of ``e' C^-1 e / 6``), ``naive_inside_6dof`` and ``naive_inside_3dof_translation``
    (one shared noise scale, independent frames), ``per_sensor`` (``{"lidar"|"camera": {those
    fractions, "nees_median", "noise_ratio_median": the estimated over the true noise sigma,
    "offset_error_max_s": the largest error of a determined clock offset, "offsets_determined":
    how many were, "nees_6dof": every estimate's ``e' C^-1 e``, to pool seeds, "nees_3dof":
    its translation part's, "pooled": how many took the MCS's per-hold error pooled over the
    sensors, "pooled_inside_6dof": how many of those hold the truth, "pooled_6dof": which did,
    in the order of "nees_6dof", "errors_m": every estimate's translation error [m] in that
    order, "error_median_m": their median}}``), ``estimator`` (the ``MocapOptions.estimator``
    used, "ls" or "gls": the ``estimator`` argument, or the options' default when it is None),
    ``thresholds``
    and ``time_s``. Each trial draws from ``numpy.random.default_rng([seed, trial])``, so a
    seed reproduces the numbers.
    """
    for what, v, lo in (("trials", trials, 1), ("holds", holds, 2), ("frames_per_hold", frames_per_hold, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise InputError(f"mocap_coverage: {what} must be an integer >= {lo}, got {v!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"mocap_coverage: seed must be an integer >= 0, got {seed!r}")
    if error_model not in ERROR_MODELS:
        raise InputError(f"mocap_coverage: error_model must be one of {', '.join(ERROR_MODELS)}, got {error_model!r}")
    from rigcal.problem.mocap import MocapOptions

    options = MocapOptions(hold_sigma_floor=hold_sigma_floor,  # checks them (ConfigError)
                           estimator=MocapOptions.estimator if estimator is None else estimator)
    t0 = time.perf_counter()
    per: dict[str, list] = {"lidar": [], "camera": []}
    failed, failures = 0, []
    for k in range(int(trials)):
        rng = np.random.default_rng([int(seed), k])
        try:
            res = _trial(rng, int(holds), int(frames_per_hold), error_model, options)
        except RigcalError as exc:
            failed += 1
            failures.append((k, str(exc)))
            continue
        for name, v in res.items():
            per[name].append(v)

    def summary(rows: list) -> dict:
        ok = rows  # flagged estimates too: their covariance must hold the truth as well

        def frac(key: str, i: int, limit: float) -> float:
            return float(np.mean([r[key][i] <= limit for r in ok])) if ok else float("nan")

        offs = [r["offset_error_s"] for r in ok if r["offset_status"] == "determined"]
        return {
            "checks": len(ok),
            "flagged": sum(1 for r in rows if r["flagged"]),
            "inside_6dof": frac("nees", 0, CHI2_95_6),
            "inside_3dof_translation": frac("nees", 1, CHI2_95_3),
            "nees_median": float(np.median([r["nees"][0] / 6 for r in ok])) if ok else float("nan"),
            "naive_inside_6dof": frac("naive", 0, CHI2_95_6),
            "naive_inside_3dof_translation": frac("naive", 1, CHI2_95_3),
            "noise_ratio_median": float(np.median([r["noise_ratio"] for r in ok])) if ok else float("nan"),
            "offset_error_max_s": float(max(offs)) if offs else float("nan"),
            "offsets_determined": len(offs),
            "nees_6dof": [float(r["nees"][0]) for r in ok],
            "nees_3dof": [float(r["nees"][1]) for r in ok],
            # the estimates that took the MCS's per-hold value pooled over the sensors, and how
            # many of them hold the truth (the pooled value is right only if they share it)
            "pooled": sum(1 for r in ok if r["pooled"]),
            "pooled_inside_6dof": sum(1 for r in ok if r["pooled"] and r["nees"][0] <= CHI2_95_6),
            "pooled_6dof": [bool(r["pooled"]) for r in ok],
            "error_median_m": float(np.median([r["error_m"] for r in ok])) if ok else float("nan"),
            "errors_m": [float(r["error_m"]) for r in ok],
        }

    every = summary(per["lidar"] + per["camera"])
    return {
        "trials": int(trials),
        "seed": int(seed),
        "holds": int(holds),
        "frames_per_hold": int(frames_per_hold),
        "error_model": error_model,
        "hold_sigma_floor": options.hold_sigma_floor,
        "estimator": options.estimator,
        "failed": failed,
        "failures": failures,
        **{k: every[k] for k in ("checks", "flagged", "inside_6dof", "inside_3dof_translation", "nees_median",
                                 "naive_inside_6dof", "naive_inside_3dof_translation")},
        "per_sensor": {name: summary(rows) for name, rows in per.items()},
        "thresholds": {"chi2_6dof_95": CHI2_95_6, "chi2_3dof_95": CHI2_95_3},
        "time_s": time.perf_counter() - t0,
    }


def wilson(k: int, n: int) -> tuple[float, float]:
    """The 95 % Wilson interval of a fraction ``k`` of ``n`` (what a sample of ``n`` can tell of
    the probability; (0, 1) for ``n = 0``)."""
    if n <= 0:
        return 0.0, 1.0
    z = 1.959963984540054
    mid = (k + z * z / 2) / (n + z * z)
    half = z * math.sqrt(k * (n - k) / n + z * z / 4) / (n + z * z)
    return max(mid - half, 0.0), min(mid + half, 1.0)


def _check_dump(name: str, data) -> None:
    """``data`` is what ``--mocap-json`` writes, else an :class:`InputError` naming ``name`` and
    the field."""
    if not isinstance(data, dict) or not isinstance(data.get("nees_6dof"), dict):
        raise InputError(f"{name}: not a --mocap-json file (no 'nees_6dof' mapping)")
    for key in ("seed", "holds"):
        if isinstance(data.get(key), bool) or not isinstance(data.get(key), int):
            raise InputError(f"{name}: '{key}' must be an integer, got {data.get(key)!r}")
    floor = data.get("hold_sigma_floor", [0.0, 0.0])
    if (not isinstance(floor, list) or len(floor) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in floor)):
        raise InputError(f"{name}: 'hold_sigma_floor' must be [rotation_rad, translation_m], got {floor!r}")
    from rigcal.problem.mocap import ESTIMATORS

    if data.get("estimator", _UNNAMED_ESTIMATOR) not in ESTIMATORS:
        raise InputError(f"{name}: 'estimator' must be one of {', '.join(ESTIMATORS)}, got {data.get('estimator')!r}")
    for field in ("nees_6dof", "nees_3dof", "errors_m"):
        by_model = data.get(field, {})
        if not isinstance(by_model, dict):
            raise InputError(f"{name}: '{field}' must map error models to sensor kinds")
        for model, kinds in by_model.items():
            if model not in ERROR_MODELS:
                raise InputError(f"{name}: '{field}' has {model!r}, not one of {', '.join(ERROR_MODELS)}")
            if not isinstance(kinds, dict) or not all(
                    isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                    for v in kinds.values()):
                raise InputError(f"{name}: '{field}.{model}' must map each sensor kind to a list of numbers")


def pool_mocap(dumps) -> dict:
    """The coverage over several runs of the benchmark, pooled: ``dumps`` a sequence of
    ``(name, data)`` with ``data`` what ``benchmarks/coverage.py --mocap-json`` wrote
    (``seed``, ``holds``, ``nees_6dof`` and optionally ``nees_3dof`` and ``hold_sigma_floor``).
    Two runs of one error model and seed draw the same first sessions (trial ``k`` of seed ``s``
    is ``default_rng([s, k])``) and runs of other holds or floors other sessions: both refused
    (:class:`InputError` naming the files). Returns ``{"holds", "seeds", "models": {model:
    {kind: {"checks", "inside_6dof" (count), "interval" (Wilson), "checks_3dof" (the estimates
    of the runs that wrote ``nees_3dof``), "inside_3dof_translation" (count of those),
    "nees_median" (per DOF), "nees_median_by_run" (each run's, in the order given),
    "checks_error" (the estimates of the runs that wrote ``errors_m``), "error_median_m" (their
    median translation error)}}}, "estimator"}``: runs of different estimators are refused too (a
    file without ``estimator`` was written by least squares)."""
    dumps = list(dumps)
    if not dumps:
        raise InputError("pool: no runs to pool")
    holds, floors, seeds, estimators = {}, {}, {}, {}
    for name, data in dumps:
        _check_dump(name, data)
        estimators[name] = data.get("estimator", _UNNAMED_ESTIMATOR)
        for model in data["nees_6dof"]:
            other = seeds.get((model, data["seed"]))
            if other is not None:
                raise InputError(f"{name} and {other} both ran {model!r} with seed {data['seed']}: "
                                 "their first sessions are the same ones; pool runs of different seeds")
            seeds[(model, data["seed"])] = name
        holds[name] = data["holds"]
        if "hold_sigma_floor" in data:
            floors[name] = tuple(data["hold_sigma_floor"])
    for what, by in (("holds", holds), ("hold_sigma_floor", floors), ("estimator", estimators)):
        if len(set(by.values())) > 1:
            raise InputError("pool: runs of different " + what + ": "
                             + ", ".join(f"{n} {v}" for n, v in by.items()))
    models: dict = {}
    for model in ERROR_MODELS:
        for kind in ("lidar", "camera"):
            six, three, medians, errors = [], [], [], []
            for name, data in dumps:
                v6 = data["nees_6dof"].get(model, {}).get(kind)
                if not v6:
                    continue
                v3 = (data.get("nees_3dof") or {}).get(model, {}).get(kind)
                if v3 is not None and len(v3) == len(v6):
                    three += [float(x) for x in v3]
                ve = (data.get("errors_m") or {}).get(model, {}).get(kind)
                if ve is not None and len(ve) == len(v6):
                    errors += [float(x) for x in ve]
                six += [float(x) for x in v6]
                medians.append(float(np.median(v6)) / 6)
            if not six:
                continue
            k = sum(1 for x in six if x <= CHI2_95_6)
            models.setdefault(model, {})[kind] = {
                "checks": len(six),
                "inside_6dof": k,
                "interval": wilson(k, len(six)),
                "checks_3dof": len(three),
                "inside_3dof_translation": sum(1 for x in three if x <= CHI2_95_3),
                "nees_median": float(np.median(six)) / 6,
                "nees_median_by_run": medians,
                "checks_error": len(errors),
                "error_median_m": float(np.median(errors)) if errors else float("nan"),
            }
    return {"holds": next(iter(holds.values())), "seeds": sorted({s for _, s in seeds}),
            "estimator": next(iter(estimators.values())), "models": models}
