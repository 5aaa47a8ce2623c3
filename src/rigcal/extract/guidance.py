"""Guidance from the mocap-predicted target pose (Charron et al., III-C, common pre-processing).

With a motion capture system the target pose in each sensor frame is always approximately
known: ``T_sensor_target_expected = inv(T_robot_sensor_initial) @ T_robot_map @ T_map_target``.
Before extracting anything we

1. check that the target is expected in the sensor's field of view (:func:`camera_view`,
   :func:`lidar_view`);
2. reject frames where the target moves relative to the robot (motion blur, lidar motion
   distortion, time-sync errors are amplified): :func:`relative_speeds`, :func:`motion_check`;
3. crop the sensor data to a region around the expected target whose margins grow with the
   confidence in the initial calibration (:class:`PoseUncertainty`) and with distance:
   :func:`expected_image_box` (camera), :func:`lidar_crop_box` (lidar).

The uncertainty is that of the initial extrinsic calibration: a rotation error ``dtheta`` of
the sensor moves a target at distance ``d`` by ``d * dtheta`` and a translation error ``dt`` by
``dt``, so the margin is ``n_sigma * (sigma_translation_m + d * sigma_rotation_rad)`` metres; in
an image that is ``n_sigma * f * (sigma_rotation_rad + sigma_translation_m / d)`` pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rigcal.errors import InputError
from rigcal.extract.result import NO_POSE_DATA, TARGET_MOVING, TARGET_NOT_IN_VIEW
from rigcal.geometry.se3 import invert, transform_points
from rigcal.geometry.so3 import so3_log

__all__ = [
    "CropBox",
    "MotionCheck",
    "PixelBox",
    "PoseUncertainty",
    "ViewCheck",
    "box_from_points",
    "camera_view",
    "check_pose",
    "check_points",
    "expected_image_box",
    "lidar_crop_box",
    "lidar_view",
    "motion_check",
    "relative_speeds",
]


# ---------------------------------------------------------------------------- validation
def check_pose(T: np.ndarray, what: str) -> np.ndarray:
    """A float (4, 4) copy of a rigid transform; raises InputError naming ``what`` otherwise."""
    m = np.array(T, dtype=float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise InputError(f"{what}: expected a finite 4x4 transform, got shape {m.shape}")
    R = m[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise InputError(f"{what}: the rotation block is not a proper rotation")
    return m


def check_points(points: np.ndarray, what: str, dim: int = 3, minimum: int = 1) -> np.ndarray:
    """A float (N, dim) copy of ``points`` with N >= minimum, finite; InputError otherwise."""
    p = np.array(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != dim:
        raise InputError(f"{what}: expected an (N, {dim}) array, got shape {p.shape}")
    if p.shape[0] < minimum:
        raise InputError(f"{what}: expected at least {minimum} points, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{what}: points must be finite")
    return p


# ---------------------------------------------------------------------------- uncertainty
@dataclass(frozen=True)
class PoseUncertainty:
    """Confidence in the expected target pose, i.e. in the initial sensor calibration.

    ``sigma_translation_m`` [m] and ``sigma_rotation_rad`` [rad] are 1-sigma errors of the
    initial extrinsic; margins are ``n_sigma`` of them. A uniform +-3 cm / +-5 deg perturbation
    (the paper's experiments) has sigma 1.7 cm / 2.9 deg.
    """

    sigma_translation_m: float = 0.03
    sigma_rotation_rad: float = math.radians(3.0)
    n_sigma: float = 3.0

    def __post_init__(self) -> None:
        for name in ("sigma_translation_m", "sigma_rotation_rad", "n_sigma"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0:
                raise InputError(f"PoseUncertainty.{name} must be finite and >= 0, got {v}")
            object.__setattr__(self, name, v)

    def margin_m(self, distance_m: float) -> float:
        """Position margin [m] of a point ``distance_m`` from the sensor."""
        d = max(float(distance_m), 0.0)
        return self.n_sigma * (self.sigma_translation_m + d * self.sigma_rotation_rad)

    def margin_px(self, focal_px: float, distance_m: float) -> float:
        """Image margin [px] of a point at depth ``distance_m`` seen with focal ``focal_px``."""
        d = max(float(distance_m), 1e-3)
        return float(focal_px) * self.margin_m(d) / d


NO_UNCERTAINTY = PoseUncertainty(0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------- field of view
class ViewCheck(NamedTuple):
    """Whether the target is expected in view: ``fraction`` of its points that are;
    ``reason`` is ``""`` when ``visible``, else ``"target_not_in_view"``."""

    visible: bool
    fraction: float
    reason: str
    detail: str


def _view(fraction: float, min_fraction: float, what: str) -> ViewCheck:
    if fraction >= min_fraction and fraction > 0:
        return ViewCheck(True, fraction, "", f"{fraction:.0%} of the {what} in view")
    return ViewCheck(
        False,
        fraction,
        TARGET_NOT_IN_VIEW,
        f"{fraction:.0%} of the {what} expected in view, need {min_fraction:.0%}",
    )


def camera_view(
    camera,
    T_camera_target: np.ndarray,
    points_target: np.ndarray,
    margin_px: float = 0.0,
    min_fraction: float = 1.0,
) -> ViewCheck:
    """Is the target expected in the image?

    ``points_target`` (N, 3) [m] (keypoints or template) are projected with ``camera`` (a
    :class:`rigcal.sensors.camera.CameraModel`) at the expected pose; a point counts when it
    projects at least ``margin_px`` inside the image border. Visible when the fraction is at
    least ``min_fraction``.
    """
    T = check_pose(T_camera_target, "T_camera_target")
    p = check_points(points_target, "points_target")
    uv, valid = camera.project(transform_points(T, p))
    m = float(margin_px)
    with np.errstate(invalid="ignore"):
        inside = (
            valid
            & (uv[:, 0] >= m - 0.5)
            & (uv[:, 0] < camera.width - 0.5 - m)
            & (uv[:, 1] >= m - 0.5)
            & (uv[:, 1] < camera.height - 0.5 - m)
        )
    return _view(float(np.mean(inside)), float(min_fraction), "target points")


def lidar_view(
    T_lidar_target: np.ndarray,
    points_target: np.ndarray,
    min_range_m: float = 0.5,
    max_range_m: float = 100.0,
    elevation_fov_rad: tuple[float, float] = (math.radians(-15.0), math.radians(15.0)),
    azimuth_fov_rad: tuple[float, float] = (-math.pi, math.pi),
    min_fraction: float = 0.5,
) -> ViewCheck:
    """Is the target expected inside the lidar's range and field of view?

    Lidar frame: x forward, y left, z up; azimuth ``atan2(y, x)``, elevation
    ``atan2(z, hypot(x, y))``. The FOV limits are inclusive; an azimuth interval may wrap
    (e.g. ``(3.0, -3.0)`` is the 0.28 rad behind the sensor).
    """
    T = check_pose(T_lidar_target, "T_lidar_target")
    p = transform_points(T, check_points(points_target, "points_target"))
    rng = np.linalg.norm(p, axis=1)
    az = np.arctan2(p[:, 1], p[:, 0])
    el = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    a0, a1 = azimuth_fov_rad
    in_az = (az >= a0) & (az <= a1) if a0 <= a1 else (az >= a0) | (az <= a1)
    ok = (
        (rng >= min_range_m)
        & (rng <= max_range_m)
        & (el >= elevation_fov_rad[0])
        & (el <= elevation_fov_rad[1])
        & in_az
    )
    return _view(float(np.mean(ok)), float(min_fraction), "target points")


# ---------------------------------------------------------------------------- motion
class MotionCheck(NamedTuple):
    """Target motion relative to the robot around one time: the largest speeds seen in the
    window; ``reason`` is ``""`` when ``still``, else ``"target_moving"`` or ``"no_pose_data"``."""

    still: bool
    max_linear_mps: float
    max_angular_radps: float
    reason: str
    detail: str


def _check_track(t_ns: np.ndarray, T_robot_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_ns)
    if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
        raise InputError(
            f"t_ns: expected a 1-D integer array of nanoseconds, got {t.dtype} {t.shape}"
        )
    T = np.asarray(T_robot_target, dtype=float)
    if T.shape != (t.shape[0], 4, 4):
        raise InputError(
            f"T_robot_target: expected ({t.shape[0]}, 4, 4) poses to match t_ns, got {T.shape}"
        )
    if t.shape[0] > 1 and np.any(np.diff(t) <= 0):
        raise InputError("t_ns: pose times must be strictly increasing")
    return t.astype(np.int64), T


def relative_speeds(
    t_ns: np.ndarray, T_robot_target: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finite-difference speeds of the target relative to the robot.

    ``t_ns`` (N,) strictly increasing [ns], ``T_robot_target`` (N, 4, 4). Returns
    ``(t_mid_ns, linear_mps, angular_radps)``, each (N-1,): the interval mid-times, the speed of
    the target origin in the robot frame [m/s] and the rotation rate [rad/s].
    """
    t, T = _check_track(t_ns, T_robot_target)
    if t.shape[0] < 2:
        empty = np.zeros(0)
        return t[:0], empty, empty
    dt = np.diff(t).astype(float) * 1e-9
    lin = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) / dt
    dR = np.swapaxes(T[:-1, :3, :3], -1, -2) @ T[1:, :3, :3]
    ang = np.linalg.norm(so3_log(dR), axis=-1) / dt
    t_mid = t[:-1] + np.diff(t) // 2
    return t_mid, lin, ang


