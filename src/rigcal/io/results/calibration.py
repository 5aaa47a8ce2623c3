"""Writing a :class:`~rigcal.problem.result.CalibrationResult`.

Every file names frames by the frame contract (:mod:`rigcal.io.results.frames`): one
:class:`~rigcal.io.results.frames.FramePlan` per result (with the robot's URDF when the
calibration took its nominal poses from one), used by all of them.

* ``calibration.yaml`` / JSON: :meth:`CalibrationResult.to_dict`, floats at full precision, plus
  a ``frames`` block (:func:`rigcal.io.results.frames.frames_block`: the convention, the frame
  the poses are relative to, each sensor's link and measured frame, and the static transforms
  every writer publishes, with quaternions);
* ``<sensor>.yaml``: the original tool's per-sensor file: ``target`` (the sensor's measured
  frame), ``source`` (the reference's measured frame) and ``transform``, the 4x4
  ``T_sensor_reference`` with ``p_target = transform @ p_source``;
* ``calibration.launch``: a ROS 1 launch file with one ``tf2_ros static_transform_publisher``
  per static transform of the plan (``x y z qx qy qz qw parent child``, on ``/tf_static``).
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
    if est is not None:
        return est.frame_id
    return result.reference_frame or result.reference


def calibration_transforms(result: CalibrationResult) -> Any:
    """The result as :class:`~rigcal.io.results.calibration_files.CalibrationTransforms` (what
    a reader of ``calibration.yaml`` gets): ``{frame_id: T_reference_sensor}`` relative to the
    reference's frame (motion capture: the robot body's ``reference_frame``), with the sensors'
    kinds and names. InputError when two sensors share a frame_id."""
    from rigcal.io.results.calibration_files import CalibrationTransforms

    parent = _reference_frame(result)
    transforms: dict[str, np.ndarray] = {}
    owner: dict[str, str] = {parent: result.reference}
    for name, est in result.sensors.items():
        if name == result.reference:
            continue
        if est.frame_id in owner:
            raise InputError(
                f"sensors '{owner[est.frame_id]}' and '{name}' share the frame_id "
                f"'{est.frame_id}'; a TF tree needs one frame per sensor (set frame_id in the "
                "manifest)"
            )
        owner[est.frame_id] = name
        transforms[est.frame_id] = np.asarray(est.T_reference_sensor, dtype=float)
    kind = "relative" if result.reference in result.sensors else "mocap"
    return CalibrationTransforms(
        kind, parent, transforms, "calibration",
        {est.frame_id: est.kind.value for est in result.sensors.values()},
        names={est.frame_id: name for name, est in result.sensors.items()},
        bounded={est.frame_id: tuple(est.bounded) for est in result.sensors.values() if est.bounded},
        bounded_values={est.frame_id: est.bounded_values for est in result.sensors.values() if est.bounded},
    )


def frame_plan(result: CalibrationResult, urdf: Any = None, body_link: str | None = None) -> Any:
    """The :class:`~rigcal.io.results.frames.FramePlan` of a result (resolved in ``urdf``, a
    parsed URDF, when given)."""
    from rigcal.io.results.frames import plan_frames

    return plan_frames(calibration_transforms(result), urdf, body_link)


def _with_frames(result: CalibrationResult, plan: Any) -> dict[str, Any]:
    from rigcal.io.results.frames import frames_block

    data = result.to_dict()
    data["frames"] = frames_block(plan if plan is not None else frame_plan(result))
    return data


def result_to_yaml_text(result: CalibrationResult, plan: Any = None) -> str:
    """``result.to_dict()`` and its ``frames`` block (of ``plan``, default: the result's own
    frame plan) as block-style YAML in field order; floats written exactly (``repr``),
    NaN/inf as ``.nan``/``.inf``."""
    return _dump_yaml(_with_frames(result, plan))


def result_to_json_text(result: CalibrationResult, plan: Any = None) -> str:
    """The same data as :func:`result_to_yaml_text` as strict JSON (indented); NaN and
    infinities become ``null``, integer dictionary keys (board indices) become strings."""
    return json.dumps(json_safe(_with_frames(result, plan)), indent=2, allow_nan=False) + "\n"


def original_sensor_yaml_text(result: CalibrationResult, name: str, plan: Any = None) -> str:
    """The original tool's YAML for sensor ``name``: ``target`` = its measured frame, ``source``
    = the reference's measured frame (the frame plan's names), ``transform`` =
    ``T_sensor_reference`` (4x4 nested list)."""
    est = _sensor(result, name)
    plan = plan if plan is not None else frame_plan(result)
    # what every writer publishes (a bounded direction may keep the URDF's value)
    measured = plan.sensor_frame(est.frame_id).measured
    T_sensor_reference = invert(invert(plan.T_root(plan.reference.measured)) @ plan.T_root(measured))
    return _dump_yaml(
        {
            "target": plan.sensor_frame(est.frame_id).measured,
            "source": plan.reference.measured,
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


def ros1_launch_text(result: CalibrationResult, plan: Any = None) -> str:
    """A ROS 1 launch file publishing the static transforms of the result's frame plan (every
    non-reference sensor's pose relative to the reference frame, and any optical joints), at
    full float precision (see :mod:`rigcal.io.results.tf_export`)."""
    from rigcal.io.results.tf_export import ros1_launch_text as _launch

    for name, est in result.sensors.items():
        _ros_frame(est.frame_id, name)
    plan = plan if plan is not None else frame_plan(result)
    return _launch(plan.transforms)


def write_results(result: CalibrationResult, out_dir: str | os.PathLike[str],
                  urdf: Any = None) -> list[Path]:
    """Write ``calibration.yaml``, ``<sensor>.yaml`` per sensor (original format) and
    ``calibration.launch`` into ``out_dir`` (created if needed), each atomically, all from one
    frame plan (resolved in ``urdf``, a parsed URDF, when given: e.g. the robot's URDF the
    nominal poses came from).

    Returns the written paths in that order. Texts are all built before anything is written.
    """
    out = Path(out_dir)
    for name, est in result.sensors.items():
        _ros_frame(est.frame_id, name)
    plan = frame_plan(result, urdf)
    reserved = {Path(RESULT_YAML_NAME).stem.lower()}
    lowered: dict[str, str] = {}
    files: list[tuple[Path, str]] = [(out / RESULT_YAML_NAME, result_to_yaml_text(result, plan))]
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
        files.append((out / f"{name}.yaml", original_sensor_yaml_text(result, name, plan)))
    files.append((out / LAUNCH_NAME, ros1_launch_text(result, plan)))
    written = [atomic_write_text(path, text) for path, text in files]
    mark_output(out)
    return written
