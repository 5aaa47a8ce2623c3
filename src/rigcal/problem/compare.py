"""Compare a calibration with ground truth (simulation) - the arbiter of accuracy."""

from __future__ import annotations

from typing import Mapping, NamedTuple

import numpy as np

from rigcal.geometry.se3 import invert
from rigcal.geometry.so3 import so3_log
from rigcal.problem.result import CalibrationResult


class PoseError(NamedTuple):
    """Error of an estimated pose against the truth.

    ``translation_m`` / ``rotation_deg``: overall. Split in the sensor's own frame (what a 2D
    radar observes well vs not): ``in_plane_m`` (x, y), ``yaw_deg`` (about z),
    ``out_of_plane_m`` (z) and ``tilt_deg`` (angle between the true and estimated z axes).
    """

    translation_m: float
    rotation_deg: float
    in_plane_m: float = 0.0
    yaw_deg: float = 0.0
    out_of_plane_m: float = 0.0
    tilt_deg: float = 0.0


def pose_error(T_estimate: np.ndarray, T_truth: np.ndarray) -> PoseError:
    """Errors of ``T_estimate`` against ``T_truth`` (both ``T_reference_sensor``)."""
    D = invert(T_truth) @ T_estimate  # the estimated sensor frame in the true one
    return PoseError(
        float(np.linalg.norm(T_estimate[:3, 3] - T_truth[:3, 3])),
        float(np.degrees(np.linalg.norm(so3_log(D[:3, :3])))),
        float(np.linalg.norm(D[:2, 3])),
        float(np.degrees(abs(np.arctan2(D[1, 0], D[0, 0])))),
        float(abs(D[2, 3])),
        float(np.degrees(np.arccos(np.clip(D[2, 2], -1.0, 1.0)))),
    )


def errors_against_truth(
    result: CalibrationResult, truth_T_world_sensor: Mapping[str, np.ndarray]
) -> dict[str, PoseError]:
    """Per non-reference sensor: error of ``T_reference_sensor`` against the truth."""
    T_w_ref = truth_T_world_sensor[result.reference]
    out = {}
    for name, est in result.sensors.items():
        if name == result.reference:
            continue
        T_true = invert(T_w_ref) @ truth_T_world_sensor[name]
        out[name] = pose_error(est.T_reference_sensor, T_true)
    return out
