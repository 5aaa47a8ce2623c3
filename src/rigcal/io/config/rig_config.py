"""Detection rig configuration (``rig.yaml`` for ``rigcal detect``): where each sensor's raw
data is in a recording and how to detect the board in it.

Example::

    sensors:
      - name: lidar1
        kind: lidar
        topic: /velodyne_points
        frame_id: velodyne                       # optional, default: the messages' frame_id, else name
        detector: {roi_min: [-2, 3, -3], roi_max: [2.5, 6.5, 1]}   # optional detector settings
      - name: camera1
        kind: camera
        input: mono                              # mono (default) | stereo_cloud | stereo_pair
        topic: /camera/image_raw
        intrinsics: intrinsics.ini               # any camera file (ROS ini, CameraInfo YAML, Kalibr
                                                 # camchain, intrinsics JSON); or camera_info_topic
        camera: cam0                             # optional: which camera of a multi-camera file
      - name: camera2
        kind: camera
        input: stereo_pair
        topic: /stereo/left/image_rect
        right_topic: /stereo/right/image_rect
        stereo: {fx: 1400, fy: 1400, cx: 968, cy: 608, baseline_m: 0.12}
      - name: radar1
        kind: radar
        topic: /radar/detections
        elevation_fov_deg: 9
        detector: {rcs_min_dbsm: 5, range_max_m: 10, select: closest}
    reference: lidar1
    board: {spacing_m: 0.24, reflector_offset_m: 0.105}
    placements:                                  # optional
      stability: {tolerance_m: 0.03, min_duration_s: 1.0}
      windows_s: [[12.0, 15.5], [20.0, 23.0]]    # optional: placements given by hand (seconds)

``detector`` keys are the fields of the sensor's detector configuration (checked when the
detectors are built). Paths are relative to the file's folder. A camera's ``intrinsics`` is any
camera file :func:`rigcal.io.config.camchain.read_camera_file` reads; from a multi-camera file
(a Kalibr camchain) the camera is ``camera``, else the one whose ``rostopic`` is the sensor's
topic, else the one named like the sensor or its frame_id. Without ``frame_id`` the sensor's
frame is the ``header.frame_id`` of its messages (when they carry one), else its name.
"""

from __future__ import annotations

import math
import os
import stat
from dataclasses import dataclass, field, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from rigcal.dataset import DEFAULT_MAX_ELEVATION_DEG, BoardGeometry, SensorKind
from rigcal.detect.placements import NS, StabilityRule
from rigcal.errors import InputError
from rigcal.io._text import (
    check_keys,
    is_number,
    load_yaml,
    nonempty_string,
    read_text,
    type_name,
)
from rigcal.io.limits import check_scalar, path_stat
from rigcal.io.dataset.manifest import check_sensor_name, parse_board

INPUTS = {
    SensorKind.LIDAR: ("cloud",),
    SensorKind.CAMERA: ("mono", "stereo_cloud", "stereo_pair"),
    SensorKind.RADAR: ("radar",),
    SensorKind.RADAR3D: ("radar",),
}
_SENSOR_KEYS = (
    "name", "kind", "input", "topic", "right_topic", "frame_id", "intrinsics",
    "camera_info_topic", "stereo", "elevation_fov_deg", "detector", "camera",
)
_TOP_KEYS = ("sensors", "reference", "board", "placements")
_PLACEMENT_KEYS = ("stability", "windows_s", "min_sensors")
_STABILITY_KEYS = tuple(f.name for f in fields(StabilityRule))


@dataclass(frozen=True)
class SensorSetup:
    name: str
    kind: SensorKind
    input: str
    topic: str
    frame_id: str
    right_topic: str | None = None
    intrinsics: Path | None = None
    camera_info_topic: str | None = None
    stereo: Mapping[str, float] = field(default_factory=dict)
    max_elevation_rad: float = math.radians(DEFAULT_MAX_ELEVATION_DEG)
    detector: Mapping[str, Any] = field(default_factory=dict)
    #: False: ``frame_id`` defaulted to the name (the messages' frame_id replaces it if known)
    frame_id_given: bool = True
    #: the camera of a multi-camera intrinsics file (a Kalibr camchain's ``cam1``)
    camera: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stereo", MappingProxyType(dict(self.stereo)))
        object.__setattr__(self, "detector", MappingProxyType(dict(self.detector)))


