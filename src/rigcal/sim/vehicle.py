"""A simulated vehicle with known truth for absolute calibration (the body frame).

Body frame (as :mod:`rigcal.absolute.body_frame` defines it): origin on the ground below the
centre of the rear axle, x forward, y left, z up; the ground is ``z = 0``. The vehicle:

* four wheels: closed cylinders of ``tyre_radius_m`` (0.32 m) and ``tyre_width_m`` about
  axes along y, centred at ``x = 0`` (rear) and ``x = wheelbase_m`` (2.7 m),
  ``y = +-track_m / 2`` (1.55 m), ``z = tyre_radius_m`` (the tyres touch the ground);
  each wheel's outer face carries a rim: a disc of ``rim_radius_m`` recessed by ``rim_inset_m``
  into the face. The **rim circle** (what a person labels) is the rim's edge on the recessed
  face; its centre (the **hub**) is at ``(x_axle, +-(track/2 + tyre_width/2 - rim_inset),
  tyre_radius)``;
* a body box between the wheels (narrower than the inner tyre faces, so the wheels stay
  visible), from ``body_bottom_m`` to ``body_top_m``;
* sensors at their true ``T_body_sensor`` (default :func:`rigcal.sim.rig.prius_like_rig`,
  whose rig frame is this body frame).

The external scanner (Leica-P40-like) is a static terrestrial scanner at one or more
stations around the car; each casts a dense grid of rays (``angle_step_deg``) with Gaussian
range noise (``range_sigma_m``, 2 mm) against the ground, the body and the wheels. Points of
every station are expressed in the **external frame** = the first station's frame (x along
its first azimuth, z up, a levelled scanner with a small residual tilt); the registration
between stations is exact.

Labels (:class:`~rigcal.absolute.labels.LabelSet`, external frame):

* rim labels: N points on each rim circle at jittered angles, isotropic noise (2 mm);
* hub labels: one point per wheel, the hub centre with isotropic noise (1 cm: a person
  clicking "the middle" of a wheel is less precise than clicking its edge);
* markers ``marker_<wheel>``: on the ground beside each wheel below its axle,
  ``marker_offset_m`` outside the tyre, placed with horizontal error ``placement_sigma_m``
  (1 cm) and detected by the scanner with ``detection_sigma_m`` (1 mm).

A straight drive (:func:`simulate_straight_drive`): the vehicle moves along the world x axis
on flat ground past vertical poles; a spinning lidar (:class:`SimLidar`) at the sensor's
**true** pose scans ground and poles. The **believed** pose differs by ``error_rpy_deg``:
``R_believed = R(error) @ R_true`` (rotation about the body axes, same translation), so a yaw
error of +0.5 deg means the believed calibration's yaw is 0.5 deg larger than the truth.

Every random draw comes from a seeded ``numpy.random.Generator`` (or an int seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np

from rigcal.absolute.labels import LabelSet, WHEEL_NAMES
from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.sim.rig import SimSensor, _as_rng, prius_like_rig

__all__ = [
    "ExternalScan",
    "ExternalScanner",
    "SURFACE_BODY",
    "SURFACE_GROUND",
    "SURFACE_POLE",
    "SURFACE_RIM",
    "SURFACE_TYRE",
    "SimLidar",
    "SimVehicle",
    "StraightDrive",
    "believed_pose",
    "default_poles",
    "default_stations",
    "simulate_external_scan",
    "simulate_hub_labels",
    "simulate_markers",
    "simulate_rim_labels",
    "simulate_straight_drive",
]

SURFACE_NONE = -1
SURFACE_GROUND = 0
SURFACE_BODY = 1
SURFACE_TYRE = 2
SURFACE_RIM = 3
SURFACE_POLE = 4

_SIDE = {"rear_left": 1.0, "rear_right": -1.0, "front_left": 1.0, "front_right": -1.0}
_EPS = 1e-9


def _positive(v: float, what: str) -> float:
    x = float(v)
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{what} must be a positive number, got {v!r}")
    return x


@dataclass(frozen=True, eq=False)
class SimVehicle:
    """A car: wheels, rims, a body box and its sensors (truth). Lengths in metres."""

    wheelbase_m: float = 2.7
    track_m: float = 1.55
    tyre_radius_m: float = 0.32
    tyre_width_m: float = 0.2
    rim_radius_m: float = 0.2
    rim_inset_m: float = 0.03
    body_rear_x_m: float = -0.9
    body_length_m: float = 4.5
    body_width_m: float = 1.3
    body_bottom_m: float = 0.22
    body_top_m: float = 1.45
    sensors: tuple[SimSensor, ...] = field(default_factory=prius_like_rig)

    def __post_init__(self) -> None:
        for name in (
            "wheelbase_m", "track_m", "tyre_radius_m", "tyre_width_m", "rim_radius_m",
            "rim_inset_m", "body_length_m", "body_width_m", "body_top_m",
        ):
            _positive(getattr(self, name), f"SimVehicle.{name}")
        if not self.rim_radius_m < self.tyre_radius_m:
            raise InputError(
                f"SimVehicle.rim_radius_m ({self.rim_radius_m}) must be below tyre_radius_m "
                f"({self.tyre_radius_m})"
            )
        if not self.body_width_m / 2 < self.track_m / 2 - self.tyre_width_m / 2:
            raise InputError(
                "SimVehicle.body_width_m must leave the wheels outside the body: "
                f"{self.body_width_m} >= track_m - tyre_width_m = "
                f"{self.track_m - self.tyre_width_m}"
            )
        object.__setattr__(self, "sensors", tuple(self.sensors))

    def wheel_centres_body(self) -> dict[str, np.ndarray]:
        """Centres of the wheels' mid-planes, (3,) each, keyed by wheel name."""
        half = self.track_m / 2
        return {w: np.array([self._x(w), _SIDE[w] * half, self.tyre_radius_m]) for w in WHEEL_NAMES}

    def hub_centres_body(self) -> dict[str, np.ndarray]:
        """Centres of the rim circles (on the recessed rim faces), (3,) each: what labels find."""
        off = self.track_m / 2 + self.tyre_width_m / 2 - self.rim_inset_m
        return {w: np.array([self._x(w), _SIDE[w] * off, self.tyre_radius_m]) for w in WHEEL_NAMES}

    def T_body_sensor(self, name: str) -> np.ndarray:
        """True (4, 4) pose of sensor ``name`` in the body frame."""
        for s in self.sensors:
            if s.name == name:
                return np.array(s.T_rig_sensor)
        names = [s.name for s in self.sensors]
        raise InputError(f"unknown sensor '{name}' (vehicle sensors: {names})")

    def _x(self, wheel: str) -> float:
        return 0.0 if wheel.startswith("rear") else self.wheelbase_m


