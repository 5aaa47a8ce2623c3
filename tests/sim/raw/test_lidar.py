from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.recording import PointCloudFrame
from rigcal.sim.raw import LidarModel, Scene, hdl64e, scan, vlp16

from .conftest import facing_board


def test_hdl64e_preset():
    m = hdl64e()
    ang = np.array(m.vertical_angles_deg)
    assert m.num_rings == 64
    assert ang[0] == pytest.approx(-24.9) and ang[-1] == pytest.approx(2.0)
    assert np.all(np.diff(ang) > 0)
    assert 130_000 <= m.num_rays <= 140_000


def test_vlp16_preset():
    m = vlp16()
    assert m.num_rings == 16 and m.num_azimuths == 1800
    assert np.allclose(m.vertical_angles_deg, np.arange(-15, 16, 2))


def test_hdl64e_scan_counts_and_rings():
    m = hdl64e()
    scene = Scene(facing_board(8.0, 1.0), wall_distance_m=2.5)
    T = from_rt(np.eye(3), [0.0, 0.0, 1.9])
    frame = scan(m, T, scene, np.random.default_rng(0), 5, "lidar1")
    assert isinstance(frame, PointCloudFrame)
    assert frame.sensor == "lidar1" and frame.t_ns == 5
    ring = frame.fields["ring"]
    assert ring.dtype == np.uint16 and ring.min() == 0 and ring.max() == 63
    # every downward ring hits the ground all around: 2118 returns each
    counts = np.bincount(ring, minlength=64)
    down = np.array(m.vertical_angles_deg) < -5.0
    assert np.all(counts[down] == m.num_azimuths)
    assert 100_000 < len(frame) <= m.num_rays
    # ring 0 is the lowest beam: measured elevation matches the laser's angle
    p = frame.points_xyz
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    assert np.allclose(el, np.array(m.vertical_angles_deg)[ring], atol=1e-6)
    inten = frame.fields["intensity"]
    assert inten.shape == (len(frame),) and np.all((inten >= 0) & (inten <= 255))


def test_points_are_in_the_lidar_frame_and_see_the_plate():
    m = replace(vlp16(), range_sigma_m=0.0)
    T_world_lidar = from_rt(matrix_from_rpy(np.radians([2.0, -3.0, 30.0])), [0.5, -0.2, 1.0])
    scene = Scene(facing_board(5.0, 1.0), has_ground=False)
    frame = scan(m, T_world_lidar, scene, np.random.default_rng(1))
    pts_world = frame.points_xyz @ T_world_lidar[:3, :3].T + T_world_lidar[:3, 3]
    T_bw = np.linalg.inv(scene.T_world_board)
    pts_board = pts_world @ T_bw[:3, :3].T + T_bw[:3, 3]
    on_plate = np.abs(pts_board[:, 2]) < 1e-6
    assert on_plate.sum() > 100
    a, b = pts_board[on_plate, 0], pts_board[on_plate, 1]
    assert np.all((np.abs(a) <= 0.5 + 1e-9) & (b >= -0.45 - 1e-9) & (b <= 1.05 + 1e-9))
    assert np.all((np.abs(a) - 0.12) ** 2 + (np.abs(b) - 0.12) ** 2 >= 0.075**2 - 1e-9)
    # everything else lies on the wall
    wall = scene.wall_point_world
    assert np.allclose(pts_world[~on_plate, 0], wall[0])
    # plate is brighter than the wall at similar incidence
    inten = frame.fields["intensity"]
    assert inten[on_plate].mean() > inten[~on_plate].mean()


def test_range_noise_statistics():
    sigma = 0.015
    scene = Scene(facing_board(6.0, 1.0), has_ground=False)
    T = from_rt(np.eye(3), [0.0, 0.0, 1.0])
    truth = scan(replace(vlp16(), range_sigma_m=0.0), T, scene, np.random.default_rng(2))
    noisy = scan(vlp16(range_sigma_m=sigma), T, scene, np.random.default_rng(2))
    assert len(truth) == len(noisy)
    r_true = np.linalg.norm(truth.points_xyz, axis=1)
    r_meas = np.linalg.norm(noisy.points_xyz, axis=1)
    err = r_meas - r_true
    assert len(err) > 10_000
    assert abs(err.mean()) < 4 * sigma / np.sqrt(len(err))
    assert np.std(err) == pytest.approx(sigma, rel=0.05)
    # noise is along the ray: directions are unchanged
    u_t = truth.points_xyz / r_true[:, None]
    u_m = noisy.points_xyz / r_meas[:, None]
    assert np.allclose(u_t, u_m, atol=1e-9)


def test_max_range_drops_returns():
    scene = Scene(facing_board(6.0, 1.0), has_ground=False)
    T = from_rt(np.eye(3), [0.0, 0.0, 1.0])
    far = scan(vlp16(), T, scene, np.random.default_rng(0))
    near = scan(vlp16(max_range_m=7.0), T, scene, np.random.default_rng(0))
    assert len(near) < len(far)
    assert np.linalg.norm(near.points_xyz, axis=1).max() < 7.1


def test_scan_is_deterministic(board_scene):
    T = from_rt(np.eye(3), [0.0, 0.0, 1.5])
    a = scan(vlp16(), T, board_scene, np.random.default_rng(7))
    b = scan(vlp16(), T, board_scene, np.random.default_rng(7))
    c = scan(vlp16(), T, board_scene, np.random.default_rng(8))
    assert np.array_equal(a.points_xyz, b.points_xyz)
    assert np.array_equal(a.fields["ring"], b.fields["ring"])
    assert not np.array_equal(a.points_xyz, c.points_xyz)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"vertical_angles_deg": (1.0, 0.0)}, "strictly ascending"),
        ({"vertical_angles_deg": ()}, "vertical_angles_deg must be finite"),
        ({"azimuth_step_deg": 0.0}, "azimuth_step_deg must be in"),
        ({"range_sigma_m": -1.0}, "range_sigma_m must be >= 0"),
        ({"min_range_m": 5.0, "max_range_m": 1.0}, "min_range_m < max_range_m"),
    ],
)
def test_lidar_model_validation(kwargs, match):
    args = {"vertical_angles_deg": (-1.0, 1.0), **kwargs}
    with pytest.raises(InputError, match=match):
        LidarModel(**args)


def test_scan_validation(board_scene):
    with pytest.raises(InputError, match="model must be a LidarModel"):
        scan("hdl", np.eye(4), board_scene, np.random.default_rng(0))
    with pytest.raises(InputError, match="rng must be a numpy.random.Generator"):
        scan(vlp16(), np.eye(4), board_scene, 0)
    with pytest.raises(InputError, match="T_world_lidar: expected a 4x4 matrix"):
        scan(vlp16(), np.eye(3), board_scene, np.random.default_rng(0))
