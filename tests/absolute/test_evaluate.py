"""Checks of T_body_sensor: ground-normal angle (eq. 13), yaw from a straight drive past poles,
labelling repeatability (Table IV)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.absolute.evaluate import (
    extract_poles,
    ground_normal_angle,
    labelling_repeatability,
    track_poles,
    yaw_from_pole_tracks,
    yaw_from_straight_drive,
)
from rigcal.absolute.labels import wheel_centre
from rigcal.errors import GeometryError, InputError
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.sim.vehicle import (
    SimVehicle,
    believed_pose,
    simulate_hub_labels,
    simulate_rim_labels,
    simulate_straight_drive,
)

ERROR_RPY_DEG = (0.3, 0.4, 0.5)  # believed minus true: tilt 0.5 deg, yaw 0.5 deg


@pytest.fixture(scope="module")
def drive():
    return simulate_straight_drive(SimVehicle(), "lidar1", error_rpy_deg=ERROR_RPY_DEG, rng=3)


@pytest.fixture(scope="module")
def poles(drive):
    return [extract_poles(scan, rng=k) for k, scan in enumerate(drive.scans_sensor)]


# ----------------------------------------------------------------------------- eq. 13


def test_ground_normal_angle_recovers_an_injected_tilt(drive):
    """Must-show: a 0.5 deg tilt error (roll 0.3, pitch 0.4) is measured within 0.02 deg."""
    E = matrix_from_rpy(np.radians(ERROR_RPY_DEG[:2] + (0.0,)))
    expected = math.degrees(math.acos(E[2, 2]))  # 0.49999 deg
    for scan in drive.scans_sensor[:3]:
        chk = ground_normal_angle(scan, drive.T_body_sensor_believed, max_range_m=6.0)
        assert abs(chk.angle_deg - expected) <= 0.02  # measured within 0.001 deg
        assert abs(math.degrees(chk.roll_error_rad) - 0.3) <= 0.02
        assert abs(math.degrees(chk.pitch_error_rad) - 0.4) <= 0.02
        fixed = chk.correct(drive.T_body_sensor_believed)
        again = ground_normal_angle(scan, fixed, max_range_m=6.0)
        assert again.angle_deg <= 0.02
    truth = ground_normal_angle(drive.scans_sensor[0], drive.T_body_sensor_true)
    assert truth.angle_deg <= 0.02


def test_ground_normal_angle_without_ground(drive):
    scan = drive.scans_sensor[0]
    T = drive.T_body_sensor_true
    no_ground = scan[(scan @ T[:3, :3].T + T[:3, 3])[:, 2] > 0.3]  # only the poles are left
    with pytest.raises(GeometryError, match=r"lidar1: no ground"):
        ground_normal_angle(no_ground, drive.T_body_sensor_believed, source="lidar1")
    with pytest.raises(InputError, match=r"T_body_sensor: expected a finite \(4, 4\) transform"):
        ground_normal_angle(scan, np.eye(3))


# ----------------------------------------------------------------------------- poles, yaw


def test_pole_extraction_finds_the_poles(drive, poles):
    scan = 12
    T_ws = drive.T_world_body[scan] @ drive.T_body_sensor_true
    truth = drive.poles_world
    found = np.array([p.position for p in poles[scan]])
    world = found @ T_ws[:3, :3].T + T_ws[:3, 3]
    near = np.hypot(truth[:, 0] - T_ws[0, 3], truth[:, 1] - T_ws[1, 3]) < 15.0
    assert len(found) >= near.sum() >= 2
    for x, y, r in truth[near]:
        d = np.hypot(world[:, 0] - x, world[:, 1] - y)
        assert d.min() < 0.05  # the axis, not the near-side centroid
        k = int(np.argmin(d))
        assert abs(world[k, 2]) < 0.05  # on the ground
        assert poles[scan][k].radius_m == pytest.approx(r, abs=0.03)
        assert poles[scan][k].height_span_m > 1.0


def test_yaw_from_a_straight_drive_recovers_an_injected_error(drive, poles):
    """Must-show: a 0.5 deg yaw error is measured within 0.02 deg (median over six poles)."""
    yd = yaw_from_straight_drive(poles, drive.T_body_sensor_believed)
    assert len(yd.tracks) == 6 and yd.spans_m.min() > 15.0
    assert abs(yd.alpha_deg - 0.5) <= 0.02  # measured 0.498 deg
    fixed = yd.correct(drive.T_body_sensor_believed)
    assert abs(yaw_from_straight_drive(poles, fixed).alpha_deg) <= 0.02
    assert abs(yaw_from_straight_drive(poles, drive.T_body_sensor_true).alpha_deg) <= 0.02
    # centroids instead of circle centres are biased toward the sensor: a worse estimate
    centroids = [np.array([p.centroid for p in ps]).reshape(-1, 3) for ps in poles]
    biased = yaw_from_straight_drive(centroids, drive.T_body_sensor_believed)
    assert abs(biased.alpha_deg - 0.5) > abs(yd.alpha_deg - 0.5)


def test_negative_yaw_error_from_pole_positions():
    """Tracks built from pole positions directly (no lidar): sign and tracking."""
    err = math.radians(-0.7)
    T_true = np.eye(4)
    T_believed = believed_pose(T_true, (0.0, 0.0, -0.7))
    poles_world = np.array([[12.0, -4.0, 0.0], [20.0, -5.0, 0.0], [28.0, -4.5, 0.0], [36.0, 3.0, 0.0]])
    per_scan = []
    for k in range(30):
        rel = poles_world - [1.2 * k, 0.0, 0.0]
        rel = rel[(rel[:, 0] > -12) & (rel[:, 0] < 18)]
        per_scan.append(rel)  # T_true = I: the sensor frame is the body frame
    yd = yaw_from_straight_drive(per_scan, T_believed)
    assert len(yd.tracks) == 4
    assert yd.alpha_rad == pytest.approx(err, abs=1e-9)
    assert np.allclose(yd.per_pole_alpha_rad, err)


def test_tracking_needs_poles_seen_long_enough():
    one_scan = [np.array([[5.0, -4.0, 0.0]])]
    with pytest.raises(GeometryError, match=r"none of 0 pole tracks was seen over 5\.0 m with 5 positions"):
        yaw_from_straight_drive(one_scan, np.eye(4))
    short = [np.array([[5.0 - 0.5 * k, -4.0, 0.0]]) for k in range(8)]
    assert len(track_poles(short)) == 1
    with pytest.raises(GeometryError, match=r"none of 1 pole tracks was seen over 5\.0 m"):
        yaw_from_pole_tracks(track_poles(short))
    with pytest.raises(InputError, match=r"scan 1 has non-finite pole positions"):
        yaw_from_straight_drive([np.zeros((1, 3)), np.full((1, 3), np.nan)], np.eye(4))


# ----------------------------------------------------------------------------- Table IV


def test_labelling_repeatability_single_point_vs_circle_fit():
    """Must-show (Table IV): the rear-left wheel labelled 10 times; the circle fit through 10 rim
    clicks (2 mm) spreads less than single clicks on the hub (1 cm) on every axis."""
    v = SimVehicle()
    T = np.eye(4)
    single = [wheel_centre("rear_left", simulate_hub_labels(v, T, k).points["rear_left"]).centre for k in range(10)]
    circle = [
        wheel_centre("rear_left", simulate_rim_labels(v, T, 100 + k).points["rear_left"], rng=k).centre
        for k in range(10)
    ]
    s, c = labelling_repeatability(np.array(single)), labelling_repeatability(np.array(circle))
    assert s.count == c.count == 10
    assert np.all(c.std_m < s.std_m)  # measured: single (10.6, 12.3, 12.3), circle (0.7, 0.6, 0.7) mm
    assert np.all(c.std_m < 0.0015)
    np.testing.assert_allclose(c.mean_m, v.hub_centres_body()["rear_left"], atol=0.001)


def test_repeatability_input_errors():
    with pytest.raises(InputError, match=r"needs at least 2 repeated labellings, got 1"):
        labelling_repeatability(np.zeros((1, 3)))
    with pytest.raises(InputError, match=r"expected \(R, 3\) repeated centres, got shape \(3,\)"):
        labelling_repeatability(np.zeros(3))
