"""Radar measurement model: 2D projection, elevation, and their Jacobians."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.sensors.radar import elevation, elevation_jacobian, project_2d, project_2d_jacobian

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)


def _points(seed: int, n: int = 10) -> np.ndarray:
    """Points 0.5-40 m away, any azimuth, elevation within +-60 deg."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.5, 40.0, n)
    az = rng.uniform(-math.pi, math.pi, n)
    el = rng.uniform(-math.radians(60), math.radians(60), n)
    return r[:, None] * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
    )


def _central_difference(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(N, out..., 3) numerical Jacobian of a row-wise function f: (N, 3) -> (N, out...)."""
    cols = []
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_project_2d_keeps_range_and_azimuth(seed: int) -> None:
    x = _points(seed)
    p = project_2d(x)
    assert p.shape == (10, 2)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), np.linalg.norm(x, axis=1), rtol=1e-12)
    np.testing.assert_allclose(
        np.arctan2(p[:, 1], p[:, 0]), np.arctan2(x[:, 1], x[:, 0]), atol=1e-12
    )


def test_project_2d_of_planar_point_is_identity() -> None:
    x = np.array([[3.0, -1.0, 0.0], [0.5, 2.0, 0.0]])
    np.testing.assert_allclose(project_2d(x), x[:, :2])


def test_project_2d_example() -> None:
    # range 5 (3-4-0 triangle in x-z), azimuth 0
    np.testing.assert_allclose(project_2d(np.array([[3.0, 0.0, 4.0]])), [[5.0, 0.0]])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_project_2d_jacobian_matches_finite_differences(seed: int) -> None:
    x = _points(seed)
    J = project_2d_jacobian(x)
    assert J.shape == (10, 2, 3)
    np.testing.assert_allclose(J, _central_difference(project_2d, x), atol=1e-6)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_elevation_jacobian_matches_finite_differences(seed: int) -> None:
    x = _points(seed)
    J = elevation_jacobian(x)
    assert J.shape == (10, 3)
    np.testing.assert_allclose(J, _central_difference(elevation, x), atol=1e-6)


@pytest.mark.parametrize(
    "point, expected_deg",
    [
        ([1.0, 0.0, 1.0], 45.0),
        ([1.0, 0.0, -1.0], -45.0),
        ([0.0, 2.0, 0.0], 0.0),
        ([-1.0, 0.0, math.sqrt(3.0)], 60.0),
        ([0.0, 0.0, 1.0], 90.0),
    ],
)
def test_elevation_sign_z_up_positive(point: list[float], expected_deg: float) -> None:
    assert math.degrees(elevation(np.array([point]))[0]) == pytest.approx(expected_deg)


def test_functions_do_not_mutate_inputs() -> None:
    x = _points(1)
    before = x.copy()
    project_2d(x), project_2d_jacobian(x), elevation(x), elevation_jacobian(x)
    np.testing.assert_array_equal(x, before)
