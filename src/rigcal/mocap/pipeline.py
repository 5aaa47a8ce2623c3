"""The motion-capture calibration pipeline: recording + MCS poses -> ``T_robot_sensor``.

Charron et al., section III, end to end:

1. read the MCS pose streams: the robot ``T_M_R`` and every target ``T_M_T``
   (:mod:`rigcal.mocap.streams`), and the initial extrinsics ``T_robot_sensor``
   (``robot_frame`` <- the sensor's ``frame_id``, :mod:`rigcal.mocap.extrinsics`);
2. step through the recording's sensor frames in time order; for every frame and target:

   * **pose**: ``T_M_R`` and ``T_M_T`` interpolated at the frame's stamp; a time before, after
     or inside a gap of a stream (longer than ``max_gap_s``) is rejected as ``no_pose_data``;
   * **guidance** (III-C): the expected pose ``T_sensor_target = inv(T_robot_sensor_initial)
     @ inv(T_M_R) @ T_M_T``; rejected as ``target_not_in_view`` when the target is not
     expected in the sensor's view, then as ``target_moving`` when the target moves relative to
     the robot faster than the limits within the motion window (or ``no_pose_data`` when the
     streams do not cover that window);
   * **extraction**: the camera extractor (checkerboard corners, or the coloured silhouette)
     or the lidar extractor (crop, cluster, ICP) of :mod:`rigcal.extract`, searching around the
     expected pose; failures keep the extractor's reason code;
   * a kept measurement becomes a :class:`~rigcal.problem.mocap.TargetObservation`: with known
     correspondences when the extractor orders its keypoints (``keypoint_index``: checkerboard
     corners, diamond corners), template-based otherwise (cylinder);

3. :func:`~rigcal.problem.mocap.calibrate_mocap` from the initial extrinsics;
4. per kept measurement, the residual under the initial and the final calibration: the RMS
   distance [m] (lidar) or reprojection error [px] (camera) between the measured keypoints and
   their target keypoints placed by the MCS; without correspondences, a lidar point's distance
   to the target's surface and a pixel's to the nearest projected template point.

A sensor without any kept measurement (a target it never sees, a mocap dropout over all its
holds) or whose measurements leave its pose undetermined is *not calibrated*: the others are
calibrated without it and it is reported with its reason (``MocapRun.not_calibrated``,
``CalibrationResult.not_calibrated``); only when no sensor is left is it an error, listing every
reason. A target no sensor measured is an InputError that lists the rejection reasons. :func:`write_mocap_outputs` writes the result files
(:func:`rigcal.io.results.calibration.write_results`), ``extrinsics.json`` (the original tool's format,
``robot_frame`` <- ``frame_id``), ``diagnostics.csv`` (one row per frame and target) and
overlay images (:mod:`rigcal.report.overlay`).
"""

from __future__ import annotations

import csv
import io
import logging
import math
import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import ConvergenceError, InputError, RigcalError
from rigcal.extract.guidance import camera_view, lidar_view, motion_check
from rigcal.extract.lidar import ring_edge_rays
from rigcal.extract.result import (NO_CLUSTER, NO_CONTOUR, NO_POSE_DATA, ORIENTATION_AMBIGUOUS,
                                   TARGET_MOVING, ExtractionFailure)
from rigcal.geometry.se3 import invert, transform_points
from rigcal.geometry.so3 import so3_log
from rigcal.mocap.config import MocapConfig, PoseSourceSpec, SensorSpec, TargetSpec
from rigcal.mocap.extrinsics import Extrinsics
from rigcal.mocap.streams import (PoseStream, interpolate, interpolation_weight, mcs_noise,
                                  relative_velocity)
from rigcal.problem.consistency import mocap_verdict
from rigcal.problem.mocap import (MocapFit, MocapSensor, TargetObservation, calibrate_mocap_fit,
                                  measured_residuals, shift_observation)
from rigcal.targets.surface import TargetSurface
from rigcal.problem.result import CalibrationResult
from rigcal.problem.uncertainty import weak_directions
from rigcal.report.overlay import OverlayInput
from rigcal.targets.definition import Target

__all__ = [
    "DIAGNOSTICS_COLUMNS",
    "DIAGNOSTICS_NAME",
    "KEPT",
    "SUMMARY_COLUMNS",
    "MeasurementDiagnostic",
    "MocapRun",
    "diagnostics_csv_text",
    "observation_residual",
    "read_mocap_streams",
    "refuse_inconsistent",
    "run_mocap",
    "summary_rows",
    "write_mocap_outputs",
]

log = logging.getLogger(__name__)

KEPT = "kept"
DIAGNOSTICS_NAME = "diagnostics.csv"
EXTRINSICS_NAME = "extrinsics.json"
OVERLAY_DIR = "overlays"
_NS = 1_000_000_000
_OVERLAY_MIN_MOVE_M = 0.1
_OVERLAY_MIN_TURN_RAD = math.radians(5.0)

DIAGNOSTICS_COLUMNS = (
    "sensor", "kind", "t_ns", "t_s", "target", "status", "reason", "keypoints",
    "correspondences", "residual_initial", "residual_final", "unit", "detail",
)
"""Columns of ``diagnostics.csv`` (``t_s`` is seconds since the first frame)."""

SUMMARY_COLUMNS = (
    "sensor", "kind", "frames", "kept", "rejected", "rejections", "residual_initial",
    "residual_final", "unit", "change_mm", "change_deg",
)
"""Columns of :func:`summary_rows`."""


# --------------------------------------------------------------------------------------------
# values


