"""The motion-capture calibration configuration (``mocap.yaml``): what to read and how.

Example (paths are relative to the file's folder)::

    recording: run.bag                        # ROS 1/2 bag, or a folder recording
    mocap:
      robot: {topic: /vicon/robot/robot}      # or {tf_child: robot, tf_parent: world}
                                              # or {csv: robot.csv, time_unit: s}
      targets:
        diamond: {topic: /vicon/diamond/diamond, definition: CheckerboardTargetSim.json,
                  use_lidar_keypoints: false}   # lidar: every point on the plate, not corners
        board:   {topic: /vicon/board/board,
                  analytic: {kind: checkerboard_diamond, side_m: 0.5, square_m: 0.029,
                             rows: 6, cols: 7}}
        cylinder: {topic: /vicon/cyl/cyl, definition: CylinderTarget.json,
                   template: cyl.pcd, dims: {radius_m: 0.0564, height_m: 0.4956}}
      max_gap_s: 0.05                         # longest mocap gap bridged by interpolation
      max_dropout_s: 0.25                     # longest burst of dropped (NaN) samples bridged
                                              # (default: 25 sample periods of each stream)
    initial_calibration: initial.json         # the original tool's extrinsics JSON, or a
                                              # calibration YAML; omitted: the bag's /tf_static
    robot_frame: base_link                    # the frame of the tracked robot body
    sensors:
      - {name: lidar1, kind: lidar, topic: /velodyne_points, frame_id: velodyne_link,
         sigma_m: 0.01}
      - {name: camera1, kind: camera, topic: /F1/image_raw, frame_id: camera_link,
         intrinsics: F1_sim.json, sigma_px: 1.0}
    extraction: {max_linear_mps: 0.1, max_angular_dps: 5, motion_window_s: 0.5,
                 sigma_translation_m: 0.03, sigma_rotation_deg: 5}
    options: {loss: huber, correspondences: surface,                # MocapOptions fields
              target_pose_sigma: [0.0005, 0.00015]}
    report: {overlays_per_sensor: 3}

Every pose source gives ``T_M_body``: the tracked body's pose in the mocap frame ``M``. A
``topic`` is a ``geometry_msgs/TransformStamped`` (the Vicon bridge), ``PoseStamped``,
``PoseWithCovarianceStamped`` or ``nav_msgs/Odometry`` topic of the recording; ``tf_child``
reads ``/tf`` (and ``/tf_static``), composing the chain up to ``tf_parent`` (default: the root);
``csv`` is a file ``t, x, y, z, qx, qy, qz, qw`` (:func:`rigcal.mocap.streams.parse_pose_csv`).

Sensors: ``lidar`` (``sigma_m`` [m], optional ``vertical_step_deg``, ``horizontal_step_deg``,
``min_range_m``, ``max_range_m``, ``elevation_fov_deg: [lo, hi]``, ``azimuth_fov_deg: [lo,
hi]``; defaults: a VLP-16) or ``camera`` (``intrinsics``: any camera file
:func:`rigcal.io.config.camchain.read_camera_file` reads; ``camera`` names one camera of a
multi-camera file; ``sigma_px`` [px]). ``frame_id`` (default: the name) is the sensor's frame in the initial
calibration, which must connect it to ``robot_frame``.

:func:`parse_mocap_config` reads the referenced target definitions, intrinsics and initial
calibration at once, so a broken file is reported before any data is processed; every error
is an :class:`~rigcal.errors.InputError` naming the configuration file and the key.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.extract.guidance import PoseUncertainty
from rigcal.extract.lidar import LidarSpec
from rigcal.io._text import check_keys, is_finite_number, load_yaml, read_text, type_name
from rigcal.io.dataset.manifest import check_sensor_name
from rigcal.mocap.extrinsics import Extrinsics
from rigcal.mocap.streams import DEFAULT_MAX_GAP_S
from rigcal.problem.mocap import MocapOptions
from rigcal.targets.definition import Target, TargetKind

__all__ = [
    "ExtractionSettings",
    "MocapConfig",
    "PoseSourceSpec",
    "SensorSpec",
    "TargetSpec",
    "load_mocap_config",
    "parse_mocap_config",
    "read_initial_calibration",
]

_TOP_KEYS = ("recording", "mocap", "initial_calibration", "robot_frame", "sensors",
             "extraction", "options", "report")
_MOCAP_KEYS = ("robot", "targets", "max_gap_s", "max_dropout_s")
_POSE_KEYS = ("topic", "tf_child", "tf_parent", "csv", "time_unit")
_TARGET_KEYS = _POSE_KEYS + ("definition", "analytic", "template", "dims", "kind", "use_lidar_keypoints")
_SENSOR_COMMON = ("name", "kind", "topic", "frame_id")
_LIDAR_KEYS = _SENSOR_COMMON + ("sigma_m", "vertical_step_deg", "horizontal_step_deg",
                                "min_range_m", "max_range_m", "elevation_fov_deg",
                                "azimuth_fov_deg")
_CAMERA_KEYS = _SENSOR_COMMON + ("intrinsics", "camera", "sigma_px")
_REPORT_KEYS = ("overlays_per_sensor",)
_CAMERA_TARGET_KINDS = (TargetKind.CHECKERBOARD_DIAMOND, TargetKind.CYLINDER)


# --------------------------------------------------------------------------------------------
# small checks


def _mapping(value: Any, where: str, what: str = "a mapping") -> dict:
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected {what}, got {type_name(value)}")
    return value


def _string(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where}: expected a non-empty string, got {type_name(value)} {value!r}")
    return value.strip()


def _number(value: Any, where: str, *, minimum: float | None = None, positive: bool = False
            ) -> float:
    if not is_finite_number(value):
        raise InputError(f"{where}: expected a finite number, got {type_name(value)} {value!r}")
    v = float(value)
    if positive and not v > 0:
        raise InputError(f"{where}: expected a number > 0, got {value!r}")
    if minimum is not None and v < minimum:
        raise InputError(f"{where}: expected a number >= {minimum:g}, got {value!r}")
    return v


def _pair(value: Any, where: str) -> tuple[float, float]:
    ok = isinstance(value, list) and len(value) == 2
    if not (ok and all(is_finite_number(v) for v in value)):
        raise InputError(f"{where}: expected [low, high] (two numbers), got {value!r}")
    lo, hi = float(value[0]), float(value[1])
    if not lo < hi:
        raise InputError(f"{where}: expected low < high, got {value!r}")
    return lo, hi


def _file(value: Any, where: str, base_dir: Path, what: str) -> Path:
    p = Path(_string(value, where))
    path = p if p.is_absolute() else base_dir / p
    if not path.is_file():
        raise InputError(f"{where}: {what} not found: {path}")
    return path


# --------------------------------------------------------------------------------------------
# values


@dataclass(frozen=True)
class PoseSourceSpec:
    """Where one tracked body's poses come from: ``kind`` ``topic`` (a pose topic of the
    recording), ``tf`` (``child`` frame on /tf, chained up to ``parent``, None = the root) or
    ``csv`` (``path``, stamps in ``time_unit``: s, ns or auto)."""

    kind: str
    topic: str = ""
    child: str = ""
    parent: str | None = None
    path: Path | None = None
    time_unit: str = "auto"

    def describe(self) -> str:
        if self.kind == "topic":
            return f"topic {self.topic}"
        if self.kind == "tf":
            return f"TF frame '{self.child}'" + (f" in '{self.parent}'" if self.parent else "")
        return f"CSV {self.path}"


@dataclass(frozen=True, eq=False)
class TargetSpec:
    """A tracked target: its pose source and its definition (``definition`` says where the
    :class:`~rigcal.targets.definition.Target` came from: a file or ``analytic``)."""

    name: str
    pose: PoseSourceSpec
    target: Target
    definition: str


@dataclass(frozen=True, eq=False)
class SensorSpec:
    """A sensor to calibrate: ``kind`` lidar or camera, its data ``topic`` (or folder),
    ``frame_id`` in the initial calibration, measurement ``sigma`` (lidar [m], camera [px]),
    the camera model (cameras) or the lidar's :class:`~rigcal.extract.lidar.LidarSpec`."""

    name: str
    kind: SensorKind
    topic: str
    frame_id: str
    sigma: float
    camera: Any = None
    lidar: LidarSpec | None = None
    intrinsics: Path | None = None


