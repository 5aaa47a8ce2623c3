"""The Levenberg-Marquardt solver on SE(3), its residual Jacobians and the field-of-view
constraint of 2D radars (paper eq. 4)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry.se3 import from_rt, invert, se3_exp
from rigcal.geometry.so3 import matrix_from_rpy, so3_log
from rigcal.problem.configurations import RADAR_PLANE_FREE, build_pairwise
from rigcal.problem.initialise import initial_poses
from rigcal.problem.pairs import pair_data
from rigcal.problem.residuals import (
    MODEL_POINT,
    MODEL_RADAR2D,
    MODEL_RANGE,
    MODEL_RAY_EDGE,
    MODEL_SURFACE,
    elevation_limit_residuals,
    observation_residuals,
    ray_plane_hits,
)
from rigcal.problem.solver import ALL_FREE, ElevationLimits, Observations, PoseBlock, Problem, solve
from rigcal.problem.verify import kkt_violations, reference_solve
from rigcal.sensors.radar import elevation, project_2d

HELD = (False,) * 6
T_TRUE = from_rt(matrix_from_rpy([0.1, -0.2, 0.3]), [0.5, -0.3, 0.2])
#: a start well away from the truth: about 15 deg and 45 cm
PERTURBATION = np.array([0.15, -0.1, 0.2, 0.3, -0.2, 0.25])


def _points(rng: np.random.Generator, n: int = 16) -> np.ndarray:
    """Points 3-8 m ahead of the fixed sensor, spread left-right and up-down."""
    return np.column_stack(
        [rng.uniform(3.0, 8.0, n), rng.uniform(-3.0, 3.0, n), rng.uniform(-0.6, 0.6, n)]
    )


def _measure(points_a: np.ndarray, T_a_b: np.ndarray, model: str) -> np.ndarray:
    x = points_a @ invert(T_a_b)[:3, :3].T + invert(T_a_b)[:3, 3]
    return project_2d(x) if model == MODEL_RADAR2D else x


def _tiny_problem(model: str, start: np.ndarray, free=ALL_FREE, truth=T_TRUE, seed=0) -> Problem:
    """Sensor ``a`` (held, identity) and sensor ``b`` (pose ``T_a_b`` to estimate): noise-free
    observations by ``b`` of points known in ``a``."""
    pts = _points(np.random.default_rng(seed))
    meas = _measure(pts, truth, model)
    n = len(pts)
    obs = Observations(
        label="a-b",
        sensor="b",
        model=model,
        frame=("a",) * n,
        observer=("b",) * n,
        points=pts,
        measured=meas,
        sigma=np.ones_like(meas),
        board=np.arange(n),
    )
    return Problem((PoseBlock("a", np.eye(4), HELD), PoseBlock("b", start, free)), (obs,))


def _pose_error(T: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    D = invert(T_ref) @ T
    return float(np.linalg.norm(D[:3, 3])), float(np.linalg.norm(so3_log(D[:3, :3])))


# --------------------------------------------------------------------------- convergence


@pytest.mark.parametrize("model", [MODEL_POINT, MODEL_RADAR2D])
def test_tiny_problem_converges_to_truth(model):
    scale = 1.0 if model == MODEL_POINT else 0.3  # 2D radar: tilt is only weakly observable
    start = T_TRUE @ se3_exp(scale * PERTURBATION)
    assert _pose_error(start, T_TRUE)[0] > 0.05  # the start is really off
    sol = solve(_tiny_problem(model, start))
    assert sol.converged, sol.status
    dt, dr = _pose_error(sol.poses["b"], T_TRUE)
    assert dt < 1e-8 and dr < 1e-8
    assert sol.cost < 1e-16
    # the held reference block is returned bit for bit
    assert np.array_equal(sol.poses["a"], np.eye(4))
    assert sol.iterations > 1


def test_held_dofs_stay_at_their_value():
    """A 2D radar with RADAR_PLANE_FREE: yaw, x, y move; z, roll and pitch in its own frame stay
    at the start even though the data want them elsewhere."""
    start = T_TRUE @ se3_exp(0.3 * PERTURBATION)
    held = solve(_tiny_problem(MODEL_RADAR2D, start, free=RADAR_PLANE_FREE))
    assert held.converged, held.status
    D = invert(start) @ held.poses["b"]  # motion of the radar in its own start frame
    assert abs(D[2, 3]) < 1e-12  # z
    np.testing.assert_allclose(D[2, :3], [0.0, 0.0, 1.0], atol=1e-12)  # roll, pitch
    np.testing.assert_allclose(D[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)
    # the free DOFs did move: x, y, yaw
    assert np.hypot(D[0, 3], D[1, 3]) > 1e-3
    assert abs(np.arctan2(D[1, 0], D[0, 0])) > 1e-3
    # held DOFs have no covariance; free ones do
    cov = held.pose_covariance("b")
    for i, free in enumerate(RADAR_PLANE_FREE):
        if not free:
            assert np.all(cov[i] == 0.0) and np.all(cov[:, i] == 0.0)
        else:
            assert cov[i, i] > 0.0
    # the same problem with every DOF free moves z / roll / pitch (to the truth): holding matters
    free = solve(_tiny_problem(MODEL_RADAR2D, start))
    D_free = invert(start) @ free.poses["b"]
    assert abs(D_free[2, 3]) > 1e-3 or np.linalg.norm(D_free[2, :2]) > 1e-3
    assert _pose_error(free.poses["b"], T_TRUE)[0] < 1e-8


def test_not_converged_when_iterations_run_out():
    start = T_TRUE @ se3_exp(PERTURBATION)
    problem = _tiny_problem(MODEL_POINT, start)
    full = solve(problem)
    assert full.converged and full.iterations > 1  # the problem needs more than one step
    one = solve(problem, max_iterations=1)
    assert not one.converged
    assert "iteration" in one.status
    assert one.cost > full.cost


# --------------------------------------------------------------------------- Jacobians


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    return from_rt(matrix_from_rpy(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-2.0, 2.0, 3))


def _case(seed: int, n: int, min_abs_elevation: float, max_abs_elevation: float):
    """Random poses T_W_A, T_W_B and points in A that lie 2-10 m in front of B with
    |elevation| in the given range (so the radar projection and elevation are smooth)."""
    rng = np.random.default_rng(seed)
    T_W_A, T_W_B = _random_pose(rng), _random_pose(rng)
    rng_m = rng.uniform(2.0, 10.0, n)
    az = rng.uniform(-1.0, 1.0, n)
    el = rng.uniform(min_abs_elevation, max_abs_elevation, n) * rng.choice([-1.0, 1.0], n)
    x_B = rng_m[:, None] * np.column_stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
    )
    T_A_B = invert(T_W_A) @ T_W_B
    points_A = x_B @ T_A_B[:3, :3].T + T_A_B[:3, 3]
    return rng, np.repeat(T_W_A[None], n, 0), np.repeat(T_W_B[None], n, 0), points_A


def _function(kind: str, rng: np.random.Generator, n: int, poses=None, points=None):
    """(f(TA, TB) -> (r, JA, JB)) for one residual family with random whitening (the ray
    models measure their rays at ``poses`` = (TA, TB) through ``points``)."""
    if kind == "elevation":
        max_el = np.full(n, 0.1)
        sigma = 0.01
        return lambda TA, TB, P: elevation_limit_residuals(TA, TB, P, max_el, sigma)
    if kind == "surface":
        normals = rng.normal(size=(n, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        measured = rng.normal(0.0, 3.0, (n, 3))
        sigma = rng.uniform(0.01, 0.2, (n, 1))
        return lambda TA, TB, P: observation_residuals(TA, TB, P, measured, sigma, MODEL_SURFACE,
                                                       normals_A=normals)
    if kind in ("range", "ray_edge"):
        # rays from B towards A's plane z = 0 (through the case's points dropped onto the plane),
        # measured once at the case's poses: fixed in B
        T_B_A = invert(poses[1][0]) @ poses[0][0]
        q = points.copy()
        q[:, 2] = 0.0
        x = q @ T_B_A[:3, :3].T + T_B_A[:3, 3]
        rho = np.linalg.norm(x, axis=1)
        u = x / rho[:, None]
        sigma = rng.uniform(0.01, 0.2, (n, 1))
        if kind == "range":
            measured = u * (rho + rng.normal(0.0, 0.05, n))[:, None]
            return lambda TA, TB, P: observation_residuals(TA, TB, P, measured, sigma, MODEL_RANGE)
        from rigcal.targets.surface import TargetSurface
        from rigcal.targets.templates import diamond_target

        surface = TargetSurface.of(diamond_target(side_m=8.0, square_m=0.5, rows=6, cols=7))
        turn = matrix_from_rpy([0.0, 0.0, 0.01])
        rays = np.column_stack([u, u @ turn.T])
        return lambda TA, TB, P: observation_residuals(TA, TB, P, rays, sigma, MODEL_RAY_EDGE, surface=surface)
    if kind == "cylinder_range":
        # rays from B to the near side of a tube about A's z axis, measured at the case's poses
        surface, measured, _, _ = _tube_rays(rng, poses[0][0], poses[1][0], n)
        sigma = rng.uniform(0.01, 0.2, (n, 1))
        return lambda TA, TB, P: observation_residuals(TA, TB, P, measured, sigma, MODEL_RANGE, surface=surface)
    model = MODEL_POINT if kind == "point3d" else MODEL_RADAR2D
    d = 3 if kind == "point3d" else 2
    measured = rng.normal(0.0, 3.0, (n, d))
    sigma = rng.uniform(0.01, 0.2, (n, d))
    return lambda TA, TB, P: observation_residuals(TA, TB, P, measured, sigma, model)


def _tube_rays(rng, T_W_A, T_W_B, n, noise_m=0.05):
    """A cylinder about A's z axis (its radius half B's distance from the axis) and n points
    on the side that faces B, measured by B along their rays with a range error:
    (surface, measured (n, 3) in B, their ranges' errors (n,), the hits (n, 3) in A)."""
    from rigcal.targets.surface import TargetSurface
    from rigcal.targets.templates import cylinder_target

    T_A_B = invert(T_W_A) @ T_W_B
    o = T_A_B[:3, 3]
    radius = 0.5 * float(np.hypot(o[0], o[1]))
    surface = TargetSurface.of(cylinder_target(radius, 200.0))
    a = np.arctan2(o[1], o[0]) + rng.uniform(-0.9, 0.9, n)  # facing B, off grazing
    q = np.column_stack([radius * np.cos(a), radius * np.sin(a), rng.uniform(-100.0, -1.0, n)])
    x = q @ invert(T_A_B)[:3, :3].T + invert(T_A_B)[:3, 3]
    rho = np.linalg.norm(x, axis=1)
    e = rng.normal(0.0, noise_m, n)
    return surface, x / rho[:, None] * (rho + e)[:, None], e, q


def _central_differences(residuals, TA, TB, block: str, h: float = 1e-6) -> np.ndarray:
    """d residuals / d xi of block A or B (right perturbation), by central differences:
    (n, d, 6) for residuals(TA, TB) -> (n, d)."""
    r0 = residuals(TA, TB)
    fd = np.empty(r0.shape + (6,))
    for j in range(6):
        xi = np.zeros(6)
        xi[j] = h
        if block == "A":
            rp, rm = residuals(TA @ se3_exp(xi), TB), residuals(TA @ se3_exp(-xi), TB)
        else:
            rp, rm = residuals(TA, TB @ se3_exp(xi)), residuals(TA, TB @ se3_exp(-xi))
        fd[..., j] = (rp - rm) / (2 * h)
    return fd


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("block", ["A", "B"])
@pytest.mark.parametrize("kind", ["point3d", "radar2d", "elevation", "surface", "range", "ray_edge",
                                  "cylinder_range"])
def test_jacobian_matches_central_differences_of_right_perturbation(kind, block, seed):
    """Contract: J[i, :, j] = d r_i / d xi_j with T <- T @ se3_exp(xi), xi = (omega, v)."""
    n = 12
    rng, TA, TB, P = _case(seed, n, 0.2, 0.6)  # |elevation| > 0.1: every hinge is active
    f = _function(kind, rng, n, (TA, TB), P)
    r, JA, JB = f(TA, TB, P)
    J = JA if block == "A" else JB
    assert J.shape == r.shape + (6,)
    if kind == "elevation":
        assert np.all(r > 0)  # the contract is tested where the hinge is differentiable
    fd = _central_differences(lambda A, B: f(A, B, P)[0], TA, TB, block)
    scale = float(np.max(np.abs(J)))
    assert scale > 1.0  # not a trivially zero Jacobian
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6 * scale)


