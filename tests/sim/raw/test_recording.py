from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import invert
from rigcal.recording import PointCloudFrame, RadarFrame, StereoFrame
from rigcal.sim.raw import (
    BoardTimeline,
    PinholeRadtanCamera,
    RawSensor,
    Scene,
    StereoCamera,
    frame_times_ns,
    hdl64e,
    iter_recording,
    make_timeline,
    prius_like_raw_rig,
    raw_rig_placements,
    scene_for_placements,
    simulate_recording,
    small_raw_rig,
)
from rigcal.sim.rig import prius_like_rig, visible

TINY_STEREO = StereoCamera(PinholeRadtanCamera(160, 120, 150.0, 150.0, 79.5, 59.5), 0.12)


def tiny_rig() -> tuple[RawSensor, ...]:
    """The small preset with a 160 x 120 stereo pair: a recording in well under a second."""
    lidar, cam, radar = small_raw_rig()
    return (lidar, replace(cam, model=TINY_STEREO), radar)


@pytest.fixture(scope="module")
def placements():
    return raw_rig_placements(3, small_raw_rig(), 3)


@pytest.fixture(scope="module")
def recording(placements):
    return simulate_recording(tiny_rig(), placements, 5, dwell_s=1.0, transition_s=0.6)


def test_presets_match_the_detection_level_rig():
    truth = {s.name: s.T_rig_sensor for s in prius_like_rig()}
    rig = prius_like_raw_rig()
    assert [s.name for s in rig] == ["lidar1", "camera1", "radar1"]
    assert [s.kind for s in rig] == ["lidar", "stereo", "radar"]
    for s in rig:
        assert np.allclose(s.T_rig_sensor, truth[s.name])
    assert rig[0].model == hdl64e()
    cam = rig[1].model
    assert (cam.camera.width, cam.camera.height) == (1936, 1216)
    assert (cam.camera.fx, cam.baseline_m) == (1400.0, 0.12)
    assert [s.rate_hz for s in rig] == [10.0, 10.0, 13.0]
    small = small_raw_rig()
    assert small[0].model.num_rings == 16 and small[1].model.camera.width == 640
    assert np.allclose(small[1].T_rig_sensor, truth["camera1"])


def test_to_sim_sensor_fields_of_view():
    lidar, cam, radar = prius_like_raw_rig()
    sl, sc, sr = lidar.to_sim_sensor(), cam.to_sim_sensor(), radar.to_sim_sensor()
    assert sl.kind is SensorKind.LIDAR and sl.min_elevation_deg == pytest.approx(-24.9)
    assert sc.kind is SensorKind.CAMERA
    assert sc.max_azimuth_deg == pytest.approx(np.degrees(np.arctan(968.0 / 1400.0)))
    assert sr.kind is SensorKind.RADAR and sr.max_elevation_deg == 9.0
    assert np.allclose(sr.T_rig_sensor, radar.T_rig_sensor)


def test_raw_placements_are_seen_and_above_ground(placements):
    rig = small_raw_rig()
    assert placements.shape == (3, 4, 4)
    for T in placements:
        assert Scene(T).plate_corners_world()[:, 2].min() >= 0.02 - 1e-9
        for s in rig:
            assert visible(s.to_sim_sensor(), T[None])[0]
    again = raw_rig_placements(3, small_raw_rig(), 3)
    assert np.array_equal(placements, again)


def test_frame_times():
    lidar, cam, radar = small_raw_rig()
    t = frame_times_ns(radar, 0, 1_000_000_000)
    assert t[0] == 20_000_000 and len(t) == 13
    assert np.allclose(np.diff(t), 1e9 / 13, atol=1)
    assert len(frame_times_ns(lidar, 0, 1_000_000_000)) == 11  # 0, 0.1, ..., 1.0 s