@dataclass(frozen=True)
class ExtractionSettings:
    """Guidance and extraction settings (Charron et al., III-C).

    A frame is used when the target is expected in view (at least ``*_min_fraction_in_view`` of
    its keypoints, or template points, for a camera; of its template points for a lidar) and
    it moves relative to the robot by at most ``max_linear_mps`` [m/s] and ``max_angular_dps``
    [deg/s] over ``motion_window_s`` [s] around the frame. The initial calibration's 1-sigma
    errors ``sigma_translation_m`` / ``sigma_rotation_deg`` (times ``n_sigma``) size the search
    regions. ``crop_margin_px`` (None: the target's ``crop_image`` or 20 px), ``crop_pad_m``,
    ``on_template_m`` and ``min_cluster_points`` go to the extractors; ``estimate_pose`` asks the
    camera extractor for a PnP pose (not needed by the calibration)."""

    max_linear_mps: float = 0.1
    max_angular_dps: float = 5.0
    motion_window_s: float = 0.5
    sigma_translation_m: float = 0.03
    sigma_rotation_deg: float = 3.0
    n_sigma: float = 3.0
    camera_min_fraction_in_view: float = 1.0
    lidar_min_fraction_in_view: float = 0.5
    crop_margin_px: float | None = None
    crop_pad_m: float = 0.05
    on_template_m: float = 0.02
    min_cluster_points: int = 10
    estimate_pose: bool = False

    @property
    def uncertainty(self) -> PoseUncertainty:
        return PoseUncertainty(self.sigma_translation_m, math.radians(self.sigma_rotation_deg),
                               self.n_sigma)

    @property
    def max_angular_radps(self) -> float:
        return math.radians(self.max_angular_dps)


