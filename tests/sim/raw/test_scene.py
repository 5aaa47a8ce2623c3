from __future__ import annotations


import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sim.raw import (
    SURFACE_GROUND,
    SURFACE_NONE,
    SURFACE_PLATE,
    SURFACE_WALL,
    Material,
    Scene,
    hdl64e,
)

from .conftest import facing_board


def test_default_wall_is_behind_the_board(board_scene):
    assert np.allclose(board_scene.wall_normal_world, [-1.0, 0.0, 0.0])
    assert np.allclose(board_scene.wall_point_world, [6.5, 0.0, 1.0])


def test_plate_layout_holes_below_the_plate_centre(board_scene):
    x0, x1, y0, y1 = board_scene.plate_bounds_board
    assert (x0, x1) == (-0.5, 0.5)
    assert y0 == pytest.approx(-0.45) and y1 == pytest.approx(1.05)
    corners = board_scene.plate_corners_world()
    assert np.allclose(corners[:, 2], [2.05, 2.05, 0.55, 0.55])
    assert np.allclose(board_scene.reflector_world(), [4.105, 0.0, 1.0])


def test_rays_through_hole_centres_reach_the_wall(board_scene):
    o = np.array([0.0, 0.3, 1.2])
    centres = board_scene.hole_centres_world()
    hits = board_scene.cast(o, centres - o)
    assert np.all(hits.surface == SURFACE_WALL)
    d = centres - o
    expected = np.linalg.norm(d, axis=1) * (6.5 - o[0]) / d[:, 0]
    assert np.allclose(hits.range_m, expected, atol=1e-9)
    assert np.allclose(hits.points_world[:, 0], 6.5)


def test_rays_hit_the_plate_except_through_the_holes(board_scene):
    o = np.array([0.0, 0.0, 1.0])
    # a grid over the plate face, in board coordinates
    a, b = np.meshgrid(np.linspace(-0.49, 0.49, 99), np.linspace(-0.44, 1.04, 149))
    pts_board = np.stack([a.ravel(), b.ravel(), np.zeros(a.size)], axis=1)
    T = board_scene.T_world_board
    pts = pts_board @ T[:3, :3].T + T[:3, 3]
    hits = board_scene.cast(o, pts - o)
    r = 0.075
    in_hole = (np.abs(a.ravel()) - 0.12) ** 2 + (np.abs(b.ravel()) - 0.12) ** 2 < r * r
    assert in_hole.sum() > 50
    assert np.all(hits.surface[~in_hole] == SURFACE_PLATE)
    assert np.allclose(hits.points_world[~in_hole], pts[~in_hole], atol=1e-9)
    assert np.all(hits.surface[in_hole] != SURFACE_PLATE)


def test_ground_sky_and_range_units(board_scene):
    o = np.array([0.0, 0.0, 2.0])
    dirs = np.array([[1.0, 0.0, -1.0], [0.0, 0.0, 1.0], [-3.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    hits = board_scene.cast(o, dirs)
    assert hits.surface.tolist() == [SURFACE_GROUND, SURFACE_NONE, SURFACE_NONE, SURFACE_NONE]
    assert hits.range_m[0] == pytest.approx(2.0 * np.sqrt(2.0))
    assert np.allclose(hits.points_world[0], [2.0, 0.0, 0.0])
    assert np.all(np.isinf(hits.range_m[1:])) and np.all(np.isnan(hits.points_world[1:]))


def test_per_ray_origins_and_plate_back_side(board_scene):
    origins = np.array([[0.0, 0.0, 1.6], [8.0, 0.0, 1.6]])  # in front of and behind the board
    dirs = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    hits = Scene(board_scene.T_world_board, has_wall=False).cast(origins, dirs)
    assert hits.surface.tolist() == [SURFACE_PLATE, SURFACE_PLATE]
    assert np.allclose(hits.range_m, [4.0, 4.0])


def test_switching_surfaces_off():
    sc = Scene(facing_board(4.0), has_wall=False, has_ground=False)
    hits = sc.cast(np.zeros(3), np.array([[1.0, 0.0, -1.0]]))
    assert hits.surface[0] == SURFACE_NONE


def test_with_board_keeps_the_wall(board_scene):
    moved = board_scene.with_board(facing_board(2.0, 1.0, 0.5))
    assert np.allclose(moved.wall_point_world, board_scene.wall_point_world)
    hits = moved.cast(np.array([0.0, 0.5, 1.6]), np.array([[1.0, 0.0, 0.0]]))
    assert hits.surface[0] == SURFACE_PLATE and hits.range_m[0] == pytest.approx(2.0)


def test_explicit_wall():
    sc = Scene(facing_board(4.0), wall_point_world=[10.0, 0, 0], wall_normal_world=[-2.0, 0, 0])
    hits = sc.cast(np.array([0.0, 3.0, 1.5]), np.array([[1.0, 0.0, 0.0]]))
    assert hits.surface[0] == SURFACE_WALL and hits.range_m[0] == pytest.approx(10.0)


def test_cast_130k_rays(board_scene):
    dirs, _ = hdl64e().ray_directions()
    o = np.array([0.0, 0.0, 1.9])
    hits = board_scene.cast(o, dirs)
    assert hits.range_m.shape == (dirs.shape[0],) and dirs.shape[0] > 130_000


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"T_world_board": np.eye(3)}, "T_world_board: expected a 4x4 matrix"),
        ({"T_world_board": np.diag([1.0, 1.0, -1.0, 1.0])}, "must be a rotation"),
        ({"holes_above_plate_centre_m": 0.7}, "outside the 1.0 x 1.5 m plate"),
        ({"wall_point_world": [1.0, 0.0, 0.0]}, "give both wall_point_world and wall_normal_world"),
        ({"wall_point_world": [1.0, 0.0, 0.0], "wall_normal_world": [0, 0, 0]}, "must not be zero"),
        ({"wall_distance_m": -1.0}, "wall_distance_m must be a finite number > 0"),
        ({"sky_grey": 300.0}, "sky_grey must be in"),
    ],
)
def test_scene_validation(kwargs, match):
    args = {"T_world_board": facing_board(4.0), **kwargs}
    with pytest.raises(InputError, match=match):
        Scene(**args)


def test_material_and_cast_validation(board_scene):
    with pytest.raises(InputError, match="reflectivity must be in"):
        Material(reflectivity=1.5, grey=100.0)
    with pytest.raises(InputError, match="dirs must be"):
        board_scene.cast(np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="origins must be"):
        board_scene.cast(np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(InputError, match="finite and non-zero"):
        board_scene.cast(np.zeros(3), np.zeros((1, 3)))