def test_timeline_windows_and_poses(placements):
    tl = make_timeline(placements, 0, dwell_s=3.0, transition_s=1.5, jitter_m=0.002, jitter_deg=0.1)
    assert isinstance(tl, BoardTimeline)
    assert tl.windows_ns.tolist() == [[0, 3_000_000_000], [4_500_000_000, 7_500_000_000],
                                      [9_000_000_000, 12_000_000_000]]
    assert tl.placement_at(1_000_000_000) == 0 and tl.placement_at(4_000_000_000) == -1
    assert tl.placement_at(12_000_000_000) == 2 and tl.placement_at(13_000_000_000) == -1
    # window edges: exactly the placement (the sway starts and ends at zero)
    for k, (a, b) in enumerate(tl.windows_ns):
        assert np.allclose(tl.pose_at(a), placements[k], atol=1e-12)
        assert np.allclose(tl.pose_at(b), placements[k], atol=1e-12)
        ts = np.linspace(a, b, 31).astype(np.int64)
        dev = np.array([np.linalg.norm(tl.pose_at(t)[:3, 3] - placements[k][:3, 3]) for t in ts])
        assert dev.max() < 0.005 and dev.max() > 1e-5  # small, but the board is not frozen
    # halfway through a transition the board is between the two placements
    mid = tl.pose_at((3_000_000_000 + 4_500_000_000) // 2)
    assert np.allclose(mid[:3, 3], placements[:2, :3, 3].mean(axis=0), atol=1e-9)


def test_recording_timing(recording, placements):
    frames = recording.frames
    t = np.array([f.t_ns for f in frames])
    assert np.all(np.diff(t) >= 0)
    assert t[0] >= 0 and t[-1] <= recording.timeline.end_ns
    assert recording.windows_ns.tolist() == [[0, 1_000_000_000], [1_600_000_000, 2_600_000_000],
                                             [3_200_000_000, 4_200_000_000]]
    by = {s.name: recording.frames_of(s.name) for s in recording.sensors}
    assert len(by["lidar1"]) == 43 and len(by["camera1"]) == 42 and len(by["radar1"]) == 55
    assert all(isinstance(f, PointCloudFrame) for f in by["lidar1"])
    assert all(isinstance(f, StereoFrame) for f in by["camera1"])
    assert all(isinstance(f, RadarFrame) for f in by["radar1"])
    for name, fs in by.items():
        dt = np.diff([f.t_ns for f in fs])
        rate = next(s.rate_hz for s in recording.sensors if s.name == name)
        assert np.allclose(dt, 1e9 / rate, atol=1)
    # placements of frames follow the dwell windows
    for f, k, T in zip(frames, recording.frame_placement, recording.frame_T_rig_board):
        assert k == recording.timeline.placement_at(f.t_ns)
        assert np.allclose(T, recording.timeline.pose_at(f.t_ns))
        if k >= 0:
            assert np.linalg.norm(T[:3, 3] - placements[k][:3, 3]) < 0.005
    assert len(recording.dwell_frames(1, "radar1")) == 13
    moving = recording.frame_placement == -1
    assert moving.sum() > 0  # transition frames exist
    assert np.allclose(recording.truth_T("rig", "radar1"), recording.sensors[2].T_rig_sensor)
    assert np.allclose(
        recording.truth_T("camera1", "lidar1"),
        invert(recording.sensors[1].T_rig_sensor) @ recording.sensors[0].T_rig_sensor,
    )


def test_recorded_frames_see_the_board(recording):
    # radar: the reflector is detected while the board dwells, at the true range
    radar = recording.sensors[2]
    for f, k, T in zip(recording.frames, recording.frame_placement, recording.frame_T_rig_board):
        if f.sensor != "radar1" or k < 0:
            continue
        refl = T[:3, :3] @ np.array([0.0, 0.0, -0.105]) + T[:3, 3]
        p = invert(radar.T_rig_sensor)[:3, :3] @ refl + invert(radar.T_rig_sensor)[:3, 3]
        strong = f.rcs_dbsm > 8.0
        assert strong.sum() == 1
        assert np.linalg.norm(f.points[strong][0]) == pytest.approx(np.linalg.norm(p), abs=0.2)
    # lidar: some returns lie on the plate of the board
    lidar = recording.sensors[0]
    f = recording.dwell_frames(0, "lidar1")[0]
    T_board_lidar = invert(recording.T_rig_board[0]) @ lidar.T_rig_sensor
    pts = f.points_xyz @ T_board_lidar[:3, :3].T + T_board_lidar[:3, 3]
    assert np.sum((np.abs(pts[:, 2]) < 0.06) & (np.abs(pts[:, 0]) < 0.5)) > 20


def test_recording_is_deterministic(placements):
    a = simulate_recording(tiny_rig(), placements[:2], 9, dwell_s=0.3, transition_s=0.2)
    b = simulate_recording(tiny_rig(), placements[:2], 9, dwell_s=0.3, transition_s=0.2)
    c = simulate_recording(tiny_rig(), placements[:2], 10, dwell_s=0.3, transition_s=0.2)
    assert len(a.frames) == len(b.frames) == len(c.frames)
    same = differs = True
    for fa, fb, fc in zip(a.frames, b.frames, c.frames):
        assert fa.sensor == fb.sensor and fa.t_ns == fb.t_ns
        if isinstance(fa, PointCloudFrame):
            same &= np.array_equal(fa.points_xyz, fb.points_xyz)
            differs &= not np.array_equal(fa.points_xyz, fc.points_xyz)
        elif isinstance(fa, StereoFrame):
            same &= np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
        else:
            same &= np.array_equal(fa.points, fb.points)
    assert same and differs
    assert np.array_equal(a.frame_T_rig_board, b.frame_T_rig_board)


def test_small_preset_recording_and_iterator(placements):
    rig = small_raw_rig()
    tl = make_timeline(placements[:1], 0, dwell_s=0.25)
    scene = scene_for_placements(placements[:1])
    items = list(iter_recording(rig, tl, scene, 0))
    assert [f.sensor for f, _, _ in items] == ["lidar1", "radar1", "camera1", "radar1", "lidar1",
                                               "camera1", "radar1", "lidar1", "camera1"]
    stereo = items[2][0]
    assert stereo.left.shape == (480, 640)
    assert all(k == 0 for _, _, k in items)


def test_scene_for_placements_puts_the_wall_behind_every_board(placements):
    scene = scene_for_placements(placements, wall_distance_m=2.0)
    n, p0 = scene.wall_normal_world, scene.wall_point_world
    assert n[2] == 0.0
    for T in placements:
        corners = scene.with_board(T).plate_corners_world()
        assert np.min((corners - p0) @ n) >= 2.0 - 1e-9


def test_recording_validation(placements):
    lidar, cam, radar = small_raw_rig()
    with pytest.raises(InputError, match="duplicate raw sensor names"):
        simulate_recording([lidar, lidar], placements)
    with pytest.raises(InputError, match="needs at least one sensor"):
        simulate_recording([], placements)
    with pytest.raises(InputError, match="placements must have shape"):
        simulate_recording([lidar], np.eye(4))
    with pytest.raises(InputError, match="dwell_s must be > 0"):
        make_timeline(placements, 0, dwell_s=0.0)
    with pytest.raises(InputError, match="model must be a LidarModel, a camera"):
        RawSensor("x", "lidar", np.eye(4))
    with pytest.raises(InputError, match="rate_hz must be > 0"):
        RawSensor("x", lidar.model, np.eye(4), rate_hz=0.0)
    with pytest.raises(InputError, match="rng must be a numpy.random.Generator or an int seed"):
        simulate_recording([lidar], placements, rng="seed")
    with pytest.raises(InputError, match="num_boards must be >= 1"):
        raw_rig_placements(0, [lidar], 0)


def test_simulation_reports_its_progress_frame_by_frame(placements):
    calls: list[tuple[int, int]] = []
    rec = simulate_recording(tiny_rig(), placements, 5, dwell_s=1.0, transition_s=0.6,
                             progress=lambda done, total: calls.append((done, total)))
    total = len(rec.frames)
    assert calls == [(k, total) for k in range(total + 1)]
    again = simulate_recording(tiny_rig(), placements, 5, dwell_s=1.0, transition_s=0.6)
    assert [f.t_ns for f in again.frames] == [f.t_ns for f in rec.frames]  # the same recording
