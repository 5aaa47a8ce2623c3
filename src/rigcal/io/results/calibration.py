"""Writing a :class:`~rigcal.problem.result.CalibrationResult`.

* ``calibration.yaml`` / JSON: :meth:`CalibrationResult.to_dict`, floats at full precision;
* ``<sensor>.yaml``: the original tool's per-sensor file: ``target`` (the sensor's frame),
  ``source`` (the reference sensor's frame) and ``transform``, the 4x4 ``T_sensor_reference``
  with ``p_target = transform @ p_source``;
* ``calibration.launch``: a ROS 1 launch file with one ``tf/static_transform_publisher`` per
  non-reference sensor, publishing ``T_reference_sensor`` (the sensor's pose in the reference
  frame) as ``x y z yaw pitch roll parent child period_ms`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import invert
from rigcal.io._text import dump_yaml, json_safe
from rigcal.io.atomic import atomic_write_text, mark_output
from rigcal.io.dataset.manifest import check_sensor_name
from rigcal.problem.result import CalibrationResult

RESULT_YAML_NAME = "calibration.yaml"
LAUNCH_NAME = "calibration.launch"
TF_PERIOD_MS = 100


def _dump_yaml(data: Any) -> str:
    return dump_yaml(data, flow=False)


def result_to_yaml_text(result: CalibrationResult) -> str:
    """``result.to_dict()`` as block-style YAML in field order; floats written exactly
    (``repr``), NaN/inf as ``.nan``/``.inf``."""
    return _dump_yaml(result.to_dict())


def result_to_json_text(result: CalibrationResult) -> str:
    """``result.to_dict()`` as strict JSON (indented); NaN and infinities become ``null``,
    integer dictionary keys (board indices) become strings."""
    return json.dumps(json_safe(result.to_dict()), indent=2, allow_nan=False) + "\n"


def _sensor(result: CalibrationResult, name: str) -> Any:
    try:
        return result.sensors[name]
    except KeyError:
        raise InputError(
            f"unknown sensor '{name}' (calibrated sensors: {', '.join(result.sensors)})"
        ) from None


def _reference_frame(result: CalibrationResult) -> str:
    est = result.sensors.get(result.reference)
    return est.frame_id if est is not None else result.reference


def original_sensor_yaml_text(result: CalibrationResult, name: str) -> str:
    """The original tool's YAML for sensor ``name``: ``target`` = its frame, ``source`` = the
    reference frame, ``transform`` = ``T_sensor_reference`` (4x4 nested list)."""
    est = _sensor(result, name)
    T_sensor_reference = invert(np.asarray(est.T_reference_sensor, dtype=float))
    return _dump_yaml(
        {
            "target": est.frame_id,
            "source": _reference_frame(result),
            "transform": [[float(v) for v in row] for row in T_sensor_reference],
        }
    )


def _ros_frame(frame: str, sensor: str) -> str:
    if not frame or re.search(r"\s", frame):
        raise InputError(
            f"sensor '{sensor}': frame_id {frame!r} cannot be used in a launch file "
            "(must be non-empty without whitespace)"
        )
    return frame


def ros1_launch_text(result: CalibrationResult) -> str:
    """A ROS 1 launch file publishing every non-reference sensor's pose in the reference frame
    (``T_reference_sensor``), at full float precision (see :mod:`rigcal.io.results.tf_export`)."""
    from rigcal.io.results.tf_export import ros1_launch_text as _launch

    parent = _ros_frame(_reference_frame(result), result.reference)
    transforms = {
        _ros_frame(est.frame_id, name): np.asarray(est.T_reference_sensor, dtype=float)
        for name, est in result.sensors.items()
        if name != result.reference
    }
    return _launch(transforms, parent)


def write_results(result: CalibrationResult, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write ``calibration.yaml``, ``<sensor>.yaml`` per sensor (original format) and
    ``calibration.launch`` into ``out_dir`` (created if needed), each atomically.

    Returns the written paths in that order. Texts are all built before anything is written.
    """
    out = Path(out_dir)
    reserved = {Path(RESULT_YAML_NAME).stem.lower()}
    lowered: dict[str, str] = {}
    files: list[tuple[Path, str]] = [(out / RESULT_YAML_NAME, result_to_yaml_text(result))]
    for name in result.sensors:
        check_sensor_name(name, f"sensor '{name}'")
        if name.lower() in lowered:
            raise InputError(
                f"sensors '{lowered[name.lower()]}' and '{name}' would write the same file on "
                "a case-insensitive file system; rename one"
            )
        lowered[name.lower()] = name
        if name.lower() in reserved:
            raise InputError(
                f"sensor '{name}': its file {name}.yaml would overwrite {RESULT_YAML_NAME}; "
                "rename the sensor"
            )
        files.append((out / f"{name}.yaml", original_sensor_yaml_text(result, name)))
    files.append((out / LAUNCH_NAME, ros1_launch_text(result)))
    written = [atomic_write_text(path, text) for path, text in files]
    mark_output(out)
    return written
