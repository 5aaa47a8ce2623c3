"""Double sphere: the published equations, parameter checks and the projection's domain.

The double sphere cases are defined in ``conftest.py`` (``DS_CASES``). The contract suite in
``test_contract.py`` runs on them along with the cases of the other models, so only what is
particular to this model is tested here. The ``ds_camera`` fixture from ``conftest.py`` runs
the case-based tests below once per double sphere case. OpenCV has no double sphere model, so
the contract's cv2.projectPoints comparison is skipped for it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.registry import camera_from_params


def test_camera_from_params(ds_camera):
    for name in ("double_sphere", "ds", "DS", "DOUBLESPHERE"):
        again = camera_from_params(name, ds_camera.width, ds_camera.height, ds_camera.params)
        assert again == ds_camera and type(again) is DoubleSphereCamera


# ---------------------------------------------------------------------------- the equations
def _paper_projection(p: np.ndarray, fx, fy, cx, cy, xi, alpha) -> np.ndarray:
    """Eq. (40)-(45) of Usenko et al. 2018, one point at a time."""
    x, y, z = p
    d1 = math.sqrt(x * x + y * y + z * z)
    d2 = math.sqrt(x * x + y * y + (xi * d1 + z) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + z)
    return np.array([fx * x / den + cx, fy * y / den + cy])


def test_matches_the_published_projection(ds_camera, points_in_view):
    pts = points_in_view(ds_camera, 50, seed=31)
    uv, valid = ds_camera.project(pts)
    assert valid.all()
    expected = np.array([_paper_projection(p, *ds_camera.params) for p in pts])
    np.testing.assert_allclose(uv, expected, atol=1e-9)


def test_zero_xi_and_alpha_is_a_pinhole(pixels_in_image):
    ds = DoubleSphereCamera.from_intrinsics(640, 480, 500, 520, 330, 235, xi=0.0, alpha=0.0)
    pinhole = PinholeCamera.from_intrinsics(640, 480, 500, 520, 330, 235)
    pts = np.random.default_rng(32).uniform([-1, -1, 0.5], [1, 1, 5], size=(100, 3))
    np.testing.assert_allclose(ds.project(pts)[0], pinhole.project(pts)[0], atol=1e-9)
    np.testing.assert_allclose(ds.project_jacobian(pts), pinhole.project_jacobian(pts), atol=1e-9)
    uv = pixels_in_image(ds, 50, seed=33)
    np.testing.assert_allclose(ds.unproject(uv), pinhole.unproject(uv), atol=1e-12)


def test_parameter_names_and_order():
    cam = DoubleSphereCamera.from_intrinsics(640, 480, 300, 301, 320, 240, xi=-0.2, alpha=0.6)
    assert cam.name == "double_sphere"
    assert cam.param_names == ("fx", "fy", "cx", "cy", "xi", "alpha")
    assert cam.param("xi") == -0.2 and cam.param("alpha") == 0.6


# ---------------------------------------------------------------------------- parameter checks
@pytest.mark.parametrize("alpha", [-0.01, 1.01])
def test_alpha_outside_zero_one_raises(alpha):
    with pytest.raises(InputError, match=rf"double_sphere camera: alpha must be in \[0, 1\], got {alpha}"):
        DoubleSphereCamera.from_intrinsics(640, 480, 300, 300, 320, 240, xi=0.0, alpha=alpha)


@pytest.mark.parametrize("alpha", [0.0, 0.5, 1.0])
def test_alpha_bounds_are_accepted(alpha, pixels_in_image):
    # image radius 0.67 in normalised units: inside alpha = 1's disc r < 1
    cam = DoubleSphereCamera.from_intrinsics(640, 480, 600, 600, 320, 240, xi=-0.1, alpha=alpha)
    uv = pixels_in_image(cam, 50, seed=34)
    back, valid = cam.project(cam.unproject(uv))
    assert valid.all()
    np.testing.assert_allclose(back, uv, atol=1e-6)


@pytest.mark.parametrize("xi", [-1.0, -1.5])
def test_xi_at_or_below_minus_one_raises(xi):
    with pytest.raises(InputError, match=rf"xi must be > -1 .*got {xi}"):
        DoubleSphereCamera.from_intrinsics(640, 480, 300, 300, 320, 240, xi=xi, alpha=0.5)


def test_focal_lengths_must_be_positive():
    with pytest.raises(InputError, match="double_sphere camera: fx and fy must be > 0"):
        DoubleSphereCamera.from_intrinsics(640, 480, -300, 300, 320, 240)


# ---------------------------------------------------------------------------- domain
def _radius_by_angle(cam: DoubleSphereCamera, angles_deg: np.ndarray) -> np.ndarray:
    a = np.radians(angles_deg)
    uv, _ = cam.project(np.column_stack([np.sin(a), np.zeros_like(a), np.cos(a)]))
    return uv[:, 0] - cam.param("cx")


def test_paper_bound_is_enforced():
    cam = DoubleSphereCamera.from_intrinsics(4000, 4000, 160, 160, 1999.5, 1999.5, xi=-0.5, alpha=0.7)
    limit = math.degrees(math.acos(-cam.w2))  # z / d1 > -w2
    assert limit == pytest.approx(85.48, abs=0.01)
    r = _radius_by_angle(cam, np.array([limit - 0.05, limit + 0.05]))
    assert np.isfinite(r[0]) and np.isnan(r[1])


def test_fold_back_beyond_the_paper_bound_is_invalid():
    # the image radius peaks at ~43 deg off axis, yet z > -w2 d1 allows ~54 deg
    cam = DoubleSphereCamera.from_intrinsics(
        4000, 4000, 300, 300, 1999.5, 1999.5, xi=-0.745, alpha=0.984
    )
    assert math.degrees(math.acos(-cam.w2)) > 53.0
    angles = np.linspace(0.0, 60.0, 601)
    r = _radius_by_angle(cam, angles)
    ok = np.isfinite(r)
    assert ok[0] and 40.0 < angles[ok].max() < 45.0  # one cone around the axis ...
    assert np.all(ok[: ok.sum()])
    assert np.all(np.diff(r[ok]) > 0)  # ... on which the radius increases: one-to-one
    # pixels beyond the image circle unproject to NaN
    rays = cam.unproject(np.array([[1999.5 + r[ok].max() * 1.001, 1999.5]]))
    assert np.isnan(rays).all()


def test_unproject_outside_the_alpha_disc_is_nan():
    cam = DoubleSphereCamera.from_intrinsics(4000, 4000, 100, 100, 1999.5, 1999.5, xi=0.2, alpha=0.8)
    r_max = 1.0 / math.sqrt(2 * 0.8 - 1)  # normalised radius of the disc
    uv = np.array([[1999.5 + 100 * r_max * 0.99, 1999.5], [1999.5 + 100 * r_max * 1.01, 1999.5]])
    rays = cam.unproject(uv)
    assert np.isnan(rays[1]).all()
    if np.isfinite(rays[0]).all():  # inside the disc but maybe behind: then NaN as well
        back, _ = cam.project(rays[:1])
        np.testing.assert_allclose(back, uv[:1], atol=1e-6)


def test_random_parameters_round_trip():
    rng = np.random.default_rng(35)
    for _ in range(300):
        xi, alpha = rng.uniform(-0.95, 1.5), rng.uniform(0.0, 1.0)
        cam = DoubleSphereCamera.from_intrinsics(
            1000, 1000, *rng.uniform(100, 500, 2), 499.5, 499.5, xi=xi, alpha=alpha
        )
        # pixels -> rays -> pixels wherever a ray exists
        uv = rng.uniform(-2000, 3000, size=(300, 2))
        rays = cam.unproject(uv)
        ok = np.isfinite(rays).all(axis=1)
        back, _ = cam.project(rays[ok] * 2.0)
        np.testing.assert_allclose(back, uv[ok], atol=1e-6)
        # points in the domain -> pixels -> the same rays (the projection is one-to-one)
        pts = rng.normal(size=(300, 3))
        uv, _ = cam.project(pts)
        ok = np.isfinite(uv).all(axis=1)
        rays = cam.unproject(uv[ok])
        expected = pts[ok] / np.linalg.norm(pts[ok], axis=1, keepdims=True)
        np.testing.assert_allclose(rays, expected, atol=1e-7)