@dataclass(frozen=True, eq=False)
class MocapConfig:
    """A parsed ``mocap.yaml`` (see the module docstring). ``initial`` holds the initial
    extrinsics read from ``initial_calibration`` (None: read the recording's /tf_static when
    running)."""

    source: str
    recording: Path
    robot: PoseSourceSpec
    targets: Mapping[str, TargetSpec]
    robot_frame: str
    sensors: tuple[SensorSpec, ...]
    initial_calibration: Path | None = None
    initial: Extrinsics | None = None
    max_gap_s: float = DEFAULT_MAX_GAP_S
    #: the longest gap left by dropped samples (a NaN burst) that is interpolated over; None:
    #: DROPOUT_SAMPLES sample periods of each stream (:func:`rigcal.mocap.streams.interpolate`)
    max_dropout_s: float | None = None
    extraction: ExtractionSettings = ExtractionSettings()
    options: MocapOptions = MocapOptions()
    overlays_per_sensor: int = 3

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", MappingProxyType(dict(self.targets)))

    def sensor(self, name: str) -> SensorSpec:
        for s in self.sensors:
            if s.name == name:
                return s
        raise InputError(f"{self.source}: no sensor '{name}' (sensors: "
                         f"{', '.join(s.name for s in self.sensors)})")

    def initial_T_robot_sensor(self, extrinsics: Extrinsics | None = None) -> dict[str, np.ndarray]:
        """``T_robot_sensor`` (4, 4) per sensor, looked up ``robot_frame`` <- ``frame_id`` in
        ``extrinsics`` (default: :attr:`initial`); InputError naming the sensor otherwise."""
        ext = extrinsics if extrinsics is not None else self.initial
        if ext is None:
            raise InputError(f"{self.source}: no initial calibration (initial_calibration)")
        out = {}
        for s in self.sensors:
            try:
                out[s.name] = ext.lookup(self.robot_frame, s.frame_id)
            except InputError as exc:
                raise InputError(
                    f"{self.source}: initial calibration for sensor '{s.name}' (robot_frame "
                    f"'{self.robot_frame}' <- frame_id '{s.frame_id}'): {exc}"
                ) from None
        return out


# --------------------------------------------------------------------------------------------
# parsing


