"""Absolute calibration end to end on a simulated vehicle with truth.

The setup: :class:`SimVehicle` with the Prius-like rig (lidar1 1 cm noise per centre, camera1
3 mm lateral + range-squared depth noise, radar1 2D), 20 board placements in front of the car
seen by the rig, and an external scanner (a P40-like lidar: 2 mm noise per centre, 360 deg view)
at the first station of :class:`ExternalScanner` (4.5 m right of the car, 1.5 m high), which
sees the boards too and scans the car; 10 rim clicks per wheel with 2 mm noise.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.absolute.labels import WHEEL_NAMES, LabelSet
from rigcal.absolute.pipeline import (
    METHODS,
    absolute_calibration,
    adjoint,
    compose_body,
)
from rigcal.absolute.result import AbsoluteResult, tangent_std
from rigcal.dataset import SensorKind
from rigcal.errors import ConfigError, InputError
from rigcal.geometry.se3 import invert, se3_exp, se3_log
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.problem.calibrate import CalibrationOptions
from rigcal.sim.rig import SimSensor, make_rig_placements, simulate
from rigcal.sim.vehicle import (
    ExternalScanner,
    SimVehicle,
    simulate_external_scan,
    simulate_hub_labels,
    simulate_markers,
    simulate_rim_labels,
)

VEHICLE = SimVehicle()
SCANNER = ExternalScanner()
EXT = "leica"
STD_KEYS = ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg")


def external_sensor(sigma_m: float = 0.002) -> SimSensor:
    """The external scanner as a detection-level lidar at its true pose T_body_external."""
    return SimSensor(
        EXT, SensorKind.LIDAR, SCANNER.T_body_stations[0], sigma_m=sigma_m,
        max_azimuth_deg=180.0, max_elevation_deg=60.0, min_elevation_deg=-60.0, max_range_m=30.0,
    )


def simulated(seed: int, num_boards: int = 20, noise_free_rig: bool = False):
    rig = VEHICLE.sensors
    if noise_free_rig:
        rig = tuple(s.noise_free() for s in rig)
    boards = make_rig_placements(seed, VEHICLE.sensors, num_boards)
    return simulate(rig + (external_sensor(),), boards, rng=seed)


@pytest.fixture(scope="module")
def scan():
    return simulate_external_scan(VEHICLE, SCANNER, rng=1)


@pytest.fixture(scope="module")
def sim0():
    return simulated(0)


@pytest.fixture(scope="module")
def labels0(scan):
    return simulate_rim_labels(VEHICLE, scan.T_external_body, 0, n_points=10, sigma_m=0.002)


@pytest.fixture(scope="module")
def result0(sim0, labels0, scan):
    return absolute_calibration(sim0.dataset, EXT, labels0, scan.points_external)


def errors(result: AbsoluteResult, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(dx, dy, dz) [mm] and (droll, dpitch, dyaw) [deg] of T_body_sensor, estimate - truth."""
    T = result.sensors[name].T_body_sensor
    T_true = VEHICLE.T_body_sensor(name)
    dxyz = 1000 * (T[:3, 3] - T_true[:3, 3])
    drpy = np.degrees(rpy_from_matrix(T[:3, :3]) - rpy_from_matrix(T_true[:3, :3]))
    return dxyz, drpy


def zscores(result: AbsoluteResult, name: str) -> np.ndarray:
    dxyz, drpy = errors(result, name)
    std = np.array([result.sensors[name].std[k] for k in STD_KEYS])
    std[:3] *= 1000
    return np.concatenate([dxyz, drpy]) / std


# ----------------------------------------------------------------------------- accuracy


def test_body_frame_and_outputs(result0, scan):
    """The body frame matches the truth; every rig sensor (not the scanner) is in the result."""
    assert isinstance(result0, AbsoluteResult)
    assert set(result0.sensors) == {"lidar1", "camera1", "radar1"}
    assert result0.body_frame == "base_link" and result0.origin == "rear_axle"
    assert result0.external == EXT and result0.method == "circle"
    E = invert(scan.T_external_body) @ result0.T_external_body
    assert 1000 * np.linalg.norm(E[:3, 3]) <= 3.0
    assert np.degrees(np.linalg.norm(se3_log(E)[:3])) <= 0.05
    assert result0.body.wheelbase_m == pytest.approx(VEHICLE.wheelbase_m, abs=0.003)
    assert result0.body.ground.rms_m <= 0.003
    assert result0.relative.reference == EXT


