"""Pose streams from real ROS 1 and ROS 2 bags (sqlite3, mcap) written with rosbags: /tf and
/tf_static chains, Vicon-style TransformStamped topics, PoseStamped and Odometry, occlusions,
and every error path."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry import so3_log
from rigcal.mocap import (
    interpolate,
    list_pose_sources,
    read_extrinsics_from_bag,
    read_pose_topics,
    read_tf_streams,
)

FORMATS = ["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"]
NS = 1_000_000_000
T0 = 1_700_000_000_000_000_000
TF = "tf2_msgs/msg/TFMessage"


def rot_err(Ra, Rb):
    return np.linalg.norm(so3_log(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1)


def _times(rate_hz: float, duration_s: float, offset_ns: int = 0) -> np.ndarray:
    n = int(duration_s * rate_hz) + 1
    return T0 + offset_ns + np.round(np.arange(n) * NS / rate_hz).astype(np.int64)


def _mocap_bag(kit, tmp_path, fmt, *, leading_slash=False):
    """world -> vicon/robot (100 Hz), world -> vicon/target (100 Hz, other phase), both in one
    TFMessage per tick on /tf; vicon/robot -> base_link and base_link -> lidar on /tf_static."""
    store = kit.store_for(fmt)
    t = _times(100.0, 3.0)
    T_robot = kit.trajectory((t - T0) / NS)
    T_target = kit.trajectory((t - T0) / NS, phase=2.0)
    rng = np.random.default_rng(3)
    T_robot_base, T_base_lidar = kit.random_pose(rng), kit.random_pose(rng)
    w = "/world" if leading_slash else "world"
    msgs = [("/tf_static", TF, int(t[0]),
             kit.tf_message(store, [("vicon/robot", "base_link", int(t[0]), T_robot_base),
                                    ("base_link", "lidar", int(t[0]), T_base_lidar)]))]
    for k, tk in enumerate(t):
        msgs.append(("/tf", TF, int(tk) + 1000, kit.tf_message(store, [
            (w, "vicon/robot", int(tk), T_robot[k]), (w, "vicon/target", int(tk), T_target[k])])))
    path = kit.write_bag(kit.bag_path(tmp_path, fmt), fmt, store, msgs)
    return path, t, T_robot, T_target, T_robot_base, T_base_lidar


@pytest.mark.parametrize("fmt", FORMATS)
def test_tf_streams_compose_static_chains(kit, tmp_path, fmt):
    path, t, T_robot, T_target, T_robot_base, T_base_lidar = _mocap_bag(kit, tmp_path, fmt)
    streams = read_tf_streams(path, ["vicon/robot", "vicon/target", "lidar"],
                              mocap_frame="world")
    assert set(streams) == {"vicon/robot", "vicon/target", "lidar"}
    robot = streams["vicon/robot"]
    assert robot.frame_id == "world" and robot.source == str(path)
    np.testing.assert_array_equal(robot.t_ns, t)  # header stamps, not receive times
    np.testing.assert_allclose(robot.T, T_robot, atol=1e-12)
    np.testing.assert_allclose(streams["vicon/target"].T, T_target, atol=1e-12)
    np.testing.assert_allclose(streams["lidar"].T, T_robot @ T_robot_base @ T_base_lidar,
                               atol=1e-12)
    # names from a mapping; the mocap frame defaults to the chain's root
    named = read_tf_streams(path, {"R": "vicon/robot"})
    assert list(named) == ["R"] and named["R"].frame_id == "world"


def test_leading_slash_in_frame_ids_is_ignored(kit, tmp_path):
    path, t, T_robot, *_ = _mocap_bag(kit, tmp_path, "rosbag1", leading_slash=True)
    s = read_tf_streams(path, ["/vicon/robot"], mocap_frame="/world")["/vicon/robot"]
    assert s.frame_id == "world"
    np.testing.assert_allclose(s.T, T_robot, atol=1e-12)


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2-mcap"])
def test_moving_parent_is_interpolated_at_the_child_stamps(kit, tmp_path, fmt):
    """map -> odom moves slowly at 30 Hz, odom -> body at 100 Hz with an offset clock: the body
    stream has the body's stamps and the parent interpolated there."""
    store = kit.store_for(fmt)
    t_body = _times(100.0, 2.0, offset_ns=3_000_000)
    t_odom = _times(30.0, 2.1)
    T_odom = kit.trajectory((t_odom - T0) / NS / 5.0, phase=1.0)  # 5x slower
    T_body = kit.trajectory((t_body - T0) / NS)
    msgs = [("/tf", TF, int(tk), kit.tf_message(store, [("map", "odom", int(tk), T_odom[k])]))
            for k, tk in enumerate(t_odom)]
    msgs += [("/tf", TF, int(tk), kit.tf_message(store, [("odom", "body", int(tk), T_body[k])]))
             for k, tk in enumerate(t_body)]
    msgs.sort(key=lambda m: m[2])
    path = kit.write_bag(kit.bag_path(tmp_path, fmt), fmt, store, msgs)
    body = read_tf_streams(path, ["body"], "map", max_gap_s=0.05)["body"]
    np.testing.assert_array_equal(body.t_ns, t_body)
    truth = kit.trajectory((t_body - T0) / NS / 5.0, phase=1.0) @ T_body
    assert np.abs(body.T[:, :3, 3] - truth[:, :3, 3]).max() < 1e-4
    assert rot_err(body.T[:, :3, :3], truth[:, :3, :3]).max() < 1e-4
    # a parent rate slower than max_gap_s: nothing can be composed
    with pytest.raises(InputError, match=r"never overlap in time \(max_gap_s = 0\.01\)"):
        read_tf_streams(path, ["body"], "map", max_gap_s=0.01)