def _pose_source(raw: dict, where: str, base_dir: Path) -> PoseSourceSpec:
    given = [k for k in ("topic", "tf_child", "csv") if k in raw]
    if len(given) != 1:
        raise InputError(
            f"{where}: give exactly one pose source: topic, tf_child (with optional tf_parent) "
            f"or csv; got {given or 'none'}"
        )
    if "tf_parent" in raw and given[0] != "tf_child":
        raise InputError(f"{where}.tf_parent: only a tf_child source has a parent frame")
    if "time_unit" in raw and given[0] != "csv":
        raise InputError(f"{where}.time_unit: only a csv source has a time unit")
    if given[0] == "topic":
        topic = _string(raw["topic"], f"{where}.topic")
        return PoseSourceSpec("topic", topic=topic)
    if given[0] == "tf_child":
        parent = raw.get("tf_parent")
        return PoseSourceSpec(
            "tf", child=_string(raw["tf_child"], f"{where}.tf_child"),
            parent=_string(parent, f"{where}.tf_parent") if parent is not None else None)
    unit = raw.get("time_unit", "auto")
    if unit not in ("auto", "s", "ns"):
        raise InputError(f"{where}.time_unit: expected auto, s or ns, got {unit!r}")
    return PoseSourceSpec("csv", path=_file(raw["csv"], f"{where}.csv", base_dir, "pose CSV"),
                          time_unit=unit)


def _dims(value: Any, where: str) -> dict[str, float]:
    d = _mapping(value, where, "a mapping of dimensions (name: number)")
    out: dict[str, float] = {}
    for k, v in d.items():
        if not isinstance(k, str) or not is_finite_number(v):
            raise InputError(f"{where}.{k}: expected a finite number, got {v!r}")
        out[k] = v
    return out


def _target(name: Any, raw: Any, where: str, base_dir: Path) -> TargetSpec:
    spec = _target_definition(name, raw, where, base_dir)
    where = f"{where}.{name}"
    if "use_lidar_keypoints" not in raw:
        return spec
    value = raw["use_lidar_keypoints"]
    if not isinstance(value, bool):
        raise InputError(f"{where}.use_lidar_keypoints: expected true or false, got {value!r}")
    if value and spec.target.lidar_keypoints is None:
        raise InputError(f"{where}.use_lidar_keypoints: target '{name}' has no lidar keypoints")
    return replace(spec, target=spec.target.with_params(use_lidar_keypoints=value))


def _target_definition(name: Any, raw: Any, where: str, base_dir: Path) -> TargetSpec:
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{where}: target names must be non-empty strings, got {name!r}")
    where = f"{where}.{name}"
    raw = _mapping(raw, where, "a mapping with a pose source and a definition or analytic")
    check_keys(raw, _TARGET_KEYS, where)
    pose = _pose_source(raw, where, base_dir)
    if ("definition" in raw) == ("analytic" in raw):
        raise InputError(f"{where}: give exactly one of 'definition' (a target JSON file) or "
                         "'analytic' ({kind, dims...})")
    dims = _dims(raw["dims"], f"{where}.dims") if "dims" in raw else None
    if "analytic" in raw:
        for key in ("template", "kind"):
            if key in raw:
                raise InputError(f"{where}.{key}: only a 'definition' file takes '{key}'")
        spec = dict(_mapping(raw["analytic"], f"{where}.analytic", "a mapping {kind, dims...}"))
        if "kind" not in spec:
            raise InputError(f"{where}.analytic: missing 'kind' (one of "
                             f"{', '.join(k.value for k in TargetKind)})")
        kind = TargetKind.parse(spec.pop("kind"), f"{where}.analytic.kind")
        all_dims = {**(dims or {}), **_dims(spec, f"{where}.analytic")}
        from rigcal.targets.templates import analytic_target

        try:
            target = analytic_target(kind, all_dims, name=name)
        except InputError as exc:
            raise InputError(f"{where}.analytic: {exc}") from None
        return TargetSpec(name, pose, target, "analytic")
    path = _file(raw["definition"], f"{where}.definition", base_dir, "target definition")
    template = (_file(raw["template"], f"{where}.template", base_dir, "template cloud")
                if "template" in raw else None)
    kind = (TargetKind.parse(raw["kind"], f"{where}.kind") if "kind" in raw else None)
    from rigcal.io.config.vicon_json import read_vicon_target

    try:
        target = read_vicon_target(path, name=name, kind=kind, template=template, dims=dims)
    except InputError as exc:
        raise InputError(f"{where}.definition: {exc}") from None
    return TargetSpec(name, pose, target, str(path))