# ----------------------------------------------------------------------------- ray casting


class _Hits:
    """Nearest hit per ray: distance ``t`` (inf: none) and surface id."""

    def __init__(self, n: int) -> None:
        self.t = np.full(n, np.inf)
        self.surface = np.full(n, SURFACE_NONE, dtype=np.int16)

    def add(self, t: np.ndarray, valid: np.ndarray, surface: int) -> None:
        better = valid & (t > _EPS) & (t < self.t)
        self.t[better] = t[better]
        self.surface[better] = surface


def _plane_hit(o, d, axis, value):
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (value - o[axis]) / d[:, axis]
    t = np.where(np.isfinite(t), t, np.inf)
    return t, o + t[:, None] * d


def _cylinder_hits(o, d, centre, axis, radius, lo, hi):
    """Both intersections (t1, valid1), (t2, valid2) of rays with a finite cylinder surface."""
    i, j = [k for k in range(3) if k != axis]
    ox, oy = o[i] - centre[i], o[j] - centre[j]
    dx, dy = d[:, i], d[:, j]
    A = dx * dx + dy * dy
    B = 2 * (ox * dx + oy * dy)
    C = ox * ox + oy * oy - radius * radius
    disc = B * B - 4 * A * C
    ok = (disc >= 0) & (A > 1e-15)
    sq = np.sqrt(np.where(ok, disc, 0.0))
    A2 = np.where(ok, 2 * A, 1.0)
    out = []
    for t in ((-B - sq) / A2, (-B + sq) / A2):
        along = o[axis] + t * d[:, axis]
        out.append((t, ok & (along >= lo) & (along <= hi)))
    return out


def _box_hit(o, d, lo, hi):
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    tn = np.nanmax(np.minimum(t1, t2), axis=1)
    tf = np.nanmin(np.maximum(t1, t2), axis=1)
    return tn, (tn <= tf) & (tn > 0)


