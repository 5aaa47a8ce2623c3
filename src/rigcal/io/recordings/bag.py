"""ROS 1 and ROS 2 bags: read sensor frames out of a recording, and write recordings.

Reading (:func:`open_bag`) goes through ``rosbags.highlevel.AnyReader`` and understands

* a ROS 1 bag (a ``.bag`` file), and
* a ROS 2 bag (a directory with ``metadata.yaml``, storage ``sqlite3`` or ``mcap``; a bare
  ``.db3``/``.mcap`` file works too).

Message definitions stored in the bag are used; bags without them (older ROS 2 bags) fall back
to the ROS 2 Humble (or, for ``.bag``, ROS 1 Noetic) definitions.

:meth:`Recording.frames` converts messages to :mod:`rigcal.recording` frames:

============================  ======================  ==========================================
message                       sensor kind             frame
============================  ======================  ==========================================
sensor_msgs/PointCloud2       lidar, camera           PointCloudFrame (all fields kept)
sensor_msgs/PointCloud2       radar / radar3d         RadarFrame: x, y (, z) and an RCS field
sensor_msgs/Image             camera                  ImageFrame (mono8, bgr8, rgb8, bgra8, rgba8)
sensor_msgs/CompressedImage   camera                  ImageFrame (jpeg, png)
sensor_msgs/CameraInfo        -                       :meth:`Recording.camera_info`
============================  ======================  ==========================================

A frame's ``t_ns`` is its header stamp; a zero stamp falls back to the bag's receive time.

Writing (:func:`write_recording`) produces real bags with rosbags' writers, atomically: the bag
is written under a temporary name next to the target and renamed into place when complete.
"""

from __future__ import annotations

import heapq
import logging
import os
import secrets
import shutil
import stat
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np

from rigcal import interrupts
from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.limits import os_error_text
from rigcal.io.clouds import radar_frame_from_cloud
from rigcal.io.recordings.images import decode_image_bytes, encode_png
from rigcal.io.recordings.pointcloud2 import (
    decode_pointcloud2,
    encode_pointcloud2,
    make_header,
    stamp_ns,
)
from rigcal.recording import Frame, ImageFrame, PointCloudFrame, RadarFrame

__all__ = [
    "BAG_FORMATS",
    "CameraInfo",
    "Recording",
    "decode_compressed_image_msg",
    "decode_image_msg",
    "open_bag",
    "write_recording",
]

log = logging.getLogger(__name__)

BAG_FORMATS = ("rosbag1", "rosbag2-sqlite3", "rosbag2-mcap")
"""Formats :func:`write_recording` writes."""

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

_IMAGE_ENCODINGS = {  # encoding -> (channels, OpenCV conversion to mono/BGR or None)
    "mono8": (1, None),
    "8uc1": (1, None),
    "bgr8": (3, None),
    "8uc3": (3, None),
    "rgb8": (3, "rgb"),
    "bgra8": (4, "bgra"),
    "rgba8": (4, "rgba"),
    "8uc4": (4, "bgra"),
}


@dataclass(frozen=True, eq=False)
class CameraInfo:
    """A camera's calibration as ``sensor_msgs/CameraInfo`` carries it.

    ``K`` (3, 3) intrinsic matrix [px], ``D`` (k,) distortion coefficients of
    ``distortion_model`` (e.g. ``plumb_bob``: k1 k2 p1 p2 k3), ``R`` (3, 3) rectification
    rotation, ``P`` (3, 4) projection matrix; ``width``/``height`` [px]."""

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    distortion_model: str = "plumb_bob"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: np.ndarray | None = None
    frame_id: str = ""
    t_ns: int = 0

    def __post_init__(self) -> None:
        def frozen(name: str, value: Any, shape: tuple[int, ...] | None) -> np.ndarray:
            arr = np.array(value, dtype=np.float64)
            if shape is not None:
                if arr.size != int(np.prod(shape)):
                    raise InputError(
                        f"camera info '{self.frame_id}': {name} needs {int(np.prod(shape))} "
                        f"values, got {arr.size}"
                    )
                arr = arr.reshape(shape)
            else:
                arr = arr.reshape(-1)
            arr.setflags(write=False)
            return arr

        object.__setattr__(self, "K", frozen("K", self.K, (3, 3)))
        object.__setattr__(self, "D", frozen("D", self.D, None))
        object.__setattr__(self, "R", frozen("R", self.R, (3, 3)))
        P = self.P
        if P is None:
            P = np.hstack([self.K, np.zeros((3, 1))])
        object.__setattr__(self, "P", frozen("P", P, (3, 4)))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "t_ns", int(self.t_ns))


