"""Synthetic rigs: noise-free consistency, fields of view, reproducibility, presets, outliers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.dataset import BoardGeometry, Dataset, SensorKind
from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, so3_log, transform_points
from rigcal.sensors.radar import elevation, project_2d
from rigcal.sim import (
    R_BODY_OPTICAL,
    SimSensor,
    board_area_center,
    make_board_placements,
    make_rig_placements,
    move_boards,
    prius_like_rig,
    random_rig,
    simulate,
    visible,
)
from rigcal.targets import reflector_in_board, reflectors_from_centres

BOARD = BoardGeometry()


def _noise_free(sensors):
    return tuple(s.noise_free() for s in sensors)


def _true_reflectors(T_rig_board: np.ndarray, T_rig_sensor: np.ndarray) -> np.ndarray:
    T = invert(T_rig_sensor) @ T_rig_board
    return T[:, :3, :3] @ reflector_in_board(BOARD) + T[:, :3, 3]


@pytest.fixture(scope="module")
def random_sim():
    rig = random_rig(11, n_lidar=2, n_camera=2, n_radar=1, n_radar3d=1)
    T = make_rig_placements(11, rig, 25)
    return simulate(_noise_free(rig), T, rng=11)


def test_noise_free_detections_coincide_in_rig_frame(random_sim) -> None:
    res = random_sim
    ds = res.dataset
    clouds = [s for s in ds.sensors if s.kind.is_point_cloud]
    assert len(clouds) == 4
    ref = clouds[0]
    ref_rig = np.stack(
        [transform_points(res.truth[ref.name], p) for p in ref.points]
    )  # NaN rows stay NaN
    for other in clouds[1:]:
        both = ref.detected & other.detected
        assert both.sum() >= 10
        other_rig = np.stack([transform_points(res.truth[other.name], p) for p in other.points])
        np.testing.assert_allclose(other_rig[both], ref_rig[both], atol=1e-9)
        # truth_T maps one sensor's detections onto the other's
        T_ref_other = res.truth_T(ref.name, other.name)
        mapped = np.stack([transform_points(T_ref_other, p) for p in other.points[both]])
        np.testing.assert_allclose(mapped, ref.points[both], atol=1e-9)


def test_noise_free_3d_radar_sees_the_reflector_of_the_centres(random_sim) -> None:
    res = random_sim
    lidar = res.dataset.sensor("lidar1")
    radar = res.dataset.sensor("radar3d1")
    both = lidar.detected & radar.detected
    assert both.sum() >= 10
    T = res.truth_T("radar3d1", "lidar1")
    centres_radar = np.stack([transform_points(T, p) for p in lidar.points[both]])
    np.testing.assert_allclose(
        reflectors_from_centres(centres_radar, BOARD), radar.points[both], atol=1e-9
    )


def test_noise_free_2d_radar_is_project_2d_of_true_reflector(random_sim) -> None:
    res = random_sim
    radar = res.dataset.sensor("radar1")
    truth = _true_reflectors(res.T_rig_board, res.truth["radar1"])
    d = radar.detected
    assert d.sum() >= 15
    np.testing.assert_allclose(radar.points[d], project_2d(truth[d]), atol=1e-9)
    assert radar.max_elevation_rad == pytest.approx(math.radians(9.0))


def test_truth_T_conventions(random_sim) -> None:
    res = random_sim
    np.testing.assert_allclose(res.truth_T("rig", "camera1"), res.truth["camera1"])
    np.testing.assert_allclose(res.truth_T("lidar1", "lidar1"), np.eye(4), atol=1e-12)
    T_a_c = res.truth_T("lidar1", "radar1")
    np.testing.assert_allclose(
        T_a_c, res.truth_T("lidar1", "camera1") @ res.truth_T("camera1", "radar1"), atol=1e-12
    )
    with pytest.raises(InputError, match="unknown sensor 'nope'"):
        res.truth_T("nope", "lidar1")


def test_2d_radar_elevation_fov_respected() -> None:
    radar = SimSensor("radar1", SensorKind.RADAR, from_rt(np.eye(3), [0.0, 0.0, 0.5]))
    lidar = SimSensor("lidar1", SensorKind.LIDAR, from_rt(np.eye(3), [0.0, 0.0, 0.5]))
    T = make_board_placements(3, 200, (0.0, 0.0, 0.5), elevation_spread_deg=20.0)
    res = simulate(_noise_free((radar, lidar)), T, rng=3)
    el = np.degrees(elevation(_true_reflectors(T, radar.T_rig_sensor)))
    det = res.dataset.sensor("radar1").detected
    assert np.all(np.abs(el[det]) <= 9.0)
    assert np.all(det[np.abs(el) < 8.9])  # nothing else limits these boards
    assert (~det).sum() > 50  # and many are out of the field of view


def test_camera_fov_and_facing() -> None:
    cam = SimSensor("cam", SensorKind.CAMERA, from_rt(R_BODY_OPTICAL, [0.0, 0.0, 1.0]))
    lidar = SimSensor("lidar", SensorKind.LIDAR, from_rt(np.eye(3), [0.0, 0.0, 1.0]))
    front = make_board_placements(0, 20, (0.0, 0.0, 1.0), azimuth_spread_deg=20.0)
    behind = make_board_placements(0, 20, (0.0, 0.0, 1.0), heading_deg=180.0)
    wide = make_board_placements(0, 50, (0.0, 0.0, 1.0), azimuth_spread_deg=80.0)
    assert visible(cam, front).all()
    assert not visible(cam, behind).any()
    assert visible(lidar, behind).all()  # 360 deg
    az = np.degrees(np.arctan2(wide[:, 1, 3], wide[:, 0, 3]))
    assert not visible(cam, wide)[np.abs(az) > 40].any()
    # a board turned away (its back to the sensor) is not detected
    turned = front.copy()
    turned[:, :3, :3] = turned[:, :3, :3] @ np.diag([-1.0, 1.0, -1.0])
    assert not visible(cam, turned).any()


def test_camera_detections_are_in_the_optical_frame() -> None:
    rig = prius_like_rig()
    T = make_rig_placements(5, rig, 10)
    cam = simulate(_noise_free(rig), T, rng=0).dataset.sensor("camera1")
    pts = cam.points[cam.detected]
    assert np.all(pts[..., 2] > 2.0)  # z forward
    tl, tr, bl, br = (pts[:, i] for i in range(4))
    assert np.all(tr[:, 0] > tl[:, 0])  # x right
    assert np.all(bl[:, 1] > tl[:, 1])  # y down


def test_seeded_reproducibility() -> None:
    rig = prius_like_rig()
    T1 = make_rig_placements(7, rig, 15)
    T2 = make_rig_placements(7, rig, 15)
    np.testing.assert_array_equal(T1, T2)
    a = simulate(rig, T1, rng=7).dataset
    b = simulate(rig, T1, rng=np.random.default_rng(7)).dataset
    c = simulate(rig, T1, rng=8).dataset
    for sa, sb, sc in zip(a.sensors, b.sensors, c.sensors):
        np.testing.assert_array_equal(sa.points, sb.points)
        assert not np.allclose(sa.points, sc.points, equal_nan=True)
    r1, r2 = random_rig(4, 2, 2, 2, 1), random_rig(4, 2, 2, 2, 1)
    for s1, s2 in zip(r1, r2):
        np.testing.assert_array_equal(s1.T_rig_sensor, s2.T_rig_sensor)


def test_noise_levels_match_the_model() -> None:
    lidar = SimSensor("lidar", SensorKind.LIDAR, np.eye(4), sigma_m=0.01)
    radar = SimSensor("radar", SensorKind.RADAR, from_rt(np.eye(3), [0.0, 0.0, 0.5]))
    cam = SimSensor("cam", SensorKind.CAMERA, from_rt(R_BODY_OPTICAL, [0.0, 0.0, 0.5]))
    T = make_board_placements(1, 600, (0.0, 0.0, 0.5), distance_m=(5.0, 5.0))
    sensors = (lidar, radar, cam)
    noisy = simulate(sensors, T, rng=1).dataset
    clean = simulate(_noise_free(sensors), T, rng=1).dataset
    d = noisy.sensor("lidar").points - clean.sensor("lidar").points
    assert np.nanstd(d) == pytest.approx(0.01, rel=0.1)
    rr = np.linalg.norm(noisy.sensor("radar").points, axis=1) - np.linalg.norm(
        clean.sensor("radar").points, axis=1
    )
    assert np.nanstd(rr) == pytest.approx(0.02, rel=0.1)
    # camera: error along the ray ~ 0.002 * 5**2 = 5 cm, across it 3 mm
    pc, pn = clean.sensor("cam").points, noisy.sensor("cam").points
    ok = clean.sensor("cam").detected & noisy.sensor("cam").detected
    u = pc[ok] / np.linalg.norm(pc[ok], axis=-1, keepdims=True)
    err = pn[ok] - pc[ok]
    along = np.sum(err * u, axis=-1)
    across = err - along[..., None] * u
    r = np.linalg.norm(pc[ok], axis=-1)
    assert np.std(along / (0.002 * r**2)) == pytest.approx(1.0, rel=0.1)
    assert np.sqrt(np.mean(np.sum(across**2, axis=-1)) / 2) == pytest.approx(0.003, rel=0.1)


def test_miss_probability_drops_boards() -> None:
    a = SimSensor("a", SensorKind.LIDAR, np.eye(4), miss_probability=0.5)
    b = SimSensor("b", SensorKind.LIDAR, np.eye(4))
    T = make_board_placements(2, 400, (0.0, 0.0, 0.0))
    ds = simulate((a, b), T, rng=2).dataset
    assert ds.sensor("b").detected.all()
    assert ds.sensor("a").detected.mean() == pytest.approx(0.5, abs=0.08)


def _rotation_angle_deg(T: np.ndarray) -> float:
    return math.degrees(np.linalg.norm(so3_log(T[:3, :3])))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def test_random_rig_orientations_are_arbitrary() -> None:
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    lidar_yaws, lidar_flips, camera_rolls, radar3d_rolls = [], [], [], []
    for seed in range(12):
        rig = random_rig(seed, n_lidar=1, n_camera=1, n_radar=1, n_radar3d=1)
        by = {s.kind: s.T_rig_sensor[:3, :3] for s in rig}
        assert max(_rotation_angle_deg(s.T_rig_sensor) for s in rig) > 60.0
        R = by[SensorKind.LIDAR]
        lidar_yaws.append(math.degrees(math.atan2(R[1, 0], R[0, 0])))
        lidar_flips.append(R[2, 2] < 0)  # mounted upside down
        # camera roll about its optical axis: its y axis (image down) against the rig's down
        camera_rolls.append(_angle_deg(by[SensorKind.CAMERA][:, 1], down))
        radar3d_rolls.append(_angle_deg(by[SensorKind.RADAR3D][:, 2], up))
        for s in rig:
            assert np.linalg.norm(s.position_rig) <= 2.1
            if s.kind is SensorKind.RADAR:
                # 2D radars stay nearly level: their z axis within a few degrees of up
                assert _angle_deg(s.T_rig_sensor[:3, 2], up) < 4.0
            if s.kind is SensorKind.CAMERA:
                # the optical axis still looks forward
                assert s.T_rig_sensor[0, 2] > math.cos(math.radians(35.0))
    assert max(np.abs(lidar_yaws)) > 90.0
    assert any(lidar_flips) and not all(lidar_flips)
    assert max(camera_rolls) > 60.0
    assert max(radar3d_rolls) > 60.0


@pytest.mark.parametrize(
    "make_rig",
    [
        prius_like_rig,
        lambda: random_rig(0, 1, 1, 1, 0),
        lambda: random_rig(1, 2, 1, 1, 1),
        lambda: random_rig(2, 1, 2, 2, 1),
        lambda: random_rig(3, 1, 1, 0, 2),
    ],
)
def test_presets_every_sensor_sees_most_boards(make_rig) -> None:
    rig = make_rig()
    T = make_rig_placements(42, rig, 30)
    ds = simulate(rig, T, rng=42).dataset
    for s in ds.sensors:
        assert s.detected.mean() >= 0.6, s.name


def test_prius_like_rig_layout() -> None:
    rig = {s.name: s for s in prius_like_rig()}
    assert rig["lidar1"].position_rig[2] == pytest.approx(1.9)
    assert rig["camera1"].position_rig[2] == pytest.approx(1.3)
    assert rig["radar1"].position_rig[2] == pytest.approx(0.5)
    # the camera's optical axis (z) looks along the rig's x axis, its y axis down
    R = rig["camera1"].T_rig_sensor[:3, :3]
    assert R[:, 2] @ [1.0, 0.0, 0.0] > 0.99
    assert R[:, 1] @ [0.0, 0.0, -1.0] > 0.99
    center = board_area_center(tuple(rig.values()))
    assert center[2] == pytest.approx(0.5)


def test_board_placements_face_the_center() -> None:
    c = np.array([1.0, 0.5, 0.6])
    T = make_board_placements(9, 100, c, tilt_deg=0.0, yaw_deg=0.0, azimuth_spread_deg=30.0)
    reflector = T[:, :3, :3] @ reflector_in_board(BOARD) + T[:, :3, 3]
    d = np.linalg.norm(reflector - c, axis=1)
    assert np.all((d >= 3.0 - 1e-9) & (d <= 7.0 + 1e-9))
    to_center = (c - T[:, :3, 3]) / np.linalg.norm(c - T[:, :3, 3], axis=1, keepdims=True)
    assert np.all(np.einsum("ki,ki->k", T[:, :3, 2], to_center) > 0.99)
    np.testing.assert_allclose(T[:, :3, 1], np.broadcast_to([0.0, 0.0, 1.0], (100, 3)), atol=1e-12)
    tilted = make_board_placements(9, 100, c)
    assert np.all(np.einsum("ki,ki->k", tilted[:, :3, 2], to_center) > math.cos(math.radians(40)))


def test_move_boards_changes_only_chosen_boards(random_sim) -> None:
    ds = random_sim.dataset
    moved = move_boards(ds, "camera1", [1, 4], [0.5, -0.2, 0.1])
    assert isinstance(moved, Dataset)
    before, after = ds.sensor("camera1").points, moved.sensor("camera1").points
    changed = np.any(np.abs(np.nan_to_num(after - before)) > 0, axis=(1, 2))
    det = ds.sensor("camera1").detected
    assert set(np.flatnonzero(changed)) == {b for b in (1, 4) if det[b]}
    shift = np.broadcast_to([0.5, -0.2, 0.1], (2, 4, 3))
    np.testing.assert_allclose(after[[1, 4]] - before[[1, 4]], shift)
    for name in ds.names:
        if name != "camera1":
            assert moved.sensor(name) is ds.sensor(name)
    radar = move_boards(ds, "radar1", [0], [0.3, 0.0])
    np.testing.assert_allclose(
        radar.sensor("radar1").points[0] - ds.sensor("radar1").points[0], [0.3, 0.0]
    )
    np.testing.assert_array_equal(radar.sensor("radar1").points[1:], ds.sensor("radar1").points[1:])
    # the original is untouched
    np.testing.assert_array_equal(ds.sensor("camera1").points, before)


def test_move_boards_validates() -> None:
    ds = simulate(prius_like_rig(), make_rig_placements(0, prius_like_rig(), 5), rng=0).dataset
    with pytest.raises(InputError, match=r"'radar1' \(radar\) needs a finite \(2,\) offset_m"):
        move_boards(ds, "radar1", [0], [0.1, 0.2, 0.3])
    with pytest.raises(InputError, match=r"boards 0..4, got \[7\]"):
        move_boards(ds, "lidar1", [7], [0.1, 0.2, 0.3])
    with pytest.raises(InputError, match="unknown sensor 'x'"):
        move_boards(ds, "x", [0], [0.1, 0.2, 0.3])


def test_sim_sensor_defaults_and_validation() -> None:
    r = SimSensor("r", "radar", np.eye(4))
    assert r.kind is SensorKind.RADAR
    assert (r.range_sigma_m, r.azimuth_sigma_deg, r.max_elevation_deg) == (0.02, 0.3, 9.0)
    assert r.min_elevation_deg == -9.0 and r.sigma_m == 0.0
    c = SimSensor("c", SensorKind.CAMERA, np.eye(4))
    assert (c.sigma_m, c.depth_sigma_at_1m_m, c.max_azimuth_deg, c.max_elevation_deg) == (
        0.003, 0.002, 35.0, 25.0,
    )
    r3 = SimSensor("r3", SensorKind.RADAR3D, np.eye(4))
    assert r3.elevation_sigma_deg == 0.5
    with pytest.raises(InputError, match="'bad'.T_rig_sensor: not rigid: the 3x3 block must be a"):
        SimSensor("bad", SensorKind.LIDAR, np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InputError, match=r"'s'.sigma_m must be >= 0"):
        SimSensor("s", SensorKind.LIDAR, np.eye(4), sigma_m=-1.0)
    with pytest.raises(InputError, match=r"miss_probability must be in \[0, 1\]"):
        SimSensor("s", SensorKind.LIDAR, np.eye(4), miss_probability=1.5)
    with pytest.raises(InputError, match="unknown sensor kind 'sonar'"):
        SimSensor("s", "sonar", np.eye(4))
    with pytest.raises(InputError, match="duplicate simulated sensor names"):
        simulate((r, r), make_board_placements(0, 2))
    with pytest.raises(InputError, match=r"T_rig_board must have shape \(K, 4, 4\)"):
        simulate((r, c), np.eye(4))
    with pytest.raises(InputError, match="rng must be a numpy.random.Generator or an int seed"):
        make_board_placements(None, 3)  # type: ignore[arg-type]


def test_impossible_placement_raises() -> None:
    # a camera looking backwards and a 2D radar looking forwards share no boards
    back = from_rt(np.diag([-1.0, -1.0, 1.0]) @ R_BODY_OPTICAL, [0.0, 0.0, 0.5])
    rig = (
        SimSensor("cam", SensorKind.CAMERA, back),
        SimSensor("radar", SensorKind.RADAR, from_rt(np.eye(3), [0.0, 0.0, 0.5])),
    )
    with pytest.raises(InputError, match="could not place 5 boards"):
        make_rig_placements(0, rig, 5, max_candidates=200)


def test_simulate_does_not_mutate_inputs() -> None:
    rig = prius_like_rig()
    T = make_rig_placements(1, rig, 6)
    before = T.copy()
    simulate(rig, T, rng=1)
    np.testing.assert_array_equal(T, before)
