"""Any calibration file rigcal reads, as one value: a parent frame and ``T_parent_child`` per
child frame. Kinds:

* ``original``: the original tool's YAML ``{source, target, transform}`` with
  ``p_target = transform @ p_source``, i.e. ``transform = T_target_source``; the parent is the
  source frame and the child the target: ``T_source_target = inverse(transform)``;
* ``relative``: a rigcal ``calibration.yaml`` (``reference``, ``sensors.<name>.frame_id`` and
  ``T_reference_sensor``); the parent is the reference sensor's frame;
* ``absolute``: a rigcal ``absolute.yaml`` (``body_frame`` and ``sensors.<name>.T_body_sensor``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid, invert
from rigcal.io._text import load_yaml, read_text, type_name


@dataclass(frozen=True, eq=False)
class CalibrationTransforms:
    kind: str
    parent_frame: str
    transforms: Mapping[str, np.ndarray]  # child frame -> T_parent_child (4, 4)
    source: str = ""
    kinds: Mapping[str, str] = field(default_factory=dict)  # child frame -> sensor kind, if known
    #: child frame -> the directions the calibration only bounds (a 2D radar's roll, pitch, z
    #: about / along its own axes), if any
    bounded: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    #: child frame -> what is written of them: {quantity: (low, high, estimate)} (m / deg)
    bounded_values: Mapping[str, Mapping[str, tuple[float, float, float]]] = field(default_factory=dict)


def _matrix(value: Any, where: str) -> np.ndarray:
    return as_rigid(value, where, tol=1e-5)


def _kinds(sensors: Mapping[str, Any]) -> dict[str, str]:
    return {
        str(entry.get("frame_id", name)): entry["kind"]
        for name, entry in sensors.items()
        if isinstance(entry.get("kind"), str)
    }


_LOCAL_DIRECTIONS = ("roll", "pitch", "z")


def _bounded(sensors: Mapping[str, Any], source: str) -> tuple[dict, dict]:
    """(frame -> bounded directions, frame -> bounded values) of a rigcal result file's sensors:
    ``bounded_directions`` (else, in older files, the keys of ``bounded``)."""
    directions, values = {}, {}
    for name, entry in sensors.items():
        frame = str(entry.get("frame_id", name))
        raw = entry.get("bounded") or {}
        dirs = entry.get("bounded_directions", list(raw) if isinstance(raw, dict) else [])
        if not isinstance(dirs, list) or any(d not in _LOCAL_DIRECTIONS for d in dirs):
            raise InputError(f"{source}: sensors.{name}.bounded_directions: expected a list of "
                             f"{', '.join(_LOCAL_DIRECTIONS)}, got {dirs!r}")
        if dirs:
            directions[frame] = tuple(dirs)
        if isinstance(raw, dict):
            vals = {k: (float(v["low"]), float(v["high"]), float(v["estimate"]))
                    for k, v in raw.items() if isinstance(v, dict) and {"low", "high", "estimate"} <= set(v)}
            if vals:
                values[frame] = vals
    return directions, values


def parse_calibration_transforms(text: str, source: str) -> CalibrationTransforms:
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a calibration mapping")
    if {"source", "target", "transform"} <= set(data):
        T = _matrix(data["transform"], f"{source}: transform")
        return CalibrationTransforms("original", str(data["source"]), {str(data["target"]): invert(T)}, source)
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise InputError(
            f"{source}: not a calibration file: expected {{source, target, transform}} (original tool), "
            "or 'sensors' with T_reference_sensor (rigcal calibration.yaml) or T_body_sensor (absolute.yaml)"
        )
    for name, entry in sensors.items():
        if not isinstance(name, str) or not isinstance(entry, dict):
            raise InputError(
                f"{source}: sensors.{name}: expected a mapping with frame_id and the sensor's "
                f"transform, got {type_name(entry)}"
            )
        frame = entry.get("frame_id", name)
        if not isinstance(frame, str) or not frame:
            raise InputError(f"{source}: sensors.{name}.frame_id: expected a frame name, got {frame!r}")
    if "body_frame" in data:
        bf = data["body_frame"]
        parent = bf.get("name", "base_link") if isinstance(bf, dict) else bf
        if not isinstance(parent, str) or not parent:
            raise InputError(f"{source}: body_frame: expected a frame name, got {type_name(parent)}")
        out = {}
        for name, entry in sensors.items():
            if "T_body_sensor" not in entry:
                raise InputError(f"{source}: sensors.{name}: missing T_body_sensor")
            out[str(entry.get("frame_id", name))] = _matrix(entry["T_body_sensor"], f"{source}: sensors.{name}.T_body_sensor")
        return CalibrationTransforms("absolute", parent, out, source, _kinds(sensors), *_bounded(sensors, source))
    ref = data.get("reference")
    if not isinstance(ref, str) or ref not in sensors:
        raise InputError(f"{source}: reference {ref!r} is not one of the sensors {list(sensors)}")
    parent = str(sensors[ref].get("frame_id", ref))
    out = {}
    for name, entry in sensors.items():
        if name == ref:
            continue
        if "T_reference_sensor" not in entry:
            raise InputError(f"{source}: sensors.{name}: missing T_reference_sensor")
        out[str(entry.get("frame_id", name))] = _matrix(entry["T_reference_sensor"], f"{source}: sensors.{name}.T_reference_sensor")
    return CalibrationTransforms("relative", parent, out, source, _kinds(sensors), *_bounded(sensors, source))


def read_calibration_transforms(path: str | os.PathLike[str]) -> CalibrationTransforms:
    p = Path(path)
    return parse_calibration_transforms(read_text(p, "calibration file"), str(p))


def read_initial_poses(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Initial guesses ``T_reference_sensor`` by sensor name from a rigcal ``calibration.yaml``
    (every sensor, the reference included)."""
    p = Path(path)
    source = str(p)
    data = load_yaml(read_text(p, "initial guesses"), source)
    sensors = data.get("sensors") if isinstance(data, dict) else None
    if not isinstance(sensors, dict):
        raise InputError(f"{source}: expected a calibration.yaml with a 'sensors' mapping")
    out = {}
    for name, entry in sensors.items():
        value = entry.get("T_reference_sensor") if isinstance(entry, dict) else None
        if value is None:
            raise InputError(f"{source}: sensors.{name}.T_reference_sensor must be a 4x4 matrix")
        out[str(name)] = np.array(_matrix(value, f"{source}: sensors.{name}.T_reference_sensor"))
    return out
