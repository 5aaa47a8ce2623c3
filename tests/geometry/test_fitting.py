"""Robust plane / circle / square-of-circles fitting on seeded synthetic data with outliers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.errors import GeometryError, InputError
from rigcal.geometry.fitting import (
    circle_angular_gap,
    fit_circle_2d,
    fit_plane_lstsq,
    fit_square_circles_2d,
    from_plane_2d,
    intersect_rays_plane,
    plane_basis,
    project_to_plane,
    ransac_circle_2d,
    ransac_plane,
    square_template_2d,
    to_plane_2d,
)


def _plane_points(rng, normal, d, n, sigma, extent=2.0):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    basis = plane_basis(normal)
    uv = rng.uniform(-extent, extent, (n, 2))
    return -d * normal + uv @ basis + rng.normal(0, sigma, (n, 1)) * normal


def _angle_deg(a, b):
    return math.degrees(math.acos(min(1.0, abs(float(np.dot(a, b))))))


# ----------------------------------------------------------------------------- planes


def test_lstsq_plane_recovers_normal_and_orients_toward_origin():
    rng = np.random.default_rng(0)
    n_true = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    pts = _plane_points(rng, n_true, 3.0, 500, 0.002)
    fit = fit_plane_lstsq(pts)
    assert _angle_deg(fit.normal, n_true) < 0.1
    assert fit.d > 0 and abs(fit.d - 3.0) < 0.005
    assert fit.inliers.all() and 0.001 < fit.rms < 0.003


def test_lstsq_plane_rejects_degenerate_input():
    with pytest.raises(GeometryError, match="at least 3 points"):
        fit_plane_lstsq(np.zeros((2, 3)))
    with pytest.raises(GeometryError, match="collinear"):
        fit_plane_lstsq(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]))
    with pytest.raises(GeometryError, match="non-finite"):
        fit_plane_lstsq(np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0.0]]))
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        fit_plane_lstsq(np.zeros((5, 2)))


def test_ransac_plane_with_40_percent_outliers():
    rng = np.random.default_rng(1)
    n_true = np.array([0.0, 0.6, 0.8])
    good = _plane_points(rng, n_true, 2.0, 600, 0.01)
    bad = rng.uniform(-4, 4, (400, 3))
    pts = np.vstack([good, bad])
    fit = ransac_plane(pts, 0.03, np.random.default_rng(7), 200)
    assert _angle_deg(fit.normal, n_true) < 1.0
    assert abs(fit.d - 2.0) < 0.02
    assert fit.inliers[:600].mean() > 0.95
    assert fit.inliers[600:].mean() < 0.05
    # same seed, same answer
    again = ransac_plane(pts, 0.03, np.random.default_rng(7), 200)
    assert np.array_equal(again.inliers, fit.inliers)


def test_ransac_plane_angle_constraint_picks_the_ground_not_the_wall():
    rng = np.random.default_rng(2)
    ground = _plane_points(rng, [0, 0, 1], 1.8, 400, 0.01)
    wall = _plane_points(rng, [1, 0, 0], -5.0, 900, 0.01)  # bigger, vertical
    pts = np.vstack([ground, wall])
    free = ransac_plane(pts, 0.05, 3, 200)
    assert _angle_deg(free.normal, [1, 0, 0]) < 2
    hinted = ransac_plane(pts, 0.05, 3, 200, normal_hint=[0, 0, 1], max_angle_deg=20)
    assert _angle_deg(hinted.normal, [0, 0, 1]) < 2
    assert hinted.normal[2] > 0 and abs(hinted.d - 1.8) < 0.02  # normal toward the origin


def test_ransac_plane_failures_and_arguments():
    rng = np.random.default_rng(3)
    wall = _plane_points(rng, [1, 0, 0], -5.0, 100, 0.01)
    with pytest.raises(GeometryError, match="within 10"):
        ransac_plane(wall, 0.05, 0, 50, normal_hint=[0, 0, 1], max_angle_deg=10)
    with pytest.raises(GeometryError, match="inliers"):
        ransac_plane(wall, 0.05, 0, 50, min_inliers=500)
    with pytest.raises(InputError, match="threshold_m"):
        ransac_plane(wall, -1, 0)
    with pytest.raises(InputError, match="needs a normal_hint"):
        ransac_plane(wall, 0.05, 0, max_angle_deg=10)
    with pytest.raises(InputError, match="Generator"):
        ransac_plane(wall, 0.05, "seed")


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    nx=st.floats(-1, 1), ny=st.floats(-1, 1), nz=st.floats(0.1, 1), d=st.floats(0.5, 10),
    seed=st.integers(0, 2**31 - 1),
)
def test_ransac_plane_property_noise_free_is_exact(nx, ny, nz, d, seed):
    n_true = np.array([nx, ny, nz]) / np.linalg.norm([nx, ny, nz])
    pts = _plane_points(np.random.default_rng(seed), n_true, d, 50, 0.0)
    fit = ransac_plane(pts, 1e-3, seed, 20)
    assert fit.inliers.all()
    assert _angle_deg(fit.normal, n_true) < 1e-4
    assert abs(fit.d - d) < 1e-6


# ----------------------------------------------------------------------------- plane helpers


def test_plane_basis_is_right_handed_and_follows_up():
    n = np.array([-1.0, 0.2, 0.1]) / np.linalg.norm([-1.0, 0.2, 0.1])
    B = plane_basis(n, up_hint=[0, 0, 1])
    assert np.allclose(B @ B.T, np.eye(2))
    assert np.allclose(np.cross(B[0], B[1]), n)
    assert B[1][2] > 0.99  # y is "up"
    with pytest.raises(GeometryError, match="perpendicular"):
        plane_basis([0, 0, 1], up_hint=[0, 0, 1])
    B2 = plane_basis([0, 0, 1])
    assert np.allclose(np.cross(B2[0], B2[1]), [0, 0, 1])


def test_plane_coordinates_round_trip_and_projections():
    rng = np.random.default_rng(4)
    n = np.array([0.2, -0.3, 0.93]) / np.linalg.norm([0.2, -0.3, 0.93])
    B = plane_basis(n)
    o = -2.0 * n
    uv = rng.normal(size=(10, 2))
    p = from_plane_2d(uv, o, B)
    assert np.allclose(to_plane_2d(p, o, B), uv)
    off = p + 0.3 * n
    assert np.allclose(project_to_plane(off, n, 2.0), p)
    hit = intersect_rays_plane(p / np.linalg.norm(p, axis=1, keepdims=True), n, 2.0)
    assert np.allclose(hit, p)
    away = intersect_rays_plane(-p, n, 2.0)
    assert np.all(np.isnan(away))


# ----------------------------------------------------------------------------- circles


def test_circle_fit_full_and_partial_arcs():
    rng = np.random.default_rng(5)
    c, r = np.array([1.0, -2.0]), 0.075
    for span in (2 * math.pi, math.pi / 2):
        a = rng.uniform(0, span, 60)
        pts = c + r * np.column_stack([np.cos(a), np.sin(a)]) + rng.normal(0, 0.001, (60, 2))
        fit = fit_circle_2d(pts)
        tol = 0.001 if span > 6 else 0.005
        assert np.linalg.norm(fit.centre - c) < tol and abs(fit.radius - r) < tol
        assert fit.rms < 0.002
    centre, radius, rms = fit  # a plain (centre, radius, rms) triple


def test_circle_fit_with_radius_prior_and_fixed_radius():
    c, r = np.array([0.0, 0.0]), 0.075
    # two chords of a circle (like two lidar rings): x = +-sqrt(r^2 - y^2)
    ys = np.array([0.03, -0.05])
    xs = np.sqrt(r**2 - ys**2)
    pts = np.column_stack([np.r_[xs, -xs], np.r_[ys, ys]])
    fixed = fit_circle_2d(pts, centre0=[0.01, 0.01], radius_prior=r, radius_weight=math.inf)
    assert np.linalg.norm(fixed.centre - c) < 1e-9 and fixed.radius == r
    prior = fit_circle_2d(pts, radius_prior=0.08, radius_weight=4.0)
    assert np.linalg.norm(prior.centre - c) < 0.01
    two = fit_circle_2d(pts[[0, 2]], centre0=[0.0, 0.01], radius_prior=r, radius_weight=math.inf)
    assert abs(np.linalg.norm(two.centre - pts[0]) - r) < 1e-9


def test_circle_fit_degenerate():
    with pytest.raises(GeometryError, match="collinear"):
        fit_circle_2d(np.column_stack([np.arange(5.0), np.arange(5.0)]))
    with pytest.raises(GeometryError, match="at least 3"):
        fit_circle_2d(np.zeros((2, 2)))


def test_angular_gap():
    a = np.radians([10, 170])
    chord = np.column_stack([np.cos(a), np.sin(a)])
    assert circle_angular_gap(chord, np.zeros(2)) > math.pi
    a = np.radians([10, 170, 200, 340])
    assert circle_angular_gap(np.column_stack([np.cos(a), np.sin(a)]), np.zeros(2)) < math.pi


def test_ransac_circle_with_outliers_and_radius_bounds():
    rng = np.random.default_rng(6)
    c, r = np.array([0.5, 0.2]), 0.08
    a = rng.uniform(0, 2 * math.pi, 40)
    good = c + r * np.column_stack([np.cos(a), np.sin(a)]) + rng.normal(0, 0.002, (40, 2))
    # a circle whose radius is out of bounds
    big = np.array([2.0, 2.0]) + 0.5 * np.column_stack([np.cos(a), np.sin(a)])
    junk = rng.uniform(-1, 3, (30, 2))
    pts = np.vstack([good, big, junk])
    fit = ransac_circle_2d(pts, 0.06, 0.10, 0.01, np.random.default_rng(1), 800)
    assert np.linalg.norm(fit.centre - c) < 0.003 and abs(fit.radius - r) < 0.003
    assert fit.inliers[:40].mean() > 0.9 and not fit.inliers[40:80].any()
    with pytest.raises(GeometryError, match="radius in"):
        ransac_circle_2d(big, 0.06, 0.10, 0.01, 1, 200)


# ----------------------------------------------------------------------------- square of circles


def _square_edges(rng, centre, angle, side, r, per_hole=12, sigma=0.002, hole_xy=None):
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    cents = centre + (square_template_2d(side) if hole_xy is None else np.asarray(hole_xy)) @ R.T
    pts = []
    for cc in cents:
        a = rng.uniform(0, 2 * math.pi, per_hole)
        pts.append(cc + r * np.column_stack([np.cos(a), np.sin(a)]))
    return np.vstack(pts) + rng.normal(0, sigma, (4 * per_hole, 2)), cents


def test_square_of_circles_fit_recovers_pose_and_order():
    rng = np.random.default_rng(8)
    pts, cents = _square_edges(rng, np.array([0.3, -0.1]), math.radians(12), 0.24, 0.075)
    junk = rng.uniform(-0.5, 0.8, (10, 2))
    fit = fit_square_circles_2d(
        np.vstack([pts, junk]), 0.24, [0.32, -0.08], math.radians(5), 0.075, gate=0.02
    )
    assert np.max(np.linalg.norm(fit.centres - cents, axis=1)) < 0.002
    assert abs(fit.angle_rad - math.radians(12)) < 0.01 and abs(fit.radius - 0.075) < 0.002
    assert np.all(fit.labels[:48] == np.repeat(np.arange(4), 12))


def test_square_of_circles_angle_wraps_and_keeps_order_meaning():
    rng = np.random.default_rng(9)
    pts, cents = _square_edges(rng, np.zeros(2), math.radians(40), 0.24, 0.075, sigma=0.0)
    fit = fit_square_circles_2d(pts, 0.24, [0, 0], math.radians(40), 0.075, gate=0.02)
    # 40 deg stays; start past 45 deg: the fit wraps to [-45, 45) and relabels TL..BR
    fit2 = fit_square_circles_2d(pts, 0.24, [0, 0], math.radians(50), 0.075, gate=0.05)
    for f in (fit, fit2):
        assert -math.pi / 4 <= f.angle_rad < math.pi / 4
        tl, tr, bl, br = f.centres
        assert tl[1] > bl[1] - 1e-9 and tr[0] > tl[0] - 1e-9
        assert np.isclose(np.linalg.norm(tl - br), 0.24 * math.sqrt(2))
        used = f.labels >= 0
        d = np.linalg.norm(pts[used] - f.centres[f.labels[used]], axis=1)
        assert np.allclose(d, f.radius, atol=1e-6)


def test_square_of_circles_needs_points_on_two_circles():
    rng = np.random.default_rng(10)
    pts, _ = _square_edges(rng, np.zeros(2), 0.0, 0.24, 0.075)
    with pytest.raises(GeometryError, match="within"):
        fit_square_circles_2d(pts[:12], 0.24, [0, 0], 0.0, 0.075, gate=0.01)
