"""The in-house dense numerics against scipy's (which stays a test reference: rigcal itself
imports scipy only for large sparse problems)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import scipy.sparse
import scipy.special

from rigcal.problem.numerics import (
    assemble,
    block_diag,
    chi2_isf,
    chi2_sf,
    issparse,
    maximise_in_polytope,
    nnls,
    null_space,
    scale_rows,
    spd_solver,
    to_dense,
)


@pytest.mark.parametrize("seed", range(6))
def test_nnls_reaches_scipys_optimum(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        m, n = int(rng.integers(1, 40)), int(rng.integers(1, 15))
        A = rng.normal(size=(m, n))
        if n > 2 and rng.random() < 0.4:
            A[:, 1] = A[:, 0]  # duplicate columns: a rank-deficient problem
        b = rng.normal(size=m)
        x, res = nnls(A, b)
        x_ref, res_ref = scipy.optimize.nnls(A, b)
        assert np.all(x >= 0.0)
        assert res == pytest.approx(np.linalg.norm(A @ x - b))
        assert res <= res_ref + 1e-10 * max(1.0, res_ref)


def test_nnls_keeps_its_inputs_and_handles_empty_and_exact_cases():
    A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    b = np.array([1.0, -1.0, 0.0])
    A0, b0 = A.copy(), b.copy()
    x, _ = nnls(A, b)
    np.testing.assert_array_equal(A, A0)
    np.testing.assert_array_equal(b, b0)
    np.testing.assert_allclose(x, [1.0 / 2.0, 0.0], atol=1e-12)  # x2 >= 0 binds
    x, res = nnls(np.eye(3), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(x, [1.0, 2.0, 3.0])
    assert res == pytest.approx(0.0, abs=1e-12)
    x, res = nnls(np.zeros((0, 2)), np.zeros(0))
    np.testing.assert_array_equal(x, [0.0, 0.0])
    with pytest.raises(ValueError, match="entries"):
        nnls(np.eye(3), np.zeros(2))


@pytest.mark.parametrize("seed", range(4))
def test_polytope_maximum_equals_linprog(seed):
    rng = np.random.default_rng(seed)
    limit = np.array([np.pi / 2, np.pi / 2, 10.0])
    for _ in range(60):
        N = int(rng.integers(1, 60))
        A = rng.normal(size=(N, 3))
        b = np.abs(rng.normal(size=N)) * (rng.random(N) > 0.3)  # many zeros: degenerate vertices
        for i in range(3):
            for sign in (1.0, -1.0):
                c = sign * np.eye(3)[i]
                d = maximise_in_polytope(c, A, b, limit)
                ref = scipy.optimize.linprog(-c, A_ub=A, b_ub=b, bounds=[(-v, v) for v in limit], method="highs")
                assert np.all(A @ d <= b + 1e-9) and np.all(np.abs(d) <= limit + 1e-12)
                assert c @ d == pytest.approx(-ref.fun, abs=1e-9)


def test_polytope_needs_the_origin_feasible():
    with pytest.raises(ValueError, match="origin"):
        maximise_in_polytope(np.ones(3), np.eye(3), -np.ones(3), np.ones(3))
    # only the box: the optimum is its corner
    np.testing.assert_allclose(maximise_in_polytope(np.array([1.0, -1.0, 0.0]), np.zeros((0, 3)), np.zeros(0), np.array([1.0, 2.0, 3.0]))[:2], [1.0, -2.0])


@pytest.mark.parametrize("dof", [1, 2, 3, 5, 12, 40, 300])
def test_chi2_quantile_equals_scipy(dof):
    for p in (0.5, 0.05, 1e-3, 1e-6, 1e-10):
        assert chi2_isf(p, dof) == pytest.approx(scipy.special.chdtri(dof, p), rel=1e-10)
        assert chi2_sf(chi2_isf(p, dof), dof) == pytest.approx(p, rel=1e-9)
    with pytest.raises(ValueError):
        chi2_isf(0.0, dof)


def test_dense_linear_algebra_equals_scipy():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(30, 8))
    M = J.T @ J
    rhs = rng.normal(size=(8, 3))
    np.testing.assert_allclose(spd_solver(M)(rhs), scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), rhs), rtol=1e-10)
    with pytest.raises(np.linalg.LinAlgError):
        spd_solver(-M)
    G = rng.normal(size=(2, 5))
    Z = null_space(G)
    assert Z.shape == (5, 3)
    np.testing.assert_allclose(G @ Z, 0.0, atol=1e-12)
    np.testing.assert_allclose(Z.T @ Z, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(Z @ Z.T, scipy.linalg.null_space(G) @ scipy.linalg.null_space(G).T, atol=1e-12)
    blocks = [rng.normal(size=(2, 2)), rng.normal(size=(3, 1)), np.array([[5.0]])]
    np.testing.assert_array_equal(block_diag(*blocks), scipy.linalg.block_diag(*blocks))


def test_assemble_sums_duplicates_dense_or_sparse():
    rows, cols, vals = [0, 1, 0, 2], [1, 2, 1, 0], [1.0, 2.0, 3.0, 4.0]
    dense = assemble(rows, cols, vals, (3, 3), dense=True)
    sparse = assemble(rows, cols, vals, (3, 3), dense=False)
    ref = scipy.sparse.coo_matrix((vals, (rows, cols)), shape=(3, 3)).toarray()
    np.testing.assert_array_equal(dense, ref)
    assert issparse(sparse) and not issparse(dense)
    np.testing.assert_array_equal(to_dense(sparse), ref)
    s = np.array([2.0, -1.0, 0.5])
    np.testing.assert_array_equal(scale_rows(dense, s), ref * s[:, None])
    np.testing.assert_array_equal(to_dense(scale_rows(sparse, s)), ref * s[:, None])


def test_calibrating_imports_no_scipy(tmp_path):
    """The point of this module: a small calibration never imports scipy (0.3-0.6 s)."""
    code = (
        "import sys\n"
        "from rigcal.sim.rig import random_rig, make_rig_placements, simulate\n"
        "from rigcal.problem.calibrate import CalibrationOptions, calibrate\n"
        "import numpy as np\n"
        "rng = np.random.default_rng(0)\n"
        "sensors = random_rig(rng, 1, 1, 1)\n"
        "ds = simulate(sensors, make_rig_placements(rng, sensors, 12), rng=1).dataset\n"
        "calibrate(ds, CalibrationOptions(mode='fcpe', cross_validation_folds=3))\n"
        "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_single_threaded_also_limits_a_blas_loaded_after_its_first_use():
    # the thread pools are looked up once per process, and again once scipy (its own BLAS) is
    # imported; every BLAS pool then runs one thread inside the block
    code = (
        "from rigcal.problem.numerics import single_threaded\n"
        "with single_threaded():\n    pass\n"
        "import scipy.linalg\n"
        "from threadpoolctl import threadpool_info\n"
        "with single_threaded():\n"
        "    pools = [p for p in threadpool_info() if p['user_api'] == 'blas']\n"
        "print(len(pools), max(p['num_threads'] for p in pools))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    n, most = (int(x) for x in out.split())
    assert n >= 1 and most == 1


@pytest.mark.parametrize("seed", range(6))
def test_polytope_vertices_give_what_the_linear_program_finds(seed):
    from rigcal.problem.numerics import maximise_in_polytope, polytope_vertices

    rng = np.random.default_rng(seed)
    for _ in range(40):
        k = int(rng.integers(1, 4))
        A = rng.normal(size=(int(rng.integers(0, 60)), k))
        if seed % 2:  # near-duplicate constraints, as several pairs seeing one reflector give
            A = np.vstack([A, A * (1 + 1e-7)])
        b = np.abs(rng.normal(size=len(A))) * rng.uniform(0.01, 2.0)
        if len(b):
            b[int(rng.integers(0, len(b)))] = 0.0  # the origin on a face
        limit = rng.uniform(0.5, 10.0, size=k)
        V = polytope_vertices(A, b, limit)
        assert np.all(np.abs(V) <= limit + 1e-9)
        if len(A):
            assert np.all(A @ V.T <= b[:, None] + 1e-9)
        for c in rng.normal(size=(8, k)):
            assert float(np.max(V @ c)) == pytest.approx(float(c @ maximise_in_polytope(c, A, b, limit)), abs=1e-9)


def test_polytope_vertices_refuses_more_than_three_dimensions():
    from rigcal.problem.numerics import polytope_vertices

    with pytest.raises(ValueError, match=r"k = 4 \(1 to 3\)"):
        polytope_vertices(np.zeros((1, 4)), np.ones(1), np.ones(4))
