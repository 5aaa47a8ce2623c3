"""Synthetic rigs with known ground truth: sensors, board placements, simulated detections.

Frames (see ``docs/conventions.md``): the rig (vehicle) frame has x forward, y left, z up.
Lidar and radar frames have x forward, y left, z up; a camera uses its optical frame
(z forward along the optical axis, x right, y down). ``T_rig_sensor`` maps sensor-frame points
into the rig frame; ``T_rig_board`` maps board-frame points (:mod:`rigcal.targets.circle_board`)
into the rig frame.

Noise models (all sigmas are one standard deviation, independent per board and per point):

* lidar: isotropic Gaussian noise ``sigma_m`` on each circle centre (x, y, z);
* camera (stereo-like): ``sigma_m`` across the line of sight (two perpendicular directions) and
  ``depth_sigma_at_1m_m * (range_m / 1 m)**2`` along it - stereo depth error grows with the
  square of the range;
* 2D radar: Gaussian noise on range (``range_sigma_m``) and azimuth (``azimuth_sigma_deg``) of
  the reflector; the detection is ``range * (cos az, sin az)``, i.e.
  :func:`rigcal.sensors.radar.project_2d` of the noisy point;
* 3D radar: Gaussian noise on range, azimuth and elevation (``elevation_sigma_deg``).

A board is detected only when the sensor faces the board's front (incidence angle at most
``max_incidence_deg``), and all its measured points (four circle centres for lidar / camera,
the reflector for radars) lie within the field of view and between ``min_range_m`` and
``max_range_m``. ``miss_probability`` drops detected boards at random. Undetected boards are NaN
rows in the dataset.

Every random draw comes from a ``numpy.random.Generator`` given by the caller (or an int seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Iterable, Sequence

import numpy as np

from rigcal.dataset import BoardGeometry, Dataset, SensorDetections, SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.targets.circle_board import board_centres, reflector_in_board
from rigcal.geometry.se3 import as_rigid

RIG_FRAME = "rig"

#: Rotation of a camera optical frame (z forward, x right, y down) in a body frame with
#: x forward, y left, z up: columns are the optical x, y, z axes in the body frame.
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_BODY_OPTICAL.setflags(write=False)

_KIND_DEFAULTS: dict[SensorKind, dict[str, float]] = {
    SensorKind.LIDAR: {
        "sigma_m": 0.01,
        "max_azimuth_deg": 180.0,
        "max_elevation_deg": 15.0,
        "max_range_m": 100.0,
    },
    SensorKind.CAMERA: {
        "sigma_m": 0.003,
        "depth_sigma_at_1m_m": 0.002,
        "max_azimuth_deg": 35.0,
        "max_elevation_deg": 25.0,
        "max_range_m": 20.0,
    },
    SensorKind.RADAR: {
        "range_sigma_m": 0.02,
        "azimuth_sigma_deg": 0.3,
        "max_azimuth_deg": 60.0,
        "max_elevation_deg": 9.0,
        "max_range_m": 50.0,
    },
    SensorKind.RADAR3D: {
        "range_sigma_m": 0.02,
        "azimuth_sigma_deg": 0.3,
        "elevation_sigma_deg": 0.5,
        "max_azimuth_deg": 60.0,
        "max_elevation_deg": 15.0,
        "max_range_m": 50.0,
    },
}

_NOISE_FIELDS = (
    "sigma_m",
    "depth_sigma_at_1m_m",
    "range_sigma_m",
    "azimuth_sigma_deg",
    "elevation_sigma_deg",
)


def _as_rng(rng: np.random.Generator | int) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise InputError(
        f"rng must be a numpy.random.Generator or an int seed, got {type(rng).__name__}"
    )




@dataclass(frozen=True, eq=False)
class SimSensor:
    """A simulated sensor: pose in the rig frame, noise, field of view.

    Fields left at ``None`` take the kind's default (see the table in ``docs/conventions.md``);
    noise fields that do not apply to the kind become 0.

    * ``sigma_m``: lidar - isotropic noise per axis [m]; camera - noise across the line of sight.
    * ``depth_sigma_at_1m_m``: camera - noise along the line of sight at 1 m; it grows with
      ``range_m**2``: ``sigma_depth = depth_sigma_at_1m_m * (range_m / 1 m)**2``.
    * ``range_sigma_m``, ``azimuth_sigma_deg``, ``elevation_sigma_deg``: radar noise.
    * ``max_azimuth_deg``: horizontal half-angle field of view; lidar / radar: max ``|atan2(y, x)|``
      (180 = all around); camera: max ``|atan2(x, z)|`` in the optical frame.
    * ``max_elevation_deg`` / ``min_elevation_deg``: vertical limits; lidar / radar: elevation
      ``atan2(z, hypot(x, y))`` must lie in [min, max]; camera: ``-atan2(y, z)`` (up is positive).
      ``min_elevation_deg=None`` means ``-max_elevation_deg`` (symmetric). For a 2D radar
      ``max_elevation_deg`` is the |elevation| limit of the paper's constraint (eq. 4).
    """

    name: str
    kind: SensorKind
    T_rig_sensor: np.ndarray
    sigma_m: float | None = None
    depth_sigma_at_1m_m: float | None = None
    range_sigma_m: float | None = None
    azimuth_sigma_deg: float | None = None
    elevation_sigma_deg: float | None = None
    max_azimuth_deg: float | None = None
    max_elevation_deg: float | None = None
    min_elevation_deg: float | None = None
    min_range_m: float = 0.5
    max_range_m: float | None = None
    max_incidence_deg: float = 75.0
    miss_probability: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InputError(f"sim sensor name must be a non-empty string, got {self.name!r}")
        kind = (
            self.kind
            if isinstance(self.kind, SensorKind)
            else SensorKind.parse(self.kind, f"sim sensor '{self.name}'")
        )
        object.__setattr__(self, "kind", kind)
        T = as_rigid(self.T_rig_sensor, f"sim sensor '{self.name}'.T_rig_sensor")
        object.__setattr__(self, "T_rig_sensor", T)
        defaults = _KIND_DEFAULTS[kind]
        for f in fields(self):
            if getattr(self, f.name) is None and f.name != "min_elevation_deg":
                object.__setattr__(self, f.name, float(defaults.get(f.name, 0.0)))
        if self.min_elevation_deg is None:
            object.__setattr__(self, "min_elevation_deg", -float(self.max_elevation_deg))
        for name in _NOISE_FIELDS + ("min_range_m",):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"sim sensor '{self.name}'.{name} must be >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        for name in ("max_azimuth_deg", "max_elevation_deg", "max_range_m", "max_incidence_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"sim sensor '{self.name}'.{name} must be > 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if not self.min_elevation_deg < self.max_elevation_deg:
            raise InputError(
                f"sim sensor '{self.name}': min_elevation_deg ({self.min_elevation_deg}) must be "
                f"below max_elevation_deg ({self.max_elevation_deg})"
            )
        if not self.min_range_m < self.max_range_m:
            raise InputError(
                f"sim sensor '{self.name}': min_range_m ({self.min_range_m}) must be below "
                f"max_range_m ({self.max_range_m})"
            )
        if not (0.0 <= self.miss_probability <= 1.0):
            raise InputError(
                f"sim sensor '{self.name}'.miss_probability must be in [0, 1], "
                f"got {self.miss_probability!r}"
            )

    @property
    def position_rig(self) -> np.ndarray:
        """(3,) sensor origin in the rig frame [m]."""
        return self.T_rig_sensor[:3, 3].copy()

    def with_pose(self, T_rig_sensor: np.ndarray) -> "SimSensor":
        """A copy at another pose."""
        return replace(self, T_rig_sensor=T_rig_sensor)

    def noise_free(self) -> "SimSensor":
        """A copy with every sigma and the miss probability set to 0."""
        return replace(self, miss_probability=0.0, **{n: 0.0 for n in _NOISE_FIELDS})


@dataclass(frozen=True, eq=False)
class SimResult:
    """A simulated dataset and the truth it was drawn from.

    ``truth[name]`` is ``T_rig_sensor`` (4, 4); ``T_rig_board`` (K, 4, 4) the board poses.
    """

    dataset: Dataset
    truth: dict[str, np.ndarray]
    T_rig_board: np.ndarray
    sensors: tuple[SimSensor, ...] = field(default=())

    def truth_T(self, to: str, frm: str) -> np.ndarray:
        """True ``T_to_from`` between two sensors; the name ``"rig"`` stands for the rig frame."""
        return invert(self._T_rig(to)) @ self._T_rig(frm)

    def _T_rig(self, name: str) -> np.ndarray:
        if name in self.truth:
            return np.asarray(self.truth[name])
        if name == RIG_FRAME:
            return np.eye(4)
        raise InputError(
            f"unknown sensor '{name}' (simulated sensors: {sorted(self.truth)}, or '{RIG_FRAME}')"
        )


# --------------------------------------------------------------------------- visibility


def _angles(sensor: SimSensor, points_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth, elevation [rad] of (..., 3) points in the sensor's own convention."""
    x, y, z = points_sensor[..., 0], points_sensor[..., 1], points_sensor[..., 2]
    if sensor.kind is SensorKind.CAMERA:
        # optical frame: azimuth right-positive, elevation up-positive; behind the camera -> pi
        az = np.where(z > 0, np.arctan2(x, z), np.pi)
        el = np.where(z > 0, np.arctan2(-y, z), np.pi)
        return az, el
    return np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))


