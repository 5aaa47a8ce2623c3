"""Raw simulation of the motion-capture calibration setup (Charron et al., section IV-A).

A robot tracked by a motion capture system (MCS) carries a VLP-16-like lidar and a 2048 x 1536
pinhole camera (no lens distortion, the F1 camera's focal lengths and principal point); a target
- the diamond with a checkerboard or the green cylinder - is moved around it and, at every
measurement, held still somewhere in one sensor's view. The MCS reports the robot's pose
``T_map_robot`` and the target's pose ``T_map_target``, exactly or with noise. This module makes
the raw data the extractors see: ray-cast lidar scans and rendered camera images.

Frames (metres, :doc:`conventions`): the map frame ``map`` is the MCS frame with z up and the
floor at ``z = 0``; the robot frame ``robot`` sits on the floor (x forward, y left, z up); the
lidar frame is x forward, y left, z up; the camera frame is the optical frame (x right, y down, z
forward). Target frames are those of :mod:`rigcal.targets.templates`:

* diamond: origin at the checkerboard's outer corner, plate in z = 0, z out of the printed face;
  placed with its face toward the sensor, x to the sensor's right and y up (so its corners point
  up, down, left and right), then yawed, pitched and rolled at random;
* cylinder: axis z, top end at z = 0, body down to ``-height_m``; placed upright, tilted up to
  ``cylinder_tilt_deg`` about a random horizontal axis and spun at random about its axis.

Data:

* lidar: one instantaneous revolution (16 rings from -15 to +15 deg, 0.2 deg azimuth step, a
  random azimuth offset per scan) cast against the target, the floor, a few clutter boxes
  standing on it and the walls of a room; ranges exact unless ``lidar_range_sigma_m`` is set
  (the paper adds no lidar noise). A :class:`~rigcal.recording.PointCloudFrame` with ``ring``
  and ``intensity``; optionally only the returns within an azimuth window (a Velodyne's FOV
  setting).
* camera: the whole frame is a grey background (the paper's Gazebo world); the target is drawn
  inside its projected bounding box only, with analytic anti-aliasing (the checkerboard is box
  filtered over each pixel's footprint on the plate, plate edges by their pixel distance; the
  cylinder is supersampled). Gaussian pixel noise of ``pixel_noise_sigma`` grey levels (1.8 as
  in the paper) is added everywhere. Diamond images are mono, cylinder images BGR (green on
  grey). Clutter is not drawn in images. Distorted camera models (radtan, Kannala-Brandt, ...)
  are rendered by casting every pixel's ray through the model (:func:`render_image`).
* MCS: exact poses (the paper), or each pose perturbed on the right by a translation with
  ``mcs_noise_m`` per axis and a rotation with ``mcs_noise_m / marker_baseline_m`` rad per axis
  (markers ``marker_baseline_m`` apart measured to ``mcs_noise_m``; the Vicon figure is
  0.15 mm).

Targets are read from the original tool's files when they can be (:func:`paper_targets`):
``CheckerboardTargetSim.json`` (a 0.5 m diamond, 7 x 6 inner corners of 29 mm) and
``CylinderTarget.json`` (which holds no dimensions: radius 56.4 mm and height 495.3 mm are those
of the tool's ``cylinder_target_rotated.pcd``). Without the files the same values are used.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from rigcal.errors import GeometryError, InputError, RigcalError
from rigcal.geometry.se3 import as_rigid, from_rt, invert, se3_exp, transform_points
from rigcal.geometry.so3 import matrix_from_rpy, so3_exp
from rigcal.recording import ImageFrame, PointCloudFrame
from rigcal.sensors.camera.base import MIN_DEPTH_M, CameraModel
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sim.raw.lidar import LidarModel, vlp16
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.templates import cylinder_target, diamond_target

__all__ = [
    "CYLINDER_HEIGHT_M",
    "CYLINDER_RADIUS_M",
    "F1_INTRINSICS",
    "Appearance",
    "Box",
    "MocapCapture",
    "MocapRig",
    "MocapSimulation",
    "PaperTargets",
    "Placement",
    "SensorView",
    "cast_lidar",
    "check_azimuth_fov",
    "paper_rig",
    "paper_targets",
    "render_image",
    "sample_pose_in_view",
    "sample_target_pose",
    "sees_part",
    "simulate_mocap",
    "target_centre",
]

#: (fx, fy, cx, cy) [px] of the shared ``F1_sim.json`` (its radtan distortion is dropped: the
#: paper simulates an undistorted pinhole camera).
F1_INTRINSICS = (2352.65873010560, 2352.63261236703, 1023.59896018009, 766.135645001119)
F1_SIZE = (2048, 1536)

#: The original tool's cylinder (``cylinder_target_rotated.pcd``): a 56.4 mm tube, 495.3 mm long.
CYLINDER_RADIUS_M = 0.0564
CYLINDER_HEIGHT_M = 0.4953

R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

SURFACE_TARGET, SURFACE_GROUND, SURFACE_CLUTTER = 0, 1, 2

LIDAR = "lidar"
CAMERA = "camera"


# --------------------------------------------------------------------------------------------
# the rig


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapRig:
    """The robot: a lidar and a camera with their true extrinsics ``T_robot_lidar`` and
    ``T_robot_camera`` (4, 4) (the values a calibration should recover)."""

    T_robot_lidar: np.ndarray
    T_robot_camera: np.ndarray
    lidar: LidarModel
    camera: PinholeCamera
    lidar_name: str = "lidar1"
    camera_name: str = "camera1"

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_robot_lidar", as_rigid(self.T_robot_lidar, "MocapRig.T_robot_lidar"))
        object.__setattr__(self, "T_robot_camera", as_rigid(self.T_robot_camera, "MocapRig.T_robot_camera"))
        if not isinstance(self.lidar, LidarModel):
            raise InputError(f"MocapRig.lidar must be a LidarModel, got {type(self.lidar).__name__}")
        if self.lidar_name == self.camera_name:
            raise InputError(f"MocapRig: lidar and camera need different names, both are '{self.lidar_name}'")

    def name_of(self, kind: str) -> str:
        return self.lidar_name if kind == LIDAR else self.camera_name

    def T_robot_sensor(self, kind: str) -> np.ndarray:
        return self.T_robot_lidar if kind == LIDAR else self.T_robot_camera


def paper_rig(overlapping: bool = False, lidar: LidarModel | None = None) -> MocapRig:
    """A Husky-like robot: the lidar 0.65 m above the floor looking forward (slightly rolled,
    pitched and yawed), the camera 0.55 m up looking left (``overlapping=False``: no shared
    view) or forward next to the lidar (``overlapping=True``). The lidar is a noise-free VLP-16
    unless ``lidar`` is given; the camera an F1-like 2048 x 1536 pinhole."""
    T_rl = from_rt(matrix_from_rpy(np.radians([0.8, -1.5, 2.0])), [0.25, 0.02, 0.65])
    if overlapping:
        R_rc = matrix_from_rpy(np.radians([0.5, 3.0, -4.0])) @ R_BODY_OPTICAL
        T_rc = from_rt(R_rc, [0.30, -0.12, 0.55])
    else:
        R_rc = matrix_from_rpy(np.radians([-0.7, 2.0, 88.0])) @ R_BODY_OPTICAL
        T_rc = from_rt(R_rc, [0.05, 0.22, 0.55])
    return MocapRig(
        T_robot_lidar=T_rl,
        T_robot_camera=T_rc,
        lidar=lidar if lidar is not None else vlp16(range_sigma_m=0.0),
        camera=PinholeCamera.from_intrinsics(*F1_SIZE, *F1_INTRINSICS),
    )


# --------------------------------------------------------------------------------------------
# targets


@dataclass(frozen=True)
class PaperTargets:
    """The paper's two targets and where their definitions came from (file paths, or
    ``"defaults"`` when a file could not be read - ``notes`` says why)."""

    diamond: Target
    cylinder: Target
    diamond_source: str
    cylinder_source: str
    notes: tuple[str, ...] = ()


def _default_data_dir() -> Path | None:
    env = os.environ.get("RIGCAL_VICON_SIM_DIR")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for base in (Path.cwd().parent, Path.cwd(), *here.parents):
        cand = base / "shared" / "data" / "vicon_sim"
        if cand.is_dir():
            return cand
    return None


def paper_targets(data_dir: str | os.PathLike[str] | None = None, resolution_m: float = 0.005) -> PaperTargets:
    """The diamond and cylinder targets, from ``CheckerboardTargetSim.json`` and
    ``CylinderTarget.json`` in ``data_dir`` (default: ``$RIGCAL_VICON_SIM_DIR`` or a
    ``shared/data/vicon_sim`` folder next to the working directory or the package), else from
    the documented defaults (the same dimensions). ``resolution_m``: template sampling step."""
    from rigcal.io.config.vicon_json import read_vicon_target

    d = Path(data_dir) if data_dir is not None else _default_data_dir()
    notes = []
    diamond = cylinder = None
    dsrc = csrc = "defaults"
    if d is not None:
        try:
            diamond = read_vicon_target(d / "CheckerboardTargetSim.json", name="diamond", resolution_m=resolution_m)
            if diamond.kind is not TargetKind.CHECKERBOARD_DIAMOND or "side_m" not in diamond.dims:
                notes.append(f"{d / 'CheckerboardTargetSim.json'} is not a checkerboard diamond; using defaults")
                diamond = None
            else:
                dsrc = str(d / "CheckerboardTargetSim.json")
        except (RigcalError, OSError) as exc:
            notes.append(f"diamond: {exc}; using defaults")
        try:
            cylinder = read_vicon_target(
                d / "CylinderTarget.json", name="cylinder", kind=TargetKind.CYLINDER,
                dims={"radius_m": CYLINDER_RADIUS_M, "height_m": CYLINDER_HEIGHT_M},
                resolution_m=resolution_m,
            )
            csrc = str(d / "CylinderTarget.json")
        except (RigcalError, OSError) as exc:
            notes.append(f"cylinder: {exc}; using defaults")
    else:
        notes.append("no vicon_sim data folder found; using the default target dimensions")
    if diamond is None:
        diamond = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond", resolution_m=resolution_m)
    if cylinder is None:
        cylinder = cylinder_target(CYLINDER_RADIUS_M, CYLINDER_HEIGHT_M, name="cylinder", resolution_m=resolution_m)
    return PaperTargets(diamond, cylinder, dsrc, csrc, tuple(notes))


def _kind(target: Target) -> TargetKind:
    if target.kind not in (TargetKind.CHECKERBOARD_DIAMOND, TargetKind.CYLINDER):
        raise InputError(
            f"target '{target.name}': the mocap simulation draws checkerboard diamonds and "
            f"cylinders, not {target.kind.value}"
        )
    need = ("side_m", "square_m", "rows", "cols") if target.kind is TargetKind.CHECKERBOARD_DIAMOND else ("radius_m", "height_m")
    missing = [k for k in need if k not in target.dims]
    if missing:
        raise InputError(f"target '{target.name}': dims {missing} are needed to simulate it")
    return target.kind


def target_centre(target: Target) -> np.ndarray:
    """(3,) the target's centre in its frame [m]: the diamond's centre, the cylinder's
    mid-axis point."""
    if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND:
        sq = float(target.dims["square_m"])
        return np.array([(int(target.dims["cols"]) + 1) * sq / 2, (int(target.dims["rows"]) + 1) * sq / 2, 0.0])
    return np.array([0.0, 0.0, -float(target.dims["height_m"]) / 2])


def _outline(target: Target) -> np.ndarray:
    """A few points that bound the target (diamond corners; cylinder end circles)."""
    if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND:
        c = target_centre(target)
        h = float(target.dims["side_m"]) / math.sqrt(2)
        return c + np.array([[0, -h, 0], [h, 0, 0], [0, h, 0], [-h, 0, 0]])
    r, hgt = float(target.dims["radius_m"]), float(target.dims["height_m"])
    a = np.linspace(0, 2 * math.pi, 16, endpoint=False)
    ring = np.column_stack([r * np.cos(a), r * np.sin(a)])
    return np.vstack([np.column_stack([ring, np.zeros(16)]), np.column_stack([ring, np.full(16, -hgt)])])


# --------------------------------------------------------------------------------------------
# scene pieces


@dataclass(frozen=True, eq=False)
class Box:
    """An axis-aligned box in the map frame: ``min_xyz`` <= p <= ``max_xyz`` [m]."""

    min_xyz: np.ndarray
    max_xyz: np.ndarray

    def __post_init__(self) -> None:
        lo = np.array(self.min_xyz, dtype=float).reshape(3)
        hi = np.array(self.max_xyz, dtype=float).reshape(3)
        if np.any(hi <= lo):
            raise InputError(f"Box: max {hi.tolist()} must exceed min {lo.tolist()}")
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "min_xyz", lo)
        object.__setattr__(self, "max_xyz", hi)


@dataclass(frozen=True)
class Appearance:
    """Grey levels and colours of the rendered scene (before shading ``0.8 + 0.2 |cos|``)."""

    background_grey: float = 110.0
    plate_white: float = 235.0
    checker_black: float = 20.0
    cylinder_bgr: tuple[float, float, float] = (50.0, 175.0, 60.0)
    background_bgr: tuple[float, float, float] = (112.0, 110.0, 108.0)
    plate_reflectivity: float = 0.8
    cylinder_reflectivity: float = 0.5
    ground_reflectivity: float = 0.2
    clutter_reflectivity: float = 0.4


@dataclass(frozen=True)
class Placement:
    """Where targets may be held: centre ``distance_range_m`` from the sensor; the lidar sees
    the target within ``lidar_azimuth_deg`` of its x axis and with every outline point inside
    ``lidar_elevation_margin_deg`` of the beam fan; the camera sees the whole target at least
    ``image_margin_px`` inside the image. Diamond faces are turned from facing the sensor by up
    to ``yaw_deg`` / ``pitch_deg`` and rolled in their plane by up to ``roll_deg``; cylinders are
    tilted up to ``cylinder_tilt_deg``. Every target point stays ``ground_clearance_m`` above the
    floor. A pose that must stay out of other sensors' views (:func:`sample_pose_in_view`'s
    ``avoid``) keeps every target point ``avoid_margin_deg`` outside a lidar's beam fan and
    azimuth window and ``avoid_margin_px`` outside a camera's image (see :func:`sees_part`)."""

    distance_range_m: tuple[float, float] = (1.5, 5.0)
    lidar_azimuth_deg: float = 60.0
    lidar_elevation_margin_deg: float = 1.0
    image_margin_px: float = 40.0
    yaw_deg: float = 45.0
    pitch_deg: float = 30.0
    roll_deg: float = 20.0
    cylinder_tilt_deg: float = 35.0
    ground_clearance_m: float = 0.1
    robot_area_m: float = 2.0
    clutter_boxes: int = 3
    room_half_size_m: float = 8.0
    avoid_margin_deg: float = 2.0
    avoid_margin_px: float = 20.0

    def __post_init__(self) -> None:
        lo, hi = self.distance_range_m
        if not 0 < lo <= hi:
            raise InputError(f"Placement.distance_range_m must be 0 < min <= max, got {self.distance_range_m}")
        if self.clutter_boxes < 0:
            raise InputError(f"Placement.clutter_boxes must be >= 0, got {self.clutter_boxes}")
        for name in ("avoid_margin_deg", "avoid_margin_px"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"Placement.{name} must be a number >= 0, got {v!r}")


