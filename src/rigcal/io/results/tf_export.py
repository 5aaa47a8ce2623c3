"""Static transforms for ROS: ROS 1 launch, ROS 2 launch (Python), ``ros2 run`` lines, YAML/JSON.

Every writer takes the static transforms of a frame plan (:mod:`rigcal.io.results.frames`, the
frame contract every writer shares): a sequence of
:class:`~rigcal.io.results.frames.StaticTransform` ``(parent, child, T_parent_child)`` (4x4,
``p_parent = T @ p_child``, the child frame's pose in the parent frame), or - the older form - a
mapping ``{child_frame: T_parent_child}`` with one parent frame. Each returns text; numbers are
written in shortest round-trip form (``repr``), so reading them back gives the same floats.

* ROS 1: ``tf2_ros static_transform_publisher`` (publishes once on ``/tf_static``, latched) with
  ``args="x y z qx qy qz qw parent child"`` - the quaternion form, no period;
* ROS 2 (Humble and later): ``--x --y --z --qx --qy --qz --qw --frame-id --child-frame-id``;
* YAML/JSON: per child its parent, ``T_parent_child``, ``xyz``, ``rpy`` (``R = Rz(yaw) @
  Ry(pitch) @ Rx(roll)`` [rad], as a URDF ``rpy`` means) and ``quaternion_xyzw``.
"""

from __future__ import annotations

import json
import math
import os
import re
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any


import rigcal
from rigcal.errors import InputError
from rigcal.io._text import dump_yaml
from rigcal.io.atomic import atomic_write_text
from rigcal.geometry.se3 import as_rigid
from rigcal.io.results.frames import CONVENTION, edges_of, quaternion_xyzw
from rigcal.io.results.urdf import format_float, origin_from_matrix

TF_PERIOD_MS = 100  # kept for callers of the former tf publisher; tf2_ros needs no period

Transforms = Mapping[str, Any] | Sequence[Any]


class _Pose:
    __slots__ = ("parent", "child", "matrix", "xyz", "rpy", "quat")

    def __init__(self, parent: str, child: str, matrix: Any, xyz: tuple, rpy: tuple, quat: list):
        self.parent, self.child, self.matrix = parent, child, matrix
        self.xyz, self.rpy, self.quat = xyz, rpy, quat


def _frame(name: Any, what: str) -> str:
    if not isinstance(name, str) or not name or re.search(r"\s", name):
        raise InputError(
            f"{what}: frame name must be a non-empty string without whitespace, got {name!r}"
        )
    return name


def _poses(transforms: Transforms, parent_frame: str | None = None) -> list[_Pose]:
    if parent_frame is not None:
        _frame(parent_frame, "parent frame")
    if not transforms:
        raise InputError(
            "static transforms: expected a non-empty mapping child frame -> T_parent_child "
            "(or a list of (parent, child, T_parent_child))"
        )
    if not isinstance(transforms, (Mapping, Sequence)):
        raise InputError(
            "static transforms: expected a non-empty mapping child frame -> T_parent_child"
        )
    poses = []
    seen: set[str] = set()
    for edge in edges_of(transforms, parent_frame):
        parent = _frame(edge.parent, "parent frame")
        child = _frame(edge.child, f"child frame {edge.child!r}")
        if child == parent:
            raise InputError(f"child frame '{child}' is the parent frame itself")
        if child in seen:
            raise InputError(f"child frame '{child}' is published twice; a TF tree needs one parent per frame")
        seen.add(child)
        m = as_rigid(edge.T_parent_child, f"T_{parent}_{child}")
        xyz, rpy = origin_from_matrix(m)
        poses.append(_Pose(parent, child, m, xyz, rpy, quaternion_xyzw(m)))
    return poses


def _root(poses: list[_Pose]) -> str:
    children = {p.child for p in poses}
    roots = list(dict.fromkeys(p.parent for p in poses if p.parent not in children))
    return roots[0] if len(roots) == 1 else ", ".join(roots)


