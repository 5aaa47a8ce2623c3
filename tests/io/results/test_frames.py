"""The frame contract (rigcal.io.results.frames): which frames every writer publishes, with and
without the robot's URDF, and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, matrix_from_rpy, so3_exp
from rigcal.io.results.calibration_files import CalibrationTransforms, parse_calibration_transforms
from rigcal.io.results.frames import (
    T_BODY_OPTICAL,
    frames_block,
    plan_frames,
    plan_with_checks,
    recorded_frames,
)
from rigcal.io.results.urdf import forward_kinematics, parse_urdf

URDF = """<?xml version="1.0"?>
<robot name="car">
  <link name="base_link"/>
  <link name="lidar_link"/>
  <joint name="lidar_joint" type="fixed">
    <parent link="base_link"/><child link="lidar_link"/>
    <origin xyz="1.2 0 1.9" rpy="0 0 0"/>
  </joint>
  <link name="cam_link"/>
  <joint name="cam_joint" type="fixed">
    <parent link="base_link"/><child link="cam_link"/>
    <origin xyz="1.6 0.27 1.3" rpy="0 0.05 0"/>
  </joint>
  <link name="cam_optical_frame"/>
  <joint name="cam_optical_joint" type="fixed">
    <parent link="cam_link"/><child link="cam_optical_frame"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
  <link name="plain_cam"/>
  <joint name="plain_cam_joint" type="fixed">
    <parent link="base_link"/><child link="plain_cam"/>
    <origin xyz="1.5 -0.3 1.2" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
  <link name="stereo_link"/>
  <joint name="stereo_joint" type="fixed">
    <parent link="base_link"/><child link="stereo_link"/>
    <origin xyz="1.5 0 1.2" rpy="0 0 0"/>
  </joint>
  <link name="stereo_left_optical"/>
  <joint name="stereo_left_joint" type="fixed">
    <parent link="stereo_link"/><child link="stereo_left_optical"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
  <link name="stereo_right_optical"/>
  <joint name="stereo_right_joint" type="fixed">
    <parent link="stereo_link"/><child link="stereo_right_optical"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
</robot>
"""


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return from_rt(so3_exp(rng.normal(0, 0.5, 3)), rng.normal(0, 1.0, 3))


def _cal(frames: dict[str, tuple[str, np.ndarray]], parent="lidar_link", parent_kind="lidar",
         kind="relative") -> CalibrationTransforms:
    kinds = {f: k for f, (k, _) in frames.items()}
    if kind == "relative":
        kinds[parent] = parent_kind
    names = {f: f"s_{f}" for f in frames}
    if kind == "relative":
        names[parent] = "ref"
    return CalibrationTransforms(kind, parent, {f: T for f, (_, T) in frames.items()}, "cal.yaml",
                                 kinds, names=names)


def test_without_a_urdf_a_frame_id_is_its_measured_frame():
    T = _pose(1)
    plan = plan_frames(_cal({"cam_link": ("camera", T), "radar": ("radar", _pose(2))}))
    assert plan.root == "lidar_link" and plan.urdf is None
    assert [(t.parent, t.child) for t in plan.transforms] == [("lidar_link", "cam_link"),
                                                               ("lidar_link", "radar")]
    assert np.array_equal(plan.transforms[0].T_parent_child, T)
    # a camera whose name does not say "optical" is warned about
    _, warnings = plan_with_checks(_cal({"cam_link": ("camera", T)}))
    assert len(warnings) == 1 and "optical frame" in warnings[0] and "--urdf" in warnings[0]
    _, warnings = plan_with_checks(_cal({"cam_optical_frame": ("camera", T)}))
    assert warnings == []


@pytest.mark.parametrize("frame", ["cam_link", "cam_optical_frame"])
def test_a_camera_with_a_separate_optical_link_is_published_with_it(frame):
    """REP 103: whichever of the two the frame_id names, the calibrated pose is the optical
    child's; the camera link is published under the root and the optical joint below it."""
    urdf = parse_urdf(URDF, "car.urdf")
    T = _pose(3)
    plan, warnings = plan_with_checks(_cal({frame: ("camera", T)}), urdf)
    assert [(t.parent, t.child, t.calibrated) for t in plan.transforms] == [
        ("lidar_link", "cam_link", True), ("cam_link", "cam_optical_frame", False)]
    np.testing.assert_allclose(plan.T_root("cam_optical_frame"), T, atol=1e-12)
    np.testing.assert_allclose(plan.transforms[1].T_parent_child, T_BODY_OPTICAL, atol=1e-15)
    assert plan.notes and "REP 103" in plan.notes[0]
    # files written without this URDF publish another frame: the user is told
    if frame == "cam_link":
        assert len(warnings) == 1 and "cam_optical_frame" in warnings[0] and "disagrees" in warnings[0]
    # the 120 deg that the old writers got wrong: optical pose published as the body link
    wrong = plan_frames(_cal({frame: ("camera", T)})).T_root(frame)
    cos = (np.trace(wrong[:3, :3].T @ plan.T_root(frame)[:3, :3]) - 1) / 2
    angle = math.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    if frame == "cam_link":
        assert angle == pytest.approx(120.0, abs=1e-9)