# --------------------------------------------------------------------------------------------
# message -> value


def decode_image_msg(msg: Any, sensor: str = "", t_ns: int | None = None,
                     source: str = "Image") -> ImageFrame:
    """A ``sensor_msgs/Image`` as an ImageFrame (mono stays mono, colour becomes BGR).

    Encodings: mono8, bgr8, rgb8, bgra8, rgba8 (and 8UC1/8UC3/8UC4); others raise InputError
    naming the encoding."""
    encoding = str(msg.encoding)
    spec = _IMAGE_ENCODINGS.get(encoding.lower())
    if spec is None:
        raise InputError(
            f"{source}: unsupported image encoding '{encoding}' (supported: mono8, bgr8, rgb8, "
            "bgra8, rgba8)"
        )
    channels, conversion = spec
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if step < width * channels:
        raise InputError(
            f"{source}: image step {step} is less than width x channels = {width} x {channels}"
        )
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1) if not isinstance(
        msg.data, (bytes, bytearray, memoryview)) else np.frombuffer(msg.data, dtype=np.uint8)
    if data.size < height * step:
        raise InputError(
            f"{source}: truncated image: {height} rows of {step} bytes need {height * step} "
            f"bytes, got {data.size}"
        )
    img = data[:height * step].reshape(height, step)[:, :width * channels]
    img = img.reshape(height, width, channels) if channels > 1 else img
    if conversion == "rgb":
        img = img[:, :, ::-1]
    elif conversion == "bgra":
        img = img[:, :, :3]
    elif conversion == "rgba":
        img = img[:, :, 2::-1]
    header = getattr(msg, "header", None)
    return ImageFrame(sensor=sensor, t_ns=stamp_ns(header) if t_ns is None else t_ns,
                      image=np.ascontiguousarray(img),
                      frame_id=str(getattr(header, "frame_id", "")))


def decode_compressed_image_msg(msg: Any, sensor: str = "", t_ns: int | None = None,
                                source: str = "CompressedImage") -> ImageFrame:
    """A ``sensor_msgs/CompressedImage`` (jpeg or png) as an ImageFrame (mono or BGR)."""
    fmt = str(msg.format)
    if "compresseddepth" in fmt.lower():
        raise InputError(f"{source}: unsupported compressed image format '{fmt}' (depth)")
    data = msg.data if isinstance(msg.data, (bytes, bytearray, memoryview)) else np.asarray(
        msg.data, dtype=np.uint8).tobytes()
    img = decode_image_bytes(data, f"{source} ({fmt or 'no format'})")
    header = getattr(msg, "header", None)
    return ImageFrame(sensor=sensor, t_ns=stamp_ns(header) if t_ns is None else t_ns, image=img,
                      frame_id=str(getattr(header, "frame_id", "")))


def _camera_info_from_msg(msg: Any, t_ns: int) -> CameraInfo:
    def get(name: str) -> Any:  # ROS 1 spells the matrices K, D, R, P; ROS 2 k, d, r, p
        return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.lower())

    return CameraInfo(width=msg.width, height=msg.height, K=get("K"), D=get("D"),
                      distortion_model=str(msg.distortion_model), R=get("R"), P=get("P"),
                      frame_id=str(msg.header.frame_id), t_ns=t_ns)


# --------------------------------------------------------------------------------------------
# reading


def _default_typestore(path: Path) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)


def _detail(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:300]


