"""With raw data: every lidar's points projected onto each camera's image with the calibrated
extrinsics, and the detected circles (for the report of ``rigcal calibrate --rig``).

For a few board placements, the first lidar scan and camera image (a stereo pair's left image)
within the placement's stable window are read again from the recording; the scan is mapped into
the camera with ``T_camera_lidar = result.T(camera, lidar)`` and projected through the camera
model (mono: the rig's intrinsics; stereo: its rectified ``fx, fy, cx, cy``), coloured by depth.
The camera's detected circles (its circle centres of that board, camera frame) are drawn as
circles of the board's hole radius, the lidar's detected centres mapped into the camera as
crosses: when the calibration is right they coincide, and the board's edges in the scan line up
with the image. Images are JPEG (scaled to ``width_px``), base64 in the report data.
OpenCV is imported inside the functions that draw.
"""

from __future__ import annotations

import base64
import logging
from typing import Any, Iterable, Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.geometry.se3 import transform_points
from rigcal.problem.result import CalibrationResult

log = logging.getLogger(__name__)

#: colours (BGR) of the drawn circles (camera detections) and crosses (lidar detections)
CIRCLE_BGR = (0, 220, 0)
CROSS_BGR = (255, 0, 255)


def lidar_on_image(image: np.ndarray, camera: Any, points_lidar: np.ndarray, T_camera_lidar: np.ndarray,
                   circles_camera: np.ndarray | None = None, hole_radius_m: float = 0.075,
                   lidar_centres: np.ndarray | None = None, width_px: int = 960,
                   max_points: int = 60_000) -> np.ndarray:
    """A BGR uint8 image (scaled to ``width_px`` wide): ``points_lidar`` (N, 3) [m, lidar frame]
    projected through ``camera`` after ``T_camera_lidar``, coloured by depth (near red, far
    blue); ``circles_camera`` (4, 3) [m, camera frame] drawn as circles of ``hole_radius_m``;
    ``lidar_centres`` (4, 3) [m, lidar frame] drawn as crosses."""
    import cv2

    img = np.asarray(image)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    scale = min(1.0, width_px / img.shape[1])
    if scale < 1.0:
        img = cv2.resize(img, (int(round(img.shape[1] * scale)), int(round(img.shape[0] * scale))),
                         interpolation=cv2.INTER_AREA)
    pts = np.asarray(points_lidar, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).round().astype(int)]
    p_cam = transform_points(T_camera_lidar, pts)
    front = p_cam[:, 2] > 0.1
    uv, valid = camera.project(p_cam[front])
    uv, depth = uv[valid] * scale, p_cam[front][valid, 2]
    if len(depth):
        lo, hi = np.percentile(depth, [2, 98])
        t = np.clip((depth - lo) / max(hi - lo, 1e-6), 0, 1)
        colours = cv2.applyColorMap((255 * (1 - t)).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_JET).reshape(-1, 3)
        for (u, v), c in zip(uv.astype(int), colours):
            img[max(v - 1, 0):v + 1, max(u - 1, 0):u + 1] = c
    if circles_camera is not None:
        c = np.asarray(circles_camera, dtype=float).reshape(-1, 3)
        c = c[np.all(np.isfinite(c), axis=1)]
        if len(c):
            uvc, ok = camera.project(c)
            fx = float(np.asarray(getattr(camera, "params", [500.0]))[0])
            for (u, v), z, good in zip(uvc * scale, c[:, 2], ok):
                if good:
                    r = max(int(round(fx * hole_radius_m / z * scale)), 2)
                    cv2.circle(img, (int(round(u)), int(round(v))), r, CIRCLE_BGR, 2, cv2.LINE_AA)
    if lidar_centres is not None:
        c = transform_points(T_camera_lidar, np.asarray(lidar_centres, dtype=float).reshape(-1, 3))
        c = c[np.all(np.isfinite(c), axis=1) & (c[:, 2] > 0.1)]
        if len(c):
            uvl, ok = camera.project(c)
            for (u, v), good in zip(uvl * scale, ok):
                if good:
                    cv2.drawMarker(img, (int(round(u)), int(round(v))), CROSS_BGR, cv2.MARKER_CROSS, 14, 2)
    return img