@pytest.mark.parametrize("fmt", FORMATS)
def test_vicon_style_pose_topics(kit, tmp_path, fmt):
    store = kit.store_for(fmt)
    t = _times(100.0, 1.0)
    T_r = kit.trajectory((t - T0) / NS)
    T_t = kit.trajectory((t - T0) / NS, phase=1.0)
    T_o = kit.trajectory((t - T0) / NS, phase=2.0)
    msgs = []
    for k, tk in enumerate(t):
        tk = int(tk)
        msgs.append(("/vicon/robot/robot", "geometry_msgs/msg/TransformStamped", tk + 500,
                     kit.transform_stamped(store, "world", "vicon/robot/robot", tk, T_r[k])))
        msgs.append(("/target_pose", "geometry_msgs/msg/PoseStamped", tk + 500,
                     kit.pose_stamped(store, "world", tk, T_t[k])))
        msgs.append(("/odom", "nav_msgs/msg/Odometry", tk + 500,
                     kit.odometry(store, "world", "base", tk, T_o[k])))
    path = kit.write_bag(kit.bag_path(tmp_path, fmt), fmt, store, msgs)
    streams = read_pose_topics(path, ["/vicon/robot/robot", "/target_pose", "/odom"])
    assert set(streams) == {"vicon/robot/robot", "target_pose", "odom"}
    for name, truth in (("vicon/robot/robot", T_r), ("target_pose", T_t), ("odom", T_o)):
        s = streams[name]
        assert s.frame_id == "world"
        np.testing.assert_array_equal(s.t_ns, t)
        np.testing.assert_allclose(s.T, truth, atol=1e-12)
    named = read_pose_topics(path, {"target": "/target_pose"})
    assert list(named) == ["target"]
    sources = list_pose_sources(path)
    assert sources.pose_topics == {
        "/vicon/robot/robot": "geometry_msgs/msg/TransformStamped",
        "/target_pose": "geometry_msgs/msg/PoseStamped", "/odom": "nav_msgs/msg/Odometry"}
    assert sources.tf_parents == {} and sources.moving_frames == ()