class Recording:
    """An open bag. Use as a context manager (``with open_bag(p) as rec: ...``) or call
    :meth:`close`. Topics are named as in the bag; message types as ``pkg/msg/Type``."""

    def __init__(self, path: Path, reader: Any) -> None:
        self.path = path
        self._reader = reader

    # -- lifetime
    def close(self) -> None:
        """Close the bag (idempotent)."""
        if self._reader is not None:
            reader, self._reader = self._reader, None
            try:
                reader.close()
            except Exception as exc:  # noqa: BLE001 - closing must not mask the caller's error
                log.debug("%s: error while closing: %s", self.path, exc)

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def _open_reader(self) -> Any:
        if self._reader is None:
            raise InputError(f"{self.path}: recording is closed")
        return self._reader

    # -- what is inside
    def topics(self) -> dict[str, str]:
        """Topic -> message type (``pkg/msg/Type``; ``?`` for a topic with mixed types)."""
        return {name: info.msgtype or "?" for name, info in self._open_reader().topics.items()}

    def _topic(self, topic: str) -> Any:
        topics = self._open_reader().topics
        if topic not in topics:
            raise InputError(
                f"{self.path}: topic {topic} not in bag; topics: {sorted(topics)}"
            )
        return topics[topic]

    def count(self, topic: str) -> int:
        """Number of messages on ``topic`` (for progress bars)."""
        return int(self._topic(topic).msgcount)

    def _messages(self, connections: Sequence[Any]) -> Iterator[tuple[Any, int, Any]]:
        """(connection, receive time, deserialized message); bag errors become InputError."""
        reader = self._open_reader()
        iterator = reader.messages(connections=connections)
        while True:
            try:
                conn, recv_ns, raw = next(iterator)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 - corrupt bag data, wrapped with context
                raise InputError(f"{self.path}: cannot read messages: {_detail(exc)}") from exc
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # noqa: BLE001 - third-party decoder, wrapped with context
                raise InputError(
                    f"{self.path}: topic {conn.topic}: cannot decode {conn.msgtype} message: "
                    f"{_detail(exc)}"
                ) from exc
            yield conn, int(recv_ns), msg

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, message type, receive time [ns], deserialized message) for ``topics``, in
        bag order. InputError names an unknown topic, unreadable bag data or a message that
        does not decode."""
        connections = [c for t in topics for c in self._topic(t).connections]
        for conn, recv_ns, msg in self._messages(connections):
            yield conn.topic, conn.msgtype, recv_ns, msg

    def camera_info(self, topic: str) -> CameraInfo:
        """The first ``sensor_msgs/CameraInfo`` on ``topic``."""
        info = self._topic(topic)
        if info.msgtype != CAMERA_INFO:
            raise InputError(
                f"{self.path}: topic {topic} has type {info.msgtype}, expected {CAMERA_INFO}"
            )
        for _, recv_ns, msg in self._messages(info.connections):
            stamp = stamp_ns(msg.header)
            return _camera_info_from_msg(msg, stamp or recv_ns)
        raise InputError(f"{self.path}: topic {topic} has no messages")

    def frames(
        self,
        sensor_topics: Mapping[str, tuple[str, SensorKind | str]],
        start_ns: int | None = None,
        end_ns: int | None = None,
        *,
        rcs_field: str | Sequence[str] | None = None,
        remove_nan: bool = False,
        reorder_window_ns: int = 2_000_000_000,
    ) -> Iterator[Frame]:
        """Frames of the given sensors in order of ``t_ns`` (header stamps), within
        ``[start_ns, end_ns)`` when given.

        ``sensor_topics`` maps a sensor name to ``(topic, kind)`` with kind lidar, camera, radar
        or radar3d. ``rcs_field`` names the RCS field of radar clouds (default: the first of
        rcs, RCS, rcs0). ``remove_nan`` drops non-finite points of point clouds.

        Frames are released in stamp order as soon as every other topic has reached that stamp;
        to bound memory a frame is also released once the bag's receive time is
        ``reorder_window_ns`` past its stamp (order can then break only for messages received
        later than that; a warning is logged)."""
        plan = self._plan(sensor_topics)
        return self._iter_frames(plan, start_ns, end_ns, rcs_field, remove_nan,
                                 reorder_window_ns)

    def _iter_frames(self, plan: dict[str, tuple[str, SensorKind]], start_ns: int | None,
                     end_ns: int | None, rcs_field: str | Sequence[str] | None,
                     remove_nan: bool, reorder_window_ns: int) -> Iterator[Frame]:
        connections = [c for topic in plan for c in self._topic(topic).connections]
        remaining = {topic: self.count(topic) for topic in plan}
        latest: dict[str, int] = {}
        heap: list[tuple[int, int, Any]] = []
        seq = 0
        last_out: int | None = None
        warned = False

        def ready(t_top: int, recv_ns: int) -> bool:
            if t_top <= recv_ns - reorder_window_ns:
                return True
            return all(remaining[tp] <= 0 or latest.get(tp, -1) >= t_top for tp in plan)

        def release() -> Frame:
            nonlocal last_out, warned
            t, _, frame = heapq.heappop(heap)
            if last_out is not None and t < last_out and not warned:
                log.warning("%s: frames out of time order (a stamp lags its receive time by "
                            "more than %.1f s)", self.path, reorder_window_ns / 1e9)
                warned = True
            last_out = t if last_out is None else max(last_out, t)
            return frame

        for conn, recv_ns, msg in self._messages(connections):
            topic = conn.topic
            sensor, kind = plan[topic]
            t_ns = stamp_ns(msg.header) or recv_ns
            remaining[topic] -= 1
            latest[topic] = max(latest.get(topic, t_ns), t_ns)
            if (start_ns is None or t_ns >= start_ns) and (end_ns is None or t_ns < end_ns):
                frame = self._convert(msg, conn.msgtype, topic, sensor, kind, t_ns, rcs_field,
                                      remove_nan)
                heapq.heappush(heap, (t_ns, seq, frame))
                seq += 1
            while heap and ready(heap[0][0], recv_ns):
                yield release()
        while heap:
            yield release()

    def _plan(self, sensor_topics: Mapping[str, tuple[str, SensorKind | str]]
              ) -> dict[str, tuple[str, SensorKind]]:
        """topic -> (sensor, kind), checked against the bag's topics and types."""
        plan: dict[str, tuple[str, SensorKind]] = {}
        for sensor, spec in sensor_topics.items():
            try:
                topic, kind_value = spec
            except (TypeError, ValueError):
                raise InputError(
                    f"{self.path}: sensor '{sensor}': expected (topic, kind), got {spec!r}"
                ) from None
            kind = kind_value if isinstance(kind_value, SensorKind) else SensorKind.parse(
                kind_value, f"{self.path}: sensor '{sensor}'"
            )
            if topic in plan:
                raise InputError(
                    f"{self.path}: topic {topic} is given for sensors '{plan[topic][0]}' and "
                    f"'{sensor}'"
                )
            msgtype = self._topic(topic).msgtype
            if msgtype == CAMERA_INFO:
                raise InputError(
                    f"{self.path}: topic {topic} (sensor '{sensor}') carries CameraInfo, not "
                    "frames; read it with camera_info()"
                )
            if msgtype in (IMAGE, COMPRESSED_IMAGE) and kind is not SensorKind.CAMERA:
                raise InputError(
                    f"{self.path}: topic {topic} carries images, but sensor '{sensor}' is a "
                    f"{kind.value}"
                )
            if msgtype not in (POINTCLOUD2, IMAGE, COMPRESSED_IMAGE):
                raise InputError(
                    f"{self.path}: topic {topic} (sensor '{sensor}') has type {msgtype}; "
                    f"expected {POINTCLOUD2}, {IMAGE} or {COMPRESSED_IMAGE}"
                )
            plan[topic] = (sensor, kind)
        return plan

    def _convert(self, msg: Any, msgtype: str, topic: str, sensor: str, kind: SensorKind,
                 t_ns: int, rcs_field: str | Sequence[str] | None, remove_nan: bool) -> Frame:
        source = f"{self.path}: {topic}"
        if msgtype == IMAGE:
            return decode_image_msg(msg, sensor, t_ns, source)
        if msgtype == COMPRESSED_IMAGE:
            return decode_compressed_image_msg(msg, sensor, t_ns, source)
        cloud = decode_pointcloud2(msg, sensor, t_ns, source, remove_nan=remove_nan)
        if kind.is_radar:
            return radar_frame_from_cloud(cloud, 2 if kind is SensorKind.RADAR else 3,
                                          rcs_field, source)
        return cloud


