"""A complete motion-capture calibration session written to a folder, ready for ``rigcal mocap``.

:func:`write_mocap_scene` simulates what a calibration session with a motion capture system
(MCS, e.g. Vicon) records (Charron et al., section IV) and writes it as the files a user would
have:

* ``run.bag`` - a ROS 1 bag (written with ``rosbags``) holding the Vicon bridge's
  ``geometry_msgs/TransformStamped`` topics of the robot and the target (``/vicon/<body>/<body>``,
  parent ``world``) at ``mcs_hz``, every lidar's ``sensor_msgs/PointCloud2`` scans (ray cast:
  :func:`rigcal.sim.mocap.cast_lidar`) and every camera's ``sensor_msgs/Image`` frames
  (rendered: :func:`rigcal.sim.mocap.render_image`, any camera model) at ``sensor_hz``;
* ``diamond.json`` - the target definition (the original tool's format,
  :func:`rigcal.io.config.vicon_json.write_vicon_target`);
* ``<camera>.yaml`` - each camera's intrinsics as a Kalibr camchain
  (:func:`rigcal.io.config.camchain.format_camchain`);
* ``initial.json`` - the initial calibration (the original tool's extrinsics JSON,
  ``robot_frame`` <- each sensor's ``frame_id``): the truth perturbed uniformly by up to
  ``perturbation[0]`` metres and ``perturbation[1]`` degrees per axis (3 cm and 5 deg, as in
  the paper);
* ``mocap.yaml`` - the configuration ``rigcal mocap`` reads (:mod:`rigcal.mocap.config`).

The session (times in integer nanoseconds, frames as in :mod:`rigcal.sim.mocap`): a robot
creeps across the MCS volume (:class:`RobotPath`); a checkerboard diamond is held still at
``holds`` poses in each sensor's view in turn (sensor after sensor, in the order given), for
``hold_s`` each, and carried between them in ``move_s`` (a smooth move, far faster than the
extraction's motion limit). A pose is drawn in the view of the sensor it is held for, at the
robot's pose halfway through the hold (:func:`rigcal.sim.mocap.sample_pose_in_view`); with
``exclusive`` no part of the target may show in any other sensor's view (a rig with no shared
view: each sensor is calibrated to the robot frame through the MCS alone). Before the first
hold and after the last the target stands at their poses. The robot body's MCS stream drops out
for a moment during one hold (``gap_hold``), as markers do. A frame is stamped at its capture
time; the lidar fires at ``sensor_hz`` and each camera half a period later (the k-th camera
another k/8 of a period later).

:func:`default_rig` is a three-sensor rig with no shared view (a VLP-16 looking forward with
its returns limited to +-50 deg, a pinhole camera looking left, a radtan camera looking right);
:func:`two_sensor_rig` the lidar (all around) and the left camera.

Everything random is drawn from one generator seeded with ``seed``, so a seed reproduces the
files byte for byte. The returned :class:`MocapScene` holds the paths, the truth, the initial
calibration, the hold / move / dropout times, every frame's time and whether the target shows
in it (simulation truth).
"""

from __future__ import annotations

import math
import os
import secrets
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rigcal import interrupts
from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid, from_rt, invert, se3_exp, transform_points
from rigcal.geometry.so3 import matrix_from_rpy, so3_exp, so3_log
from rigcal.sensors.camera.base import CameraModel
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera
from rigcal.sim.mocap import (
    CAMERA,
    LIDAR,
    R_BODY_OPTICAL,
    Appearance,
    Placement,
    SensorView,
    cast_lidar,
    check_azimuth_fov,
    paper_rig,
    render_image,
    sample_pose_in_view,
)
from rigcal.sim.raw.lidar import LidarModel, vlp16
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.templates import diamond_target

__all__ = [
    "CONFIG_NAME",
    "BAG_NAME",
    "INITIAL_NAME",
    "TARGET_NAME",
    "Hold",
    "MocapScene",
    "RobotPath",
    "SceneSensor",
    "SceneTiming",
    "default_rig",
    "two_sensor_rig",
    "write_mocap_scene",
]

NS = 1_000_000_000
T0_NS = 1_700_000_000_000_000_000
"""The session's first MCS sample [ns since the epoch]."""

BAG_NAME = "run.bag"
CONFIG_NAME = "mocap.yaml"
INITIAL_NAME = "initial.json"
TARGET_NAME = "diamond.json"
ROBOT_FRAME = "base_link"
MOCAP_FRAME = "world"
ROBOT_BODY = "robot"

Progress = Callable[[int, int], None]


# --------------------------------------------------------------------------------------------
# values


