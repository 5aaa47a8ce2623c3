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
from rigcal.errors import InputError, printable
from rigcal.geometry.se3 import as_rigid
from rigcal.io._text import is_number, load_yaml, read_text, type_name
from rigcal.io.limits import MAX_ABS
from rigcal.problem.noise import COMPONENT_UNITS
from rigcal.problem.stored import TANGENT, StoredCalibration, StoredSensor


def _finite(value: Any, limit: float) -> bool:
    """True for a number (not a boolean) within ``[-limit, limit]`` (an integer of any size too)."""
    return is_number(value) and -limit <= value <= limit


def _matrix(value: Any, shape: tuple[int, int], where: str) -> np.ndarray:
    """A (rows, cols) float matrix from a YAML list of lists of numbers (no booleans, strings or
    integers too large for a float); InputError naming ``where`` otherwise."""
    rows, cols = shape
    if not isinstance(value, list):
        raise InputError(f"{where}: expected a {rows}x{cols} matrix of numbers, got {type_name(value)}")
    if len(value) != rows or not all(isinstance(r, list) and len(r) == cols for r in value):
        lengths = {len(r) if isinstance(r, list) else None for r in value}
        if not value or None in lengths:
            got = f"shape ({len(value)},)"
        elif len(lengths) == 1:
            got = f"shape ({len(value)}, {lengths.pop()})"
        else:
            got = f"rows of {', '.join(str(n) for n in sorted(lengths)[:6])} numbers"
        raise InputError(f"{where}: expected a {rows}x{cols} matrix, got {got}")
    out = np.empty(shape)
    for i, row in enumerate(value):
        for j, x in enumerate(row):
            if not is_number(x):
                raise InputError(f"{where}[{i}][{j}]: expected a number, got {type_name(x)} {printable(repr(x))[:40]}")
            try:
                out[i, j] = float(x)
            except OverflowError:
                raise InputError(f"{where}[{i}][{j}]: an integer of {len(str(abs(x)))} digits is too large "
                                 "for a number") from None
    return out


#: largest variance accepted per tangent direction (rad^2 for rotations, m^2 for translations):
#: beyond it a covariance is a unit mistake or an attack, not an uncertainty (:mod:`rigcal.io.limits`)
MAX_VARIANCE = np.array([MAX_ABS["rad"] ** 2] * 3 + [MAX_ABS["m"] ** 2] * 3)
#: smallest variance a measured direction of a sensor other than the reference may have: a std
#: of 1 nm or 1 nrad - no calibration knows a pose that well; a covariance of zeros says "no
#: uncertainty given", not "exact"
MIN_VARIANCE = 1e-18
#: most boards a calibration.yaml may say it used
MAX_BOARDS = 10 ** 9