def _cast_vehicle(
    vehicle: SimVehicle, o: np.ndarray, d: np.ndarray, ground: bool, max_range: float
) -> _Hits:
    """Cast rays from ``o`` (3,) along unit ``d`` (R, 3), body frame."""
    hits = _Hits(d.shape[0])
    if ground:
        t, _ = _plane_hit(o, d, 2, 0.0)
        hits.add(t, t <= max_range, SURFACE_GROUND)
    v = vehicle
    lo = np.array([v.body_rear_x_m, -v.body_width_m / 2, v.body_bottom_m])
    hi = np.array([v.body_rear_x_m + v.body_length_m, v.body_width_m / 2, v.body_top_m])
    t, ok = _box_hit(o, d, lo, hi)
    hits.add(t, ok, SURFACE_BODY)
    R, r = v.tyre_radius_m, v.rim_radius_m
    for w, c in v.wheel_centres_body().items():
        s = _SIDE[w]
        y_out = c[1] + s * v.tyre_width_m / 2
        y_in = c[1] - s * v.tyre_width_m / 2
        y_rim = y_out - s * v.rim_inset_m
        for t, ok in _cylinder_hits(o, d, c, 1, R, min(y_in, y_out), max(y_in, y_out)):
            hits.add(t, ok, SURFACE_TYRE)
        faces = (
            (y_out, r, R, SURFACE_TYRE),  # outer sidewall around the rim
            (y_in, 0.0, R, SURFACE_TYRE),  # inner sidewall
            (y_rim, 0.0, r, SURFACE_RIM),  # recessed rim face
        )
        for y, rmin, rmax, surf in faces:
            t, p = _plane_hit(o, d, 1, y)
            rho = np.hypot(p[:, 0] - c[0], p[:, 2] - c[2])
            hits.add(t, (rho >= rmin) & (rho <= rmax), surf)
        for t, ok in _cylinder_hits(o, d, c, 1, r, min(y_rim, y_out), max(y_rim, y_out)):
            hits.add(t, ok, SURFACE_RIM)
    return hits


def _grid_directions(az_deg: np.ndarray, el_deg: np.ndarray) -> np.ndarray:
    az, el = np.meshgrid(np.radians(az_deg), np.radians(el_deg), indexing="ij")
    return np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
    ).reshape(-1, 3)


# ----------------------------------------------------------------------------- external scan


def _station(xyz, yaw_deg, tilt_deg=(0.0, 0.0)) -> np.ndarray:
    R = matrix_from_rpy(np.radians([tilt_deg[0], tilt_deg[1], yaw_deg]))
    return from_rt(R, np.asarray(xyz, float))


def default_stations() -> tuple[np.ndarray, ...]:
    """Two stations ``T_body_station``: 4.5 m right and 4.2 m left of the car, 1.5 m high,
    looking at it; the first (the external frame) is rotated 80 deg and tilted by a few
    hundredths of a degree (a levelled scanner's residual tilt)."""
    return (
        _station((1.6, -4.5, 1.5), 80.0, (0.03, -0.02)),
        _station((1.1, 4.2, 1.45), -95.0, (-0.01, 0.02)),
    )


@dataclass(frozen=True, eq=False)
class ExternalScanner:
    """A static terrestrial laser scanner (Leica-P40-like) at one or more stations.

    ``T_body_stations``: station poses in the body frame (x: the middle of the azimuth window,
    z up); the rays of a station cover azimuths within ``azimuth_half_width_deg`` of its x axis
    and elevations in ``elevation_limits_deg``, every ``angle_step_deg``.
    """

    T_body_stations: tuple[np.ndarray, ...] = field(default_factory=default_stations)
    range_sigma_m: float = 0.002
    angle_step_deg: float = 0.3
    azimuth_half_width_deg: float = 75.0
    elevation_limits_deg: tuple[float, float] = (-65.0, 25.0)
    max_range_m: float = 20.0

    def __post_init__(self) -> None:
        stations = tuple(np.array(T, dtype=float) for T in self.T_body_stations)
        if not stations or any(T.shape != (4, 4) for T in stations):
            raise InputError("ExternalScanner.T_body_stations: expected one or more (4, 4) poses")
        object.__setattr__(self, "T_body_stations", stations)
        _positive(self.angle_step_deg, "ExternalScanner.angle_step_deg")
        if not self.range_sigma_m >= 0:
            raise InputError(
                f"ExternalScanner.range_sigma_m must be >= 0, got {self.range_sigma_m!r}"
            )


class ExternalScan(NamedTuple):
    """An external scan: ``points_external`` (N, 3) [m] in the external frame, ``surface``
    (N,) ids (SURFACE_GROUND, _BODY, _TYRE, _RIM), ``station`` (N,) index, and the truth
    ``T_external_body`` (4, 4)."""

    points_external: np.ndarray
    surface: np.ndarray
    station: np.ndarray
    T_external_body: np.ndarray