@pytest.mark.parametrize("seed", [0, 1])
def test_elevation_limit_is_zero_inside_the_field_of_view(seed):
    n = 10
    _, TA, TB, P = _case(seed, n, 0.0, 0.09)
    r, JA, JB = elevation_limit_residuals(TA, TB, P, np.full(n, 0.1), 0.01)
    assert np.all(r == 0.0) and np.all(JA == 0.0) and np.all(JB == 0.0)
    # and the hinge value outside is (|elevation| - max) / sigma
    _, TA, TB, P = _case(seed, n, 0.2, 0.6)
    r = elevation_limit_residuals(TA, TB, P, np.full(n, 0.1), 0.01)[0]
    x = np.einsum("nij,nj->ni", invert(TB) @ TA, np.column_stack([P, np.ones(n)]))[:, :3]
    np.testing.assert_allclose(r[:, 0], (np.abs(elevation(x)) - 0.1) / 0.01, rtol=1e-12)


def test_ray_plane_hits_and_the_range_residual_are_exact():
    """A ray from B meets A's plane z = 0 where the geometry says, and a point measured on it
    with a range error e has the range residual e / sigma."""
    rng = np.random.default_rng(3)
    T_W_A, T_W_B = _random_pose(rng), _random_pose(rng)
    T_A_B = invert(T_W_A) @ T_W_B
    q = np.column_stack([rng.uniform(-1, 1, 5), rng.uniform(-1, 1, 5), np.zeros(5)])
    x = q @ invert(T_A_B)[:3, :3].T + invert(T_A_B)[:3, 3]
    rho = np.linalg.norm(x, axis=1)
    u = x / rho[:, None]
    TA, TB = np.repeat(T_W_A[None], 5, 0), np.repeat(T_W_B[None], 5, 0)
    h, s, *_ = ray_plane_hits(TA, TB, u)
    np.testing.assert_allclose(h, q, atol=1e-12)
    np.testing.assert_allclose(s, rho, rtol=1e-12)
    e = rng.normal(0, 0.02, 5)
    r, _, _ = observation_residuals(TA, TB, np.zeros((5, 3)), u * (rho + e)[:, None], np.full((5, 1), 0.01),
                                    MODEL_RANGE)
    np.testing.assert_allclose(r[:, 0], e / 0.01, rtol=1e-9)