#: the shortest time over which :func:`motion_check` measures a speed [s]
MOTION_BASELINE_S = 0.1


def _window_speeds(t: np.ndarray, T: np.ndarray, lo: int, hi: int, baseline_ns: int) -> tuple[float, float]:
    """The largest linear [m/s] and angular [rad/s] speed between the poses ``T`` (N, 4, 4) at
    ``t`` (N,) [ns] covering ``[lo, hi]``, each over at least ``baseline_ns`` (the whole
    stretch when it is shorter)."""
    a = max(int(np.searchsorted(t, lo, side="right")) - 1, 0)
    b = min(int(np.searchsorted(t, hi, side="left")), t.shape[0] - 1)
    t, T = t[a:b + 1], T[a:b + 1]
    i = np.arange(t.shape[0])
    j = np.searchsorted(t, t + max(int(baseline_ns), 1), side="left")
    keep = j < t.shape[0]
    i, j = (i[keep], j[keep]) if keep.any() else (np.array([0]), np.array([t.shape[0] - 1]))
    dt = (t[j] - t[i]).astype(float) * 1e-9
    lin = np.linalg.norm(T[j, :3, 3] - T[i, :3, 3], axis=1) / dt
    dR = np.swapaxes(T[i, :3, :3], -1, -2) @ T[j, :3, :3]
    ang = np.linalg.norm(so3_log(dR), axis=-1) / dt
    return float(np.max(lin)), float(np.max(ang))


