"""Any calibration file rigcal reads, as one value: a parent frame and ``T_parent_child`` per
child frame. Kinds:

* ``original``: the original tool's YAML ``{source, target, transform}`` with
  ``p_target = transform @ p_source``, i.e. ``transform = T_target_source``; the parent is the
  source frame and the child the target: ``T_source_target = inverse(transform)``;
* ``relative``: a rigcal ``calibration.yaml`` (``reference``, ``sensors.<name>.frame_id`` and
  ``T_reference_sensor``); the parent is the reference sensor's frame;
* ``absolute``: a rigcal ``absolute.yaml`` (``body_frame`` and ``sensors.<name>.T_body_sensor``);
* ``mocap``: a ``calibration.yaml`` of ``rigcal mocap``: ``T_reference_sensor`` relative to the
  robot's body (reference ``robot``, not a sensor); the parent is the body's frame, mocap.yaml's
  ``robot_frame`` as recorded in ``frames.reference_frame``.

Transforms are between *measured frames* (a camera's optical frame; see
:mod:`rigcal.io.results.frames`). A ``frames`` block (written by rigcal since the frame contract)
is read too: the reference frame and, per sensor, the link and measured frame it was published as
(``recorded``), so a later export without the URDF publishes the same frames.

:func:`read_initial_poses` reads nominal poses from a ``calibration.yaml`` or the robot's URDF.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid, invert
from rigcal.io._text import load_yaml, read_text, type_name


@dataclass(frozen=True, eq=False)
class CalibrationTransforms:
    kind: str  # original, relative, absolute or mocap
    parent_frame: str
    transforms: Mapping[str, np.ndarray]  # child frame -> T_parent_child (4, 4)
    source: str = ""
    kinds: Mapping[str, str] = field(default_factory=dict)  # frame -> sensor kind, if known
    #: frame -> sensor name (the reference's frame included), if known
    names: Mapping[str, str] = field(default_factory=dict)
    #: frame -> (link, measured frame, T_link_measured) recorded in the file's ``frames`` block
    recorded: Mapping[str, tuple[str, str, np.ndarray]] = field(default_factory=dict)
    urdf: str | None = None  # the URDF the recorded frames were resolved in
    #: child frame -> the directions the calibration only bounds (a 2D radar's roll, pitch, z
    #: about / along its own axes), if any
    bounded: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    #: child frame -> what is written of them: {quantity: (low, high, estimate)} (m / deg)
    bounded_values: Mapping[str, Mapping[str, tuple[float, float, float]]] = field(default_factory=dict)
    #: child frame -> the pose published with the URDF's values for its bounded directions
    #: (``kept_from_urdf`` in the ``frames`` block), ``T_reference_measured``
    kept: Mapping[str, np.ndarray] = field(default_factory=dict)


def _matrix(value: Any, where: str) -> np.ndarray:
    return as_rigid(value, where, tol=1e-5)


def _kinds(sensors: Mapping[str, Any]) -> dict[str, str]:
    return {
        str(entry.get("frame_id", name)): entry["kind"]
        for name, entry in sensors.items()
        if isinstance(entry.get("kind"), str)
    }


def _names(sensors: Mapping[str, Any]) -> dict[str, str]:
    return {str(entry.get("frame_id", name)): str(name) for name, entry in sensors.items()}


_LOCAL_DIRECTIONS = ("roll", "pitch", "z")


def _bounded(sensors: Mapping[str, Any], source: str) -> tuple[dict, dict]:
    """(frame -> bounded directions, frame -> bounded values) of a rigcal result file's sensors:
    the keys of ``bounded_offsets`` (else, in older files, of ``bounded``)."""
    directions, values = {}, {}
    for name, entry in sensors.items():
        frame = str(entry.get("frame_id", name))
        raw = entry.get("bounded") or {}
        offsets = entry.get("bounded_offsets", raw)
        dirs = list(offsets) if isinstance(offsets, dict) else offsets
        if not isinstance(dirs, list) or any(d not in _LOCAL_DIRECTIONS for d in dirs):
            raise InputError(f"{source}: sensors.{name}.bounded_offsets: expected a mapping of "
                             f"{', '.join(_LOCAL_DIRECTIONS)} -> [low, high], got {offsets!r}")
        if dirs:
            directions[frame] = tuple(dirs)
        if isinstance(raw, dict):
            vals = {k: (float(v["low"]), float(v["high"]), float(v["estimate"]))
                    for k, v in raw.items() if isinstance(v, dict) and {"low", "high", "estimate"} <= set(v)}
            if vals:
                values[frame] = vals
    return directions, values


def _kept(block: Any, source: str) -> dict[str, np.ndarray]:
    """frame_id -> ``T_reference_measured`` of the ``frames`` block's ``kept_from_urdf`` entries."""
    out = {}
    sensors = block.get("sensors") if isinstance(block, dict) else None
    for key, e in (sensors or {}).items() if isinstance(sensors, dict) else ():
        kept = e.get("kept_from_urdf") if isinstance(e, dict) else None
        if kept is None:
            continue
        where = f"{source}: frames.sensors.{key}.kept_from_urdf"
        if not isinstance(kept, dict) or "T_reference_measured" not in kept:
            raise InputError(f"{where}: expected a mapping with directions and T_reference_measured")
        out[str(e.get("frame_id", key))] = _matrix(kept["T_reference_measured"], f"{where}.T_reference_measured")
    return out


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
    from rigcal.io.results.frames import recorded_frames

    ref_frame, recorded, urdf = recorded_frames(data.get("frames"), source)
    bounded, bounded_values = _bounded(sensors, source)
    extra = {"names": _names(sensors), "recorded": recorded, "urdf": urdf, "bounded": bounded,
             "bounded_values": bounded_values, "kept": _kept(data.get("frames"), source)}
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
        return CalibrationTransforms("absolute", parent, out, source, _kinds(sensors), **extra)
    ref = data.get("reference")
    mocap = data.get("mode") == "mocap" and isinstance(ref, str) and ref not in sensors
    if not mocap and (not isinstance(ref, str) or ref not in sensors):
        raise InputError(f"{source}: reference {ref!r} is not one of the sensors {list(sensors)}")
    if mocap:  # relative to the robot's body: mocap.yaml's robot_frame, as recorded
        parent = ref_frame or str(ref)
    else:
        parent = str(sensors[ref].get("frame_id", ref))
    out = {}
    for name, entry in sensors.items():
        if name == ref:
            continue
        if "T_reference_sensor" not in entry:
            raise InputError(f"{source}: sensors.{name}: missing T_reference_sensor")
        frame = str(entry.get("frame_id", name))
        if frame == parent:
            raise InputError(f"{source}: sensors.{name}: frame_id '{frame}' is the reference frame itself")
        out[frame] = _matrix(entry["T_reference_sensor"], f"{source}: sensors.{name}.T_reference_sensor")
    return CalibrationTransforms("mocap" if mocap else "relative", parent, out, source,
                                 _kinds(sensors), **extra)


