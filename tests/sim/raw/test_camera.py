from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.recording import ImageFrame, StereoFrame
from rigcal.sim.raw import PinholeRadtanCamera, Scene, StereoCamera, render, render_stereo

from .conftest import camera_pose, facing_board

PINHOLE = PinholeRadtanCamera(320, 240, 300.0, 300.0, 159.5, 119.5)
DISTORTED = PinholeRadtanCamera(
    320, 240, 300.0, 300.0, 161.0, 118.0, k1=-0.25, k2=0.08, p1=0.001, p2=-0.0015, k3=-0.01
)


def _patch_mean(img: np.ndarray, uv: np.ndarray, half: int = 1) -> float:
    c, r = int(round(uv[0])), int(round(uv[1]))
    return float(img[r - half : r + half + 1, c - half : c + half + 1].mean())


def _board_points(scene: Scene, ab: np.ndarray) -> np.ndarray:
    T = scene.T_world_board
    pts = np.column_stack([ab, np.zeros(len(ab))])
    return pts @ T[:3, :3].T + T[:3, 3]


def _to_camera(T_world_camera: np.ndarray, pts_world: np.ndarray) -> np.ndarray:
    T = np.linalg.inv(T_world_camera)
    return pts_world @ T[:3, :3].T + T[:3, 3]


@pytest.mark.parametrize("camera", [PINHOLE, DISTORTED])
def test_project_unproject_round_trip(camera):
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.uniform(0, 319, 200), rng.uniform(0, 239, 200)])
    rays = camera.unproject(uv)
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)
    back, valid = camera.project(rays * 3.0)
    assert np.all(valid)
    assert np.allclose(back, uv, atol=1e-6)