@dataclass(frozen=True)
class MeasurementDiagnostic:
    """What happened to one target in one sensor frame.

    ``status`` is ``"kept"`` or ``"rejected"``; ``reason`` a code of
    :data:`rigcal.extract.result.REASONS` (empty when kept) and ``detail`` a sentence with the
    numbers seen. For kept measurements: ``keypoints`` measured, ``correspondences`` (True:
    keypoints matched by index; False: template-based), and the RMS residual under the
    initial and the final calibration in ``unit`` (``m`` lidar, ``px`` camera)."""

    sensor: str
    kind: str
    t_ns: int
    target: str
    status: str
    reason: str = ""
    detail: str = ""
    keypoints: int = 0
    correspondences: bool = False
    residual_initial: float = math.nan
    residual_final: float = math.nan
    unit: str = ""

    @property
    def kept(self) -> bool:
        return self.status == KEPT


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapRun:
    """Everything :func:`run_mocap` produced.

    ``result``: the calibration (reference ``robot``); ``initial`` and :attr:`final`:
    ``T_robot_sensor`` (4, 4) per sensor; ``observations``: the kept measurements (in frame
    order, the same order as the kept rows of ``diagnostics``); ``diagnostics``: one row per
    sensor frame and target; ``frames``: frames read per sensor; ``overlays``: the
    measurements kept for overlay images (a few per sensor, at distinct target poses);
    ``mocap_frame``: the MCS frame's name when the streams give it."""

    config: MocapConfig
    result: CalibrationResult
    initial: Mapping[str, np.ndarray]
    observations: tuple[TargetObservation, ...]
    diagnostics: tuple[MeasurementDiagnostic, ...]
    frames: Mapping[str, int]
    overlays: tuple[OverlayInput, ...] = ()
    mocap_frame: str = ""
    first_t_ns: int = 0
    #: per-sensor fit statistics (noise sigma, reduced chi2, hold inflation, per-target
    #: matches: :class:`rigcal.problem.mocap.MocapSensorFit`) in ``fit.sensors``
    fit: MocapFit | None = None
    #: extraction passes run (coarse to fine: wider searches, then guided by the calibration)
    passes: int = 1
    #: sensors left out of ``result``, each with the reason (no frames, every measurement
    #: rejected, or a pose its measurements do not determine); also ``result.not_calibrated``
    not_calibrated: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    #: configured targets no sensor kept a measurement of, each with its rejection counts (the
    #: others calibrated the sensors; also a note in the verdict)
    targets_not_seen: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def final(self) -> dict[str, np.ndarray]:
        return {n: np.asarray(e.T_reference_sensor, dtype=float).copy()
                for n, e in self.result.sensors.items()}

    @property
    def counts(self) -> dict[str, dict[str, int]]:
        """sensor -> {``"kept"`` or a rejection reason: number of (frame, target) rows}."""
        out: dict[str, dict[str, int]] = {s.name: {} for s in self.config.sensors}
        for d in self.diagnostics:
            key = KEPT if d.kept else d.reason
            out[d.sensor][key] = out[d.sensor].get(key, 0) + 1
        return out


# --------------------------------------------------------------------------------------------
# reading the MCS


def _where(config: MocapConfig, label: str, spec: PoseSourceSpec) -> str:
    return f"{config.source}: mocap.{label} ({spec.describe()})"


def read_mocap_streams(config: MocapConfig) -> tuple[PoseStream, dict[str, PoseStream]]:
    """The robot's pose stream and every target's (by target name), from the sources the
    configuration names; errors name the configuration key. All streams must share one mocap
    frame when their frame ids are known."""
    specs: dict[str, tuple[str, PoseSourceSpec]] = {"robot": ("robot", config.robot)}
    for name, t in config.targets.items():
        specs[f"target:{name}"] = (f"targets.{name}", t.pose)
    streams: dict[str, PoseStream] = {}
    topics = {k: s.topic for k, (_, s) in specs.items() if s.kind == "topic"}
    if topics:
        from rigcal.io.recordings.bag import open_bag
        from rigcal.mocap.streams import POSE_MSGTYPES, read_pose_topics

        with open_bag(config.recording) as rec:
            available = rec.topics()
        for k, topic in topics.items():
            msgtype = available.get(topic)
            if msgtype not in POSE_MSGTYPES:
                label, spec = specs[k]
                poses = sorted(t for t, ty in available.items() if ty in POSE_MSGTYPES)
                what = ("not in the recording" if msgtype is None
                        else f"has type {msgtype}, expected one of {', '.join(POSE_MSGTYPES)}")
                raise InputError(f"{_where(config, label, spec)}: topic {topic} {what} "
                                 f"({config.recording}; pose topics: {poses or 'none'})")
        try:
            streams.update(read_pose_topics(config.recording, topics))
        except InputError as exc:
            labels = ", ".join(f"mocap.{specs[k][0]}" for k in topics)
            raise InputError(f"{config.source}: {labels}: {exc}") from None
    by_parent: dict[str | None, dict[str, str]] = {}
    for k, (_, s) in specs.items():
        if s.kind == "tf":
            by_parent.setdefault(s.parent, {})[k] = s.child
    for parent, children in by_parent.items():
        from rigcal.mocap.streams import read_tf_streams

        try:
            streams.update(read_tf_streams(config.recording, children, parent,
                                           max_gap_s=config.max_gap_s))
        except InputError as exc:
            labels = ", ".join(f"mocap.{specs[k][0]}" for k in children)
            raise InputError(f"{config.source}: {labels}: {exc}") from None
    for k, (label, s) in specs.items():
        if s.kind == "csv":
            from rigcal.mocap.streams import read_pose_csv

            try:
                assert s.path is not None
                streams[k] = read_pose_csv(s.path, name=k, time_unit=s.time_unit)
            except InputError as exc:
                raise InputError(f"{_where(config, label, s)}: {exc}") from None
    frames = {specs[k][0]: st.frame_id for k, st in streams.items() if st.frame_id}
    if len(set(frames.values())) > 1:
        raise InputError(
            f"{config.source}: the mocap streams are given in different frames ("
            + ", ".join(f"mocap.{k}: '{v}'" for k, v in frames.items())
            + "); every pose must be in the same mocap frame"
        )
    robot = streams.pop("robot")
    return robot, {k.split(":", 1)[1]: v for k, v in streams.items()}


def _initial_extrinsics(config: MocapConfig) -> Extrinsics:
    if config.initial is not None:
        return config.initial
    from rigcal.mocap.extrinsics import read_extrinsics_from_bag

    try:
        return read_extrinsics_from_bag(config.recording)
    except InputError as exc:
        raise InputError(f"{config.source}: initial_calibration not given and the recording's "
                         f"static TF cannot serve: {exc}") from None


# --------------------------------------------------------------------------------------------
# one frame, one target