def _lidar_spec(raw: dict, where: str) -> LidarSpec:
    kw: dict[str, Any] = {}
    for key, name in (("vertical_step_deg", "vertical_step_rad"),
                      ("horizontal_step_deg", "horizontal_step_rad")):
        if key in raw:
            kw[name] = math.radians(_number(raw[key], f"{where}.{key}", positive=True))
    for key in ("min_range_m", "max_range_m"):
        if key in raw:
            kw[key] = _number(raw[key], f"{where}.{key}", minimum=0.0)
    for key, name in (("elevation_fov_deg", "elevation_fov_rad"),
                      ("azimuth_fov_deg", "azimuth_fov_rad")):
        if key in raw:
            lo, hi = _pair(raw[key], f"{where}.{key}")
            kw[name] = (math.radians(lo), math.radians(hi))
    try:
        return LidarSpec(**kw)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _camera_model(raw: dict, name: str, frame_id: str, where: str, base_dir: Path
                  ) -> tuple[Any, Path]:
    if "intrinsics" not in raw:
        raise InputError(f"{where}: a camera needs 'intrinsics' (a camera file)")
    path = _file(raw["intrinsics"], f"{where}.intrinsics", base_dir, "intrinsics file")
    from rigcal.io.config.camchain import read_camera_file

    try:
        chain = read_camera_file(path)
    except InputError as exc:
        raise InputError(f"{where}.intrinsics (sensor '{name}'): {exc}") from None
    cams = chain.cameras
    if "camera" in raw:
        wanted = _string(raw["camera"], f"{where}.camera")
        if wanted not in cams:
            raise InputError(f"{where}.camera: no camera '{wanted}' in {path} (cameras: "
                             f"{', '.join(cams)})")
        return cams[wanted], path
    if len(cams) == 1:
        return next(iter(cams.values())), path
    for key in (name, frame_id):
        if key in cams:
            return cams[key], path
    raise InputError(f"{where}: {path} holds cameras {', '.join(cams)}; say which with "
                     "'camera'")


def _sensor(i: int, raw: Any, source: str, base_dir: Path) -> SensorSpec:
    where = f"{source}: sensors[{i}]"
    raw = _mapping(raw, where, "a mapping with name, kind, topic")
    for key in ("name", "kind", "topic"):
        if key not in raw:
            raise InputError(f"{where}: missing required key '{key}' (required: name, kind, "
                             "topic)")
    name = check_sensor_name(raw["name"], f"{where}.name")
    where = f"{where} ('{name}')"
    kind_text = _string(raw["kind"], f"{where}.kind").lower()
    if kind_text not in ("lidar", "camera"):
        raise InputError(f"{where}.kind: unknown sensor kind '{raw['kind']}' for mocap "
                         "calibration (expected lidar or camera)")
    kind = SensorKind(kind_text)
    check_keys(raw, _LIDAR_KEYS if kind is SensorKind.LIDAR else _CAMERA_KEYS, where)
    topic = _string(raw["topic"], f"{where}.topic")
    frame_id = _string(raw["frame_id"], f"{where}.frame_id") if "frame_id" in raw else name
    if kind is SensorKind.LIDAR:
        sigma = _number(raw.get("sigma_m", 0.01), f"{where}.sigma_m", positive=True)
        return SensorSpec(name, kind, topic, frame_id, sigma, lidar=_lidar_spec(raw, where))
    sigma = _number(raw.get("sigma_px", 1.0), f"{where}.sigma_px", positive=True)
    camera, path = _camera_model(raw, name, frame_id, where, base_dir)
    return SensorSpec(name, kind, topic, frame_id, sigma, camera=camera, intrinsics=path)


def _extraction(raw: Any, source: str) -> ExtractionSettings:
    where = f"{source}: extraction"
    raw = _mapping(raw, where)
    names = tuple(f.name for f in fields(ExtractionSettings))
    check_keys(raw, names, where)
    kw: dict[str, Any] = {}
    for key, value in raw.items():
        w = f"{where}.{key}"
        if key == "estimate_pose":
            if not isinstance(value, bool):
                raise InputError(f"{w}: expected true or false, got {value!r}")
            kw[key] = value
        elif key == "min_cluster_points":
            if not isinstance(value, int) or isinstance(value, bool) or value < 3:
                raise InputError(f"{w}: expected an integer >= 3, got {value!r}")
            kw[key] = value
        elif key == "crop_margin_px" and value is None:
            kw[key] = None
        elif key.endswith("fraction_in_view"):
            v = _number(value, w)
            if not 0 < v <= 1:
                raise InputError(f"{w}: expected a fraction in (0, 1], got {value!r}")
            kw[key] = v
        elif key in ("motion_window_s", "n_sigma"):
            kw[key] = _number(value, w, positive=True)
        else:
            kw[key] = _number(value, w, minimum=0.0)
    return ExtractionSettings(**kw)


