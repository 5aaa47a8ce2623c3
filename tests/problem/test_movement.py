"""rigcal.problem.movement: the chi-square test of a pose change, its power, the F-test when the
residuals scatter more than the model says, and the tested subspace - against scipy and by
simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from rigcal.problem.movement import (
    change_std,
    change_summary,
    detectable_noncentrality,
    f_sf,
    move_test,
    noncentral_chi2_sf,
    determined_basis,
    z_score,
)
from rigcal.geometry.se3 import se3_exp


@pytest.mark.parametrize("x,dof,nc", [(10.0, 3, 5.0), (1.0, 6, 0.5), (100.0, 6, 300.0), (40.0, 1, 10.0)])
def test_noncentral_chi2_matches_scipy(x, dof, nc):
    assert noncentral_chi2_sf(x, dof, nc) == pytest.approx(scipy.stats.ncx2.sf(x, dof, nc), rel=1e-9, abs=1e-14)


@pytest.mark.parametrize("x,d1,d2", [(2.5, 6, 20), (0.3, 3, 9), (10.0, 6, 54), (1.0, 1, 1)])
def test_f_sf_matches_scipy(x, d1, d2):
    assert f_sf(x, d1, d2) == pytest.approx(scipy.stats.f.sf(x, d1, d2), rel=1e-9)


@pytest.mark.parametrize("dof,alpha,power", [(6, 0.05 / 6, 0.8), (3, 0.01, 0.95)])
def test_detectable_noncentrality_gives_the_power(dof, alpha, power):
    nc = detectable_noncentrality(dof, alpha, power)
    assert scipy.stats.ncx2.sf(scipy.stats.chi2.isf(alpha, dof), dof, nc) == pytest.approx(power, abs=1e-4)


def test_z_score_orders_like_the_p_value_across_dof():
    assert z_score(30.0, 6) > z_score(20.0, 3) > z_score(5.0, 6)
    for stat, dof in ((12.0, 6), (7.0, 3)):
        z = z_score(stat, dof)
        assert scipy.stats.norm.sf(z) == pytest.approx(scipy.stats.chi2.sf(stat, dof), rel=0.05)


def test_determined_basis_drops_undetermined_directions():
    assert determined_basis(np.eye(6), range(6)).shape == (6, 6)
    U = determined_basis(np.diag([1.0, 1, 0, 1e6, 1e6, 0]), range(6))  # scale does not decide the rank
    assert U.shape == (6, 4) and np.allclose(U[[2, 5]], 0.0)
    v = np.ones(6) / math.sqrt(6.0)
    U = determined_basis(np.outer(v, v), range(6))
    assert U.shape == (6, 1) and abs(abs(float(U[:, 0] @ v)) - 1.0) < 1e-9
    U = determined_basis(np.eye(6), [2, 3, 4])  # a 2D radar: yaw, x, y only
    assert U.shape == (6, 3) and np.allclose(U[[0, 1, 5]], 0.0)


def test_false_alarm_rate_and_power_by_simulation():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    C = A @ A.T * 1e-6
    U = determined_basis(np.linalg.inv(C), range(6))
    L = np.linalg.cholesky(C)
    null = [move_test(L @ rng.normal(size=6), C, U, 0.05).significant for _ in range(4000)]
    assert abs(np.mean(null) - 0.05) < 0.012
    t0 = move_test(np.zeros(6), C, U, 0.05, power=0.8)
    # a pure translation as large as the quoted detectable one, in the worst direction, is found 80 %
    Q = np.linalg.inv(C)[3:, 3:]
    w, V = np.linalg.eigh(Q)
    shift = np.r_[0, 0, 0, V[:, 0] * t0.detectable_translation_m]
    # (the worst direction for a pure translation, rotation held at zero)
    found = [move_test(shift + L @ rng.normal(size=6), C, U, 0.05).significant for _ in range(3000)]
    assert abs(np.mean(found) - 0.8) < 0.03


def test_a_variance_factor_makes_it_an_f_test():
    C = np.eye(6) * 1e-6
    d = np.full(6, 3e-3)
    plain = move_test(d, C, np.eye(6), 0.05)
    inflated = move_test(d, C, np.eye(6), 0.05, variance_factor=4.0, redundancy=30)
    assert inflated.statistic == pytest.approx(plain.statistic / 4.0)
    assert inflated.p_value == pytest.approx(scipy.stats.f.sf(plain.statistic / 4.0 / 6, 6, 30))
    assert move_test(d, C, np.eye(6), 0.05, variance_factor=0.5, redundancy=30).p_value == plain.p_value


def test_change_summary_and_std():
    T = se3_exp(np.r_[0.1, -0.2, 0.3, 1.0, 2.0, 0.5])
    xi = np.r_[0.0, 0.0, math.radians(0.5), 0.01, 0.0, 0.0]
    c = change_summary(T, T @ se3_exp(xi))
    assert c["rotation_deg"] == pytest.approx(0.5) and np.allclose(c["axis_sensor"], [0, 0, 1])
    assert c["distance_m"] == pytest.approx(0.01, rel=1e-3)
    assert np.allclose(c["axis_reference"], T[:3, :3] @ [0, 0, 1])
    sd_t, sd_r = change_std(xi, np.diag([1e-6, 1e-6, 4e-6, 9e-6, 1e-6, 1e-6]))
    assert sd_t == pytest.approx(3e-3) and sd_r == pytest.approx(math.degrees(2e-3))