class _PoseLookup:
    """Interpolated MCS poses with the reason a time has none, and the stream's own noise."""

    def __init__(self, stream: PoseStream, label: str, max_gap_s: float,
                 max_dropout_s: float | None = None) -> None:
        self.stream = stream
        self.label = label
        self.max_gap_s = max_gap_s
        self.max_dropout_s = max_dropout_s
        self.noise = mcs_noise(stream)

    def at(self, t_ns: int) -> tuple[np.ndarray | None, str]:
        T, ok = interpolate(self.stream, np.array([t_ns], dtype=np.int64), self.max_gap_s,
                            self.max_dropout_s)
        if ok[0]:
            return T[0], ""
        try:
            self.stream.at(t_ns, self.max_gap_s, self.max_dropout_s)
        except InputError as exc:
            return None, f"{self.label}: {exc}"
        return None, f"{self.label}: no pose at t = {t_ns} ns"  # pragma: no cover

    def times(self, lo: int, hi: int) -> np.ndarray:
        t = self.stream.t_ns
        return t[(t > lo) & (t < hi)]


@dataclass
class _Context:
    config: MocapConfig
    robot: _PoseLookup
    targets: dict[str, _PoseLookup]
    initial: dict[str, np.ndarray]
    prepared: dict[str, Any] = field(default_factory=dict)
    #: per sensor, how much wider than configured the search is (a guess far off: nothing found)
    widen: dict[str, float] = field(default_factory=dict)
    #: per sensor, ``T_robot_sensor`` implied by each measurement with a fitted target pose
    #: (the lidar's ICP): what a wide search tells about a far-off guess
    found_poses: dict[str, list] = field(default_factory=dict)
    #: per target, its surface (the flat plates' outlines for a lidar's ring ends)
    surfaces: dict[str, TargetSurface] = field(default_factory=dict)


def _motion(ctx: _Context, t_ns: int, target: str) -> tuple[bool, str, str]:
    ex = ctx.config.extraction
    half = int(round(ex.motion_window_s * 0.5 * _NS))
    lo, hi = t_ns - half, t_ns + half
    tl = ctx.targets[target]
    times = np.unique(np.concatenate([[lo, t_ns, hi], ctx.robot.times(lo, hi),
                                      tl.times(lo, hi)]).astype(np.int64))
    T_mr, ok_r = interpolate(ctx.robot.stream, times, ctx.robot.max_gap_s, ctx.robot.max_dropout_s)
    T_mt, ok_t = interpolate(tl.stream, times, tl.max_gap_s, tl.max_dropout_s)
    bad = ~(ok_r & ok_t)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        lookup = ctx.robot if not ok_r[k] else tl
        _, why = lookup.at(int(times[k]))
        return False, NO_POSE_DATA, (
            f"the +-{ex.motion_window_s / 2:g} s motion window around t = {t_ns} ns is not "
            f"covered: {why}"
        )
    T_rt = invert(T_mr) @ T_mt
    check = motion_check(t_ns, times, T_rt, ex.motion_window_s, ex.max_linear_mps,
                         ex.max_angular_radps)
    return check.still, check.reason, check.detail


def _velocity(ctx: _Context, t_ns: int, target: str) -> np.ndarray | None:
    """The target's velocity relative to the robot at ``t_ns`` (a twist, see
    :func:`rigcal.mocap.streams.relative_velocity`) over the motion window; None (taken as
    still) when the streams do not cover it or it is below what the MCS's noise can show."""
    tl = ctx.targets[target]
    v = relative_velocity(ctx.robot.stream, tl.stream, t_ns, ctx.config.extraction.motion_window_s,
                          tl.max_gap_s, tl.max_dropout_s)
    if v is None or not np.all(np.isfinite(v)) or float(np.abs(v).max()) < 1e-6:
        return None
    return v


def _pose_cov(ctx: _Context, t_ns: int, target: str, T_rt: np.ndarray) -> np.ndarray | None:
    """(6, 6) the MCS's error of ``T_robot_target`` at ``t_ns`` from the streams' own noise
    (:func:`rigcal.mocap.streams.mcs_noise`): the target's, and the robot's reaching the target
    through the lever arm between them, each scaled by its interpolation weight. None when the
    streams show none (exact poses) or cannot tell."""
    from rigcal.geometry.se3 import adjoint

    tl, rl = ctx.targets[target], ctx.robot
    if (tl.noise.samples == 0 or rl.noise.samples == 0 or
            max(tl.noise.translation_m, rl.noise.translation_m, tl.noise.rotation_rad, rl.noise.rotation_rad) <= 0):
        return None
    Ad = adjoint(invert(T_rt))
    return (interpolation_weight(tl.stream, t_ns) * tl.noise.covariance()
            + interpolation_weight(rl.stream, t_ns) * (Ad @ rl.noise.covariance() @ Ad.T))


def _expected_view(sensor: SensorSpec, target: Target, T_st: np.ndarray, ctx: _Context):
    ex = ctx.config.extraction
    if sensor.kind is SensorKind.CAMERA:
        wide = ctx.widen.get(sensor.name, 1.0) > 1.0
        return camera_view(sensor.camera, T_st, target.camera_points,
                           min_fraction=0.2 if wide else ex.camera_min_fraction_in_view)
    spec = sensor.lidar
    assert spec is not None
    wide = ctx.widen.get(sensor.name, 1.0) > 1.0
    return lidar_view(T_st, target.template, spec.min_range_m, spec.max_range_m,
                      spec.elevation_fov_rad, spec.azimuth_fov_rad,
                      0.0 if wide else ex.lidar_min_fraction_in_view)


def _wide_checkerboard(frame: Any, sensor: SensorSpec, target: Target, T_st: np.ndarray):
    """The whole image searched for the board, its corners ordered like the prediction's
    (however far off: the guess only has to tell the grid's symmetries apart)."""
    from rigcal.extract.camera import extract_checkerboard, order_grid

    dims = target.dims
    size = (int(dims["cols"]), int(dims["rows"]))
    m = extract_checkerboard(frame, sensor.camera, size, target.camera_keypoints, None,
                             estimate_pose=False, sensor=sensor.name, t_ns=frame.t_ns,
                             target=target.name)
    if isinstance(m, ExtractionFailure):
        return m
    expected, _ = sensor.camera.project(transform_points(T_st, target.camera_keypoints))
    if not np.all(np.isfinite(expected)):
        return ExtractionFailure(sensor.name, frame.t_ns, ORIENTATION_AMBIGUOUS,
                                 "a checkerboard was found, but its predicted corners do not all "
                                 "project: which corner is which cannot be told")
    corners, sym, err, runner = order_grid(m.keypoints, size, expected)
    if err > _ORDER_AMBIGUITY * runner:
        # the guess tells the grid's symmetric orderings apart too weakly: a half-turned grid
        # would be a wrong calibration, so the frame is left out
        return ExtractionFailure(sensor.name, frame.t_ns, ORIENTATION_AMBIGUOUS,
                                 f"the predicted corners fit the grid's best ordering ({sym}) by "
                                 f"{err:.0f} px, its next best by {runner:.0f} px: the guess cannot "
                                 "tell which way round the checkerboard is")
    return replace(m, keypoints=corners, keypoint_index=np.arange(len(corners)))