def test_project_marks_points_behind_and_outside(small_camera):
    pts = np.array([[0.0, 0.0, -1.0], [10.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    uv, valid = small_camera.project(pts)
    assert valid.tolist() == [False, False, True]
    assert np.all(np.isnan(uv[0]))
    assert np.allclose(uv[2], [159.5, 119.5])


@pytest.mark.parametrize("camera", [PINHOLE, DISTORTED])
def test_holes_appear_where_the_camera_projects_them(camera):
    scene = Scene(facing_board(3.0, 1.0, lateral_m=0.2))
    T_wc = camera_pose(1.1)
    frame = render(camera, T_wc, scene, np.random.default_rng(0), t_ns=42, sensor="cam")
    assert isinstance(frame, ImageFrame) and frame.image.shape == (240, 320)
    assert frame.image.dtype == np.uint8 and frame.t_ns == 42 and frame.sensor == "cam"
    img = frame.image
    holes, ok = camera.project(_to_camera(T_wc, scene.hole_centres_world()))
    assert np.all(ok)
    plate_ab = np.array(
        [[0.0, 0.12], [0.0, -0.12], [0.12, 0.0], [-0.12, 0.0], [0.0, 0.5], [0.3, 0.8]]
    )
    plate_uv, ok = camera.project(_to_camera(T_wc, _board_points(scene, plate_ab)))
    assert np.all(ok)
    hole_grey = [_patch_mean(img, uv) for uv in holes]
    plate_grey = [_patch_mean(img, uv) for uv in plate_uv]
    assert max(hole_grey) < 170 and min(plate_grey) > 195
    assert np.mean(plate_grey) == pytest.approx(220, abs=12)


def test_hole_edges_are_anti_aliased(small_camera):
    scene = Scene(facing_board(3.0, 1.0))
    T_wc = camera_pose(1.0)
    img = render(small_camera, T_wc, scene, np.random.default_rng(0), noise_sigma=0.0).image
    hard = render(
        small_camera, T_wc, scene, np.random.default_rng(0), noise_sigma=0.0, supersample=1
    ).image
    holes, _ = small_camera.project(_to_camera(T_wc, scene.hole_centres_world()))
    c, r = np.round(holes[0]).astype(int)
    win = (slice(r - 12, r + 13), slice(c - 12, c + 13))
    # mixed pixels along the rim exist only with supersampling
    def mixed(a):
        return int(np.sum((a[win] > 150) & (a[win] < 195)))
    assert mixed(img) > mixed(hard)


def test_texture_and_noise(small_camera):
    scene = Scene(facing_board(3.0, 1.0))
    T_wc = camera_pose(1.0)
    a = render(small_camera, T_wc, scene, np.random.default_rng(3)).image
    b = render(small_camera, T_wc, scene, np.random.default_rng(3)).image
    c = render(small_camera, T_wc, scene, np.random.default_rng(4)).image
    clean = render(small_camera, T_wc, scene, np.random.default_rng(4), noise_sigma=0.0).image
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    noise = c.astype(float) - clean.astype(float)
    assert np.std(noise) == pytest.approx(2.0, rel=0.15)
    wall_patch = clean[5:40, 5:60].astype(float)  # upper-left: wall
    assert 60 < wall_patch.mean() < 140 and wall_patch.std() > 8  # textured
    other_seed = render(small_camera, T_wc, Scene(facing_board(3.0, 1.0), texture_seed=9),
                        np.random.default_rng(4), noise_sigma=0.0).image
    assert not np.array_equal(clean, other_seed)


def test_bgr_output(small_camera, board_scene):
    frame = render(small_camera, camera_pose(), board_scene, np.random.default_rng(0), bgr=True)
    assert frame.image.shape == (240, 320, 3)
    assert np.array_equal(frame.image[..., 0], frame.image[..., 2])


def _stereo_scene(depth: float) -> Scene:
    return Scene(facing_board(depth, 1.0))


def test_stereo_direct_shift_equals_fx_b_over_z(small_camera):
    depth, baseline = 3.0, 0.12
    stereo = StereoCamera(small_camera, baseline)
    scene = _stereo_scene(depth)
    T_wc = camera_pose(1.3)  # optical axis 0.3 m above the hole centre: plate around the centre
    frame = render_stereo(stereo, T_wc, scene, np.random.default_rng(0), t_ns=9, sensor="stereo1")
    assert isinstance(frame, StereoFrame) and frame.left.shape == (240, 320)
    expected = stereo.disparity_px(depth)
    assert expected == pytest.approx(12.0)
    L, R = frame.left.astype(float), frame.right.astype(float)
    # a plate patch well inside the plate, away from the holes (board y 0.3 .. 0.6)
    uv, _ = small_camera.project(_to_camera(T_wc, _board_points(scene, np.array([[0.0, 0.45]]))))
    c, r = (int(round(x)) for x in uv[0])
    patch = L[r - 10 : r + 11, c - 10 : c + 11]
    shifts = np.arange(0, 25)
    ssd = np.array(
        [np.sum((R[r - 10 : r + 11, c - 10 - d : c + 11 - d] - patch) ** 2) for d in shifts]
    )
    k = int(np.argmin(ssd))
    y0, y1, y2 = ssd[k - 1], ssd[k], ssd[k + 1]
    sub = k + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    assert sub == pytest.approx(expected, abs=0.3)


def test_stereo_sgbm_disparity_on_the_plate():
    import cv2

    camera = PinholeRadtanCamera(480, 360, 450.0, 450.0, 239.5, 179.5)
    depth, baseline = 3.5, 0.12
    stereo = StereoCamera(camera, baseline)
    scene = _stereo_scene(depth)
    T_wc = camera_pose(1.3)
    frame = render_stereo(stereo, T_wc, scene, np.random.default_rng(1))
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=32, blockSize=7, P1=8 * 49, P2=32 * 49, uniquenessRatio=5
    )
    disp = sgbm.compute(frame.left, frame.right).astype(np.float32) / 16.0
    # plate interior above the holes: board x in [-0.35, 0.35], y in [0.3, 0.9]
    corners = _board_points(scene, np.array([[-0.35, 0.9], [0.35, 0.3]]))
    (u0, v0), (u1, v1) = camera.project(_to_camera(T_wc, corners))[0]
    region = disp[int(v0) : int(v1), int(u0) : int(u1)]
    valid = region[region > 0]
    assert valid.size > 0.8 * region.size
    assert float(np.median(valid)) == pytest.approx(stereo.disparity_px(depth), abs=0.3)


def test_stereo_is_deterministic_and_pair_differs(small_camera, board_scene):
    st = StereoCamera(small_camera, 0.12)
    a = render_stereo(st, camera_pose(), board_scene, np.random.default_rng(5))
    b = render_stereo(st, camera_pose(), board_scene, np.random.default_rng(5))
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert not np.array_equal(a.left, a.right)


def test_full_size_render_runs():
    camera = PinholeRadtanCamera(1936, 1216, 1400.0, 1400.0, 967.5, 607.5)
    scene = Scene(facing_board(5.0, 1.0))
    frame = render(camera, camera_pose(1.3), scene, np.random.default_rng(0))
    assert frame.size_wh == (1936, 1216)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"width": 0}, "width must be a positive integer"),
        ({"fx": -1.0}, "fx must be a positive number"),
        ({"k1": float("nan")}, "k1 must be finite"),
    ],
)
def test_camera_validation(kwargs, match):
    args = {"width": 10, "height": 10, "fx": 10.0, "fy": 10.0, "cx": 5.0, "cy": 5.0, **kwargs}
    with pytest.raises(InputError, match=match):
        PinholeRadtanCamera(**args)