def _covariance(value: Any, where: str) -> np.ndarray:
    C = _matrix(value, (6, 6), where)
    if not np.all(np.isfinite(C)):
        raise InputError(f"{where}: expected finite numbers, got NaN or infinity (a calibration without "
                         "uncertainty cannot be compared)")
    big = np.flatnonzero(~(np.abs(np.diag(C)) <= MAX_VARIANCE))
    if big.size or not np.all(np.abs(C) <= MAX_VARIANCE.max()):
        i = int(big[0]) if big.size else int(np.argmax(np.abs(C)) // 6)
        raise InputError(f"{where}: variance of {TANGENT[i]} is {C[i, i]:.3g}, expected at most "
                         f"{MAX_VARIANCE[i]:.0e} ({'rad' if i < 3 else 'm'} squared; rotation first, then "
                         "translation)")
    if not np.allclose(C, C.T, rtol=1e-6, atol=1e-12 * max(float(np.max(np.abs(np.diag(C)))), 1e-30)):
        i, j = np.unravel_index(int(np.argmax(np.abs(C - C.T))), C.shape)
        raise InputError(f"{where}: not symmetric (entry [{i}][{j}] is {C[i, j]:.6g}, [{j}][{i}] is {C[j, i]:.6g}); "
                         "expected a covariance matrix")
    C = 0.5 * (C + C.T)
    if float(np.min(np.linalg.eigvalsh(C))) < -1e-9 * max(float(np.max(np.abs(np.diag(C)))), 1e-30):
        raise InputError(f"{where}: not a covariance (negative eigenvalue)")
    return C


def _bounded(value: Any, where: str) -> dict[str, tuple[float, float]]:
    """Bounded directions -> (low, high) offsets from the estimate about / along the sensor's own
    axes. ``bounded_offsets`` (and ``bounded`` in older files) hold ``[low, high]`` offsets; today's
    ``bounded`` holds the pose table's absolute ranges ``{low, high, estimate}``, read as the
    offsets ``low - estimate``, ``high - estimate`` (the same to first order for the near-level
    tilts these directions are) when a hand-edited file lacks ``bounded_offsets``."""
    if value in (None, {}):
        return {}
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected a mapping of direction -> [low, high], got {type_name(value)}")
    out = {}
    for d, iv in value.items():
        if d not in TANGENT:
            raise InputError(f"{where}.{printable(d)}: unknown direction (expected one of {', '.join(TANGENT)})")
        if isinstance(iv, dict) and set(iv) == {"low", "high", "estimate"}:
            values = [iv["low"], iv["high"], iv["estimate"]]
            if not (all(_finite(x, MAX_ABS['deg']) for x in values) and values[0] <= values[2] <= values[1]):
                raise InputError(f"{where}.{d}: expected low <= estimate <= high (finite numbers), got "
                                 f"{printable(repr(iv))[:80]}")
            out[str(d)] = (float(values[0]) - float(values[2]), float(values[1]) - float(values[2]))
            continue
        if not (isinstance(iv, list) and len(iv) == 2 and all(_finite(x, MAX_ABS['deg']) for x in iv)
                and iv[0] <= iv[1]):
            raise InputError(f"{where}.{d}: expected [low, high] (finite numbers, low <= high) or "
                             f"{{low, high, estimate}}, got {printable(repr(iv))[:80]}")
        out[str(d)] = (float(iv[0]), float(iv[1]))
    return out


def _noise_model(value: Any, where: str) -> dict[str, dict[str, float]]:
    """The noise model (sensor -> component -> std); components rigcal does not know are kept
    but never used (:func:`rigcal.problem.check` reads the ones its detections need)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected a mapping sensor -> component -> std, got {type_name(value)}")
    out: dict[str, dict[str, float]] = {}
    for sensor, comps in value.items():
        if not isinstance(comps, dict):
            raise InputError(f"{where}.{printable(sensor)}: expected a mapping component -> std, got "
                             f"{type_name(comps)}")
        for comp, std in comps.items():
            unit = COMPONENT_UNITS.get(str(comp), "m").split()[0]
            limit = MAX_ABS.get(unit, MAX_ABS["m"])
            if not (_finite(std, limit) and std > 0):
                raise InputError(f"{where}.{printable(sensor)}.{printable(comp)}: expected a positive std of at "
                                 f"most {limit:g} {unit}, got {printable(repr(std))[:40]}")
            out.setdefault(str(sensor), {})[str(comp)] = float(std)
    return out


def _name(value: Any, where: str) -> str:
    """A sensor name as a manifest allows it (it names files and lands in pages and terminals)."""
    from rigcal.io.dataset.manifest import check_sensor_name

    if not isinstance(value, str):
        shown = "" if value is None else f" {printable(repr(value))[:40]}"
        raise InputError(f"{where}: expected a sensor name (a string), got {type_name(value)}{shown}")
    return check_sensor_name(value, where)


def _refuse_other_files(data: dict, source: str) -> None:
    """The files a user may give instead of calibration.yaml, each named with what to give."""
    if {"source", "target", "transform"} <= set(data):
        raise InputError(f"{source}: the original tool's per-sensor file has no uncertainty to compare with; "
                         "give rigcal's calibration.yaml")
    if "body_frame" in data:
        raise InputError(f"{source}: an absolute.yaml; give the calibration.yaml of the same result folder "
                         "(relative poses with their covariances)")
    if data.get("mode") == "mocap":
        raise InputError(f"{source}: a motion-capture calibration (mode: mocap, poses in the robot body's frame "
                         f"{printable(data.get('reference'))!r}); rigcal check and diff compare board calibrations "
                         "(rigcal calibrate's calibration.yaml: poses between sensors, their covariances and the "
                         "detections' noise model)")
    fmt = data.get("format")
    if isinstance(fmt, str) or {"status", "pairs"} <= set(data) or {"old", "new", "only_old"} <= set(data):
        what = f"a {printable(fmt)[:40]} file" if isinstance(fmt, str) else "the output of rigcal check or diff"
        raise InputError(f"{source}: {what}, not a calibration; give the calibration.yaml of a result folder")
    sensors = data.get("sensors")
    if isinstance(sensors, list) and any(isinstance(s, dict) and ("detections" in s or "topic" in s)
                                         for s in sensors):
        raise InputError(f"{source}: a dataset manifest (sensors with detections or topics), not a calibration; "
                         "rigcal check takes the calibration first: rigcal check calibration.yaml rig.yaml")


def parse_stored_calibration(text: str, source: str) -> StoredCalibration:
    """A rigcal ``calibration.yaml`` (its text; ``source`` names it in messages). Fields that a
    comparison does not use are ignored; every field it uses is checked (InputError naming the
    file and the field)."""
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected rigcal's calibration.yaml (a mapping with reference and sensors), "
                         f"got {type_name(data)}")
    _refuse_other_files(data, source)
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise InputError(f"{source}: sensors: expected a mapping of sensors with T_reference_sensor and covariance "
                         "(rigcal's calibration.yaml)")
    names = {key: _name(key, f"{source}: sensors: a sensor's name") for key in sensors}
    reference = data.get("reference")
    if not isinstance(reference, str) or reference not in sensors:
        raise InputError(f"{source}: reference: expected one of the sensors {list(names.values())}, got "
                         f"{printable(repr(reference))[:80]}")
    parsed = {}
    for key, entry in sensors.items():
        name = names[key]
        where = f"{source}: sensors.{name}"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected a mapping, got {type_name(entry)}")
        for field_name in ("kind", "T_reference_sensor", "covariance"):
            if field_name not in entry:
                raise InputError(f"{where}: missing {field_name}")
        kind = SensorKind.parse(entry["kind"], f"{where}.kind")
        frame = entry.get("frame_id", name)
        if not isinstance(frame, str) or not frame or not frame.isprintable() or len(frame) > 255:
            raise InputError(f"{where}.frame_id: expected a frame name (printable, at most 255 characters), got "
                             f"{printable(repr(frame))[:80]}")
        held = entry.get("held") or []
        if not isinstance(held, list) or not all(isinstance(h, str) and h in TANGENT for h in held):
            raise InputError(f"{where}.held: expected a list of directions ({', '.join(TANGENT)}), got "
                             f"{printable(repr(held))[:80]}")
        T = as_rigid(_matrix(entry["T_reference_sensor"], (4, 4), f"{where}.T_reference_sensor"),
                     f"{where}.T_reference_sensor", tol=1e-5)
        C = _covariance(entry["covariance"], f"{where}.covariance")
        if name == reference and not np.allclose(T, np.eye(4), rtol=0.0, atol=1e-9):
            raise InputError(f"{where}.T_reference_sensor: the reference sensor's pose in its own frame must be "
                             "the identity")
        if name != reference:
            measured = [i for i, d in enumerate(TANGENT) if d not in held]
            low = [TANGENT[i] for i in measured if C[i, i] < MIN_VARIANCE]
            if low:
                raise InputError(f"{where}.covariance: no uncertainty in {', '.join(low)} (variance below "
                                 f"{MIN_VARIANCE:g}) although they are not held; expected the covariance rigcal "
                                 "calibrate wrote (only the reference sensor's is zero)")
        bounded = _bounded(entry.get("bounded"), f"{where}.bounded")  # checked also when offsets are given
        if "bounded_offsets" in entry:
            bounded = _bounded(entry["bounded_offsets"], f"{where}.bounded_offsets")
        parsed[name] = StoredSensor(name, kind, frame, T, C, bounded, tuple(held))
    relative = {}
    rel = data.get("relative") or {}
    if not isinstance(rel, dict):
        raise InputError(f"{source}: relative: expected a mapping, got {type_name(rel)}")
    for key, entry in rel.items():
        where = f"{source}: relative.{printable(key)}"
        ends = [entry.get(k) for k in ("to", "from")] if isinstance(entry, dict) else []
        if len(ends) != 2 or not all(isinstance(e, str) and e in parsed for e in ends):
            raise InputError(f"{where}: expected 'to' and 'from' naming two sensors, and a covariance")
        relative[(ends[0], ends[1])] = _covariance(entry.get("covariance"), f"{where}.covariance")
    num = data.get("num_boards", 0)
    num = 0 if num is None else num
    if not (isinstance(num, int) and not isinstance(num, bool) and 0 <= num <= MAX_BOARDS
            or isinstance(num, float) and math.isfinite(num) and num.is_integer() and 0 <= num <= MAX_BOARDS):
        raise InputError(f"{source}: num_boards: expected a count of boards (0 to {MAX_BOARDS:,}), got "
                         f"{printable(repr(num))[:40]}")
    mode = data.get("mode") or ""
    if not isinstance(mode, str):
        raise InputError(f"{source}: mode: expected a calibration mode (mcpe, fcpe, pse), got {type_name(mode)}")
    return StoredCalibration(
        reference, parsed, relative, _noise_model(data.get("noise_model"), f"{source}: noise_model"),
        printable(mode)[:40], int(num), source, _joint(data.get("joint_covariance"), parsed, source))


def _joint(value: Any, sensors: dict, source: str) -> np.ndarray | None:
    """``joint_covariance: {sensors: [...], matrix: 6N x 6N}``, the block of ``sensors`` in their
    order (a sensor removed by hand drops out); None when absent, when it lacks a sensor, or
    when a sensor's own covariance (edited by hand) is not its diagonal block: the check then
    bounds the unknown cross terms instead (conservative)."""
    if value is None:
        return None
    where = f"{source}: joint_covariance"
    if not isinstance(value, dict) or not isinstance(value.get("sensors"), list):
        raise InputError(f"{where}: expected a mapping with 'sensors' (a list) and 'matrix'")
    names = value["sensors"]
    if not all(isinstance(nm, str) for nm in names) or len(set(names)) != len(names):
        raise InputError(f"{where}.sensors: expected distinct sensor names, got {printable(repr(names))[:120]}")
    n = 6 * len(names)
    J = _matrix(value.get("matrix"), (n, n), f"{where}.matrix")
    scale = max(float(np.max(np.abs(np.diag(J)))) if J.size else 0.0, 1e-30)
    if not np.all(np.isfinite(J)) or not np.allclose(J, J.T, rtol=1e-6, atol=1e-12 * scale):
        raise InputError(f"{where}.matrix: expected a finite symmetric matrix")
    J = 0.5 * (J + J.T)
    if float(np.min(np.linalg.eigvalsh(J))) < -1e-9 * scale:
        raise InputError(f"{where}.matrix: not a covariance (negative eigenvalue)")
    index = {str(nm): i for i, nm in enumerate(names)}
    if not set(sensors) <= set(index):
        return None  # a sensor added by hand: the joint does not describe it
    perm = np.concatenate([np.arange(6) + 6 * index[nm] for nm in sensors])
    J = J[np.ix_(perm, perm)]
    for i, (nm, sensor) in enumerate(sensors.items()):
        block = J[6 * i:6 * i + 6, 6 * i:6 * i + 6]
        if not np.allclose(block, sensor.covariance, rtol=1e-6, atol=1e-12 * scale):
            return None  # a hand-edited sensor covariance: the joint no longer describes the file
    return J


def read_stored_calibration(path: str | os.PathLike[str]) -> StoredCalibration:
    """:func:`parse_stored_calibration` of a file, or of ``calibration.yaml`` in a result folder."""
    p = Path(path)
    if p.is_dir():
        if not (p / "calibration.yaml").exists() and (p / "rig.yaml").exists():
            raise InputError(f"{printable(p)}: a dataset folder (rig.yaml), not a result folder; expected "
                             "calibration.yaml or the folder rigcal calibrate wrote it to")
        p = p / "calibration.yaml"
    return parse_stored_calibration(read_text(p, "calibration"), str(p))


__all__ = ["parse_stored_calibration", "read_stored_calibration"]