def _extract(frame: Any, sensor: SensorSpec, target: Target, T_st: np.ndarray, ctx: _Context):
    ex = ctx.config.extraction
    unc = ex.uncertainty
    w = ctx.widen.get(sensor.name, 1.0)
    if w > 1.0:
        unc = replace(unc, sigma_translation_m=unc.sigma_translation_m * w,
                      sigma_rotation_rad=unc.sigma_rotation_rad * w)
        if sensor.kind is SensorKind.CAMERA and target.kind.value == "checkerboard_diamond":
            return _wide_checkerboard(frame, sensor, target, T_st)
    if sensor.kind is SensorKind.CAMERA:
        from rigcal.extract.camera import extract_target_camera

        opts: dict[str, Any] = dict(uncertainty=unc, sensor=sensor.name, t_ns=frame.t_ns)
        if ex.crop_margin_px is not None:
            opts["crop_margin_px"] = ex.crop_margin_px
        if target.kind.value == "checkerboard_diamond":
            opts["estimate_pose"] = ex.estimate_pose
        return extract_target_camera(frame, sensor.camera, target, T_st, **opts)
    from rigcal.extract.icp import prepare_template
    from rigcal.extract.lidar import extract_target_lidar

    if target.name not in ctx.prepared:
        ctx.prepared[target.name] = prepare_template(target.template)
    return extract_target_lidar(
        frame, target, T_st, ctx.prepared[target.name], lidar=sensor.lidar, uncertainty=unc,
        crop_pad_m=ex.crop_pad_m, on_template_m=ex.on_template_m,
        min_cluster_points=ex.min_cluster_points,
        min_fraction_in_view=0.0 if w > 1.0 else ex.lidar_min_fraction_in_view,
        multi_start=w > 1.0, sensor=sensor.name, t_ns=frame.t_ns,
    )


#: a scanning lidar's returns from a flat plate are the cluster's points within this many of
#: its configured sigmas of the fitted plate (at least ``on_template_m``): the range noise
#: whole, not cut at the extractor's on-template distance (cut at 1.3 sigma, its variance would
#: be halved and the pose's uncertainty with it)
PLATE_RETURN_SIGMAS = 4.0


def _plate_returns(m: Any, sensor: SensorSpec, target: Target, ctx: _Context) -> np.ndarray | None:
    """A lidar's returns from a flat plate (:data:`PLATE_RETURN_SIGMAS`), or None when the target
    is no flat plate with a known outline, the lidar's scan pattern is not known, or the
    extractor kept no cluster or fitted pose."""
    cluster = m.extras.get("cluster_points") if m.extras else None
    if sensor.lidar is None or cluster is None or m.T_sensor_target is None:
        return None
    surface = ctx.surfaces.get(target.name)
    if surface is None:
        surface = ctx.surfaces[target.name] = TargetSurface.of(target)
    if not surface.planar:
        return None
    pts = np.asarray(cluster, dtype=float)
    T_ts = invert(np.asarray(m.T_sensor_target, dtype=float))
    d = surface.distance(transform_points(T_ts, pts))
    tol = max(PLATE_RETURN_SIGMAS * float(sensor.sigma), float(ctx.config.extraction.on_template_m))
    keep = d <= tol
    return pts[keep] if keep.sum() >= 3 else None


def _process(frame: Any, sensor: SensorSpec, tspec: TargetSpec, ctx: _Context):
    """(diagnostic, observation or None, measurement or None) of one target in one frame."""
    t = int(frame.t_ns)
    target = tspec.target
    row = dict(sensor=sensor.name, kind=sensor.kind.value, t_ns=t, target=tspec.name)

    def reject(reason: str, detail: str):
        return MeasurementDiagnostic(status="rejected", reason=reason, detail=detail, **row), \
            None, None

    T_mr, why = ctx.robot.at(t)
    if T_mr is None:
        return reject(NO_POSE_DATA, why)
    T_mt, why = ctx.targets[tspec.name].at(t)
    if T_mt is None:
        return reject(NO_POSE_DATA, why)
    T_rt = invert(T_mr) @ T_mt
    T_st = invert(ctx.initial[sensor.name]) @ T_rt
    view = _expected_view(sensor, target, T_st, ctx)
    if not view.visible:
        return reject(view.reason, f"expected pose: {view.detail}")
    still, reason, detail = _motion(ctx, t, tspec.name)
    if not still:
        return reject(reason, detail)
    m = _extract(frame, sensor, target, T_st, ctx)
    if isinstance(m, ExtractionFailure):
        return reject(m.reason, m.detail)
    if len(m.keypoints) == 0:
        return reject(NO_CONTOUR if sensor.kind is SensorKind.CAMERA else NO_CLUSTER,
                      "the extractor returned no keypoints")
    keypoints_target = None
    if m.keypoint_index is not None:
        source = (target.camera_keypoints if sensor.kind is SensorKind.CAMERA
                  else target.lidar_keypoints)
        if source is not None:
            keypoints_target = source[m.keypoint_index]
    measured, edge_rays = m.keypoints, None
    if sensor.kind is SensorKind.LIDAR and keypoints_target is None:
        plate = _plate_returns(m, sensor, target, ctx)
        if plate is not None:
            measured = plate
            spec = sensor.lidar
            edge_rays = ring_edge_rays(plate, spec.vertical_step_rad, spec.horizontal_step_rad,
                                       spec.azimuth_fov_rad)
    obs = TargetObservation(sensor.name, tspec.name, t, T_rt, measured, keypoints_target,
                            velocity=_velocity(ctx, t, tspec.name),
                            pose_cov=_pose_cov(ctx, t, tspec.name, T_rt), edge_rays=edge_rays)
    diag = MeasurementDiagnostic(status=KEPT, keypoints=len(measured),
                                 correspondences=keypoints_target is not None,
                                 unit="px" if sensor.kind is SensorKind.CAMERA else "m", **row)
    return diag, obs, m