def _points_in_board(kind: SensorKind, board: BoardGeometry) -> np.ndarray:
    """(P, 3) points a sensor of ``kind`` measures, in the board frame."""
    if kind.is_point_cloud:
        return board_centres(board)
    return reflector_in_board(board)[None, :]


def _check_board_poses(T_rig_board: np.ndarray) -> np.ndarray:
    T = np.array(T_rig_board, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"T_rig_board must have shape (K, 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError("T_rig_board has non-finite entries")
    return T


def visible(
    sensor: SimSensor, T_rig_board: np.ndarray, board: BoardGeometry = BoardGeometry()
) -> np.ndarray:
    """(K,) bool: the sensor can detect each board (geometry only: FOV, range, facing).

    ``miss_probability`` is not applied here.
    """
    T = _check_board_poses(T_rig_board)
    T_sensor_board = invert(sensor.T_rig_sensor) @ T
    pts_board = _points_in_board(sensor.kind, board)
    pts = np.einsum("kij,pj->kpi", T_sensor_board[:, :3, :3], pts_board) + T_sensor_board[
        :, None, :3, 3
    ]
    rng_m = np.linalg.norm(pts, axis=-1)
    az, el = _angles(sensor, pts)
    ok = (
        (rng_m >= sensor.min_range_m)
        & (rng_m <= sensor.max_range_m)
        & (np.abs(az) <= math.radians(sensor.max_azimuth_deg) + 1e-12)
        & (el <= math.radians(sensor.max_elevation_deg))
        & (el >= math.radians(sensor.min_elevation_deg))
    )
    # the sensor must see the front face: board z axis toward the sensor
    normal = T_sensor_board[:, :3, 2]
    to_sensor = -T_sensor_board[:, :3, 3]
    dist = np.maximum(np.linalg.norm(to_sensor, axis=-1), 1e-12)
    cos_inc = np.einsum("ki,ki->k", normal, to_sensor) / dist
    facing = cos_inc >= math.cos(math.radians(sensor.max_incidence_deg))
    return np.all(ok, axis=1) & facing


# --------------------------------------------------------------------------- simulation


def _camera_noise(
    sensor: SimSensor, pts: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """Noise (..., 3) for points (..., 3): ``sigma_m`` across the ray, range-squared along it."""
    r = np.maximum(np.linalg.norm(pts, axis=-1, keepdims=True), 1e-12)
    u = pts / r
    helper = np.where(np.abs(u[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(u, e1)
    depth_sigma = sensor.depth_sigma_at_1m_m * r**2
    return sensor.sigma_m * (normals[..., :1] * e1 + normals[..., 1:2] * e2) + depth_sigma * (
        normals[..., 2:3] * u
    )


def _spherical(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = np.linalg.norm(pts, axis=-1)
    az = np.arctan2(pts[..., 1], pts[..., 0])
    return r, az, np.arctan2(pts[..., 2], np.hypot(pts[..., 0], pts[..., 1]))


def _detect(
    sensor: SimSensor, T_rig_board: np.ndarray, board: BoardGeometry, rng: np.random.Generator
) -> np.ndarray:
    """One sensor's detection table (K, ...) with NaN rows for undetected boards."""
    K = T_rig_board.shape[0]
    T_sensor_board = invert(sensor.T_rig_sensor) @ T_rig_board
    pts_board = _points_in_board(sensor.kind, board)
    pts = np.einsum("kij,pj->kpi", T_sensor_board[:, :3, :3], pts_board) + T_sensor_board[
        :, None, :3, 3
    ]  # (K, P, 3)
    # draw the same numbers whatever is visible, so the stream does not depend on the FOV
    normals = rng.standard_normal(pts.shape)
    miss = rng.random(K) < sensor.miss_probability
    if sensor.kind is SensorKind.LIDAR:
        out = pts + sensor.sigma_m * normals
    elif sensor.kind is SensorKind.CAMERA:
        out = pts + _camera_noise(sensor, pts, normals)
    else:
        r, az, el = _spherical(pts[:, 0, :])
        r = r + sensor.range_sigma_m * normals[:, 0, 0]
        az = az + math.radians(sensor.azimuth_sigma_deg) * normals[:, 0, 1]
        if sensor.kind is SensorKind.RADAR:
            out = np.stack([r * np.cos(az), r * np.sin(az)], axis=-1)
        else:
            el = el + math.radians(sensor.elevation_sigma_deg) * normals[:, 0, 2]
            out = np.stack(
                [r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1
            )
    detected = visible(sensor, T_rig_board, board) & ~miss
    out = np.array(out, dtype=float)
    out[~detected] = np.nan
    return out


def _check_sensors(sensors: Sequence[SimSensor]) -> tuple[SimSensor, ...]:
    sensors = tuple(sensors)
    for s in sensors:
        if not isinstance(s, SimSensor):
            raise InputError(f"expected SimSensor values, got {type(s).__name__}")
    names = [s.name for s in sensors]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise InputError(f"duplicate simulated sensor names: {dupes}")
    return sensors


def simulate(
    sensors: Sequence[SimSensor],
    T_rig_board: np.ndarray,
    board: BoardGeometry = BoardGeometry(),
    rng: np.random.Generator | int = 0,
    reference: str | None = None,
) -> SimResult:
    """Detections of K boards at ``T_rig_board`` (K, 4, 4) by every sensor, with their truth.

    Draws, sensor by sensor in the given order, the same amount of random numbers whatever is
    visible: a seed reproduces the dataset exactly.
    """
    sensors = _check_sensors(sensors)
    T = _check_board_poses(T_rig_board)
    gen = _as_rng(rng)
    detections = []
    for s in sensors:
        pts = _detect(s, T, board, gen)
        extra = {}
        if s.kind.is_radar:
            extra["max_elevation_rad"] = math.radians(
                max(s.max_elevation_deg, -s.min_elevation_deg)
            )
        detections.append(
            SensorDetections(
                name=s.name, kind=s.kind, points=pts, frame_id=s.name, source="simulated", **extra
            )
        )
    dataset = Dataset(
        sensors=tuple(detections), board=board, reference=reference, source="simulated"
    )
    T.setflags(write=False)
    truth = {s.name: s.T_rig_sensor for s in sensors}
    return SimResult(dataset=dataset, truth=truth, T_rig_board=T, sensors=sensors)


# --------------------------------------------------------------------------- board placements


def _rot_x(a: np.ndarray) -> np.ndarray:
    return matrix_from_rpy(np.stack([a, np.zeros_like(a), np.zeros_like(a)], axis=-1))


def _rot_y(a: np.ndarray) -> np.ndarray:
    return matrix_from_rpy(np.stack([np.zeros_like(a), a, np.zeros_like(a)], axis=-1))


def _rot_z(a: np.ndarray) -> np.ndarray:
    return matrix_from_rpy(np.stack([np.zeros_like(a), np.zeros_like(a), a], axis=-1))


def make_board_placements(
    rng: np.random.Generator | int,
    num_boards: int,
    center_rig: Sequence[float] = (0.0, 0.0, 0.5),
    *,
    distance_m: tuple[float, float] = (3.0, 7.0),
    azimuth_spread_deg: float = 25.0,
    heading_deg: float = 0.0,
    elevation_spread_deg: float = 4.0,
    tilt_deg: float = 15.0,
    yaw_deg: float = 20.0,
    board: BoardGeometry = BoardGeometry(),
) -> np.ndarray:
    """(K, 4, 4) ``T_rig_board`` for boards in front of ``center_rig`` (3,) [m, rig frame].

    The reflector of each board lies at a distance in ``distance_m`` from ``center_rig``, at an
    azimuth within ``heading_deg +- azimuth_spread_deg`` (0 = rig x axis) and an elevation within
    ``+- elevation_spread_deg`` seen from ``center_rig`` - put ``center_rig`` on a 2D radar's
    plane and the radar sees the reflector. The board's front face (board z axis) points back
    toward ``center_rig``, then the board is turned by a random yaw (about its y axis, within
    ``+- yaw_deg``), pitch (about its x axis) and roll (about its z axis), each within
    ``+- tilt_deg``. Board frame as in :mod:`rigcal.targets.circle_board` (y up before tilting).
    """
    gen = _as_rng(rng)
    K = int(num_boards)
    if K < 0:
        raise InputError(f"num_boards must be >= 0, got {num_boards}")
    c = np.asarray(center_rig, dtype=float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"center_rig must be a finite (3,) point, got shape {c.shape}")
    d_lo, d_hi = (float(v) for v in distance_m)
    if not 0 < d_lo <= d_hi:
        raise InputError(f"distance_m must be (min, max) with 0 < min <= max, got {distance_m}")
    d = gen.uniform(d_lo, d_hi, K)
    az = math.radians(heading_deg) + np.radians(gen.uniform(-1, 1, K) * azimuth_spread_deg)
    el = np.radians(gen.uniform(-1, 1, K) * elevation_spread_deg)
    yaw = np.radians(gen.uniform(-1, 1, K) * yaw_deg)
    pitch = np.radians(gen.uniform(-1, 1, K) * tilt_deg)
    roll = np.radians(gen.uniform(-1, 1, K) * tilt_deg)
    reflector_rig = c + d[:, None] * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
    )
    # base orientation: z toward the centre (horizontal), y up, x = y cross z (right as seen)
    z_b = -np.stack([np.cos(az), np.sin(az), np.zeros(K)], axis=-1)
    y_b = np.broadcast_to([0.0, 0.0, 1.0], (K, 3))
    x_b = np.cross(y_b, z_b)
    R_base = np.stack([x_b, y_b, z_b], axis=-1)
    R = R_base @ _rot_y(yaw) @ _rot_x(pitch) @ _rot_z(roll)
    origin = reflector_rig - np.einsum("kij,j->ki", R, reflector_in_board(board))
    return from_rt(R, origin)


def board_area_center(sensors: Sequence[SimSensor]) -> np.ndarray:
    """(3,) point [m, rig frame] boards are placed around for a rig.

    x, y: the mean position of all sensors; z: the mean height of the 2D radars (so their planes
    pass near the reflectors), or the mean sensor height clipped to [0.5, 1.5] m without 2D radars.
    """
    sensors = _check_sensors(sensors)
    if not sensors:
        raise InputError("board_area_center needs at least one sensor")
    pos = np.array([s.position_rig for s in sensors])
    radars = [s.position_rig[2] for s in sensors if s.kind is SensorKind.RADAR]
    z = float(np.mean(radars)) if radars else float(np.clip(pos[:, 2].mean(), 0.5, 1.5))
    return np.array([pos[:, 0].mean(), pos[:, 1].mean(), z])


def make_rig_placements(
    rng: np.random.Generator | int,
    sensors: Sequence[SimSensor],
    num_boards: int,
    *,
    min_fraction: float = 0.6,
    partial_probability: float = 0.25,
    board: BoardGeometry = BoardGeometry(),
    max_candidates: int = 20000,
    **placement: float | tuple[float, float],
) -> np.ndarray:
    """(K, 4, 4) ``T_rig_board`` such that every sensor geometrically sees >= ``min_fraction``.

    Candidates come from :func:`make_board_placements` around :func:`board_area_center`
    (``placement`` keyword arguments are passed on). A candidate seen by every sensor is kept; one
    missed by some sensors (e.g. outside a 2D radar's elevation field of view - it simply is not
    detected by that radar) is kept with probability ``partial_probability`` if at least two
    sensors see it and no sensor's share of missed boards would exceed ``1 - min_fraction``.
    Raises InputError if ``max_candidates`` candidates do not suffice.
    """
    sensors = _check_sensors(sensors)
    gen = _as_rng(rng)
    K = int(num_boards)
    if not 0.0 <= min_fraction <= 1.0:
        raise InputError(f"min_fraction must be in [0, 1], got {min_fraction}")
    center = board_area_center(sensors)
    allowed_misses = int(math.floor((1.0 - min_fraction) * K + 1e-9))
    misses = np.zeros(len(sensors), dtype=int)
    seen_total = np.zeros(len(sensors), dtype=int)
    kept: list[np.ndarray] = []
    tried = 0
    batch = max(8, 2 * K)
    while len(kept) < K and tried < max_candidates:
        cand = make_board_placements(
            gen, batch, center, board=board, **placement  # type: ignore[arg-type]
        )
        vis = np.stack([visible(s, cand, board) for s in sensors])  # (S, B)
        coins = gen.random(batch)
        for j in range(batch):
            if len(kept) >= K:
                break
            tried += 1
            seen = vis[:, j]
            seen_total += seen
            if seen.all():
                kept.append(cand[j])
            elif (
                seen.sum() >= 2
                and coins[j] < partial_probability
                and np.all(misses + ~seen <= allowed_misses)
            ):
                misses += ~seen
                kept.append(cand[j])
    if len(kept) < K:
        share = ", ".join(
            f"{s.name} {100.0 * n / max(tried, 1):.0f}%" for s, n in zip(sensors, seen_total)
        )
        raise InputError(
            f"could not place {K} boards seen by the rig's sensors: {len(kept)} found in "
            f"{tried} candidates around {np.round(center, 2).tolist()} (candidates seen: {share})"
        )
    return np.array(kept).reshape(K, 4, 4)


# --------------------------------------------------------------------------- presets


def _pose(
    xyz: Sequence[float], rpy_deg: Sequence[float], R_post: np.ndarray | None = None
) -> np.ndarray:
    R = matrix_from_rpy(np.radians(np.asarray(rpy_deg, dtype=float)))
    if R_post is not None:
        R = R @ R_post
    return from_rt(R, np.asarray(xyz, dtype=float))


def prius_like_rig() -> tuple[SimSensor, ...]:
    """A Toyota-Prius-like rig (rig frame: on the ground below the rear axle, x forward, z up).

    * ``lidar1``: HDL-64E-like on the roof, 1.9 m high; 360 deg horizontally, +2 / -24.8 deg
      vertically (the HDL-64E's span), 1 cm noise;
    * ``camera1``: left camera of a stereo pair behind the windshield, 1.3 m high, optical frame,
      pitched 3 deg down; 3 mm lateral noise, depth noise 1 mm at 1 m growing with range squared
      (a 0.5 m baseline, 1400 px focal length, 0.5 px disparity noise gives about 0.7 mm);
    * ``radar1``: 2D radar (ARS430-like) in the front bumper, 0.5 m high; 2 cm range noise,
      0.3 deg azimuth noise, +-9 deg elevation field of view.

    Each pose carries a small, deliberate misalignment so that no axis is exactly aligned.
    """
    return (
        SimSensor(
            "lidar1",
            SensorKind.LIDAR,
            _pose((1.2, 0.0, 1.9), (0.4, -0.8, 1.5)),
            sigma_m=0.01,
            max_elevation_deg=2.0,
            min_elevation_deg=-24.8,
        ),
        SimSensor(
            "camera1",
            SensorKind.CAMERA,
            _pose((1.6, 0.27, 1.3), (-0.5, 3.0, -0.7), R_BODY_OPTICAL),
            sigma_m=0.003,
            depth_sigma_at_1m_m=0.001,
        ),
        SimSensor(
            "radar1",
            SensorKind.RADAR,
            _pose((3.7, -0.05, 0.5), (0.3, 0.5, -1.2)),
            range_sigma_m=0.02,
            azimuth_sigma_deg=0.3,
            max_elevation_deg=9.0,
        ),
    )


_PROBE_DISTANCES_M = (3.0, 5.0, 7.0)
_PROBE_AZIMUTHS_DEG = (-20.0, 0.0, 20.0)


def _probe_boards(center: np.ndarray, board: BoardGeometry) -> np.ndarray:
    """A deterministic grid of untilted boards over the default board area."""
    Ts = []
    for d in _PROBE_DISTANCES_M:
        for a in _PROBE_AZIMUTHS_DEG:
            Ts.append(
                make_board_placements(
                    0,
                    1,
                    center,
                    distance_m=(d, d),
                    azimuth_spread_deg=0.0,
                    heading_deg=a,
                    elevation_spread_deg=0.0,
                    tilt_deg=0.0,
                    yaw_deg=0.0,
                    board=board,
                )[0]
            )
    return np.array(Ts)


def random_rig(
    rng: np.random.Generator | int,
    n_lidar: int = 1,
    n_camera: int = 1,
    n_radar: int = 1,
    n_radar3d: int = 0,
    *,
    min_probe_fraction: float = 0.7,
    max_tries: int = 500,
) -> tuple[SimSensor, ...]:
    """A rig of sensors in arbitrary orientations, within about 2 m of the rig origin.

    * lidars: any yaw, upright or upside down (roll 0 or 180 deg), +-5 deg roll / pitch on top;
    * cameras: optical axis within +-25 deg yaw / +-10 deg pitch of the rig's x axis, any roll
      about the optical axis (sideways, upside down, ...);
    * 3D radars: boresight within +-25 deg yaw / +-10 deg pitch, any roll about the boresight;
    * 2D radars: +-25 deg yaw, +-2 deg roll / pitch (their plane must stay near the boards),
      0.4 - 0.7 m high.

    Positions: x in [0, 1.2], y in [-0.8, 0.8], z in [0.3, 1.4] m (2D radars lower). Each
    orientation is redrawn until the sensor sees at least ``min_probe_fraction`` of a grid of
    boards over the default board area, so :func:`make_rig_placements` can serve every sensor.
    Names: ``lidar1``, ``camera1``, ``radar1``, ``radar3d1``, ...
    """
    gen = _as_rng(rng)
    counts = {
        SensorKind.RADAR: n_radar,
        SensorKind.LIDAR: n_lidar,
        SensorKind.CAMERA: n_camera,
        SensorKind.RADAR3D: n_radar3d,
    }
    for kind, n in counts.items():
        if int(n) < 0:
            raise InputError(f"random_rig: n_{kind.value} must be >= 0, got {n}")
    plan: list[tuple[str, SensorKind, np.ndarray]] = []
    for kind in (SensorKind.LIDAR, SensorKind.CAMERA, SensorKind.RADAR, SensorKind.RADAR3D):
        for i in range(int(counts[kind])):
            if kind is SensorKind.RADAR:
                x_lim, z_lim = (0.6, 1.2), (0.4, 0.7)
            else:
                x_lim, z_lim = (0.0, 1.2), (0.3, 1.4)
            xyz = np.array([gen.uniform(*x_lim), gen.uniform(-0.8, 0.8), gen.uniform(*z_lim)])
            plan.append((f"{kind.value}{i + 1}", kind, xyz))
    placeholders = tuple(SimSensor(n, k, from_rt(np.eye(3), p)) for n, k, p in plan)
    if not placeholders:
        raise InputError("random_rig: asked for no sensors")
    center = board_area_center(placeholders)
    probes = _probe_boards(center, BoardGeometry())
    out = []
    for name, kind, xyz in plan:
        for _ in range(max_tries):
            s = SimSensor(name, kind, from_rt(_random_rotation(gen, kind), xyz))
            if visible(s, probes).mean() >= min_probe_fraction:
                out.append(s)
                break
        else:
            raise InputError(
                f"random_rig: no orientation of '{name}' at {np.round(xyz, 2).tolist()} sees "
                f"{min_probe_fraction:.0%} of the board area after {max_tries} tries"
            )
    return tuple(out)


def _random_rotation(gen: np.random.Generator, kind: SensorKind) -> np.ndarray:
    u = lambda lim: math.radians(gen.uniform(-lim, lim))  # noqa: E731
    if kind is SensorKind.LIDAR:
        roll = (math.pi if gen.random() < 0.5 else 0.0) + u(5.0)
        return matrix_from_rpy(np.array([roll, u(5.0), u(180.0)]))
    if kind is SensorKind.RADAR:
        return matrix_from_rpy(np.array([u(2.0), u(2.0), u(25.0)]))
    aim = matrix_from_rpy(np.array([0.0, u(10.0), u(25.0)]))
    spin = u(180.0)
    if kind is SensorKind.CAMERA:
        return aim @ R_BODY_OPTICAL @ _rot_z(np.array(spin))
    return aim @ _rot_x(np.array(spin))


# --------------------------------------------------------------------------- outliers


def move_boards(
    dataset: Dataset, sensor: str, boards: Iterable[int], offset_m: Sequence[float] | np.ndarray
) -> Dataset:
    """A copy of ``dataset`` in which ``sensor``'s detections of ``boards`` are shifted.

    ``offset_m`` [m, sensor frame]: (3,) for lidar / camera (added to all four circle centres)
    and 3D radar, (2,) for a 2D radar (added to x, y). Undetected (NaN) boards stay undetected.
    """
    det = dataset.sensor(sensor)
    dim = det.kind.point_shape[-1]
    off = np.asarray(offset_m, dtype=float)
    if off.shape != (dim,) or not np.all(np.isfinite(off)):
        raise InputError(
            f"move_boards: sensor '{sensor}' ({det.kind.value}) needs a finite ({dim},) offset_m, "
            f"got shape {off.shape}"
        )
    idx = sorted({int(b) for b in boards})
    bad = [b for b in idx if not 0 <= b < det.num_boards]
    if bad:
        raise InputError(
            f"move_boards: sensor '{sensor}' has boards 0..{det.num_boards - 1}, got {bad}"
        )
    pts = np.array(det.points, dtype=float)
    pts[idx] = pts[idx] + off
    new = replace(det, points=pts)
    return replace(dataset, sensors=tuple(new if s.name == sensor else s for s in dataset.sensors))