def _options(raw: Any, source: str) -> MocapOptions:
    where = f"{source}: options"
    raw = _mapping(raw, where)
    names = tuple(f.name for f in fields(MocapOptions))
    check_keys(raw, names, where)
    defaults = MocapOptions()
    kw: dict[str, Any] = {}
    for key, value in raw.items():
        w = f"{where}.{key}"
        default = getattr(defaults, key)
        if key in ("loss", "correspondences", "estimator"):
            from rigcal.problem.mocap import CORRESPONDENCES, ESTIMATORS
            from rigcal.problem.solver import LOSSES

            allowed = {"loss": tuple(LOSSES), "correspondences": CORRESPONDENCES, "estimator": ESTIMATORS}[key]
            if value not in allowed:
                raise InputError(f"{w}: expected one of {', '.join(allowed)}, got {value!r}")
            kw[key] = value
        elif key == "target_pose_sigma":
            if value is None:
                kw[key] = None
                continue
            if not (isinstance(value, list) and len(value) == 2
                    and all(is_finite_number(v) and v > 0 for v in value)):
                raise InputError(f"{w}: expected [rotation_rad, translation_m] (two numbers "
                                 f"> 0) or null, got {value!r}")
            kw[key] = (float(value[0]), float(value[1]))
        elif key == "hold_sigma_floor":
            if not (isinstance(value, list) and len(value) == 2
                    and all(is_finite_number(v) and v >= 0 for v in value)):
                raise InputError(f"{w}: expected [rotation_rad, translation_m] (two numbers "
                                 f">= 0), got {value!r}")
            kw[key] = (float(value[0]), float(value[1]))
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise InputError(f"{w}: expected true or false, got {value!r}")
            kw[key] = value
        elif isinstance(default, int) and not isinstance(default, bool):
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise InputError(f"{w}: expected an integer >= 0, got {value!r}")
            kw[key] = value
        else:
            kw[key] = _number(value, w, minimum=0.0)
    try:
        return MocapOptions(**kw)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def read_initial_calibration(path: str | os.PathLike[str]) -> Extrinsics:
    """Initial extrinsics from the original tool's extrinsics JSON (``{to_frame, from_frame,
    transform}`` entries) or a calibration YAML (:mod:`rigcal.io.results.calibration_files`: the
    original tool's per-sensor YAML, a rigcal ``calibration.yaml`` or ``absolute.yaml``),
    chosen by content."""
    from rigcal.mocap.extrinsics import parse_extrinsics_json

    p = Path(path)
    text = read_text(p, "initial calibration")
    if text.lstrip().startswith(("{", "[")):
        return parse_extrinsics_json(text, str(p))
    from rigcal.io.results.calibration_files import parse_calibration_transforms

    cal = parse_calibration_transforms(text, str(p))
    return Extrinsics({(cal.parent_frame, child): T for child, T in cal.transforms.items()},
                      str(p))


