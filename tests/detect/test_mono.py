"""The monocular circle-board detector: the real Prius images, synthetic renders with known
poses (accuracy, the ellipse-centre bias, ordering, polarity, distractors) and every failure."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from rigcal.dataset import BoardGeometry
from rigcal.detect.mono import (
    MonoBoardFit,
    MonoDetectorConfig,
    detect_board_mono,
    fit_board_mono,
    order_corners,
)
from rigcal.detect.result import BoardDetection, DetectionFailure
from rigcal.errors import ConfigError
from rigcal.geometry.so3 import so3_exp
from rigcal.io.config.intrinsics import read_intrinsics
from rigcal.recording import ImageFrame
from rigcal.sensors.camera import RadtanCamera
from rigcal.targets.circle_board import board_centres

MONO = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tudelft_prius" / "mono"

CAM = RadtanCamera.from_intrinsics(
    1936, 1216, 1419.435287, 1442.298159, 948.748187, 621.179140,
    k1=-0.175243, k2=0.158967, p1=0.003024, p2=-0.002257, k3=-0.062404,
)
BOARD = BoardGeometry()
SIDES = [(0, 1), (2, 3), (0, 2), (1, 3)]  # TL-TR, BL-BR, TL-BL, TR-BR


# ---------------------------------------------------------------------------- rendering
def board_pose(
    distance_m: float, yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0,
    u: float | None = None, v: float | None = None, camera: RadtanCamera = CAM,
) -> np.ndarray:
    """T_camera_board: the board's centre on the ray of pixel (u, v) at ``distance_m``, facing
    the camera, then turned about its own y (yaw), x (pitch) and z (roll) axes."""
    u = camera.param("cx") if u is None else u
    v = camera.param("cy") if v is None else v
    ray = camera.unproject(np.array([[u, v]]))[0]
    R = (
        np.diag([1.0, -1.0, -1.0])  # board x right, y up, z toward the camera
        @ so3_exp(np.array([0.0, math.radians(yaw_deg), 0.0]))
        @ so3_exp(np.array([math.radians(pitch_deg), 0.0, 0.0]))
        @ so3_exp(np.array([0.0, 0.0, math.radians(roll_deg)]))
    )
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = ray * distance_m
    return T


def true_centres(T: np.ndarray, board: BoardGeometry = BOARD) -> np.ndarray:
    return board_centres(board) @ T[:3, :3].T + T[:3, 3]


def render(
    T_camera_board: np.ndarray,
    camera: RadtanCamera = CAM,
    board: BoardGeometry = BOARD,
    seed: int = 0,
    plate: int = 190,
    hole: int = 35,
    background: int = 100,
    noise: float = 2.0,
    supersample: int = 4,
    extra_ellipses: tuple[tuple[float, float, float, float, float], ...] = (),
) -> np.ndarray:
    """A grey image of the board: a textured background, the white plate (1.0 x 1.5 m, holes in
    its lower half) and the four holes filled with the exact projections of the 3D rims
    (densely sampled, projected with the radtan model), drawn ``supersample`` times finer and
    area-averaged, then blurred (sigma 0.7 px) with seeded Gaussian noise. ``extra_ellipses``
    (u, v, a, b, angle_deg) are dark distractor blobs."""
    rng = np.random.default_rng(seed)
    W, H = camera.width, camera.height
    texture = rng.normal(0.0, 25.0, (H // 64 + 2, W // 64 + 2)).astype(np.float32)
    img = np.clip(background + cv2.resize(texture, (W, H)), 0, 255).astype(np.float32)
    R, t = T_camera_board[:3, :3], T_camera_board[:3, 3]

    def project(points_board: np.ndarray) -> np.ndarray:
        uv, _ = camera.project(points_board @ R.T + t)
        return uv[np.all(np.isfinite(uv), axis=1)]

    s = np.linspace(0.0, 1.0, 400, endpoint=False)
    x0, x1, y0, y1 = -0.5, 0.5, -0.55, 0.95
    outline = np.concatenate(
        [
            np.column_stack([x0 + (x1 - x0) * s, np.full_like(s, y0)]),
            np.column_stack([np.full_like(s, x1), y0 + (y1 - y0) * s]),
            np.column_stack([x1 - (x1 - x0) * s, np.full_like(s, y1)]),
            np.column_stack([np.full_like(s, x0), y1 - (y1 - y0) * s]),
        ]
    )
    plate_uv = project(np.column_stack([outline, np.zeros(len(outline))]))
    th = np.linspace(0.0, 2.0 * np.pi, 1440, endpoint=False)
    r = board.hole_diameter_m / 2.0
    holes_uv = [
        project(c + r * np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)]))
        for c in board_centres(board)
    ]
    # draw the plate's bounding box (in the image) finely, then average it down
    bu0 = int(max(np.floor(plate_uv[:, 0].min()) - 2, 0))
    bv0 = int(max(np.floor(plate_uv[:, 1].min()) - 2, 0))
    bu1 = int(min(np.ceil(plate_uv[:, 0].max()) + 2, W))
    bv1 = int(min(np.ceil(plate_uv[:, 1].max()) + 2, H))
    ss = supersample
    patch = cv2.resize(img[bv0:bv1, bu0:bu1], ((bu1 - bu0) * ss, (bv1 - bv0) * ss),
                       interpolation=cv2.INTER_NEAREST)

    def fine(uv: np.ndarray) -> np.ndarray:  # full-res pixel -> fine pixel, 4 fractional bits
        q = ((uv - [bu0, bv0] + 0.5) * ss - 0.5) * 16
        return np.round(q).astype(np.int32)

    cv2.fillPoly(patch, [fine(plate_uv)], float(plate), shift=4)
    for uv in holes_uv:
        cv2.fillPoly(patch, [fine(uv)], float(hole), shift=4)
    img[bv0:bv1, bu0:bu1] = cv2.resize(patch, (bu1 - bu0, bv1 - bv0), interpolation=cv2.INTER_AREA)
    for u, v, a, b, ang in extra_ellipses:
        cv2.ellipse(img, ((u, v), (2 * a, 2 * b), ang), float(hole), -1, cv2.LINE_AA)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    img += rng.normal(0.0, noise, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def detect(img: np.ndarray, config: MonoDetectorConfig = MonoDetectorConfig(), **kw):
    return fit_board_mono(ImageFrame("cam", 7, img), CAM, kw.pop("board", BOARD), config)


def centre_errors(T: np.ndarray, config: MonoDetectorConfig = MonoDetectorConfig(), **render_kw):
    out = detect(render(T, **render_kw), config)
    assert isinstance(out, MonoBoardFit), out
    return np.linalg.norm(out.detection.points - true_centres(T), axis=1), out


def assert_image_order(points_cam: np.ndarray, camera=CAM) -> None:
    uv, valid = camera.project(points_cam)
    assert valid.all()
    tl, tr, bl, br = uv
    assert tl[0] < tr[0] and bl[0] < br[0], uv  # left is left
    assert tl[1] < bl[1] and tr[1] < br[1], uv  # top is above


# ---------------------------------------------------------------------------- real images
@pytest.fixture(scope="module")
def prius_camera():
    path = MONO / "intrinsics.ini"
    if not path.is_file():
        pytest.skip(f"real data not present: {path}")
    return read_intrinsics(path)


@pytest.fixture(scope="module", params=[1, 2], ids=["example_image1", "example_image2"])
def real_fit(request, prius_camera):
    path = MONO / f"example_image{request.param}.png"
    if not path.is_file():
        pytest.skip(f"real image not present: {path}")
    frame = ImageFrame("camera1", 1000 + request.param, cv2.imread(str(path), cv2.IMREAD_COLOR))
    return request.param, fit_board_mono(frame, prius_camera), prius_camera


def test_real_images_four_holes_as_a_024_m_square(real_fit):
    _, out, _ = real_fit
    assert isinstance(out, MonoBoardFit), out
    det = out.detection
    assert isinstance(det, BoardDetection) and det.points.shape == (4, 3)
    assert len(out.ellipses) == 4
    for i, j in SIDES:
        assert abs(np.linalg.norm(det.points[i] - det.points[j]) - 0.24) < 0.005
    # the independent per-hole circles agree with the square too
    assert det.quality["square_side_error_m"] < 0.005


def test_real_images_distance_reprojection_and_order(real_fit):
    n, out, camera = real_fit
    det = out.detection
    distance = float(np.linalg.norm(det.points.mean(axis=0)))
    assert 3.0 < distance < 8.0
    assert det.quality["reprojection_rms_px"] < 1.0
    assert_image_order(det.points, camera)
    # the chosen holes are where they appear in the image: ellipse centres in TL, TR, BL, BR
    c = np.array([e.centre for e in out.ellipses])
    assert c[0, 0] < c[1, 0] and c[2, 0] < c[3, 0] and c[0, 1] < c[2, 1] and c[1, 1] < c[3, 1]
    np.testing.assert_allclose(out.projected_centres_px, c, atol=2.0)
    # golden values of this implementation (loose): distances ~4.23 m and ~3.42 m
    assert distance == pytest.approx({1: 4.23, 2: 3.42}[n], abs=0.1)
    assert det.sensor == "camera1" and det.t_ns == 1000 + n


def test_real_images_holes_are_dark_and_about_15_cm(real_fit):
    _, out, _ = real_fit
    q = out.detection.quality
    assert q["bright_holes"] == 0.0
    assert q["hole_diameter_m"] == pytest.approx(0.15, abs=0.01)


# ---------------------------------------------------------------------------- synthetic accuracy
POSES = [  # yaw, pitch, u, v: tilts up to 35 degrees, across the image
    (0, 0, None, None),
    (25, 0, 500, 400),
    (-30, 10, 1400, 800),
    (15, -20, 900, 300),
    (35, 15, 1200, 500),
    (-20, -25, 600, 900),
]


@pytest.mark.parametrize(
    "distance, median_mm, max_mm", [(3.0, 3.0, 6.0), (5.0, 10.0, 15.0), (7.0, 10.0, 25.0)]
)
def test_synthetic_centre_accuracy(distance, median_mm, max_mm):
    errors = []
    for k, (yaw, pitch, u, v) in enumerate(POSES):
        T = board_pose(distance, yaw, pitch, 0.0, u, v)
        err, out = centre_errors(T, seed=k)
        q = out.detection.quality
        assert q["reprojection_rms_px"] < 0.5
        assert q["square_side_error_m"] < 0.003
        assert q["distance_m"] == pytest.approx(distance, abs=0.05)
        assert_image_order(out.detection.points)
        errors.append(err)
    errors = np.concatenate(errors)
    assert np.median(errors) <= median_mm / 1000.0
    assert np.max(errors) <= max_mm / 1000.0


def test_ellipse_centre_bias_correction_matters():
    # strongly tilted, close and off-axis: ellipse centres are ~2 px from the projected centres
    T = board_pose(1.3, yaw_deg=55.0, pitch_deg=25.0, u=1300, v=500)
    img = render(T, seed=3)
    with_fix = detect(img)
    without = detect(img, MonoDetectorConfig(refine_rim=False))
    assert isinstance(with_fix, MonoBoardFit) and isinstance(without, MonoBoardFit)
    truth = true_centres(T)
    err_with = np.linalg.norm(with_fix.detection.points - truth, axis=1)
    err_without = np.linalg.norm(without.detection.points - truth, axis=1)
    assert with_fix.detection.quality["centre_bias_px"] > 1.0
    assert np.max(err_with) < 0.5 * np.min(err_without)
    assert np.max(err_with) < 0.001


def test_fitting_the_rim_radius_removes_the_edge_bias_from_the_distance():
    # with the radius fixed, a sub-pixel edge bias scales the distance; fitted, it does not
    errs = {}
    for free in (True, False):
        config = MonoDetectorConfig(fit_hole_radius=free)
        e = [
            np.median(centre_errors(board_pose(6.0, yaw, pitch, 0.0, u, v), config, seed=k)[0])
            for k, (yaw, pitch, u, v) in enumerate(POSES[:3])
        ]
        errs[free] = np.median(e)
    assert errs[True] < errs[False]


def test_planar_pose_ambiguity_is_resolved_by_the_rims():
    # far, mildly tilted boards: the two IPPE poses of the four centres are close in cost; the
    # rims decide, and the chosen board normal is the true one
    rng = np.random.default_rng(21)
    for k in range(6):
        yaw, pitch = rng.uniform(-20.0, 20.0, 2)
        T = board_pose(6.0, yaw, pitch, 0.0, rng.uniform(400, 1500), rng.uniform(300, 900))
        _, out = centre_errors(T, seed=30 + k, noise=4.0)
        normal_error = math.degrees(math.acos(min(1.0, out.T_camera_board[:3, 2] @ T[:3, 2])))
        assert normal_error < 3.0
        q = out.detection.quality
        assert q["flip_cost_ratio"] >= 1.0 and q["flip_angle_deg"] >= 0.0


@pytest.mark.parametrize("roll", [-35.0, -10.0, 0.0, 20.0, 40.0])
def test_order_follows_the_board_when_rolled(roll):
    T = board_pose(4.0, 10.0, -5.0, roll, 800, 700)
    err, out = centre_errors(T, seed=int(roll) + 50)
    assert np.max(err) < 0.01  # each centre matched to its own hole, not a neighbour


def test_bright_holes():
    T = board_pose(4.0, 20.0, 5.0, 0.0, 1100, 600)
    err, out = centre_errors(T, plate=160, hole=250, background=200, seed=11)
    assert out.detection.quality["bright_holes"] == 1.0
    assert np.median(err) < 0.01
    dark_only = detect(render(T, plate=160, hole=250, background=200, seed=11),
                       MonoDetectorConfig(hole_polarity="dark"))
    assert isinstance(dark_only, DetectionFailure)


def test_distractor_blobs_are_ignored():
    T = board_pose(4.0, -15.0, 10.0, 0.0, 900, 650)
    uv, _ = CAM.project(true_centres(T))
    a = float(np.linalg.norm(uv[0] - uv[1])) * 0.15 / 0.24 / 2  # the holes' radius [px]
    extra = (
        (200.0, 200.0, a, a, 0.0),  # same size, alone
        (uv[1, 0] + 4.5 * a, uv[1, 1], a, a, 0.0),  # a fifth hole right of the square
        (300.0, 1000.0, 3 * a, 2 * a, 30.0),  # a big blob
        (1700.0, 300.0, a, a, 0.0),
        (1700.0 + 3.2 * a, 300.0, a, a, 0.0),  # a pair that could start a square
    )
    err, out = centre_errors(T, extra_ellipses=extra, seed=12)
    assert np.max(err) < 0.01
    assert out.detection.quality["candidates"] >= 7


def test_grey_and_colour_images_agree():
    T = board_pose(5.0, 10.0, 10.0)
    img = render(T, seed=13)
    a = detect(img)
    b = detect(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    np.testing.assert_allclose(a.detection.points, b.detection.points, atol=1e-9)


def test_roi():
    T = board_pose(4.0, 0.0, 0.0, 0.0, 1300, 800)
    img = render(T, seed=14)
    uv, _ = CAM.project(true_centres(T))
    corner = (int(uv[:, 0].min()) - 100, int(uv[:, 1].min()) - 100)
    inside = MonoDetectorConfig(roi=(corner[0], corner[1], 400, 400))
    outside = MonoDetectorConfig(roi=(0, 0, 600, 400))
    full = detect(img)
    cropped = detect(img, inside)
    assert isinstance(cropped, MonoBoardFit)
    np.testing.assert_allclose(cropped.detection.points, full.detection.points, atol=1e-3)
    missed = detect(img, outside)
    assert isinstance(missed, DetectionFailure) and missed.reason == "too_few_holes"


def test_without_refinement_still_detects():
    T = board_pose(5.0, 20.0, -10.0, 0.0, 700, 500)
    err, out = centre_errors(T, MonoDetectorConfig(refine_rim=False), seed=15)
    assert np.median(err) < 0.02
    assert out.rim_points_px.shape == (0, 2)


def test_detect_board_mono_returns_the_detection_and_never_mutates():
    T = board_pose(4.0, 5.0, 5.0)
    img = render(T, seed=16)
    before = img.copy()
    det = detect_board_mono(ImageFrame("front", 42, img), CAM)
    assert isinstance(det, BoardDetection) and det.ok
    assert det.sensor == "front" and det.t_ns == 42
    assert not det.points.flags.writeable
    np.testing.assert_array_equal(img, before)
    assert np.max(np.linalg.norm(det.points - true_centres(T), axis=1)) < 0.01


# ---------------------------------------------------------------------------- failures
def test_wrong_image_size():
    frame = ImageFrame("cam", 1, np.zeros((480, 640), np.uint8))
    out = detect_board_mono(frame, CAM)
    assert isinstance(out, DetectionFailure) and not out.ok
    assert out.reason == "wrong_image_size"
    assert "640x480" in out.detail and "1936x1216" in out.detail


def test_black_image_has_too_few_holes():
    out = detect_board_mono(ImageFrame("cam", 1, np.zeros((1216, 1936, 3), np.uint8)), CAM)
    assert isinstance(out, DetectionFailure)
    assert out.reason == "too_few_holes" and "need 4" in out.detail


def test_holes_not_in_the_board_square():
    T = board_pose(4.0, 10.0, 0.0)
    img = render(T, seed=17)
    wrong_board = BoardGeometry(spacing_m=0.5)  # 15 cm holes 50 cm apart: not what is seen
    out = detect_board_mono(ImageFrame("cam", 1, img), CAM, wrong_board)
    assert isinstance(out, DetectionFailure)
    assert out.reason == "no_square_pattern" and "spacing 0.5 m" in out.detail


def test_pnp_failure_is_reported(monkeypatch):
    img = render(board_pose(4.0), seed=18)

    def broken(*args, **kwargs):
        raise cv2.error("simulated")

    monkeypatch.setattr(cv2, "solvePnPGeneric", broken)
    out = detect_board_mono(ImageFrame("cam", 1, img), CAM)
    assert isinstance(out, DetectionFailure) and out.reason == "pnp_failed"


def test_poor_fit_threshold():
    img = render(board_pose(4.0, 10.0, 10.0), seed=19)
    config = MonoDetectorConfig(max_reprojection_rms_px=1e-6)
    out = detect_board_mono(ImageFrame("cam", 1, img), CAM, config=config)
    assert isinstance(out, DetectionFailure) and out.reason == "poor_fit"


# ---------------------------------------------------------------------------- pieces
def test_order_corners():
    pts = np.array([[10.0, 0.0], [0.0, 0.0], [10.0, 10.0], [0.0, 10.0]])  # TR, TL, BR, BL
    assert order_corners(pts).tolist() == [1, 0, 3, 2]
    # rolled by 30 degrees clockwise on screen: TL is still the top-left-most
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]])  # TL TR BL BR
    rolled = square @ np.array([[c, s], [-s, c]])
    perm = np.array([3, 0, 2, 1])
    assert perm[order_corners(rolled[perm])].tolist() == [0, 1, 2, 3]
    assert order_corners(np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 1.0], [5.0, 10.0]])) is None


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(min_hole_radius_px=0), "min_hole_radius_px must be a positive number"),
        (dict(min_hole_radius_px=50, max_hole_radius_px=40), "must be below max_hole_radius_px"),
        (dict(roi=(0, 0, 10)), "roi must be four integers"),
        (dict(roi=(0, 0, 0, 10)), "width, height > 0"),
        (dict(hole_polarity="grey"), "hole_polarity must be 'dark', 'bright' or 'any'"),
        (dict(rim_points_per_hole=4), "rim_points_per_hole must be >= 8"),
        (dict(threshold_step=True), "threshold_step must be a positive number"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        MonoDetectorConfig(**kwargs)
