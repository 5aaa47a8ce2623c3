"""A calibration's cameras as a Kalibr camchain (``rigcal export --format kalibr``).

The cameras of a calibration (``calibration.yaml``, ``absolute.yaml``, a motion-capture
``calibration.yaml``) in calibration order become ``cam0``, ``cam1``, ...: ``T_cn_cnm1`` from
the calibrated poses (optical frames, as Kalibr's camera frames are), ``camera_model``,
``intrinsics``, ``distortion_model``/``distortion_coeffs`` and ``resolution`` from the cameras'
intrinsics files, ``rostopic`` where known. Intrinsics come from

* ``intrinsics``: ``[(sensor or None, path)]`` - any camera file rigcal reads
  (:func:`rigcal.io.config.camchain.read_camera_file`: a Kalibr camchain, the original tool's
  JSON, a CameraInfo YAML, a calibrator INI); ``sensor`` (a sensor name or frame_id) says whose
  it is (``path#cam1`` picks one camera of a multi-camera file), else a file's cameras are
  matched to sensors by name or frame_id (a single-camera file fits a single-camera calibration);
* ``rig``: a detection rig (``rigcal detect``) or ``mocap.yaml``, whose camera sensors name
  their ``intrinsics`` file (and ``camera``, ``topic``).

Numbers are written with ``repr`` (PyYAML), so :func:`~rigcal.io.config.camchain.
parse_camchain_text` reads back the same floats.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np

import rigcal
from rigcal.errors import InputError
from rigcal.io._text import load_yaml, read_text

__all__ = ["CameraSource", "camchain_text", "rig_cameras"]


class CameraSource(NamedTuple):
    """Where one camera's intrinsics are: ``path`` (a camera file), ``camera`` (its name in a
    multi-camera file, or None) and the ROS ``topic`` (or None)."""

    path: Path
    camera: str | None = None
    topic: str | None = None


def rig_cameras(path: str | os.PathLike[str]) -> dict[str, CameraSource]:
    """``{sensor name: CameraSource}`` of the camera sensors of a detection rig or a
    ``mocap.yaml`` that name an ``intrinsics`` file (paths relative to the file's folder);
    their ``frame_id`` keys the same entries too."""
    p = Path(path)
    data = load_yaml(read_text(p, "rig file"), str(p))
    sensors = data.get("sensors") if isinstance(data, dict) else None
    if not isinstance(sensors, list):
        raise InputError(f"{p}: expected a detection rig or mocap.yaml with a 'sensors' list")
    out: dict[str, CameraSource] = {}
    for i, s in enumerate(sensors):
        if not isinstance(s, dict) or s.get("kind") != "camera" or not s.get("intrinsics"):
            continue
        file = Path(str(s["intrinsics"]))
        file = file if file.is_absolute() else p.parent / file
        camera = s.get("camera")
        topic = s.get("topic")
        src = CameraSource(file, str(camera) if camera else None, str(topic) if topic else None)
        for key in (s.get("name"), s.get("frame_id")):
            if isinstance(key, str) and key:
                out.setdefault(key, src)
    return out


def _cameras_of(cal: Any) -> list[tuple[str, str, np.ndarray]]:
    """(sensor name, frame_id, T_parent_camera) of every camera of ``cal`` in order."""
    names = dict(getattr(cal, "names", {}) or {})
    kinds = dict(cal.kinds or {})
    out = []
    if kinds.get(cal.parent_frame) == "camera" and cal.kind == "relative":
        out.append((names.get(cal.parent_frame, cal.parent_frame), cal.parent_frame, np.eye(4)))
    for frame, T in cal.transforms.items():
        if kinds.get(frame) == "camera":
            out.append((names.get(frame, frame), frame, np.asarray(T, dtype=float)))
    return out


def camchain_text(
    cal: Any,
    intrinsics: Sequence[tuple[str | None, str | os.PathLike[str]]] = (),
    rig: str | os.PathLike[str] | None = None,
) -> str:
    """The Kalibr camchain YAML of the cameras of ``cal`` (a
    :class:`~rigcal.io.results.calibration_files.CalibrationTransforms`); see the module
    docstring. InputError naming the camera when its intrinsics are missing or ambiguous."""
    from rigcal.io.config.camchain import (
        calibration_camchain,
        format_camchain,
        read_camera_file,
        select_camera,
    )

    cameras = _cameras_of(cal)
    if not cameras:
        raise InputError(
            f"{cal.source}: no camera in this calibration (a camchain lists cameras; sensor kinds "
            f"are: {', '.join(sorted(set((cal.kinds or {}).values()))) or 'unknown'})"
        )
    known = {n for n, _, _ in cameras} | {f for _, f, _ in cameras}
    sources: dict[str, CameraSource] = rig_cameras(rig) if rig is not None else {}
    loose: list[Path] = []
    for sensor, path in intrinsics:
        if sensor is None:
            loose.append(Path(path))
            continue
        if sensor not in known:
            raise InputError(
                f"--intrinsics {sensor}={path}: '{sensor}' is not a camera of the calibration "
                f"(cameras: {', '.join(n for n, _, _ in cameras)})"
            )
        text = str(path)
        file, _, camera = text.rpartition("#") if "#" in text else (text, "", "")
        sources[sensor] = CameraSource(Path(file), camera or None)
    chains = {p: read_camera_file(p) for p in loose}
    rows = []
    lines = []
    for i, (name, frame, T) in enumerate(cameras):
        src = sources.get(name) or sources.get(frame)
        if src is not None:
            chain = read_camera_file(src.path)
            key, model = select_camera(chain, str(src.path), camera=src.camera,
                                       names=(name, frame), topic=src.topic)
            topic = src.topic or chain.topics.get(key)
        else:
            own = [(p, c) for p, c in chains.items() if name in c.cameras or frame in c.cameras]
            if own:
                p, chain = own[0]
                key, model = select_camera(chain, str(p), names=(name, frame))
            elif len(chains) == 1 and len(cameras) == 1:
                p, chain = next(iter(chains.items()))
                key, model = select_camera(chain, str(p), names=(name, frame))
            else:
                raise InputError(
                    f"camera '{name}' (frame '{frame}'): no intrinsics; give --intrinsics "
                    f"{name}=FILE (any camera file) or --rig RIG.yaml naming its intrinsics"
                )
            topic = chain.topics.get(key)
        rows.append((model, T, topic))
        lines.append(f"# cam{i}: sensor '{name}', frame '{frame}'")
    text = format_camchain(calibration_camchain(rows))
    header = [
        f"# Kalibr camchain written by rigcal {rigcal.__version__} from {cal.source}",
        "# T_cn_cnm1 maps points in cam(n-1)'s optical frame into camn's (x right, y down, z forward)",
    ] + lines
    return "\n".join(header) + "\n" + text
