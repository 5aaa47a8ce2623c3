"""The contract every camera model honours, run on the cases of every model.

The cases and the ``camera`` fixture that runs a test once per case live in ``conftest.py``
in this directory; a new model adds its cases to ``CASES`` there. Every test below that takes
``camera`` runs for every case: round trips, Jacobians against central finite differences,
the validity mask (image border, behind the camera, non-finite input), immutability
(``with_params``, read-only params, inputs untouched), shapes and errors, and - for models
with an OpenCV plumb-bob equivalent - agreement with cv2.projectPoints (the test is skipped
for the other models). The model modules test what is particular to each model.
"""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sensors.camera import CAMERA_MODELS, CameraModel, make_camera


# ---------------------------------------------------------------------------- registry
def test_every_registered_model_has_a_contract_case(camera_cases):
    covered = {factory().name for _, factory in camera_cases}
    assert covered == set(CAMERA_MODELS)


def test_make_camera_by_name(camera):
    again = make_camera(camera.name, camera.width, camera.height, camera.params)
    assert again == camera and type(again) is type(camera)


def test_make_camera_unknown_name():
    with pytest.raises(InputError, match="unknown camera model 'fisheye42'"):
        make_camera("fisheye42", 10, 10, np.zeros(4))


# ---------------------------------------------------------------------------- round trips
def test_pixel_unproject_project_round_trip(camera, pixels_in_image):
    uv = pixels_in_image(camera, 500, seed=1)
    rays = camera.unproject(uv)
    assert rays.shape == (500, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    for depth in (0.3, 4.0, 50.0):
        back, valid = camera.project(rays * depth)
        assert valid.all()
        np.testing.assert_allclose(back, uv, atol=1e-6)


def test_point_project_unproject_round_trip(camera):
    rng = np.random.default_rng(2)
    pts = rng.uniform([-20, -15, 0.2], [20, 15, 30], size=(2000, 3))
    uv, valid = camera.project(pts)
    assert valid.sum() > 100  # the sample reaches into the image
    rays = camera.unproject(uv[valid])
    expected = pts[valid] / np.linalg.norm(pts[valid], axis=1, keepdims=True)
    np.testing.assert_allclose(rays, expected, atol=1e-9)


def test_rays_point_forward(camera, pixels_in_image):
    rays = camera.unproject(pixels_in_image(camera, 200, seed=3))
    assert np.all(rays[:, 2] > 0)


def test_principal_ray_near_principal_point(camera):
    if "cx" not in camera.param_names:
        pytest.skip("model has no principal point parameters")
    uv, valid = camera.project(np.array([[0.0, 0.0, 1.0]]))
    assert valid[0]
    np.testing.assert_allclose(uv[0], [camera.param("cx"), camera.param("cy")], atol=1e-12)


# ---------------------------------------------------------------------------- Jacobians
def _central_difference(f, x: np.ndarray, h: float) -> np.ndarray:
    cols = []
    for j in range(x.size):
        dx = np.zeros_like(x)
        dx[j] = h
        cols.append((f(x + dx) - f(x - dx)) / (2 * h))
    return np.stack(cols, axis=-1)


def test_project_jacobian_matches_finite_differences(camera, points_in_view):
    pts = points_in_view(camera, 40, seed=4)
    J = camera.project_jacobian(pts)
    assert J.shape == (40, 2, 3)
    for i, p in enumerate(pts):
        h = 1e-6 * max(1.0, np.linalg.norm(p))
        num = _central_difference(lambda x: camera.project(x[None])[0][0], p, h)
        np.testing.assert_allclose(J[i], num, rtol=1e-5, atol=1e-4)


def test_params_jacobian_matches_finite_differences(camera, points_in_view):
    pts = points_in_view(camera, 40, seed=5)
    J = camera.params_jacobian(pts)
    assert J.shape == (40, 2, camera.num_params)
    p0 = camera.params

    def f(params: np.ndarray) -> np.ndarray:
        return camera.with_params(params).project(pts)[0]

    num = _central_difference(f, np.array(p0), 1e-6)
    np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-4)


def test_jacobians_are_nan_behind_the_camera(camera):
    pts = np.array([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0]])
    assert np.isnan(camera.project_jacobian(pts)).all()
    assert np.isnan(camera.params_jacobian(pts)).all()


# ---------------------------------------------------------------------------- validity mask
def _point_at_pixel(camera: CameraModel, u: float, v: float, depth: float = 3.0) -> np.ndarray:
    ray = camera.unproject(np.array([[u, v]]))[0]
    assert np.all(np.isfinite(ray)), (u, v)
    return ray * depth


@pytest.mark.parametrize("inside", [True, False])
def test_validity_at_the_image_border(camera, inside):
    w, h = camera.width, camera.height
    d = -0.1 if inside else 0.1  # 0.1 px inside / outside the border
    border_pixels = [
        (-0.5 - d, h / 2),
        (w - 0.5 + d, h / 2),
        (w / 2, -0.5 - d),
        (w / 2, h - 0.5 + d),
        (-0.5 - d, -0.5 - d),
        (w - 0.5 + d, h - 0.5 + d),
    ]
    pts = np.array([_point_at_pixel(camera, u, v) for u, v in border_pixels])
    uv, valid = camera.project(pts)
    np.testing.assert_allclose(uv, border_pixels, atol=1e-6)
    assert valid.tolist() == [inside] * len(border_pixels)


