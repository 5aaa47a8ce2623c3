"""Static transforms for ROS: ROS 1 launch, ROS 2 launch (Python), ``ros2 run`` lines, YAML/JSON.

Every writer takes ``{child_frame: T_parent_child}`` (4x4, ``p_parent = T @ p_child``, i.e. the
child frame's pose in the parent frame, e.g. ``T_body_sensor``) and the parent frame's name,
and returns text; numbers are written in shortest round-trip form (``repr``), so reading them
back gives the same floats. Angles: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` [rad], as both
``tf/static_transform_publisher`` (ROS 1: ``x y z yaw pitch roll parent child period_ms``) and
``tf2_ros static_transform_publisher`` (ROS 2 Humble+: ``--x --y --z --yaw --pitch --roll
--frame-id --child-frame-id``) read them, and as a URDF ``rpy`` means.
"""

from __future__ import annotations

import json
import os
import re
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any


import rigcal
from rigcal.errors import InputError
from rigcal.io._text import dump_yaml
from rigcal.io.atomic import atomic_write_text
from rigcal.geometry.se3 import as_rigid
from rigcal.io.results.urdf import format_float, origin_from_matrix

TF_PERIOD_MS = 100
CONVENTION = (
    "T_parent_child: p_parent = T_parent_child @ p_child (the child frame's pose in the parent "
    "frame); xyz [m]; rpy = (roll, pitch, yaw) [rad] with R = Rz(yaw) @ Ry(pitch) @ Rx(roll)"
)


class _Pose:
    __slots__ = ("child", "matrix", "xyz", "rpy")

    def __init__(self, child: str, matrix: Any, xyz: tuple, rpy: tuple):
        self.child, self.matrix, self.xyz, self.rpy = child, matrix, xyz, rpy


def _frame(name: Any, what: str) -> str:
    if not isinstance(name, str) or not name or re.search(r"\s", name):
        raise InputError(
            f"{what}: frame name must be a non-empty string without whitespace, got {name!r}"
        )
    return name


def _poses(transforms: Mapping[str, Any], parent_frame: str) -> list[_Pose]:
    _frame(parent_frame, "parent frame")
    if not isinstance(transforms, Mapping) or not transforms:
        raise InputError(
            "static transforms: expected a non-empty mapping child frame -> T_parent_child"
        )
    poses = []
    for child, T in transforms.items():
        _frame(child, f"child frame {child!r}")
        if child == parent_frame:
            raise InputError(f"child frame '{child}' is the parent frame itself")
        m = as_rigid(T, f"T_{parent_frame}_{child}")
        xyz, rpy = origin_from_matrix(m)
        poses.append(_Pose(child, m, xyz, rpy))
    return poses


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


def _ros2_arguments(pose: _Pose, parent_frame: str) -> list[str]:
    (x, y, z), (roll, pitch, yaw) = pose.xyz, pose.rpy
    args = []
    named = (("x", x), ("y", y), ("z", z), ("yaw", yaw), ("pitch", pitch), ("roll", roll))
    for flag, value in named:
        args += [f"--{flag}", format_float(value)]
    return args + ["--frame-id", parent_frame, "--child-frame-id", pose.child]


_ATTR_ESCAPES = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}


def quoteattr(value: str) -> str:
    """``value`` as a double-quoted XML attribute value (markup, quotes and line breaks as
    entities). Written here: xml.sax.saxutils pulls in urllib, http and ssl (30 ms)."""
    return '"' + "".join(_ATTR_ESCAPES.get(ch, ch) for ch in value) + '"'