def test_lidar_and_camera_in_body_frame(result0):
    """Must-show, FCPE (the default). Bounds from the noise: lidar1's 1 cm per centre over 20
    boards x 4 centres limits its link to the scanner to about 2 / 5 / 8 mm (x / y / z) and
    0.06 / 0.08 / 0.035 deg (roll / pitch / yaw) 1-sigma - boards at 3-7 m spread +-25 deg in
    azimuth but only +-4 deg in elevation, so pitch and z are the weak pair; the camera's is
    similar. The body frame from rim circles adds 0.013 deg of yaw and < 1 mm. Measured here
    (seed 0): lidar1 (0.9, -1.9, -2.2) mm, (-0.03, -0.01, 0.05) deg; camera1 (2.5, 8.1, -0.8)
    mm, (-0.00, -0.05, -0.06) deg; over 20 seeds the RMS is lidar1 1.8 / 4.6 / 8.2 mm,
    0.06 / 0.08 / 0.035 deg, camera1 4.2 / 9.5 / 5.7 mm, 0.06 / 0.04 / 0.09 deg."""
    for name in ("lidar1", "camera1"):
        dxyz, drpy = errors(result0, name)
        assert np.all(np.abs(dxyz) <= 15.0), (name, dxyz)
        assert np.all(np.abs(drpy) <= 0.15), (name, drpy)
        # and within 4 sigma of the reported uncertainty
        assert np.all(np.abs(zscores(result0, name)) <= 4.0), (name, zscores(result0, name))


def test_pse_over_seeds_matches_reported_uncertainty(scan):
    """PSE weighs every sensor by its estimated noise, so its covariance is honest: over 5
    seeds the errors' RMS in units of the reported std is about 1 (measured 0.8-1.4 over
    20 seeds) and the RMS errors are lidar1 about 2 / 5 / 8 mm, 0.06 / 0.08 / 0.035 deg,
    camera1 4 / 3 / 3 mm, 0.03 / 0.03 / 0.035 deg."""
    z = {"lidar1": [], "camera1": []}
    err = {"lidar1": [], "camera1": []}
    for seed in range(1, 6):
        sim = simulated(seed)
        labels = simulate_rim_labels(VEHICLE, scan.T_external_body, seed)
        res = absolute_calibration(sim.dataset, EXT, labels, scan.points_external, mode="pse")
        for name in z:
            z[name].append(zscores(res, name))
            dxyz, drpy = errors(res, name)
            err[name].append(np.concatenate([dxyz, drpy]))
    for name in z:
        zz = np.array(z[name])
        e = np.array(err[name])
        assert np.sqrt(np.mean(zz**2)) <= 1.6, (name, zz)
        assert np.abs(zz).max() <= 4.0, (name, zz)
        rms = np.sqrt(np.mean(e**2, axis=0))
        assert np.all(rms[:3] <= 12.0), (name, rms)  # mm
        assert np.all(rms[3:] <= 0.12), (name, rms)  # deg


def test_noise_free_rig_isolates_the_chain(scan):
    """With noise-free rig sensors only the scanner's 2 mm per centre and the labels remain:
    every sensor (the radar too) within 4 mm and 0.05 deg (measured over 10 seeds: RMS
    0.5 / 1.0 / 1.5 mm, 0.01 / 0.013 / 0.015 deg; max 2.8 mm, 0.03 deg)."""
    for seed in range(2):
        sim = simulated(seed, noise_free_rig=True)
        labels = simulate_rim_labels(VEHICLE, scan.T_external_body, seed)
        res = absolute_calibration(sim.dataset, EXT, labels, scan.points_external, mode="pse")
        for name in ("lidar1", "camera1", "radar1"):
            dxyz, drpy = errors(res, name)
            assert np.all(np.abs(dxyz) <= 4.0), (seed, name, dxyz)
            assert np.all(np.abs(drpy) <= 0.05), (seed, name, drpy)


