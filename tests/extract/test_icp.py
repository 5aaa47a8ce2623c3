"""ICP of a template onto a scan: each cost, robustness to outliers, degenerate directions left
alone, divergence reported, and the template preparation (normals, rim)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.extract.icp import (
    IcpOptions,
    IcpResult,
    estimate_normals,
    icp_align,
    prepare_template,
    voxel_downsample,
)
from rigcal.extract.result import ExtractionFailure
from rigcal.geometry.se3 import from_rt, invert, se3_exp, transform_points
from rigcal.geometry.so3 import so3_exp, so3_log


def box_surface(size=(0.6, 0.4, 0.25), spacing=0.005) -> np.ndarray:
    """Dense points on the six faces of a box [0, size] (an asymmetric closed shape)."""
    sx, sy, sz = size
    faces = []
    for (a, b), fixed_axis, values in (
        ((sy, sz), 0, (0.0, sx)), ((sx, sz), 1, (0.0, sy)), ((sx, sy), 2, (0.0, sz))
    ):
        u, v = np.meshgrid(np.arange(0, a + 1e-9, spacing), np.arange(0, b + 1e-9, spacing))
        for val in values:
            pts = np.zeros((u.size, 3))
            free = [i for i in range(3) if i != fixed_axis]
            pts[:, free[0]], pts[:, free[1]] = u.ravel(), v.ravel()
            pts[:, fixed_axis] = val
            faces.append(pts)
    return np.concatenate(faces)


def pose_error(T_est, T_true):
    dR = T_est[:3, :3].T @ T_true[:3, :3]
    return (
        float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
        math.degrees(float(np.linalg.norm(so3_log(dR)))),
    )


@pytest.fixture(scope="module")
def box():
    return prepare_template(box_surface(), voxel_m=0.006)


def scan_of(template_pts, T, rng, n=400, noise=0.002, visible_normal=None):
    """n points of the template (optionally only faces whose normal has a negative dot with
    ``visible_normal``, i.e. a partial view), in the sensor frame, with noise."""
    idx = rng.choice(len(template_pts), size=n, replace=False)
    return transform_points(T, template_pts[idx]) + rng.normal(0, noise, (n, 3))


@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane", "combined"])
def test_each_cost_recovers_a_perturbed_pose(box, method):
    rng = np.random.default_rng(1)
    T = from_rt(so3_exp([0.2, -0.4, 1.0]), [3.0, 0.5, -0.2])
    scan = scan_of(box.points, T, rng, n=800, noise=0.001)
    T0 = se3_exp(np.r_[np.radians([4.0, -5.0, 3.0]), [0.03, -0.02, 0.03]]) @ T
    fit = icp_align(box, scan, T0, IcpOptions(method=method, max_iterations=200))
    assert isinstance(fit, IcpResult), fit
    dt, dr = pose_error(fit.T_sensor_target, T)
    assert dt < 0.002 and dr < 0.15
    assert fit.inlier_fraction > 0.95 and fit.rms_m < 0.005
    assert fit.distances_m.shape == (len(scan),) and fit.inliers.dtype == bool


@pytest.mark.parametrize("loss", ["huber", "trimmed"])
def test_robust_losses_ignore_outliers(box, loss):
    """A quarter of the scan is clutter in a 0.9 m cube around the box (the plain least-squares
    fit is 0.25 deg off here; trimming more than the clutter's share would drop good matches
    that start far off)."""
    rng = np.random.default_rng(2)
    T = from_rt(so3_exp([0.0, 0.3, -0.2]), [2.5, -0.4, 0.1])
    scan = scan_of(box.points, T, rng, n=300)
    centre = transform_points(T, np.array([[0.3, 0.2, 0.125]]))[0]
    clutter = centre + rng.uniform(-0.45, 0.45, (100, 3))
    T0 = se3_exp(np.r_[np.radians([-3.0, 2.0, 4.0]), [0.02, 0.03, -0.02]]) @ T
    opts = IcpOptions(loss=loss, trim_fraction=0.1, min_inlier_fraction=0.5)
    fit = icp_align(box, np.vstack([scan, clutter]), T0, opts)
    assert isinstance(fit, IcpResult), fit
    dt, dr = pose_error(fit.T_sensor_target, T)
    assert dt < 0.002 and dr < 0.15


def test_unconstrained_spin_of_a_cylinder_is_left_alone(sim):
    """A cylinder's spin about its axis and its slide along it are not in the data: the fit must
    correct the axis and keep those where they started (no drift)."""
    tpl = prepare_template(sim.cylinder_template())
    assert not tpl.planar and not tpl.has_rim
    rng = np.random.default_rng(3)
    T = from_rt(np.eye(3), [2.5, 0.0, 0.25])
    pts = tpl.points[np.abs(tpl.points[:, 2] + 0.25) < 0.2]  # the side, away from the ends
    side = pts[np.abs(np.hypot(pts[:, 0], pts[:, 1]) - sim.CYL_RADIUS) < 1e-3]
    side = side[side[:, 0] < 0]  # the half facing a sensor at the origin
    scan = transform_points(T, side[rng.choice(len(side), 300, replace=False)])
    spin = from_rt(so3_exp([0.0, 0.0, math.radians(20.0)]), [0.0, 0.0, 0.04])  # spin + slide
    tilt = from_rt(so3_exp(np.radians([2.0, -2.0, 0.0])), [0.01, -0.01, 0.0])  # about the top
    T0 = T @ tilt @ spin
    start = invert(T) @ T0
    fit = icp_align(tpl, scan, T0, IcpOptions(method="point_to_plane"))
    assert isinstance(fit, IcpResult), fit
    Tm = fit.T_sensor_target
    assert math.degrees(math.acos(min(1.0, Tm[:3, 2] @ T[:3, 2]))) < 0.1  # axis fixed
    off = Tm[:3, 3] - 0.25 * Tm[:3, 2] - (T[:3, 3] - 0.25 * T[:3, 2])
    assert np.linalg.norm(off[:2]) < 0.002  # the axis passes through the true one
    rel = invert(T) @ Tm  # what is left: a spin and a slide, kept from the start
    spin_deg = math.degrees(math.atan2(rel[1, 0], rel[0, 0]))
    assert spin_deg == pytest.approx(math.degrees(math.atan2(start[1, 0], start[0, 0])), abs=1.0)
    assert rel[2, 3] == pytest.approx(start[2, 3], abs=0.005)


def test_divergence_is_reported(box):
    rng = np.random.default_rng(4)
    T = from_rt(np.eye(3), [3.0, 0.0, 0.0])
    scan = scan_of(box.points, T, rng)
    far = T.copy()
    far[:3, 3] += [0.0, 1.5, 0.0]
    r = icp_align(box, scan, far, sensor="lidar", t_ns=7)
    assert isinstance(r, ExtractionFailure)
    assert r.reason == "icp_diverged" and r.sensor == "lidar" and r.t_ns == 7
    assert "within" in r.detail
    # a plane where the box should be: matches, but the residuals stay high
    plane = np.c_[
        rng.uniform(2.7, 3.3, 400), rng.uniform(-0.3, 0.3, 400), rng.normal(0.5, 0.002, 400)
    ]
    r = icp_align(box, plane, T, IcpOptions(max_rms_m=0.005, min_inlier_fraction=0.9))
    assert isinstance(r, ExtractionFailure) and r.reason == "icp_diverged"


def test_options_are_validated():
    with pytest.raises(InputError, match="method"):
        IcpOptions(method="plane")
    with pytest.raises(InputError, match="loss"):
        IcpOptions(loss="cauchy")
    with pytest.raises(InputError, match="trim_fraction"):
        IcpOptions(trim_fraction=1.0)
    with pytest.raises(InputError, match="min_correspondence_m must not exceed"):
        IcpOptions(min_correspondence_m=0.5, max_correspondence_m=0.1)
    with pytest.raises(InputError, match="max_iterations"):
        IcpOptions(max_iterations=0)


def test_plate_template_rim(sim):
    """A flat plate: planar, with a rim along its edges pointing outward and placed at the
    true edge within a millimetre or two; the interior has none."""
    tpl = prepare_template(sim.diamond_template())
    assert tpl.planar and tpl.has_rim
    centre = sim.DIAMOND_CORNERS[:, :2].mean(axis=0)
    half = np.linalg.norm(sim.DIAMOND_CORNERS[0, :2] - centre)
    on = np.any(tpl.rim != 0, axis=1)
    d = tpl.points[on, :2] - centre
    outward = np.sign(d) / math.sqrt(2.0)
    assert np.mean(np.sum(outward * tpl.rim[on, :2], axis=1) > 0.9) > 0.95
    # L1 distance / sqrt(2) is the distance to the diamond's edge line
    edge_gap = (half - np.abs(tpl.rim_edge[on, :2] - centre).sum(axis=1)) / math.sqrt(2.0)
    assert np.median(np.abs(edge_gap)) < 0.0015
    interior = np.abs(tpl.points[:, :2] - centre).sum(axis=1) < half - 0.03
    assert not np.any(on & interior)
    assert np.allclose(np.abs(tpl.normals[:, 2]), 1.0)


def test_voxel_downsample_and_normals():
    rng = np.random.default_rng(5)
    v = rng.normal(size=(5000, 3))
    sphere = v / np.linalg.norm(v, axis=1, keepdims=True)
    down = voxel_downsample(sphere, 0.2)
    assert 100 < len(down) < 1500
    n, variation = estimate_normals(sphere, 16)
    assert np.mean(np.sum(n * sphere, axis=1) > 0.95) > 0.99  # outward
    assert np.median(variation) < 0.02
    with pytest.raises(InputError, match="voxel filtering"):
        prepare_template(np.zeros((50, 3)), voxel_m=0.01)
