"""The body frame from rim circles, single clicks and markers on a simulated Leica scan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.absolute.body_frame import (
    body_frame_from_labels,
    body_frame_from_markers,
    body_frame_from_reference_points,
    body_frame_from_wheels,
    sensor_in_body,
    sensors_in_body,
)
from rigcal.absolute.labels import WHEEL_NAMES, GroundPlane, LabelSet, fit_ground_plane
from rigcal.errors import ConfigError, GeometryError, InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy, rpy_from_matrix
from rigcal.sim.vehicle import (
    SimVehicle,
    simulate_external_scan,
    simulate_hub_labels,
    simulate_markers,
    simulate_rim_labels,
)

VEHICLE = SimVehicle()
SEEDS = range(20)


@pytest.fixture(scope="module")
def scan():
    return simulate_external_scan(VEHICLE, rng=1)


@pytest.fixture(scope="module")
def ground(scan):
    return fit_ground_plane(scan.points_external, rng=0)


def _errors(bf, T_external_body):
    """(roll, pitch, yaw) [deg] and origin error [mm] of an estimated body frame."""
    E = invert(T_external_body) @ bf.T_external_body
    return np.degrees(rpy_from_matrix(E[:3, :3])), 1000 * np.linalg.norm(E[:3, 3])


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def test_rim_circles_with_2mm_noise(scan, ground):
    """Must-show: 10 rim clicks per wheel, 2 mm noise -> yaw <= 0.02 deg (RMS over 20
    labellings; one labelling's 1-sigma is about 0.013 deg), roll/pitch <= 0.05 deg and
    origin <= 5 mm (every labelling)."""
    T = scan.T_external_body
    rpy, origin = [], []
    for seed in SEEDS:
        labels = simulate_rim_labels(VEHICLE, T, seed, n_points=10, sigma_m=0.002)
        if seed == 0:  # the whole pipeline once: ground plane of the scan, circles, frame
            bf = body_frame_from_labels(labels, scan.points_external, method="circle", rng=seed)
        else:
            bf = body_frame_from_labels(labels, ground_plane=ground, method="circle", rng=seed)
        r, o = _errors(bf, T)
        rpy.append(r)
        origin.append(o)
    rpy = np.abs(np.array(rpy))
    assert _rms(rpy[:, 2]) <= 0.02  # measured 0.012 deg
    assert rpy[:, 2].max() <= 0.04  # about 3 sigma
    assert rpy[:, :2].max() <= 0.05  # measured < 0.005 deg: Z is the ground normal
    assert max(origin) <= 5.0  # measured 0.8 mm RMS, 1.3 mm max
    bf = body_frame_from_labels(simulate_rim_labels(VEHICLE, T, 0), ground_plane=ground)
    assert bf.wheelbase_m == pytest.approx(VEHICLE.wheelbase_m, abs=0.003)
    hub_track = VEHICLE.track_m + VEHICLE.tyre_width_m - 2 * VEHICLE.rim_inset_m
    assert bf.track_rear_m == pytest.approx(hub_track, abs=0.003)
    assert bf.points_body["front_left"][2] == pytest.approx(VEHICLE.tyre_radius_m, abs=0.003)


def test_markers_with_1cm_placement_error_are_worse(scan, ground):
    """Must-show: markers placed with 1 cm error -> yaw ~ 1 cm / wheelbase ~ 0.2 deg RMS and the
    origin ~ 1 cm off (the midpoint of two markers); rim circles are > 10x better in yaw."""
    T = scan.T_external_body
    yaw_m, origin_m, yaw_r, tilt_own = [], [], [], []
    for seed in SEEDS:
        markers = simulate_markers(VEHICLE, T, seed, placement_sigma_m=0.01)
        bf = body_frame_from_labels(markers, ground_plane=ground)
        r, o = _errors(bf, T)
        yaw_m.append(r[2])
        origin_m.append(o)
        assert max(abs(r[:2])) < 0.005  # Z still comes from the scan's ground
        own = body_frame_from_markers(markers.markers)  # Z from the four markers' plane
        tilt_own.append(_errors(own, T)[0][:2])
        rim = body_frame_from_labels(simulate_rim_labels(VEHICLE, T, seed), ground_plane=ground)
        yaw_r.append(_errors(rim, T)[0][2])
    expected_yaw = math.degrees(0.01 / VEHICLE.wheelbase_m)  # 0.21 deg
    assert 0.5 * expected_yaw < _rms(yaw_m) < 1.6 * expected_yaw  # measured 0.21 deg
    assert 5.0 < _rms(origin_m) < 15.0  # measured 11 mm
    assert _rms(yaw_m) > 10 * _rms(yaw_r)
    # without the scan's ground, marker detection noise (1 mm) tilts Z by a few 0.01 deg
    assert 0.005 < _rms(tilt_own) < 0.1


def test_single_clicks_on_the_hub(scan, ground):
    T = scan.T_external_body
    exact = body_frame_from_labels(simulate_hub_labels(VEHICLE, T, 0, sigma_m=0.0), ground_plane=ground)
    r, o = _errors(exact, T)
    assert max(abs(r)) < 0.005 and o < 0.5
    noisy = [_errors(body_frame_from_labels(simulate_hub_labels(VEHICLE, T, s), ground_plane=ground), T)[0][2] for s in SEEDS]
    assert 0.05 < _rms(noisy) < 0.5  # 1 cm clicks: about as bad as markers


@pytest.mark.parametrize("origin, x", [("rear_axle", 0.0), ("front_axle", 2.7), ("wheelbase_centre", 1.35)])
def test_origin_choice(ground, scan, origin, x):
    centres = {w: invert(np.eye(4))[:3, :3] @ c for w, c in VEHICLE.wheel_centres_body().items()}
    T = scan.T_external_body
    ext = {w: T[:3, :3] @ c + T[:3, 3] for w, c in centres.items()}
    bf = body_frame_from_wheels(ext, ground, origin=origin)
    expected = T @ from_rt(np.eye(3), [x, 0.0, 0.0])
    np.testing.assert_allclose(bf.T_external_body, expected, atol=5e-4)
    assert bf.origin == origin
    assert bf.transform("leica").to_frame == "leica" and bf.transform().from_frame == "body"
    np.testing.assert_allclose(bf.T_body_external @ bf.T_external_body, np.eye(4), atol=1e-12)


def _flat_ground():
    return GroundPlane(np.array([0.0, 0.0, 1.0]), 0.0, np.ones(1, bool), 0.0, 0.02)


def test_degenerate_wheels_are_refused():
    c = {w: v for w, v in VEHICLE.wheel_centres_body().items()}
    coincident = {**c, "front_left": c["rear_left"] + [0.1, 0, 0], "front_right": c["rear_right"]}
    with pytest.raises(GeometryError, match=r"rear and front axle centres coincide on the ground \(50 mm apart"):
        body_frame_from_wheels(coincident, _flat_ground())
    swapped = {**c, "rear_left": c["rear_right"], "rear_right": c["rear_left"]}
    with pytest.raises(GeometryError, match=r"'rear_left' lies 0\.775 m to the right of the rear->front axis"):
        body_frame_from_wheels(swapped, _flat_ground())
    backwards = {**c, "rear_left": c["front_left"], "front_left": c["rear_left"],
                 "rear_right": c["front_right"], "front_right": c["rear_right"]}
    with pytest.raises(GeometryError, match=r"are left/right or rear/front swapped"):
        body_frame_from_wheels(backwards, _flat_ground())
    down = GroundPlane(np.array([0.0, 0.0, -1.0]), 0.0, np.ones(1, bool), 0.0, 0.02)
    with pytest.raises(GeometryError, match=r"ground normal pointing down"):
        body_frame_from_wheels(c, down)
    one_sided = {**c, "rear_left": c["rear_right"] + [0.0, 0.1, 0.0]}
    with pytest.raises(GeometryError, match=r"'rear_left' lies 0\.04\d m to the left .* at least 0\.1 m"):
        body_frame_from_wheels(one_sided, _flat_ground())


def test_bad_arguments():
    c = VEHICLE.wheel_centres_body()
    with pytest.raises(InputError, match=r"wheel centres: missing 'front_right'; present: front_left, rear_left, rear_right"):
        body_frame_from_wheels({k: v for k, v in c.items() if k != "front_right"}, _flat_ground())
    with pytest.raises(ConfigError, match=r"origin must be one of rear_axle, front_axle, wheelbase_centre, got 'centre'"):
        body_frame_from_wheels(c, _flat_ground(), origin="centre")
    with pytest.raises(InputError, match=r"wheel centres 'rear_left': expected a finite \(3,\) point"):
        body_frame_from_wheels({**c, "rear_left": [1.0, 2.0]}, _flat_ground())
    with pytest.raises(InputError, match=r"ground_plane\.normal must be a unit vector"):
        body_frame_from_wheels(c, _flat_ground()._replace(normal=np.array([0.0, 0.0, 2.0])))
    markers = {f"marker_{w}": v for w, v in c.items() if w != "rear_right"}
    with pytest.raises(InputError, match=r"markers: missing 'marker_rear_right'; present: front_left, front_right, rear_left"):
        body_frame_from_markers(markers)
    with pytest.raises(InputError, match=r"give the scan points or a ground plane"):
        body_frame_from_labels(LabelSet({w: v for w, v in c.items()}, "l.yaml"))


def test_scan_without_ground_stops_the_pipeline():
    no_ground = simulate_external_scan(VEHICLE, rng=2, ground=False)
    labels = simulate_rim_labels(VEHICLE, no_ground.T_external_body, 0)
    with pytest.raises(GeometryError, match=r"simulated rim labels: scan: no ground"):
        body_frame_from_labels(labels, no_ground.points_external)


def test_sensor_in_body_composes_through_the_external_frame(scan, ground):
    T_eb = scan.T_external_body
    truth = {s.name: np.asarray(s.T_rig_sensor) for s in VEHICLE.sensors}
    T_e = {n: T_eb @ T for n, T in truth.items()}  # what a joint calibration with the scanner gives
    bf = body_frame_from_labels(simulate_rim_labels(VEHICLE, T_eb, 3), ground_plane=ground)
    for n, T in truth.items():
        est = sensor_in_body(bf.T_external_body, T_e[n])
        assert np.linalg.norm(est[:3, 3] - T[:3, 3]) < 0.005
    T_ref = {n: invert(truth["lidar1"]) @ T for n, T in truth.items()}
    all_in_body = sensors_in_body(T_eb, T_e["lidar1"], T_ref)
    for n, T in truth.items():
        np.testing.assert_allclose(all_in_body[n], T, atol=1e-9)
    with pytest.raises(InputError, match=r"expected two \(4, 4\) transforms"):
        sensor_in_body(np.eye(3), np.eye(4))


def test_reference_points_by_kabsch():
    T = from_rt(matrix_from_rpy(np.radians([1.0, -2.0, 70.0])), [3.0, -1.0, 0.5])
    body = {w: c for w, c in VEHICLE.hub_centres_body().items()}
    ext = {w: T[:3, :3] @ c + T[:3, 3] for w, c in body.items()}
    np.testing.assert_allclose(body_frame_from_reference_points(ext, body), T, atol=1e-9)
    with pytest.raises(InputError, match=r"need at least 3 names known in both frames, got 2 \(rear_left, rear_right\)"):
        body_frame_from_reference_points(ext, {k: body[k] for k in WHEEL_NAMES[:2]})
