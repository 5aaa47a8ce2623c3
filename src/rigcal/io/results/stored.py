"""Reading a rigcal ``calibration.yaml`` back as a :class:`~rigcal.problem.stored.StoredCalibration`
(poses, covariances, bounded directions, relative covariances and the noise model): what
``rigcal check`` and ``rigcal diff`` compare against.

Only rigcal's relative calibration carries what a comparison needs (each pose's covariance); the
original tool's per-sensor YAML and ``absolute.yaml`` are refused with a message naming the file
to give instead.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid
from rigcal.io._text import is_number, load_yaml, read_text, type_name
from rigcal.problem.stored import TANGENT, StoredCalibration, StoredSensor


def _covariance(value: Any, where: str) -> np.ndarray:
    try:
        C = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected a 6x6 matrix of numbers, got {type_name(value)}") from None
    if C.shape != (6, 6):
        raise InputError(f"{where}: expected a 6x6 matrix, got shape {C.shape}")
    if not np.all(np.isfinite(C)):
        raise InputError(f"{where}: expected finite numbers, got NaN or infinity (a calibration without "
                         "uncertainty cannot be compared)")
    C = 0.5 * (C + C.T)
    if float(np.min(np.linalg.eigvalsh(C))) < -1e-9 * max(float(np.max(np.abs(np.diag(C)))), 1e-30):
        raise InputError(f"{where}: not a covariance (negative eigenvalue)")
    return C


def _bounded(value: Any, where: str) -> dict[str, tuple[float, float]]:
    """Bounded directions -> (low, high) offsets from the estimate about / along the sensor's own
    axes: ``bounded_offsets`` (older files: ``bounded``; now ``bounded`` holds the pose table's
    absolute ranges)."""
    if value in (None, {}):
        return {}
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected a mapping of direction -> [low, high], got {type_name(value)}")
    out = {}
    for d, iv in value.items():
        if d not in TANGENT:
            raise InputError(f"{where}.{d}: unknown direction (expected one of {', '.join(TANGENT)})")
        if not (isinstance(iv, (list, tuple)) and len(iv) == 2 and all(is_number(x) for x in iv)):
            raise InputError(f"{where}.{d}: expected [low, high], got {iv!r}")
        out[str(d)] = (float(iv[0]), float(iv[1]))
    return out


def _noise_model(value: Any, where: str) -> dict[str, dict[str, float]]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected a mapping sensor -> component -> std, got {type_name(value)}")
    out: dict[str, dict[str, float]] = {}
    for sensor, comps in value.items():
        if not isinstance(comps, dict):
            raise InputError(f"{where}.{sensor}: expected a mapping component -> std, got {type_name(comps)}")
        for comp, std in comps.items():
            if not (is_number(std) and math.isfinite(std) and std > 0):
                raise InputError(f"{where}.{sensor}.{comp}: expected a positive std, got {std!r}")
            out.setdefault(str(sensor), {})[str(comp)] = float(std)
    return out


def parse_stored_calibration(text: str, source: str) -> StoredCalibration:
    """A rigcal ``calibration.yaml`` (its text; ``source`` names it in messages)."""
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected rigcal's calibration.yaml (a mapping with reference and sensors), "
                         f"got {type_name(data)}")
    if {"source", "target", "transform"} <= set(data):
        raise InputError(f"{source}: the original tool's per-sensor file has no uncertainty to compare with; "
                         "give rigcal's calibration.yaml")
    if "body_frame" in data:
        raise InputError(f"{source}: an absolute.yaml; give the calibration.yaml of the same result folder "
                         "(relative poses with their covariances)")
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise InputError(f"{source}: sensors: expected a mapping of sensors with T_reference_sensor and covariance "
                         "(rigcal's calibration.yaml)")
    reference = data.get("reference")
    if not isinstance(reference, str) or reference not in sensors:
        raise InputError(f"{source}: reference: expected one of the sensors {list(sensors)}, got {reference!r}")
    parsed = {}
    for name, entry in sensors.items():
        where = f"{source}: sensors.{name}"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected a mapping, got {type_name(entry)}")
        for key in ("kind", "T_reference_sensor", "covariance"):
            if key not in entry:
                raise InputError(f"{where}: missing {key}")
        kind = SensorKind.parse(entry["kind"], f"{where}.kind")
        frame = entry.get("frame_id", name)
        if not isinstance(frame, str) or not frame:
            raise InputError(f"{where}.frame_id: expected a frame name, got {frame!r}")
        held = entry.get("held") or []
        if not isinstance(held, list) or not all(h in TANGENT for h in held):
            raise InputError(f"{where}.held: expected a list of directions ({', '.join(TANGENT)}), got {held!r}")
        parsed[str(name)] = StoredSensor(
            str(name), kind, frame, as_rigid(entry["T_reference_sensor"], f"{where}.T_reference_sensor", tol=1e-5),
            _covariance(entry["covariance"], f"{where}.covariance"), _bounded(entry["bounded_offsets"], f"{where}.bounded_offsets") if "bounded_offsets" in entry
            else _bounded(entry.get("bounded"), f"{where}.bounded"),
            tuple(held))
    relative = {}
    rel = data.get("relative") or {}
    if not isinstance(rel, dict):
        raise InputError(f"{source}: relative: expected a mapping, got {type_name(rel)}")
    for key, entry in rel.items():
        where = f"{source}: relative.{key}"
        if not isinstance(entry, dict) or entry.get("to") not in parsed or entry.get("from") not in parsed:
            raise InputError(f"{where}: expected 'to' and 'from' naming two sensors, and a covariance")
        relative[(entry["to"], entry["from"])] = _covariance(entry.get("covariance"), f"{where}.covariance")
    num = data.get("num_boards", 0)
    return StoredCalibration(
        reference, parsed, relative, _noise_model(data.get("noise_model"), f"{source}: noise_model"),
        str(data.get("mode") or ""), int(num) if is_number(num) else 0, source)


def read_stored_calibration(path: str | os.PathLike[str]) -> StoredCalibration:
    """:func:`parse_stored_calibration` of a file, or of ``calibration.yaml`` in a result folder."""
    p = Path(path)
    if p.is_dir():
        p = p / "calibration.yaml"
    return parse_stored_calibration(read_text(p, "calibration"), str(p))


__all__ = ["parse_stored_calibration", "read_stored_calibration"]
