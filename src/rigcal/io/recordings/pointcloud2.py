"""sensor_msgs/PointCloud2 <-> :class:`PointCloudFrame`, as pure functions on message objects.

A PointCloud2 is ``height`` rows of ``width`` points; each point is ``point_step`` bytes and each
row ``row_step`` bytes (rows may be padded). Every ``PointField`` gives a ``name``, a byte
``offset`` within the point, a ``datatype`` (1 INT8, 2 UINT8, 3 INT16, 4 UINT16, 5 INT32,
6 UINT32, 7 FLOAT32, 8 FLOAT64) and a ``count``; ``is_bigendian`` gives the byte order. Bytes not
covered by a field are padding.

:func:`decode_pointcloud2` reads any such layout: ``x``, ``y``, ``z`` become ``points_xyz``
(float64); every other field keeps its name and dtype in ``fields`` (a field with count k > 1
becomes ``name_0 .. name_{k-1}``; count 0, which some drivers write, is read as 1). ``height``
> 1 gives an organised cloud. NaN points are kept unless ``remove_nan`` (which also drops the
organisation). :func:`encode_pointcloud2` builds a message of a rosbags typestore (ROS 1 or
ROS 2) from a frame. Messages are duck-typed: any object with these attributes works.
"""

from __future__ import annotations

from dataclasses import fields as dataclass_fields
from typing import Any

import numpy as np

from rigcal.errors import InputError
from rigcal.io.limits import check_points
from rigcal.recording import PointCloudFrame

__all__ = [
    "DATATYPE_DTYPES",
    "decode_pointcloud2",
    "encode_pointcloud2",
    "make_header",
    "stamp_ns",
]

DATATYPE_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
"""PointField datatype code -> numpy type code (without byte order)."""

_DTYPE_DATATYPES = {v: k for k, v in DATATYPE_DTYPES.items()}
_XYZ = ("x", "y", "z")
_NS = 1_000_000_000


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in integer nanoseconds (0 if unset)."""
    stamp = header.stamp
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def make_header(typestore: Any, t_ns: int, frame_id: str = "") -> Any:
    """A ``std_msgs/msg/Header`` of ``typestore`` (ROS 1 headers get ``seq`` 0)."""
    if t_ns < 0:
        raise InputError(f"frame '{frame_id}': cannot stamp a message at negative time {t_ns} ns")
    time_cls = typestore.types["builtin_interfaces/msg/Time"]
    header_cls = typestore.types["std_msgs/msg/Header"]
    stamp = time_cls(sec=int(t_ns // _NS), nanosec=int(t_ns % _NS))
    if "seq" in {f.name for f in dataclass_fields(header_cls)}:
        return header_cls(seq=0, stamp=stamp, frame_id=frame_id)
    return header_cls(stamp=stamp, frame_id=frame_id)


def _as_bytes_array(data: Any) -> np.ndarray:
    """A message's ``data`` (numpy uint8 array, bytes or a list of ints) as a flat uint8 array."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


