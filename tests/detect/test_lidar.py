"""The lidar circle-board detector on simulated ring scans with known ground truth.

The scan generator below is self-contained (analytic ray casting, no dependency on rigcal.sim):
a spinning lidar at the origin (x forward, y left, z up, 1.8 m above a flat ground), the board
(1.0 x 1.5 m plate, four 0.15 m holes on a 0.24 m square in its upper part, on a thin pole),
a back wall 2 m (``wall_gap_m``) behind the board, a distractor panel and a far cylindrical
"building" so that every ray returns. Rays through the holes continue to the wall or the
ground. Range noise is Gaussian along the ray.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.dataset import BoardGeometry
from rigcal.detect.lidar import LidarDetectorConfig, detect_board_lidar
from rigcal.detect.result import BoardDetection, DetectionFailure
from rigcal.errors import ConfigError
from rigcal.recording import PointCloudFrame
from rigcal.targets.circle_board import board_centres

HDL64_ELEV_DEG = np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)])
VLP16_ELEV_DEG = np.linspace(-15.0, 15.0, 16)
SENSOR_HEIGHT_M = 1.8
HOLES_Z_M = -0.25  # height of the hole-square centre in the sensor frame
PLATE_RECT = (-0.5, 0.5, -1.1, 0.4)  # board frame x0, x1, y0, y1: 1.0 x 1.5 m, holes up top
REASONS = {
    "no_points_in_roi", "no_board_plane", "too_few_edge_points", "circles_not_found", "not_square"
}


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def facing_pose(distance, azimuth, height, yaw=0.0, tilt=0.0):
    """R (board -> sensor), t: a panel at ``distance`` / ``azimuth`` facing the sensor, then
    turned by ``yaw`` about the vertical and tilted by ``tilt`` about its own x axis."""
    toward = -np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    y = np.array([0.0, 0.0, 1.0])
    R_face = np.column_stack([np.cross(y, toward), y, toward])
    R = _rz(yaw) @ R_face @ _rx(tilt)
    t = np.array([distance * math.cos(azimuth), distance * math.sin(azimuth), height])
    return R, t


def _hit_rect(dirs, R, t, rect, holes=None, hole_r=0.0):
    """Ray parameter of the hits on a rectangle (board frame rect) with circular holes."""
    n = R[:, 2]
    den = dirs @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = (t @ n) / den
    ok = np.isfinite(tt) & (tt > 0)
    local = (tt[:, None] * dirs - t) @ R
    x, y = local[:, 0], local[:, 1]
    ok &= (x >= rect[0]) & (x <= rect[1]) & (y >= rect[2]) & (y <= rect[3])
    if holes is not None:
        for hx, hy in holes:
            ok &= (x - hx) ** 2 + (y - hy) ** 2 > hole_r**2
    return np.where(ok, tt, np.inf)


def lidar_scan(
    seed,
    *,
    distance=5.0,
    azimuth=0.0,
    yaw=0.0,
    tilt=0.0,
    elev_deg=HDL64_ELEV_DEG,
    az_step_deg=0.17,
    sigma_m=0.015,
    hole_xy=None,
    with_board=True,
    with_ring=True,
    wall_gap_m=2.0,
    board=BoardGeometry(),
):
    """A PointCloudFrame of one scan and the true centres (4, 3) TL, TR, BL, BR (sensor frame)."""
    rng = np.random.default_rng(seed)
    az = np.radians(np.arange(0.0, 360.0, az_step_deg))
    el = np.radians(np.asarray(elev_deg))
    A, E = np.meshgrid(az, el, indexing="ij")
    ring = np.broadcast_to(np.arange(el.size), A.shape).reshape(-1)
    A, E = A.reshape(-1), E.reshape(-1)
    dirs = np.column_stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)])
    hits = []
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(dirs[:, 2] < 0, -SENSOR_HEIGHT_M / dirs[:, 2], np.inf)
    hits.append(np.where(t_ground < 70.0, t_ground, np.inf))
    t_cyl = 40.0 / np.cos(E)
    hits.append(np.where(t_cyl * dirs[:, 2] < 6.0, t_cyl, np.inf))
    R, t = facing_pose(distance, azimuth, HOLES_Z_M, yaw, tilt)
    holes = board_centres(board)[:, :2] if hole_xy is None else np.asarray(hole_xy, float)
    if with_board:
        hits.append(_hit_rect(dirs, R, t, PLATE_RECT, holes, board.hole_diameter_m / 2))
        pole_t = t + R @ np.array([0.0, PLATE_RECT[2], -0.05])
        hits.append(_hit_rect(dirs, R, pole_t, (-0.03, 0.03, -0.6, 0.0)))
    Rw, tw = facing_pose(distance + wall_gap_m, azimuth, HOLES_Z_M)
    hits.append(_hit_rect(dirs, Rw, tw, (-5.0, 5.0, -SENSOR_HEIGHT_M - HOLES_Z_M, 3.0)))
    Rd, td = facing_pose(6.0, azimuth + 1.2, -0.5, yaw=0.3)
    hits.append(_hit_rect(dirs, Rd, td, (-1.25, 1.25, -0.3, 0.3)))
    tt = np.min(np.stack(hits), axis=0)
    ok = np.isfinite(tt)
    rng_m = tt[ok] + rng.normal(0.0, sigma_m, ok.sum())
    pts = dirs[ok] * rng_m[:, None]
    fields = {"intensity": rng.uniform(0, 100, ok.sum())}
    if with_ring:
        fields["ring"] = ring[ok].astype(np.uint16)
    truth = t + np.column_stack([holes, np.zeros(4)]) @ R.T
    return PointCloudFrame("lidar1", 1_000, pts, fields), truth


def errors_m(det, truth):
    return np.linalg.norm(np.asarray(det.points) - truth, axis=1)


def assert_order(det, truth):
    """Every returned centre is nearest to its own true centre (no swap, no mirror)."""
    d = np.linalg.norm(np.asarray(det.points)[:, None] - truth[None], axis=2)
    assert np.array_equal(np.argmin(d, axis=1), np.arange(4)), d


# ----------------------------------------------------------------------------- accuracy


@pytest.fixture(scope="module")
def random_boards():
    """20 seeded placements at 3-7 m, anywhere around the sensor, yaw +-30, tilt +-15 deg."""
    rng = np.random.default_rng(2024)
    out = []
    for k in range(20):
        dist = [3.0, 5.0, 7.0][k % 3] + rng.uniform(-0.3, 0.3)
        dist = float(np.clip(dist, 3.0, 7.0))
        az = rng.uniform(-math.pi, math.pi)
        yaw = math.radians(rng.uniform(-30, 30))
        tilt = math.radians(rng.uniform(-15, 15))
        frame, truth = lidar_scan(100 + k, distance=dist, azimuth=az, yaw=yaw, tilt=tilt)
        out.append((frame, truth, dist))
    return out


def test_hdl64_accuracy_and_order_over_random_boards(random_boards):
    errs, by_dist = [], {}
    for frame, truth, dist in random_boards:
        det = detect_board_lidar(frame)
        assert isinstance(det, BoardDetection), (dist, det)
        assert det.points.shape == (4, 3)
        assert_order(det, truth)
        e = errors_m(det, truth)
        errs.extend(e)
        by_dist.setdefault(round(dist), []).extend(e)
    med = float(np.median(errs))
    print(f"\nlidar HDL-64E median centre error {med * 1000:.1f} mm, "
          f"max {max(errs) * 1000:.1f} mm; "
          + ", ".join(f"~{k} m: {np.median(v) * 1000:.1f} mm" for k, v in sorted(by_dist.items())))
    assert med <= 0.01
    assert max(errs) <= 0.04


def test_without_ring_field_rings_come_from_elevation(random_boards):
    for frame, truth, _ in random_boards[:4]:
        bare = PointCloudFrame(frame.sensor, frame.t_ns, frame.points_xyz, {})
        det = detect_board_lidar(bare)
        assert isinstance(det, BoardDetection), det
        assert_order(det, truth)
        assert np.median(errors_m(det, truth)) <= 0.015


def test_individual_circles_without_square_refinement(random_boards):
    cfg = LidarDetectorConfig(refine_square=False)
    errs = []
    for frame, truth, dist in random_boards[:6]:
        det = detect_board_lidar(frame, config=cfg)
        if isinstance(det, DetectionFailure):
            assert det.reason in REASONS
            continue
        assert_order(det, truth)
        errs.extend(errors_m(det, truth))
    assert len(errs) >= 12
    assert np.median(errs) <= 0.02


@pytest.mark.parametrize("azimuth_deg", [0.0, 90.0, 180.0, -135.0, 37.0])
def test_order_is_as_seen_from_the_sensor_all_around(azimuth_deg):
    frame, truth = lidar_scan(7, distance=4.0, azimuth=math.radians(azimuth_deg),
                              yaw=math.radians(20), tilt=math.radians(-10))
    det = detect_board_lidar(frame)
    assert isinstance(det, BoardDetection), det
    assert_order(det, truth)
    # top holes are higher, left holes are on the sensor's left when looking at the board
    p = det.points
    assert p[0, 2] > p[2, 2] and p[1, 2] > p[3, 2]
    look = p.mean(axis=0) / np.linalg.norm(p.mean(axis=0))
    left = np.cross(np.array([0.0, 0.0, 1.0]), look)  # sensor's left when facing the board
    assert (p[0] - p[1]) @ left > 0.2 and (p[2] - p[3]) @ left > 0.2


def test_board_behind_the_sensor_is_not_mirrored():
    frame, truth = lidar_scan(11, distance=5.0, azimuth=math.pi, yaw=0.2, tilt=0.1)
    det = detect_board_lidar(frame)
    assert isinstance(det, BoardDetection), det
    assert_order(det, truth)
    assert np.max(errors_m(det, truth)) < 0.03


def test_board_close_to_the_wall_is_split_from_it():
    # 0.3 m in front of the wall and yawed: board and wall form one voxel cluster
    frame, truth = lidar_scan(13, distance=5.0, azimuth=0.2, yaw=0.3, wall_gap_m=0.3)
    det = detect_board_lidar(frame)
    assert isinstance(det, BoardDetection), det
    assert_order(det, truth)
    assert np.max(errors_m(det, truth)) < 0.01


def test_roi_box_restricts_the_search():
    frame, truth = lidar_scan(5, distance=4.5, azimuth=0.3)
    c = truth.mean(axis=0)
    cfg = LidarDetectorConfig(
        roi_min_xyz=tuple(c - [1.5, 1.5, 1.5]), roi_max_xyz=tuple(c + [1.5, 1.5, 1.0])
    )
    det = detect_board_lidar(frame, config=cfg)
    assert isinstance(det, BoardDetection), det
    assert_order(det, truth)
    elsewhere = LidarDetectorConfig(roi_min_xyz=(-8.0, -8.0, -1.0), roi_max_xyz=(-7.0, -7.0, 1.0))
    out = detect_board_lidar(frame, config=elsewhere)
    assert isinstance(out, DetectionFailure)
    assert out.reason in ("no_points_in_roi", "no_board_plane")


@pytest.mark.parametrize("distance", [3.0, 3.5, 4.0])
def test_vlp16_works_or_fails_with_a_reason(distance):
    frame, truth = lidar_scan(3, distance=distance, azimuth=0.4, yaw=0.3, tilt=0.1,
                              elev_deg=VLP16_ELEV_DEG, az_step_deg=0.2, sigma_m=0.02)
    det = detect_board_lidar(frame)
    if isinstance(det, BoardDetection):
        assert_order(det, truth)
        print(f"\nVLP-16 at {distance} m: max error {np.max(errors_m(det, truth)) * 1000:.0f} mm")
        assert np.max(errors_m(det, truth)) < 0.05
    else:
        print(f"\nVLP-16 at {distance} m: {det.reason}: {det.detail}")
        assert det.reason in REASONS and det.detail


# ----------------------------------------------------------------------------- failures


def test_empty_cloud_fails_with_no_points_in_roi():
    out = detect_board_lidar(PointCloudFrame("lidar1", 5, np.zeros((0, 3))))
    assert isinstance(out, DetectionFailure)
    assert out.reason == "no_points_in_roi" and out.t_ns == 5 and out.sensor == "lidar1"
    nan = detect_board_lidar(PointCloudFrame("lidar1", 5, np.full((100, 3), np.nan)))
    assert nan.reason == "no_points_in_roi" and "0 of 100" in nan.detail


def test_scene_without_board_fails_with_no_board_plane():
    frame, _ = lidar_scan(21, distance=5.0, with_board=False)
    out = detect_board_lidar(frame)
    assert isinstance(out, DetectionFailure)
    assert out.reason == "no_board_plane"
    assert "clusters" in out.detail


def test_holes_not_on_a_square_fail_with_not_square():
    rect_holes = [(-0.12, 0.17), (0.12, 0.17), (-0.12, -0.17), (0.12, -0.17)]  # 0.24 x 0.34 m
    frame, _ = lidar_scan(31, distance=4.0, azimuth=0.2, hole_xy=rect_holes)
    out = detect_board_lidar(frame)
    assert isinstance(out, DetectionFailure), out
    assert out.reason == "not_square"
    assert "cm" in out.detail


def test_board_without_holes_fails_with_too_few_edge_points():
    frame, _ = lidar_scan(41, distance=4.0, hole_xy=[(5.0, 5.0)] * 4)
    out = detect_board_lidar(frame)
    assert isinstance(out, DetectionFailure)
    assert out.reason == "too_few_edge_points"


def test_config_is_validated():
    with pytest.raises(ConfigError, match="roi_min_xyz and roi_max_xyz"):
        LidarDetectorConfig(roi_min_xyz=(0, 0, 0))
    with pytest.raises(ConfigError, match="max_radius_m"):
        LidarDetectorConfig(min_radius_m=0.1, max_radius_m=0.05)
    with pytest.raises(ConfigError, match="jump_m must be a positive number"):
        LidarDetectorConfig(jump_m=-1)
    with pytest.raises(ConfigError, match="up_axis"):
        LidarDetectorConfig(up_axis=(0, 0, 0))
    with pytest.raises(ConfigError, match="seed must be an integer"):
        LidarDetectorConfig(seed=-1)


# ----------------------------------------------------------------------------- speed


def test_a_full_hdl64_scan():
    """A whole HDL-64E scan (its speed: benchmarks/bench_detect.py, not a timed test)."""
    frame, truth = lidar_scan(99, distance=5.0, azimuth=0.5, yaw=0.2, tilt=0.1)
    assert len(frame) > 125_000
    det = detect_board_lidar(frame)
    assert isinstance(det, BoardDetection)