def motion_check(
    t_query_ns: int,
    t_ns: np.ndarray,
    T_robot_target: np.ndarray,
    window_s: float = 0.5,
    max_linear_mps: float = 0.02,
    max_angular_radps: float = math.radians(2.0),
    baseline_s: float = MOTION_BASELINE_S,
) -> MotionCheck:
    """Is the target still relative to the robot around ``t_query_ns``?

    The poses from the last one at or before ``t_query - window_s / 2`` to the first one at or
    after ``t_query + window_s / 2`` are checked against ``max_linear_mps`` [m/s] and
    ``max_angular_radps`` [rad/s]: the speed between every pose and the first one at least
    ``baseline_s`` later (a motion-capture system's noise per sample, 0.15 mm / 0.3 mrad for a
    Vicon, is 0.1 m/s and 6 deg/s between two samples 10 ms apart, but 10 times less over
    0.1 s; a carry of the target lasts longer than that). Fails with ``no_pose_data`` when the
    poses do not cover the window's ends.
    """
    t, T = _check_track(t_ns, T_robot_target)
    if window_s <= 0 or max_linear_mps < 0 or max_angular_radps < 0 or not baseline_s >= 0:
        raise InputError(
            f"motion_check: window_s must be > 0 and the limits >= 0, got {window_s}, "
            f"{max_linear_mps}, {max_angular_radps}"
        )
    half = int(round(window_s * 0.5e9))
    lo, hi = int(t_query_ns) - half, int(t_query_ns) + half
    if t.shape[0] < 2 or t[0] > lo or t[-1] < hi:
        span = f"[{t[0]}, {t[-1]}]" if t.shape[0] else "no poses"
        return MotionCheck(
            False,
            math.nan,
            math.nan,
            NO_POSE_DATA,
            f"poses cover {span} ns, need [{lo}, {hi}] ns around t = {int(t_query_ns)} ns",
        )
    vmax, wmax = _window_speeds(t, T, lo, hi, int(round(baseline_s * 1e9)))
    if vmax <= max_linear_mps and wmax <= max_angular_radps:
        return MotionCheck(True, vmax, wmax, "", f"{vmax:.4f} m/s, {math.degrees(wmax):.3f} deg/s")
    return MotionCheck(
        False,
        vmax,
        wmax,
        TARGET_MOVING,
        f"target moves at {vmax:.4f} m/s and {math.degrees(wmax):.3f} deg/s relative to the "
        f"robot, limits {max_linear_mps:.4f} m/s and {math.degrees(max_angular_radps):.3f} deg/s",
    )


# ---------------------------------------------------------------------------- image crop
class PixelBox(NamedTuple):
    """An axis-aligned pixel region ``u_min <= u < u_max``, ``v_min <= v < v_max`` (integer
    pixel indices: columns and rows of the image array)."""

    u_min: int
    v_min: int
    u_max: int
    v_max: int

    @property
    def width(self) -> int:
        return max(self.u_max - self.u_min, 0)

    @property
    def height(self) -> int:
        return max(self.v_max - self.v_min, 0)

    @property
    def area(self) -> int:
        return self.width * self.height

    def clip(self, width: int, height: int) -> "PixelBox":
        """The part inside a ``width`` x ``height`` image (may be empty: ``area == 0``)."""
        return PixelBox(
            min(max(self.u_min, 0), width),
            min(max(self.v_min, 0), height),
            max(min(self.u_max, width), 0),
            max(min(self.v_max, height), 0),
        )

    def contains(self, uv: np.ndarray) -> np.ndarray:
        """(N,) bool: pixels (N, 2) inside the box (pixel centres at integer coordinates)."""
        p = np.asarray(uv, dtype=float).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return (
                (p[:, 0] >= self.u_min - 0.5)
                & (p[:, 0] < self.u_max - 0.5)
                & (p[:, 1] >= self.v_min - 0.5)
                & (p[:, 1] < self.v_max - 0.5)
            )