def simulate_external_scan(
    vehicle: SimVehicle = SimVehicle(),
    scanner: ExternalScanner = ExternalScanner(),
    rng: np.random.Generator | int = 0,
    *,
    ground: bool = True,
) -> ExternalScan:
    """Scan the parked vehicle from every station; ``ground=False`` removes the floor (a scan
    with no ground)."""
    gen = _as_rng(rng)
    T_external_body = invert(scanner.T_body_stations[0])
    step = scanner.angle_step_deg
    hw = scanner.azimuth_half_width_deg
    el0, el1 = scanner.elevation_limits_deg
    d_station = _grid_directions(np.arange(-hw, hw + 1e-9, step), np.arange(el0, el1 + 1e-9, step))
    pts, surf, sta = [], [], []
    for k, T in enumerate(scanner.T_body_stations):
        o = T[:3, 3]
        d = d_station @ T[:3, :3].T
        hits = _cast_vehicle(vehicle, o, d, ground, scanner.max_range_m)
        keep = np.isfinite(hits.t) & (hits.t <= scanner.max_range_m)
        t = hits.t[keep] + scanner.range_sigma_m * gen.standard_normal(int(keep.sum()))
        p_body = o + t[:, None] * d[keep]
        pts.append(p_body @ T_external_body[:3, :3].T + T_external_body[:3, 3])
        surf.append(hits.surface[keep])
        sta.append(np.full(int(keep.sum()), k, dtype=np.int16))
    return ExternalScan(
        np.concatenate(pts), np.concatenate(surf), np.concatenate(sta), T_external_body
    )


# ----------------------------------------------------------------------------- labels


def _to_external(T_external_body: np.ndarray, p_body: np.ndarray) -> np.ndarray:
    T = np.asarray(T_external_body, dtype=float)
    return np.asarray(p_body, float) @ T[:3, :3].T + T[:3, 3]


def simulate_rim_labels(
    vehicle: SimVehicle,
    T_external_body: np.ndarray,
    rng: np.random.Generator | int = 0,
    *,
    n_points: int = 10,
    sigma_m: float = 0.002,
    wheels: Sequence[str] = WHEEL_NAMES,
) -> LabelSet:
    """``n_points`` clicks on each rim circle (angles spread around it with 10 deg jitter),
    isotropic noise ``sigma_m``, in the external frame."""
    gen = _as_rng(rng)
    pts = {}
    for w in wheels:
        c = vehicle.hub_centres_body()[w]
        ang = gen.uniform(0, 2 * math.pi) + np.arange(n_points) * 2 * math.pi / max(n_points, 1)
        ang = ang + np.radians(10.0) * gen.standard_normal(n_points)
        circle = np.column_stack([np.cos(ang), np.zeros(n_points), np.sin(ang)])
        p = c + vehicle.rim_radius_m * circle
        p = p + sigma_m * gen.standard_normal(p.shape)
        pts[w] = _to_external(T_external_body, p)
    return LabelSet(pts, "simulated rim labels")


def simulate_hub_labels(
    vehicle: SimVehicle,
    T_external_body: np.ndarray,
    rng: np.random.Generator | int = 0,
    *,
    sigma_m: float = 0.01,
    wheels: Sequence[str] = WHEEL_NAMES,
) -> LabelSet:
    """One click per wheel on the hub (the rim circle's centre), isotropic noise ``sigma_m``."""
    gen = _as_rng(rng)
    pts = {}
    for w in wheels:
        p = vehicle.hub_centres_body()[w] + sigma_m * gen.standard_normal(3)
        pts[w] = _to_external(T_external_body, p[None, :])
    return LabelSet(pts, "simulated hub labels")


def simulate_markers(
    vehicle: SimVehicle,
    T_external_body: np.ndarray,
    rng: np.random.Generator | int = 0,
    *,
    placement_sigma_m: float = 0.01,
    detection_sigma_m: float = 0.001,
    marker_offset_m: float = 0.3,
) -> LabelSet:
    """Markers ``marker_<wheel>`` on the ground below each axle, ``marker_offset_m`` outside
    each tyre; horizontal placement error ``placement_sigma_m``, 3D detection noise
    ``detection_sigma_m``."""
    gen = _as_rng(rng)
    pts = {}
    lateral = vehicle.track_m / 2 + vehicle.tyre_width_m / 2 + marker_offset_m
    for w in WHEEL_NAMES:
        p = np.array([vehicle._x(w), _SIDE[w] * lateral, 0.0])
        p[:2] += placement_sigma_m * gen.standard_normal(2)
        p = p + detection_sigma_m * gen.standard_normal(3)
        pts[f"marker_{w}"] = _to_external(T_external_body, p[None, :])
    return LabelSet(pts, "simulated markers")


# ----------------------------------------------------------------------------- straight drive