def test_a_ray_meets_the_cylinder_where_the_geometry_says_and_its_range_residual_is_exact():
    """Rays from B to the near side of a tube: the range is the hit's, a range error e gives the
    residual e / sigma (no bias from the tube's curvature), and a ray that misses the tube is
    not on it."""
    from rigcal.problem.residuals import ray_surface_hits

    rng = np.random.default_rng(4)
    T_W_A, T_W_B = _random_pose(rng), _random_pose(rng)
    surface, measured, e, q = _tube_rays(rng, T_W_A, T_W_B, 6)
    TA, TB = np.repeat(T_W_A[None], 6, 0), np.repeat(T_W_B[None], 6, 0)
    rho = np.linalg.norm(measured, axis=1)
    s, on, _, _ = ray_surface_hits(TA, TB, measured / rho[:, None], surface)
    np.testing.assert_allclose(s, rho - e, rtol=1e-10)
    assert on.all()
    r, _, _ = observation_residuals(TA, TB, np.zeros((6, 3)), measured, np.full((6, 1), 0.01), MODEL_RANGE,
                                    surface=surface)
    np.testing.assert_allclose(r[:, 0], e / 0.01, rtol=1e-8)
    T_A_B = invert(T_W_A) @ T_W_B
    away = (invert(T_A_B)[:3, :3] @ np.array([-T_A_B[1, 3], T_A_B[0, 3], 0.0]))[None]  # along the tangent
    u = away / np.linalg.norm(away)
    assert not ray_surface_hits(TA[:1], TB[:1], u, surface)[1][0]
    # past the silhouette the range is that of the ray's closest approach, and so is its gradient
    miss = u * 3.0

    def f(A, B):
        return observation_residuals(A, B, np.zeros((1, 3)), miss, np.full((1, 1), 0.01), MODEL_RANGE,
                                     surface=surface)[0]

    for block, J in zip("AB", observation_residuals(TA[:1], TB[:1], np.zeros((1, 3)), miss, np.full((1, 1), 0.01),
                                                     MODEL_RANGE, surface=surface)[1:]):
        np.testing.assert_allclose(J, _central_differences(f, TA[:1], TB[:1], block), rtol=1e-5,
                                   atol=1e-6 * np.abs(J).max())