def read_calibration_transforms(path: str | os.PathLike[str]) -> CalibrationTransforms:
    p = Path(path)
    return parse_calibration_transforms(read_text(p, "calibration file"), str(p))


def _looks_like_xml(text: str) -> bool:
    return text.lstrip("\ufeff \t\r\n").startswith("<")


def initial_is_urdf(path: str | os.PathLike[str]) -> bool:
    """Whether an ``--initial`` file is a URDF (``.urdf``/``.xml``, or text starting with ``<``)."""
    p = Path(path)
    return p.suffix.lower() in (".urdf", ".xml") or _looks_like_xml(read_text(p, "initial guesses"))


def _sensor_fields(sensor: Any) -> tuple[str, str | None, str]:
    """(name, kind, frame_id) of a rig sensor: a SensorDetections-like object or a tuple."""
    if isinstance(sensor, (tuple, list)):
        name, kind, frame_id = sensor
    else:
        name, kind, frame_id = sensor.name, sensor.kind, getattr(sensor, "frame_id", "") or sensor.name
    kind = getattr(kind, "value", kind)
    return str(name), (str(kind) if kind is not None else None), str(frame_id or name)


def urdf_initial_poses(
    urdf: Any, sensors: Sequence[Any], reference: str | None = None
) -> dict[str, np.ndarray]:
    """Nominal ``T_reference_sensor`` of every sensor from the robot's parsed URDF: the pose of
    the link its ``frame_id`` names (a camera: its optical frame, see
    :mod:`rigcal.io.results.frames`) relative to the reference sensor's, by forward kinematics
    over fixed joints. ``reference`` defaults to the first sensor. InputError naming the sensor,
    its frame_id and the URDF's links when a link is missing."""
    from rigcal.io.results.frames import resolve_in_urdf
    from rigcal.io.results.urdf import forward_kinematics, link_names

    fields = [_sensor_fields(s) for s in sensors]
    if not fields:
        raise InputError(f"{urdf.source}: no sensors to take nominal poses for")
    names = [f[0] for f in fields]
    reference = reference or names[0]
    if reference not in names:
        raise InputError(f"reference sensor '{reference}' is not one of the sensors {names}")
    measured: dict[str, str] = {}
    for name, kind, frame_id in fields:
        frame, _ = resolve_in_urdf(urdf, name, kind, frame_id)
        if not frame.in_urdf:
            raise InputError(
                f"{urdf.source}: sensor '{name}' ({kind}): its frame_id '{frame_id}' is not a link "
                f"of the URDF (links: {link_names(urdf)}); set the sensor's frame_id to its "
                "link in the robot's URDF"
            )
        measured[name] = frame.measured
    out = {}
    for name in names:
        try:
            T = forward_kinematics(urdf, measured[reference], measured[name])
        except InputError as exc:
            raise InputError(
                f"sensor '{name}': no nominal pose relative to the reference '{reference}' from "
                f"the URDF: {exc}"
            ) from None
        out[name] = T
    return out