# --------------------------------------------------------------------------------------------
# residuals


def observation_residual(obs: TargetObservation, sensor: SensorSpec, target: Target,
                         T_robot_sensor: np.ndarray, surface: TargetSurface | None = None) -> float:
    """RMS residual of one observation under ``T_robot_sensor``: [m] for a lidar, [px] for a
    camera - the RMS of :func:`rigcal.problem.mocap.measured_residuals` (the one definition of
    a mocap residual: the result's ``rmse_m`` / ``reprojection_px`` are the RMS of the same
    numbers over every point of a sensor)."""
    m = MocapSensor(sensor.name, sensor.kind, camera=sensor.camera, sigma=sensor.sigma,
                    frame_id=sensor.frame_id)
    e = measured_residuals(obs, m, T_robot_sensor,
                           surface if surface is not None else TargetSurface.of(target))
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(np.square(e)))) if e.size else math.nan


# --------------------------------------------------------------------------------------------
# the run


def _rejection_text(counts: Counter) -> str:
    if not counts:
        return "no frames"
    return ", ".join(f"{r}: {n}" for r, n in counts.most_common())


def _overlay_wanted(chosen: list[OverlayInput], T_rt: np.ndarray, limit: int) -> bool:
    if len(chosen) >= limit:
        return False
    for c in chosen:
        d = float(np.linalg.norm(c.T_robot_target[:3, 3] - T_rt[:3, 3]))
        a = float(np.linalg.norm(so3_log(c.T_robot_target[:3, :3].T @ T_rt[:3, :3])))
        if d < _OVERLAY_MIN_MOVE_M and a < _OVERLAY_MIN_TURN_RAD:
            return False
    return True


_MAX_PASSES = 5
#: a wide-search checkerboard is ordered by the guess only when the best ordering fits the
#: prediction at least this much better than the next (the half-turned grid)
_ORDER_AMBIGUITY = 0.5
#: a sensor whose residuals scatter by more than this many times its configured sigma is refused
_MAX_NOISE_RATIO = 5.0
_WIDEN = 4.0
_SETTLED_M = 0.002
_SETTLED_RAD = math.radians(0.1)


def _consensus(cands: list[np.ndarray], metres: float = 0.05, radians: float = math.radians(5.0)
               ) -> np.ndarray | None:
    """The pose most of ``cands`` (4, 4) agree on: the candidate with the most others within
    ``metres`` and ``radians`` of it (at least half of them; None otherwise), averaged with
    them (mean translation, rotation by the chordal mean)."""
    n = len(cands)
    support = []
    for A in cands:
        near = [B for B in cands
                if np.linalg.norm(A[:3, 3] - B[:3, 3]) <= metres
                and np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3])) <= radians]
        support.append(near)
    best = max(support, key=len)
    if 2 * len(best) < n:
        return None
    U, _, Vt = np.linalg.svd(sum(B[:3, :3] for B in best))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.mean([B[:3, 3] for B in best], axis=0)
    return T


def _close(A: np.ndarray, B: np.ndarray) -> bool:
    dt = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    dr = float(np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3])))
    return dt <= _SETTLED_M and dr <= _SETTLED_RAD


def _extract_all(config: MocapConfig, ctx: _Context, sensors: dict[str, SensorSpec],
                 progress: Callable[[int, int], None] | None):
    """One pass over the recording's frames of ``sensors`` with the guidance in ``ctx``."""
    from rigcal.io.recordings.open_any import open_any

    diagnostics: list[MeasurementDiagnostic] = []
    observations: list[TargetObservation] = []
    overlays: dict[str, list[OverlayInput]] = {s: [] for s in sensors}
    frames_read: Counter = Counter()
    first_t: int | None = None
    found_poses = ctx.found_poses
    found_poses.clear()
    with open_any(config.recording) as rec:
        plan = {}
        total = 0
        for s in sensors.values():
            try:
                total += rec.count(s.topic)
            except InputError as exc:
                raise InputError(f"{config.source}: sensor '{s.name}' (topic {s.topic}): {exc}"
                                 ) from None
            plan[s.name] = (s.topic, s.kind)
        done = 0
        for frame in rec.frames(plan):
            sensor = sensors[frame.sensor]
            frames_read[sensor.name] += 1
            first_t = frame.t_ns if first_t is None else min(first_t, frame.t_ns)
            for tspec in config.targets.values():
                diag, obs, m = _process(frame, sensor, tspec, ctx)
                diagnostics.append(diag)
                if obs is None:
                    continue
                observations.append(obs)
                if m.T_sensor_target is not None:
                    found_poses.setdefault(sensor.name, []).append(
                        obs.T_robot_target @ invert(np.asarray(m.T_sensor_target, dtype=float)))
                if _overlay_wanted(overlays[sensor.name], obs.T_robot_target,
                                   config.overlays_per_sensor):
                    camera = sensor.kind is SensorKind.CAMERA
                    points = None
                    if not camera:
                        cluster = m.extras.get("cluster_points")
                        points = np.array(cluster if cluster is not None else m.keypoints)
                    overlays[sensor.name].append(OverlayInput(
                        sensor=sensor.name, kind=sensor.kind.value, target=tspec.target,
                        t_ns=obs.t_ns, T_robot_target=obs.T_robot_target,
                        measured=obs.measured,
                        image=np.array(frame.image) if camera else None,
                        camera=sensor.camera if camera else None, points_sensor=points,
                    ))
            done += 1
            if progress is not None:
                progress(done, total)
    return diagnostics, observations, overlays, frames_read, first_t


_HOLD_M = 0.02
_HOLD_RAD = math.radians(1.0)


