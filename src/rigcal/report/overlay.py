"""Overlays of a motion-capture calibration, like Figs. 4-6 of Charron et al.

The MCS knows every target's pose at every measurement, so the calibration can be checked by
eye:

* camera (Fig. 5): the image with the target's outline and keypoints projected through the
  MCS pose and the *initial* (red) and the *final* (green) ``T_robot_camera``, and the measured
  keypoints (blue). A planar target with lidar keypoints (the diamond) is outlined by the
  polygon through them; other targets by a sample of their template points.
* lidar (Figs. 4 and 6): the target's template placed in the robot frame by the MCS (blue) and
  the scan points on the target mapped into the robot frame with the initial (red) and the
  optimised (green) ``T_robot_lidar``: the green points should lie on the blue ones. A second
  panel shows the same points in the MCS target frame, edge-on for a plate (x, z) and along
  the axis for other targets (x, y), where an offset is easiest to see.

Images are PNG bytes; :func:`write_overlays` writes a few per sensor atomically. OpenCV and
matplotlib (Agg) are imported inside the functions that draw.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import invert, transform_points
from rigcal.targets.definition import Target

__all__ = [
    "BLUE_BGR",
    "GREEN_BGR",
    "OverlayInput",
    "RED_BGR",
    "camera_overlay_image",
    "camera_overlay_png",
    "lidar_overlay_png",
    "overlay_file_name",
    "overlay_png",
    "write_overlays",
]

RED_BGR = (0, 0, 255)
GREEN_BGR = (0, 190, 0)
BLUE_BGR = (255, 80, 0)
_MAX_TEMPLATE_POINTS = 2500


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class OverlayInput:
    """One kept measurement to draw: the sensor's name and kind (``"lidar"`` / ``"camera"``),
    the target, the time, the MCS target pose ``T_robot_target`` (4, 4), the measured keypoints
    ``measured`` ((N, 2) px or (N, 3) m in the sensor frame), and the raw data to draw on: the
    ``image`` (camera, uint8 mono or BGR) with its ``camera`` model, or the scan points on the
    target ``points_sensor`` (lidar, (M, 3) m in the lidar frame)."""

    sensor: str
    kind: str
    target: Target
    t_ns: int
    T_robot_target: np.ndarray
    measured: np.ndarray
    image: np.ndarray | None = None
    camera: Any = None
    points_sensor: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("lidar", "camera"):
            raise InputError(f"overlay of '{self.sensor}': kind must be lidar or camera, got "
                             f"{self.kind!r}")
        if self.kind == "camera" and (self.image is None or self.camera is None):
            raise InputError(f"overlay of '{self.sensor}': a camera overlay needs the image and "
                             "the camera model")
        if self.kind == "lidar" and self.points_sensor is None:
            raise InputError(f"overlay of '{self.sensor}': a lidar overlay needs the scan points")


def _sample(points: np.ndarray, n: int) -> np.ndarray:
    if len(points) <= n:
        return points
    idx = np.linspace(0, len(points) - 1, n).round().astype(int)
    return points[idx]


def _outline_polygon(target: Target) -> np.ndarray | None:
    """The closed outline (K, 3) of a planar target with keypoints on its rim (the diamond's
    corners), else None."""
    kp = target.lidar_keypoints
    if target.planar and kp is not None and len(kp) >= 3:
        return kp
    return None


# --------------------------------------------------------------------------------------------
# camera


def _to_bgr(image: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise InputError(f"overlay: expected a uint8 image, got {img.dtype} {img.shape}")
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()


def _project(camera: Any, T_camera_target: np.ndarray, points_target: np.ndarray) -> np.ndarray:
    uv, _ = camera.project(transform_points(T_camera_target, points_target))
    return np.asarray(uv, dtype=float)


def camera_overlay_image(
    image: np.ndarray,
    camera: Any,
    target: Target,
    T_robot_target: np.ndarray,
    T_robot_camera_initial: np.ndarray,
    T_robot_camera_final: np.ndarray,
    measured_px: np.ndarray,
    *,
    crop: bool = True,
    max_side_px: int = 1600,
    label: str = "",
) -> np.ndarray:
    """The BGR overlay image (see the module docstring): projections with the initial (red)
    and final (green) calibration, measured keypoints (blue). With ``crop`` the image is cut
    to the drawn region plus a margin; it is then shrunk to at most ``max_side_px``."""
    import cv2

    out = _to_bgr(image)
    h, w = out.shape[:2]
    scale_line = max(1, int(round(max(h, w) / 800)))
    kp = target.camera_points
    if target.camera_keypoints is None:
        kp = _sample(kp, 400)
    outline = _outline_polygon(target)
    drawn: list[np.ndarray] = [np.asarray(measured_px, dtype=float).reshape(-1, 2)]
    for T_rc, colour in ((T_robot_camera_initial, RED_BGR), (T_robot_camera_final, GREEN_BGR)):
        T_ct = invert(np.asarray(T_rc, dtype=float)) @ np.asarray(T_robot_target, dtype=float)
        uv = _project(camera, T_ct, kp)
        ok = np.all(np.isfinite(uv), axis=1)
        drawn.append(uv[ok])
        for u, v in uv[ok]:
            cv2.circle(out, (int(round(u)), int(round(v))), 2 * scale_line + 1, colour,
                       scale_line, cv2.LINE_AA)
        if outline is not None:
            poly = _project(camera, T_ct, outline)
            if np.all(np.isfinite(poly)):
                drawn.append(poly)
                cv2.polylines(out, [np.round(poly).astype(np.int32).reshape(-1, 1, 2)], True,
                              colour, scale_line + 1, cv2.LINE_AA)
    arm = 3 * scale_line + 2
    for u, v in drawn[0]:
        if np.isfinite(u) and np.isfinite(v):
            p = (int(round(u)), int(round(v)))
            cv2.drawMarker(out, p, BLUE_BGR, cv2.MARKER_CROSS, 2 * arm, scale_line, cv2.LINE_AA)
    if crop:
        pts = np.vstack([d for d in drawn if len(d)])
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts):
            lo = pts.min(axis=0)
            hi = pts.max(axis=0)
            pad = max(40.0, 0.15 * float(np.max(hi - lo)))
            u0, v0 = (max(int(x), 0) for x in np.floor(lo - pad))
            u1, v1 = int(min(math.ceil(hi[0] + pad), w)), int(min(math.ceil(hi[1] + pad), h))
            if u1 - u0 >= 16 and v1 - v0 >= 16:
                out = out[v0:v1, u0:u1].copy()
    side = max(out.shape[:2])
    if side > max_side_px:
        f = max_side_px / side
        out = cv2.resize(out, (max(1, int(out.shape[1] * f)), max(1, int(out.shape[0] * f))),
                         interpolation=cv2.INTER_AREA)
    return _with_banner(out, label)


def _with_banner(image: np.ndarray, label: str) -> np.ndarray:
    """``image`` under a white banner with ``label`` and the colour legend (at least 460 px
    wide, the image centred on a grey canvas when narrower)."""
    import cv2

    h, w = image.shape[:2]
    width = max(w, 460)
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    banner_h = 48 if label else 26
    canvas = np.full((h + banner_h, width, 3), 128, dtype=np.uint8)
    canvas[:banner_h] = 255
    x0 = (width - w) // 2
    canvas[banner_h:, x0:x0 + w] = image
    y = 18
    if label:
        cv2.putText(canvas, label, (8, y), font, fs, (0, 0, 0), 1, cv2.LINE_AA)
        y += 22
    x = 8
    for text, colour in (("initial", RED_BGR), ("final", GREEN_BGR), ("measured", BLUE_BGR)):
        cv2.putText(canvas, text, (x, y), font, fs, colour, 1, cv2.LINE_AA)
        x += cv2.getTextSize(text, font, fs, 1)[0][0] + 16
    return canvas


def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise InputError("overlay: cannot PNG-encode the image")
    return bytes(buf.tobytes())


def camera_overlay_png(*args: Any, **kwargs: Any) -> bytes:
    """:func:`camera_overlay_image` encoded as PNG bytes."""
    return _png(camera_overlay_image(*args, **kwargs))


# --------------------------------------------------------------------------------------------
# lidar


def lidar_overlay_png(
    target: Target,
    T_robot_target: np.ndarray,
    points_lidar: np.ndarray,
    T_robot_lidar_initial: np.ndarray,
    T_robot_lidar_final: np.ndarray,
    *,
    title: str = "",
    dpi: int = 100,
) -> bytes:
    """PNG bytes of the lidar overlay (see the module docstring): the template placed by the
    MCS (blue) and ``points_lidar`` (M, 3) [m, lidar frame] mapped with the initial (red) and
    final (green) ``T_robot_lidar``, in the robot frame (left) and in the target frame
    (right)."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    T_rt = np.asarray(T_robot_target, dtype=float)
    tpl_t = _sample(np.asarray(target.template, dtype=float), _MAX_TEMPLATE_POINTS)
    pts = np.asarray(points_lidar, dtype=float).reshape(-1, 3)
    sets_robot = {
        "template (MCS)": transform_points(T_rt, tpl_t),
        "scan, initial": transform_points(T_robot_lidar_initial, pts),
        "scan, final": transform_points(T_robot_lidar_final, pts),
    }
    T_tr = invert(T_rt)
    sets_target = {k: transform_points(T_tr, v) for k, v in sets_robot.items()}
    style = {
        "template (MCS)": dict(c="tab:blue", s=2, alpha=0.35),
        "scan, initial": dict(c="tab:red", s=8, alpha=0.9),
        "scan, final": dict(c="tab:green", s=8, alpha=0.9),
    }
    fig = Figure(figsize=(13, 5.5), dpi=dpi)
    FigureCanvasAgg(fig)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax3.set_title("robot frame, seen from the sensor")
    for k, p in sets_robot.items():
        ax3.scatter(p[:, 0], p[:, 1], p[:, 2], label=k, depthshade=False, **style[k])
    allp = np.vstack(list(sets_robot.values()))
    centre = 0.5 * (allp.min(axis=0) + allp.max(axis=0))
    half = 0.5 * float(np.max(allp.max(axis=0) - allp.min(axis=0))) + 1e-3
    ax3.set_xlim(centre[0] - half, centre[0] + half)
    ax3.set_ylim(centre[1] - half, centre[1] + half)
    ax3.set_zlim(centre[2] - half, centre[2] + half)
    # look from the sensor at the target (face-on for a plate facing it)
    centre_t = sets_robot["template (MCS)"].mean(axis=0)
    eye = np.asarray(T_robot_lidar_final, dtype=float)[:3, 3] - centre_t
    eye = eye / max(float(np.linalg.norm(eye)), 1e-9)
    ax3.view_init(elev=math.degrees(math.asin(float(np.clip(eye[2], -1.0, 1.0)))),
                  azim=math.degrees(math.atan2(float(eye[1]), float(eye[0]))))
    ax3.set_xlabel("x_robot [m]")
    ax3.set_ylabel("y_robot [m]")
    ax3.set_zlabel("z_robot [m]")
    ax3.legend(loc="upper left", fontsize=8, markerscale=2)
    ax2 = fig.add_subplot(1, 2, 2)
    a, b = (0, 2) if target.planar else (0, 1)
    names = "xyz"
    for k, p in sets_target.items():
        ax2.scatter(p[:, a], p[:, b], label=k, **style[k])
    if not target.planar:  # edge-on views keep their own scale: offsets off the plate show
        ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel(f"{names[a]}_target [m]")
    ax2.set_ylabel(f"{names[b]}_target [m]")
    ax2.set_title("target frame (MCS), "
                  + ("edge-on, z exaggerated" if target.planar else "along z"))
    ax2.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.subplots_adjust(left=0.03, right=0.98, wspace=0.25)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


