"""The simulated vehicle: external scan, labels, markers and the straight drive match their truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.absolute.labels import WHEEL_NAMES
from rigcal.errors import InputError
from rigcal.geometry.se3 import invert
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.sim.rig import prius_like_rig
from rigcal.sim.vehicle import (
    SURFACE_BODY,
    SURFACE_GROUND,
    SURFACE_RIM,
    SURFACE_TYRE,
    ExternalScanner,
    SimLidar,
    SimVehicle,
    believed_pose,
    simulate_external_scan,
    simulate_hub_labels,
    simulate_markers,
    simulate_rim_labels,
    simulate_straight_drive,
)

V = SimVehicle()


@pytest.fixture(scope="module")
def scan():
    return simulate_external_scan(V, rng=5)


def _body(scan, pts):
    T = invert(scan.T_external_body)
    return pts @ T[:3, :3].T + T[:3, 3]


def test_vehicle_geometry_and_sensors():
    c = V.wheel_centres_body()
    assert list(c) == list(WHEEL_NAMES)
    np.testing.assert_allclose(c["front_left"], [2.7, 0.775, 0.32])
    np.testing.assert_allclose(V.hub_centres_body()["rear_right"], [0.0, -0.845, 0.32])
    np.testing.assert_array_equal(V.T_body_sensor("lidar1"), prius_like_rig()[0].T_rig_sensor)
    with pytest.raises(InputError, match=r"unknown sensor 'lidar9'"):
        V.T_body_sensor("lidar9")
    with pytest.raises(InputError, match=r"rim_radius_m \(0\.4\) must be below tyre_radius_m"):
        SimVehicle(rim_radius_m=0.4)
    with pytest.raises(InputError, match=r"body_width_m must leave the wheels outside the body"):
        SimVehicle(body_width_m=1.5)


def test_external_scan_surfaces_lie_where_they_should(scan):
    p = _body(scan, scan.points_external)
    assert set(np.unique(scan.surface)) == {SURFACE_GROUND, SURFACE_BODY, SURFACE_TYRE, SURFACE_RIM}
    assert set(np.unique(scan.station)) == {0, 1}
    g = p[scan.surface == SURFACE_GROUND]
    assert abs(np.mean(g[:, 2])) < 2e-4 and np.std(g[:, 2]) < 0.004  # 2 mm range noise
    rim = p[scan.surface == SURFACE_RIM]
    assert np.all(np.abs(np.abs(rim[:, 1]) - 0.86) < 0.03)  # recessed faces and their walls
    both_sides = np.sign(rim[:, 1])
    assert (both_sides > 0).any() and (both_sides < 0).any()
    tyre = p[scan.surface == SURFACE_TYRE]
    assert tyre[:, 2].min() > -0.01 and tyre[:, 2].max() < 0.65


def test_external_scan_is_seeded():
    a = simulate_external_scan(V, ExternalScanner(angle_step_deg=1.0), rng=2)
    b = simulate_external_scan(V, ExternalScanner(angle_step_deg=1.0), rng=2)
    np.testing.assert_array_equal(a.points_external, b.points_external)
    none = simulate_external_scan(V, ExternalScanner(angle_step_deg=1.0), rng=2, ground=False)
    assert SURFACE_GROUND not in none.surface


def test_labels_and_markers_follow_their_noise(scan):
    T = scan.T_external_body
    rim = simulate_rim_labels(V, T, 0, n_points=200, sigma_m=0.002)
    for w, hub in V.hub_centres_body().items():
        p = _body(scan, rim.points[w]) - hub
        radial = np.hypot(p[:, 0], p[:, 2]) - V.rim_radius_m
        assert np.std(radial) == pytest.approx(0.002, rel=0.2)
        assert np.std(p[:, 1]) == pytest.approx(0.002, rel=0.2)
    hub = simulate_hub_labels(V, T, 0, sigma_m=0.0)
    np.testing.assert_allclose(_body(scan, hub.points["front_right"])[0], V.hub_centres_body()["front_right"], atol=1e-12)
    m = simulate_markers(V, T, 0, placement_sigma_m=0.0, detection_sigma_m=0.0)
    np.testing.assert_allclose(_body(scan, m.markers["marker_rear_left"][None])[0], [0.0, 1.175, 0.0], atol=1e-12)
    errs = np.array([
        _body(scan, simulate_markers(V, T, k).markers["marker_front_left"][None])[0] - [2.7, 1.175, 0.0]
        for k in range(200)
    ])
    assert np.std(errs[:, :2]) == pytest.approx(0.01, rel=0.15) and np.std(errs[:, 2]) < 0.002


def test_straight_drive_truth():
    lidar = SimLidar(azimuth_step_deg=1.0, range_sigma_m=0.0)
    d = simulate_straight_drive(V, error_rpy_deg=(0.1, -0.2, 0.5), n_scans=3, lidar=lidar, rng=0)
    assert len(d.scans_sensor) == 3 and d.T_world_body.shape == (3, 4, 4)
    np.testing.assert_allclose(d.T_world_body[:, 0, 3], [0.0, 1.25, 2.5])
    E = d.T_body_sensor_believed[:3, :3] @ d.T_body_sensor_true[:3, :3].T
    np.testing.assert_allclose(np.degrees(rpy_from_matrix(E)), [0.1, -0.2, 0.5], atol=1e-9)
    np.testing.assert_array_equal(d.T_body_sensor_believed[:3, 3], d.T_body_sensor_true[:3, 3])
    # noise-free points land on the ground or on a pole surface in the world
    T_ws = d.T_world_body[1] @ d.T_body_sensor_true
    w = d.scans_sensor[1] @ T_ws[:3, :3].T + T_ws[:3, 3]
    on_ground = np.abs(w[:, 2]) < 1e-9
    rho = np.min(np.hypot(w[:, None, 0] - d.poles_world[:, 0], w[:, None, 1] - d.poles_world[:, 1]), axis=1)
    assert np.all(on_ground | (np.abs(rho - 0.1) < 1e-9))
    assert (~on_ground).sum() > 20  # a 1 deg azimuth step still hits the poles
    np.testing.assert_allclose(believed_pose(np.eye(4), (0, 0, 90))[:3, 0], [0, 1, 0], atol=1e-12)
    with pytest.raises(InputError, match=r"poles: expected \(P, 3\) rows \(x, y, radius\), got shape \(2,\)"):
        simulate_straight_drive(V, poles=np.zeros(2))
    assert math.isclose(SimLidar().range_sigma_m, 0.01)