def _label_holds(observations: list[TargetObservation], ctx: _Context) -> list[TargetObservation]:
    """Every observation labelled with its hold: consecutive observations of one target by one
    sensor while the target stays still in the MCS frame (within 2 cm and 1 deg) share the
    MCS's error of it, whether or not the robot moves."""
    order = sorted(range(len(observations)),
                   key=lambda i: (observations[i].sensor, observations[i].target, observations[i].t_ns))
    labels = [""] * len(observations)
    prev, k = None, 0
    for i in order:
        o = observations[i]
        T_mt, _ = ctx.targets[o.target].at(o.t_ns)
        if prev is None or prev[0] != (o.sensor, o.target) or T_mt is None or prev[1] is None or \
                float(np.linalg.norm(T_mt[:3, 3] - prev[1][:3, 3])) > _HOLD_M or \
                float(np.linalg.norm(so3_log(prev[1][:3, :3].T @ T_mt[:3, :3]))) > _HOLD_RAD:
            k += 1
        labels[i] = f"{o.target}#{k}"
        prev = ((o.sensor, o.target), T_mt)
    return [replace(o, hold=h) for o, h in zip(observations, labels)]


def _unusable(config: MocapConfig, sensors: Mapping[str, SensorSpec], diagnostics,
              observations, frames_read, widen: Mapping[str, float]) -> dict[str, str]:
    """sensor -> why it has nothing to be calibrated with: no frames on its topic, or every
    measurement rejected (with the rejection counts)."""
    by_sensor: dict[str, Counter] = {s: Counter() for s in sensors}
    for d in diagnostics:
        if not d.kept and d.sensor in by_sensor:
            by_sensor[d.sensor][d.reason] += 1
    kept_sensor = Counter(o.sensor for o in observations)
    out: dict[str, str] = {}
    for name, spec in sensors.items():
        if frames_read[name] == 0:
            out[name] = f"no frames on topic {spec.topic} in {config.recording}"
        elif kept_sensor[name] == 0:
            wider = (f"; also searched in a {widen[name]:g} times wider window: is its initial "
                     f"calibration right?" if widen.get(name, 1.0) > 1.0 else "")
            out[name] = (
                f"every measurement was rejected ({frames_read[name]} frames x "
                f"{len(config.targets)} targets; rejections: {_rejection_text(by_sensor[name])}); "
                f"nothing to calibrate it with{wider}"
            )
    return out


def _unseen_targets(config: MocapConfig, diagnostics, observations) -> dict[str, str]:
    """target -> why no sensor kept a measurement of it (its rejection counts): reported, not
    fatal - the other targets calibrate the sensors."""
    by_target: dict[str, Counter] = {t: Counter() for t in config.targets}
    for d in diagnostics:
        if not d.kept:
            by_target[d.target][d.reason] += 1
    kept_target = Counter(o.target for o in observations)
    return {name: f"never extracted by any sensor: rejections {_rejection_text(by_target[name])}"
            for name in config.targets if kept_target[name] == 0}


def _own_reason(name: str, message: str) -> str:
    """``message`` without a leading "sensor 'name': " or "camera 'name': "."""
    for kind in ("sensor", "camera", "lidar"):
        prefix = f"{kind} '{name}': "
        if message.startswith(prefix):
            return message[len(prefix):]
    return message


def _inconsistent(fit: MocapFit) -> dict[str, str]:
    """sensor -> why its residuals fit no single pose (see :func:`refuse_inconsistent`)."""
    return {
        n: (f"its residuals scatter by {f.noise_sigma:.3g} {f.unit}, more than "
            f"{_MAX_NOISE_RATIO:g} times its configured sigma {f.sigma_nominal:g} {f.unit}: its "
            "measurements fit no single pose (a wrong match of the target, wrong intrinsics or "
            "a far too small sigma)")
        for n, f in fit.sensors.items() if f.noise_sigma > _MAX_NOISE_RATIO * f.sigma_nominal
    }


def refuse_inconsistent(fit: MocapFit, source: str = "mocap") -> None:
    """Raise ConvergenceError when a sensor's residuals scatter by more than
    ``_MAX_NOISE_RATIO`` times its configured sigma: its measurements fit no single pose (a
    wrong match of the target - a ring taken for the plate, a grid ordered wrongly -, wrong
    intrinsics or a far too small sigma), so no calibration is returned rather than a confident
    wrong one."""
    bad = {n: f for n, f in fit.sensors.items() if f.noise_sigma > _MAX_NOISE_RATIO * f.sigma_nominal}
    if bad:
        raise ConvergenceError(
            f"{source}: " + "; ".join(
                f"sensor '{n}': its residuals scatter by {f.noise_sigma:.3g} {f.unit}, more than "
                f"{_MAX_NOISE_RATIO:g} times its configured sigma {f.sigma_nominal:g} {f.unit}"
                for n, f in bad.items())
            + ": its measurements fit no single pose (a wrong match of the target, wrong "
              "intrinsics or a far too small sigma); no calibration is returned")


