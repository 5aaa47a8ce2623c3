"""The original tool's ROS accumulator YAML.

A mapping ``topic -> list of entries``, one entry per board placement, in board order::

    /lidar_detector/lidar_pattern:
      - frame_id: velodyne
        points:
          - {x: -0.13, y: 5.79, z: -0.77}
          - ...                      # P points per entry (4 circle centres, or 1 reflector)

Every entry of a topic must have the same ``frame_id`` and the same number of points P, except
that an entry with ``points: []`` (or ``null``) marks a missed detection and becomes NaN. Every
point needs ``x``, ``y`` and ``z`` (numbers; ``.nan``/``nan`` allowed). Other keys of an entry
are ignored (the format belongs to another tool). For radar topics the original tool stores a
third value in ``z`` that is not a coordinate; :func:`accumulator_points_for_kind` drops it for
2D radars.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io._text import is_number, load_yaml, read_text, type_name

_EXPECTED = "a mapping topic -> list of {frame_id, points: [{x, y, z}, ...]}"


def _coordinate(value: Any, where: str) -> float:
    if is_number(value):
        v = float(value)
    elif isinstance(value, str) and value.strip().lower() in ("nan", ".nan"):
        v = math.nan
    else:
        raise InputError(f"{where}: expected a number, got {type_name(value)} {value!r}")
    if math.isinf(v):
        raise InputError(f"{where}: expected a finite number or nan, got {value!r}")
    return v


def _parse_points(raw: Any, where: str) -> list[tuple[float, float, float]]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise InputError(f"{where}: expected a list of {{x, y, z}} points, got {type_name(raw)}")
    out = []
    for j, point in enumerate(raw):
        pwhere = f"{where}[{j}]"
        if not isinstance(point, dict):
            raise InputError(f"{pwhere}: expected a mapping {{x, y, z}}, got {type_name(point)}")
        missing = [axis for axis in ("x", "y", "z") if axis not in point]
        if missing:
            raise InputError(f"{pwhere}: missing key(s) {', '.join(missing)} (expected x, y, z)")
        out.append(tuple(_coordinate(point[axis], f"{pwhere}.{axis}") for axis in ("x", "y", "z")))
    return out  # type: ignore[return-value]


def _parse_topic(topic: str, entries: Any, source: str) -> tuple[str, np.ndarray]:
    where = f"{source}: {topic}"
    if not isinstance(entries, list):
        raise InputError(
            f"{where}: expected a list of {{frame_id, points}} entries, got {type_name(entries)}"
        )
    if not entries:
        raise InputError(f"{where}: no entries (expected one per board placement)")
    frame_id = ""
    boards: list[list[tuple[float, float, float]]] = []
    for k, entry in enumerate(entries):
        ewhere = f"{where}[{k}]"
        if not isinstance(entry, dict):
            raise InputError(
                f"{ewhere}: expected a mapping {{frame_id, points}}, got {type_name(entry)}"
            )
        missing = [key for key in ("frame_id", "points") if key not in entry]
        if missing:
            raise InputError(
                f"{ewhere}: missing key(s) {', '.join(missing)} (expected frame_id, points)"
            )
        fid = entry["frame_id"]
        if not isinstance(fid, str) or not fid.strip():
            raise InputError(f"{ewhere}.frame_id: expected a non-empty string, got {fid!r}")
        if k == 0:
            frame_id = fid
        elif fid != frame_id:
            raise InputError(
                f"{ewhere}.frame_id: '{fid}' differs from '{frame_id}' of entry 0; "
                "a topic must come from one sensor frame"
            )
        boards.append(_parse_points(entry["points"], f"{ewhere}.points"))
    sizes = {len(b) for b in boards if b}
    if not sizes:
        raise InputError(f"{where}: every entry has an empty points list (no detections)")
    if len(sizes) > 1:
        first = next(k for k, b in enumerate(boards) if b)
        bad = next(k for k, b in enumerate(boards) if b and len(b) != len(boards[first]))
        raise InputError(
            f"{where}[{bad}].points: {len(boards[bad])} points, but entry {first} has "
            f"{len(boards[first])}; every entry of a topic needs the same number of points"
        )
    num_points = sizes.pop()
    array = np.full((len(boards), num_points, 3), np.nan)
    for k, b in enumerate(boards):
        if b:
            array[k] = b
    array.setflags(write=False)
    return frame_id, array


def parse_accumulator_yaml(text: str, source: str) -> dict[str, tuple[str, np.ndarray]]:
    """Topics of an accumulator YAML ``text``: ``topic -> (frame_id, points (K, P, 3))``.

    ``points`` is a new read-only array in metres; missed detections are NaN.
    """
    data = load_yaml(text, source)
    if data is None:
        raise InputError(f"{source}: empty file, expected {_EXPECTED}")
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected {_EXPECTED}, got {type_name(data)}")
    out: dict[str, tuple[str, np.ndarray]] = {}
    for topic, entries in data.items():
        if not isinstance(topic, str):
            raise InputError(f"{source}: topic names must be strings, got {topic!r}")
        out[topic] = _parse_topic(topic, entries, source)
    return out


def read_accumulator_yaml(path: str | os.PathLike[str]) -> dict[str, tuple[str, np.ndarray]]:
    """Read an accumulator YAML file; see :func:`parse_accumulator_yaml`."""
    p = Path(path)
    return parse_accumulator_yaml(read_text(p, "accumulator YAML file"), str(p))


def accumulator_points_for_kind(
    points: np.ndarray, kind: SensorKind | str, source: str, topic: str
) -> np.ndarray:
    """Convert one topic's points (K, P, 3) to the dataset layout of ``kind``.

    lidar/camera need P == 4 (TL, TR, BL, BR) -> (K, 4, 3); radar needs P == 1 and keeps x, y
    -> (K, 2); radar3d needs P == 1 -> (K, 3). Returns a new read-only array.
    """
    kind = kind if isinstance(kind, SensorKind) else SensorKind.parse(kind, f"{source}: {topic}")
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 3 or pts.shape[2] != 3:
        raise InputError(f"{source}: {topic}: expected points of shape (K, P, 3), got {pts.shape}")
    num_points = pts.shape[1]
    if kind.is_point_cloud:
        if num_points != 4:
            raise InputError(
                f"{source}: {topic}: a {kind.value} needs 4 points (circle centres TL, TR, BL, BR) "
                f"per entry, got {num_points}"
            )
        out = pts.copy()
    else:
        if num_points != 1:
            raise InputError(
                f"{source}: {topic}: a {kind.value} needs 1 point (the reflector) per entry, "
                f"got {num_points}"
            )
        out = pts[:, 0, :2].copy() if kind is SensorKind.RADAR else pts[:, 0, :].copy()
    out.setflags(write=False)
    return out