# --------------------------------------------------------------------------------------------
# many


def overlay_png(item: OverlayInput, T_robot_sensor_initial: np.ndarray,
                T_robot_sensor_final: np.ndarray) -> bytes:
    """The PNG of one :class:`OverlayInput` for the two calibrations."""
    label = f"{item.sensor} / {item.target.name} / t = {item.t_ns * 1e-9:.3f} s"
    if item.kind == "camera":
        return camera_overlay_png(item.image, item.camera, item.target, item.T_robot_target,
                                  T_robot_sensor_initial, T_robot_sensor_final, item.measured,
                                  label=label)
    return lidar_overlay_png(item.target, item.T_robot_target, item.points_sensor,
                             T_robot_sensor_initial, T_robot_sensor_final, title=label)


_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def overlay_file_name(item: OverlayInput) -> str:
    """``<sensor>_<target>_<t_ns>.png`` with characters unsafe in file names replaced."""
    return _UNSAFE.sub("_", f"{item.sensor}_{item.target.name}_{int(item.t_ns)}") + ".png"


def write_overlays(
    items: Iterable[OverlayInput],
    initial: Mapping[str, np.ndarray],
    final: Mapping[str, np.ndarray],
    out_dir: str | os.PathLike[str],
    max_per_sensor: int = 3,
) -> list[Path]:
    """Write the overlay PNG of at most ``max_per_sensor`` items per sensor (in the given
    order) into ``out_dir`` (created if needed), atomically; returns the paths.
    ``initial`` / ``final``: ``T_robot_sensor`` per sensor name. Lidar overlays are drawn with
    matplotlib: without it (the ``plots`` extra) they are left out, with a warning."""
    import logging

    from rigcal.extras import available, missing_extra_message
    from rigcal.io.atomic import atomic_write_bytes

    out = Path(out_dir)
    written: list[Path] = []
    per_sensor: dict[str, int] = {}
    plots = None
    for item in items:
        if per_sensor.get(item.sensor, 0) >= max_per_sensor:
            continue
        if item.kind != "camera":
            if plots is None:
                plots = available("matplotlib")
                if not plots:
                    logging.getLogger(__name__).warning(
                        "lidar overlays left out: %s", missing_extra_message("matplotlib", "drawing them"))
            if not plots:
                continue
        for name, poses in (("initial", initial), ("final", final)):
            if item.sensor not in poses:
                raise InputError(f"overlay: no {name} calibration for sensor '{item.sensor}'")
        data = overlay_png(item, initial[item.sensor], final[item.sensor])
        written.append(atomic_write_bytes(out / overlay_file_name(item), data))
        per_sensor[item.sensor] = per_sensor.get(item.sensor, 0) + 1
    return written