def parse_mocap_config(text: str, source: str, base_dir: str | os.PathLike[str]) -> MocapConfig:
    """A :class:`MocapConfig` from YAML ``text``; ``source`` names the file in messages and
    relative paths are resolved against ``base_dir``."""
    base = Path(base_dir)
    data = load_yaml(text, source)
    data = _mapping(data, source, "a mapping with recording, mocap, robot_frame, sensors")
    check_keys(data, _TOP_KEYS, source)
    for key in ("recording", "mocap", "robot_frame", "sensors"):
        if key not in data:
            raise InputError(f"{source}: missing required key '{key}' (required: recording, "
                             "mocap, robot_frame, sensors)")
    rec = Path(_string(data["recording"], f"{source}: recording"))
    recording = rec if rec.is_absolute() else base / rec
    if not recording.exists():
        raise InputError(f"{source}: recording: not found: {recording}")

    mocap = _mapping(data["mocap"], f"{source}: mocap", "a mapping with robot and targets")
    check_keys(mocap, _MOCAP_KEYS, f"{source}: mocap")
    for key in ("robot", "targets"):
        if key not in mocap:
            raise InputError(f"{source}: mocap: missing required key '{key}'")
    robot_raw = _mapping(mocap["robot"], f"{source}: mocap.robot", "a pose source mapping")
    check_keys(robot_raw, _POSE_KEYS, f"{source}: mocap.robot")
    robot = _pose_source(robot_raw, f"{source}: mocap.robot", base)
    targets_raw = _mapping(mocap["targets"], f"{source}: mocap.targets",
                           "a mapping target name -> {pose source, definition}")
    if not targets_raw:
        raise InputError(f"{source}: mocap.targets: no targets")
    targets = {str(n): _target(n, r, f"{source}: mocap.targets", base)
               for n, r in targets_raw.items()}
    max_gap = _number(mocap.get("max_gap_s", DEFAULT_MAX_GAP_S), f"{source}: mocap.max_gap_s",
                      positive=True)
    max_dropout = None
    if mocap.get("max_dropout_s") is not None:
        max_dropout = _number(mocap["max_dropout_s"], f"{source}: mocap.max_dropout_s", positive=True)
    folder = not (recording.is_file() or (recording / "metadata.yaml").exists())
    if folder:
        for label, spec in [("robot", robot)] + [(f"targets.{n}", t.pose)
                                                 for n, t in targets.items()]:
            if spec.kind != "csv":
                raise InputError(f"{source}: mocap.{label}: the recording {recording} is a "
                                 f"folder, which holds no {spec.describe()}; give a csv source")

    raw_sensors = data["sensors"]
    if not isinstance(raw_sensors, list) or not raw_sensors:
        raise InputError(f"{source}: sensors: expected a non-empty list of sensors")
    sensors = tuple(_sensor(i, r, source, base) for i, r in enumerate(raw_sensors))
    names = [s.name for s in sensors]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise InputError(f"{source}: sensors: duplicate sensor names {dupes}")
    topics = [s.topic for s in sensors]
    dupes = sorted({t for t in topics if topics.count(t) > 1})
    if dupes:
        raise InputError(f"{source}: sensors: topic(s) {dupes} given for two sensors")
    if any(s.kind is SensorKind.CAMERA for s in sensors):
        for n, t in targets.items():
            if t.target.kind not in _CAMERA_TARGET_KINDS:
                raise InputError(
                    f"{source}: mocap.targets.{n}: a {t.target.kind.value} target has no camera "
                    f"extractor (cameras measure "
                    f"{', '.join(k.value for k in _CAMERA_TARGET_KINDS)})"
                )

    robot_frame = _string(data["robot_frame"], f"{source}: robot_frame")
    initial_path = None
    initial = None
    if data.get("initial_calibration") is not None:
        initial_path = _file(data["initial_calibration"], f"{source}: initial_calibration", base,
                             "initial calibration")
        try:
            initial = read_initial_calibration(initial_path)
        except InputError as exc:
            raise InputError(f"{source}: initial_calibration: {exc}") from None
    elif folder:
        raise InputError(f"{source}: initial_calibration: required with a folder recording "
                         "(there is no /tf_static to read)")

    report = _mapping(data.get("report") or {}, f"{source}: report")
    check_keys(report, _REPORT_KEYS, f"{source}: report")
    overlays = report.get("overlays_per_sensor", 3)
    if not isinstance(overlays, int) or isinstance(overlays, bool) or overlays < 0:
        raise InputError(f"{source}: report.overlays_per_sensor: expected an integer >= 0, got "
                         f"{overlays!r}")
    config = MocapConfig(
        source=source,
        recording=recording,
        robot=robot,
        targets=targets,
        robot_frame=robot_frame,
        sensors=sensors,
        initial_calibration=initial_path,
        initial=initial,
        max_gap_s=max_gap,
        max_dropout_s=max_dropout,
        extraction=_extraction(data.get("extraction") or {}, source),
        options=_options(data.get("options") or {}, source),
        overlays_per_sensor=overlays,
    )
    if initial is not None:
        config.initial_T_robot_sensor()  # every sensor must connect to the robot frame
    return config


def load_mocap_config(path: str | os.PathLike[str]) -> MocapConfig:
    """Read and parse a ``mocap.yaml`` file (paths relative to its folder)."""
    p = Path(path)
    return parse_mocap_config(read_text(p, "mocap configuration"), str(p), p.parent)