@dataclass(frozen=True)
class SimLidar:
    """A spinning lidar: lasers at ``elevations_deg``, azimuth step, range noise, range limits."""

    elevations_deg: tuple[float, ...] = tuple(float(a) for a in np.linspace(-24.8, 2.0, 32))
    azimuth_step_deg: float = 0.25
    range_sigma_m: float = 0.01
    min_range_m: float = 1.0
    max_range_m: float = 60.0


def default_poles() -> np.ndarray:
    """(P, 3) street-light poles ``(x, y, radius)`` [m] in the world frame: six poles along the
    right side of the road, 8 m apart from x = 10 m, 4-6 m to the right, 0.1 m radius."""
    x = 10.0 + 8.0 * np.arange(6)
    y = -np.array([4.0, 5.5, 4.5, 6.0, 5.0, 4.2])
    return np.column_stack([x, y, np.full(6, 0.1)])


class StraightDrive(NamedTuple):
    """A straight drive: ``scans_sensor`` (K,) point clouds (N_k, 3) in the lidar frame,
    ``T_world_body`` (K, 4, 4) vehicle poses, ``T_body_sensor_true`` and
    ``T_body_sensor_believed`` (4, 4), ``poles_world`` (P, 3) = (x, y, radius)."""

    scans_sensor: tuple[np.ndarray, ...]
    T_world_body: np.ndarray
    T_body_sensor_true: np.ndarray
    T_body_sensor_believed: np.ndarray
    poles_world: np.ndarray


def believed_pose(T_body_sensor_true: np.ndarray, error_rpy_deg: Sequence[float]) -> np.ndarray:
    """``T_body_sensor`` with its rotation ``R(error_rpy_deg) @ R_true`` (same translation)."""
    T = np.array(T_body_sensor_true, dtype=float)
    E = matrix_from_rpy(np.radians(np.asarray(error_rpy_deg, dtype=float)))
    return from_rt(E @ T[:3, :3], T[:3, 3])


def simulate_straight_drive(
    vehicle: SimVehicle = SimVehicle(),
    sensor: str = "lidar1",
    *,
    error_rpy_deg: Sequence[float] = (0.0, 0.0, 0.5),
    poles: np.ndarray | None = None,
    pole_height_m: float = 6.0,
    start_x_m: float = 0.0,
    step_m: float = 1.25,
    n_scans: int = 40,
    lidar: SimLidar = SimLidar(),
    lateral_sigma_m: float = 0.0,
    rng: np.random.Generator | int = 0,
) -> StraightDrive:
    """The vehicle drives along the world x axis (body x = world x, flat ground ``z = 0``),
    ``step_m`` per scan from ``start_x_m``; its lateral position wanders with
    ``lateral_sigma_m`` (0: a perfect line). At each stop the lidar at its **true** pose scans
    the ground and the poles (vertical cylinders of ``pole_height_m``)."""
    gen = _as_rng(rng)
    P = default_poles() if poles is None else np.asarray(poles, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"poles: expected (P, 3) rows (x, y, radius), got shape {P.shape}")
    T_bs = vehicle.T_body_sensor(sensor)
    T_believed = believed_pose(T_bs, error_rpy_deg)
    d_sensor = _grid_directions(
        np.arange(-180.0, 180.0, lidar.azimuth_step_deg), np.asarray(lidar.elevations_deg, float)
    )
    scans, poses = [], []
    for k in range(int(n_scans)):
        y = lateral_sigma_m * gen.standard_normal() if lateral_sigma_m > 0 else 0.0
        T_wb = from_rt(np.eye(3), np.array([start_x_m + k * step_m, y, 0.0]))
        T_ws = T_wb @ T_bs
        o = T_ws[:3, 3]
        d = d_sensor @ T_ws[:3, :3].T
        hits = _Hits(d.shape[0])
        t, _ = _plane_hit(o, d, 2, 0.0)
        hits.add(t, np.ones_like(t, dtype=bool), SURFACE_GROUND)
        near = np.hypot(P[:, 0] - o[0], P[:, 1] - o[1]) < lidar.max_range_m + 1.0
        for px, py, pr in P[near]:
            for t, ok in _cylinder_hits(o, d, np.array([px, py, 0.0]), 2, pr, 0.0, pole_height_m):
                hits.add(t, ok, SURFACE_POLE)
        keep = np.isfinite(hits.t) & (hits.t >= lidar.min_range_m) & (hits.t <= lidar.max_range_m)
        r = hits.t[keep] + lidar.range_sigma_m * gen.standard_normal(int(keep.sum()))
        scans.append(r[:, None] * d_sensor[keep])
        poses.append(T_wb)
    return StraightDrive(tuple(scans), np.stack(poses), T_bs, T_believed, P)
