"""Compare a calibration with ground truth (simulation) - the arbiter of accuracy."""

from __future__ import annotations

from typing import Mapping, NamedTuple

import numpy as np

from rigcal.geometry.se3 import invert
from rigcal.geometry.so3 import so3_log
from rigcal.problem.result import CalibrationResult


class PoseError(NamedTuple):
    translation_m: float
    rotation_deg: float


def pose_error(T_estimate: np.ndarray, T_truth: np.ndarray) -> PoseError:
    """Translation distance [m] and rotation angle [deg] of ``T_truth^-1 T_estimate``."""
    D = invert(T_truth) @ T_estimate
    return PoseError(
        float(np.linalg.norm(T_estimate[:3, 3] - T_truth[:3, 3])),
        float(np.degrees(np.linalg.norm(so3_log(D[:3, :3])))),
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