def test_occluded_samples_are_dropped_and_interpolated_over(kit, tmp_path, caplog):
    store = kit.store_for("rosbag2-sqlite3")
    t = _times(100.0, 1.0)
    T = kit.trajectory((t - T0) / NS)
    msgs = []
    for k, tk in enumerate(t):
        Tk = T[k].copy()
        msg = kit.transform_stamped(store, "world", "b", int(tk), Tk)
        if 40 <= k < 50:  # occluded: zero quaternion (vicon bridge) or NaN
            rot = msg.transform.rotation
            if k % 2:
                rot.x = rot.y = rot.z = rot.w = 0.0
            else:
                msg.transform.translation.x = float("nan")
        msgs.append(("/vicon/b/b", "geometry_msgs/msg/TransformStamped", int(tk), msg))
    path = kit.write_bag(kit.bag_path(tmp_path, "rosbag2-sqlite3"), "rosbag2-sqlite3", store,
                         msgs)
    with caplog.at_level("INFO"):
        s = read_pose_topics(path, ["/vicon/b/b"])["vicon/b/b"]
    assert len(s) == len(t) - 10
    assert "dropped 10 samples" in caplog.text
    assert s.dropout_t_ns.tolist() == [int(x) for x in t[40:50]]
    # a burst of 10 dropped samples (0.11 s) is interpolated over by default (25 periods)...
    T_i, valid = interpolate(s, t[38:53])
    assert valid.all()
    np.testing.assert_allclose(T_i[:, :3, 3], T[38:53, :3, 3], atol=2e-3)  # a smooth path
    # ... up to max_dropout_s; a longer burst is a gap, named as a dropout
    _, valid = interpolate(s, t[38:53], max_dropout_s=0.1)
    assert valid.tolist() == [True, True] + [False] * 10 + [True] * 3
    with pytest.raises(InputError, match=r"falls in a dropout of 10 samples, a gap of 0\.110 s.*max_dropout_s = 0\.1 s"):
        s.at(int(t[45]), max_dropout_s=0.1)


def test_duplicate_stamps_and_receive_time_fallback(kit, tmp_path):
    store = kit.store_for("rosbag1")
    T = kit.trajectory(np.array([0.0, 0.01, 0.02]))
    msgs = [
        ("/p", "geometry_msgs/msg/PoseStamped", T0, kit.pose_stamped(store, "w", T0, T[0])),
        ("/p", "geometry_msgs/msg/PoseStamped", T0 + 5, kit.pose_stamped(store, "w", T0, T[0])),
        ("/p", "geometry_msgs/msg/PoseStamped", T0 + 20_000_000,
         kit.pose_stamped(store, "w", 0, T[2])),  # zero stamp: receive time
        ("/p", "geometry_msgs/msg/PoseStamped", T0 + 20_000_001,
         kit.pose_stamped(store, "w", T0 + 10_000_000, T[1])),  # late, out of bag order
    ]
    path = kit.write_bag(kit.bag_path(tmp_path, "rosbag1"), "rosbag1", store, msgs)
    s = read_pose_topics(path, ["/p"])["p"]
    assert s.t_ns.tolist() == [T0, T0 + 10_000_000, T0 + 20_000_000]
    np.testing.assert_allclose(s.T, T, atol=1e-12)
    msgs.append(("/p", "geometry_msgs/msg/PoseStamped", T0 + 30_000_000,
                 kit.pose_stamped(store, "w", T0, T[1])))
    path = kit.write_bag(tmp_path / "conflict.bag", "rosbag1", store, msgs)
    with pytest.raises(InputError, match=r"conflict\.bag: topic /p: two different poses stamped "
                                         r"1700000000000000000 ns"):
        read_pose_topics(path, ["/p"])


def test_list_pose_sources_for_tf(kit, tmp_path):
    path, *_ = _mocap_bag(kit, tmp_path, "rosbag2-mcap")
    src = list_pose_sources(path)
    assert src.tf_parents == {"base_link": "vicon/robot", "lidar": "base_link",
                              "vicon/robot": "world", "vicon/target": "world"}
    assert src.moving_frames == ("vicon/robot", "vicon/target")
    assert src.pose_topics == {}


# -- errors ------------------------------------------------------------------------------------


def test_tf_errors(kit, tmp_path):
    path, *_ = _mocap_bag(kit, tmp_path, "rosbag2-sqlite3")
    with pytest.raises(InputError, match=r"frame 'camera' \(stream 'camera'\) is not a child frame "
                                         r"on /tf, /tf_static; known child frames: \['base_link', "
                                         r"'lidar', 'vicon/robot', 'vicon/target'\]"):
        read_tf_streams(path, ["camera"], "world")
    with pytest.raises(InputError, match=r"frame 'vicon/target' does not connect to the mocap "
                                         r"frame 'vicon/robot': its parents are vicon/target -> "
                                         r"world \(root 'world'\)"):
        read_tf_streams(path, ["vicon/target"], "vicon/robot")
    with pytest.raises(InputError, match=r"frame 'lidar' \(stream 'lidar'\) only has static "
                                         r"transforms up to 'vicon/robot'"):
        read_tf_streams(path, ["lidar"], "vicon/robot", topics=["/tf_static"])
    with pytest.raises(InputError, match=r"none of the TF topics \['/tf_vicon'\] is in the bag"):
        read_tf_streams(path, ["lidar"], topics=["/tf_vicon"])
    with pytest.raises(InputError, match="no child frames requested"):
        read_tf_streams(path, [])
    with pytest.raises(InputError, match="max_gap_s must be a finite number > 0"):
        read_tf_streams(path, ["lidar"], max_gap_s=-1)
    with pytest.raises(InputError, match=r"topic /tf \(stream 'tf'\) has type tf2_msgs/msg/"
                                         r"TFMessage; expected one of geometry_msgs/msg/"
                                         r"TransformStamped, geometry_msgs/msg/PoseStamped"):
        read_pose_topics(path, ["/tf"])
    with pytest.raises(InputError, match=r"topic /vicon \(stream 'vicon'\) not in bag; pose "
                                         r"topics: none"):
        read_pose_topics(path, ["/vicon"])
    with pytest.raises(InputError, match="no pose topics requested"):
        read_pose_topics(path, [])
    with pytest.raises(InputError, match=r"missing\.bag: bag not found"):
        read_tf_streams(tmp_path / "missing.bag", ["x"])


