"""SO(3): hat, exp/log inverse (including angles near 0 and near pi), roll-pitch-yaw."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.geometry import hat, matrix_from_rpy, rpy_from_matrix, so3_exp, so3_log

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)

unit_vectors = st.tuples(
    st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)
).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1).map(lambda v: v / np.linalg.norm(v))


def _is_rotation(R: np.ndarray) -> bool:
    return np.allclose(R @ R.T, np.eye(3), atol=1e-12) and abs(np.linalg.det(R) - 1) < 1e-12


def test_hat_is_cross_product() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b), atol=1e-15)
    np.testing.assert_allclose(hat(a), -hat(a).T)


@SETTINGS
@given(axis=unit_vectors, angle=st.floats(0.0, math.pi - 1e-6))
def test_log_inverts_exp(axis: np.ndarray, angle: float) -> None:
    w = axis * angle
    R = so3_exp(w)
    assert _is_rotation(R)
    np.testing.assert_allclose(so3_log(R), w, atol=1e-9)


@SETTINGS
@given(
    axis=unit_vectors,
    angle=st.sampled_from([0.0, 1e-12, 1e-9, 1e-6, 1e-5, 9.9e-5, 1e-4, 1.01e-4, 1e-3]),
)
def test_exp_log_near_zero(axis: np.ndarray, angle: float) -> None:
    w = axis * angle
    R = so3_exp(w)
    assert _is_rotation(R)
    # second-order Taylor expansion; the next term is of order angle**3 / 6
    taylor = np.eye(3) + hat(w) + 0.5 * hat(w) @ hat(w)
    np.testing.assert_allclose(R, taylor, rtol=0, atol=angle**3 / 6 + 1e-15)
    np.testing.assert_allclose(so3_log(R), w, atol=1e-12)


@SETTINGS
@given(
    axis=unit_vectors,
    delta=st.sampled_from([0.0, 1e-9, 1e-7, 1e-5, 1e-4, 9.9e-4, 1e-3, 1.01e-3, 1e-2]),
)
def test_exp_log_near_pi(axis: np.ndarray, delta: float) -> None:
    angle = math.pi - delta
    R = so3_exp(axis * angle)
    w = so3_log(R)
    assert abs(np.linalg.norm(w) - angle) < 1e-7
    # at exactly pi the sign of the axis is free; the rotation must match either way
    np.testing.assert_allclose(so3_exp(w), R, atol=1e-7)
    if delta >= 1e-5:
        np.testing.assert_allclose(w, axis * angle, atol=1e-6)


@SETTINGS
@given(axis=unit_vectors, angle=st.floats(math.pi + 1e-3, 2 * math.pi - 1e-3))
def test_log_returns_angle_at_most_pi(axis: np.ndarray, angle: float) -> None:
    w = so3_log(so3_exp(axis * angle))
    assert np.linalg.norm(w) <= math.pi + 1e-12
    np.testing.assert_allclose(so3_exp(w), so3_exp(axis * angle), atol=1e-9)


def test_exp_log_batched_shapes() -> None:
    rng = np.random.default_rng(2)
    w = rng.normal(size=(4, 5, 3))
    w *= (rng.uniform(0, math.pi - 0.01, size=(4, 5)) / np.linalg.norm(w, axis=-1))[..., None]
    R = so3_exp(w)
    assert R.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(so3_log(R), w, atol=1e-9)
    for i in range(4):
        for j in range(5):
            np.testing.assert_allclose(R[i, j], so3_exp(w[i, j]), atol=1e-15)


def test_exp_of_axis_is_rotation_about_it() -> None:
    R = so3_exp(np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


@SETTINGS
@given(
    roll=st.floats(-math.pi + 1e-6, math.pi - 1e-6),
    pitch=st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3),
    yaw=st.floats(-math.pi + 1e-6, math.pi - 1e-6),
)
def test_rpy_round_trip(roll: float, pitch: float, yaw: float) -> None:
    rpy = np.array([roll, pitch, yaw])
    R = matrix_from_rpy(rpy)
    assert _is_rotation(R)
    np.testing.assert_allclose(rpy_from_matrix(R), rpy, atol=1e-9)


@SETTINGS
@given(axis=unit_vectors, angle=st.floats(0.0, math.pi))
def test_matrix_rpy_matrix_round_trip(axis: np.ndarray, angle: float) -> None:
    R = so3_exp(axis * angle)
    np.testing.assert_allclose(matrix_from_rpy(rpy_from_matrix(R)), R, atol=1e-7)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
def test_rpy_gimbal_lock_gives_same_matrix(pitch: float) -> None:
    R = matrix_from_rpy(np.array([0.3, pitch, -1.1]))
    np.testing.assert_allclose(matrix_from_rpy(rpy_from_matrix(R)), R, atol=1e-9)


def test_rpy_is_z_y_x_product() -> None:
    r, p, y = 0.1, -0.4, 2.0
    Rx = so3_exp(np.array([r, 0, 0]))
    Ry = so3_exp(np.array([0, p, 0]))
    Rz = so3_exp(np.array([0, 0, y]))
    np.testing.assert_allclose(matrix_from_rpy(np.array([r, p, y])), Rz @ Ry @ Rx, atol=1e-15)


def test_functions_do_not_mutate_inputs() -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(size=(6, 3))
    R = so3_exp(w)
    rpy = rng.normal(size=(6, 3))
    copies = (w.copy(), R.copy(), rpy.copy())
    hat(w), so3_exp(w), so3_log(R), matrix_from_rpy(rpy), rpy_from_matrix(R)
    for before, after in zip(copies, (w, R, rpy)):
        np.testing.assert_array_equal(before, after)