def read_initial_poses(
    path: str | os.PathLike[str],
    sensors: Sequence[Any] | None = None,
    reference: str | None = None,
) -> dict[str, np.ndarray]:
    """Initial (nominal) poses ``T_reference_sensor`` by sensor name, from

    * a rigcal ``calibration.yaml`` (every sensor, its reference included); with ``reference``
      the poses are re-expressed relative to that sensor (InputError if the file lacks it);
    * the robot's URDF (a file starting with ``<``): each sensor's pose from the link its
      ``frame_id`` names, through the chain from the reference's link
      (:func:`urdf_initial_poses`); needs ``sensors`` (the rig's sensors with name, kind and
      frame_id); ``reference`` defaults to the first sensor.
    """
    p = Path(path)
    source = str(p)
    if initial_is_urdf(p):
        from rigcal.io.results.urdf import read_urdf

        if sensors is None:
            raise InputError(
                f"{source}: a URDF as initial guesses needs the rig's sensors (their frame_ids "
                "name the URDF links)"
            )
        return urdf_initial_poses(read_urdf(p), sensors, reference)
    data = load_yaml(read_text(p, "initial guesses"), source)
    sensors_in = data.get("sensors") if isinstance(data, dict) else None
    if not isinstance(sensors_in, dict):
        raise InputError(
            f"{source}: expected a calibration.yaml with a 'sensors' mapping, or the robot's URDF"
        )
    out = {}
    for name, entry in sensors_in.items():
        value = entry.get("T_reference_sensor") if isinstance(entry, dict) else None
        if value is None:
            raise InputError(f"{source}: sensors.{name}.T_reference_sensor must be a 4x4 matrix")
        out[str(name)] = np.array(_matrix(value, f"{source}: sensors.{name}.T_reference_sensor"))
    if reference is not None:
        if reference not in out:
            raise InputError(
                f"{source}: the reference sensor '{reference}' is not in this calibration "
                f"(sensors: {', '.join(out)}); its poses cannot be related to '{reference}'"
            )
        T_file_ref = out[reference]
        if not np.array_equal(T_file_ref, np.eye(4)):
            T_ref_file = invert(T_file_ref)
            out = {name: T_ref_file @ T for name, T in out.items()}
    return out