# --------------------------------------------------------------------------- field of view


def _reflector_elevations(dataset, poses, frame: str, radar: str) -> np.ndarray:
    p = pair_data(dataset, frame, radar)
    T = invert(poses[radar]) @ poses[frame]
    return np.abs(elevation(p.points @ T[:3, :3].T + T[:3, 3]))


def test_fov_constraint_holds_and_matters_on_real_lidar_radar_pair(real_dataset):
    """Alone, the real lidar1-radar1 pair's least-squares optimum tilts the radar so that the
    reflectors leave its +-9 deg field of view; with the constraint every reflector stays in."""
    poses0 = initial_poses(real_dataset, "lidar1")
    problem = build_pairwise(real_dataset, poses0, "lidar1", [("lidar1", "radar1")])
    assert len(problem.limits) == 1
    max_el = real_dataset.sensor("radar1").max_elevation_rad

    constrained = solve(problem)
    assert constrained.converged, constrained.status
    el = _reflector_elevations(real_dataset, constrained.poses, "lidar1", "radar1")
    assert np.all(el <= max_el + 1e-6)
    assert np.max(el) > max_el - 1e-4  # the constraint is active: some board sits on the edge

    free = solve(dataclasses.replace(problem, limits=()))
    assert free.converged, free.status
    el_free = _reflector_elevations(real_dataset, free.poses, "lidar1", "radar1")
    assert np.sum(el_free > max_el + 1e-3) >= 3
    # dropping the constraint lowers the cost: the limit is what holds the radar back
    assert free.cost < constrained.cost