def jpeg_base64(image: np.ndarray, quality: int = 80) -> str:
    import cv2

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGR image
        raise ValueError("JPEG encoding failed")
    return base64.b64encode(buf.tobytes()).decode("ascii")


def _spread(indices: list[int], n: int) -> list[int]:
    if len(indices) <= n:
        return indices
    return [indices[i] for i in np.linspace(0, len(indices) - 1, n).round().astype(int)]


def raw_overlays(recording: Any, rig: Any, placements: Iterable[Any], dataset: Dataset,
                 result: CalibrationResult, max_images: int = 4, width_px: int = 960) -> list[dict[str, Any]]:
    """For up to ``max_images`` placements per (camera, lidar) pair: the lidar scan on the camera
    image (:func:`lidar_on_image`) as report entries ``{camera, lidar, board, t_s, jpeg_base64}``.
    A camera without a usable model, or a placement without a frame of both, is skipped (logged)."""
    # the detection pipeline's own camera model of a rig sensor (intrinsics file or CameraInfo)
    from rigcal.detect.pipeline import camera_model as camera_model_of
    from rigcal.sensors.camera.pinhole import PinholeCamera

    placements = list(placements)
    cameras = [s for s in rig.sensors if s.kind is SensorKind.CAMERA and s.name in result.sensors]
    lidars = [s for s in rig.sensors if s.kind is SensorKind.LIDAR and s.name in result.sensors]
    out: list[dict[str, Any]] = []
    t0 = min((p.start_ns for p in placements), default=0)
    for cam in cameras:
        if cam.input == "stereo_pair":
            st = cam.stereo
            model = None  # its size comes with the first image
        else:
            try:
                model = camera_model_of(cam, rig, recording)
            except Exception as exc:  # noqa: BLE001 - a report image is never worth failing a run
                log.warning("report: no camera model for '%s' (%s); no lidar-on-image overlay", cam.name, exc)
                continue
        for lidar in lidars:
            T_cl = result.T(cam.name, lidar.name)
            det_cam = dataset.sensor(cam.name) if cam.name in dataset.names else None
            det_lid = dataset.sensor(lidar.name) if lidar.name in dataset.names else None
            seen = [k for k, p in enumerate(placements) if det_cam is not None and k < dataset.num_boards
                    and bool(det_cam.detected[k])]
            for k in _spread(seen, max_images):
                p = placements[k]
                topics = {"camera": (cam.topic, SensorKind.CAMERA), "lidar": (lidar.topic, SensorKind.LIDAR)}
                got: dict[str, Any] = {}
                for frame in recording.frames(topics, p.start_ns, p.end_ns + 1):
                    got.setdefault(frame.sensor, frame)
                    if len(got) == 2:
                        break
                if len(got) < 2:
                    log.info("report: placement %d has no frame of both %s and %s", k, cam.name, lidar.name)
                    continue
                image = got["camera"].image
                cam_model = model
                if cam_model is None:
                    h, w = image.shape[:2]
                    cam_model = PinholeCamera.from_intrinsics(w, h, st["fx"], st["fy"], st["cx"], st["cy"])
                img = lidar_on_image(
                    image, cam_model, got["lidar"].points_xyz, T_cl,
                    circles_camera=np.asarray(det_cam.points[k]) if det_cam is not None else None,
                    hole_radius_m=dataset.board.hole_diameter_m / 2,
                    lidar_centres=np.asarray(det_lid.points[k]) if det_lid is not None and det_lid.detected[k] else None,
                    width_px=width_px,
                )
                out.append({"camera": cam.name, "lidar": lidar.name, "board": int(k),
                            "t_s": round((got["camera"].t_ns - t0) / 1e9, 2), "jpeg_base64": jpeg_base64(img)})
    return out


def with_raw(report: Mapping[str, Any], images: list[dict[str, Any]]) -> dict[str, Any]:
    """``report`` with the raw-data images added (``raw.images``)."""
    return {**report, "raw": {"images": images}}


__all__ = ["jpeg_base64", "lidar_on_image", "raw_overlays", "with_raw"]