def open_bag(path: str | os.PathLike[str]) -> Recording:
    """Open a ROS 1 bag (``.bag``) or a ROS 2 bag (a directory with ``metadata.yaml``, or a
    ``.db3``/``.mcap`` file). Returns an open :class:`Recording` (a context manager)."""
    from rosbags.highlevel import AnyReader

    p = Path(path)
    try:
        if p.name == "metadata.yaml" and p.is_file():
            p = p.parent
        st = p.stat()
    except FileNotFoundError:
        raise InputError(f"{p}: bag not found") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot open bag: {os_error_text(exc)}") from None
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise InputError(f"{p}: is not a regular file or a folder, expected a ROS1 or ROS2 bag")
    if p.is_file() and p.suffix not in (".bag", ".db3", ".mcap"):
        try:
            with p.open("rb") as fh:
                magic = fh.read(13)
        except OSError as exc:
            raise InputError(f"{p}: cannot read bag: {exc.strerror or exc}") from exc
        hint = ("it looks like a ROS1 bag; name it *.bag" if magic.startswith(b"#ROSBAG")
                else "expected a .bag file or a ROS2 bag directory with metadata.yaml")
        raise InputError(f"{p} is not a ROS1 or ROS2 bag: {hint}")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        storage = sorted(c.name for c in p.iterdir() if c.suffix.lower() in (".db3", ".mcap"))
        if storage:
            raise InputError(
                f"{p}: looks like a ROS 2 bag (has {', '.join(storage[:3])}) but metadata.yaml "
                "is missing; expected a ROS 2 bag folder with metadata.yaml (`ros2 bag reindex` "
                "rebuilds it)"
            )
        raise InputError(f"{p} is not a ROS1 or ROS2 bag: directory has no metadata.yaml")
    try:
        reader = AnyReader([p], default_typestore=_default_typestore(p))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - any failure of the third-party reader
        raise InputError(f"{p} is not a ROS1 or ROS2 bag: {_detail(exc)}") from exc
    return Recording(p, reader)