# --------------------------------------------------------------------------------------------
# a sensor in the scene


def check_azimuth_fov(value: object, what: str) -> tuple[float, float] | None:
    """``None`` or a lidar's azimuth window ``(lo, hi)`` [deg] with ``-180 <= lo < hi <= 180``,
    as floats; InputError naming ``what`` otherwise."""
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected (lo, hi) in degrees or None, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and -180.0 <= lo < hi <= 180.0):
        raise InputError(f"{what}: expected -180 <= lo < hi <= 180 [deg], got {value!r}")
    return lo, hi


@dataclass(frozen=True, eq=False)  # holds an array: compare by identity
class SensorView:
    """One sensor placed in the map: its ``model`` (a :class:`LidarModel` or a camera model of
    :mod:`rigcal.sensors.camera`), its pose ``T_map_sensor`` (4, 4) and, for a lidar,
    ``azimuth_fov_deg`` ``(lo, hi)`` [deg, lidar frame, counter-clockwise from +x]: the window
    its returns are kept in (None: all around)."""

    model: LidarModel | CameraModel
    T_map_sensor: np.ndarray
    azimuth_fov_deg: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.model, (LidarModel, CameraModel)):
            raise InputError(f"SensorView.model must be a LidarModel or a CameraModel, got {type(self.model).__name__}")
        object.__setattr__(self, "T_map_sensor", as_rigid(self.T_map_sensor, "SensorView.T_map_sensor"))
        fov = check_azimuth_fov(self.azimuth_fov_deg, "SensorView.azimuth_fov_deg")
        if fov is not None and not self.is_lidar:
            raise InputError("SensorView.azimuth_fov_deg: only a lidar has an azimuth window")
        object.__setattr__(self, "azimuth_fov_deg", fov)

    @property
    def is_lidar(self) -> bool:
        return isinstance(self.model, LidarModel)

    @property
    def kind(self) -> str:
        """``"lidar"`` or ``"camera"``."""
        return LIDAR if self.is_lidar else CAMERA


