"""The frame-checked Transform value."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.errors import GeometryError
from rigcal.geometry import Transform, from_rt, so3_exp, transform_points

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)


def _random_T(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return from_rt(so3_exp(rng.normal(size=3)), rng.uniform(-3, 3, 3))


@SETTINGS
@given(s1=st.integers(0, 2**32 - 1), s2=st.integers(0, 2**32 - 1))
def test_compose_matching_frames(s1: int, s2: int) -> None:
    T_a_b = Transform(_random_T(s1), "a", "b")
    T_b_c = Transform(_random_T(s2), "b", "c")
    T_a_c = T_a_b @ T_b_c
    assert (T_a_c.to_frame, T_a_c.from_frame) == ("a", "c")
    np.testing.assert_allclose(T_a_c.matrix, T_a_b.matrix @ T_b_c.matrix, atol=1e-12)


def test_compose_mismatched_frames_raises() -> None:
    T_a_b = Transform(_random_T(1), "a", "b")
    T_c_d = Transform(_random_T(2), "c", "d")
    with pytest.raises(GeometryError, match="inner frames 'b' and 'c' differ"):
        T_a_b @ T_c_d


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_inverse_round_trip(seed: int) -> None:
    T = Transform(_random_T(seed), "base", "lidar")
    inv = T.inverse()
    assert (inv.to_frame, inv.from_frame) == ("lidar", "base")
    np.testing.assert_allclose((T @ inv).matrix, np.eye(4), atol=1e-12)
    np.testing.assert_allclose((inv @ T).matrix, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(inv.inverse().matrix, T.matrix, atol=1e-12)


def test_apply_maps_points() -> None:
    M = _random_T(3)
    pts = np.random.default_rng(4).normal(size=(5, 3))
    np.testing.assert_allclose(Transform(M, "a", "b").apply(pts), transform_points(M, pts))


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.diag([1.0, 1.0, -1.0, 1.0]), "no proper rotation"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "no proper rotation"),
        (np.eye(3), r"4x4 matrix, got shape \(3, 3\)"),
        (np.full((4, 4), np.nan), "non-finite entries"),
        (np.vstack([np.eye(4)[:3], [1.0, 0.0, 0.0, 1.0]]), r"last row must be \[0, 0, 0, 1\]"),
    ],
)
def test_non_rigid_input_rejected(matrix: np.ndarray, message: str) -> None:
    with pytest.raises(GeometryError, match=message):
        Transform(matrix, "a", "b")


def test_matrix_is_an_immutable_copy() -> None:
    M = _random_T(5)
    before = M.copy()
    T = Transform(M, "a", "b")
    M[0, 3] = 100.0
    assert T.matrix[0, 3] == before[0, 3]
    with pytest.raises(ValueError):
        T.matrix[0, 0] = 2.0


def test_operations_do_not_mutate_inputs() -> None:
    A = Transform(_random_T(6), "a", "b")
    B = Transform(_random_T(7), "b", "c")
    pts = np.random.default_rng(8).normal(size=(4, 3))
    copies = (A.matrix.copy(), B.matrix.copy(), pts.copy())
    A @ B, A.inverse(), A.apply(pts)
    for before, after in zip(copies, (A.matrix, B.matrix, pts)):
        np.testing.assert_array_equal(before, after)