@pytest.mark.parametrize("block", ["A", "B"])
def test_surface_jacobian_with_closest_points_found_at_every_evaluation(block):
    """With a surface, the residual is the signed distance to it: its gradient is n^T dy."""
    from rigcal.targets.surface import TargetSurface
    from rigcal.targets.templates import cylinder_target

    surface = TargetSurface.of(cylinder_target(0.2, 1.0))
    rng = np.random.default_rng(4)
    n = 20
    T_W_A, T_W_B = _random_pose(rng), _random_pose(rng)
    a = rng.uniform(0, 2 * np.pi, n)
    y = np.column_stack([0.2 * np.cos(a), 0.2 * np.sin(a), rng.uniform(-0.8, -0.2, n)])
    y[:, :2] *= rng.uniform(1.02, 1.2, (n, 1))  # off the lateral surface, away from the rims
    z = (invert(T_W_B) @ T_W_A @ np.column_stack([y, np.ones(n)]).T).T[:, :3]
    sigma = np.full((n, 1), 0.01)
    TA, TB = np.repeat(T_W_A[None], n, 0), np.repeat(T_W_B[None], n, 0)

    def f(TA_, TB_):
        return observation_residuals(TA_, TB_, np.zeros((n, 3)), z, sigma, MODEL_SURFACE, surface=surface)

    r, JA, JB = f(TA, TB)
    np.testing.assert_allclose(r[:, 0] * 0.01, surface.distance(y), atol=1e-12)  # outside: +distance
    J = JA if block == "A" else JB
    fd = _central_differences(lambda A, B: f(A, B)[0], TA, TB, block)
    np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-5 * float(np.max(np.abs(J))))