# --------------------------------------------------------------------------------------------
# ray casting


def _rays_to_local(T_frame_obj: np.ndarray, origin: np.ndarray, dirs: np.ndarray):
    """Ray origin (3,) and directions (N, 3) given in ``frame`` expressed in the object frame."""
    R, t = T_frame_obj[:3, :3], T_frame_obj[:3, 3]
    return R.T @ (origin - t), dirs @ R


def _hit_diamond(target: Target, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (N,) to the diamond plate (inf if missed) and |cos incidence| (N,); rays in the
    target frame."""
    c = target_centre(target)
    h = float(target.dims["side_m"]) / math.sqrt(2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
    p = o[None, :2] + t[:, None] * d[:, :2]
    inside = (np.abs(p[:, 0] - c[0]) + np.abs(p[:, 1] - c[1]) <= h) & (t > 0)
    return np.where(inside, t, np.inf), np.abs(d[:, 2])


def _hit_cylinder(target: Target, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (N,) to the closed cylinder (inf if missed) and |cos incidence| (N,)."""
    r, hgt = float(target.dims["radius_m"]), float(target.dims["height_m"])
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (o[0] * d[:, 0] + o[1] * d[:, 1])
    cc = o[0] ** 2 + o[1] ** 2 - r * r
    disc = b * b - 4 * a * cc
    best = np.full(len(d), np.inf)
    cos = np.zeros(len(d))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        z = o[2] + t_side * d[:, 2]
        ok = (disc > 0) & (a > 1e-12) & (t_side > 0) & (z <= 0) & (z >= -hgt)
        best[ok] = t_side[ok]
        px = o[0] + t_side * d[:, 0]
        py = o[1] + t_side * d[:, 1]
        cos[ok] = np.abs(px[ok] * d[ok, 0] + py[ok] * d[ok, 1]) / r
        for zc in (0.0, -hgt):
            tc = (zc - o[2]) / d[:, 2]
            x = o[0] + tc * d[:, 0]
            y = o[1] + tc * d[:, 1]
            okc = (tc > 0) & (x * x + y * y <= r * r) & (tc < best)
            best[okc] = tc[okc]
            cos[okc] = np.abs(d[okc, 2])
    return best, cos


def _hit_target(target: Target, o: np.ndarray, d: np.ndarray):
    if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND:
        return _hit_diamond(target, o, d)
    return _hit_cylinder(target, o, d)


def _hit_boxes(boxes: Sequence[Box], o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (N,) to the nearest box (inf if none) and |cos incidence|; rays in the map frame."""
    best = np.full(len(d), np.inf)
    cos = np.zeros(len(d))
    if not boxes:
        return best, cos
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
    for bx in boxes:
        with np.errstate(invalid="ignore"):
            t1 = (bx.min_xyz - o) * inv
            t2 = (bx.max_xyz - o) * inv
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        tmin = np.nan_to_num(tmin, nan=-np.inf)
        tmax = np.nan_to_num(tmax, nan=np.inf)
        t_in = tmin.max(axis=1)
        axis = tmin.argmax(axis=1)
        t_out = tmax.min(axis=1)
        ok = (t_in <= t_out) & (t_in > 0) & (t_in < best)
        best[ok] = t_in[ok]
        cos[ok] = np.abs(d[ok, axis[ok]])
    return best, cos


def _lidar_rays(model: LidarModel, offset_deg: float) -> tuple[np.ndarray, np.ndarray]:
    el = np.radians(np.asarray(model.vertical_angles_deg))
    az = np.radians(offset_deg + model.azimuth_step_deg * np.arange(model.num_azimuths))
    ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
    dirs = np.stack(np.broadcast_arrays(ce * np.cos(az)[:, None], ce * np.sin(az)[:, None], se), axis=-1)
    rings = np.broadcast_to(np.arange(model.num_rings, dtype=np.uint16), (model.num_azimuths, model.num_rings))
    return dirs.reshape(-1, 3), rings.reshape(-1).copy()


def cast_lidar(
    model: LidarModel,
    T_map_lidar: np.ndarray,
    target: Target,
    T_map_target: np.ndarray,
    boxes: Sequence[Box],
    rng: np.random.Generator,
    *,
    range_sigma_m: float | None = None,
    appearance: Appearance = Appearance(),
    t_ns: int = 0,
    sensor: str = "lidar",
    azimuth_fov_deg: tuple[float, float] | None = None,
) -> PointCloudFrame:
    """One revolution of ``model`` at ``T_map_lidar`` against the target at ``T_map_target``,
    the floor (map z = 0) and ``boxes``; a random azimuth offset in [0, step) is drawn from
    ``rng`` (the firing angles of consecutive revolutions differ), then one range noise per
    return (``range_sigma_m``, default the model's). Points (N, 3) in the lidar frame with
    fields ``ring`` (uint16), ``intensity`` (float32) and ``surface`` (int8: 0 target, 1 floor,
    2 clutter) - the last one is simulation truth, not something a lidar reports.
    ``azimuth_fov_deg`` (lo, hi) [deg, lidar frame, counter-clockwise from +x]: only returns
    in this window are kept (a Velodyne's FOV setting); None: all around."""
    T_ml = as_rigid(T_map_lidar, "cast_lidar: T_map_lidar")
    T_mt = as_rigid(T_map_target, "cast_lidar: T_map_target")
    fov = check_azimuth_fov(azimuth_fov_deg, "cast_lidar: azimuth_fov_deg")
    dirs, rings = _lidar_rays(model, float(rng.uniform(0.0, model.azimuth_step_deg)))
    sigma = model.range_sigma_m if range_sigma_m is None else float(range_sigma_m)
    # target, in its own frame
    o_t, d_t = _rays_to_local(invert(T_ml) @ T_mt, np.zeros(3), dirs)
    t_target, cos_target = _hit_target(target, o_t, d_t)
    # floor and boxes, in the map frame
    o_m = T_ml[:3, 3]
    d_m = dirs @ T_ml[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = -o_m[2] / d_m[:, 2]
    t_ground = np.where(t_ground > 0, t_ground, np.inf)
    t_box, cos_box = _hit_boxes(boxes, o_m, d_m)
    t_all = np.stack([t_target, t_ground, t_box])
    sid = np.argmin(t_all, axis=0)
    t = t_all[sid, np.arange(len(dirs))]
    cos = np.choose(sid, [cos_target, np.abs(d_m[:, 2]), cos_box])
    keep = np.isfinite(t) & (t >= model.min_range_m) & (t <= model.max_range_m)
    keep &= cos >= math.cos(math.radians(model.max_incidence_deg))
    if fov is not None:
        keep &= _in_azimuth_window(dirs, fov)
    noise = rng.standard_normal(int(keep.sum())) * sigma if sigma > 0 else 0.0
    r = t[keep] + noise
    refl = np.array([appearance.plate_reflectivity if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND
                     else appearance.cylinder_reflectivity, appearance.ground_reflectivity,
                     appearance.clutter_reflectivity])
    return PointCloudFrame(
        sensor=sensor,
        t_ns=t_ns,
        points_xyz=dirs[keep] * r[:, None],
        fields={
            "ring": rings[keep],
            "intensity": (255.0 * refl[sid[keep]] * cos[keep]).astype(np.float32),
            "surface": sid[keep].astype(np.int8),
        },
        frame_id=sensor,
    )


# --------------------------------------------------------------------------------------------
# rendering


def _bbox(camera: PinholeCamera, T_camera_target: np.ndarray, points_target: np.ndarray, pad_px: int):
    pc = transform_points(T_camera_target, points_target)
    if np.any(pc[:, 2] <= 1e-3):
        raise GeometryError("render: part of the target is behind the camera")
    uv, _ = camera.project(pc)
    lo = np.floor(uv.min(axis=0)).astype(int) - pad_px
    hi = np.ceil(uv.max(axis=0)).astype(int) + pad_px + 1
    u0, v0 = max(lo[0], 0), max(lo[1], 0)
    u1, v1 = min(hi[0], camera.width), min(hi[1], camera.height)
    return u0, v0, u1, v1


def _dense_outline(target: Target) -> np.ndarray:
    """Points along the target's outline dense enough that their distorted projections bound
    its image: the diamond's four edges, or the cylinder's end circles and side lines."""
    if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND:
        corners = _outline(target)
        a = np.linspace(0.0, 1.0, 33)[:-1, None]
        return np.vstack([(1 - a) * corners[k] + a * corners[(k + 1) % 4] for k in range(4)])
    r, hgt = float(target.dims["radius_m"]), float(target.dims["height_m"])
    ang = np.linspace(0, 2 * math.pi, 64, endpoint=False)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    z = np.linspace(0.0, -hgt, 17)
    side = np.array([[x, y, zz] for x, y in ring[::4] for zz in z])
    return np.vstack([np.column_stack([ring, np.zeros(64)]),
                      np.column_stack([ring, np.full(64, -hgt)]), side])


def _bbox_any(camera: CameraModel, T_camera_target: np.ndarray, target: Target, pad_px: int):
    """The pixel box (u0, v0, u1, v1) holding the target's image under any camera model: the
    bounds of its projected outline, or the whole image when part of the outline is outside
    the model's domain (behind the camera, beyond a lens's field of view); every pixel's own
    ray decides what it sees."""
    uv, _ = camera.project(transform_points(T_camera_target, _dense_outline(target)))
    if not np.all(np.isfinite(uv)):
        return 0, 0, camera.width, camera.height
    lo = np.floor(uv.min(axis=0)).astype(int) - pad_px
    hi = np.ceil(uv.max(axis=0)).astype(int) + pad_px + 1
    return max(lo[0], 0), max(lo[1], 0), min(hi[0], camera.width), min(hi[1], camera.height)


def _tri(x: np.ndarray) -> np.ndarray:
    """Integral of the +-1 square wave of period 2 (+1 on [0, 1)): a triangle wave."""
    return 1.0 - np.abs(np.mod(x, 2.0) - 1.0)


def _box_filtered_square(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The +-1 square wave (period 2, +1 on [0, 1)) averaged over [x - w/2, x + w/2]."""
    w = np.maximum(w, 1e-9)
    return (_tri(x + w / 2) - _tri(x - w / 2)) / w


def _box_filtered_interval(x: np.ndarray, w: np.ndarray, length: float) -> np.ndarray:
    """Fraction of [x - w/2, x + w/2] inside [0, length]."""
    w = np.maximum(w, 1e-9)
    return np.clip(np.minimum(x + w / 2, length) - np.maximum(x - w / 2, 0.0), 0.0, w) / w


def _render_diamond(camera: PinholeCamera, T_ct: np.ndarray, target: Target, app: Appearance):
    """(box, grey (h, w) float) of the diamond drawn over the background inside its box."""
    u0, v0, u1, v1 = _bbox(camera, T_ct, _outline(target), 3)
    if u1 <= u0 or v1 <= v0:
        return None
    fx, fy, cx, cy = camera.params
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    H = K @ np.column_stack([T_ct[:3, 0], T_ct[:3, 1], T_ct[:3, 3]])  # plate (x, y, 1) -> pixel
    Hi = np.linalg.inv(H)
    u, v = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
    a = Hi[0, 0] * u + Hi[0, 1] * v + Hi[0, 2]
    b = Hi[1, 0] * u + Hi[1, 1] * v + Hi[1, 2]
    c = Hi[2, 0] * u + Hi[2, 1] * v + Hi[2, 2]
    x, y = a / c, b / c
    # Jacobian of (x, y) with respect to (u, v): the pixel's footprint on the plate [m / px]
    xu, xv = (Hi[0, 0] - x * Hi[2, 0]) / c, (Hi[0, 1] - x * Hi[2, 1]) / c
    yu, yv = (Hi[1, 0] - y * Hi[2, 0]) / c, (Hi[1, 1] - y * Hi[2, 1]) / c
    # shading by the incidence of each pixel's ray
    ray = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)])
    n = T_ct[:3, 2]
    cos = np.abs(np.einsum("i,ihw->hw", n, ray)) / np.linalg.norm(ray, axis=0)
    return (u0, v0, u1, v1), _diamond_shading(target, app, x, y, (xu, xv, yu, yv), cos, c > 0)


def _diamond_shading(target: Target, app: Appearance, x: np.ndarray, y: np.ndarray,
                     jac: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                     cos: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Grey levels of pixels whose centres see the plate at ``(x, y)`` [m, target frame], with
    the pixel footprint ``jac = (dx/du, dx/dv, dy/du, dy/dv)`` [m / px], the incidence
    ``cos`` and ``seen`` (False: the ray does not meet the plate's plane)."""
    xu, xv, yu, yv = jac
    sq = float(target.dims["square_m"])
    cols, rows = int(target.dims["cols"]), int(target.dims["rows"])
    wx = (np.abs(xu) + np.abs(xv)) / sq
    wy = (np.abs(yu) + np.abs(yv)) / sq
    sx, sy = x / sq, y / sq
    board = _box_filtered_interval(sx, wx, cols + 1) * _box_filtered_interval(sy, wy, rows + 1)
    checker = _box_filtered_square(sx, wx) * _box_filtered_square(sy, wy)  # +1: black squares
    black = board * 0.5 * (1.0 + checker)
    albedo = app.plate_white - black * (app.plate_white - app.checker_black)
    # plate coverage from the pixel distance to the nearest diamond edge
    ctr = target_centre(target)
    h = float(target.dims["side_m"]) / math.sqrt(2)
    dx, dy = x - ctr[0], y - ctr[1]
    sd = (h - np.abs(dx) - np.abs(dy)) / math.sqrt(2)  # metres, > 0 inside
    gx, gy = -np.sign(dx) / math.sqrt(2), -np.sign(dy) / math.sqrt(2)
    gu = gx * xu + gy * yu
    gv = gx * xv + gy * yv
    sd_px = sd / np.maximum(np.hypot(gu, gv), 1e-12)
    cover = np.clip(0.5 + sd_px, 0.0, 1.0) * seen
    return cover * albedo * (0.8 + 0.2 * cos) + (1.0 - cover) * app.background_grey


def _render_diamond_rays(camera: CameraModel, T_ct: np.ndarray, target: Target, app: Appearance):
    """:func:`_render_diamond` for any camera model: every pixel's ray (the model's
    ``unproject``) is intersected with the plate; the pixel footprint on the plate, which the
    anti-aliasing needs, comes from the neighbouring pixels' intersections (central
    differences), the lens's distortion included."""
    u0, v0, u1, v1 = _bbox_any(camera, T_ct, target, 4)
    if u1 <= u0 or v1 <= v0:
        return None
    u, v = np.meshgrid(np.arange(u0 - 1, u1 + 1, dtype=float), np.arange(v0 - 1, v1 + 1, dtype=float))
    rays = camera.unproject(np.column_stack([u.ravel(), v.ravel()])).reshape(u.shape + (3,))
    o, d = _rays_to_local(T_ct, np.zeros(3), rays.reshape(-1, 3))
    d = d.reshape(rays.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[2] / d[..., 2]
        hit = np.isfinite(s) & (s > 0)
    s = np.where(hit, s, 0.0)
    x = np.where(hit, o[0] + s * d[..., 0], 0.0)
    y = np.where(hit, o[1] + s * d[..., 1], 0.0)
    inner = (slice(1, -1), slice(1, -1))
    seen = hit[inner] & hit[1:-1, 2:] & hit[1:-1, :-2] & hit[2:, 1:-1] & hit[:-2, 1:-1]
    jac = tuple(np.where(seen, val, 0.0) for val in (
        (x[1:-1, 2:] - x[1:-1, :-2]) / 2, (x[2:, 1:-1] - x[:-2, 1:-1]) / 2,
        (y[1:-1, 2:] - y[1:-1, :-2]) / 2, (y[2:, 1:-1] - y[:-2, 1:-1]) / 2,
    ))
    cos = np.abs(np.nan_to_num(rays[inner]) @ T_ct[:3, 2])
    grey = _diamond_shading(target, app, x[inner], y[inner], jac, cos, seen)
    return (u0, v0, u1, v1), grey


def _cylinder_shade(camera: CameraModel, T_ct: np.ndarray, target: Target, u: np.ndarray, v: np.ndarray):
    """Shading factor (N,) of the cylinder seen through pixel positions (u, v) (N,), 0 where the
    ray misses it."""
    if type(camera) is not PinholeCamera:
        dirs = camera.unproject(np.column_stack([u, v]))
        ok = np.isfinite(dirs).all(axis=1)
        dirs[~ok] = (0.0, 0.0, 1.0)
        o_t, d_t = _rays_to_local(T_ct, np.zeros(3), dirs)
        t, cos = _hit_cylinder(target, o_t, d_t)
        return np.where(np.isfinite(t) & ok, 0.8 + 0.2 * cos, 0.0)
    fx, fy, cx, cy = camera.params
    dirs = np.column_stack([(u - cx) / fx, (v - cy) / fy, np.ones(u.size)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o_t, d_t = _rays_to_local(T_ct, np.zeros(3), dirs)
    t, cos = _hit_cylinder(target, o_t, d_t)
    return np.where(np.isfinite(t), 0.8 + 0.2 * cos, 0.0)


def _render_cylinder(camera: CameraModel, T_ct: np.ndarray, target: Target, app: Appearance, supersample: int):
    """(box, bgr (h, w, 3) float) of the cylinder over the background inside its box. One ray
    per pixel centre, then ``supersample`` x ``supersample`` rays in the pixels next to the
    silhouette's edge (the only ones a partial cover can reach)."""
    if type(camera) is PinholeCamera:
        u0, v0, u1, v1 = _bbox(camera, T_ct, _outline(target), 3)
    else:
        u0, v0, u1, v1 = _bbox_any(camera, T_ct, target, 4)
    if u1 <= u0 or v1 <= v0:
        return None
    U, V = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
    shade = _cylinder_shade(camera, T_ct, target, U.ravel(), V.ravel()).reshape(U.shape)
    hit = shade > 0
    cover = hit.astype(float)
    s = int(supersample)
    if s > 1:
        pad = np.pad(hit, 1, mode="edge")
        edge = np.zeros_like(hit)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                edge |= pad[1 + dv:1 + dv + hit.shape[0], 1 + du:1 + du + hit.shape[1]] != hit
        iv, iu = np.nonzero(edge)
        off = (np.arange(s) + 0.5) / s - 0.5
        ou, ov = (a.ravel() for a in np.meshgrid(off, off))
        su = (U[iv, iu][:, None] + ou[None, :]).ravel()
        sv = (V[iv, iu][:, None] + ov[None, :]).ravel()
        sub = _cylinder_shade(camera, T_ct, target, su, sv).reshape(-1, s * s)
        inside = sub > 0
        cover[iv, iu] = inside.mean(axis=1)
        mean_shade = np.where(inside.any(axis=1), sub.sum(axis=1) / np.maximum(inside.sum(axis=1), 1), 0.0)
        shade[iv, iu] = mean_shade
    col = np.asarray(app.cylinder_bgr)[None, None, :] * shade[..., None]
    bg = np.asarray(app.background_bgr)[None, None, :]
    return (u0, v0, u1, v1), cover[..., None] * col + (1.0 - cover[..., None]) * bg


def render_image(
    camera: CameraModel,
    T_camera_target: np.ndarray,
    target: Target,
    rng: np.random.Generator,
    *,
    noise_sigma: float = 1.8,
    appearance: Appearance = Appearance(),
    supersample: int = 4,
    t_ns: int = 0,
    sensor: str = "camera",
) -> ImageFrame:
    """A full-size image of ``target`` at ``T_camera_target`` (4, 4) on a grey background with
    Gaussian noise of ``noise_sigma`` grey levels in every pixel (and channel). Diamonds give a
    mono (H, W) image, cylinders a BGR (H, W, 3) one (``supersample`` x ``supersample`` rays per
    pixel on the cylinder's box).

    ``camera``: any :class:`~rigcal.sensors.camera.base.CameraModel`. An undistorted
    :class:`PinholeCamera` maps the plate to the image by a homography (and refuses a target
    partly behind it: GeometryError); other models (radtan, Kannala-Brandt, double sphere)
    cast each pixel's ray (``unproject``) against the target, so lens distortion bends the
    target's edges as a real lens does."""
    T = as_rigid(T_camera_target, "render_image: T_camera_target")
    if not isinstance(camera, CameraModel):
        raise InputError(f"render_image: needs a camera model (rigcal.sensors.camera), got {type(camera).__name__}")
    if not (math.isfinite(noise_sigma) and noise_sigma >= 0):
        raise InputError(f"render_image: noise_sigma must be >= 0, got {noise_sigma!r}")
    W, Hh = camera.width, camera.height
    if _kind(target) is TargetKind.CHECKERBOARD_DIAMOND:
        img = np.full((Hh, W), appearance.background_grey, dtype=np.float32)
        if type(camera) is PinholeCamera:
            out = _render_diamond(camera, T, target, appearance)
        else:
            out = _render_diamond_rays(camera, T, target, appearance)
    else:
        img = np.empty((Hh, W, 3), dtype=np.float32)
        img[:] = np.asarray(appearance.background_bgr, dtype=np.float32)
        out = _render_cylinder(camera, T, target, appearance, supersample)
    if out is not None:
        (u0, v0, u1, v1), patch = out
        img[v0:v1, u0:u1] = patch
    if noise_sigma > 0:
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(noise_sigma)
    np.clip(np.rint(img, out=img), 0, 255, out=img)
    return ImageFrame(sensor=sensor, t_ns=t_ns, image=img.astype(np.uint8), frame_id=sensor)


# --------------------------------------------------------------------------------------------
# placements


def _look_frame(forward: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) whose z axis is ``-forward`` (toward the viewer), x horizontal to the
    viewer's right and y up (as horizontal as possible), in the map frame."""
    z = -forward / np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def _rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, float)
    return so3_exp(a / np.linalg.norm(a) * angle)


def _in_azimuth_window(directions: np.ndarray, fov_deg: tuple[float, float], margin_deg: float = 0.0) -> np.ndarray:
    """(N,) whether directions (N, 3) in a lidar's frame lie in its azimuth window ``(lo, hi)``
    [deg, counter-clockwise from +x], widened by ``margin_deg`` on both sides."""
    az = np.degrees(np.arctan2(directions[:, 1], directions[:, 0]))
    return (az >= fov_deg[0] - margin_deg) & (az <= fov_deg[1] + margin_deg)


def _in_lidar_view(T_lidar_target: np.ndarray, pts_target: np.ndarray, model: LidarModel, p: Placement, strict: bool,
                   azimuth_fov_deg: tuple[float, float] | None = None) -> bool:
    q = transform_points(T_lidar_target, pts_target)
    el = np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))
    az = np.degrees(np.arctan2(q[:, 1], q[:, 0]))
    rng = np.linalg.norm(q, axis=1)
    lo, hi = model.vertical_angles_deg[0], model.vertical_angles_deg[-1]
    m = p.lidar_elevation_margin_deg if strict else 0.0
    ok = (el >= lo + m) & (el <= hi - m) & (rng >= model.min_range_m) & (rng <= model.max_range_m)
    if azimuth_fov_deg is not None:
        ok &= _in_azimuth_window(q, azimuth_fov_deg)
    if strict:
        ok &= np.abs(az) <= p.lidar_azimuth_deg
        return bool(ok.all())
    return bool(ok.mean() >= 0.5)


def _in_camera_view(T_camera_target: np.ndarray, pts_target: np.ndarray, camera: CameraModel, p: Placement, strict: bool) -> bool:
    q = transform_points(T_camera_target, pts_target)
    if np.any(q[:, 2] <= 0.1):
        return False
    uv, _ = camera.project(q)
    m = p.image_margin_px if strict else 0.0
    ok = (uv[:, 0] >= m) & (uv[:, 0] <= camera.width - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= camera.height - 1 - m)
    return bool(ok.all())


def _visible(kind: str, rig: MocapRig, T_sensor_target: np.ndarray, pts: np.ndarray, p: Placement, strict: bool) -> bool:
    if kind == LIDAR:
        return _in_lidar_view(T_sensor_target, pts, rig.lidar, p, strict)
    return _in_camera_view(T_sensor_target, pts, rig.camera, p, strict)


def _in_view(view: SensorView, T_sensor_target: np.ndarray, pts: np.ndarray, p: Placement, strict: bool) -> bool:
    if view.is_lidar:
        return _in_lidar_view(T_sensor_target, pts, view.model, p, strict, view.azimuth_fov_deg)
    return _in_camera_view(T_sensor_target, pts, view.model, p, strict)


def _avoid_points(target: Target) -> np.ndarray:
    """About a thousand points spread over the target (its template, thinned) and its
    outline: what :func:`sees_part` checks."""
    tmpl = target.template
    return np.vstack([tmpl[:: max(1, len(tmpl) // 1000)], _dense_outline(target)])


def _sees_points(view: SensorView, pts_map: np.ndarray, p: Placement) -> bool:
    q = transform_points(invert(view.T_map_sensor), pts_map)
    if view.is_lidar:
        model = view.model
        el = np.degrees(np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))
        rng = np.linalg.norm(q, axis=1)
        m = p.avoid_margin_deg
        ok = (el >= model.vertical_angles_deg[0] - m) & (el <= model.vertical_angles_deg[-1] + m)
        ok &= (rng >= 0.9 * model.min_range_m) & (rng <= 1.1 * model.max_range_m)
        if view.azimuth_fov_deg is not None:
            ok &= _in_azimuth_window(q, view.azimuth_fov_deg, m)
        return bool(ok.any())
    cam = view.model
    front = q[:, 2] > MIN_DEPTH_M
    if not front.any():
        return False
    uv, _ = cam.project(q[front])
    m = p.avoid_margin_px
    with np.errstate(invalid="ignore"):
        ok = (uv[:, 0] >= -0.5 - m) & (uv[:, 0] <= cam.width - 0.5 + m) & (uv[:, 1] >= -0.5 - m) & (uv[:, 1] <= cam.height - 0.5 + m)
    return bool(ok.any())


def sees_part(view: SensorView, target: Target, T_map_target: np.ndarray, placement: Placement = Placement()) -> bool:
    """Whether any part of ``target`` at ``T_map_target`` (4, 4) may show in the data of the
    sensor ``view`` - a conservative test: True when one of about a thousand points spread over
    the target lies inside the lidar's beam fan (widened by ``placement.avoid_margin_deg``), range
    limits and azimuth window (widened too), or in front of the camera and projecting within
    ``placement.avoid_margin_px`` of its image (occlusions are ignored)."""
    T_mt = as_rigid(T_map_target, "sees_part: T_map_target")
    _kind(target)
    return _sees_points(view, transform_points(T_mt, _avoid_points(target)), placement)


def sample_pose_in_view(
    view: SensorView,
    target: Target,
    rng: np.random.Generator,
    placement: Placement = Placement(),
    *,
    avoid: Sequence[SensorView] = (),
    max_tries: int = 2000,
) -> np.ndarray:
    """``T_map_target`` (4, 4): the target held still in the view of the sensor ``view``,
    facing it (see :class:`Placement`): a lidar sees its whole outline within
    ``placement.lidar_azimuth_deg`` of its x axis (and within its azimuth window), inside the
    beam fan; a camera of any model sees it wholly, ``placement.image_margin_px`` inside the
    image. With ``avoid``, no part of the target may show in any of those sensors' views
    (:func:`sees_part`): a hold for one sensor of a non-overlapping rig. Raises GeometryError
    when no pose satisfies all of it after ``max_tries`` draws."""
    if not isinstance(view, SensorView) or not all(isinstance(v, SensorView) for v in avoid):
        raise InputError("sample_pose_in_view: view and avoid must be SensorView values")
    if isinstance(max_tries, bool) or not isinstance(max_tries, (int, np.integer)) or max_tries < 1:
        raise InputError(f"sample_pose_in_view: max_tries must be an integer >= 1, got {max_tries!r}")
    tk = _kind(target)
    T_ms = view.T_map_sensor
    T_sm = invert(T_ms)
    pts = _outline(target)
    ctr = target_centre(target)
    lo, hi = placement.distance_range_m
    az_lo, az_hi = -placement.lidar_azimuth_deg, placement.lidar_azimuth_deg
    if view.azimuth_fov_deg is not None:
        az_lo, az_hi = max(az_lo, view.azimuth_fov_deg[0]), min(az_hi, view.azimuth_fov_deg[1])
        if az_lo >= az_hi:
            raise InputError(
                f"sample_pose_in_view: the lidar's azimuth window {view.azimuth_fov_deg} and the placement's "
                f"+-{placement.lidar_azimuth_deg} deg do not overlap"
            )
    avoid_pts = _avoid_points(target) if avoid else None
    for _ in range(max_tries):
        d = rng.uniform(lo, hi)
        if view.is_lidar:
            az = math.radians(rng.uniform(az_lo, az_hi))
            el = math.radians(rng.uniform(-8.0, 8.0))
            ray_s = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        else:
            cam = view.model
            uv = np.array([[rng.uniform(0, cam.width - 1), rng.uniform(0, cam.height - 1)]])
            ray_s = cam.unproject(uv)[0]
            ray_s = ray_s / np.linalg.norm(ray_s)
        centre_m = T_ms[:3, :3] @ (d * ray_s) + T_ms[:3, 3]
        fwd = centre_m - T_ms[:3, 3]
        R = _look_frame(fwd)
        if tk is TargetKind.CHECKERBOARD_DIAMOND:
            yaw = math.radians(rng.uniform(-placement.yaw_deg, placement.yaw_deg))
            pitch = math.radians(rng.uniform(-placement.pitch_deg, placement.pitch_deg))
            roll = math.radians(rng.uniform(-placement.roll_deg, placement.roll_deg))
            R = _rot_axis([0, 0, 1], yaw) @ _rot_axis(R[:, 0], pitch) @ R
            R = R @ _rot_axis([0, 0, 1], roll)
        else:
            tilt_axis = np.array([math.cos(a := rng.uniform(0, 2 * math.pi)), math.sin(a), 0.0])
            tilt = math.radians(rng.uniform(0, placement.cylinder_tilt_deg))
            R = _rot_axis(tilt_axis, tilt) @ _rot_axis([0, 0, 1], rng.uniform(0, 2 * math.pi))
        T_mt = from_rt(R, centre_m - R @ ctr)
        world = transform_points(T_mt, pts)
        if world[:, 2].min() < placement.ground_clearance_m:
            continue
        if placement.room_half_size_m > 0 and np.any(np.abs(world[:, :2]) > placement.room_half_size_m - 0.5):
            continue
        if not _in_view(view, T_sm @ T_mt, pts, placement, strict=True):
            continue
        if avoid_pts is not None:
            spread = transform_points(T_mt, avoid_pts)
            if any(_sees_points(v, spread, placement) for v in avoid):
                continue
        return T_mt
    others = f", outside {len(avoid)} other sensor view(s)" if avoid else ""
    raise GeometryError(
        f"no {target.name} pose in the {view.kind}'s view satisfies the placement after {max_tries} tries "
        f"(distance {lo}..{hi} m{others})"
    )


def sample_target_pose(
    rig: MocapRig,
    kind: str,
    target: Target,
    T_map_robot: np.ndarray,
    rng: np.random.Generator,
    placement: Placement = Placement(),
    max_tries: int = 2000,
) -> np.ndarray:
    """``T_map_target`` (4, 4): the target held still in the view of the rig's ``kind``
    (``"lidar"`` or ``"camera"``) sensor, facing it (see :class:`Placement` and
    :func:`sample_pose_in_view`). Raises GeometryError when no pose satisfies the placement
    after ``max_tries`` draws."""
    if kind not in (LIDAR, CAMERA):
        raise InputError(f"sample_target_pose: kind must be 'lidar' or 'camera', got {kind!r}")
    T_ms = np.asarray(T_map_robot, float) @ rig.T_robot_sensor(kind)
    model = rig.lidar if kind == LIDAR else rig.camera
    return sample_pose_in_view(SensorView(model, T_ms), target, rng, placement, max_tries=max_tries)


def _clutter(rng: np.random.Generator, T_map_robot: np.ndarray, T_map_target: np.ndarray,
             sensors_m: Sequence[np.ndarray], p: Placement) -> tuple[Box, ...]:
    """Boxes standing on the floor around the robot, away from the target and from every
    sensor's line of sight to it, plus the room's four walls."""
    boxes = []
    centre_t = T_map_target[:3, 3]
    robot = T_map_robot[:3, 3]
    tries = 0
    while len(boxes) < p.clutter_boxes and tries < 200:
        tries += 1
        r = rng.uniform(1.5, 6.0)
        a = rng.uniform(0, 2 * math.pi)
        c = robot[:2] + r * np.array([math.cos(a), math.sin(a)])
        half = rng.uniform(0.15, 0.5, 2)
        height = rng.uniform(0.4, 2.0)
        rad = float(np.linalg.norm(half))
        if np.linalg.norm(c - centre_t[:2]) < rad + 0.8 or np.any(np.abs(c) + half > p.room_half_size_m - 0.3):
            continue
        blocked = False
        for s in sensors_m:
            seg = centre_t[:2] - s[:2]
            L = float(np.linalg.norm(seg))
            tt = float(np.clip(np.dot(c - s[:2], seg) / max(L * L, 1e-9), 0.0, 1.0))
            if np.linalg.norm(s[:2] + tt * seg - c) < rad + 0.5 or np.linalg.norm(c - s[:2]) < rad + 0.5:
                blocked = True
        if blocked:
            continue
        boxes.append(Box([c[0] - half[0], c[1] - half[1], 0.0], [c[0] + half[0], c[1] + half[1], height]))
    R = p.room_half_size_m
    if R > 0:
        th, hgt = 0.1, 3.0
        boxes += [
            Box([R, -R, 0], [R + th, R, hgt]), Box([-R - th, -R, 0], [-R, R, hgt]),
            Box([-R, R, 0], [R, R + th, hgt]), Box([-R, -R - th, 0], [R, -R, hgt]),
        ]
    return tuple(boxes)


# --------------------------------------------------------------------------------------------
# the simulation


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapCapture:
    """One measurement: the target held still at ``t_ns`` in the view of ``aimed_at`` (the
    sensor kind it was placed for). True poses ``T_map_robot``, ``T_map_target`` and the MCS's
    reports ``*_mcs`` (equal without MCS noise). ``cloud`` (lidar frame) and ``image`` are the
    data of the sensors that see the target (None otherwise); ``clutter`` the boxes in the
    scene (map frame)."""

    index: int
    t_ns: int
    aimed_at: str
    T_map_robot: np.ndarray
    T_map_target: np.ndarray
    T_map_robot_mcs: np.ndarray
    T_map_target_mcs: np.ndarray
    cloud: PointCloudFrame | None = None
    image: ImageFrame | None = None
    clutter: tuple[Box, ...] = ()

    def __post_init__(self) -> None:
        for name in ("T_map_robot", "T_map_target", "T_map_robot_mcs", "T_map_target_mcs"):
            object.__setattr__(self, name, as_rigid(getattr(self, name), f"MocapCapture.{name}"))

    @property
    def T_robot_target(self) -> np.ndarray:
        """True target pose in the robot frame."""
        return invert(self.T_map_robot) @ self.T_map_target

    @property
    def T_robot_target_mcs(self) -> np.ndarray:
        """The target pose in the robot frame as the MCS measures it (what calibration uses)."""
        return invert(self.T_map_robot_mcs) @ self.T_map_target_mcs


@dataclass(frozen=True, eq=False)
class MocapSimulation:
    """A simulated calibration session: the rig (with the true extrinsics), the target and its
    captures in time order, and the MCS noise used."""

    rig: MocapRig
    target: Target
    captures: tuple[MocapCapture, ...]
    mcs_noise_m: float
    marker_baseline_m: float

    def data(self, kind: str) -> list[MocapCapture]:
        """The captures holding data of the ``kind`` (``"lidar"`` / ``"camera"``) sensor."""
        attr = "cloud" if kind == LIDAR else "image"
        return [c for c in self.captures if getattr(c, attr) is not None]


def _mcs(T: np.ndarray, rng: np.random.Generator, sigma_m: float, baseline_m: float) -> np.ndarray:
    if sigma_m <= 0:
        return T.copy()
    xi = np.concatenate([rng.normal(0.0, sigma_m / baseline_m, 3), rng.normal(0.0, sigma_m, 3)])
    return T @ se3_exp(xi)


def _random_robot(rng: np.random.Generator, area_m: float) -> np.ndarray:
    yaw = rng.uniform(-math.pi, math.pi)
    xy = rng.uniform(-area_m, area_m, 2)
    return from_rt(matrix_from_rpy(np.array([0.0, 0.0, yaw])), [xy[0], xy[1], 0.0])


def simulate_mocap(
    rig: MocapRig,
    target: Target,
    measurements: int,
    rng: np.random.Generator | int,
    *,
    sensors: Sequence[str] = (LIDAR,),
    mcs_noise_m: float = 0.0,
    marker_baseline_m: float = 0.5,
    pixel_noise_sigma: float = 1.8,
    lidar_range_sigma_m: float | None = None,
    placement: Placement = Placement(),
    appearance: Appearance = Appearance(),
    period_ns: int = 1_000_000_000,
    first_index: int = 0,
) -> MocapSimulation:
    """``measurements`` captures of ``target`` around the robot (see the module docstring).

    Capture ``i`` is aimed at ``sensors[i % len(sensors)]``: the robot stands at a random pose
    on the floor and the target is held in that sensor's view (:func:`sample_target_pose`);
    every sensor in ``sensors`` that sees the target (the lidar at least half of its outline,
    the camera all of it) then records it - with an overlapping rig a capture may hold both a
    scan and an image. ``rng``: a Generator or a
    seed; everything random is drawn from it, so a seed reproduces the session. Captures are
    numbered from ``first_index`` and taken every ``period_ns`` (``t_ns = index * period_ns``),
    so a session can be extended by a second call.
    """
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    if isinstance(measurements, bool) or not isinstance(measurements, (int, np.integer)) or measurements < 1:
        raise InputError(f"simulate_mocap: measurements must be an integer >= 1, got {measurements!r}")
    kinds = tuple(sensors)
    if not kinds or any(k not in (LIDAR, CAMERA) for k in kinds) or len(set(kinds)) != len(kinds):
        raise InputError(f"simulate_mocap: sensors must be distinct 'lidar' / 'camera', got {sensors!r}")
    if not (math.isfinite(mcs_noise_m) and mcs_noise_m >= 0) or not marker_baseline_m > 0:
        raise InputError(
            f"simulate_mocap: need mcs_noise_m >= 0 and marker_baseline_m > 0, got {mcs_noise_m!r}, "
            f"{marker_baseline_m!r}"
        )
    _kind(target)
    pts = _outline(target)
    captures = []
    for i in range(int(first_index), int(first_index) + int(measurements)):
        aim = kinds[i % len(kinds)]
        t_ns = int(i * period_ns)
        T_mr = _random_robot(gen, placement.robot_area_m)
        T_mt = sample_target_pose(rig, aim, target, T_mr, gen, placement)
        sensors_m = [(T_mr @ rig.T_robot_sensor(k))[:3, 3] for k in kinds]
        clutter = _clutter(gen, T_mr, T_mt, sensors_m, placement)
        cloud = image = None
        for k in kinds:
            T_ms = T_mr @ rig.T_robot_sensor(k)
            T_st = invert(T_ms) @ T_mt
            if not _visible(k, rig, T_st, pts, placement, strict=False):
                continue
            if k == LIDAR:
                cloud = cast_lidar(rig.lidar, T_ms, target, T_mt, clutter, gen, range_sigma_m=lidar_range_sigma_m,
                                   appearance=appearance, t_ns=t_ns, sensor=rig.lidar_name)
            else:
                image = render_image(rig.camera, T_st, target, gen, noise_sigma=pixel_noise_sigma,
                                     appearance=appearance, t_ns=t_ns, sensor=rig.camera_name)
        captures.append(MocapCapture(
            index=i, t_ns=t_ns, aimed_at=aim, T_map_robot=T_mr, T_map_target=T_mt,
            T_map_robot_mcs=_mcs(T_mr, gen, mcs_noise_m, marker_baseline_m),
            T_map_target_mcs=_mcs(T_mt, gen, mcs_noise_m, marker_baseline_m),
            cloud=cloud, image=image, clutter=clutter,
        ))
    return MocapSimulation(rig, target, tuple(captures), float(mcs_noise_m), float(marker_baseline_m))
