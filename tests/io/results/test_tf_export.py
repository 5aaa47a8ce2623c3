"""Static-transform exports: every format is read back into 4x4 matrices (quaternions (x, y, z, w)
with an independent formula here; rpy as R = Rz(yaw) Ry(pitch) Rx(roll)) and compared with the
input to 1e-9."""

from __future__ import annotations

import json
import math
import shlex
import sys
import types
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from rigcal.errors import InputError
from rigcal.geometry import from_rt, so3_exp
from rigcal.io.results.tf_export import (
    json_text,
    ros1_launch_text,
    ros2_launch_py_text,
    ros2_run_commands,
    write_tf_export,
    yaml_text,
)

PARENT = "base_link"


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=float)


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=float)


def pose(x, y, z, yaw, pitch, roll) -> np.ndarray:
    return from_rt(Rz(yaw) @ Ry(pitch) @ Rx(roll), [x, y, z])


def quat_pose(x, y, z, qx, qy, qz, qw) -> np.ndarray:
    """The rotation of a unit quaternion (x, y, z, w), written out here (not rigcal's code)."""
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    assert abs(n - 1) < 1e-12
    R = np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])
    return from_rt(R, [x, y, z])


def transforms(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {
        f"sensor_{i}": from_rt(so3_exp(rng.normal(size=3)), rng.normal(scale=3, size=3))
        for i in range(5)
    }
    out["gimbal"] = pose(0.1, -0.2, 0.3, 0.7, math.pi / 2, -0.2)
    out["identity"] = np.eye(4)
    out["front/left-radar"] = pose(1.5, 0.5, 0.2, -0.3, 0.0, 0.0)
    return out


def named(args: list[str]) -> dict[str, str]:
    assert len(args) % 2 == 0
    return {args[i]: args[i + 1] for i in range(0, len(args), 2)}


def from_named(values: dict[str, str]) -> tuple[str, str, np.ndarray]:
    f = {k: float(values[f"--{k}"]) for k in ("x", "y", "z", "qx", "qy", "qz", "qw")}
    T = quat_pose(f["x"], f["y"], f["z"], f["qx"], f["qy"], f["qz"], f["qw"])
    return values["--frame-id"], values["--child-frame-id"], T


def test_ros1_launch_round_trip():
    Ts = transforms()
    root = ET.fromstring(ros1_launch_text(Ts, PARENT))
    nodes = root.findall("node")
    assert len(nodes) == len(Ts)
    names = set()
    for node in nodes:
        # tf2_ros (publishes /tf_static), not the old tf publisher; quaternion form, no period
        assert (node.get("pkg"), node.get("type")) == ("tf2_ros", "static_transform_publisher")
        names.add(node.get("name"))
        x, y, z, qx, qy, qz, qw, parent, child = node.get("args").split()
        assert parent == PARENT
        T = quat_pose(*(float(v) for v in (x, y, z, qx, qy, qz, qw)))
        np.testing.assert_allclose(T, Ts[child], atol=1e-9)
    assert len(names) == len(Ts)


def test_ros1_argument_order_is_x_y_z_qx_qy_qz_qw():
    # a 90 deg yaw: q = (0, 0, sin 45, cos 45)
    text = ros1_launch_text({"s": pose(1, 2, 3, math.pi / 2, 0.0, 0.0)}, PARENT)
    args = ET.fromstring(text).find("node").get("args").split()
    h = math.sqrt(0.5)
    assert [float(a) for a in args[:7]] == pytest.approx([1, 2, 3, 0, 0, h, h], abs=1e-15)
    assert args[7:] == [PARENT, "s"]
    # a 30 deg roll read with w first (the classic mistake) is another rotation
    args = ET.fromstring(ros1_launch_text({"s": pose(0, 0, 0, 0, 0, math.pi / 6)}, PARENT)
                         ).find("node").get("args").split()
    q = [float(a) for a in args[3:7]]
    assert q == pytest.approx([math.sin(math.pi / 12), 0, 0, math.cos(math.pi / 12)], abs=1e-15)
    assert np.abs(quat_pose(0, 0, 0, q[3], q[0], q[1], q[2]) - quat_pose(0, 0, 0, *q)).max() > 0.1


def test_ros1_launch_takes_edges_with_several_parents():
    """A frame plan's transforms: a camera link under the reference and its optical child."""
    T_link = pose(1, 0.2, 1.2, 0.1, 0.0, 0.0)
    T_opt = pose(0, 0, 0, -math.pi / 2, 0.0, -math.pi / 2)
    edges = [(PARENT, "cam_link", T_link), ("cam_link", "cam_optical_frame", T_opt)]
    nodes = ET.fromstring(ros1_launch_text(edges)).findall("node")
    got = {}
    for node in nodes:
        a = node.get("args").split()
        got[(a[7], a[8])] = quat_pose(*(float(v) for v in a[:7]))
    assert set(got) == {(PARENT, "cam_link"), ("cam_link", "cam_optical_frame")}
    np.testing.assert_allclose(got[(PARENT, "cam_link")], T_link, atol=1e-15)
    np.testing.assert_allclose(got[("cam_link", "cam_optical_frame")], T_opt, atol=1e-15)
    with pytest.raises(InputError, match="'cam_link' is published twice"):
        ros1_launch_text(edges + [("other", "cam_link", T_link)])


class _Recorder:
    def __init__(self):
        self.nodes = []


def _run_launch_file(text: str, monkeypatch) -> list[dict]:
    recorder = _Recorder()
    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")

    def Node(**kwargs):
        recorder.nodes.append(kwargs)
        return kwargs

    actions.Node = Node
    launch_ros.actions = actions
    monkeypatch.setitem(sys.modules, "launch", launch)
    monkeypatch.setitem(sys.modules, "launch_ros", launch_ros)
    monkeypatch.setitem(sys.modules, "launch_ros.actions", actions)
    namespace: dict = {}
    exec(compile(text, "calibration.launch.py", "exec"), namespace)
    description = namespace["generate_launch_description"]()
    assert description == recorder.nodes
    return recorder.nodes


def test_ros2_launch_compiles_and_round_trips(monkeypatch):
    Ts = transforms(1)
    text = ros2_launch_py_text(Ts, PARENT)
    compile(text, "calibration.launch.py", "exec")
    assert "from launch_ros.actions import Node" in text
    assert '"--frame-id", "base_link"' in text and '"--child-frame-id", "identity"' in text
    nodes = _run_launch_file(text, monkeypatch)
    assert len(nodes) == len(Ts)
    for node in nodes:
        assert node["package"] == "tf2_ros"
        assert node["executable"] == "static_transform_publisher"
        values = named(node["arguments"])
        assert set(values) == {"--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--frame-id",
                               "--child-frame-id"}
        parent, child, T = from_named(values)
        assert parent == PARENT
        np.testing.assert_allclose(T, Ts[child], atol=1e-9)
    assert len({n["name"] for n in nodes}) == len(nodes)
    assert all(n["name"].isidentifier() for n in nodes)


def test_ros2_run_commands_round_trip():
    Ts = transforms(2)
    lines = ros2_run_commands(Ts, PARENT)
    assert len(lines) == len(Ts)
    for line in lines:
        words = shlex.split(line)
        assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
        parent, child, T = from_named(named(words[4:]))
        assert parent == PARENT
        np.testing.assert_allclose(T, Ts[child], atol=1e-9)


@pytest.mark.parametrize("fmt", ["yaml", "json"])
def test_yaml_and_json_round_trip(fmt):
    Ts = transforms(3)
    text = yaml_text(Ts, PARENT) if fmt == "yaml" else json_text(Ts, PARENT)
    data = yaml.safe_load(text) if fmt == "yaml" else json.loads(text)
    assert data["parent_frame"] == PARENT
    assert "Rz(yaw) @ Ry(pitch) @ Rx(roll)" in data["convention"]
    assert list(data["transforms"]) == list(Ts)
    for child, entry in data["transforms"].items():
        assert entry["parent"] == PARENT
        M = np.array(entry["T_parent_child"])
        np.testing.assert_array_equal(M, Ts[child])  # full precision: exact
        roll, pitch, yaw = entry["rpy"]
        np.testing.assert_allclose(pose(*entry["xyz"], yaw, pitch, roll), Ts[child], atol=1e-9)
        # quaternions (x, y, z, w) beside rpy, w >= 0
        assert entry["quaternion_xyzw"][3] >= 0
        np.testing.assert_allclose(quat_pose(*entry["xyz"], *entry["quaternion_xyzw"]), Ts[child],
                                   atol=1e-9)


def test_full_precision():
    x = 0.1234567890123456789
    T = pose(x, 0, 0, 1e-10, 0, 0)
    args = ET.fromstring(ros1_launch_text({"s": T}, PARENT)).find("node").get("args").split()
    assert float(args[0]) == x
    assert float(args[5]) == pytest.approx(math.sin(0.5e-10), rel=1e-12)  # qz of a 1e-10 yaw


def test_write_tf_export_picks_format_from_name(tmp_path):
    Ts = transforms(4)
    for name in ("tf.launch", "tf.launch.py", "tf.sh", "tf.yaml", "tf.json"):
        path = write_tf_export(tmp_path / name, Ts, PARENT)
        assert path.read_text()
    assert (tmp_path / "tf.sh").read_text().count("ros2 run tf2_ros") == len(Ts)
    compile((tmp_path / "tf.launch.py").read_text(), "tf.launch.py", "exec")
    with pytest.raises(InputError, match=r"tf\.txt: cannot tell the format"):
        write_tf_export(tmp_path / "tf.txt", Ts, PARENT)
    with pytest.raises(InputError, match=r"unknown format 'csv'"):
        write_tf_export(tmp_path / "tf.txt", Ts, PARENT, fmt="csv")


@pytest.mark.parametrize(
    "Ts, parent, match",
    [
        ({}, PARENT, r"expected a non-empty mapping"),
        ({"s": np.eye(4)}, "base link", r"parent frame: frame name must be .* without whitespace"),
        ({"": np.eye(4)}, PARENT, r"frame name must be a non-empty string"),
        ({PARENT: np.eye(4)}, PARENT, r"child frame 'base_link' is the parent frame itself"),
        ({"s": np.eye(3)}, PARENT, r"T_base_link_s: expected a 4x4 matrix, got shape \(3, 3\)"),
        ({"s": np.diag([2.0, 1.0, 1.0, 1.0])}, PARENT, r"T_base_link_s: .* must be a rotation"),
    ],
)
def test_refusals(Ts, parent, match):
    for writer in (ros1_launch_text, ros2_launch_py_text, ros2_run_commands, yaml_text, json_text):
        with pytest.raises(InputError, match=match):
            writer(Ts, parent)


def test_inputs_not_mutated():
    Ts = transforms(5)
    copies = {k: v.copy() for k, v in Ts.items()}
    ros1_launch_text(Ts, PARENT)
    ros2_launch_py_text(Ts, PARENT)
    yaml_text(Ts, PARENT)
    assert all(np.array_equal(Ts[k], copies[k]) for k in Ts)