def test_tf_topic_of_the_wrong_type_and_two_parents(kit, tmp_path):
    store = kit.store_for("rosbag2-sqlite3")
    I = np.eye(4)
    msgs = [("/tf", "geometry_msgs/msg/PoseStamped", T0, kit.pose_stamped(store, "w", T0, I))]
    path = kit.write_bag(tmp_path / "wrongtype", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"topic /tf has type geometry_msgs/msg/PoseStamped, "
                                         r"expected tf2_msgs/msg/TFMessage"):
        read_tf_streams(path, ["b"])
    msgs = [("/tf", TF, T0, kit.tf_message(store, [("a", "b", T0, I)])),
            ("/tf", TF, T0 + 1, kit.tf_message(store, [("c", "b", T0 + 1, I)]))]
    path = kit.write_bag(tmp_path / "twoparents", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"frame 'b' has two parents, 'a' and 'c'"):
        read_tf_streams(path, ["b"])
    msgs = [("/tf", TF, T0, kit.tf_message(store, [("a", "b", T0, I), ("b", "a", T0, I)]))]
    path = kit.write_bag(tmp_path / "loop", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"TF frames form a loop: b -> a -> b"):
        read_tf_streams(path, ["b"])
    msgs = [("/tf", TF, T0, kit.tf_message(store, [("a", "", T0, I)]))]
    path = kit.write_bag(tmp_path / "empty", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"topic /tf: a transform has an empty frame id \(parent "
                                         r"'a', child ''\)"):
        read_tf_streams(path, ["b"])
    msgs = [("/tf", TF, T0, kit.tf_message(store, [("a", "a", T0, I)]))]
    path = kit.write_bag(tmp_path / "self", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"topic /tf: frame 'a' is its own parent"):
        read_tf_streams(path, ["a"])
    bad = kit.tf_message(store, [("a", "b", T0, I)])
    bad.transforms[0].transform.rotation.w = 0.0
    path = kit.write_bag(tmp_path / "badstatic", "rosbag2-sqlite3", store,
                         [("/tf_static", TF, T0, bad)])
    with pytest.raises(InputError, match=r"topic /tf_static: static transform a -> b has invalid "
                                         r"numbers"):
        read_extrinsics_from_bag(path)
    path = kit.write_bag(tmp_path / "baddynamic", "rosbag2-sqlite3", store, [("/tf", TF, T0, bad)])
    with pytest.raises(InputError, match=r"TF a -> b: no valid pose samples \(1 dropped as "
                                         r"invalid\)"):
        read_tf_streams(path, ["b"])


def test_pose_topic_frame_must_not_change(kit, tmp_path):
    store = kit.store_for("rosbag2-sqlite3")
    I = np.eye(4)
    msgs = [("/p", "geometry_msgs/msg/PoseStamped", T0, kit.pose_stamped(store, "w", T0, I)),
            ("/p", "geometry_msgs/msg/PoseStamped", T0 + 1,
             kit.pose_stamped(store, "v", T0 + 1, I))]
    path = kit.write_bag(tmp_path / "frames", "rosbag2-sqlite3", store, msgs)
    with pytest.raises(InputError, match=r"topic /p: header frame id changes from 'w' to 'v'"):
        read_pose_topics(path, ["/p"])


