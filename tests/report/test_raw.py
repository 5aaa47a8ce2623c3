"""With raw data: lidar scans projected onto camera images with the calibrated extrinsics, and
the detected circles (rigcal.report.raw), on synthetic frames whose geometry is known."""

from __future__ import annotations

import base64

import cv2
import numpy as np

from rigcal.dataset import BoardGeometry, Dataset, SensorDetections, SensorKind
from rigcal.io.config.rig_config import DetectionRig, SensorSetup
from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate
from rigcal.recording import ImageFrame, PointCloudFrame
from rigcal.report.raw import CIRCLE_BGR, CROSS_BGR, lidar_on_image, raw_overlays
from rigcal.sensors.camera.pinhole import PinholeCamera

# lidar: x forward, y left, z up; camera optical frame: z forward, x right, y down; 10 cm apart
T_CAMERA_LIDAR = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.1], [1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1]])
CAMERA = PinholeCamera.from_intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
CENTRES_LIDAR = np.array([[4.0, 0.12, 0.12], [4.0, -0.12, 0.12], [4.0, 0.12, -0.12], [4.0, -0.12, -0.12]])


def _uv(points_lidar: np.ndarray) -> np.ndarray:
    p = points_lidar @ T_CAMERA_LIDAR[:3, :3].T + T_CAMERA_LIDAR[:3, 3]
    return np.stack([500 * p[:, 0] / p[:, 2] + 320, 500 * p[:, 1] / p[:, 2] + 240], 1)


def _wall(x: float = 6.0) -> np.ndarray:
    y, z = np.meshgrid(np.linspace(-2, 2, 60), np.linspace(-1, 1, 30))
    return np.stack([np.full(y.size, x), y.ravel(), z.ravel()], 1)


def test_crosses_sit_in_the_circles_where_the_geometry_says():
    circles = CENTRES_LIDAR @ T_CAMERA_LIDAR[:3, :3].T + T_CAMERA_LIDAR[:3, 3]  # what the camera saw
    img = lidar_on_image(np.zeros((480, 640), np.uint8), CAMERA, _wall(), T_CAMERA_LIDAR,
                         circles_camera=circles, lidar_centres=CENTRES_LIDAR, width_px=640)
    assert img.shape == (480, 640, 3)
    r = 500 * 0.075 / 4.0  # the hole's radius in pixels at 4 m
    for u, v in _uv(CENTRES_LIDAR):
        assert tuple(img[int(round(v)), int(round(u))]) == CROSS_BGR
        ring = img[int(round(v)) - 1:int(round(v)) + 2, int(round(u + r)) - 1:int(round(u + r)) + 2]
        assert np.any(np.all(np.abs(ring.astype(int) - CIRCLE_BGR) < 60, axis=-1)), (u, v)
    # the scan of the wall behind is drawn, coloured, where it projects
    u, v = _uv(_wall()[[0]])[0]
    assert img[int(v), int(u)].any()
    # a wrong extrinsic puts the crosses elsewhere
    wrong = T_CAMERA_LIDAR.copy()
    wrong[0, 3] += 0.3
    img2 = lidar_on_image(np.zeros((480, 640), np.uint8), CAMERA, _wall(), wrong,
                          circles_camera=circles, lidar_centres=CENTRES_LIDAR, width_px=640)
    u, v = _uv(CENTRES_LIDAR[[0]])[0]
    assert tuple(img2[int(round(v)), int(round(u))]) != CROSS_BGR


def test_scaled_to_the_requested_width():
    img = lidar_on_image(np.zeros((960, 1280), np.uint8), PinholeCamera.from_intrinsics(1280, 960, 1000, 1000, 640, 480),
                         _wall(), T_CAMERA_LIDAR, width_px=640)
    assert img.shape == (480, 640, 3)


class _Recording:
    """Frames of a lidar and a stereo camera's left images, one of each per placement."""

    def __init__(self, starts):
        self.starts = starts
        self.calls = 0

    def frames(self, topics, start_ns=None, end_ns=None):
        self.calls += 1
        for t in self.starts:
            if start_ns <= t < end_ns:
                for key, (topic, kind) in topics.items():
                    if kind is SensorKind.CAMERA:
                        yield ImageFrame(key, t + 1000, np.full((480, 640), 90, np.uint8))
                    else:
                        yield PointCloudFrame(key, t + 2000, _wall())


def test_raw_overlays_read_a_frame_of_both_per_placement():
    from types import SimpleNamespace

    n = 5
    rig = DetectionRig(sensors=(
        SensorSetup("lidar1", SensorKind.LIDAR, "cloud", "/lidar", "velodyne"),
        SensorSetup("camera1", SensorKind.CAMERA, "stereo_pair", "/left", "left", right_topic="/right",
                    stereo={"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "baseline_m": 0.2}),
    ))
    circles = CENTRES_LIDAR @ T_CAMERA_LIDAR[:3, :3].T + T_CAMERA_LIDAR[:3, 3]
    cam_pts = np.repeat(circles[None], n, axis=0)
    cam_pts[2] = np.nan  # the camera missed board 2
    ds = Dataset((SensorDetections("lidar1", SensorKind.LIDAR, np.repeat(CENTRES_LIDAR[None], n, axis=0)),
                  SensorDetections("camera1", SensorKind.CAMERA, cam_pts)), BoardGeometry())
    T_lidar_camera = np.linalg.inv(T_CAMERA_LIDAR)
    est = {name: SensorEstimate(name, kind, name, T, np.eye(6), {k: 0.0 for k in STD_KEYS})
           for name, kind, T in (("lidar1", SensorKind.LIDAR, np.eye(4)), ("camera1", SensorKind.CAMERA, T_lidar_camera))}
    result = CalibrationResult("fcpe", "lidar1", True, est, {}, {}, {}, num_boards=n)
    starts = [k * 10**9 for k in range(n)]
    placements = [SimpleNamespace(start_ns=t, end_ns=t + 5 * 10**8) for t in starts]
    rec = _Recording(starts)
    images = raw_overlays(rec, rig, placements, ds, result, max_images=3)
    assert [im["board"] for im in images] == [0, 3, 4]  # spread over the boards the camera saw
    assert all(im["camera"] == "camera1" and im["lidar"] == "lidar1" for im in images)
    jpg = cv2.imdecode(np.frombuffer(base64.b64decode(images[0]["jpeg_base64"]), np.uint8), cv2.IMREAD_COLOR)
    assert jpg.shape == (480, 640, 3)
    u, v = _uv(CENTRES_LIDAR[[0]])[0]
    patch = jpg[int(v) - 2:int(v) + 3, int(u) - 2:int(u) + 3].astype(int)
    assert np.any((patch[..., 0] > 150) & (patch[..., 2] > 150) & (patch[..., 1] < 120))  # the magenta cross
