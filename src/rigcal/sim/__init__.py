"""Synthetic rigs with known ground truth: sensors, board placements, simulated detections."""

from rigcal.sim.rig import (
    R_BODY_OPTICAL,
    RIG_FRAME,
    SimResult,
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

__all__ = [
    "RIG_FRAME",
    "R_BODY_OPTICAL",
    "SimResult",
    "SimSensor",
    "board_area_center",
    "make_board_placements",
    "make_rig_placements",
    "move_boards",
    "prius_like_rig",
    "random_rig",
    "simulate",
    "visible",
]