# -- initial extrinsics from TF ------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_extrinsics_from_static_tf(kit, tmp_path, fmt):
    path, t, T_robot, _, T_robot_base, T_base_lidar = _mocap_bag(kit, tmp_path, fmt)
    ext = read_extrinsics_from_bag(path)
    assert set(ext.transforms) == {("vicon/robot", "base_link"), ("base_link", "lidar")}
    np.testing.assert_allclose(ext.lookup("vicon/robot", "lidar"), T_robot_base @ T_base_lidar,
                               atol=1e-12)
    # /tf too: moving mocap transforms are skipped
    ext = read_extrinsics_from_bag(path, topics=("/tf", "/tf_static"))
    assert ("world", "vicon/robot") not in ext.transforms
    with pytest.raises(InputError, match=r"no static transforms on /tf \(moving ones skipped: "
                                         r"world -> vicon/robot, world -> vicon/target\)"):
        read_extrinsics_from_bag(path, topics=("/tf",))


def test_extrinsics_from_constant_tf(kit, tmp_path):
    """The original tool's simulated bags publish the true calibrations on /tf, repeatedly."""
    store = kit.store_for("rosbag1")
    rng = np.random.default_rng(11)
    T_base_cam = kit.random_pose(rng)
    msgs = [("/tf", TF, T0 + k * 10_000_000, kit.tf_message(store, [
        ("base_link", "camera", T0 + k * 10_000_000, T_base_cam),
        ("world", "base_link", T0 + k * 10_000_000, kit.random_pose(rng))])) for k in range(5)]
    path = kit.write_bag(tmp_path / "gt.bag", "rosbag1", store, msgs)
    ext = read_extrinsics_from_bag(path, topics=("/tf",))
    assert list(ext.transforms) == [("base_link", "camera")]
    np.testing.assert_allclose(ext.lookup("camera", "base_link"), np.linalg.inv(T_base_cam),
                               atol=1e-12)


# -- hostile numbers (issue #11) ---------------------------------------------------------------


def _pose_bag(kit, tmp_path, fmt, edit):
    """/robot_pose PoseStamped at 100 Hz for 1 s; ``edit(k, msg)`` may spoil message k."""
    store = kit.store_for(fmt)
    t = _times(100.0, 1.0)
    T = kit.trajectory((t - T0) / NS)
    msgs = []
    for k, tk in enumerate(t):
        msg = kit.pose_stamped(store, "world", int(tk), T[k])
        edit(k, msg)
        msgs.append(("/robot_pose", "geometry_msgs/msg/PoseStamped", int(tk), msg))
    return kit.write_bag(kit.bag_path(tmp_path, fmt), fmt, store, msgs), t


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2-mcap"])
def test_nan_poses_in_a_pose_stream_are_dropouts_with_a_warning(kit, tmp_path, caplog, fmt):
    def nan_orientation(k, msg):
        if k in (20, 21, 60):
            msg.pose.orientation.x = float("nan")

    path, t = _pose_bag(kit, tmp_path, fmt, nan_orientation)
    with caplog.at_level("WARNING"):
        s = read_pose_topics(path, ["/robot_pose"])["robot_pose"]
    assert len(s) == len(t) - 3 and np.all(np.isfinite(s.T))
    assert not np.isin(t[[20, 21, 60]], s.t_ns).any()
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "topic /robot_pose: dropped 3 samples (of 101) as mocap dropouts" in caplog.text


@pytest.mark.parametrize("spoil, match", [
    (lambda m: setattr(m.pose.orientation, "w", 3.0),
     r"topic /robot_pose: message 30 \(stamp \d+ ns\): quaternion \(qx, qy, qz, qw\) = .* has norm "
     r"3\.\d+; expected a unit quaternion \(norm within 0\.001 of 1"),
    (lambda m: setattr(m.pose.position, "y", float("inf")),
     r"topic /robot_pose: message 30 \(stamp \d+ ns\): y is inf; expected a finite number"),
    (lambda m: setattr(m.pose.position, "z", -2.5e4),
     r"topic /robot_pose: message 30 .*: position z = -25000 m is beyond 10000 m"),
])
def test_non_poses_in_a_pose_stream_are_refused(kit, tmp_path, spoil, match):
    def edit(k, msg):
        if k == 30:
            spoil(msg)

    path, _ = _pose_bag(kit, tmp_path, "rosbag1", edit)
    with pytest.raises(InputError, match=match):
        read_pose_topics(path, ["/robot_pose"])