def ros1_launch_text(
    transforms: Mapping[str, Any], parent_frame: str, period_ms: int = TF_PERIOD_MS
) -> str:
    """A ROS 1 launch file: one ``tf/static_transform_publisher`` node per child frame with
    ``args="x y z yaw pitch roll parent child period_ms"``."""
    poses = _poses(transforms, parent_frame)
    if not isinstance(period_ms, int) or isinstance(period_ms, bool) or period_ms <= 0:
        raise InputError(f"period_ms: expected a positive integer, got {period_ms!r}")
    nodes = _node_names([p.child for p in poses])
    comment = (
        f"written by rigcal {rigcal.__version__}. Each node publishes T_{parent_frame}_child "
        "(the child frame's pose in the parent frame) as args = x y z [m] yaw pitch roll [rad] "
        "parent child period [ms], with R = Rz(yaw) Ry(pitch) Rx(roll)."
    )
    lines = ['<?xml version="1.0"?>', "<launch>", f"  <!-- {comment.replace('--', '- -')} -->"]
    for pose in poses:
        (x, y, z), (roll, pitch, yaw) = pose.xyz, pose.rpy
        numbers = " ".join(format_float(v) for v in (x, y, z, yaw, pitch, roll))
        args = f"{numbers} {parent_frame} {pose.child} {period_ms}"
        lines.append(
            f'  <node pkg="tf" type="static_transform_publisher" '
            f"name={quoteattr(nodes[pose.child])} args={quoteattr(args)}/>"
        )
    lines.append("</launch>")
    return "\n".join(lines) + "\n"


def ros2_launch_py_text(transforms: Mapping[str, Any], parent_frame: str) -> str:
    """A ROS 2 Python launch file: one ``tf2_ros static_transform_publisher`` Node per child
    frame, with the named arguments of ROS 2 Humble and later."""
    poses = _poses(transforms, parent_frame)
    nodes = _node_names([p.child for p in poses])
    out = [
        f'"""Static transforms written by rigcal {rigcal.__version__}.',
        "",
        f"Each node publishes T_{parent_frame}_child (the child frame's pose in the parent frame):",
        "--x --y --z [m], --yaw --pitch --roll [rad] with R = Rz(yaw) Ry(pitch) Rx(roll).",
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
        args = _ros2_arguments(pose, parent_frame)
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


def ros2_run_commands(transforms: Mapping[str, Any], parent_frame: str) -> list[str]:
    """One shell line per child frame:
    ``ros2 run tf2_ros static_transform_publisher --x .. --child-frame-id child``."""
    return [
        "ros2 run tf2_ros static_transform_publisher "
        + " ".join(shlex.quote(a) for a in _ros2_arguments(pose, parent_frame))
        for pose in _poses(transforms, parent_frame)
    ]


def _document(transforms: Mapping[str, Any], parent_frame: str) -> dict[str, Any]:
    return {
        "parent_frame": parent_frame,
        "convention": CONVENTION,
        "transforms": {
            pose.child: {
                "T_parent_child": [[float(v) + 0.0 for v in row] for row in pose.matrix],
                "xyz": [float(v) + 0.0 for v in pose.xyz],
                "rpy": [float(v) + 0.0 for v in pose.rpy],
            }
            for pose in _poses(transforms, parent_frame)
        },
    }


def yaml_text(transforms: Mapping[str, Any], parent_frame: str) -> str:
    """YAML ``{parent_frame, convention, transforms: {child: {T_parent_child, xyz, rpy}}}``."""
    return dump_yaml(_document(transforms, parent_frame), flow=None)


def json_text(transforms: Mapping[str, Any], parent_frame: str) -> str:
    """The same document as :func:`yaml_text`, as indented JSON."""
    return json.dumps(_document(transforms, parent_frame), indent=2, allow_nan=False) + "\n"


_FORMATS = {
    "ros1": ros1_launch_text,
    "ros2": ros2_launch_py_text,
    "sh": lambda t, p: "#!/bin/sh\n" + "\n".join(ros2_run_commands(t, p)) + "\n",
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
    transforms: Mapping[str, Any],
    parent_frame: str,
    fmt: str | None = None,
) -> Path:
    """Write one export atomically; ``fmt`` is one of ros1, ros2, sh, yaml, json (default:
    from the file name). Returns the path."""
    target = Path(path)
    fmt = fmt or _format_of(target)
    if fmt not in _FORMATS:
        raise InputError(f"{target}: unknown format {fmt!r} (expected: {', '.join(_FORMATS)})")
    return atomic_write_text(target, _FORMATS[fmt](transforms, parent_frame))
