"""Guidance: field-of-view checks, relative-motion rejection, crop regions that grow with the
calibration uncertainty and with distance; and the result values."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.extract import (
    REASONS,
    ExtractionFailure,
    Measurement,
    PixelBox,
    PoseUncertainty,
    box_from_points,
    camera_view,
    expected_image_box,
    lidar_crop_box,
    lidar_view,
    motion_check,
    relative_speeds,
)
from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import so3_exp
from rigcal.sensors.camera import PinholeCamera

CAM = PinholeCamera(1280, 960, np.array([1000.0, 1000.0, 640.0, 480.0]))
SQUARE = np.array([[x, y, 0.0] for x in (-0.2, 0.2) for y in (-0.2, 0.2)])


def ahead(z: float, x: float = 0.0) -> np.ndarray:
    return from_rt(np.eye(3), [x, 0.0, z])


# ---------------------------------------------------------------------------- field of view
def test_camera_view():
    v = camera_view(CAM, ahead(2.0), SQUARE)
    assert v.visible and v.fraction == 1.0 and v.reason == ""
    # 0.2 m square corners at 2 m project 100 px from the centre: a 600 px margin cuts all
    v = camera_view(CAM, ahead(2.0), SQUARE, margin_px=600)
    assert not v.visible and v.reason == "target_not_in_view"
    # half of it beyond the right border
    v = camera_view(CAM, ahead(2.0, x=1.28), SQUARE, min_fraction=0.5)
    assert v.visible and v.fraction == 0.5
    assert not camera_view(CAM, ahead(2.0, x=1.28), SQUARE).visible
    assert not camera_view(CAM, ahead(-2.0), SQUARE).visible  # behind
    with pytest.raises(InputError, match="4x4"):
        camera_view(CAM, np.eye(3), SQUARE)
    with pytest.raises(InputError, match="points_target"):
        camera_view(CAM, ahead(2.0), SQUARE[:, :2])


def test_lidar_view():
    T = from_rt(np.eye(3), [5.0, 0.0, 0.0])
    assert lidar_view(T, SQUARE).visible
    assert lidar_view(T, SQUARE, max_range_m=4.0).reason == "target_not_in_view"
    high = from_rt(np.eye(3), [2.0, 0.0, 1.5])  # 37 deg up
    assert not lidar_view(high, SQUARE).visible
    behind = from_rt(np.eye(3), [-5.0, 0.0, 0.0])
    front_only = (math.radians(-60), math.radians(60))
    assert lidar_view(behind, SQUARE).visible
    assert not lidar_view(behind, SQUARE, azimuth_fov_rad=front_only).visible
    # a wrapped interval: 170 deg to -170 deg is the 20 deg behind the sensor
    wrapped = (math.radians(170), math.radians(-170))
    assert lidar_view(behind, SQUARE, azimuth_fov_rad=wrapped).visible


# ---------------------------------------------------------------------------- motion
def track(speeds_mps, rates_radps, dt_s=0.01):
    """Poses of a target moving along x at the given speeds and turning about z."""
    n = len(speeds_mps) + 1
    t_ns = np.arange(n, dtype=np.int64) * int(dt_s * 1e9)
    x = np.concatenate([[2.0], 2.0 + np.cumsum(np.asarray(speeds_mps) * dt_s)])
    yaw = np.concatenate([[0.0], np.cumsum(np.asarray(rates_radps) * dt_s)])
    T = np.stack([from_rt(so3_exp([0.0, 0.0, a]), [xi, 0.5, 0.0]) for xi, a in zip(x, yaw)])
    return t_ns, T


def test_relative_speeds():
    t, T = track([0.1] * 5, [0.2] * 5)
    t_mid, lin, ang = relative_speeds(t, T)
    assert len(t_mid) == 5 and np.allclose(lin, 0.1) and np.allclose(ang, 0.2)
    assert t_mid[0] == 5_000_000


def test_motion_check_rejects_a_moving_target():
    # still for 1 s, then a push at 0.2 m/s for 0.1 s, then still again
    speeds = [0.0] * 100 + [0.2] * 10 + [0.0] * 100
    t, T = track(speeds, [0.0] * len(speeds))
    still = motion_check(500_000_000, t, T, window_s=0.4)
    assert still.still and still.reason == "" and still.max_linear_mps == pytest.approx(0.0)
    moving = motion_check(1_050_000_000, t, T, window_s=0.4)
    assert not moving.still and moving.reason == "target_moving"
    assert moving.max_linear_mps == pytest.approx(0.2)
    # the window reaches the push from 0.15 s away, not from 0.3 s
    assert not motion_check(1_250_000_000, t, T, window_s=0.4).still
    assert motion_check(1_400_000_000, t, T, window_s=0.4).still
    # turning only
    t, T = track([0.0] * 100, [math.radians(10.0)] * 100)
    spin = motion_check(500_000_000, t, T, window_s=0.2, max_angular_radps=math.radians(2.0))
    assert not spin.still and spin.max_angular_radps == pytest.approx(math.radians(10.0))
    # no mocap data around the query
    none = motion_check(5_000_000_000, t, T)
    assert not none.still and none.reason == "no_pose_data"


def test_motion_check_sees_through_the_mcs_noise_per_sample():
    # a Vicon's noise on the robot and the target (0.15 mm / 0.3 mrad each, 100 Hz) seen 2.5 m
    # away: sample to sample it is 0.1 m/s and 6 deg/s; over the 0.1 s baseline the still
    # target is still, and the push is still seen
    from rigcal.geometry.se3 import se3_exp

    rng = np.random.default_rng(3)
    speeds = [0.0] * 100 + [0.2] * 10 + [0.0] * 100
    t, T = track(speeds, [0.0] * len(speeds))
    noise = [se3_exp(np.r_[rng.normal(0, 0.0003 * 2 ** 0.5, 3), rng.normal(0, 0.00015 * 2 ** 0.5, 3)])
             for _ in T]
    lever = [from_rt(so3_exp(rng.normal(0, 0.0003, 3)), [0, 0, 0]) for _ in T]  # the robot's turn
    Tn = np.stack([L @ A @ N for L, A, N in zip(lever, T, noise)])
    raw = relative_speeds(t, Tn)
    assert raw[1].max() > 0.1 and raw[2].max() > math.radians(5.0)  # what the old check saw
    still = motion_check(500_000_000, t, Tn, window_s=0.5, max_linear_mps=0.1, max_angular_radps=math.radians(5))
    assert still.still, still.detail
    assert not motion_check(1_050_000_000, t, Tn, window_s=0.5, max_linear_mps=0.1,
                            max_angular_radps=math.radians(5)).still


def test_motion_check_validates_the_track():
    t, T = track([0.0] * 10, [0.0] * 10)
    with pytest.raises(InputError, match="strictly increasing"):
        motion_check(0, t[::-1].copy(), T)
    with pytest.raises(InputError, match="integer"):
        motion_check(0, t.astype(float), T)
    with pytest.raises(InputError, match="match t_ns"):
        motion_check(0, t, T[:-1])


# ---------------------------------------------------------------------------- crops
def test_image_box_grows_with_uncertainty_and_nearness():
    base = expected_image_box(CAM, ahead(2.0), SQUARE, None, margin_px=0.0)
    assert base == PixelBox(540, 380, 741, 581)
    unc = PoseUncertainty(0.02, math.radians(1.0), 2.0)
    grown = expected_image_box(CAM, ahead(2.0), SQUARE, unc, margin_px=0.0)
    # margin = n * f * (sigma_rot + sigma_t / d) = 2 * 1000 * (0.01745 + 0.01) = 54.9 px
    # (at the nearest point, 2.02 m away, and the largest image scale there)
    assert grown.u_min == pytest.approx(540 - 55, abs=2)
    assert grown.width == pytest.approx(base.width + 2 * 55, abs=4)
    near = expected_image_box(CAM, ahead(1.0), SQUARE, unc, margin_px=0.0)
    far = expected_image_box(CAM, ahead(4.0), SQUARE, unc, margin_px=0.0)
    # the translation part of the margin shrinks with depth
    assert near.width - 400 > far.width - 100
    assert expected_image_box(CAM, ahead(-2.0), SQUARE, unc) is None


def test_pixel_box():
    b = PixelBox(-10, 20, 100, 2000)
    c = b.clip(64, 48)
    assert c == PixelBox(0, 20, 64, 48) and c.area == 64 * 28
    assert PixelBox(100, 100, 200, 200).clip(50, 50).area == 0
    uv = np.array([[0, 0], [9.4, 9.4], [9.6, 0], [-0.6, 0]])
    assert list(PixelBox(0, 0, 10, 10).contains(uv)) == [True, True, False, False]


def test_lidar_crop_box_grows_with_distance():
    lo, hi = box_from_points(SQUARE, pad_m=0.05)
    assert np.allclose(lo, [-0.25, -0.25, -0.05]) and np.allclose(hi, [0.25, 0.25, 0.05])
    unc = PoseUncertainty(0.02, math.radians(2.0), 3.0)
    near = lidar_crop_box(from_rt(np.eye(3), [2.0, 0, 0]), lo, hi, unc)
    far = lidar_crop_box(from_rt(np.eye(3), [8.0, 0, 0]), lo, hi, unc)
    # margin 3 * (0.02 + d * 0.0349): 0.27 m at 2 m, 0.90 m at 8 m
    assert near.size_m[0] == pytest.approx(0.5 + 2 * 3 * (0.02 + 2.0 * math.radians(2.0)))
    assert far.size_m[0] == pytest.approx(0.5 + 2 * 3 * (0.02 + 8.0 * math.radians(2.0)))
    pts = np.array([[2.0, 0.0, 0.0], [2.0, 0.5, 0.0], [2.0, 0.6, 0.0], [3.0, 0.0, 0.0]])
    assert list(near.contains(pts)) == [True, True, False, False]
    with pytest.raises(InputError, match="below min"):
        lidar_crop_box(np.eye(4), hi, lo)


def test_uncertainty_is_validated():
    with pytest.raises(InputError, match="sigma_rotation_rad"):
        PoseUncertainty(0.01, -0.1)
    u = PoseUncertainty(0.01, 0.0, 2.0)
    assert u.margin_m(10.0) == pytest.approx(0.02)
    assert u.margin_px(1000.0, 2.0) == pytest.approx(10.0)


# ---------------------------------------------------------------------------- results
def test_measurement_is_an_immutable_value():
    m = Measurement("cam", 3.0, "checkerboard", [[1.0, 2.0], [3.0, 4.0]], [0, 1], np.eye(4),
                    extras={"crop_box": [0, 0, 4, 4]}, quality={"rms": 1})
    assert m.ok and len(m) == 2 and m.t_ns == 3 and isinstance(m.t_ns, int)
    assert not m.keypoints.flags.writeable and not m.extras["crop_box"].flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.sensor = "x"  # type: ignore[misc]
    with pytest.raises(TypeError):
        m.quality["rms"] = 2.0  # type: ignore[index]
    with pytest.raises(InputError, match=r"\(N, 2\) pixels or \(N, 3\)"):
        Measurement("cam", 0, "x", np.zeros((3, 4)))
    with pytest.raises(InputError, match="keypoint_index"):
        Measurement("cam", 0, "x", np.zeros((3, 2)), [0, 1])
    with pytest.raises(InputError, match="4x4"):
        Measurement("cam", 0, "x", np.zeros((3, 2)), None, np.eye(3))


def test_failure_reasons_are_a_closed_set():
    f = ExtractionFailure("lidar", 1, "no_cluster", "none")
    assert not f.ok and f.reason in REASONS
    with pytest.raises(InputError, match="unknown extraction failure reason"):
        ExtractionFailure("lidar", 1, "oops")
    assert {"black_image", "no_corners", "crop_outside_image", "target_not_in_view",
            "pattern_size_mismatch", "no_points_in_crop", "no_cluster", "icp_diverged",
            "target_moving"} <= REASONS