# --------------------------------------------------------------------------------------------
# writing

BagItem = Frame | CameraInfo


def _msgtype_of(item: Any, topic: str) -> str:
    if isinstance(item, (PointCloudFrame, RadarFrame)):
        return POINTCLOUD2
    if isinstance(item, ImageFrame):
        return COMPRESSED_IMAGE if topic.rstrip("/").endswith("/compressed") else IMAGE
    if isinstance(item, CameraInfo):
        return CAMERA_INFO
    raise InputError(
        f"topic {topic}: cannot write {type(item).__name__} to a bag (expected PointCloudFrame, "
        "ImageFrame, RadarFrame or CameraInfo)"
    )


def _image_msg(frame: ImageFrame, typestore: Any) -> Any:
    img = frame.image
    channels = 1 if img.ndim == 2 else 3
    return typestore.types[IMAGE](
        header=make_header(typestore, frame.t_ns, frame.frame_id),
        height=img.shape[0], width=img.shape[1],
        encoding="mono8" if channels == 1 else "bgr8", is_bigendian=0,
        step=img.shape[1] * channels,
        data=np.ascontiguousarray(img).reshape(-1).copy(),
    )


def _compressed_image_msg(frame: ImageFrame, typestore: Any, topic: str) -> Any:
    png = encode_png(frame.image, f"topic {topic}, sensor '{frame.sensor}'")
    return typestore.types[COMPRESSED_IMAGE](
        header=make_header(typestore, frame.t_ns, frame.frame_id), format="png",
        data=np.frombuffer(png, dtype=np.uint8).copy(),
    )


def _camera_info_msg(info: CameraInfo, typestore: Any) -> Any:
    cls = typestore.types[CAMERA_INFO]
    names = {f for f in cls.__dataclass_fields__}
    upper = "K" in names
    roi = typestore.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    matrices = {"D": info.D, "K": info.K, "R": info.R, "P": info.P}
    kwargs = {(k if upper else k.lower()): np.asarray(v, dtype=np.float64).reshape(-1).copy()
              for k, v in matrices.items()}
    return cls(header=make_header(typestore, info.t_ns, info.frame_id), height=info.height,
               width=info.width, distortion_model=info.distortion_model, binning_x=0,
               binning_y=0, roi=roi, **kwargs)


def _message(item: Any, msgtype: str, topic: str, typestore: Any, xyz_dtype: object) -> Any:
    if isinstance(item, RadarFrame):
        pts = item.points
        xyz = pts if pts.shape[1] == 3 else np.hstack([pts, np.zeros((len(pts), 1))])
        cloud = PointCloudFrame(sensor=item.sensor, t_ns=item.t_ns, points_xyz=xyz,
                                fields={"rcs": item.rcs_dbsm.astype(np.float32)},
                                frame_id=item.frame_id)
        return encode_pointcloud2(cloud, typestore, xyz_dtype)
    if isinstance(item, PointCloudFrame):
        return encode_pointcloud2(item, typestore, xyz_dtype)
    if isinstance(item, CameraInfo):
        return _camera_info_msg(item, typestore)
    if msgtype == COMPRESSED_IMAGE:
        return _compressed_image_msg(item, typestore, topic)
    return _image_msg(item, typestore)