@dataclass(frozen=True)
class DetectionRig:
    sensors: tuple[SensorSetup, ...]
    reference: str | None = None
    board: BoardGeometry = BoardGeometry()
    stability: StabilityRule = StabilityRule()
    windows_ns: tuple[tuple[int, int], ...] | None = None
    min_sensors: int = 1
    source: str = ""

    def sensor(self, name: str) -> SensorSetup:
        for s in self.sensors:
            if s.name == name:
                return s
        raise InputError(f"{self.source}: no sensor '{name}'")


def _parse_sensor(i: int, raw: Any, source: str, base_dir: Path) -> SensorSetup:
    where = f"{source}: sensors[{i}]"
    if not isinstance(raw, dict):
        raise InputError(f"{where}: expected a mapping with name, kind, topic, got {type_name(raw)}")
    if "topic" not in raw and "detections" in raw:
        raise InputError(
            f"{where}: has 'detections' and no 'topic': {source} is a dataset manifest "
            "(detection files), not a detection rig (raw data); calibrate it directly: "
            f"rigcal calibrate {source}"
        )
    for key in ("name", "kind", "topic"):
        if key not in raw:
            raise InputError(f"{where}: missing required key '{key}' (required: name, kind, topic)")
    check_keys(raw, _SENSOR_KEYS, where)
    name = check_sensor_name(raw["name"], f"{where}.name")
    kind = SensorKind.parse(nonempty_string(raw["kind"], f"{where}.kind"), f"{where}.kind")
    allowed = INPUTS[kind]
    inp = raw.get("input", allowed[0])
    if inp not in allowed:
        raise InputError(f"{where}.input: '{inp}' is not an input of a {kind.value} (allowed: {', '.join(allowed)})")
    topic = nonempty_string(raw["topic"], f"{where}.topic")
    right = raw.get("right_topic")
    if inp == "stereo_pair":
        if right is None:
            raise InputError(f"{where}: input stereo_pair needs right_topic")
        right = nonempty_string(right, f"{where}.right_topic")
        stereo = raw.get("stereo")
        need = ("fx", "fy", "cx", "cy", "baseline_m")
        if not isinstance(stereo, dict) or any(k not in stereo for k in need):
            raise InputError(f"{where}.stereo: input stereo_pair needs {{{', '.join(need)}}} of the rectified pair")
        check_keys(stereo, need, f"{where}.stereo")
        for k, v in stereo.items():
            if not is_number(v) or (k in ("fx", "fy", "baseline_m") and not v > 0):
                raise InputError(f"{where}.stereo.{k}: expected a positive number, got {v!r}")
            check_scalar(v, f"{where}.stereo", k, "m" if k == "baseline_m" else "px")
    elif right is not None:
        raise InputError(f"{where}.right_topic: only input stereo_pair has a right topic")
    intrinsics = raw.get("intrinsics")
    cam_info = raw.get("camera_info_topic")
    if inp == "mono":
        if intrinsics is None and cam_info is None:
            raise InputError(f"{where}: a mono camera needs intrinsics (file) or camera_info_topic")
    if intrinsics is not None:
        p = Path(nonempty_string(intrinsics, f"{where}.intrinsics"))
        intrinsics = p if p.is_absolute() else base_dir / p
        st = path_stat(intrinsics, "camera intrinsics file")
        if st is None or not stat.S_ISREG(st.st_mode):
            raise InputError(f"{where}.intrinsics: file not found: {intrinsics}")
    if cam_info is not None:
        cam_info = nonempty_string(cam_info, f"{where}.camera_info_topic")
    elev = raw.get("elevation_fov_deg", DEFAULT_MAX_ELEVATION_DEG)
    if not is_number(elev) or not 0 < elev <= 90:
        raise InputError(f"{where}.elevation_fov_deg: expected degrees in (0, 90], got {elev!r}")
    det = raw.get("detector", {}) or {}
    if not isinstance(det, dict):
        raise InputError(f"{where}.detector: expected a mapping of detector settings, got {type_name(det)}")
    frame_id = raw.get("frame_id")
    camera = raw.get("camera")
    if camera is not None:
        if intrinsics is None:
            raise InputError(f"{where}.camera: names a camera of the intrinsics file; give intrinsics")
        camera = nonempty_string(camera, f"{where}.camera")
    return SensorSetup(
        name=name,
        kind=kind,
        input=inp,
        topic=topic,
        frame_id=nonempty_string(frame_id, f"{where}.frame_id") if frame_id is not None else name,
        right_topic=right,
        intrinsics=intrinsics,
        camera_info_topic=cam_info,
        stereo={k: float(v) for k, v in (raw.get("stereo") or {}).items()},
        max_elevation_rad=math.radians(float(elev)),
        detector=det,
        frame_id_given=frame_id is not None,
        camera=camera,
    )