def test_radar_in_plane_small_out_of_plane_weak(result0):
    """A 2D radar measures range and azimuth: x, y and yaw come out well (measured 1.5 / 8.5 mm,
    0.12 deg; over 20 seeds RMS 4.7 / 7.6 mm, 0.2 deg), z, roll and pitch only through the
    +-9 deg elevation field of view (here 77 mm, -0.9 / 2.1 deg) - and the result says so."""
    dxyz, drpy = errors(result0, "radar1")
    std = result0.sensors["radar1"].std
    assert np.all(np.abs(dxyz[:2]) <= 20.0), dxyz
    assert abs(drpy[2]) <= 0.5, drpy
    assert abs(drpy[2]) <= 4 * std["yaw_deg"]
    assert std["z_m"] > 5 * max(std["x_m"], std["y_m"])  # the weak direction is reported
    assert any("radar1 (2D radar)" in w for w in result0.warnings)


def test_covariance_is_relative_plus_body(result0):
    """The relative part of each covariance is the calibration's own (a right perturbation is
    unchanged by the left factor T_body_external); the body frame adds its share."""
    for name, est in result0.sensors.items():
        rel = result0.relative.sensors[name].covariance
        assert np.allclose(est.relative_covariance, rel)
        assert np.allclose(est.covariance, rel + est.body_covariance)
        assert np.all(np.linalg.eigvalsh(est.body_covariance) >= -1e-15)
    # the body frame from 10 rim clicks of 2 mm: yaw about 0.013 deg, origin < 1 mm
    # (tests/absolute/test_body_frame.py measures 0.012 deg RMS, 0.8 mm RMS over 20 labellings)
    std = result0.body_std
    assert 0.007 <= std["yaw_deg"] <= 0.02
    assert std["x_m"] <= 0.0015 and std["y_m"] <= 0.0015
    assert std["roll_deg"] <= 0.005 and std["pitch_deg"] <= 0.005
    assert result0.body_uncertainty == "fit residuals"


def test_compose_body_propagates_a_body_perturbation():
    """``T_external_body @ exp(e)`` moves ``T_body_sensor`` by ``exp(-Ad(T_sensor_body) e)`` on
    the right: check against finite perturbations."""
    rng = np.random.default_rng(0)
    T_eb = se3_exp(rng.normal(size=6))
    T_es = se3_exp(rng.normal(size=6))
    T_bs, cov, share = compose_body(T_eb, T_es, np.zeros((6, 6)), np.eye(6))
    A = adjoint(invert(T_bs))
    assert np.allclose(share, A @ A.T)
    for _ in range(3):
        e = 1e-6 * rng.normal(size=6)
        moved = invert(T_eb @ se3_exp(e)) @ T_es
        assert np.allclose(se3_log(invert(T_bs) @ moved), -A @ e, atol=1e-11)
    assert np.allclose(adjoint(T_bs) @ adjoint(invert(T_bs)), np.eye(6))
    assert tangent_std(np.diag([1e-6, 0, 0, 4e-6, 0, 0]))["x_m"] == pytest.approx(2e-3)


# ----------------------------------------------------------------------------- other methods


def test_hub_clicks_and_markers(sim0, scan):
    """Hub clicks (1 cm) and markers (1 cm placement) give a rougher yaw (0.2-0.3 deg); without
    ``label_sigma_m`` their frame is taken as exact and a warning says so; with it the body
    covariance follows 1 cm / sqrt(n)."""
    hub = simulate_hub_labels(VEHICLE, scan.T_external_body, 3)
    res = absolute_calibration(sim0.dataset, EXT, hub, scan.points_external, method="single")
    assert res.body_uncertainty == "none"
    assert np.allclose(res.body_covariance, 0.0)
    assert any("hub clicks carry no residuals" in w for w in res.warnings)
    res = absolute_calibration(
        sim0.dataset, EXT, hub, scan.points_external, method="single", label_sigma_m=0.01
    )
    assert res.body_uncertainty == "label sigma"
    assert 0.1 <= res.body_std["yaw_deg"] <= 0.5  # 1 cm * 2 / 2.7 m ~ 0.2-0.3 deg
    markers = simulate_markers(VEHICLE, scan.T_external_body, 3)
    res = absolute_calibration(
        sim0.dataset, EXT, markers, scan.points_external, method="markers",
        origin="wheelbase_centre", label_sigma_m=0.01, body_frame="vehicle",
    )
    assert res.body_frame == "vehicle" and res.origin == "wheelbase_centre"
    dxyz, _ = errors(res, "lidar1")
    # origin moved by half the wheelbase: lidar1's x is 1.35 m smaller
    assert dxyz[0] == pytest.approx(-1000 * VEHICLE.wheelbase_m / 2, abs=30.0)
    d = res.to_dict()
    assert d["body_frame"]["origin"] == "wheelbase_centre"
    assert "midpoint" in d["body_frame"]["definition"]


