"""Shared helpers of the raw-simulation tests: a board standing in front of a sensor."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry.se3 import from_rt
from rigcal.sim.raw import PinholeRadtanCamera, Scene
from rigcal.sim.rig import R_BODY_OPTICAL

#: Board axes for a board facing the world origin from +x: x right (= -y world as seen from
#: the origin), y up, z toward the origin.
R_FACING = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def facing_board(distance_m: float, height_m: float = 1.0, lateral_m: float = 0.0) -> np.ndarray:
    """``T_world_board`` of an untilted board whose hole centre is at (distance, lateral, height)
    and whose front faces -x (toward a sensor on the x axis)."""
    return from_rt(R_FACING, np.array([distance_m, lateral_m, height_m]))


def camera_pose(height_m: float = 1.0) -> np.ndarray:
    """``T_world_camera`` of a camera at (0, 0, height) looking along +x."""
    return from_rt(R_BODY_OPTICAL, np.array([0.0, 0.0, height_m]))


@pytest.fixture
def small_camera() -> PinholeRadtanCamera:
    return PinholeRadtanCamera(320, 240, 300.0, 300.0, 159.5, 119.5)


@pytest.fixture
def board_scene() -> Scene:
    """A board 4 m ahead, hole centre 1 m high, wall 2.5 m behind it, ground at z = 0."""
    return Scene(facing_board(4.0, 1.0))