def run_mocap(config: MocapConfig, progress: Callable[[int, int], None] | None = None
              ) -> MocapRun:
    """Run the pipeline of the module docstring; ``progress(done, total)`` is called after
    every sensor frame.

    One sensor's trouble does not stop the others: a sensor with no frames, with every
    measurement rejected (a target it never sees, a mocap dropout over all its holds), or
    whose measurements leave its pose undetermined (the solver names it) is left out, the
    others are calibrated without it, and it is reported in ``MocapRun.not_calibrated`` (and
    ``result.not_calibrated``) with the reason. Raises InputError for unreadable inputs (an
    unknown topic, a wrong message type, a missing file), a target no sensor measured, or when
    no sensor at all can be calibrated (one message naming every sensor's reason;
    ConvergenceError instead when a reason came from the solver), and ConvergenceError when
    the calibration as a whole does not converge."""
    robot_stream, target_streams = read_mocap_streams(config)
    extrinsics = _initial_extrinsics(config)
    initial = config.initial_T_robot_sensor(extrinsics)
    ctx = _Context(
        config=config,
        robot=_PoseLookup(robot_stream, "mocap.robot", config.max_gap_s, config.max_dropout_s),
        targets={n: _PoseLookup(s, f"mocap.targets.{n}", config.max_gap_s, config.max_dropout_s)
                 for n, s in target_streams.items()},
        initial=initial,
    )
    sensors = {s.name: s for s in config.sensors}
    templates = {n: TargetSurface.of(t.target) for n, t in config.targets.items()}
    mocap_sensors = [
        MocapSensor(s.name, s.kind, camera=s.camera, sigma=s.sigma, frame_id=s.frame_id)
        for s in config.sensors
    ]
    # a sensor with nothing to be calibrated with (no frames, every measurement rejected) or
    # whose own measurements leave its pose undetermined is given up: the others are
    # calibrated without it and it is reported in ``not_calibrated`` with the reason; its
    # diagnostics rows from the pass that gave it up are kept, it is not read again
    given_up: dict[str, str] = {}
    from_solver: set[str] = set()
    carried_diags: list[MeasurementDiagnostic] = []
    carried_obs: list[TargetObservation] = []
    carried_frames: Counter = Counter()

    def give_up(reasons: Mapping[str, str], solver: bool) -> None:
        nonlocal diagnostics, observations
        for n, why in reasons.items():
            given_up[n] = why
            if solver:
                from_solver.add(n)
            carried_frames[n] = frames_read.pop(n, 0)
            overlays.pop(n, None)
            log.warning("%s: sensor '%s' is not calibrated: %s", config.source, n, why)
        carried_diags.extend(d for d in diagnostics if d.sensor in reasons)
        carried_obs.extend(o for o in observations if o.sensor in reasons)
        diagnostics = [d for d in diagnostics if d.sensor not in reasons]
        observations = [o for o in observations if o.sensor not in reasons]

    def nothing_left() -> RigcalError:
        text = "; ".join(f"sensor '{n}': {given_up[n]}" for n in sensors if n in given_up)
        cls = ConvergenceError if from_solver else InputError
        return cls(f"{config.source}: no sensor can be calibrated: {text}")

    def fit_active(may_widen: bool):
        """The fit of the sensors not given up; a sensor the solver names as undetermined is
        given up and the rest fitted again. None when a wider search is wanted first."""
        while True:
            active = [m for m in mocap_sensors if m.name not in given_up]
            try:
                return calibrate_mocap_fit(active, observations,
                                           {m.name: ctx.initial[m.name] for m in active},
                                           templates, config.options)
            except ConvergenceError as exc:
                # too little seen to determine a pose (e.g. the lidar kept a single hold, the
                # others predicted out of its view): search the sensors with few holds wider
                holds = Counter(o.sensor for o in {(o.sensor, o.hold): o for o in observations}.values())
                few = [m.name for m in active if holds[m.name] < 3 and ctx.widen.get(m.name, 1.0) < _WIDEN]
                if few and may_widen:
                    for n in few:
                        ctx.widen[n] = _WIDEN
                    return None
                if exc.sensor is None or exc.sensor not in {m.name for m in active}:
                    raise
                give_up({exc.sensor: _own_reason(exc.sensor, str(exc))}, solver=True)
                if len(given_up) == len(sensors):
                    raise nothing_left() from None

    # coarse to fine: a sensor that kept nothing is searched again in a wider window; every
    # pass after the first is guided by the previous calibration, until it no longer moves
    fit = None
    for attempt in range(_MAX_PASSES):
        active_specs = {n: s for n, s in sensors.items() if n not in given_up}
        diagnostics, observations, overlays, frames_read, first_t = _extract_all(
            config, ctx, active_specs, progress if attempt == 0 else None)
        kept_sensor = Counter(o.sensor for o in observations)
        # a wider search helps only where something was searched for and not found
        searched = {d.sensor for d in diagnostics
                    if not d.kept and d.reason not in (NO_POSE_DATA, TARGET_MOVING)}
        empty = [n for n in active_specs if kept_sensor[n] == 0 and n in searched]
        if empty and attempt < _MAX_PASSES - 1 and any(ctx.widen.get(n, 1.0) < _WIDEN for n in empty):
            for n in empty:
                ctx.widen[n] = _WIDEN
            continue
        # a sensor found in the wide search with its target's pose fitted (the lidar's global
        # ICP search): the poses it implies agree on one T_robot_sensor - searched again from
        # there, at the configured width
        moved_start = {}
        for n, cands in ctx.found_poses.items():
            if ctx.widen.get(n, 1.0) > 1.0 and n in active_specs and len(cands) >= 2:
                T = _consensus(cands)
                if T is not None and not _close(T, ctx.initial[n]):
                    moved_start[n] = T
        if moved_start and attempt < _MAX_PASSES - 1:
            ctx.initial = {**ctx.initial, **moved_start}
            for n in moved_start:
                ctx.widen.pop(n, None)
            continue
        lost = _unusable(config, active_specs, diagnostics, observations, frames_read, ctx.widen)
        if lost:
            give_up(lost, solver=False)
        if len(given_up) == len(sensors):
            raise nothing_left()
        unseen = _unseen_targets(config, diagnostics + carried_diags, observations + carried_obs)
        observations = _label_holds(observations, ctx)
        fit = fit_active(may_widen=attempt < _MAX_PASSES - 1)
        if fit is None:
            continue
        final = {n: e.T_reference_sensor for n, e in fit.result.sensors.items()}
        moved = [n for n in final if not _close(final[n], ctx.initial[n])]
        if not moved or attempt == _MAX_PASSES - 1:
            break
        ctx.initial = {**ctx.initial, **{n: np.array(T) for n, T in final.items()}}
        ctx.widen = {}
    assert fit is not None
    # a sensor whose residuals scatter far beyond its sigma fits no single pose: refused, and
    # the others fitted again without it (refuse_inconsistent when it is the only one)
    while True:
        bad = _inconsistent(fit)
        if not bad or len(bad) == len(fit.sensors):
            break
        give_up(bad, solver=True)
        fit = fit_active(may_widen=False)
        assert fit is not None
    if given_up and _inconsistent(fit):
        give_up(_inconsistent(fit), solver=True)
        raise nothing_left()
    refuse_inconsistent(fit, config.source)
    for name, why in unseen.items():
        log.warning("%s: target '%s' %s", config.source, name, why)
    weak = {n: weak_directions(e.std) for n, e in fit.result.sensors.items() if n in sensors}
    result = replace(fit.result, verdict=mocap_verdict(fit, weak, unseen),
                     not_calibrated={n: given_up[n] for n in sensors if n in given_up},
                     reference_frame=config.robot_frame)  # the body's frame in every output
    final = {n: e.T_reference_sensor for n, e in result.sensors.items()}
    if carried_diags:  # back in frame order
        diagnostics = sorted(diagnostics + carried_diags, key=lambda d: d.t_ns)
        observations = sorted(observations + carried_obs, key=lambda o: o.t_ns)
        frames_read = frames_read + carried_frames
        first_t = min([t for t in (first_t, *(d.t_ns for d in carried_diags)) if t is not None])

    it = iter(observations)
    filled = []
    for d in diagnostics:
        if d.kept:
            obs = next(it)
            s, tgt = sensors[d.sensor], config.targets[d.target].target
            final_res = math.nan
            if d.sensor in final:
                # the final model: the MCS pose at the capture time (the clock offset applied)
                off = fit.sensors[d.sensor].time_offset_s
                shifted = shift_observation(obs, off) if math.isfinite(off) else obs
                final_res = observation_residual(shifted, s, tgt, final[d.sensor], templates[d.target])
            d = replace(d,
                        residual_initial=observation_residual(obs, s, tgt, initial[d.sensor], templates[d.target]),
                        residual_final=final_res)
        filled.append(d)
    return MocapRun(
        config=config,
        result=result,
        initial=MappingProxyType({k: np.array(v) for k, v in initial.items()}),
        observations=tuple(observations),
        diagnostics=tuple(filled),
        frames=MappingProxyType(dict(frames_read)),
        overlays=tuple(o for s in sensors for o in overlays.get(s, ())),
        mocap_frame=robot_stream.frame_id,
        first_t_ns=int(first_t or 0),
        fit=fit,
        passes=attempt + 1,
        not_calibrated=MappingProxyType(dict(result.not_calibrated)),
        targets_not_seen=MappingProxyType(dict(unseen)),
    )


