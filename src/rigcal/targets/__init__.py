"""Calibration targets: geometry in the target frame and helpers on detections."""

from rigcal.targets.circle_board import (
    board_centres,
    board_normals,
    reflector_in_board,
    reflectors_from_centres,
    square_error_m,
)

__all__ = [
    "board_centres",
    "board_normals",
    "reflector_in_board",
    "reflectors_from_centres",
    "square_error_m",
]
