"""Kabsch (rigid) and Umeyama (similarity) alignment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.errors import GeometryError
from rigcal.geometry import from_rt, kabsch, se3_exp, so3_exp, transform_points, umeyama

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)


def _random_T(rng: np.random.Generator) -> np.ndarray:
    w = rng.normal(size=3)
    w *= rng.uniform(0, np.pi - 1e-3) / np.linalg.norm(w)
    return from_rt(so3_exp(w), rng.uniform(-5, 5, 3))


def _cost(T: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sum((transform_points(T, a) - b) ** 2))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 40))
def test_kabsch_recovers_exact_transform(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    T = _random_T(rng)
    a = rng.uniform(-2, 2, (n, 3))
    b = transform_points(T, a)
    np.testing.assert_allclose(kabsch(a, b), T, atol=1e-8)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_kabsch_is_least_squares_optimal_with_noise(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = _random_T(rng)
    a = rng.uniform(-2, 2, (12, 3))
    b = transform_points(T, a) + rng.normal(scale=0.05, size=(12, 3))
    T_hat = kabsch(a, b)
    best = _cost(T_hat, a, b)
    for xi in rng.normal(scale=1e-3, size=(20, 6)):
        assert _cost(T_hat @ se3_exp(xi), a, b) >= best - 1e-12


def test_kabsch_weights_ignore_zero_weight_points() -> None:
    rng = np.random.default_rng(7)
    T = _random_T(rng)
    a = rng.uniform(-2, 2, (10, 3))
    b = transform_points(T, a)
    b[-2:] += 5.0  # corrupted, weight 0
    w = np.ones(10)
    w[-2:] = 0.0
    np.testing.assert_allclose(kabsch(a, b, w), T, atol=1e-8)


def test_kabsch_planar_three_points_gives_proper_rotation() -> None:
    rng = np.random.default_rng(8)
    T = _random_T(rng)
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    T_hat = kabsch(a, transform_points(T, a))
    assert np.linalg.det(T_hat[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T_hat, T, atol=1e-9)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), scale=st.floats(0.1, 10.0))
def test_umeyama_recovers_scale(seed: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    T = _random_T(rng)
    a = rng.uniform(-2, 2, (15, 3))
    b = scale * a @ T[:3, :3].T + T[:3, 3]
    s, T_hat = umeyama(a, b)
    assert s == pytest.approx(scale, rel=1e-9)
    np.testing.assert_allclose(T_hat, T, atol=1e-8)


@pytest.mark.parametrize("fn", [kabsch, umeyama])
def test_collinear_points_raise(fn) -> None:
    a = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(GeometryError, match="collinear"):
        fn(a, a + 1.0)


@pytest.mark.parametrize("fn", [kabsch, umeyama])
def test_fewer_than_three_points_raise(fn) -> None:
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    with pytest.raises(GeometryError, match="at least 3 point pairs, got 2"):
        fn(a, a)


@pytest.mark.parametrize("fn", [kabsch, umeyama])
@pytest.mark.parametrize(
    "shape_a, shape_b", [((4, 3), (5, 3)), ((4, 2), (4, 2)), ((4, 3), (4, 2)), ((12,), (12,))]
)
def test_shape_mismatch_raises(fn, shape_a, shape_b) -> None:
    with pytest.raises(GeometryError, match=r"\(N, 3\) point arrays of equal shape"):
        fn(np.zeros(shape_a), np.ones(shape_b))


@pytest.mark.parametrize("fn", [kabsch, umeyama])
def test_non_finite_points_raise(fn) -> None:
    a = np.random.default_rng(9).normal(size=(5, 3))
    b = a.copy()
    b[2, 1] = np.nan
    with pytest.raises(GeometryError, match="non-finite"):
        fn(a, b)


def test_alignment_does_not_mutate_inputs() -> None:
    rng = np.random.default_rng(10)
    a = rng.normal(size=(6, 3))
    b = rng.normal(size=(6, 3))
    w = rng.uniform(0.5, 1.0, 6)
    copies = (a.copy(), b.copy(), w.copy())
    kabsch(a, b, w), umeyama(a, b, w)
    for before, after in zip(copies, (a, b, w)):
        np.testing.assert_array_equal(before, after)


def test_bad_weights_are_refused():
    import numpy as np
    import pytest

    from rigcal.errors import GeometryError
    from rigcal.geometry.align import kabsch

    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 3))
    with pytest.raises(GeometryError, match="shape"):
        kabsch(a, a, weights=np.ones(4))
    with pytest.raises(GeometryError, match="not all zero"):
        kabsch(a, a, weights=np.zeros(5))
    with pytest.raises(GeometryError, match=">= 0"):
        kabsch(a, a, weights=-np.ones(5))


def test_value_types_compare_by_identity_without_crashing():
    import numpy as np

    from rigcal.geometry.frames import Transform

    a = Transform(np.eye(4), "a", "b")
    b = Transform(np.eye(4), "a", "b")
    assert a == a and a != b  # identity, not an ambiguous array comparison
    assert len({a, b}) == 2