def _windows_ns(windows: Any, where: str) -> tuple[tuple[int, int], ...]:
    """``windows_s`` ([[start, end], ...] in seconds of the recording's clock) in nanoseconds;
    each bound finite and within :data:`~rigcal.io.limits.MAX_ABS` ``["s"]``, end after start."""
    if not isinstance(windows, list) or not windows:
        raise InputError(f"{where}: expected a non-empty list of [start, end] in seconds, got "
                         f"{type_name(windows) if not isinstance(windows, list) else 'an empty list'}")
    out = []
    for k, w in enumerate(windows):
        if not (isinstance(w, list) and len(w) == 2):
            raise InputError(f"{where}[{k}]: expected [start, end] in seconds, got {w!r}")
        for j, x in enumerate(w):
            if not is_number(x):
                raise InputError(f"{where}[{k}][{j}]: expected a number of seconds, got {x!r}")
            check_scalar(x, f"{where}[{k}][{j}]", "time", "s")
        a, b = (float(x) for x in w)
        if not b > a:
            raise InputError(
                f"{where}[{k}]: end {b:g} s is not after start {a:g} s; expected [start, end]"
            )
        out.append((int(round(a * NS)), int(round(b * NS))))
    return tuple(out)


def parse_rig_config(text: str, source: str, base_dir: str | os.PathLike[str]) -> DetectionRig:
    data = load_yaml(text, source)
    if not isinstance(data, dict) or "sensors" not in data:
        raise InputError(f"{source}: expected a mapping with a 'sensors' list")
    check_keys(data, _TOP_KEYS, source)
    raw = data["sensors"]
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{source}: sensors: expected a non-empty list")
    sensors = tuple(_parse_sensor(i, r, source, Path(base_dir)) for i, r in enumerate(raw))
    names = [s.name for s in sensors]
    if len(set(names)) != len(names):
        raise InputError(f"{source}: duplicate sensor names: {names}")
    reference = data.get("reference")
    if reference is not None and reference not in names:
        raise InputError(f"{source}: reference: unknown sensor '{reference}' (sensors: {', '.join(names)})")
    pl = data.get("placements") or {}
    if not isinstance(pl, dict):
        raise InputError(f"{source}: placements: expected a mapping")
    check_keys(pl, _PLACEMENT_KEYS, f"{source}: placements")
    st = pl.get("stability") or {}
    if not isinstance(st, dict):
        raise InputError(f"{source}: placements.stability: expected a mapping")
    check_keys(st, _STABILITY_KEYS, f"{source}: placements.stability")
    for k, v in st.items():
        if not is_number(v) or not v >= 0:
            raise InputError(f"{source}: placements.stability.{k}: expected a number >= 0, got {v!r}")
        unit = "m" if k.endswith("_m") else "s" if k.endswith("_s") else "1"
        check_scalar(v, f"{source}: placements.stability", k, unit)
    stability = StabilityRule(**{k: (int(v) if k == "min_frames" else float(v)) for k, v in st.items()})
    windows = pl.get("windows_s")
    windows_ns = None
    if windows is not None:
        windows_ns = _windows_ns(windows, f"{source}: placements.windows_s")
    min_sensors = pl.get("min_sensors", 1)
    if not isinstance(min_sensors, int) or min_sensors < 1:
        raise InputError(f"{source}: placements.min_sensors: expected an integer >= 1")
    return DetectionRig(
        sensors=sensors,
        reference=reference,
        board=parse_board(data.get("board"), source),
        stability=stability,
        windows_ns=windows_ns,
        min_sensors=min_sensors,
        source=source,
    )


def load_rig_config(path: str | os.PathLike[str]) -> DetectionRig:
    p = Path(path)
    return parse_rig_config(read_text(p, "rig configuration"), str(p), p.parent)
