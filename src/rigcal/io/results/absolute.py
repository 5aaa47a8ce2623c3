"""Writing and reading an absolute calibration (:class:`~rigcal.absolute.result.AbsoluteResult`).

* ``absolute.yaml`` / ``absolute.json``: :meth:`AbsoluteResult.to_dict` - the body frame (name,
  definition, ``T_external_body``, wheelbase, tracks, ground fit) and per sensor
  ``T_body_sensor`` (4x4, ``p_body = T @ p_sensor``), ``xyz_m``, ``rpy_deg``, ``std``,
  ``covariance``; floats at full precision (``repr``), so a read gives back the same numbers.
  JSON is strict: NaN and infinities become ``null``.
* launch files: ROS 1 ``absolute.launch`` and ROS 2 ``absolute.launch.py`` (or ``.sh``, YAML,
  JSON) through :mod:`rigcal.io.results.tf_export`, the static transforms of the result's frame
  plan (:mod:`rigcal.io.results.frames`): one per sensor frame with the body frame as the parent
  (default ``base_link``; ``parent_frame`` renames it). ``absolute.yaml`` carries the same
  ``frames`` block as ``calibration.yaml``.

:func:`read_absolute_yaml` / :func:`parse_absolute_yaml` read ``absolute.yaml`` (or the JSON)
back into :class:`AbsoluteTransforms`: the body frame's name and ``{sensor frame: T_body_sensor}``.
Every write is atomic; every text is built before anything is written.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from rigcal.absolute.result import AbsoluteResult
from rigcal.errors import InputError
from rigcal.io._text import dump_yaml, json_safe, load_yaml, read_text, type_name
from rigcal.io.atomic import atomic_write_text, mark_output
from rigcal.io.results.tf_export import (
    ros1_launch_text,
    ros2_launch_py_text,
    sh_text,
    write_tf_export,
)
from rigcal.geometry.se3 import as_rigid

__all__ = [
    "ABSOLUTE_JSON_NAME",
    "ABSOLUTE_YAML_NAME",
    "AbsoluteTransforms",
    "LAUNCH_NAMES",
    "absolute_to_json_text",
    "absolute_to_yaml_text",
    "body_transforms",
    "frame_plan",
    "parse_absolute_yaml",
    "read_absolute_yaml",
    "write_absolute",
    "write_absolute_launch",
]

ABSOLUTE_YAML_NAME = "absolute.yaml"
ABSOLUTE_JSON_NAME = "absolute.json"
#: Launch file names per tf_export format.
LAUNCH_NAMES = {"ros1": "absolute.launch", "ros2": "absolute.launch.py", "sh": "absolute_tf.sh"}


_LAUNCH_TEXT: dict[str, Callable[..., str]] = {
    "ros1": ros1_launch_text,
    "ros2": ros2_launch_py_text,
    "sh": sh_text,
}


class AbsoluteTransforms(NamedTuple):
    """What :func:`read_absolute_yaml` returns: ``body_frame`` (the parent frame's name) and
    ``transforms`` ``{sensor frame: T_body_sensor (4, 4)}`` in file order."""

    body_frame: str
    transforms: dict[str, np.ndarray]


def _frame_name(name: Any, what: str) -> str:
    if not isinstance(name, str) or not name or any(c.isspace() for c in name):
        raise InputError(
            f"{what}: frame name must be a non-empty string without whitespace, got {name!r}"
        )
    return name


def _parent(result: AbsoluteResult, parent_frame: str | None) -> str:
    return _frame_name(
        result.body_frame if parent_frame is None else parent_frame, "body frame"
    )


def body_transforms(
    result: AbsoluteResult, parent_frame: str | None = None
) -> dict[str, np.ndarray]:
    """``{sensor frame_id: T_body_sensor}`` for a TF export; InputError when two sensors share a
    frame id or a frame is the body frame itself."""
    if not isinstance(result, AbsoluteResult):
        raise InputError(f"expected an AbsoluteResult, got {type(result).__name__}")
    parent = _parent(result, parent_frame)
    out: dict[str, np.ndarray] = {}
    owner: dict[str, str] = {}
    for name, est in result.sensors.items():
        frame = _frame_name(est.frame_id, f"sensor '{name}'")
        if frame in owner:
            raise InputError(
                f"sensors '{owner[frame]}' and '{name}' share the frame id '{frame}'; a TF tree "
                "needs one frame per sensor"
            )
        if frame == parent:
            raise InputError(
                f"sensor '{name}': its frame id '{frame}' is the body frame's name; rename one"
            )
        owner[frame] = name
        out[frame] = np.array(est.T_body_sensor, dtype=float)
    if not out:
        raise InputError("absolute result: no rig sensor to export")
    return out


def frame_plan(result: AbsoluteResult, parent_frame: str | None = None, urdf: Any = None) -> Any:
    """The :class:`~rigcal.io.results.frames.FramePlan` of an absolute result: every sensor's
    ``T_body_sensor`` under the body frame (``parent_frame`` renames it), frame names resolved
    in ``urdf`` when given."""
    from rigcal.io.results.calibration_files import CalibrationTransforms
    from rigcal.io.results.frames import plan_frames

    parent = _parent(result, parent_frame)
    cal = CalibrationTransforms(
        "absolute", parent, body_transforms(result, parent), "absolute",
        {est.frame_id: est.kind.value for est in result.sensors.values()},
        names={est.frame_id: name for name, est in result.sensors.items()},
        bounded={est.frame_id: tuple(est.bounded) for est in result.sensors.values() if est.bounded},
        bounded_values={est.frame_id: est.bounded_values for est in result.sensors.values() if est.bounded},
    )
    return plan_frames(cal, urdf)


def _dump_yaml(data: Any) -> str:
    return dump_yaml(data, flow=None)


def _document(result: AbsoluteResult, parent_frame: str | None) -> dict[str, Any]:
    from rigcal.io.results.frames import frames_block

    res = _renamed(result, parent_frame)
    data = res.to_dict()
    data["frames"] = frames_block(frame_plan(res))  # refuses what is no TF tree
    return data


def _renamed(result: AbsoluteResult, parent_frame: str | None) -> AbsoluteResult:
    if parent_frame is None:
        return result
    return result.with_body_frame(_frame_name(parent_frame, "body frame"))


def absolute_to_yaml_text(result: AbsoluteResult, parent_frame: str | None = None) -> str:
    """``result.to_dict()`` as YAML (matrices as flow rows; floats exact, NaN as ``.nan``);
    ``parent_frame`` renames the body frame."""
    if not isinstance(result, AbsoluteResult):
        raise InputError(f"expected an AbsoluteResult, got {type(result).__name__}")
    return _dump_yaml(_document(result, parent_frame))


def absolute_to_json_text(result: AbsoluteResult, parent_frame: str | None = None) -> str:
    """The same document as :func:`absolute_to_yaml_text` as strict, indented JSON (NaN and
    infinities become ``null``, integer keys strings)."""
    if not isinstance(result, AbsoluteResult):
        raise InputError(f"expected an AbsoluteResult, got {type(result).__name__}")
    return json.dumps(json_safe(_document(result, parent_frame)), indent=2, allow_nan=False) + "\n"


def parse_absolute_yaml(text: str, source: str = ABSOLUTE_YAML_NAME) -> AbsoluteTransforms:
    """The body frame's name and ``{sensor frame: T_body_sensor}`` from the text of an
    ``absolute.yaml`` (or ``absolute.json``). Errors name ``source`` and the key at fault."""
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(
            f"{source}: expected a mapping with 'body_frame' and 'sensors', got {type_name(data)}"
        )
    for key in ("body_frame", "sensors"):
        if key not in data:
            raise InputError(f"{source}: missing key '{key}'")
    body = data["body_frame"]
    if not isinstance(body, dict) or "name" not in body:
        raise InputError(
            f"{source}: body_frame: expected a mapping with 'name', got {type_name(body)}"
        )
    parent = _frame_name(body["name"], f"{source}: body_frame.name")
    sensors = data["sensors"]
    if not isinstance(sensors, dict) or not sensors:
        raise InputError(
            f"{source}: sensors: expected a non-empty mapping sensor -> entry, got "
            f"{type_name(sensors)}"
        )
    out: dict[str, np.ndarray] = {}
    for name, entry in sensors.items():
        where = f"{source}: sensors.{name}"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected a mapping, got {type_name(entry)}")
        if "T_body_sensor" not in entry:
            raise InputError(f"{where}: missing key 'T_body_sensor'")
        frame = _frame_name(entry.get("frame_id", name), f"{where}.frame_id")
        if frame in out:
            raise InputError(f"{where}: frame '{frame}' appears twice")
        if frame == parent:
            raise InputError(f"{where}: frame '{frame}' is the body frame itself")
        out[frame] = as_rigid(entry["T_body_sensor"], f"{where}.T_body_sensor")
    return AbsoluteTransforms(parent, out)


def read_absolute_yaml(path: str | os.PathLike[str]) -> AbsoluteTransforms:
    """:func:`parse_absolute_yaml` of a file."""
    p = Path(path)
    return parse_absolute_yaml(read_text(p, "absolute calibration file"), str(p))


def write_absolute_launch(
    path: str | os.PathLike[str],
    result: AbsoluteResult,
    parent_frame: str | None = None,
    fmt: str | None = None,
) -> Path:
    """One static-transform export of every sensor's ``T_body_sensor`` with the body frame as
    the parent (``parent_frame`` overrides the result's name); ``fmt`` one of ros1, ros2, sh,
    yaml, json (default: from the file name, see
    :func:`rigcal.io.results.tf_export.write_tf_export`)."""
    return write_tf_export(path, frame_plan(result, parent_frame).transforms, None, fmt)


def write_absolute(
    result: AbsoluteResult,
    out_dir: str | os.PathLike[str],
    *,
    parent_frame: str | None = None,
    launch: Sequence[str] = ("ros1", "ros2"),
) -> list[Path]:
    """Write ``absolute.yaml``, ``absolute.json`` and one launch file per ``launch`` format
    (``ros1`` -> ``absolute.launch``, ``ros2`` -> ``absolute.launch.py``, ``sh`` ->
    ``absolute_tf.sh``) into ``out_dir`` (created if needed), each atomically; ``parent_frame``
    renames the body frame everywhere. Returns the paths in that order."""
    out = Path(out_dir)
    if isinstance(launch, str):
        launch = (launch,)
    unknown = [f for f in launch if f not in LAUNCH_NAMES]
    if unknown:
        raise InputError(
            f"launch formats {unknown} unknown (expected some of: {', '.join(LAUNCH_NAMES)})"
        )
    parent = _parent(result, parent_frame)
    transforms = frame_plan(result, parent).transforms
    files: list[tuple[Path, str]] = [
        (out / ABSOLUTE_YAML_NAME, absolute_to_yaml_text(result, parent)),
        (out / ABSOLUTE_JSON_NAME, absolute_to_json_text(result, parent)),
    ]
    for fmt in dict.fromkeys(launch):
        files.append((out / LAUNCH_NAMES[fmt], _LAUNCH_TEXT[fmt](transforms)))
    written = [atomic_write_text(p, text) for p, text in files]
    mark_output(out)
    return written