def decode_pointcloud2(msg: Any, sensor: str = "", t_ns: int | None = None,
                       source: str = "PointCloud2", remove_nan: bool = False) -> PointCloudFrame:
    """Decode a PointCloud2 message of any field layout into a PointCloudFrame.

    ``t_ns`` defaults to the header stamp; ``source`` (e.g. "bag.db3: /points") names the
    message in errors. Raises InputError for a layout that does not fit the data or lacks
    x, y, z."""
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    n = height * width
    order = ">" if msg.is_bigendian else "<"
    layout: list[tuple[str, int, np.dtype, int]] = []
    names: set[str] = set()
    for f in msg.fields:
        name = str(f.name)
        code = DATATYPE_DTYPES.get(int(f.datatype))
        if code is None:
            raise InputError(
                f"{source}: field '{name}' has unknown datatype {f.datatype} (expected 1..8, "
                "INT8..FLOAT64)"
            )
        if name in names:
            raise InputError(f"{source}: field '{name}' appears twice")
        names.add(name)
        dt = np.dtype(order + code)
        count = max(int(f.count), 1)
        offset = int(f.offset)
        if offset < 0 or offset + dt.itemsize * count > point_step:
            raise InputError(
                f"{source}: field '{name}' ({dt.itemsize * count} bytes at offset {offset}) does "
                f"not fit in point_step {point_step}"
            )
        layout.append((name, offset, dt, count))
    missing = [a for a in _XYZ if a not in names]
    if missing and not (n == 0 and not names):
        raise InputError(f"{source}: point cloud has fields {[x[0] for x in layout]}, "
                         "expected x, y, z")
    for name, _, _, count in layout:
        if name in _XYZ and count != 1:
            raise InputError(f"{source}: field '{name}' has count {count}, expected 1")
    header = getattr(msg, "header", None)
    t = stamp_ns(header) if t_ns is None else int(t_ns)
    frame_id = str(getattr(header, "frame_id", "")) if header is not None else ""
    if n == 0:
        fields = {}
        for name, _, dt, count in layout:
            if name not in _XYZ:
                keys = [name] if count == 1 else [f"{name}_{k}" for k in range(count)]
                fields.update({key: np.zeros(0, dt.newbyteorder("=")) for key in keys})
        return PointCloudFrame(sensor=sensor, t_ns=t, points_xyz=np.zeros((0, 3)),
                               fields=fields, frame_id=frame_id)
    row_bytes = width * point_step
    if row_step < row_bytes:
        raise InputError(
            f"{source}: row_step {row_step} is less than width x point_step = {width} x "
            f"{point_step}"
        )
    data = _as_bytes_array(msg.data)
    need = (height - 1) * row_step + row_bytes
    if data.size < need:
        raise InputError(
            f"{source}: truncated point cloud: {height} x {width} points of {point_step} bytes "
            f"(row_step {row_step}) need {need} bytes, got {data.size}"
        )
    if row_step == row_bytes:
        records = data[:n * point_step]
    else:  # drop the padding at the end of every row
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, row_bytes),
                                               strides=(row_step, 1), writeable=False)
        records = np.ascontiguousarray(rows).reshape(-1)
    columns: dict[str, np.ndarray] = {}
    for name, offset, dt, count in layout:
        values = np.ndarray(shape=(n, count), dtype=dt, buffer=records, offset=offset,
                            strides=(point_step, dt.itemsize))
        values = values.astype(dt.newbyteorder("="))
        if count == 1:
            columns[name] = values[:, 0]
        else:
            for k in range(count):
                key = f"{name}_{k}"
                if key in names or key in columns:
                    raise InputError(f"{source}: field '{key}' appears twice")
                columns[key] = values[:, k]
    points = check_points(np.stack([columns.pop(a).astype(np.float64) for a in _XYZ], axis=1),
                          source)
    organized = (height, width) if height > 1 else None
    if remove_nan:
        keep = np.isfinite(points).all(axis=1)
        if not keep.all():
            points = points[keep]
            columns = {k: v[keep] for k, v in columns.items()}
            organized = None
    return PointCloudFrame(sensor=sensor, t_ns=t, points_xyz=points, fields=columns,
                           organized_shape=organized, frame_id=frame_id)


def encode_pointcloud2(frame: PointCloudFrame, typestore: Any, xyz_dtype: object = np.float32,
                       t_ns: int | None = None, frame_id: str | None = None) -> Any:
    """A ``sensor_msgs/msg/PointCloud2`` of ``typestore`` holding ``frame``.

    Layout: x, y, z as ``xyz_dtype`` (FLOAT32 or FLOAT64) then every field in order with its
    own datatype, packed without padding, little-endian. int64/uint64 fields do not exist in
    PointCloud2 and are refused; bool fields are written as UINT8. ``t_ns``/``frame_id``
    default to the frame's."""
    xyz = np.dtype(xyz_dtype)  # type: ignore[call-overload]
    if xyz not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise InputError(f"sensor '{frame.sensor}': xyz_dtype must be float32 or float64, "
                         f"got {xyz}")
    cols: list[tuple[str, np.ndarray]] = [
        (a, frame.points_xyz[:, k].astype(xyz.newbyteorder("<"))) for k, a in enumerate(_XYZ)
    ]
    for name, values in frame.fields.items():
        arr = np.asarray(values)
        if arr.dtype == np.bool_:
            arr = arr.astype(np.uint8)
        code = arr.dtype.str[1:]
        if code not in _DTYPE_DATATYPES:
            raise InputError(
                f"sensor '{frame.sensor}': field '{name}' has dtype {arr.dtype}, which "
                "PointCloud2 cannot hold (int8..int32, uint8..uint32, float32, float64)"
            )
        cols.append((name, arr.astype("<" + code)))
    field_cls = typestore.types["sensor_msgs/msg/PointField"]
    offsets, pos = [], 0
    for _, c in cols:
        offsets.append(pos)
        pos += c.dtype.itemsize
    point_step = pos
    record = np.dtype({"names": [f"f{k}" for k in range(len(cols))],
                       "formats": [c.dtype for _, c in cols], "offsets": offsets,
                       "itemsize": point_step})
    n = len(frame)
    table = np.zeros(n, dtype=record)
    for k, (_, c) in enumerate(cols):
        table[f"f{k}"] = c
    height, width = frame.organized_shape if frame.organized_shape else (1, n)
    msg_cls = typestore.types["sensor_msgs/msg/PointCloud2"]
    return msg_cls(
        header=make_header(typestore, frame.t_ns if t_ns is None else t_ns,
                           frame.frame_id if frame_id is None else frame_id),
        height=height,
        width=width,
        fields=[field_cls(name=name, offset=off, datatype=_DTYPE_DATATYPES[c.dtype.str[1:]],
                          count=1) for (name, c), off in zip(cols, offsets)],
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * width,
        data=np.frombuffer(table.tobytes(), dtype=np.uint8),
        is_dense=bool(np.isfinite(frame.points_xyz).all()),
    )
