"""Spinning multi-beam lidar scans of a :class:`~rigcal.sim.raw.scene.Scene`.

Lidar frame: x forward, y left, z up. Laser ``i`` (ring ``i``, 0 = lowest beam) points at
elevation ``vertical_angles_deg[i]``; each revolution fires every laser at the azimuths
``azimuth_offset_deg + j * azimuth_step_deg`` (j = 0 .. n_azimuths-1, counter-clockwise from
+x, seen from above). Every ray is cast through the scene; rays that hit nothing or land outside
``[min_range_m, max_range_m]`` give no return and are dropped. Returns:

* ``points_xyz``: ``(range + noise) * direction`` in the lidar frame [m], range noise Gaussian
  with ``range_sigma_m``;
* ``ring`` (uint16, as Velodyne drivers publish it): the laser index;
* ``intensity`` (float32, 0..255): ``255 * reflectivity * |cos(incidence)|`` of the surface.

Points are ordered by azimuth, then by ring (as a Velodyne packet stream). The scan is
instantaneous (no motion during the revolution) and beams are infinitely thin (no mixed
pixels at hole edges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rigcal.errors import InputError
from rigcal.recording import PointCloudFrame
from rigcal.sim.raw.scene import (
    SURFACE_GROUND,
    SURFACE_PLATE,
    SURFACE_WALL,
    Scene,
    check_sim_call,
    trace_planes,
)


@dataclass(frozen=True)
class LidarModel:
    """A spinning lidar: ``vertical_angles_deg`` (one per laser, ascending: ring 0 lowest),
    azimuth step [deg], range noise sigma [m], range limits [m], and ``max_incidence_deg``
    (returns at a steeper incidence are lost)."""

    vertical_angles_deg: tuple[float, ...]
    azimuth_step_deg: float = 0.2
    range_sigma_m: float = 0.015
    min_range_m: float = 0.5
    max_range_m: float = 100.0
    azimuth_offset_deg: float = 0.0
    max_incidence_deg: float = 89.0
    name: str = "lidar"

    def __post_init__(self) -> None:
        ang = tuple(float(a) for a in self.vertical_angles_deg)
        if not ang or not all(math.isfinite(a) and -90.0 < a < 90.0 for a in ang):
            raise InputError(
                f"lidar '{self.name}': vertical_angles_deg must be finite angles in (-90, 90), "
                f"got {self.vertical_angles_deg!r}"
            )
        if any(b <= a for a, b in zip(ang, ang[1:])):
            raise InputError(
                f"lidar '{self.name}': vertical_angles_deg must be strictly ascending (ring 0 = "
                f"lowest beam), got {ang}"
            )
        object.__setattr__(self, "vertical_angles_deg", ang)
        if not (math.isfinite(self.azimuth_step_deg) and 0.0 < self.azimuth_step_deg <= 45.0):
            raise InputError(
                f"lidar '{self.name}': azimuth_step_deg must be in (0, 45], got "
                f"{self.azimuth_step_deg!r}"
            )
        if not (math.isfinite(self.range_sigma_m) and self.range_sigma_m >= 0):
            raise InputError(
                f"lidar '{self.name}': range_sigma_m must be >= 0, got {self.range_sigma_m!r}"
            )
        if not (0.0 <= self.min_range_m < self.max_range_m and math.isfinite(self.max_range_m)):
            raise InputError(
                f"lidar '{self.name}': need 0 <= min_range_m < max_range_m < inf, got "
                f"{self.min_range_m!r}, {self.max_range_m!r}"
            )
        if not (0.0 < self.max_incidence_deg <= 90.0):
            raise InputError(
                f"lidar '{self.name}': max_incidence_deg must be in (0, 90], got "
                f"{self.max_incidence_deg!r}"
            )
        for name in ("azimuth_step_deg", "range_sigma_m", "min_range_m", "max_range_m",
                     "azimuth_offset_deg", "max_incidence_deg"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def num_rings(self) -> int:
        return len(self.vertical_angles_deg)

    @property
    def num_azimuths(self) -> int:
        """Firings per revolution: round(360 / azimuth_step_deg)."""
        return int(round(360.0 / self.azimuth_step_deg))

    @property
    def num_rays(self) -> int:
        return self.num_rings * self.num_azimuths

    def ray_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions (num_rays, 3) in the lidar frame and their rings (num_rays,),
        azimuth-major (all rings of the first azimuth, then the next azimuth, ...)."""
        el = np.radians(np.asarray(self.vertical_angles_deg))
        steps = np.arange(self.num_azimuths)
        az = np.radians(self.azimuth_offset_deg + self.azimuth_step_deg * steps)
        ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
        d = np.stack(
            np.broadcast_arrays(ce * np.cos(az)[:, None], ce * np.sin(az)[:, None], se), axis=-1
        ).reshape(-1, 3)
        rings = np.broadcast_to(
            np.arange(self.num_rings, dtype=np.uint16), (self.num_azimuths, self.num_rings)
        )
        return d, rings.reshape(-1).copy()