def test_points_behind_or_on_the_camera_are_invalid_without_raising(camera):
    pts = np.array(
        [
            [0.0, 0.0, -1.0],  # straight behind
            [0.1, -0.2, -5.0],
            [0.0, 0.0, 0.0],  # the centre of projection
            [1.0, 1.0, 0.0],  # on the camera plane
            [0.0, 0.0, 1e-9],  # numerically on the plane
            [0.0, 0.0, 2.0],  # one good point
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero or invalid-value warnings either
        uv, valid = camera.project(pts)
    assert valid.tolist() == [False] * 5 + [True]
    assert uv.shape == (6, 2)


def test_non_finite_points_are_invalid(camera):
    pts = np.array([[np.nan, 0.0, 1.0], [0.0, np.inf, 2.0], [0.0, 0.0, 1.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, valid = camera.project(pts)
        rays = camera.unproject(np.array([[np.nan, 1.0], [1.0, 2.0]]))
    assert valid.tolist() == [False, False, True]
    assert np.isnan(rays[0]).all() and np.isfinite(rays[1]).all()


def test_far_off_axis_points_are_invalid(camera):
    # 89 degrees off the optical axis: outside every model's image here
    pts = np.array([[np.tan(np.radians(89.0)), 0.0, 1.0], [0.0, -np.tan(np.radians(89.0)), 1.0]])
    _, valid = camera.project(pts)
    assert not valid.any()


# ---------------------------------------------------------------------------- immutability
def test_with_params_returns_a_new_model_and_leaves_the_original(camera):
    before = np.array(camera.params)
    new_params = camera.params * 1.01
    other = camera.with_params(new_params)
    assert other is not camera and type(other) is type(camera)
    assert other.size_wh == camera.size_wh
    np.testing.assert_array_equal(camera.params, before)
    np.testing.assert_array_equal(other.params, new_params)
    assert other != camera
    new_params[0] = 123.0  # the caller's array stays theirs
    assert other.params[0] != 123.0


def test_params_are_read_only(camera):
    with pytest.raises(ValueError):
        camera.params[0] = 1.0
    with pytest.raises(AttributeError):
        camera.width = 3  # type: ignore[misc]


def test_inputs_are_never_mutated(camera, points_in_view, pixels_in_image):
    pts = points_in_view(camera, 30, seed=6)
    pts[0] = [0.0, 0.0, -1.0]
    uv = pixels_in_image(camera, 30, seed=7)
    pts_copy, uv_copy = pts.copy(), uv.copy()
    camera.project(pts)
    camera.project_jacobian(pts)
    camera.params_jacobian(pts)
    camera.unproject(uv)
    np.testing.assert_array_equal(pts, pts_copy)
    np.testing.assert_array_equal(uv, uv_copy)
    # read-only inputs are accepted too
    pts.setflags(write=False)
    uv.setflags(write=False)
    camera.project(pts)
    camera.unproject(uv)


def test_equality_hash_and_pickle(camera):
    twin = camera.with_params(np.array(camera.params))
    assert twin == camera and hash(twin) == hash(camera)
    assert pickle.loads(pickle.dumps(camera)) == camera
    assert camera.name in repr(camera) or type(camera).__name__ in repr(camera)


# ---------------------------------------------------------------------------- shapes, errors
def test_shapes_single_and_empty(camera):
    uv, valid = camera.project(np.array([0.1, 0.0, 2.0]))
    assert uv.shape == (1, 2) and valid.shape == (1,) and valid.dtype == bool
    uv, valid = camera.project(np.zeros((0, 3)))
    assert uv.shape == (0, 2) and valid.shape == (0,)
    assert camera.unproject(np.zeros((0, 2))).shape == (0, 3)
    assert camera.project_jacobian(np.zeros((0, 3))).shape == (0, 2, 3)
    assert camera.params_jacobian(np.zeros((0, 3))).shape == (0, 2, camera.num_params)


def test_bad_shapes_raise_input_error(camera):
    msg = r"expected an \(N, 3\) array of points, got shape \(4, 2\)"
    with pytest.raises(InputError, match=msg):
        camera.project(np.zeros((4, 2)))
    with pytest.raises(InputError, match=r"expected an \(N, 2\) array of pixels"):
        camera.unproject(np.zeros((4, 3)))


def test_wrong_parameter_count_raises(camera):
    with pytest.raises(InputError, match=f"expected {camera.num_params} parameters"):
        camera.with_params(np.ones(camera.num_params + 1))


def test_non_finite_parameters_raise(camera):
    p = np.array(camera.params)
    p[0] = np.nan
    with pytest.raises(InputError, match="must be finite"):
        camera.with_params(p)


@pytest.mark.parametrize("size", [(0, 10), (10, -1), (10.5, 10), (True, 10)])
def test_bad_image_size_raises(camera, size):
    with pytest.raises(InputError, match="must be a positive integer"):
        type(camera)(size[0], size[1], camera.params)


# ---------------------------------------------------------------------------- OpenCV
def test_matches_opencv_project_points(camera):
    cv2 = pytest.importorskip("cv2")
    if not hasattr(camera, "dist_coeffs"):
        pytest.skip(f"{camera.name} has no OpenCV plumb-bob equivalent")
    rng = np.random.default_rng(8)
    pts = rng.uniform([-2, -1.5, 0.5], [2, 1.5, 10], size=(1000, 3))
    uv, valid = camera.project(pts)
    K, dist = camera.camera_matrix, camera.dist_coeffs
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    ref = ref.reshape(-1, 2)
    domain = np.isfinite(uv).all(axis=1)
    assert valid.sum() > 300
    np.testing.assert_allclose(uv[domain], ref[domain], atol=1e-6)
