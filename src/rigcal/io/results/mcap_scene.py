"""A verification scene for Foxglove: an MCAP file written with Foxglove's own schemas.

What a calibration engineer opens to see whether a calibration is right: the calibrated frame
tree, and on it what every sensor measured of the board - the lidar's and the cameras' four
circle centres, the reflector, a 2D radar's detection as the arc of points it cannot tell apart
(its range and azimuth over its elevation field of view) - with a line per board and sensor pair
from where one sensor puts a point to where the other measured it, coloured by that error; with
a recording, its point clouds and images in the calibrated frames.

Topics (Foxglove protobuf schemas, written by the ``foxglove-sdk`` package: the ``mcap`` extra):

=============================  ===========================  ====================================
topic                          schema                       content
=============================  ===========================  ====================================
``/tf_static``                 ``foxglove.FrameTransforms``  every static transform, once, at the
                                                            scene's start
``/rigcal/detections/<name>``  ``foxglove.SceneUpdate``     one message per board placement the
                                                            sensor detected: one entity
                                                            ``<name>/board<k>`` in its frame
``/rigcal/residuals``          ``foxglove.SceneUpdate``     one message per board: one entity
                                                            ``<pair>/board<k>`` per sensor pair
                                                            (a line per compared point, in the
                                                            observing sensor's frame)
``/rigcal/points/<name>``      ``foxglove.PointCloud``      a recording's clouds (float32 x, y,
                                                            z and its other fields)
``/rigcal/image/<name>``       ``foxglove.RawImage``        a recording's images (mono8/bgr8)
=============================  ===========================  ====================================

Entity metadata (``KeyValuePair``) carry the numbers: ``sensor``, ``board``, ``kind`` for a
detection; ``pair``, ``board``, ``error_m`` (the board's RMS error, as ``per_board_m`` in
calibration.yaml) and ``red_at_m`` (the error drawn fully red: 3x the pair's RMSE) for a residual.
MCAP metadata records hold the calibration file (``rigcal.calibration``) and its verdict
(``rigcal.verdict``).

Times: with a recording, a placement's entities are logged at its start and live until its end;
without one, everything is logged at ``start_ns`` and lives for ever (every board at once).

The functions that build a :class:`Scene` are pure (arrays in, values out); :func:`write_scene`
is the only one that imports the SDK and writes (atomically).
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import InputError
from rigcal.io.results.frames import StaticTransform

TF_TOPIC = "/tf_static"
RESIDUAL_TOPIC = "/rigcal/residuals"
DETECTION_TOPIC = "/rigcal/detections/{}"
POINTS_TOPIC = "/rigcal/points/{}"
IMAGE_TOPIC = "/rigcal/image/{}"
#: a residual line is drawn fully red at this multiple of its pair's RMSE
RED_AT_RMSE = 3.0
CENTRE_SIZE_M = 0.04
REFLECTOR_SIZE_M = 0.06
ARC_POINTS = 17
#: RGBA per sensor kind
KIND_COLOURS = {
    SensorKind.LIDAR: (0.12, 0.47, 0.71, 1.0),
    SensorKind.CAMERA: (1.0, 0.5, 0.05, 1.0),
    SensorKind.RADAR: (0.84, 0.15, 0.64, 1.0),
    SensorKind.RADAR3D: (0.58, 0.4, 0.74, 1.0),
}



class BoardMarks(NamedTuple):
    """What one sensor measured of one board placement, in its frame ``frame_id`` [m]:
    ``centres`` (4, 3) circle centres (lidar, camera), ``reflector`` (3,) (derived from the
    centres, or a 3D radar's detection), ``arc`` (M, 3) a 2D radar's detection over its
    elevation field of view; None where the sensor has no such measurement."""

    sensor: str
    kind: SensorKind
    frame_id: str
    board: int
    t_ns: int
    lifetime_ns: int
    centres: np.ndarray | None
    reflector: np.ndarray | None
    arc: np.ndarray | None


class ResidualLines(NamedTuple):
    """One sensor pair on one board: segments from ``starts`` (n, 3) - the frame sensor's points
    mapped by the calibration - to ``ends`` (n, 3) - what the observer measured (a 2D radar's
    in its plane) - in the observer's frame ``frame_id``; ``error_m`` the board's RMS error,
    ``red_at_m`` the error drawn fully red."""

    pair: str
    frame_id: str
    board: int
    t_ns: int
    lifetime_ns: int
    starts: np.ndarray
    ends: np.ndarray
    error_m: float
    red_at_m: float


class SceneCloud(NamedTuple):
    """A point cloud of a recording: ``points_xyz`` (N, 3) [m] in ``frame_id``, extra per-point
    ``fields`` (N,) (intensity, ring, rcs...)."""

    topic_name: str
    frame_id: str
    t_ns: int
    points_xyz: np.ndarray
    fields: Mapping[str, np.ndarray]


class SceneImage(NamedTuple):
    """An image of a recording, uint8 (H, W) mono or (H, W, 3) BGR, in ``frame_id``."""

    topic_name: str
    frame_id: str
    t_ns: int
    image: np.ndarray


class Scene(NamedTuple):
    """Everything :func:`write_scene` writes."""

    start_ns: int
    transforms: tuple[StaticTransform, ...]
    marks: tuple[BoardMarks, ...] = ()
    residuals: tuple[ResidualLines, ...] = ()
    clouds: tuple[SceneCloud, ...] = ()
    images: tuple[SceneImage, ...] = ()
    #: MCAP metadata records: name -> {key: text}
    metadata: Mapping[str, Mapping[str, str]] = {}


class BoardTime(NamedTuple):
    """When a board placement is shown: from ``t_ns`` for ``lifetime_ns`` (0: for ever)."""

    t_ns: int
    lifetime_ns: int


# --------------------------------------------------------------------------------------------
# building a scene (pure)


def radar_arc(xy: np.ndarray, max_elevation_rad: float, n: int = ARC_POINTS) -> np.ndarray:
    """(n, 3) points of a 2D radar's detection ``xy`` (2,) [m]: its range and azimuth at every
    elevation in [-max, +max] (the radar cannot tell them apart), in the radar's frame."""
    x, y = float(xy[0]), float(xy[1])
    r, az = math.hypot(x, y), math.atan2(y, x)
    el = np.linspace(-max_elevation_rad, max_elevation_rad, n)
    return np.stack([r * np.cos(el) * math.cos(az), r * np.cos(el) * math.sin(az), r * np.sin(el)], axis=1)


def _times(dataset: Dataset, times: Mapping[int, BoardTime] | None, start_ns: int) -> dict[int, BoardTime]:
    if times is None:
        return {k: BoardTime(int(start_ns), 0) for k in range(dataset.num_boards)}
    return {int(k): BoardTime(int(t.t_ns), int(t.lifetime_ns)) for k, t in times.items()}


def _frames(dataset: Dataset, frames: Mapping[str, str]) -> dict[str, str]:
    missing = [s.name for s in dataset.sensors if s.name not in frames]
    if missing:
        raise InputError(f"scene: sensors {missing} of the detections are not in the calibration "
                         f"(calibrated: {sorted(frames)})")
    return {name: frames[name] for name in dataset.names}


def board_marks(dataset: Dataset, frames: Mapping[str, str], times: Mapping[int, BoardTime] | None = None,
                start_ns: int = 0) -> tuple[BoardMarks, ...]:
    """Every valid detection of ``dataset`` as :class:`BoardMarks` in its sensor's calibrated
    frame (``frames``: sensor name -> frame id), at ``times[board]`` (default: all at
    ``start_ns``, for ever)."""
    from rigcal.problem.pairs import reflector_points

    frame_of = _frames(dataset, frames)
    when = _times(dataset, times, start_ns)
    out = []
    for s in dataset.sensors:
        reflectors = reflector_points(s, dataset) if s.kind != SensorKind.RADAR else None
        for k in np.flatnonzero(s.valid):
            k = int(k)
            if k not in when:
                continue
            centres = np.array(s.points[k]) if s.kind.is_point_cloud else None
            reflector = np.array(reflectors[k]) if reflectors is not None else None
            arc = radar_arc(s.points[k], s.max_elevation_rad) if s.kind == SensorKind.RADAR else None
            out.append(BoardMarks(s.name, s.kind, frame_of[s.name], k, when[k].t_ns, when[k].lifetime_ns,
                                  centres, reflector, arc))
    return tuple(out)


def residual_lines(dataset: Dataset, poses: Mapping[str, np.ndarray], frames: Mapping[str, str],
                   times: Mapping[int, BoardTime] | None = None, start_ns: int = 0) -> tuple[ResidualLines, ...]:
    """Per board and comparable sensor pair, the segments between what the calibration
    (``poses``: sensor name -> ``T_reference_sensor``) predicts and what the observing sensor
    measured (:mod:`rigcal.problem.pairs`: the same anchors as the RMSE in calibration.yaml), in
    the observer's frame; a 2D radar's in its plane (the error its RMSE measures)."""
    from rigcal.geometry.se3 import invert
    from rigcal.problem.evaluate import anchor_errors
    from rigcal.problem.pairs import pair_data
    from rigcal.problem.residuals import MODEL_RADAR2D
    from rigcal.sensors.radar import project_2d

    frame_of = _frames(dataset, frames)
    missing = [n for n in dataset.names if n not in poses]
    if missing:
        raise InputError(f"scene: no calibrated pose for sensors {missing}")
    when = _times(dataset, times, start_ns)
    out = []
    for a, b in dataset.pairs:
        pair = pair_data(dataset, a, b)
        if pair is None or pair.board.size == 0:
            continue
        T_obs_frame = invert(poses[pair.observer]) @ poses[pair.frame]
        predicted = pair.points @ T_obs_frame[:3, :3].T + T_obs_frame[:3, 3]
        if pair.model == MODEL_RADAR2D:
            zeros = np.zeros((len(predicted), 1))
            starts = np.hstack([project_2d(predicted), zeros])
            ends = np.hstack([pair.measured, zeros])
        else:
            starts, ends = predicted, np.asarray(pair.measured, dtype=float)
        errors = anchor_errors(pair, poses)
        rmse = float(np.sqrt(np.mean(errors**2)))
        red_at = max(RED_AT_RMSE * rmse, 1e-9)
        for k in pair.boards:
            k = int(k)
            if k not in when:
                continue
            sel = pair.board == k
            out.append(ResidualLines(pair.label, frame_of[pair.observer], k, when[k].t_ns, when[k].lifetime_ns,
                                     starts[sel], ends[sel], float(np.sqrt(np.mean(errors[sel] ** 2))), red_at))
    return tuple(out)


def error_colour(error_m: float, red_at_m: float) -> tuple[float, float, float, float]:
    """RGBA from green (no error) through yellow (half) to red (``red_at_m`` or more)."""
    q = min(max(error_m / red_at_m, 0.0), 1.0) if math.isfinite(error_m) else 1.0
    return (min(1.0, 2.0 * q), min(1.0, 2.0 * (1.0 - q)), 0.0, 1.0)


# --------------------------------------------------------------------------------------------
# writing (foxglove-sdk)


def _stamp(m, t_ns: int):
    return m.Timestamp(sec=int(t_ns) // 1_000_000_000, nsec=int(t_ns) % 1_000_000_000)


def _duration(m, ns: int):
    return m.Duration(sec=int(ns) // 1_000_000_000, nsec=int(ns) % 1_000_000_000)


def _vec(m, p) -> Any:
    return m.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _point(m, p) -> Any:
    return m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _colour(m, rgba) -> Any:
    return m.Color(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def _pose(m, p=(0.0, 0.0, 0.0)) -> Any:
    return m.Pose(position=_vec(m, p), orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def _frame_transform(m, t: StaticTransform, t_ns: int):
    from rigcal.geometry.se3 import as_rigid
    from rigcal.mocap.streams import matrix_to_quat_xyzw

    T = as_rigid(t.T_parent_child, f"transform {t.parent} -> {t.child}", tol=1e-5)
    q = matrix_to_quat_xyzw(T[:3, :3])
    return m.FrameTransform(timestamp=_stamp(m, t_ns), parent_frame_id=t.parent, child_frame_id=t.child,
                            translation=_vec(m, T[:3, 3]),
                            rotation=m.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))


def _marks_entity(m, mk: BoardMarks):
    colour = _colour(m, KIND_COLOURS[mk.kind])
    spheres, lines = [], []
    size = m.Vector3(x=CENTRE_SIZE_M, y=CENTRE_SIZE_M, z=CENTRE_SIZE_M)
    if mk.centres is not None:
        spheres += [m.SpherePrimitive(pose=_pose(m, c), size=size, color=colour) for c in mk.centres]
    if mk.reflector is not None:
        r = REFLECTOR_SIZE_M
        spheres.append(m.SpherePrimitive(pose=_pose(m, mk.reflector), size=m.Vector3(x=r, y=r, z=r),
                                         color=_colour(m, (0.9, 0.9, 0.9, 1.0))))
    if mk.arc is not None:
        lines.append(m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, pose=_pose(m), thickness=4.0,
                                     scale_invariant=True, points=[_point(m, p) for p in mk.arc], color=colour))
    return m.SceneEntity(
        timestamp=_stamp(m, mk.t_ns), frame_id=mk.frame_id, id=f"{mk.sensor}/board{mk.board}",
        lifetime=_duration(m, mk.lifetime_ns), frame_locked=True,
        metadata=[m.KeyValuePair(key="sensor", value=mk.sensor), m.KeyValuePair(key="board", value=str(mk.board)),
                  m.KeyValuePair(key="kind", value=mk.kind.value)],
        spheres=spheres, lines=lines)


def _residual_entity(m, r: ResidualLines):
    points = [_point(m, p) for seg in zip(r.starts, r.ends) for p in seg]
    return m.SceneEntity(
        timestamp=_stamp(m, r.t_ns), frame_id=r.frame_id, id=f"{r.pair}/board{r.board}",
        lifetime=_duration(m, r.lifetime_ns), frame_locked=True,
        metadata=[m.KeyValuePair(key="pair", value=r.pair), m.KeyValuePair(key="board", value=str(r.board)),
                  m.KeyValuePair(key="error_m", value=repr(float(r.error_m))),
                  m.KeyValuePair(key="red_at_m", value=repr(float(r.red_at_m)))],
        lines=[m.LinePrimitive(type=m.LinePrimitiveLineType.LineList, pose=_pose(m), thickness=3.0,
                               scale_invariant=True, points=points,
                               color=_colour(m, error_colour(r.error_m, r.red_at_m)))])


def _point_cloud(m, c: SceneCloud):
    pts = np.asarray(c.points_xyz, dtype=float)
    names = list(c.fields)
    keep = np.all(np.isfinite(pts), axis=1)
    dtype = np.dtype([(n, "<f4") for n in ("x", "y", "z", *names)])
    rec = np.empty(int(keep.sum()), dtype=dtype)
    for i, axis in enumerate("xyz"):
        rec[axis] = pts[keep, i]
    for n in names:
        rec[n] = np.asarray(c.fields[n], dtype=float)[keep]
    fields = [m.PackedElementField(name=n, offset=4 * i, type=m.PackedElementFieldNumericType.Float32)
              for i, n in enumerate(dtype.names)]
    return m.PointCloud(timestamp=_stamp(m, c.t_ns), frame_id=c.frame_id, pose=_pose(m),
                        point_stride=dtype.itemsize, fields=fields, data=rec.tobytes())


def _raw_image(m, im: SceneImage):
    img = np.ascontiguousarray(im.image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise InputError(f"scene: image of '{im.topic_name}' must be uint8 (H, W) or (H, W, 3), got "
                         f"{img.dtype} {img.shape}")
    h, w = img.shape[:2]
    channels = 1 if img.ndim == 2 else 3
    return m.RawImage(timestamp=_stamp(m, im.t_ns), frame_id=im.frame_id, width=w, height=h,
                      encoding="mono8" if channels == 1 else "bgr8", step=w * channels, data=img.tobytes())


def scene_bytes(scene: Scene) -> bytes:
    """The MCAP file of ``scene`` (see the module docstring)."""
    from rigcal.extras import require

    foxglove = require("foxglove", "writing a Foxglove scene (MCAP)")
    from foxglove import channels as ch
    from foxglove import messages as m

    ctx = foxglove.Context()  # not the SDK's global context: nothing else logs into this file
    buf = io.BytesIO()
    writer = foxglove.open_mcap(buf, context=ctx)
    try:
        start = int(scene.start_ns)
        tf = ch.FrameTransformsChannel(TF_TOPIC, context=ctx)
        tf.log(m.FrameTransforms(transforms=[_frame_transform(m, t, start) for t in scene.transforms]),
               log_time=start)
        detections: dict[str, Any] = {}
        for mk in sorted(scene.marks, key=lambda x: (x.t_ns, x.sensor, x.board)):
            if mk.sensor not in detections:
                detections[mk.sensor] = ch.SceneUpdateChannel(DETECTION_TOPIC.format(mk.sensor), context=ctx)
            detections[mk.sensor].log(m.SceneUpdate(entities=[_marks_entity(m, mk)]), log_time=mk.t_ns)
        by_board: dict[tuple[int, int], list[ResidualLines]] = {}
        for r in scene.residuals:
            by_board.setdefault((r.t_ns, r.board), []).append(r)
        if by_board:
            residuals = ch.SceneUpdateChannel(RESIDUAL_TOPIC, context=ctx)
            for (t_ns, _), rs in sorted(by_board.items()):
                residuals.log(m.SceneUpdate(entities=[_residual_entity(m, r) for r in rs]), log_time=t_ns)
        clouds: dict[str, Any] = {}
        for c in sorted(scene.clouds, key=lambda x: x.t_ns):
            if c.topic_name not in clouds:
                clouds[c.topic_name] = ch.PointCloudChannel(POINTS_TOPIC.format(c.topic_name), context=ctx)
            clouds[c.topic_name].log(_point_cloud(m, c), log_time=c.t_ns)
        images: dict[str, Any] = {}
        for im in sorted(scene.images, key=lambda x: x.t_ns):
            if im.topic_name not in images:
                images[im.topic_name] = ch.RawImageChannel(IMAGE_TOPIC.format(im.topic_name), context=ctx)
            images[im.topic_name].log(_raw_image(m, im), log_time=im.t_ns)
        for name, record in scene.metadata.items():
            writer.write_metadata(name, {str(k): str(v) for k, v in record.items()})
    finally:
        writer.close()
    return buf.getvalue()


def write_scene(path: str | os.PathLike[str], scene: Scene) -> Path:
    """Write ``scene`` as an MCAP file at ``path``, atomically; returns the path."""
    from rigcal.io.atomic import atomic_write_bytes

    return atomic_write_bytes(path, scene_bytes(scene))


# --------------------------------------------------------------------------------------------
# a scene from rigcal's files and a recording


class CalibratedSensor(NamedTuple):
    """A sensor of a calibration file: its frame and its pose in the file's common frame."""

    frame_id: str
    T_common_sensor: np.ndarray


def calibrated_sensors(text: str, source: str) -> dict[str, CalibratedSensor]:
    """Sensor name -> :class:`CalibratedSensor` from a rigcal ``calibration.yaml``
    (``T_reference_sensor``) or ``absolute.yaml`` (``T_body_sensor``); empty for the original
    tool's file (it names frames, not sensors)."""
    from rigcal.geometry.se3 import as_rigid
    from rigcal.io._text import load_yaml

    data = load_yaml(text, source)
    sensors = data.get("sensors") if isinstance(data, dict) else None
    if not isinstance(sensors, dict):
        return {}
    out = {}
    for name, entry in sensors.items():
        if not isinstance(entry, dict):
            continue
        key = "T_reference_sensor" if "T_reference_sensor" in entry else "T_body_sensor"
        if key not in entry:
            continue
        T = as_rigid(entry[key], f"{source}: sensors.{name}.{key}", tol=1e-5)
        out[str(name)] = CalibratedSensor(str(entry.get("frame_id", name)), T)
    return out


def calibration_metadata(text: str, source: str) -> dict[str, dict[str, str]]:
    """The MCAP metadata records of a calibration file: ``rigcal.calibration`` (the file as
    written, its name) and ``rigcal.verdict`` (status and checks, as JSON) when it has one."""
    import json

    from rigcal.io._text import load_yaml

    import rigcal

    records = {"rigcal.calibration": {"file": Path(source).name, "text": text, "rigcal_version": rigcal.__version__}}
    data = load_yaml(text, source)
    verdict = data.get("verdict") if isinstance(data, dict) else None
    if isinstance(verdict, dict):
        records["rigcal.verdict"] = {"status": str(verdict.get("status", "")),
                                     "checks": json.dumps(verdict.get("checks", []), sort_keys=True)}
    else:
        records["rigcal.verdict"] = {"status": "not checked", "checks": "[]"}
    return records


def _recording_frames(recording, rig, placements, frames_of: Mapping[str, str]):
    """One frame per sensor per placement (the first from the middle of its window): the
    clouds and images of a recording scene."""
    from rigcal.detect.pipeline import _topics
    from rigcal.recording import ImageFrame, PointCloudFrame, RadarFrame, StereoFrame

    topics: dict[str, tuple[str, str]] = {}
    for setup in rig.sensors:
        if setup.name in frames_of:
            topics.update({k: v for k, v in _topics(setup).items() if not k.endswith("#right")})
    clouds, images = [], []
    for p in placements:
        mid = (p.start_ns + p.end_ns) // 2
        seen: set[str] = set()
        for f in recording.frames(topics, mid, p.end_ns):
            name = f.sensor.split("#")[0]
            if name in seen:
                continue
            seen.add(name)
            frame_id = frames_of[name]
            if isinstance(f, PointCloudFrame):
                clouds.append(SceneCloud(name, frame_id, f.t_ns, f.points_xyz, dict(f.fields)))
            elif isinstance(f, RadarFrame):
                pts = np.asarray(f.points, dtype=float)
                if pts.shape[1] == 2:
                    pts = np.hstack([pts, np.zeros((len(pts), 1))])
                clouds.append(SceneCloud(name, frame_id, f.t_ns, pts, {"rcs_dbsm": f.rcs_dbsm}))
            elif isinstance(f, ImageFrame):
                images.append(SceneImage(name, frame_id, f.t_ns, f.image))
            elif isinstance(f, StereoFrame):
                images.append(SceneImage(name, frame_id, f.t_ns, f.left))
            if len(seen) == len({k.split("#")[0] for k in topics}):
                break
    return tuple(clouds), tuple(images)


def build_scene(calibration_path: str | os.PathLike[str], transforms: Sequence[StaticTransform],
                dataset: Dataset | None = None, detection=None, recording=None, rig=None,
                measured: Mapping[str, str] | None = None) -> Scene:
    """The :class:`Scene` of a calibration file: its ``transforms`` (the frame tree the writers
    emit), metadata; with ``dataset`` (a dataset's detections) its boards and residual lines,
    all at time 0; with ``detection`` (a :class:`rigcal.detect.pipeline.DetectionRun` of
    ``recording`` with ``rig``) the detected boards at their placements' times and one cloud or
    image per sensor and placement. ``measured`` maps a sensor's ``frame_id`` to the frame its
    data are in as the writers publish it (:class:`rigcal.io.results.frames.SensorFrame`'s
    ``measured``: a camera's optical frame); default: the ``frame_id`` itself."""
    from rigcal.io._text import read_text

    source = str(calibration_path)
    text = read_text(source)
    sensors = calibrated_sensors(text, source)
    measured = dict(measured or {})
    frames = {name: measured.get(s.frame_id, s.frame_id) for name, s in sensors.items()}
    poses = {name: s.T_common_sensor for name, s in sensors.items()}
    meta = calibration_metadata(text, source)
    if detection is not None:
        dataset = detection.dataset
    if dataset is None:
        return Scene(0, tuple(transforms), metadata=meta)
    if not sensors:
        raise InputError(f"{source}: names frames, not sensors: detections cannot be placed on it "
                         "(give a rigcal calibration.yaml or absolute.yaml)")
    if detection is None:
        return Scene(0, tuple(transforms), board_marks(dataset, frames), residual_lines(dataset, poses, frames),
                     metadata=meta)
    placements = detection.placements
    if len(placements) != dataset.num_boards:
        raise InputError(f"scene: {len(placements)} placements but {dataset.num_boards} boards detected")
    times = {k: BoardTime(p.start_ns, max(p.end_ns - p.start_ns, 1)) for k, p in enumerate(placements)}
    clouds, images = _recording_frames(recording, rig, placements, frames)
    start = min([t.t_ns for t in times.values()] + [c.t_ns for c in clouds] + [i.t_ns for i in images])
    return Scene(start, tuple(transforms), board_marks(dataset, frames, times),
                 residual_lines(dataset, poses, frames, times), clouds, images, meta)


__all__ = [
    "BoardMarks", "BoardTime", "ResidualLines", "Scene", "SceneCloud", "SceneImage", "StaticTransform",
    "CalibratedSensor", "board_marks", "build_scene", "calibrated_sensors", "calibration_metadata", "error_colour", "radar_arc", "residual_lines", "scene_bytes",
    "write_scene",
]