def test_a_camera_link_without_an_optical_child_gets_the_optical_pose():
    urdf = parse_urdf(URDF, "car.urdf")
    plan = plan_frames(_cal({"plain_cam": ("camera", _pose(4))}), urdf)
    assert [(t.parent, t.child) for t in plan.transforms] == [("lidar_link", "plain_cam")]
    assert "no optical child" in plan.notes[0]


def test_a_lidar_named_like_an_optical_parent_is_taken_literally():
    urdf = parse_urdf(URDF, "car.urdf")
    plan = plan_frames(_cal({"cam_link": ("lidar", _pose(5))}), urdf)
    assert [(t.parent, t.child) for t in plan.transforms] == [("lidar_link", "cam_link")]


def test_a_camera_reference_with_an_optical_link_roots_the_tree_at_its_body_link():
    urdf = parse_urdf(URDF, "car.urdf")
    T = _pose(6)  # the lidar's pose in the camera's optical frame
    cal = _cal({"lidar_link": ("lidar", T)}, parent="cam_link", parent_kind="camera")
    plan = plan_frames(cal, urdf)
    assert plan.root == "cam_link"
    T_opt_lidar = invert(plan.T_root("cam_optical_frame")) @ plan.T_root("lidar_link")
    np.testing.assert_allclose(T_opt_lidar, T, atol=1e-12)


def test_refusals():
    urdf = parse_urdf(URDF, "car.urdf")
    with pytest.raises(InputError, match=r"link 'stereo_link' has 2 optical children "
                                         r"\(stereo_left_optical, stereo_right_optical\)"):
        plan_frames(_cal({"stereo_link": ("camera", _pose(7))}), urdf)
    # two sensors that end up in one frame
    with pytest.raises(InputError, match=r"would both publish the frame 'cam_link'"):
        plan_frames(_cal({"cam_link": ("camera", _pose(8)),
                          "cam_optical_frame": ("camera", _pose(9))}), urdf)
    with pytest.raises(InputError, match=r"would both publish the frame 'lidar_link'"):
        plan_frames(_cal({"lidar_link": ("radar", _pose(8))}))


def test_frames_block_round_trips_through_calibration_yaml():
    """What calibration.yaml records (resolved in a URDF) is what a later export without the
    URDF publishes."""
    urdf = parse_urdf(URDF, "car.urdf")
    T = _pose(10)
    plan = plan_frames(_cal({"cam_link": ("camera", T), "radar": ("radar", _pose(11))}), urdf)
    block = yaml.safe_load(yaml.safe_dump(frames_block(plan)))
    ref, recorded, source = recorded_frames(block, "cal.yaml")
    assert ref == "lidar_link" and source == "car.urdf"
    assert recorded["cam_link"][:2] == ("cam_link", "cam_optical_frame")
    doc = {"reference": "ref", "mode": "fcpe", "frames": block, "sensors": {
        "ref": {"kind": "lidar", "frame_id": "lidar_link", "T_reference_sensor": np.eye(4).tolist()},
        "s_cam": {"kind": "camera", "frame_id": "cam_link", "T_reference_sensor": T.tolist()},
        "s_radar": {"kind": "radar", "frame_id": "radar", "T_reference_sensor": _pose(11).tolist()},
    }}
    cal = parse_calibration_transforms(yaml.safe_dump(doc), "cal.yaml")
    again = plan_frames(cal)  # no URDF: the recorded names
    assert [(t.parent, t.child) for t in again.transforms] == [(t.parent, t.child) for t in plan.transforms]
    for a, b in zip(again.transforms, plan.transforms):
        np.testing.assert_allclose(a.T_parent_child, b.T_parent_child, atol=1e-12)
    for e in block["static_transforms"]:
        x, y, z, w = e["quaternion_xyzw"]
        assert w >= 0 and abs(x * x + y * y + z * z + w * w - 1) < 1e-12
    with pytest.raises(InputError, match=r"cal.yaml: frames.sensors.s_cam_link: link 'cam_link' differs"):
        bad = yaml.safe_load(yaml.safe_dump(block))
        del bad["sensors"]["s_cam_link"]["T_link_measured"]
        recorded_frames(bad, "cal.yaml")


def test_the_optical_rotation_is_rep_103():
    # optical z (forward) is body x, optical x (right) is body -y, optical y (down) is body -z
    R = T_BODY_OPTICAL[:3, :3]
    np.testing.assert_allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, -1], atol=1e-15)
    urdf = parse_urdf(URDF, "car.urdf")
    np.testing.assert_allclose(forward_kinematics(urdf, "cam_link", "cam_optical_frame"),
                               T_BODY_OPTICAL, atol=1e-15)
    np.testing.assert_allclose(matrix_from_rpy(np.array([-math.pi / 2, 0, -math.pi / 2])), R)
