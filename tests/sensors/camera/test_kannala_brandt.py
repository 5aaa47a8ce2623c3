"""Kannala-Brandt: agreement with cv2.fisheye, OpenCV interop, the fold-back limit.

The Kannala-Brandt cases are defined in ``conftest.py`` (``KB_CASES``). The contract suite in
``test_contract.py`` runs on them along with the cases of the other models, so only what is
particular to this model is tested here. The ``kb_camera`` fixture from ``conftest.py`` runs
the case-based tests below once per Kannala-Brandt case. The contract's cv2.projectPoints
comparison is skipped for this model, which has no plumb-bob distortion coefficients; the
cv2.fisheye tests below do that job instead.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sensors.camera.kannala_brandt import (
    KannalaBrandtCamera,
    monotonic_angle,
    theta_d,
)
from rigcal.sensors.camera.registry import camera_from_params


def test_camera_from_params(kb_camera):
    for name in ("kannala_brandt", "equidistant", "pinhole-equi", "KANNALABRANDT"):
        again = camera_from_params(name, kb_camera.width, kb_camera.height, kb_camera.params)
        assert again == kb_camera and type(again) is KannalaBrandtCamera


# ---------------------------------------------------------------------------- OpenCV fisheye
def test_matches_cv2_fisheye_project_points(kb_camera):
    rng = np.random.default_rng(21)
    pts = rng.uniform([-3, -3, 0.05], [3, 3, 8], size=(2000, 3))
    uv, valid = kb_camera.project(pts)
    ref, _ = cv2.fisheye.projectPoints(
        pts.reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        kb_camera.camera_matrix,
        kb_camera.fisheye_coeffs,
    )
    ref = ref.reshape(-1, 2)
    domain = np.isfinite(uv).all(axis=1)
    assert valid.sum() > 300 and domain.sum() > 1000
    np.testing.assert_allclose(uv[domain], ref[domain], atol=1e-6)


def test_matches_cv2_fisheye_with_a_pose(kb_camera):
    rng = np.random.default_rng(22)
    pts_board = rng.uniform(-0.4, 0.4, size=(300, 3))
    rvec, tvec = np.array([0.2, -0.1, 0.3]), np.array([0.1, 0.05, 1.5])
    ref, _ = cv2.fisheye.projectPoints(
        pts_board.reshape(-1, 1, 3), rvec, tvec, kb_camera.camera_matrix, kb_camera.fisheye_coeffs
    )
    R, _ = cv2.Rodrigues(rvec)
    uv, valid = kb_camera.project(pts_board @ R.T + tvec)
    assert np.isfinite(uv).all() and valid.any()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)


def test_unproject_matches_cv2_fisheye_undistort_points(kb_camera, pixels_in_image):
    uv = pixels_in_image(kb_camera, 300, seed=23)
    rays = kb_camera.unproject(uv)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.fisheye.undistortPoints(
        uv.reshape(-1, 1, 2), kb_camera.camera_matrix, kb_camera.fisheye_coeffs, criteria=criteria
    ).reshape(-1, 2)
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:3], ref, rtol=1e-7, atol=1e-7)


def test_from_opencv_round_trip():
    K = np.array([[600.0, 0.0, 640.5], [0.0, 602.0, 480.2], [0.0, 0.0, 1.0]])
    D = np.array([-0.02, 0.01, -0.003, 0.0005])
    cam = KannalaBrandtCamera.from_opencv(1280, 960, K, D.reshape(4, 1))
    np.testing.assert_array_equal(cam.camera_matrix, K)
    np.testing.assert_array_equal(cam.fisheye_coeffs, D)
    assert cam.param("k4") == 0.0005 and cam.name == "kannala_brandt"
    # no plumb-bob dist_coeffs: the contract's cv2.projectPoints comparison must not apply
    assert not hasattr(cam, "dist_coeffs")


def test_from_opencv_rejects_bad_input():
    K = np.array([[600.0, 0.0, 640.5], [0.0, 602.0, 480.2], [0.0, 0.0, 1.0]])
    with pytest.raises(InputError, match=r"expected 4 fisheye coefficients \(k1, k2, k3, k4\), got 5"):
        KannalaBrandtCamera.from_opencv(1280, 960, K, np.zeros(5))
    with pytest.raises(InputError, match=r"camera matrix must be 3x3, got \(2, 3\)"):
        KannalaBrandtCamera.from_opencv(1280, 960, K[:2], np.zeros(4))
    skewed = K.copy()
    skewed[0, 1] = 3.0
    with pytest.raises(InputError, match="camera matrix must be"):
        KannalaBrandtCamera.from_opencv(1280, 960, skewed, np.zeros(4))


@pytest.mark.parametrize("fx, fy", [(0.0, 500.0), (500.0, -1.0)])
def test_focal_lengths_must_be_positive(fx, fy):
    with pytest.raises(InputError, match=r"kannala_brandt camera: fx and fy must be > 0"):
        KannalaBrandtCamera.from_intrinsics(640, 480, fx, fy, 320, 240)


# ---------------------------------------------------------------------------- the model
def test_no_distortion_is_the_equidistant_projection():
    cam = KannalaBrandtCamera.from_intrinsics(640, 480, 300, 310, 322, 241)
    rng = np.random.default_rng(24)
    pts = rng.uniform([-2, -2, 0.1], [2, 2, 4], size=(200, 3))
    uv, _ = cam.project(pts)
    r = np.hypot(pts[:, 0], pts[:, 1])
    theta = np.arctan2(r, pts[:, 2])
    expected = np.column_stack(
        [300 * theta * pts[:, 0] / r + 322, 310 * theta * pts[:, 1] / r + 241]
    )
    np.testing.assert_allclose(uv, expected, atol=1e-9)


def test_theta_d_helpers():
    k = np.array([0.1, -0.02, 0.003, -0.0004])
    theta = np.linspace(0.0, 1.5, 7)
    expected = theta * (1 + 0.1 * theta**2 - 0.02 * theta**4 + 0.003 * theta**6 - 0.0004 * theta**8)
    np.testing.assert_allclose(theta_d(theta, k), expected, rtol=1e-15)
    assert monotonic_angle(0.0, 0.0, 0.0, 0.0) == math.inf
    # 1 - 0.9 theta^2 = 0
    assert monotonic_angle(-0.3, 0.0, 0.0, 0.0) == pytest.approx(math.sqrt(1 / 0.9), rel=1e-12)


def test_domain_ends_where_theta_d_folds_back():
    cam = KannalaBrandtCamera.from_intrinsics(2000, 2000, 400, 400, 999.5, 999.5, k1=-0.3)
    fold = math.sqrt(1 / 0.9)
    assert cam.max_angle_rad == pytest.approx(fold, rel=1e-12)
    angles = np.array([fold - 1e-3, fold + 1e-3, fold + 0.3])
    pts = np.column_stack([np.sin(angles), np.zeros(3), np.cos(angles)])
    uv, valid = cam.project(pts)
    # beyond the fold the formula would land back inside the image: reported invalid instead
    assert valid.tolist() == [True, False, False]
    assert np.isnan(uv[1:]).all() and np.isnan(cam.project_jacobian(pts[1:])).all()
    # pixels outside the image circle theta_d(fold) cannot be unprojected
    rho_max = float(theta_d(np.array(fold), cam.params[4:]))
    uv = np.array([[999.5 + 400 * rho_max * 0.999, 999.5], [999.5 + 400 * rho_max * 1.001, 999.5]])
    rays = cam.unproject(uv)
    assert np.isfinite(rays[0]).all() and np.isnan(rays[1]).all()


def test_domain_without_fold_is_the_front_half_space():
    cam = KannalaBrandtCamera.from_intrinsics(640, 480, 300, 310, 322, 241, k1=0.05)
    assert cam.max_angle_rad == math.pi / 2
    _, valid = cam.project(np.array([[1.0, 0.0, 1e-3], [1.0, 0.0, -1e-3]]))
    assert cam._in_domain(np.array([[1.0, 0.0, 1e-3]]))[0]
    assert not valid[1]


def test_jacobians_on_and_near_the_optical_axis():
    cam = KannalaBrandtCamera.from_intrinsics(640, 480, 300, 310, 322, 241, 0.03, -0.01, 0.002, 0.0)
    pts = np.array([[0.0, 0.0, 2.0], [1e-12, -2e-12, 2.0], [1e-6, 3e-7, 0.5], [0.3, -0.2, 1.0]])
    J = cam.project_jacobian(pts)
    Jp = cam.params_jacobian(pts)
    assert np.isfinite(J).all() and np.isfinite(Jp).all()
    for i, p in enumerate(pts):
        h = 1e-6
        num = np.stack(
            [
                (cam.project((p + h * e)[None])[0][0] - cam.project((p - h * e)[None])[0][0])
                / (2 * h)
                for e in np.eye(3)
            ],
            axis=-1,
        )
        np.testing.assert_allclose(J[i], num, rtol=1e-6, atol=1e-5)
    # on the axis: d(uv)/d(x, y) = diag(fx, fy) / z, nothing depends on k
    np.testing.assert_allclose(J[0], [[150.0, 0.0, 0.0], [0.0, 155.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(Jp[0, :, 4:], 0.0, atol=1e-12)


def test_random_parameters_round_trip():
    rng = np.random.default_rng(25)
    for _ in range(200):
        k = rng.normal(0.0, [0.05, 0.02, 0.005, 0.001])
        cam = KannalaBrandtCamera.from_intrinsics(
            800, 600, *rng.uniform(200, 500, 2), *rng.uniform([350, 250], [450, 350]), *k
        )
        pts = rng.normal(size=(300, 3))
        uv, _ = cam.project(pts)
        ok = np.isfinite(uv).all(axis=1)
        assert np.all(ok == cam._in_domain(pts))
        rays = cam.unproject(uv[ok])
        expected = pts[ok] / np.linalg.norm(pts[ok], axis=1, keepdims=True)
        np.testing.assert_allclose(rays, expected, atol=1e-8)