@lru_cache(maxsize=8)
def _cached_rays(model: LidarModel) -> tuple[np.ndarray, np.ndarray]:
    dirs, rings = model.ray_directions()
    dirs.setflags(write=False)
    rings.setflags(write=False)
    return dirs, rings


def hdl64e(range_sigma_m: float = 0.015, max_range_m: float = 120.0) -> LidarModel:
    """Velodyne HDL-64E-like: 64 lasers, upper block of 32 from +2.0 to -8.33 deg (about 1/3
    deg apart), lower block of 32 from -8.83 to -24.9 deg (about 1/2 deg apart); 0.17 deg
    azimuth step (2118 firings per revolution, 135 552 rays)."""
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.9, 32)
    angles = np.sort(np.concatenate([upper, lower]))
    return LidarModel(
        vertical_angles_deg=tuple(float(a) for a in angles),
        azimuth_step_deg=0.17,
        range_sigma_m=range_sigma_m,
        min_range_m=0.9,
        max_range_m=max_range_m,
        name="hdl64e",
    )


def vlp16(range_sigma_m: float = 0.015, max_range_m: float = 100.0) -> LidarModel:
    """Velodyne VLP-16-like: 16 lasers from -15 to +15 deg, 2 deg apart; 0.2 deg azimuth step
    (1800 firings per revolution, 28 800 rays)."""
    return LidarModel(
        vertical_angles_deg=tuple(float(a) for a in np.arange(-15.0, 15.1, 2.0)),
        azimuth_step_deg=0.2,
        range_sigma_m=range_sigma_m,
        min_range_m=0.5,
        max_range_m=max_range_m,
        name="vlp16",
    )


def scan(
    model: LidarModel,
    T_world_lidar: np.ndarray,
    scene: Scene,
    rng: np.random.Generator,
    t_ns: int = 0,
    sensor: str = "lidar",
    *,
    frame_id: str = "",
) -> PointCloudFrame:
    """One revolution of ``model`` at ``T_world_lidar`` (lidar frame -> world) as a
    :class:`~rigcal.recording.PointCloudFrame` in the lidar frame with ``ring`` and
    ``intensity`` fields. Draws exactly ``model.num_rays`` normals from ``rng`` (whatever is
    hit), so a seed reproduces the scan."""
    T = check_sim_call(f"scan '{sensor}'", model, LidarModel, scene, rng, T_world_lidar, "T_world_lidar")
    dirs, rings = _cached_rays(model)
    noise = rng.standard_normal(dirs.shape[0])
    pts, intensity, keep = range_returns(model, T, scene, dirs, noise)
    return PointCloudFrame(
        sensor=sensor,
        t_ns=t_ns,
        points_xyz=pts,
        fields={"ring": rings[keep], "intensity": intensity},
        frame_id=frame_id or sensor,
    )


def range_returns(model, T_world_sensor, scene, dirs, noise):
    """Returns of unit rays ``dirs`` (N, 3) from a range scanner at ``T_world_sensor``.

    ``model`` gives ``min_range_m``, ``max_range_m``, ``range_sigma_m`` and
    ``max_incidence_deg``; ``noise`` (N,) standard-normal draws (drawn by the caller so a seed
    reproduces the scan). Returns (points (M, 3) in the sensor frame, intensity (M,) float32,
    keep (N,) mask of the rays that returned).
    """
    # cast in the sensor frame: move the scene's planes instead of every ray
    planes = scene.planes_in(np.linalg.inv(T_world_sensor))
    du = np.ascontiguousarray(dirs.T)
    tr = trace_planes(
        planes, scene.plate_bounds_board, scene.board, (0.0, 0.0, 0.0), du[0], du[1], du[2],
        max_t=model.max_range_m, need_uv=False,
    )
    cos_inc = np.abs(tr.ndotd)
    keep = (
        (tr.sid >= 0)
        & (tr.t >= model.min_range_m)
        & (cos_inc >= math.cos(math.radians(model.max_incidence_deg)))
    )
    rng_m = tr.t[keep] + model.range_sigma_m * noise[keep]
    pts = dirs[keep] * rng_m[:, None]
    refl = np.array(
        [scene.material(sid).reflectivity for sid in (SURFACE_PLATE, SURFACE_WALL, SURFACE_GROUND)]
    )
    intensity = (255.0 * refl[tr.sid[keep].astype(np.intp)] * cos_inc[keep]).astype(np.float32)
    return pts, intensity, keep
