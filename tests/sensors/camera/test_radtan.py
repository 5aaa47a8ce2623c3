"""Radtan-specific behaviour: OpenCV interop, undistortion, the fold-back limit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sensors.camera import PinholeCamera, RadtanCamera
from rigcal.sensors.camera.radtan import monotonic_radius

PRIUS_K = np.array([[1419.435287, 0.0, 948.748187], [0.0, 1442.298159, 621.179140], [0, 0, 1.0]])
PRIUS_D = np.array([-0.175243, 0.158967, 0.003024, -0.002257, -0.062404])


@pytest.fixture
def prius() -> RadtanCamera:
    return RadtanCamera.from_opencv(1936, 1216, PRIUS_K, PRIUS_D)


def test_opencv_properties_round_trip(prius):
    np.testing.assert_array_equal(prius.camera_matrix, PRIUS_K)
    np.testing.assert_array_equal(prius.dist_coeffs, PRIUS_D)
    assert prius.param("k3") == PRIUS_D[4]
    assert prius.name == "radtan"


def test_k3_is_optional():
    cam = RadtanCamera.from_opencv(1936, 1216, PRIUS_K, PRIUS_D[:4])
    assert cam.param("k3") == 0.0
    assert RadtanCamera.from_intrinsics(10, 10, 5, 5, 5, 5, k1=0.1).param("k3") == 0.0


def test_matches_project_points_with_a_pose(prius):
    rng = np.random.default_rng(11)
    pts_board = rng.uniform(-0.5, 0.5, size=(200, 3))
    rvec, tvec = np.array([0.1, -0.3, 0.05]), np.array([0.2, -0.1, 4.0])
    ref, _ = cv2.projectPoints(pts_board, rvec, tvec, PRIUS_K, PRIUS_D)
    R, _ = cv2.Rodrigues(rvec)
    uv, valid = prius.project(pts_board @ R.T + tvec)
    assert valid.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)


def test_undistort_points_matches_opencv(prius):
    rng = np.random.default_rng(12)
    uv = np.column_stack([rng.uniform(0, 1935, 300), rng.uniform(0, 1215, 300)])
    xn = prius.undistort_points(uv)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), PRIUS_K, PRIUS_D, None, None, None, criteria)
    np.testing.assert_allclose(xn, ref.reshape(-1, 2), atol=1e-8)
    ideal = prius.undistort_points(uv, pixels=True)
    np.testing.assert_allclose(ideal, xn * [PRIUS_K[0, 0], PRIUS_K[1, 1]] + PRIUS_K[:2, 2])


def test_zero_distortion_equals_pinhole():
    radtan = RadtanCamera.from_intrinsics(640, 480, 500, 510, 320, 240)
    pinhole = PinholeCamera.from_intrinsics(640, 480, 500, 510, 320, 240)
    pts = np.random.default_rng(13).uniform([-1, -1, 1], [1, 1, 5], size=(50, 3))
    np.testing.assert_allclose(radtan.project(pts)[0], pinhole.project(pts)[0], atol=1e-12)
    np.testing.assert_allclose(
        radtan.params_jacobian(pts)[:, :, :4], pinhole.params_jacobian(pts), atol=1e-12
    )


def test_fold_back_region_is_invalid():
    cam = RadtanCamera.from_intrinsics(640, 480, 300, 300, 320, 240, k1=-0.4)
    r_max = cam.max_radius
    assert r_max == pytest.approx(np.sqrt(1 / 1.2))  # d/dr r (1 - 0.4 r^2) = 0
    # beyond the fold the polynomial maps back toward the image centre; it must not count
    far = np.array([[3.0 * r_max, 0.0, 1.0]])
    uv, valid = cam.project(far)
    assert not valid[0] and np.isnan(uv).all()
    assert monotonic_radius(0.0, 0.0, 0.0) == np.inf


def test_unproject_beyond_the_distortion_range_is_nan():
    cam = RadtanCamera.from_intrinsics(640, 480, 300, 300, 320, 240, k1=-0.4)
    # the largest distorted radius is r_max * (1 - 0.4 r_max^2) ~ 0.61 -> 182 px from centre
    rays = cam.unproject(np.array([[320 + 300.0, 240.0], [320 + 100.0, 240.0]]))
    assert np.isnan(rays[0]).all() and np.isfinite(rays[1]).all()


@pytest.mark.parametrize(
    "K, d, match",
    [
        (np.eye(2), PRIUS_D, "must be 3x3"),
        (PRIUS_K, PRIUS_D[:3], "expected 4 or 5 distortion coefficients"),
        (PRIUS_K + np.array([[0, 1.0, 0], [0, 0, 0], [0, 0, 0]]), PRIUS_D, "must be"),
    ],
)
def test_from_opencv_rejects(K, d, match):
    with pytest.raises(InputError, match=match):
        RadtanCamera.from_opencv(1936, 1216, K, d)


def test_negative_focal_length_rejected():
    with pytest.raises(InputError, match="fx and fy must be > 0"):
        RadtanCamera.from_intrinsics(10, 10, -5, 5, 5, 5)
    with pytest.raises(InputError, match="fx and fy must be > 0"):
        PinholeCamera.from_intrinsics(10, 10, 5, 0, 5, 5)
