"""Stereo: SGBM point clouds of a rendered, rectified pair, and the circle-board detector on them.

The renderer below is self-contained: a pinhole pair (left camera at the origin of the optical
frame, right camera ``baseline`` along +x, identical intrinsics: already rectified) ray-casts a
white, speckle-textured plate with four holes, a textured wall 2 m behind it and a textured
ground 1.5 m below the cameras. Rendering is 2x supersampled (edges are anti-aliased), with
Gaussian image noise. Textures are fixed on the surfaces, so both views agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.dataset import BoardGeometry
from rigcal.detect.result import BoardDetection, DetectionFailure
from rigcal.detect.stereo import StereoDetectorConfig, detect_board_stereo, detect_board_stereo_pair
from rigcal.errors import ConfigError, InputError
from rigcal.recording import PointCloudFrame, StereoFrame
from rigcal.sensors.stereo import (
    SgbmParams,
    StereoRig,
    disparity_from_pair,
    downsample_pair,
    point_cloud_from_pair,
    point_cloud_in_window,
)
from rigcal.targets.circle_board import board_centres

RIG = StereoRig(fx=1000.0, fy=1000.0, cx=639.5, cy=399.5, baseline_m=0.2, width=1280, height=800)
CAMERA_HEIGHT_M = 1.5
PLATE_RECT = (-0.5, 0.5, -1.1, 0.4)  # board frame: 1.0 x 1.5 m plate, the holes in its upper part


def _texture(rng, shape, mean, contrast, scales):
    """Multi-scale smooth noise (float32) with a given mean and contrast."""
    import cv2

    out = np.zeros(shape, np.float32)
    for s in scales:
        n = rng.normal(0, 1, shape).astype(np.float32)
        n = cv2.GaussianBlur(n, (0, 0), s)
        out += n / (n.std() + 1e-9)
    out /= out.std() + 1e-9
    return np.clip(mean + contrast * out, 0, 255).astype(np.float32)


class Scene:
    """Board (pose in the left optical frame), wall and ground with fixed textures."""

    def __init__(self, seed, distance, lateral=0.0, yaw=0.0, tilt=0.0, hole_xy=None,
                 with_board=True, board=BoardGeometry()):
        rng = np.random.default_rng(seed)
        self.with_board = with_board
        z_b = np.array([0.0, 0.0, -1.0])  # toward the camera
        y_b = np.array([0.0, -1.0, 0.0])  # up
        R_face = np.column_stack([np.cross(y_b, z_b), y_b, z_b])
        cy, sy = math.cos(yaw), math.sin(yaw)
        R_yaw = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])  # about the vertical
        ct, st = math.cos(tilt), math.sin(tilt)
        R_tilt = np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])
        self.R = R_yaw @ R_face @ R_tilt
        self.t = np.array([lateral, 0.2, distance])  # holes 0.2 m below the cameras' height
        holes = board_centres(board)[:, :2] if hole_xy is None else np.asarray(hole_xy, float)
        self.holes, self.hole_r = holes, board.hole_diameter_m / 2
        self.truth = self.t + np.column_stack([holes, np.zeros(4)]) @ self.R.T
        self.Rw, self.tw = R_face, np.array([lateral, 0.2, distance + 2.0])
        self.plate_tex = _texture(rng, (760, 510), 205, 35, (1.5, 4.0))  # 2 mm / texel
        self.wall_tex = _texture(rng, (1000, 2000), 110, 45, (1.5, 5.0))  # 5 mm / texel
        self.ground_tex = _texture(rng, (1500, 1000), 120, 40, (1.5, 4.0))  # 2 cm / texel
        self.noise_rng = rng

    @staticmethod
    def _rect_hit(o, A, B, R, t, rect):
        """Ray parameter (H, W) of the hits on a rectangle and the hit's board-frame x, y; the
        ray of pixel (u, v) is ``o + s * (A[u], B[v], 1)`` (separable: cheap float32 grids)."""
        n = R[:, 2].astype(np.float32)
        den = A * n[0] + B * n[1] + n[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = np.float32((t - o) @ R[:, 2]) / den
        ok = np.isfinite(tt) & (tt > 0)
        loc = []
        for k in (0, 1):
            e = R[:, k].astype(np.float32)
            loc.append(np.float32((o - t) @ R[:, k]) + tt * (A * e[0] + B * e[1] + e[2]))
        ok &= (loc[0] >= rect[0]) & (loc[0] <= rect[1]) & (loc[1] >= rect[2]) & (loc[1] <= rect[3])
        return np.where(ok, tt, np.float32(np.inf)), loc[0], loc[1]

    def render(self, cam_x, ss=2):
        import cv2

        W, H = RIG.width * ss, RIG.height * ss
        u = (np.arange(W, dtype=np.float32) + 0.5) / ss - 0.5
        v = (np.arange(H, dtype=np.float32) + 0.5) / ss - 0.5
        A = ((u - RIG.cx) / RIG.fx)[None, :]
        B = ((v - RIG.cy) / RIG.fy)[:, None]
        o = np.array([cam_x, 0.0, 0.0])
        t_plate, px, py = self._rect_hit(o, A, B, self.R, self.t, PLATE_RECT)
        if not self.with_board:
            t_plate[:] = np.inf
        for hx, hy in self.holes:
            t_plate[(px - hx) ** 2 + (py - hy) ** 2 < self.hole_r**2] = np.inf
        wall_rect = (-5.0, 5.0, -CAMERA_HEIGHT_M - 0.2, 3.0)
        t_wall, wx, wy = self._rect_hit(o, A, B, self.Rw, self.tw, wall_rect)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_ground = np.where(B > 0, CAMERA_HEIGHT_M / B, np.inf)
        t_ground = np.broadcast_to(t_ground, (H, W)).astype(np.float32)
        t_ground[t_ground > 60] = np.inf
        on_plate = t_plate < np.minimum(t_wall, t_ground)
        on_wall = ~on_plate & (t_wall < t_ground)
        on_ground = ~on_plate & ~on_wall & np.isfinite(t_ground)
        img = np.full((H, W), 170.0, np.float32)  # sky

        def sample(tex, mx, my, sel):
            n = int(sel.sum())
            if n == 0:
                return
            rows = -(-n // 4096)  # remap maps must stay below 32767 per side
            maps = np.zeros((2, rows * 4096), np.float32)
            maps[0, :n], maps[1, :n] = mx[sel], my[sel]
            vals = cv2.remap(tex, maps[0].reshape(rows, 4096), maps[1].reshape(rows, 4096),
                             cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            img[sel] = vals.reshape(-1)[:n]

        sample(self.plate_tex, (px + 0.5) / 0.002, (py + 1.1) / 0.002, on_plate)
        sample(self.wall_tex, (wx + 5.0) / 0.005, (wy + 1.7) / 0.005, on_wall)
        gx = np.float32(cam_x) + t_ground * A
        sample(self.ground_tex, (gx + 10.0) / 0.02, t_ground / 0.02, on_ground)
        if ss > 1:
            img = img.reshape(RIG.height, ss, RIG.width, ss).mean(axis=(1, 3))
        img += self.noise_rng.normal(0, 2.0, img.shape).astype(np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def pair(self):
        return StereoFrame("stereo1", 2_000, self.render(0.0), self.render(RIG.baseline_m))


def errors_m(det, truth):
    return np.linalg.norm(np.asarray(det.points) - truth, axis=1)


def assert_order(det, truth):
    d = np.linalg.norm(np.asarray(det.points)[:, None] - truth[None], axis=2)
    assert np.array_equal(np.argmin(d, axis=1), np.arange(4)), d


def _random_scene(rng, k, distance):
    return Scene(
        300 + k, distance, lateral=rng.uniform(-0.6, 0.6),
        yaw=math.radians(rng.uniform(-30, 30)), tilt=math.radians(rng.uniform(-15, 15)),
    )


@pytest.fixture(scope="module")
def near_pairs():
    """Six seeded boards at 3-5 m with their rendered pairs (rendering is the slow part)."""
    rng = np.random.default_rng(77)
    out = []
    for k, dist in enumerate([3.0, 3.5, 4.0, 4.5, 5.0, 5.0]):
        scene = _random_scene(rng, k, dist)
        out.append((scene, scene.pair(), dist))
    return out


@pytest.fixture(scope="module")
def near_boards(near_pairs):
    """The boards of ``near_pairs`` with their full-image SGBM clouds."""
    return [(scene, point_cloud_from_pair(pair, RIG), dist) for scene, pair, dist in near_pairs]


# ----------------------------------------------------------------------------- the point cloud


def test_point_cloud_is_organised_in_the_optical_frame():
    scene = Scene(5, 4.0, with_board=False)  # a fronto-parallel textured wall at 6 m, the ground
    frame = scene.pair()
    cloud = point_cloud_from_pair(frame, RIG)
    assert cloud.organized_shape == (RIG.height, RIG.width) and len(cloud) == RIG.width * RIG.height
    assert set(cloud.fields) == {"intensity", "disparity_px"}
    P = cloud.points_xyz.reshape(RIG.height, RIG.width, 3)
    assert np.all(np.isnan(P[:, :100, 2]))  # left border: no disparity search range
    centre = P[300:400, 500:800]
    assert np.isfinite(centre).all(axis=2).mean() > 0.95
    assert abs(np.nanmedian(centre[..., 2]) - 6.0) < 0.03
    # x right, y down: the pixel right of / below the centre has larger x / y
    assert np.nanmedian(P[350, 900:910, 0]) > 0 > np.nanmedian(P[350, 300:310, 0])
    assert np.nanmedian(P[650:660, 640, 1]) > 0  # the ground, below the camera
    disp = disparity_from_pair(frame)
    assert abs(np.nanmedian(disp[300:400, 500:800]) - RIG.fx * RIG.baseline_m / 6.0) < 0.2


def test_point_cloud_checks_sizes_and_params():
    small = StereoFrame("stereo1", 0, np.zeros((10, 20), np.uint8), np.zeros((10, 20), np.uint8))
    with pytest.raises(InputError, match="20x10 px, the stereo rig expects 1280x800"):
        point_cloud_from_pair(small, RIG)
    with pytest.raises(ConfigError, match="multiple of 16"):
        SgbmParams(num_disparities=100)
    with pytest.raises(ConfigError, match="odd"):
        SgbmParams(block_size=4)
    with pytest.raises(ConfigError, match="mode"):
        SgbmParams(mode="fast")
    with pytest.raises(InputError, match="baseline_m"):
        StereoRig(fx=1000, fy=1000, cx=1, cy=1, baseline_m=0, width=10, height=10)
    with pytest.raises(InputError, match="width"):
        StereoRig(fx=1000, fy=1000, cx=1, cy=1, baseline_m=0.1, width=10.5, height=10)
    assert RIG.size_wh == (1280, 800)
    assert np.isnan(RIG.depth_m(np.array([0.0, -1.0]))).all()


# ----------------------------------------------------------------------------- detection


def test_organised_accuracy_and_order_at_3_to_5_m(near_boards):
    errs = []
    for scene, cloud, dist in near_boards:
        det = detect_board_stereo(cloud)
        assert isinstance(det, BoardDetection), (dist, det)
        assert det.quality["organised"] == 1.0
        assert_order(det, scene.truth)
        errs.extend(errors_m(det, scene.truth))
    med = float(np.median(errs))
    print(f"\nstereo (organised) 3-5 m: median centre error {med * 1000:.1f} mm, "
          f"max {max(errs) * 1000:.1f} mm")
    assert med <= 0.01
    assert max(errs) <= 0.025


def test_unorganised_cloud_uses_the_occupancy_grid(near_boards):
    errs = []
    for scene, cloud, dist in near_boards[::2]:
        ok = np.isfinite(cloud.points_xyz).all(axis=1)
        bare = PointCloudFrame("stereo1", 9, cloud.points_xyz[ok])
        det = detect_board_stereo(bare)
        assert isinstance(det, BoardDetection), (dist, det)
        assert det.quality["organised"] == 0.0
        assert_order(det, scene.truth)
        errs.extend(errors_m(det, scene.truth))
    med = float(np.median(errs))
    print(f"\nstereo (unorganised) 3-5 m: median centre error {med * 1000:.1f} mm")
    assert med <= 0.015


def test_individual_circles_without_square_refinement(near_boards):
    scene, cloud, _ = near_boards[1]
    det = detect_board_stereo(cloud, config=StereoDetectorConfig(refine_square=False))
    assert isinstance(det, BoardDetection), det
    assert_order(det, scene.truth)
    assert np.median(errors_m(det, scene.truth)) <= 0.015


def test_at_7_m_it_still_detects():
    scene = Scene(700, 7.0, lateral=-0.4, yaw=math.radians(20), tilt=math.radians(8))
    det = detect_board_stereo(point_cloud_from_pair(scene.pair(), RIG))
    assert isinstance(det, BoardDetection), det
    assert_order(det, scene.truth)
    e = errors_m(det, scene.truth)
    print(f"\nstereo at 7 m: centre errors {np.round(e * 1000, 1)} mm")
    assert np.max(e) < 0.03


def test_pair_detector_matches_only_around_the_board_as_accurately(near_pairs, near_boards):
    errs_pair, errs_full, fractions = [], [], []
    for (scene, pair, dist), (_, cloud, _) in zip(near_pairs, near_boards):
        det = detect_board_stereo_pair(pair, RIG)
        assert isinstance(det, BoardDetection), (dist, det)
        assert det.quality["organised"] == 1.0
        fractions.append(det.quality["window_fraction"])
        assert_order(det, scene.truth)
        errs_pair.extend(errors_m(det, scene.truth))
        errs_full.extend(errors_m(detect_board_stereo(cloud), scene.truth))
    med, med_full = float(np.median(errs_pair)), float(np.median(errs_full))
    print(f"\nstereo pair (windowed SGBM) 3-5 m: median centre error {med * 1000:.1f} mm, max "
          f"{max(errs_pair) * 1000:.1f} mm (whole image: {med_full * 1000:.1f} / "
          f"{max(errs_full) * 1000:.1f} mm)")
    assert med <= 0.01 and max(errs_pair) <= 0.025
    assert med <= med_full + 0.002
    # most pairs are matched in a window around the board (a board the coarse stage misses
    # is matched over the whole image: slower, as accurate)
    print(f"matched fractions of the image: {np.round(fractions, 3).tolist()}")
    assert sum(f < 0.35 for f in fractions) >= 5, fractions


def test_windows_are_detected_from_the_coarse_candidate_without_segmenting_again(near_pairs, monkeypatch):
    """The window's detection is seeded by the coarse candidate's plane: the window is not
    segmented again (the whole detector runs there only when the seeded one fails)."""
    import rigcal.detect.stereo as stereo_module

    def no_second_segmentation(*_a, **_k):
        raise AssertionError("the window was segmented again")

    monkeypatch.setattr(stereo_module, "detect_board_stereo", no_second_segmentation)
    scene, pair, _ = near_pairs[2]
    det = detect_board_stereo_pair(pair, RIG)
    assert isinstance(det, BoardDetection) and det.quality["window_fraction"] < 0.35
    assert_order(det, scene.truth)
    assert max(errors_m(det, scene.truth)) <= 0.025


def test_seeded_window_detection_survives_a_tilted_coarse_plane(near_pairs):
    """The coarse candidate's plane seeds the window's plate; tilted by 10 deg about the
    board's centre it would cut off part of the plate (and tilt the refit), but it is refitted
    on a half-resolution plate first: the holes come out as accurately as from the true
    plane."""
    from rigcal.detect.stereo import _board_windows, _detect_seeded
    from rigcal.geometry.fitting import PlaneFit

    scene, pair, _ = near_pairs[2]
    cfg = StereoDetectorConfig()
    (window, _, cand), *_ = _board_windows(pair, RIG, BoardGeometry(), cfg, SgbmParams(), 4, 32)
    cloud = point_cloud_in_window(pair, RIG, window)
    intr = (RIG.fx, RIG.fy, RIG.cx - window[0], RIG.cy - window[1])
    n, d = cand.plane.normal, float(cand.plane.d)
    c = scene.truth.mean(axis=0)
    pivot = c - (c @ n + d) * n
    axis = np.cross(n, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    a = math.radians(10.0)
    tilted = n * math.cos(a) + np.cross(axis, n) * math.sin(a)
    seed = cand._replace(plane=PlaneFit(tilted, -float(tilted @ pivot), cand.plane.inliers,
                                        cand.plane.rms))
    det = _detect_seeded(cloud, seed, BoardGeometry(), cfg, intr)
    ref = _detect_seeded(cloud, cand, BoardGeometry(), cfg, intr)
    assert isinstance(det, BoardDetection) and isinstance(ref, BoardDetection), (det, ref)
    assert_order(det, scene.truth)
    assert max(errors_m(det, scene.truth)) <= 0.01
    assert np.max(np.linalg.norm(det.points - ref.points, axis=1)) < 0.002


def test_refine_plane_is_the_least_squares_plane_of_the_points_near_it():
    from rigcal.detect.stereo import _refine_plane
    from rigcal.geometry.fitting import fit_plane_lstsq

    rng = np.random.default_rng(3)
    plate = np.column_stack([rng.uniform(-0.5, 0.5, 5000), rng.uniform(-0.7, 0.7, 5000),
                             rng.normal(0, 0.01, 5000)])
    far = np.column_stack([rng.uniform(-1, 1, (500, 2)), rng.uniform(0.3, 1.0, 500)])
    R = np.array([[0.96, 0.0, 0.28], [0.0, 1.0, 0.0], [-0.28, 0.0, 0.96]])
    pts = np.vstack([plate, far]) @ R.T + [0.2, -0.1, 4.0]
    n0 = R @ np.array([0.05, 0.0, 1.0])
    n0 /= np.linalg.norm(n0)
    d0 = -float(n0 @ np.array([0.2, -0.1, 4.0]))
    normal, d, rms = _refine_plane(pts, n0, d0, 0.1)
    near = np.abs(pts @ n0 + d0) < 0.1
    ref = fit_plane_lstsq(pts[near])
    assert np.allclose(normal, ref.normal, atol=1e-9) and d == pytest.approx(ref.d, abs=1e-9)
    assert rms == pytest.approx(ref.rms, rel=1e-6)
    # too few points near it: the given plane is kept
    n1, d1, rms1 = _refine_plane(pts[:2], n0, d0, 0.1)
    assert n1 is n0 and d1 == d0 and math.isnan(rms1)


def test_pair_detector_falls_back_to_the_whole_image():
    scene = Scene(700, 7.0, lateral=-0.4, yaw=math.radians(20), tilt=math.radians(8))
    pair = scene.pair()
    # coarse_factor 1: no coarse stage, exactly detect_board_stereo on the whole image
    det = detect_board_stereo_pair(pair, RIG, coarse_factor=1)
    ref = detect_board_stereo(point_cloud_from_pair(pair, RIG))
    assert isinstance(det, BoardDetection) and det.quality["window_fraction"] == 1.0
    assert np.array_equal(det.points, ref.points)
    wall = detect_board_stereo_pair(Scene(5, 4.0, with_board=False).pair(), RIG)
    assert isinstance(wall, DetectionFailure) and wall.reason == "no_board_plane", wall


def test_window_cloud_equals_the_whole_image_cloud_inside(near_pairs):
    _, pair, _ = near_pairs[0]
    params = SgbmParams(num_disparities=96)
    whole = point_cloud_from_pair(pair, RIG, params).points_xyz.reshape(RIG.height, RIG.width, 3)
    win = point_cloud_in_window(pair, RIG, (500, 200, 800, 500), params)
    assert win.organized_shape == (300, 300)
    P = win.points_xyz.reshape(300, 300, 3)
    ref = whole[200:500, 500:800]
    both = np.isfinite(P[..., 2]) & np.isfinite(ref[..., 2])
    assert both.mean() > 0.8
    # SGBM's paths are cut at the window's edges: most disparities agree to a pixel fraction
    dz = np.abs(P[..., 2][both] - ref[..., 2][both])
    assert np.median(dz) < 1e-3
    # x, y follow the full image's pixel coordinates
    assert np.allclose(P[both][:, 0] * RIG.fx / P[both][:, 2] + RIG.cx,
                       np.nonzero(both)[1] + 500)
    small, rig4 = downsample_pair(pair, RIG, 4)
    assert small.left.shape == (200, 320) and rig4.size_wh == (320, 200)
    assert rig4.fx == RIG.fx / 4 and rig4.cx == pytest.approx((RIG.cx + 0.5) / 4 - 0.5)
    with pytest.raises(ConfigError, match="integer >= 1"):
        downsample_pair(pair, RIG, 0)
    with pytest.raises(InputError, match="empty window"):
        point_cloud_in_window(pair, RIG, (900, 0, 800, 10))


def test_failures_empty_no_board_not_square():
    empty = detect_board_stereo(PointCloudFrame("stereo1", 3, np.full((50, 3), np.nan)))
    assert isinstance(empty, DetectionFailure) and empty.reason == "no_points_in_roi"
    wall = detect_board_stereo(point_cloud_from_pair(Scene(5, 4.0, with_board=False).pair(), RIG))
    assert isinstance(wall, DetectionFailure) and wall.reason == "no_board_plane", wall
    rect = [(-0.12, 0.17), (0.12, 0.17), (-0.12, -0.17), (0.12, -0.17)]  # 0.24 x 0.34 m
    skew_scene = Scene(6, 4.0, yaw=0.2, hole_xy=rect)
    skew = detect_board_stereo(point_cloud_from_pair(skew_scene.pair(), RIG))
    assert isinstance(skew, DetectionFailure) and skew.reason == "not_square", skew
    assert "diagonal/side" in skew.detail


def test_roi_outside_the_board(near_boards):
    _, cloud, _ = near_boards[0]
    cfg = StereoDetectorConfig(roi_min_xyz=(-1.0, -1.0, 20.0), roi_max_xyz=(1.0, 1.0, 30.0))
    out = detect_board_stereo(cloud, config=cfg)
    assert isinstance(out, DetectionFailure) and out.reason == "no_points_in_roi"


def test_stereo_config_is_validated():
    with pytest.raises(ConfigError, match="grid_cell_m"):
        StereoDetectorConfig(grid_cell_m=0.0)
    with pytest.raises(ConfigError, match="max_hole_area_fraction"):
        StereoDetectorConfig(min_hole_area_fraction=2.0, max_hole_area_fraction=1.0)
    with pytest.raises(ConfigError, match="roi_max_xyz"):
        StereoDetectorConfig(roi_min_xyz=(0, 0, 0), roi_max_xyz=(1, 1, 0))