def _write_bag(target: Path, items: list[tuple[int, int, str, str, Any]], fmt: str,
               xyz_dtype: object) -> None:
    from rosbags.typesys import Stores, get_typestore

    if fmt == "rosbag1":
        from rosbags.rosbag1 import Writer as Writer1

        typestore = get_typestore(Stores.ROS1_NOETIC)
        writer: Any = Writer1(target)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

        typestore = get_typestore(Stores.ROS2_HUMBLE)
        plugin = StoragePlugin.MCAP if fmt == "rosbag2-mcap" else StoragePlugin.SQLITE3
        writer = Writer2(target, version=Writer2.VERSION_LATEST, storage_plugin=plugin)
    serialize = typestore.serialize_ros1 if fmt == "rosbag1" else typestore.serialize_cdr
    with writer:
        connections: dict[str, Any] = {}
        for t_ns, _, topic, msgtype, item in items:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
            try:
                msg = _message(item, msgtype, topic, typestore, xyz_dtype)
            except InputError as exc:
                raise InputError(f"topic {topic}: {exc}") from exc
            writer.write(connections[topic], t_ns, serialize(msg, msgtype))


def write_recording(
    path: str | os.PathLike[str],
    frames_by_topic: Mapping[str, Iterable[BagItem]],
    format: str = "rosbag1",  # noqa: A002 - the natural name for a file format
    *,
    xyz_dtype: object = np.float32,
) -> Path:
    """Write frames to a real bag; returns its path.

    ``frames_by_topic`` maps a topic to its items, all of one kind: PointCloudFrame and
    RadarFrame become ``sensor_msgs/PointCloud2`` (radar: fields x, y, z (0 for a 2D radar),
    rcs), ImageFrame becomes ``sensor_msgs/Image`` (mono8/bgr8) or, on a topic ending in
    ``/compressed``, a PNG ``sensor_msgs/CompressedImage``; CameraInfo becomes
    ``sensor_msgs/CameraInfo``. Header stamp and receive time are the item's ``t_ns``; messages
    are written in time order. ``format``: rosbag1 (``path`` must end in ``.bag``),
    rosbag2-sqlite3 or rosbag2-mcap (``path`` is the bag directory). An existing bag at
    ``path`` is replaced only once the new one is complete."""
    if format not in BAG_FORMATS:
        raise InputError(f"{path}: unknown bag format '{format}' (expected one of "
                         f"{', '.join(BAG_FORMATS)})")
    target = Path(path)
    if format == "rosbag1" and target.suffix != ".bag":
        raise InputError(f"{target}: a rosbag1 file must end in .bag")
    if format != "rosbag1" and target.suffix == ".bag":
        raise InputError(f"{target}: a ROS2 bag is a directory; do not name it *.bag")
    items: list[tuple[int, int, str, str, Any]] = []
    for topic, frames in frames_by_topic.items():
        if not topic.startswith("/"):
            raise InputError(f"{target}: topic '{topic}' must start with '/'")
        types = set()
        for item in frames:
            msgtype = _msgtype_of(item, topic)
            types.add(msgtype)
            if int(item.t_ns) < 0:
                raise InputError(f"{target}: topic {topic}: negative time {item.t_ns} ns")
            items.append((int(item.t_ns), len(items), topic, msgtype, item))
        if len(types) > 1:
            raise InputError(f"{target}: topic {topic} mixes message types {sorted(types)}")
    items.sort(key=lambda x: (x[0], x[1]))

    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{target.parent}: cannot create output directory: "
                         f"{exc.strerror or exc}") from exc
    staging = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
    try:
        staging.mkdir()
        _write_bag(staging / target.name, items, format, xyz_dtype)
        _replace(staging / target.name, target)
    except Exception as exc:  # noqa: BLE001 - rosbags writer errors, wrapped with context
        raise InputError(f"{target}: cannot write bag: {_detail(exc)}") from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def _replace(new: Path, target: Path) -> None:
    """Move ``new`` to ``target``; an existing target (file or directory) is swapped out."""
    interrupts.raise_if_requested()
    if target.exists() and (target.is_dir() or new.is_dir()):
        old = target.parent / f".{target.name}.{secrets.token_hex(6)}.old"
        os.replace(target, old)
        try:
            os.replace(new, target)
        except BaseException:
            os.replace(old, target)
            raise
        if old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)
    else:
        os.replace(new, target)