@dataclass(frozen=True, eq=False)  # holds an array: compare by identity
class SceneSensor:
    """One sensor of the simulated rig.

    ``kind``: ``"lidar"`` (``model`` a :class:`~rigcal.sim.raw.lidar.LidarModel`) or
    ``"camera"`` (``model`` any :class:`~rigcal.sensors.camera.base.CameraModel`);
    ``T_robot_sensor`` (4, 4): the truth; ``topic`` and ``frame_id`` of its messages; a lidar's
    ``azimuth_fov_deg`` ``(lo, hi)`` [deg, lidar frame]: the window its returns are kept in (a
    Velodyne's FOV setting; None: all around), written to ``mocap.yaml`` too; ``sigma``: the
    measurement sigma written to ``mocap.yaml`` (``sigma_m`` of a lidar, default 0.01;
    ``sigma_px`` of a camera, default 1)."""

    name: str
    kind: str
    T_robot_sensor: np.ndarray
    model: LidarModel | CameraModel
    topic: str
    frame_id: str
    azimuth_fov_deg: tuple[float, float] | None = None
    sigma: float | None = None

    def __post_init__(self) -> None:
        from rigcal.io.dataset.manifest import check_sensor_name

        check_sensor_name(self.name, "SceneSensor.name")
        where = f"SceneSensor '{self.name}'"
        if self.kind not in (LIDAR, CAMERA):
            raise InputError(f"{where}: kind must be 'lidar' or 'camera', got {self.kind!r}")
        if self.kind == LIDAR and not isinstance(self.model, LidarModel):
            raise InputError(f"{where}: a lidar's model must be a LidarModel, got {type(self.model).__name__}")
        if self.kind == CAMERA and not isinstance(self.model, CameraModel):
            raise InputError(f"{where}: a camera's model must be a CameraModel, got {type(self.model).__name__}")
        object.__setattr__(self, "T_robot_sensor", as_rigid(self.T_robot_sensor, f"{where}: T_robot_sensor"))
        for key in ("topic", "frame_id"):
            value = getattr(self, key)
            if not isinstance(value, str) or not value.strip() or value != value.strip():
                raise InputError(f"{where}: {key} must be a non-empty string without surrounding spaces, got {value!r}")
        if not self.topic.startswith("/"):
            raise InputError(f"{where}: topic must start with '/', got {self.topic!r}")
        fov = check_azimuth_fov(self.azimuth_fov_deg, f"{where}: azimuth_fov_deg")
        if fov is not None and self.kind != LIDAR:
            raise InputError(f"{where}: azimuth_fov_deg: only a lidar has an azimuth window")
        object.__setattr__(self, "azimuth_fov_deg", fov)
        if self.sigma is not None and not (isinstance(self.sigma, (int, float)) and math.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(f"{where}: sigma must be a number > 0, got {self.sigma!r}")

    def view(self, T_map_robot: np.ndarray) -> SensorView:
        """The sensor placed in the map when the robot is at ``T_map_robot`` (4, 4)."""
        return SensorView(self.model, np.asarray(T_map_robot, float) @ self.T_robot_sensor, self.azimuth_fov_deg)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class RobotPath:
    """The robot's motion in the MCS frame: at ``t_s`` seconds into the session it stands at
    ``start_xyz_m + velocity_mps * t_s`` with a constant heading ``yaw_deg`` (z up; the floor
    is z = 0), turning at ``yaw_rate_dps``. Default: creeping at 1 cm/s along the map's x axis
    with a constant heading."""

    start_xyz_m: tuple[float, float, float] = (0.5, -0.3, 0.0)
    velocity_mps: tuple[float, float, float] = (0.01, 0.0, 0.0)
    yaw_deg: float = 30.0
    #: the robot turns at this rate [deg/s] (0: a constant heading)
    yaw_rate_dps: float = 0.0
    #: and sways about its heading by this much [deg], once every ``sway_period_s`` [s] (a
    #: turn rate that changes: a constant twist makes a clock offset the same as a fixed
    #: change of every sensor's pose, so only a changing one tells them apart)
    sway_deg: float = 0.0
    sway_period_s: float = 8.0

    def __post_init__(self) -> None:
        for key in ("start_xyz_m", "velocity_mps"):
            v = np.array(getattr(self, key), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise InputError(f"RobotPath.{key}: expected three finite numbers, got {getattr(self, key)!r}")
            v.setflags(write=False)
            object.__setattr__(self, key, v)
        for key in ("yaw_deg", "yaw_rate_dps", "sway_deg"):
            if not math.isfinite(getattr(self, key)):
                raise InputError(f"RobotPath.{key}: expected a finite number, got {getattr(self, key)!r}")
        if not (math.isfinite(self.sway_period_s) and self.sway_period_s > 0):
            raise InputError(f"RobotPath.sway_period_s: expected a duration > 0 [s], got {self.sway_period_s!r}")

    def at(self, t_s: float) -> np.ndarray:
        """``T_map_robot`` (4, 4) at ``t_s`` seconds into the session."""
        sway = self.sway_deg * math.sin(2 * math.pi * t_s / self.sway_period_s)
        R = matrix_from_rpy(np.radians([0.0, 0.0, self.yaw_deg + self.yaw_rate_dps * t_s + sway]))
        return from_rt(R, self.start_xyz_m + self.velocity_mps * t_s)


@dataclass(frozen=True)
class SceneTiming:
    """The session's clock: ``lead_s`` before the first hold and after the last, holds of
    ``hold_s``, moves of ``move_s`` [s]; MCS samples at ``mcs_hz``, sensor frames at
    ``sensor_hz``; the robot body's MCS stream drops out from ``gap_s[0]`` to ``gap_s[1]``
    seconds into hold number ``gap_hold`` (0-based; None: no dropout)."""

    hold_s: float = 1.5
    move_s: float = 0.8
    lead_s: float = 0.5
    mcs_hz: int = 100
    sensor_hz: int = 4
    gap_hold: int | None = 1
    gap_s: tuple[float, float] = (0.55, 0.85)

    def __post_init__(self) -> None:
        for key in ("hold_s", "move_s", "lead_s"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"SceneTiming.{key}: expected a duration > 0 [s], got {v!r}")
        for key in ("mcs_hz", "sensor_hz"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v <= 1000:
                raise InputError(f"SceneTiming.{key}: expected an integer rate in 1..1000 [Hz], got {v!r}")
        if self.gap_hold is not None and (isinstance(self.gap_hold, bool) or not isinstance(self.gap_hold, int) or self.gap_hold < 0):
            raise InputError(f"SceneTiming.gap_hold: expected None or a hold index >= 0, got {self.gap_hold!r}")
        try:
            a, b = (float(v) for v in self.gap_s)
        except (TypeError, ValueError):
            raise InputError(f"SceneTiming.gap_s: expected (start, end) [s], got {self.gap_s!r}") from None
        if self.gap_hold is not None and not 0 <= a < b <= self.hold_s:
            raise InputError(f"SceneTiming.gap_s: expected 0 <= start < end <= hold_s ({self.hold_s}) [s], got {self.gap_s!r}")


@dataclass(frozen=True, eq=False)  # holds an array: compare by identity
class Hold:
    """The target held still from ``start_ns`` to ``end_ns`` at ``T_map_target`` (4, 4) in the
    view of the sensor named ``sensor``."""

    start_ns: int
    end_ns: int
    sensor: str
    T_map_target: np.ndarray


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class MocapScene:
    """What :func:`write_mocap_scene` wrote and the truth behind it.

    Paths: ``folder``, ``config_path`` (``mocap.yaml``), ``bag_path``, ``target_path``,
    ``initial_path`` and ``intrinsics`` (camera name -> file). ``truth`` and ``initial``: sensor
    name -> ``T_robot_sensor`` (4, 4). ``holds`` in time order, ``moves`` (start_ns, end_ns)
    between consecutive holds, ``gap`` the robot body's MCS dropout (start_ns, end_ns) or None.
    ``frames``: sensor name -> frame times (int64 ns); ``target_seen``: sensor name -> per frame,
    whether the target shows in the data (lidar returns on it, pixels of it in the image).
    ``robot`` and ``t0_ns`` give the robot's path (:meth:`T_map_robot_at`); ``timing`` the
    session's clock; ``end_ns`` its last MCS sample."""

    folder: Path
    config_path: Path
    bag_path: Path
    target_path: Path
    initial_path: Path
    intrinsics: Mapping[str, Path]
    sensors: tuple[SceneSensor, ...]
    target: Target
    truth: Mapping[str, np.ndarray]
    initial: Mapping[str, np.ndarray]
    holds: tuple[Hold, ...]
    moves: tuple[tuple[int, int], ...]
    gap: tuple[int, int] | None
    frames: Mapping[str, np.ndarray]
    target_seen: Mapping[str, np.ndarray]
    robot: RobotPath = field(default_factory=RobotPath)
    timing: SceneTiming = field(default_factory=SceneTiming)
    t0_ns: int = T0_NS
    end_ns: int = 0
    seed: int = 0
    robot_frame: str = ROBOT_FRAME
    robot_topic: str = f"/vicon/{ROBOT_BODY}/{ROBOT_BODY}"
    target_topic: str = ""
    robot_still_in_holds: bool = False

    def sensor(self, name: str) -> SceneSensor:
        for s in self.sensors:
            if s.name == name:
                return s
        raise InputError(f"scene has no sensor '{name}' (sensors: {', '.join(s.name for s in self.sensors)})")

    def T_map_robot_at(self, t_ns: int) -> np.ndarray:
        """The robot's true pose ``T_map_robot`` (4, 4) at ``t_ns`` (its path's clock stopped
        during the holds when ``robot_still_in_holds``)."""
        still = 0
        if self.robot_still_in_holds:
            still = sum(min(max(t_ns - h.start_ns, 0), h.end_ns - h.start_ns) for h in self.holds)
        return self.robot.at((t_ns - self.t0_ns - still) / NS)

    def holds_of(self, sensor: str) -> tuple[Hold, ...]:
        return tuple(h for h in self.holds if h.sensor == sensor)


# --------------------------------------------------------------------------------------------
# rigs


def _pose(rpy_deg: Sequence[float], xyz_m: Sequence[float], optical: bool) -> np.ndarray:
    R = matrix_from_rpy(np.radians(np.asarray(rpy_deg, dtype=float)))
    return from_rt(R @ R_BODY_OPTICAL if optical else R, xyz_m)


#: a VLP-16's range noise (std) [m]: what the simulated lidar's ranges err by
VLP16_RANGE_SIGMA_M = 0.015


def two_sensor_rig(lidar_range_sigma_m: float = VLP16_RANGE_SIGMA_M) -> tuple[SceneSensor, SceneSensor]:
    """The lidar and camera of :func:`rigcal.sim.mocap.paper_rig` (no shared view of their
    own, but the VLP-16 sees all around): ``lidar1`` (a VLP-16 with ``lidar_range_sigma_m`` of
    range noise, 15 mm by default, told the same ``sigma_m``; on ``/velodyne_points``, frame
    ``velodyne_link``) and ``camera1`` (a 1024 x 768 pinhole camera looking left on
    ``/F1/image_raw``, frame ``camera_link``)."""
    base = paper_rig()
    sigma = float(lidar_range_sigma_m)
    if not (math.isfinite(sigma) and sigma >= 0):
        raise InputError(f"two_sensor_rig: lidar_range_sigma_m must be >= 0, got {lidar_range_sigma_m!r}")
    return (
        SceneSensor("lidar1", LIDAR, base.T_robot_lidar, vlp16(range_sigma_m=sigma), "/velodyne_points",
                    "velodyne_link", sigma=max(sigma, 0.001)),
        SceneSensor("camera1", CAMERA, base.T_robot_camera,
                    PinholeCamera.from_intrinsics(1024, 768, 1176.0, 1176.0, 511.5, 383.5),
                    "/F1/image_raw", "camera_link"),
    )


def default_rig(lidar_range_sigma_m: float = VLP16_RANGE_SIGMA_M) -> tuple[SceneSensor, SceneSensor, SceneSensor]:
    """Three sensors looking three ways with no shared view: ``lidar1``, a VLP-16 (range noise
    ``lidar_range_sigma_m``, 15 mm by default) 0.65 m up looking forward with its returns
    limited to +-50 deg of azimuth; ``camera1``, a 1024 x 768 pinhole camera 0.55 m up looking
    left; ``camera2``, a 1280 x 960 radtan camera (k1 = -0.2: visible barrel distortion) 0.60 m
    up looking right."""
    lidar, left = two_sensor_rig(lidar_range_sigma_m)
    lidar = SceneSensor(lidar.name, LIDAR, lidar.T_robot_sensor, lidar.model, lidar.topic, lidar.frame_id,
                        azimuth_fov_deg=(-50.0, 50.0), sigma=lidar.sigma)
    right = SceneSensor(
        "camera2", CAMERA, _pose([0.6, -1.8, -92.0], [0.02, -0.24, 0.60], optical=True),
        RadtanCamera.from_intrinsics(1280, 960, 1050.0, 1050.0, 641.0, 478.5, -0.2, 0.06, 0.0005, -0.0003),
        "/F2/image_raw", "camera2_link",
    )
    return lidar, left, right


# --------------------------------------------------------------------------------------------
# the session


def _smooth(a: float) -> float:
    return a * a * (3 - 2 * a)


def _between(A: np.ndarray, B: np.ndarray, a: float) -> np.ndarray:
    w = so3_log(A[:3, :3].T @ B[:3, :3])
    return from_rt(A[:3, :3] @ so3_exp(a * w), (1 - a) * A[:3, 3] + a * B[:3, 3])


def _perturb(T: np.ndarray, rng: np.random.Generator, translation_m: float, rotation_deg: float) -> np.ndarray:
    dR = matrix_from_rpy(np.radians(rng.uniform(-rotation_deg, rotation_deg, 3)))
    return from_rt(T[:3, :3] @ dR, T[:3, 3] + rng.uniform(-translation_m, translation_m, 3))


def _counts(holds: int | Sequence[int], sensors: Sequence[SceneSensor]) -> list[int]:
    def ok(n: Any) -> bool:
        return isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= 100

    if isinstance(holds, (int, np.integer)) and not isinstance(holds, bool):
        if not ok(holds):
            raise InputError(f"write_mocap_scene: holds must be an integer in 1..100 per sensor, got {holds!r}")
        return [int(holds)] * len(sensors)
    try:
        counts = list(holds)  # type: ignore[arg-type]
    except TypeError:
        raise InputError(f"write_mocap_scene: holds must be an integer or one integer per sensor, got {holds!r}") from None
    if len(counts) != len(sensors) or not all(ok(n) for n in counts):
        raise InputError(
            f"write_mocap_scene: holds must give one integer in 1..100 per sensor ({len(sensors)} sensors), got {holds!r}"
        )
    return [int(n) for n in counts]


def _check_sensors(sensors: Sequence[SceneSensor]) -> tuple[SceneSensor, ...]:
    out = tuple(sensors)
    if not all(isinstance(s, SceneSensor) for s in out):
        raise InputError("write_mocap_scene: sensors must be SceneSensor values")
    lidars = [s for s in out if s.kind == LIDAR]
    if len(lidars) != 1 or len(out) < 2:
        raise InputError(
            f"write_mocap_scene: the rig needs exactly one lidar and at least one camera, got "
            f"{', '.join(f'{s.name} ({s.kind})' for s in out) or 'no sensors'}"
        )
    for key in ("name", "topic", "frame_id"):
        values = [getattr(s, key) for s in out]
        dupes = sorted({v for v in values if values.count(v) > 1})
        if dupes:
            raise InputError(f"write_mocap_scene: sensors share the {key} {dupes}")
    if any(s.frame_id == ROBOT_FRAME for s in out):
        raise InputError(f"write_mocap_scene: '{ROBOT_FRAME}' is the robot frame, not a sensor frame_id")
    return out


def _transform_msg(store: Any, t_ns: int, parent: str, child: str, T: np.ndarray) -> Any:
    from rigcal.io.recordings.pointcloud2 import make_header
    from rigcal.mocap.streams import matrix_to_quat_xyzw

    q = matrix_to_quat_xyzw(T[:3, :3]) if np.all(np.isfinite(T)) else np.full(4, np.nan)  # a dropout
    V = store.types["geometry_msgs/msg/Vector3"]
    Q = store.types["geometry_msgs/msg/Quaternion"]
    tr = store.types["geometry_msgs/msg/Transform"](
        translation=V(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        rotation=Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
    return store.types["geometry_msgs/msg/TransformStamped"](
        header=make_header(store, t_ns, parent), child_frame_id=child, transform=tr)


def _image_msg(store: Any, t_ns: int, img: np.ndarray, frame_id: str) -> Any:
    from rigcal.io.recordings.pointcloud2 import make_header

    return store.types["sensor_msgs/msg/Image"](
        header=make_header(store, t_ns, frame_id), height=img.shape[0], width=img.shape[1],
        encoding="mono8", is_bigendian=0, step=img.shape[1],
        data=np.ascontiguousarray(img).reshape(-1).copy())


def _write_bag(path: Path, msgs: list[tuple[int, str, str, Any]], store: Any) -> None:
    """Write time-sorted messages to a ROS 1 bag at ``path``, atomically: the bag is written
    next to it under a temporary name and moved over ``path`` once complete."""
    from rosbags.rosbag1 import Writer

    staging = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:
        staging.mkdir()
        tmp = staging / path.name
        with Writer(tmp) as writer:
            conns: dict[str, Any] = {}
            for t_ns, topic, msgtype, msg in msgs:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
                writer.write(conns[topic], t_ns, store.serialize_ros1(msg, msgtype))
        interrupts.raise_if_requested()
        os.replace(tmp, path)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - OS and rosbags writer errors, with context
        raise InputError(f"{path}: cannot write bag: {exc}") from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _config_doc(sensors: Sequence[SceneSensor], target: Target, intrinsics: Mapping[str, str],
                target_topic: str, robot_topic: str, initial_sigma: tuple[float, float]) -> dict:
    entries = []
    for s in sensors:
        e: dict[str, Any] = {"name": s.name, "kind": s.kind, "topic": s.topic, "frame_id": s.frame_id}
        if s.kind == LIDAR:
            e["sigma_m"] = 0.01 if s.sigma is None else float(s.sigma)
            if s.azimuth_fov_deg is not None:
                e["azimuth_fov_deg"] = [float(v) for v in s.azimuth_fov_deg]
        else:
            e["intrinsics"] = intrinsics[s.name]
            e["sigma_px"] = 1.0 if s.sigma is None else float(s.sigma)
        entries.append(e)
    return {
        "recording": BAG_NAME,
        "mocap": {
            "robot": {"topic": robot_topic},
            # every lidar point on the plate tied to its surface: exact on exact scans, where
            # the diamond's corners from ICP were off by up to 4 mm on some seeds
            "targets": {target.name: {"topic": target_topic, "definition": TARGET_NAME,
                                      "use_lidar_keypoints": False}},
            "max_gap_s": 0.05,
        },
        "initial_calibration": INITIAL_NAME,
        "robot_frame": ROBOT_FRAME,
        "sensors": entries,
        "extraction": {"max_linear_mps": 0.1, "max_angular_dps": 5, "motion_window_s": 0.5,
                       "sigma_translation_m": float(initial_sigma[0]),
                       "sigma_rotation_deg": float(initial_sigma[1])},
        "options": {"loss": "huber"},
        "report": {"overlays_per_sensor": 2},
    }


def write_mocap_scene(
    folder: str | os.PathLike[str],
    sensors: Sequence[SceneSensor] | None = None,
    *,
    seed: int = 7,
    holds: int | Sequence[int] = 4,
    exclusive: bool = True,
    target: Target | None = None,
    placement: Placement | None = None,
    timing: SceneTiming = SceneTiming(),
    robot: RobotPath = RobotPath(),
    pixel_noise_sigma: float = 1.8,
    perturbation: tuple[float, float] = (0.03, 5.0),
    initial_sigma: tuple[float, float] = (0.02, 3.0),
    progress: Progress | None = None,
    mcs_noise: tuple[float, float] = (0.0, 0.0),
    hold_bias: tuple[float, float] = (0.0, 0.0),
    stamp_delay_s: Mapping[str, float] | None = None,
    stamp_jitter_s: float = 0.0,
    dropout_fraction: tuple[float, float] = (0.0, 0.0),
    glitch_s: float = 0.0,
    robot_still_in_holds: bool = True,
) -> MocapScene:
    """Simulate a calibration session of ``sensors`` (default :func:`default_rig`) and write
    it to ``folder`` (see the module docstring); returns what was written and the truth.

    ``holds``: target poses per sensor (one integer for all, or one per sensor), held in
    sensor order; ``exclusive``: every hold stays out of the other sensors' views (False: only
    in the view of its own sensor - a VLP-16 that sees all around then also sees the camera
    holds); ``target``: a checkerboard diamond (default 0.5 m with 7 x 6 inner corners of
    29 mm); ``placement``: where targets may be held (default 1.6-3 m from the sensor, no
    clutter); ``pixel_noise_sigma`` [grey levels]: image noise; ``perturbation``: (metres,
    degrees) per axis of the uniform perturbation of the initial calibration;
    ``initial_sigma``: (metres, degrees), the initial calibration's uncertainty written to
    ``mocap.yaml`` (it sizes the extractors' search regions). ``progress(done, total)`` is
    called after every simulated sensor frame. Files are written atomically; existing ones are
    replaced. Raises InputError for bad arguments, GeometryError when no target pose fits a
    sensor's view.

    Errors of a real session, drawn from a second generator (``[seed, 1]``: the defaults
    write the same files as before they existed): ``mcs_noise`` (translation [m], rotation
    [rad]) - every MCS sample of the robot and the target perturbed on the right, independently
    (a Vicon: about 0.15 mm / 0.3 mrad); ``hold_bias`` (translation [m], rotation [rad]) - one
    error of the target's MCS pose per hold, from the middle of the move before it to the
    middle of the move after it; ``stamp_delay_s`` (sensor name -> seconds) - each sensor's
    frames stamped that much after their capture (a clock offset between the MCS and the
    sensor); ``stamp_jitter_s`` - every frame's stamp off its capture by a normal error of that
    std; ``dropout_fraction`` (robot, target) - that fraction of each body's MCS samples
    published as dropouts (NaN values, what a bridge sends for a lost body); ``glitch_s`` -
    in every hold, the target's samples over that long a stretch are dropouts too.

    ``robot_still_in_holds`` (default): the robot follows ``robot`` only between the holds and
    stands while the target is held (a clock offset between the MCS and a sensor then has
    nothing to act on); False: it moves all the time."""
    from rosbags.typesys import Stores, get_typestore

    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.config.camchain import Camchain, format_camchain
    from rigcal.io.recordings.pointcloud2 import encode_pointcloud2
    from rigcal.io.config.vicon_json import write_vicon_target
    from rigcal.mocap import Extrinsics, write_extrinsics_json
    from rigcal.recording import PointCloudFrame

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"write_mocap_scene: seed must be an integer >= 0, got {seed!r}")
    rig = _check_sensors(default_rig() if sensors is None else sensors)
    counts = _counts(holds, rig)
    if not isinstance(robot_still_in_holds, bool):
        raise InputError(f"write_mocap_scene: robot_still_in_holds must be true or false, got {robot_still_in_holds!r}")
    if not isinstance(exclusive, bool):
        raise InputError(f"write_mocap_scene: exclusive must be true or false, got {exclusive!r}")
    if target is None:
        target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    if not isinstance(target, Target) or target.kind is not TargetKind.CHECKERBOARD_DIAMOND:
        raise InputError("write_mocap_scene: target must be a checkerboard diamond Target")
    if placement is None:
        placement = Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0)
    if not isinstance(placement, Placement) or not isinstance(timing, SceneTiming) or not isinstance(robot, RobotPath):
        raise InputError("write_mocap_scene: placement, timing and robot must be Placement, SceneTiming and RobotPath values")
    if not (isinstance(pixel_noise_sigma, (int, float)) and math.isfinite(pixel_noise_sigma) and pixel_noise_sigma >= 0):
        raise InputError(f"write_mocap_scene: pixel_noise_sigma must be >= 0, got {pixel_noise_sigma!r}")
    for what, pair in (("perturbation", perturbation), ("initial_sigma", initial_sigma)):
        try:
            a, b = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise InputError(f"write_mocap_scene: {what} must be (metres, degrees), got {pair!r}") from None
        if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0) or (what == "initial_sigma" and not (a > 0 and b > 0)):
            raise InputError(f"write_mocap_scene: {what} must be two finite numbers >= 0 (> 0 for initial_sigma), got {pair!r}")
    for what, pair in (("mcs_noise", mcs_noise), ("hold_bias", hold_bias), ("dropout_fraction", dropout_fraction)):
        try:
            a, b = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise InputError(f"write_mocap_scene: {what} must be two numbers, got {pair!r}") from None
        if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0) or (what == "dropout_fraction" and max(a, b) >= 1):
            raise InputError(f"write_mocap_scene: {what} must be two numbers >= 0 (fractions < 1), got {pair!r}")
    for what, v in (("stamp_jitter_s", stamp_jitter_s), ("glitch_s", glitch_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"write_mocap_scene: {what} must be a number >= 0 [s], got {v!r}")
    delays = {s.name: 0.0 for s in rig}
    for name, v in dict(stamp_delay_s or {}).items():
        if name not in delays:
            raise InputError(f"write_mocap_scene: stamp_delay_s: no sensor '{name}' (sensors: {', '.join(delays)})")
        if not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) < 1.0):
            raise InputError(f"write_mocap_scene: stamp_delay_s['{name}'] must be a number of seconds below 1 in size, got {v!r}")
        delays[name] = float(v)
    n_holds = sum(counts)
    if timing.gap_hold is not None and timing.gap_hold >= n_holds:
        raise InputError(f"write_mocap_scene: timing.gap_hold {timing.gap_hold} but the session has only {n_holds} holds")

    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out}: cannot create the scene folder: {exc.strerror or exc}") from exc

    rng = np.random.default_rng(int(seed))
    T0 = T0_NS

    # the holds' times: sensor after sensor
    aims = [s for s, n in zip(rig, counts) for _ in range(n)]
    hold_ns, move_ns = int(timing.hold_s * NS), int(timing.move_s * NS)
    spans = [T0 + int(timing.lead_s * NS) + k * (hold_ns + move_ns) for k in range(len(aims))]
    spans = [(a, a + hold_ns) for a in spans]

    def robot_at(t_ns: int) -> np.ndarray:
        if not robot_still_in_holds:
            return robot.at((t_ns - T0) / NS)
        # the robot moves only between the holds: its path's clock stops while one lasts
        still = sum(min(max(t_ns - a, 0), b - a) for a, b in spans)
        return robot.at((t_ns - T0 - still) / NS)

    # the holds: each pose in its sensor's view (and no other's)
    holds: list[tuple[int, int, SceneSensor]] = []
    moves: list[tuple[int, int]] = []
    poses: list[np.ndarray] = []
    t = T0 + int(timing.lead_s * NS)
    for k, aim in enumerate(aims):
        if k:
            moves.append((t, t + move_ns))
            t += move_ns
        T_mr = robot_at(t + hold_ns // 2)
        others = [s.view(T_mr) for s in rig if s is not aim] if exclusive else []
        poses.append(sample_pose_in_view(aim.view(T_mr), target, rng, placement, avoid=others))
        holds.append((t, t + hold_ns, aim))
        t += hold_ns
    end = t + int(timing.lead_s * NS)

    def target_at(t_ns: int) -> np.ndarray:
        for k, (a, b, _) in enumerate(holds):
            if t_ns < b:
                if t_ns >= a or k == 0:
                    return poses[k]
                m0 = moves[k - 1][0]
                return _between(poses[k - 1], poses[k], _smooth((t_ns - m0) / (a - m0)))
        return poses[-1]

    gap = None
    if timing.gap_hold is not None:
        g0 = holds[timing.gap_hold][0]
        gap = (g0 + int(timing.gap_s[0] * NS), g0 + int(timing.gap_s[1] * NS))

    store = get_typestore(Stores.ROS1_NOETIC)
    robot_topic = f"/vicon/{ROBOT_BODY}/{ROBOT_BODY}"
    target_topic = f"/vicon/{target.name}/{target.name}"
    msgs: list[tuple[int, str, str, Any]] = []
    # the session's errors from their own generator: the defaults leave the files unchanged
    err = np.random.default_rng([int(seed), 1])
    biases = [se3_exp(np.concatenate([err.normal(0, hold_bias[1], 3), err.normal(0, hold_bias[0], 3)]))
              for _ in holds] if max(hold_bias) > 0 else None
    edges = [T0] + [(a + b) // 2 for a, b in moves] + [end + 1]
    glitches = []
    if glitch_s > 0:
        for a, b, _ in holds:
            g0 = a + int(err.uniform(0.1, 0.9) * (b - a - glitch_s * NS))
            glitches.append((g0, g0 + int(glitch_s * NS)))

    def noisy(T: np.ndarray) -> np.ndarray:
        if max(mcs_noise) <= 0:
            return T
        return T @ se3_exp(np.concatenate([err.normal(0, mcs_noise[1], 3), err.normal(0, mcs_noise[0], 3)]))

    nan_pose = np.full((4, 4), np.nan)
    for t_ns in range(T0, end + 1, NS // timing.mcs_hz):
        if gap is None or not gap[0] <= t_ns <= gap[1]:
            T = noisy(robot_at(t_ns))
            if dropout_fraction[0] > 0 and err.uniform() < dropout_fraction[0]:
                T = nan_pose
            msgs.append((t_ns, robot_topic, "geometry_msgs/msg/TransformStamped",
                         _transform_msg(store, t_ns, MOCAP_FRAME, f"vicon/{ROBOT_BODY}/{ROBOT_BODY}", T)))
        T = target_at(t_ns)
        if biases is not None:
            T = T @ biases[int(np.searchsorted(edges, t_ns, side="right")) - 1]
        T = noisy(T)
        if (dropout_fraction[1] > 0 and err.uniform() < dropout_fraction[1]) or any(a <= t_ns < b for a, b in glitches):
            T = nan_pose
        msgs.append((t_ns, target_topic, "geometry_msgs/msg/TransformStamped",
                     _transform_msg(store, t_ns, MOCAP_FRAME, f"vicon/{target.name}/{target.name}", T)))

    def stamp(name: str, t_ns: int) -> int:
        """The header stamp of a frame captured at ``t_ns``: late by the sensor's delay, off by
        the jitter."""
        jitter = err.normal(0, stamp_jitter_s) if stamp_jitter_s > 0 else 0.0
        return int(t_ns + round((delays[name] + jitter) * NS))

    # sensor frames: the lidar, then every camera half a period later (each a little after the
    # one before)
    step = NS // timing.sensor_hz
    lidar_times = np.arange(T0 + step // 3, end - step // 3, step, dtype=np.int64)
    cameras = [s for s in rig if s.kind == CAMERA]
    frames: dict[str, np.ndarray] = {}
    for s in rig:
        if s.kind == LIDAR:
            frames[s.name] = lidar_times
        else:
            times = lidar_times + step // 2 + cameras.index(s) * (step // 8)
            frames[s.name] = times[times < end - NS // 10]
    total = sum(len(v) for v in frames.values())
    done = 0
    seen: dict[str, np.ndarray] = {}
    lidar = next(s for s in rig if s.kind == LIDAR)
    hits = np.zeros(len(lidar_times), dtype=bool)
    for i, t_ns in enumerate(lidar_times):
        T_ml = robot_at(int(t_ns)) @ lidar.T_robot_sensor
        cloud = cast_lidar(lidar.model, T_ml, target, target_at(int(t_ns)), (), rng, t_ns=int(t_ns),
                           sensor=lidar.name, azimuth_fov_deg=lidar.azimuth_fov_deg)
        hits[i] = bool(np.any(cloud.fields["surface"] == 0))
        st = stamp(lidar.name, int(t_ns))
        cloud = PointCloudFrame(lidar.name, st, cloud.points_xyz,
                                {"intensity": cloud.fields["intensity"], "ring": cloud.fields["ring"]},
                                frame_id=lidar.frame_id)
        msgs.append((st, lidar.topic, "sensor_msgs/msg/PointCloud2", encode_pointcloud2(cloud, store)))
        done += 1
        if progress is not None:
            progress(done, total)
    seen[lidar.name] = hits
    spread = target.template[:: max(1, len(target.template) // 2000)]
    background = Appearance().background_grey
    for cam in cameras:
        model = cam.model
        assert isinstance(model, CameraModel)
        hits = np.zeros(len(frames[cam.name]), dtype=bool)
        for i, t_ns in enumerate(frames[cam.name]):
            T_ct = invert(robot_at(int(t_ns)) @ cam.T_robot_sensor) @ target_at(int(t_ns))
            corners = target.lidar_keypoints @ T_ct[:3, :3].T + T_ct[:3, 3]
            if np.all(corners[:, 2] > 0.2):
                img = render_image(model, T_ct, target, rng, noise_sigma=pixel_noise_sigma).image
                _, valid = model.project(transform_points(T_ct, spread))
                hits[i] = bool(valid.any())
            else:  # part of the target behind the camera: it is not in the image
                img = np.clip(background + rng.normal(0, pixel_noise_sigma, (model.height, model.width)),
                              0, 255).astype(np.uint8)
            st = stamp(cam.name, int(t_ns))
            msgs.append((st, cam.topic, "sensor_msgs/msg/Image", _image_msg(store, st, img, cam.frame_id)))
            done += 1
            if progress is not None:
                progress(done, total)
        seen[cam.name] = hits
    msgs.sort(key=lambda m: m[0])
    bag = out / BAG_NAME
    _write_bag(bag, msgs, store)

    truth = {s.name: s.T_robot_sensor for s in rig}
    initial = {s.name: _perturb(s.T_robot_sensor, rng, float(perturbation[0]), float(perturbation[1])) for s in rig}
    for T in initial.values():
        T.setflags(write=False)

    target_path = write_vicon_target(out / TARGET_NAME, target)
    intrinsics: dict[str, Path] = {}
    for cam in cameras:
        chain = Camchain({"cam0": cam.model}, {}, {"cam0": cam.topic})  # type: ignore[dict-item]
        intrinsics[cam.name] = atomic_write_text(out / f"{cam.name}.yaml", format_camchain(chain))
    initial_path = write_extrinsics_json(
        out / INITIAL_NAME, Extrinsics({(ROBOT_FRAME, s.frame_id): initial[s.name] for s in rig}))
    import yaml

    doc = _config_doc(rig, target, {k: v.name for k, v in intrinsics.items()}, target_topic, robot_topic,
                      (float(initial_sigma[0]), float(initial_sigma[1])))
    header = (f"# rigcal mocap configuration of a simulated session (seed {int(seed)}): "
              f"{', '.join(f'{s.name} ({s.kind})' for s in rig)}\n")
    config_path = atomic_write_text(out / CONFIG_NAME, header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))

    def frozen(a: np.ndarray) -> np.ndarray:
        a = np.array(a)
        a.setflags(write=False)
        return a

    return MocapScene(
        folder=out,
        config_path=config_path,
        bag_path=bag,
        target_path=target_path,
        initial_path=initial_path,
        intrinsics=MappingProxyType(intrinsics),
        sensors=rig,
        target=target,
        truth=MappingProxyType(truth),
        initial=MappingProxyType(initial),
        holds=tuple(Hold(a, b, s.name, frozen(p)) for (a, b, s), p in zip(holds, poses)),
        moves=tuple(moves),
        gap=gap,
        frames=MappingProxyType({k: frozen(v) for k, v in frames.items()}),
        target_seen=MappingProxyType({k: frozen(v) for k, v in seen.items()}),
        robot=robot,
        timing=timing,
        t0_ns=T0,
        end_ns=end,
        seed=int(seed),
        robot_topic=robot_topic,
        target_topic=target_topic,
        robot_still_in_holds=robot_still_in_holds,
    )