def test_to_dict_is_plain_data(result0):
    import json

    d = result0.to_dict()
    json.dumps(d)  # plain data
    assert d["body_frame"]["name"] == "base_link"
    assert d["body_frame"]["external_sensor"] == EXT
    assert set(d["sensors"]) == {"lidar1", "camera1", "radar1"}
    s = d["sensors"]["lidar1"]
    assert np.allclose(s["T_body_sensor"], result0.sensors["lidar1"].T_body_sensor)
    assert np.allclose(s["xyz_m"], result0.sensors["lidar1"].xyz_m)
    assert np.allclose(s["rpy_deg"], result0.sensors["lidar1"].rpy_deg)
    assert set(s["std"]) == set(STD_KEYS)
    for key in ("wheelbase_m", "track_rear_m", "track_front_m", "ground_rms_m"):
        assert isinstance(d["body_frame"][key], float)
    assert d["relative"]["reference"] == EXT


# ----------------------------------------------------------------------------- bad input


def _blank(dataset, sensor: str, boards):
    """A copy where ``sensor`` did not detect ``boards``."""
    det = dataset.sensor(sensor)
    pts = np.array(det.points)
    pts[list(boards)] = np.nan
    new = replace(det, points=pts)
    return replace(dataset, sensors=tuple(new if s.name == sensor else s for s in dataset.sensors))


def test_external_not_in_dataset(sim0, labels0, scan):
    with pytest.raises(InputError, match=r"external scanner 'p40' is not a sensor of the dataset "
                       r"\(sensors: lidar1, camera1, radar1, leica\)"):
        absolute_calibration(sim0.dataset, "p40", labels0, scan.points_external)


def test_external_must_measure_in_3d(sim0, labels0, scan):
    with pytest.raises(ConfigError, match="'radar1' is a 2D radar"):
        absolute_calibration(sim0.dataset, "radar1", labels0, scan.points_external)


def test_boards_seen_only_by_the_scanner_are_refused(sim0, labels0, scan):
    ds = sim0.dataset
    for name in ("lidar1", "camera1", "radar1"):
        ds = _blank(ds, name, [3, 7])
    with pytest.raises(InputError, match=r"board\(s\) \[3, 7\] are seen by the external scanner "
                       r"'leica' but by no rig sensor .* tie nothing to the rig"):
        absolute_calibration(ds, EXT, labels0, scan.points_external)
    # marking them ignored for the scanner is the way out
    ok = ds.with_excluded({EXT: [3, 7]})
    res = absolute_calibration(ok, EXT, labels0, scan.points_external)
    assert set(res.sensors) == {"lidar1", "camera1", "radar1"}


def test_scanner_sharing_no_boards(sim0, labels0, scan):
    ds = sim0.dataset
    K = ds.num_boards
    for name in ("lidar1", "camera1", "radar1"):
        ds = _blank(ds, name, [0])
    ds = _blank(ds, EXT, range(1, K))
    ds = ds.with_excluded({EXT: [0]})
    with pytest.raises(InputError, match="external scanner 'leica' shares no boards with the rig"):
        absolute_calibration(ds, EXT, labels0, scan.points_external)