def _node_names(children: list[str]) -> dict[str, str]:
    """Valid, unique ROS node names (``rigcal_<child>``)."""
    out: dict[str, str] = {}
    used: set[str] = set()
    for child in children:
        base = "rigcal_" + re.sub(r"[^A-Za-z0-9_]", "_", child)
        node, n = base, 2
        while node in used:
            node, n = f"{base}_{n}", n + 1
        used.add(node)
        out[child] = node
    return out


def _py_str(text: str) -> str:
    """A Python string literal, double-quoted when that needs no escapes."""
    if text.isprintable() and '"' not in text and "\\" not in text:
        return f'"{text}"'
    return repr(text)


def _ros2_arguments(pose: _Pose) -> list[str]:
    (x, y, z), (qx, qy, qz, qw) = pose.xyz, pose.quat
    args = []
    named = (("x", x), ("y", y), ("z", z), ("qx", qx), ("qy", qy), ("qz", qz), ("qw", qw))
    for flag, value in named:
        args += [f"--{flag}", format_float(value)]
    return args + ["--frame-id", pose.parent, "--child-frame-id", pose.child]


_ATTR_ESCAPES = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}


def quoteattr(value: str) -> str:
    """``value`` as a double-quoted XML attribute value (markup, quotes and line breaks as
    entities). Written here: xml.sax.saxutils pulls in urllib, http and ssl (30 ms)."""
    return '"' + "".join(_ATTR_ESCAPES.get(ch, ch) for ch in value) + '"'


def _deg(values: tuple) -> str:
    return " ".join(f"{math.degrees(v):.6g}" for v in values)


def ros1_launch_text(
    transforms: Transforms, parent_frame: str | None = None, period_ms: int | None = None
) -> str:
    """A ROS 1 launch file: one ``tf2_ros static_transform_publisher`` node per transform with
    ``args="x y z qx qy qz qw parent child"`` (published once on ``/tf_static``; ``period_ms``
    is accepted for compatibility and ignored: tf2_ros takes no period)."""
    poses = _poses(transforms, parent_frame)
    if period_ms is not None and (not isinstance(period_ms, int) or isinstance(period_ms, bool)
                                  or period_ms <= 0):
        raise InputError(f"period_ms: expected a positive integer, got {period_ms!r}")
    nodes = _node_names([p.child for p in poses])
    comment = (
        f"written by rigcal {rigcal.__version__}. Each node publishes T_parent_child (the child "
        "frame's pose in the parent frame) on /tf_static as args = x y z [m] qx qy qz qw parent "
        "child (tf2_ros static_transform_publisher, quaternion form). A camera's calibrated "
        "frame is its optical frame (x right, y down, z forward; docs/conventions.md)."
    )
    lines = ['<?xml version="1.0"?>', "<launch>", f"  <!-- {comment.replace('--', '- -')} -->"]
    for pose in poses:
        numbers = " ".join(format_float(v) for v in (*pose.xyz, *pose.quat))
        args = f"{numbers} {pose.parent} {pose.child}"
        note = f"{pose.parent} -> {pose.child}: rpy [deg] {_deg(pose.rpy)}"
        lines.append(f"  <!-- {note.replace('--', '- -')} -->")
        lines.append(
            f'  <node pkg="tf2_ros" type="static_transform_publisher" '
            f"name={quoteattr(nodes[pose.child])} args={quoteattr(args)}/>"
        )
    lines.append("</launch>")
    return "\n".join(lines) + "\n"


