"""Shared helpers for the mocap tests: a smooth synthetic trajectory with known truth, and real
ROS 1 / ROS 2 bags written with rosbags' own writers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rigcal.geometry import from_rt, so3_exp
from rigcal.mocap import matrix_to_quat_xyzw

FORMATS = ["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"]
T0 = 1_700_000_000_000_000_000
NS = 1_000_000_000


def trajectory(t_s: np.ndarray, phase: float = 0.0) -> np.ndarray:
    """(N, 4, 4) a smooth body motion: a 1.5 m circle at 0.5 rad/s with a bobbing height,
    yawing with the circle and wobbling in roll and pitch (angular rates below 1 rad/s)."""
    t = np.asarray(t_s, dtype=float) + phase
    p = np.column_stack([1.5 * np.cos(0.5 * t), 1.5 * np.sin(0.5 * t), 0.3 + 0.1 * np.sin(1.3 * t)])
    yaw = so3_exp(np.column_stack([np.zeros_like(t), np.zeros_like(t), 0.5 * t + 0.3]))
    wobble = so3_exp(np.column_stack([0.3 * np.sin(0.7 * t), 0.2 * np.sin(0.4 * t),
                                      np.zeros_like(t)]))
    return from_rt(yaw @ wobble, p)


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return from_rt(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def store_for(fmt: str) -> Any:
    """A typestore for ``fmt`` that knows tf2_msgs/TFMessage (ROS 1 Noetic's store lacks it)."""
    if fmt == "rosbag1":
        store = get_typestore(Stores.ROS1_NOETIC)
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                          "tf2_msgs/msg/TFMessage"))
        return store
    return get_typestore(Stores.ROS2_HUMBLE)


def bag_path(tmp_path: Path, fmt: str, name: str = "mocap") -> Path:
    return tmp_path / (f"{name}.bag" if fmt == "rosbag1" else name)


def write_bag(path: Path, fmt: str, store: Any, messages: list) -> Path:
    """messages: (topic, msgtype, receive_ns, message), written in the given order."""
    if fmt == "rosbag1":
        from rosbags.rosbag1 import Writer

        writer: Any = Writer(path)
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "rosbag2-mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        serialize = store.serialize_cdr
    conns: dict[str, Any] = {}
    with writer:
        for topic, msgtype, recv, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], recv, serialize(msg, msgtype))
    return path


def header(store: Any, t_ns: int, frame_id: str) -> Any:
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    stamp = Time(sec=int(t_ns // NS), nanosec=int(t_ns % NS))
    if "seq" in Header.__dataclass_fields__:
        return Header(seq=0, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _vec_quat(store: Any, T: np.ndarray, vec_type: str) -> tuple[Any, Any]:
    q = matrix_to_quat_xyzw(T[:3, :3])
    Q = store.types["geometry_msgs/msg/Quaternion"]
    V = store.types[vec_type]
    return (V(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))


def transform_stamped(store: Any, parent: str, child: str, t_ns: int, T: np.ndarray) -> Any:
    v, q = _vec_quat(store, T, "geometry_msgs/msg/Vector3")
    tr = store.types["geometry_msgs/msg/Transform"](translation=v, rotation=q)
    return store.types["geometry_msgs/msg/TransformStamped"](
        header=header(store, t_ns, parent), child_frame_id=child, transform=tr)


def tf_message(store: Any, transforms: list) -> Any:
    """transforms: (parent, child, t_ns, T)"""
    return store.types["tf2_msgs/msg/TFMessage"](
        transforms=[transform_stamped(store, *tr) for tr in transforms])


def pose(store: Any, T: np.ndarray) -> Any:
    p, q = _vec_quat(store, T, "geometry_msgs/msg/Point")
    return store.types["geometry_msgs/msg/Pose"](position=p, orientation=q)


def pose_stamped(store: Any, frame: str, t_ns: int, T: np.ndarray) -> Any:
    return store.types["geometry_msgs/msg/PoseStamped"](header=header(store, t_ns, frame),
                                                        pose=pose(store, T))


def odometry(store: Any, frame: str, child: str, t_ns: int, T: np.ndarray) -> Any:
    cov = np.zeros(36)
    pwc = store.types["geometry_msgs/msg/PoseWithCovariance"](pose=pose(store, T), covariance=cov)
    V = store.types["geometry_msgs/msg/Vector3"]
    twist = store.types["geometry_msgs/msg/Twist"](linear=V(x=0.0, y=0.0, z=0.0),
                                                   angular=V(x=0.0, y=0.0, z=0.0))
    twc = store.types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov)
    return store.types["nav_msgs/msg/Odometry"](header=header(store, t_ns, frame),
                                                child_frame_id=child, pose=pwc, twist=twc)


@pytest.fixture
def kit() -> SimpleNamespace:
    return SimpleNamespace(
        FORMATS=FORMATS, T0=T0, NS=NS, trajectory=trajectory, random_pose=random_pose,
        store_for=store_for, bag_path=bag_path, write_bag=write_bag,
        transform_stamped=transform_stamped, tf_message=tf_message, pose_stamped=pose_stamped,
        odometry=odometry,
    )
