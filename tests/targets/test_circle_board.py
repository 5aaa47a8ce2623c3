"""The circle board: hole geometry, reflector offset, normals, square check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.dataset import BoardGeometry
from rigcal.geometry import from_rt, so3_exp, transform_points
from rigcal.targets import (
    board_centres,
    board_normals,
    reflector_in_board,
    reflectors_from_centres,
    square_error_m,
)

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)
BOARD = BoardGeometry()


def _board_in_front(seed: int) -> np.ndarray:
    """T_sensor_board (4, 4): a board 2-8 m away, any direction, its front facing the sensor
    within 70 deg, any roll about its normal."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    position = direction * rng.uniform(2.0, 8.0)
    # z axis of the board points back to the sensor, tilted by up to 70 deg
    z = -direction
    tilt_axis = np.cross(z, rng.normal(size=3))
    tilt_axis /= np.linalg.norm(tilt_axis)
    z = so3_exp(tilt_axis * math.radians(rng.uniform(0, 70))) @ z
    x = np.cross(rng.normal(size=3), z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    return from_rt(R, position)


def test_centres_layout_and_order() -> None:
    c = board_centres(BOARD)
    s = BOARD.spacing_m
    assert c.shape == (4, 3)
    np.testing.assert_allclose(c[:, 2], 0.0)
    np.testing.assert_allclose(c.mean(axis=0), 0.0, atol=1e-15)
    tl, tr, bl, br = c
    assert tl[0] < tr[0] and bl[0] < br[0]  # left has smaller x
    assert tl[1] > bl[1] and tr[1] > br[1]  # top has larger y
    np.testing.assert_allclose(np.abs(c[:, :2]), s / 2)


@pytest.mark.parametrize("spacing", [0.24, 0.1, 0.5])
def test_square_side_is_spacing_and_diagonal_ratio_is_sqrt2(spacing: float) -> None:
    c = board_centres(BoardGeometry(spacing_m=spacing))
    sides = [np.linalg.norm(c[i] - c[j]) for i, j in ((0, 1), (2, 3), (0, 2), (1, 3))]
    diagonals = [np.linalg.norm(c[i] - c[j]) for i, j in ((0, 3), (1, 2))]
    np.testing.assert_allclose(sides, spacing)
    np.testing.assert_allclose(np.array(diagonals) / spacing, math.sqrt(2))


def test_reflector_sits_behind_front_face() -> None:
    r = reflector_in_board(BOARD)
    np.testing.assert_allclose(r, [0.0, 0.0, -BOARD.reflector_offset_m])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_normals_point_away_from_sensor_for_any_pose(seed: int) -> None:
    T = _board_in_front(seed)
    centres = transform_points(T, board_centres(BOARD))[None]
    n = board_normals(centres)[0]
    assert np.linalg.norm(n) == pytest.approx(1.0)
    # away from the sensor = toward the back of the board = -z of the board frame
    np.testing.assert_allclose(n, -T[:3, 2], atol=1e-9)
    assert n @ centres[0].mean(axis=0) > 0


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_reflector_from_centres_matches_board_model(seed: int) -> None:
    T = _board_in_front(seed)
    centres = transform_points(T, board_centres(BOARD))[None]
    expected = transform_points(T, reflector_in_board(BOARD)[None])[0]
    got = reflectors_from_centres(centres, BOARD)[0]
    np.testing.assert_allclose(got, expected, atol=1e-9)
    # behind the board: farther from the sensor than the hole centres' mean, along the normal
    mean = centres[0].mean(axis=0)
    assert (got - mean) @ mean > 0
    assert np.linalg.norm(got - mean) == pytest.approx(BOARD.reflector_offset_m)


def test_normals_batched_over_boards() -> None:
    Ts = [_board_in_front(s) for s in range(6)]
    centres = np.stack([transform_points(T, board_centres(BOARD)) for T in Ts])
    n = board_normals(centres)
    assert n.shape == (6, 3)
    np.testing.assert_allclose(n, -np.stack([T[:3, 2] for T in Ts]), atol=1e-9)


def test_square_error_zero_for_true_square_and_detects_distortion() -> None:
    T = _board_in_front(1)
    c = transform_points(T, board_centres(BOARD))
    distorted = c.copy()
    distorted[3] += 0.03 * T[:3, 0]  # BR moved 3 cm to the right in the board plane
    err = square_error_m(np.stack([c, distorted]), BOARD)
    assert err[0] == pytest.approx(0.0, abs=1e-12)
    assert err[1] == pytest.approx(0.03, rel=0.05)  # the BL-BR side grows by 3 cm


def test_square_error_detects_rectangle_with_right_sides_ratio() -> None:
    s = BOARD.spacing_m
    # a 2s x s/2 rectangle: every side is wrong by s/2 or more
    rect = np.array([[-s, s / 4, 0], [s, s / 4, 0], [-s, -s / 4, 0], [s, -s / 4, 0]])
    assert square_error_m(rect[None], BOARD)[0] >= s / 2 - 1e-12


def test_helpers_do_not_mutate_inputs() -> None:
    c = np.stack([transform_points(_board_in_front(s), board_centres(BOARD)) for s in range(3)])
    before = c.copy()
    board_normals(c), reflectors_from_centres(c, BOARD), square_error_m(c, BOARD)
    np.testing.assert_array_equal(c, before)