def ros2_launch_py_text(transforms: Transforms, parent_frame: str | None = None) -> str:
    """A ROS 2 Python launch file: one ``tf2_ros static_transform_publisher`` Node per
    transform, with the named arguments of ROS 2 Humble and later (quaternion form)."""
    poses = _poses(transforms, parent_frame)
    nodes = _node_names([p.child for p in poses])
    out = [
        f'"""Static transforms written by rigcal {rigcal.__version__}.',
        "",
        "Each node publishes T_parent_child (the child frame's pose in the parent frame):",
        "--x --y --z [m], --qx --qy --qz --qw (unit quaternion). A camera's calibrated frame is",
        "its optical frame (x right, y down, z forward; docs/conventions.md).",
        '"""',
        "",
        "from launch import LaunchDescription",
        "from launch_ros.actions import Node",
        "",
        "",
        "def generate_launch_description():",
        "    return LaunchDescription(",
        "        [",
    ]
    for pose in poses:
        args = _ros2_arguments(pose)
        out += [
            "            Node(",
            '                package="tf2_ros",',
            '                executable="static_transform_publisher",',
            f"                name={_py_str(nodes[pose.child])},",
            "                arguments=[",
        ]
        out += [
            f"                    {_py_str(flag)}, {_py_str(value)},"
            for flag, value in zip(args[::2], args[1::2])
        ]
        out += ["                ],", "            ),"]
    out += ["        ]", "    )", ""]
    return "\n".join(out)


def ros2_run_commands(transforms: Transforms, parent_frame: str | None = None) -> list[str]:
    """One shell line per transform:
    ``ros2 run tf2_ros static_transform_publisher --x .. --child-frame-id child``."""
    return [
        "ros2 run tf2_ros static_transform_publisher "
        + " ".join(shlex.quote(a) for a in _ros2_arguments(pose))
        for pose in _poses(transforms, parent_frame)
    ]


def _document(transforms: Transforms, parent_frame: str | None = None) -> dict[str, Any]:
    poses = _poses(transforms, parent_frame)
    return {
        "parent_frame": parent_frame if parent_frame is not None else _root(poses),
        "convention": CONVENTION,
        "transforms": {
            pose.child: {
                "parent": pose.parent,
                "T_parent_child": [[float(v) + 0.0 for v in row] for row in pose.matrix],
                "xyz": [float(v) + 0.0 for v in pose.xyz],
                "rpy": [float(v) + 0.0 for v in pose.rpy],
                "quaternion_xyzw": [float(v) + 0.0 for v in pose.quat],
            }
            for pose in poses
        },
    }


def yaml_text(transforms: Transforms, parent_frame: str | None = None) -> str:
    """YAML ``{parent_frame, convention, transforms: {child: {parent, T_parent_child, xyz, rpy,
    quaternion_xyzw}}}``."""
    return dump_yaml(_document(transforms, parent_frame), flow=None)


def json_text(transforms: Transforms, parent_frame: str | None = None) -> str:
    """The same document as :func:`yaml_text`, as indented JSON."""
    return json.dumps(_document(transforms, parent_frame), indent=2, allow_nan=False) + "\n"


def sh_text(transforms: Transforms, parent_frame: str | None = None) -> str:
    """A shell script of :func:`ros2_run_commands` lines."""
    return "#!/bin/sh\n" + "\n".join(ros2_run_commands(transforms, parent_frame)) + "\n"


_FORMATS = {
    "ros1": ros1_launch_text,
    "ros2": ros2_launch_py_text,
    "sh": sh_text,
    "yaml": yaml_text,
    "json": json_text,
}


def _format_of(path: Path) -> str:
    name = path.name.lower()
    suffixes = (
        (".launch.py", "ros2"),
        (".launch", "ros1"),
        (".sh", "sh"),
        (".yaml", "yaml"),
        (".yml", "yaml"),
        (".json", "json"),
    )
    for suffix, fmt in suffixes:
        if name.endswith(suffix):
            return fmt
    raise InputError(
        f"{path}: cannot tell the format from the name; use .launch (ROS 1), .launch.py "
        "(ROS 2), .sh (ros2 run lines), .yaml/.yml or .json, or pass fmt"
    )


def write_tf_export(
    path: str | os.PathLike[str],
    transforms: Transforms,
    parent_frame: str | None = None,
    fmt: str | None = None,
) -> Path:
    """Write one export atomically; ``fmt`` is one of ros1, ros2, sh, yaml, json (default:
    from the file name). Returns the path."""
    target = Path(path)
    fmt = fmt or _format_of(target)
    if fmt not in _FORMATS:
        raise InputError(f"{target}: unknown format {fmt!r} (expected: {', '.join(_FORMATS)})")
    return atomic_write_text(target, _FORMATS[fmt](transforms, parent_frame))
