"""SE(3): build, invert, compose, transform points, exp/log."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rigcal.geometry import compose, from_rt, invert, se3_exp, se3_log, so3_exp, transform_points
from rigcal.geometry.se3 import adjoint

SETTINGS = settings(max_examples=50, deadline=None, derandomize=True)

vec3 = arrays(np.float64, 3, elements=st.floats(-3, 3))


@st.composite
def transforms(draw: st.DrawFn) -> np.ndarray:
    w = draw(vec3)
    n = np.linalg.norm(w)
    if n > 0:
        w = w / n * (n % (math.pi - 1e-3))
    return from_rt(so3_exp(w), draw(vec3) * 3)


@SETTINGS
@given(T=transforms())
def test_invert_is_inverse(T: np.ndarray) -> None:
    np.testing.assert_allclose(invert(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(T @ invert(T), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(invert(invert(T)), T, atol=1e-12)
    np.testing.assert_allclose(invert(T), np.linalg.inv(T), atol=1e-12)


@SETTINGS
@given(a=transforms(), b=transforms(), c=transforms())
def test_compose_identities(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    np.testing.assert_allclose(compose(a, b, c), a @ b @ c, atol=1e-12)
    np.testing.assert_allclose(compose(a, np.eye(4)), a, atol=0)
    np.testing.assert_allclose(invert(compose(a, b)), compose(invert(b), invert(a)), atol=1e-12)
    np.testing.assert_allclose(compose(a, invert(a)), np.eye(4), atol=1e-12)


@SETTINGS
@given(T=transforms(), pts=arrays(np.float64, (7, 3), elements=st.floats(-10, 10)))
def test_transform_points_matches_homogeneous(T: np.ndarray, pts: np.ndarray) -> None:
    homog = np.concatenate([pts, np.ones((7, 1))], axis=1)
    np.testing.assert_allclose(transform_points(T, pts), (T @ homog.T).T[:, :3], atol=1e-12)
    back = transform_points(invert(T), transform_points(T, pts))
    np.testing.assert_allclose(back, pts, atol=1e-11)


@SETTINGS
@given(
    w=vec3,
    v=vec3,
    angle=st.one_of(st.floats(0.0, math.pi - 1e-4), st.sampled_from([0.0, 1e-10, 1e-6, 1e-4])),
)
def test_se3_log_inverts_exp(w: np.ndarray, v: np.ndarray, angle: float) -> None:
    n = np.linalg.norm(w)
    w = w / n * angle if n > 1e-3 else np.zeros(3)
    xi = np.concatenate([w, v])
    T = se3_exp(xi)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-8)


@SETTINGS
@given(T=transforms())
def test_se3_exp_inverts_log(T: np.ndarray) -> None:
    np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-9)


def test_se3_exp_rotation_first_and_pure_translation() -> None:
    T = se3_exp(np.array([0.0, 0.0, 0.0, 1.0, 2.0, 3.0]))
    np.testing.assert_allclose(T, from_rt(np.eye(3), [1.0, 2.0, 3.0]))
    T = se3_exp(np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(T[:3, :3], so3_exp(np.array([0.0, 0.0, 0.5])))
    np.testing.assert_allclose(T[:3, 3], 0.0)


def test_batched_invert_and_exp_log() -> None:
    rng = np.random.default_rng(5)
    xi = rng.normal(size=(3, 4, 6)) * 0.5
    T = se3_exp(xi)
    assert T.shape == (3, 4, 4, 4)
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-9)
    np.testing.assert_allclose(invert(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


def test_functions_do_not_mutate_inputs() -> None:
    rng = np.random.default_rng(6)
    xi = rng.normal(size=(5, 6))
    T = se3_exp(xi)
    R, t = T[:, :3, :3].copy(), T[:, :3, 3].copy()
    pts = rng.normal(size=(8, 3))
    copies = (xi.copy(), T.copy(), R.copy(), t.copy(), pts.copy())
    from_rt(R, t), invert(T), compose(T[0], T[1]), transform_points(T[0], pts)
    se3_exp(xi), se3_log(T)
    for before, after in zip(copies, (xi, T, R, t, pts)):
        np.testing.assert_array_equal(before, after)


@SETTINGS
@given(T=transforms(), w=vec3, v=vec3)
def test_adjoint_moves_a_twist_between_frames(T: np.ndarray, w: np.ndarray, v: np.ndarray) -> None:
    xi = np.concatenate([w, v]) * 0.3
    np.testing.assert_allclose(T @ se3_exp(xi) @ invert(T), se3_exp(adjoint(T) @ xi), atol=1e-9)
    np.testing.assert_allclose(adjoint(invert(T)), np.linalg.inv(adjoint(T)), atol=1e-9)