def test_rig_sensor_sharing_no_boards(sim0, labels0, scan):
    ds = sim0.dataset
    K = ds.num_boards
    ds = _blank(ds, "radar1", range(1, K))  # the radar sees board 0 only ...
    for name in ("lidar1", "camera1", EXT):
        ds = _blank(ds, name, [0])  # ... which nobody else sees
    with pytest.raises(InputError, match=r"rig sensor 'radar1' shares no boards with the external "
                       r"scanner 'leica' or any other rig sensor .*\[0\]"):
        absolute_calibration(ds, EXT, labels0, scan.points_external)


def test_rig_sensor_too_weakly_tied(sim0, labels0, scan):
    """The radar shares 2 boards (a 2D radar pair needs 3): the core's message, with context."""
    ds = _blank(sim0.dataset, "radar1", range(2, sim0.dataset.num_boards))
    with pytest.raises(InputError, match=r"absolute calibration with external scanner 'leica' as "
                       r"the reference: cannot relate sensor\(s\) \['radar1'\]"):
        absolute_calibration(ds, EXT, labels0, scan.points_external)


def test_labels_missing_a_wheel(sim0, scan):
    labels = simulate_rim_labels(VEHICLE, scan.T_external_body, 0, wheels=WHEEL_NAMES[:3])
    with pytest.raises(InputError, match=r"absolute calibration: body frame \(circle labels, "
                       r"external scan of 'leica'\): simulated rim labels: missing wheel "
                       r"'front_right'; present: front_left, rear_left, rear_right"):
        absolute_calibration(sim0.dataset, EXT, labels, scan.points_external)


def test_fewer_than_three_rim_points(sim0, scan):
    labels = simulate_rim_labels(VEHICLE, scan.T_external_body, 0, n_points=2)
    with pytest.raises(InputError, match="simulated rim labels: wheel 'rear_left': a rim circle "
                       "needs at least 3 labelled rim points, got 2"):
        absolute_calibration(sim0.dataset, EXT, labels, scan.points_external)


def test_scan_with_no_ground(sim0, labels0):
    no_floor = simulate_external_scan(VEHICLE, SCANNER, rng=1, ground=False)
    with pytest.raises(InputError, match=r"absolute calibration: body frame .*external scan: "
                       r"no ground"):
        absolute_calibration(sim0.dataset, EXT, labels0, no_floor.points_external)


def test_markers_missing(sim0, labels0, scan):
    with pytest.raises(InputError, match="missing 'marker_rear_left'"):
        absolute_calibration(sim0.dataset, EXT, labels0, scan.points_external, method="markers")


def test_bad_options(sim0, labels0, scan):
    ds, pts = sim0.dataset, scan.points_external
    with pytest.raises(ConfigError, match="method must be one of circle, single, markers"):
        absolute_calibration(ds, EXT, labels0, pts, method="auto")
    assert METHODS == ("circle", "single", "markers")
    with pytest.raises(ConfigError, match="origin must be one of rear_axle"):
        absolute_calibration(ds, EXT, labels0, pts, origin="front_bumper")
    with pytest.raises(ConfigError, match="body_frame must be a non-empty name"):
        absolute_calibration(ds, EXT, labels0, pts, body_frame="base link")
    with pytest.raises(ConfigError, match="label_sigma_m must be a positive number"):
        absolute_calibration(ds, EXT, labels0, pts, label_sigma_m=0.0)
    with pytest.raises(ConfigError, match="options.reference is 'lidar1'"):
        absolute_calibration(ds, EXT, labels0, pts, options=CalibrationOptions(reference="lidar1"))
    with pytest.raises(ConfigError, match="unknown mode 'xyz'"):
        absolute_calibration(ds, EXT, labels0, pts, mode="xyz")
    with pytest.raises(InputError, match="give the external scan's points"):
        absolute_calibration(ds, EXT, labels0, None)
    with pytest.raises(InputError, match="labels must be a LabelSet"):
        absolute_calibration(ds, EXT, {"rear_left": [0, 0, 0]}, pts)  # type: ignore[arg-type]


def test_ground_plane_given_instead_of_scan(result0, sim0, labels0):
    res = absolute_calibration(sim0.dataset, EXT, labels0, None, ground_plane=result0.body.ground)
    assert np.allclose(res.T_external_body, result0.T_external_body, atol=1e-9)
    assert isinstance(labels0, LabelSet)