def test_stereo_and_render_validation(small_camera, board_scene):
    with pytest.raises(InputError, match="a rectified pair has no distortion"):
        StereoCamera(DISTORTED, 0.12)
    with pytest.raises(InputError, match="baseline_m must be > 0"):
        StereoCamera(small_camera, 0.0)
    with pytest.raises(InputError, match="supersample must be an integer"):
        render(small_camera, camera_pose(), board_scene, np.random.default_rng(0), supersample=0)
    with pytest.raises(InputError, match="scene must be a Scene"):
        render(small_camera, camera_pose(), None, np.random.default_rng(0))
    with pytest.raises(InputError, match="expected a StereoCamera"):
        render_stereo(small_camera, camera_pose(), board_scene, np.random.default_rng(0))
    with pytest.raises(InputError, match="needs integer width and height"):
        render(object(), camera_pose(), board_scene, np.random.default_rng(0))


class _ForeignCamera:
    """A duck-typed camera model (as ``rigcal.sensors.camera`` may provide): unhashable,
    ``unproject`` returns (rays, valid)."""

    def __init__(self, inner: PinholeRadtanCamera) -> None:
        self.inner = inner
        self.width, self.height = inner.width, inner.height

    __hash__ = None  # type: ignore[assignment]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _ForeignCamera) and other.inner == self.inner

    def unproject(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rays = self.inner.unproject(uv)
        return rays * 2.0, np.ones(len(uv), dtype=bool)


def test_any_camera_model_with_unproject_renders():
    scene = Scene(facing_board(3.0, 1.0))
    ours = render(DISTORTED, camera_pose(), scene, np.random.default_rng(0), noise_sigma=0.0)
    theirs = render(
        _ForeignCamera(DISTORTED), camera_pose(), scene, np.random.default_rng(0), noise_sigma=0.0
    )
    diff = np.abs(ours.image.astype(int) - theirs.image.astype(int))
    assert diff.max() <= 1 and diff.mean() < 0.01


def test_stereo_pair_feeds_the_stereo_point_cloud():
    stereo_mod = pytest.importorskip("rigcal.sensors.stereo")
    camera = PinholeRadtanCamera(480, 360, 450.0, 450.0, 239.5, 179.5)
    stereo = StereoCamera(camera, 0.12)
    scene = Scene(facing_board(3.5, 1.0))
    T_wc = camera_pose(1.3)
    frame = render_stereo(stereo, T_wc, scene, np.random.default_rng(2))
    params = stereo_mod.SgbmParams(num_disparities=32)
    cloud = stereo_mod.point_cloud_from_pair(frame, stereo.stereo_rig(), params)
    pts = cloud.points_xyz.reshape(360, 480, 3)
    corners = _board_points(scene, np.array([[-0.35, 0.9], [0.35, 0.3]]))
    (u0, v0), (u1, v1) = camera.project(_to_camera(T_wc, corners))[0]
    z = pts[int(v0) : int(v1), int(u0) : int(u1), 2]
    assert np.nanmedian(z) == pytest.approx(3.5, abs=0.1)