# --------------------------------------------------------------------------------------------
# outputs


def _fmt(x: float) -> str:
    return "" if not math.isfinite(x) else repr(float(x))


def diagnostics_csv_text(run: MocapRun) -> str:
    """``diagnostics.csv`` text: a header of :data:`DIAGNOSTICS_COLUMNS`, one row per sensor
    frame and target in frame order; residuals empty for rejected rows."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(DIAGNOSTICS_COLUMNS)
    for d in run.diagnostics:
        w.writerow([
            d.sensor, d.kind, d.t_ns, f"{(d.t_ns - run.first_t_ns) / _NS:.6f}", d.target,
            d.status, d.reason, d.keypoints if d.kept else "",
            ("keypoints" if d.correspondences else "template") if d.kept else "",
            _fmt(d.residual_initial), _fmt(d.residual_final), d.unit, d.detail,
        ])
    return buf.getvalue()


def _rms(values: list[float], weights: list[int] | None = None) -> float:
    """The RMS over every point of the measurements whose RMS are ``values`` (each weighted by
    its ``weights``: points measured), the same number as the result's residual."""
    w = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    v = np.array(values, dtype=float)
    ok = np.isfinite(v) & (w > 0)
    return float(np.sqrt(np.sum(w[ok] * v[ok] ** 2) / np.sum(w[ok]))) if np.any(ok) else math.nan


def summary_rows(run: MocapRun) -> list[tuple]:
    """One row per sensor, columns :data:`SUMMARY_COLUMNS`: frames read, kept and rejected
    (frame, target) rows, the rejections by reason (``"reason: n, ..."``), the RMS residual
    over kept measurements under the initial and the final calibration (in ``unit``), and how
    far the calibration moved from the initial one [mm, deg] (NaN for a sensor that is not
    calibrated, as are its final residuals)."""
    rows = []
    final = run.final
    for s in run.config.sensors:
        mine = [d for d in run.diagnostics if d.sensor == s.name]
        kept = [d for d in mine if d.kept]
        rej = Counter(d.reason for d in mine if not d.kept)
        T0, T1 = run.initial[s.name], final.get(s.name)
        rows.append((
            s.name, s.kind.value, int(run.frames.get(s.name, 0)), len(kept), len(mine) - len(kept),
            _rejection_text(rej) if rej else "",
            _rms([d.residual_initial for d in kept], [d.keypoints for d in kept]),
            _rms([d.residual_final for d in kept], [d.keypoints for d in kept]),
            "px" if s.kind is SensorKind.CAMERA else "m",
            math.nan if T1 is None else float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]) * 1e3),
            math.nan if T1 is None else
            math.degrees(float(np.linalg.norm(so3_log(T0[:3, :3].T @ T1[:3, :3])))),
        ))
    return rows


def write_mocap_outputs(run: MocapRun, out_dir: str | os.PathLike[str],
                        max_overlays: int | None = None, report: bool = True) -> list[Path]:
    """Write the result files (:func:`rigcal.io.results.calibration.write_results`), ``extrinsics.json``
    (``robot_frame`` <- each sensor's ``frame_id``, the original tool's layout),
    ``diagnostics.csv`` and up to ``max_overlays`` (default: the configuration's
    ``overlays_per_sensor``) overlay PNGs per sensor in ``overlays/`` and (``report``)
    ``report.json`` + ``report.html`` (:mod:`rigcal.report`, the overlays embedded); every
    file atomically.
    A sensor that is not calibrated has no transform in these files (``calibration.yaml``
    lists it under ``not_calibrated`` with the reason) but its rows in ``diagnostics.csv``.
    Returns the written paths."""
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.results.calibration import write_results
    from rigcal.mocap.extrinsics import write_extrinsics_json
    from rigcal.report.overlay import write_overlays

    out = Path(out_dir)
    limit = run.config.overlays_per_sensor if max_overlays is None else int(max_overlays)
    paths = list(write_results(run.result, out))
    final = run.final
    ext = Extrinsics(
        {(run.config.robot_frame, s.frame_id): final[s.name] for s in run.config.sensors
         if s.name in final},
        str(out / EXTRINSICS_NAME),
        {"type": "extrinsic_calibration", "method": "rigcal mocap"},
    )
    paths.append(write_extrinsics_json(out / EXTRINSICS_NAME, ext))
    paths.append(atomic_write_text(out / DIAGNOSTICS_NAME, diagnostics_csv_text(run)))
    overlays: list[Path] = []
    if limit > 0:
        overlays = write_overlays([o for o in run.overlays if o.sensor in final], run.initial, final,
                                  out / OVERLAY_DIR, limit)
        paths += overlays
    if report:
        from rigcal.io.results.report import write_report
        from rigcal.report.data import mocap_report

        paths += write_report(mocap_report(run, {p.name: p.read_bytes() for p in overlays}), out)
    return paths