# --------------------------------------------------------------------------- constrained optima


def _radar_problem(max_el_deg: float, seed: int = 0, start_scale: float = 0.2) -> Problem:
    """A held sensor ``a`` and a 2D radar ``b`` that sees 16 points 3-8 m ahead at up to ~11 deg
    elevation, with the field of view cut to +-max_el_deg: noise-free data pull the radar to
    its true tilt, the limits hold it back, so several limits bind at the optimum."""
    start = T_TRUE @ se3_exp(start_scale * PERTURBATION)
    p = _tiny_problem(MODEL_RADAR2D, start, seed=seed)
    obs = p.observations[0]
    lim = ElevationLimits(
        label="a-b", frame=obs.frame, observer=obs.observer, points=obs.points,
        max_elevation_rad=np.full(obs.size, np.radians(max_el_deg)), board=obs.board,
    )
    return dataclasses.replace(p, limits=(lim,))


#: a step tolerance far below the statistical default, for checks of the optimum itself
TIGHT = 1e-9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constrained_solution_satisfies_kkt_conditions(seed):
    problem = _radar_problem(6.0, seed)
    sol = solve(problem, step_sigma=TIGHT)
    assert sol.converged, sol.status
    k = kkt_violations(problem, sol.poses)
    # the limits really bind: a clearly non-zero gradient held by positive multipliers
    assert k["gradient"] > 1e-3 and np.sum(k["multipliers"] > 1e-6) >= 1
    assert k["stationarity"] < 1e-6, k
    assert k["complementarity"] < 1e-9, k
    assert k["violation"] <= problem.fov_tolerance_rad
    # the same checks reject a feasible point that is not optimal: one step from the start
    assert kkt_violations(problem, solve(problem, max_iterations=1).poses)["stationarity"] > 1e-3


@pytest.mark.parametrize("seed", [0, 2])
def test_constrained_solution_matches_scipy_slsqp(seed):
    problem = _radar_problem(6.0, seed)
    sol = solve(problem, step_sigma=TIGHT)
    assert sol.converged, sol.status
    cost, poses = reference_solve(problem)[:2]
    assert sol.cost == pytest.approx(cost, rel=1e-7)
    dt, dr = _pose_error(sol.poses["b"], poses["b"])
    assert dt < 2e-5 and dr < 5e-6
    # without the limits the optimum is elsewhere (the comparison is not trivially met)
    free = solve(dataclasses.replace(problem, limits=()))
    assert free.cost < 0.5 * sol.cost


def test_step_qp_handles_redundant_and_degenerate_limits():
    """The step subproblem min 0.5 d'Md + g'd s.t. c + G d <= 0 with duplicated rows (FCPE has
    each reflector twice, once through each 3D sensor) and a limit that binds with a zero
    multiplier: the KKT conditions of the QP hold."""
    from rigcal.problem.solver import _constrained_step

    rng = np.random.default_rng(3)
    n = 6
    B = rng.normal(size=(n, n))
    M = B @ B.T + 0.1 * np.eye(n)
    g = rng.normal(size=n)
    G0 = rng.normal(size=(3, n))
    G = np.vstack([G0, G0, G0[:1] * 2.0])  # duplicated and scaled rows
    d_free = -np.linalg.solve(M, g)
    c = -0.5 * (G @ d_free)  # every row is violated by the unconstrained step
    d, active, mult = _constrained_step(M, g, c, G)
    slack = c + G @ d
    assert np.all(slack <= 1e-10)  # feasible
    assert np.all(mult >= 0.0)
    np.testing.assert_allclose(M @ d + g + G.T @ mult, 0.0, atol=1e-9)  # stationary
    assert np.max(np.abs(mult * slack)) < 1e-10  # complementary
    assert np.linalg.norm(d - d_free) > 1e-3  # the constraints did change the step