def _pixels_per_metre(camera, points_cam: np.ndarray) -> float:
    """Largest image scale [px/m] of lateral motion at the given points (generic model)."""
    J = camera.project_jacobian(points_cam)[:, :, :2]
    ok = np.all(np.isfinite(J), axis=(1, 2))
    if not np.any(ok):
        return math.nan
    return float(np.max(np.linalg.norm(J[ok], ord=2, axis=(1, 2))))


def expected_image_box(
    camera,
    T_camera_target: np.ndarray,
    points_target: np.ndarray,
    uncertainty: PoseUncertainty | None = None,
    margin_px: float = 20.0,
) -> PixelBox | None:
    """Where to look for the target in the image (not clipped to it).

    The bounding box of ``points_target`` (N, 3) [m] projected at the expected pose, grown by
    ``margin_px`` plus the calibration uncertainty's margin at the nearest point's depth (the
    image scale there times :meth:`PoseUncertainty.margin_m`). None when no point is in front of
    the camera inside the model's domain.
    """
    T = check_pose(T_camera_target, "T_camera_target")
    pc = transform_points(T, check_points(points_target, "points_target"))
    uv, _ = camera.project(pc)
    ok = np.all(np.isfinite(uv), axis=1)
    if not np.any(ok):
        return None
    unc = uncertainty or NO_UNCERTAINTY
    depth = float(np.min(np.linalg.norm(pc[ok], axis=1)))
    scale = _pixels_per_metre(camera, pc[ok])
    grow = float(margin_px) + (scale * unc.margin_m(depth) if math.isfinite(scale) else 0.0)
    lo = uv[ok].min(axis=0) - grow
    hi = uv[ok].max(axis=0) + grow
    return PixelBox(
        int(math.floor(lo[0] + 0.5)),
        int(math.floor(lo[1] + 0.5)),
        int(math.ceil(hi[0] + 0.5)),
        int(math.ceil(hi[1] + 0.5)),
    )


# ---------------------------------------------------------------------------- lidar crop
def box_from_points(points_target: np.ndarray, pad_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds ``(min_xyz, max_xyz)`` of points (N, 3) grown by ``pad_m`` [m]."""
    p = check_points(points_target, "points_target")
    return p.min(axis=0) - pad_m, p.max(axis=0) + pad_m


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class CropBox:
    """A box ``min_xyz <= p <= max_xyz`` in the expected target frame, placed in the sensor
    frame by ``T_sensor_box`` (4, 4)."""

    T_sensor_box: np.ndarray
    min_xyz: np.ndarray
    max_xyz: np.ndarray

    def __post_init__(self) -> None:
        for name in ("T_sensor_box", "min_xyz", "max_xyz"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def contains(self, points_sensor: np.ndarray) -> np.ndarray:
        """(N,) bool: which points (N, 3) in the sensor frame lie in the box."""
        q = transform_points(invert(self.T_sensor_box), np.asarray(points_sensor, dtype=float))
        return np.all((q >= self.min_xyz) & (q <= self.max_xyz), axis=1)

    @property
    def size_m(self) -> np.ndarray:
        return self.max_xyz - self.min_xyz


def lidar_crop_box(
    T_lidar_target: np.ndarray,
    box_min_target: np.ndarray,
    box_max_target: np.ndarray,
    uncertainty: PoseUncertainty | None = None,
) -> CropBox:
    """The crop box around the expected target: the target-frame box ``[box_min, box_max]``
    (e.g. the template's bounds plus a fixed pad) grown on every side by the uncertainty's
    margin at the distance of the box centre."""
    T = check_pose(T_lidar_target, "T_lidar_target")
    lo = np.array(box_min_target, dtype=float).reshape(3)
    hi = np.array(box_max_target, dtype=float).reshape(3)
    if np.any(hi < lo):
        raise InputError(f"crop box: max {hi.tolist()} is below min {lo.tolist()}")
    centre = transform_points(T, 0.5 * (lo + hi)[None, :])[0]
    grow = (uncertainty or NO_UNCERTAINTY).margin_m(float(np.linalg.norm(centre)))
    return CropBox(T, lo - grow, hi + grow)
