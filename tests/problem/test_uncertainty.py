"""Uncertainty propagation: relative transforms between two calibrated poses."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry.se3 import adjoint, from_rt, invert, se3_exp, se3_log
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.problem.uncertainty import relative_covariance, relative_estimates

T_W_A = from_rt(matrix_from_rpy([0.1, -0.4, 1.2]), [1.0, 0.5, 0.3])
T_W_B = from_rt(matrix_from_rpy([-0.3, 0.2, -2.0]), [-0.4, 2.0, 1.1])


def _joint(rng, correlated: bool) -> np.ndarray:
    L = rng.normal(size=(12, 12)) * np.tile(np.repeat([0.002, 0.01], 3), 2)[:, None]
    C = L @ L.T if correlated else np.zeros((12, 12))
    if not correlated:
        for i in (0, 6):
            M = rng.normal(size=(6, 6)) * np.repeat([0.002, 0.01], 3)
            C[i:i + 6, i:i + 6] = M @ M.T
    return C


@pytest.mark.parametrize("correlated", [False, True])
def test_relative_covariance_matches_monte_carlo(correlated):
    rng = np.random.default_rng(3)
    C = _joint(rng, correlated)
    pred = relative_covariance(T_W_A, T_W_B, C)
    T_ab = invert(T_W_A) @ T_W_B
    xs = rng.multivariate_normal(np.zeros(12), C, size=20000)
    errs = np.array([se3_log(invert(T_ab) @ invert(T_W_A @ se3_exp(x[:6])) @ T_W_B @ se3_exp(x[6:])) for x in xs])
    emp = np.cov(errs.T)
    scale = np.sqrt(np.outer(np.diag(pred), np.diag(pred)))
    np.testing.assert_allclose(emp / scale, pred / scale, atol=0.05)


def test_perfectly_correlated_poses_have_a_certain_relative_transform():
    # both poses moved by the same rigid motion of the world: T_a_b does not change
    rng = np.random.default_rng(4)
    M = rng.normal(size=(6, 6)) * 0.01
    C_a = M @ M.T
    # a world perturbation e^d moves T_W_x to e^d T_W_x = T_W_x e^(Ad(T_x_W) d)
    J = np.vstack([adjoint(invert(T_W_A)), adjoint(invert(T_W_B))])
    C = J @ C_a @ J.T
    assert np.abs(relative_covariance(T_W_A, T_W_B, C)).max() < 1e-15
    independent = C.copy()
    independent[:6, 6:] = independent[6:, :6] = 0
    assert np.trace(relative_covariance(T_W_A, T_W_B, independent)) > 1e-5


def test_relative_estimates_for_every_pair_in_order():
    poses = {"a": T_W_A, "b": T_W_B, "c": np.eye(4)}
    cov = {n: np.diag(np.full(6, (k + 1) * 1e-6)) for k, n in enumerate(poses)}

    def joint(names):
        out = np.zeros((12, 12))
        out[:6, :6], out[6:, 6:] = cov[names[0]], cov[names[1]]
        return out

    rel = relative_estimates(["a", "b", "c"], poses, joint)
    assert list(rel) == ["a-b", "a-c", "b-c"]
    r = rel["a-c"]
    assert (r.to, r.frm) == ("a", "c")
    np.testing.assert_allclose(r.T_to_from, invert(T_W_A), atol=1e-12)
    assert r.std["x_m"] > 0 and r.covariance.shape == (6, 6)
    np.testing.assert_allclose(r.covariance, r.covariance.T)
