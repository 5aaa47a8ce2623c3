"""Automotive radar detection lists of a :class:`~rigcal.sim.raw.scene.Scene`.

Radar frame: x forward (boresight), y left, z up; azimuth ``atan2(y, x)``, elevation
``atan2(z, hypot(x, y))`` (``docs/conventions.md``). The Styrofoam plate is transparent to the
radar; only the trihedral corner reflector (``Scene.reflector_world``) and random clutter are
reported.

Reflector: detected when its range is within ``[min_range_m, max_range_m]``, |azimuth| <=
``azimuth_fov_deg``, |elevation| <= ``elevation_fov_deg`` and the radar lies within
``max_incidence_deg`` of the board's front normal (a trihedral reflects back only over a
limited cone). The measurement is the true range, azimuth (and for a 3D radar elevation) plus
Gaussian noise; RCS ``reflector_rcs_dbsm`` plus Gaussian noise ``reflector_rcs_sigma_db``.

Clutter: ``clutter_count`` detections per frame, uniformly random in range
(``clutter_range_m``), azimuth (within the field of view), elevation (3D, within the field of
view) and RCS (``clutter_rcs_dbsm``, below the reflector's) - some of them closer than the board.

A 2D radar reports ``range * (cos az, sin az)`` (:class:`~rigcal.recording.RadarFrame` points
(N, 2)), a 3D radar ``range * (cos el cos az, cos el sin az, sin el)`` (N, 3). The reflector
takes a random place in the list. Every frame draws the same amount of random numbers whatever
is visible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.errors import InputError
from rigcal.recording import RadarFrame
from rigcal.geometry.se3 import as_rigid
from rigcal.sim.raw.scene import Scene, check_sim_call


def _interval(value, what: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what} must be a (low, high) pair, got {value!r}") from exc
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InputError(f"{what} must be finite with low <= high, got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class RadarModel:
    """A 2D (``dims=2``: range + azimuth) or 3D (``dims=3``: + elevation) radar.

    Angles in degrees; ``*_fov_deg`` are half-angles (|angle| <= fov). Sigmas are one standard
    deviation.
    """

    dims: int = 2
    range_sigma_m: float = 0.03
    azimuth_sigma_deg: float = 0.4
    elevation_sigma_deg: float = 0.5
    azimuth_fov_deg: float = 60.0
    elevation_fov_deg: float = 9.0
    min_range_m: float = 0.5
    max_range_m: float = 60.0
    reflector_rcs_dbsm: float = 15.0
    reflector_rcs_sigma_db: float = 1.0
    max_incidence_deg: float = 60.0
    clutter_count: int = 8
    clutter_rcs_dbsm: tuple[float, float] = (-10.0, 5.0)
    clutter_range_m: tuple[float, float] = (1.0, 30.0)
    name: str = "radar"

    def __post_init__(self) -> None:
        if self.dims not in (2, 3) or isinstance(self.dims, bool):
            raise InputError(f"radar '{self.name}': dims must be 2 or 3, got {self.dims!r}")
        sigmas = (
            "range_sigma_m", "azimuth_sigma_deg", "elevation_sigma_deg", "reflector_rcs_sigma_db"
        )
        for fname in sigmas:
            v = getattr(self, fname)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"radar '{self.name}': {fname} must be >= 0, got {v!r}")
            object.__setattr__(self, fname, float(v))
        limits = (
            ("azimuth_fov_deg", 180.0), ("elevation_fov_deg", 90.0), ("max_incidence_deg", 90.0)
        )
        for fname, hi in limits:
            v = getattr(self, fname)
            if not (math.isfinite(v) and 0 < v <= hi):
                raise InputError(f"radar '{self.name}': {fname} must be in (0, {hi}], got {v!r}")
            object.__setattr__(self, fname, float(v))
        if not (0.0 <= self.min_range_m < self.max_range_m and math.isfinite(self.max_range_m)):
            raise InputError(
                f"radar '{self.name}': need 0 <= min_range_m < max_range_m < inf, got "
                f"{self.min_range_m!r}, {self.max_range_m!r}"
            )
        if not math.isfinite(self.reflector_rcs_dbsm):
            raise InputError(f"radar '{self.name}': reflector_rcs_dbsm must be finite")
        if not (isinstance(self.clutter_count, (int, np.integer)) and self.clutter_count >= 0):
            raise InputError(
                f"radar '{self.name}': clutter_count must be an integer >= 0, got "
                f"{self.clutter_count!r}"
            )
        object.__setattr__(self, "clutter_count", int(self.clutter_count))
        rcs = _interval(self.clutter_rcs_dbsm, f"radar '{self.name}': clutter_rcs_dbsm")
        object.__setattr__(self, "clutter_rcs_dbsm", rcs)
        lo, hi = _interval(self.clutter_range_m, f"radar '{self.name}': clutter_range_m")
        if lo < 0:
            raise InputError(
                f"radar '{self.name}': clutter_range_m must be >= 0, got {self.clutter_range_m!r}"
            )
        object.__setattr__(self, "clutter_range_m", (lo, hi))
        for fname in ("min_range_m", "max_range_m", "reflector_rcs_dbsm"):
            object.__setattr__(self, fname, float(getattr(self, fname)))


def automotive_2d(**overrides) -> RadarModel:
    """A 2D automotive radar (ARS430-like): 3 cm / 0.4 deg noise, +-60 deg azimuth, +-9 deg
    elevation field of view, reflector at 15 dBsm, 8 clutter detections per frame."""
    return RadarModel(**{"dims": 2, "name": "automotive_2d", **overrides})


def automotive_3d(**overrides) -> RadarModel:
    """A 3D (imaging) radar: as :func:`automotive_2d` plus 0.5 deg elevation noise and a +-15
    deg elevation field of view."""
    return RadarModel(
        **{
            "dims": 3,
            "elevation_fov_deg": 15.0,
            "elevation_sigma_deg": 0.5,
            "name": "automotive_3d",
            **overrides,
        }
    )


def reflector_visible(model: RadarModel, T_world_radar: np.ndarray, scene: Scene) -> bool:
    """Whether ``model`` at ``T_world_radar`` detects the scene's reflector (geometry only)."""
    T = as_rigid(T_world_radar, "reflector_visible: T_world_radar")
    return _reflector_geometry(model, T, scene)[3]


def _reflector_geometry(
    model: RadarModel, T: np.ndarray, scene: Scene
) -> tuple[float, float, float, bool]:
    """(range, azimuth, elevation [rad], visible) of the reflector seen from the radar."""
    R, t = T[:3, :3], T[:3, 3]
    refl_world = scene.reflector_world()
    p = R.T @ (refl_world - t)
    r = float(np.linalg.norm(p))
    az = math.atan2(p[1], p[0])
    el = math.atan2(p[2], math.hypot(p[0], p[1]))
    to_radar = t - refl_world
    normal = scene.T_world_board[:3, 2]
    cos_inc = float(normal @ to_radar) / max(float(np.linalg.norm(to_radar)), 1e-12)
    ok = (
        model.min_range_m <= r <= model.max_range_m
        and abs(az) <= math.radians(model.azimuth_fov_deg)
        and abs(el) <= math.radians(model.elevation_fov_deg)
        and cos_inc >= math.cos(math.radians(model.max_incidence_deg))
    )
    return r, az, el, ok


def detections(
    model: RadarModel,
    T_world_radar: np.ndarray,
    scene: Scene,
    rng: np.random.Generator,
    t_ns: int = 0,
    sensor: str = "radar",
    *,
    frame_id: str = "",
) -> RadarFrame:
    """One frame of detections (reflector if visible, plus clutter) in the radar frame."""
    T = check_sim_call(
        f"detections '{sensor}'", model, RadarModel, scene, rng, T_world_radar, "T_world_radar"
    )
    r, az, el, visible = _reflector_geometry(model, T, scene)
    # fixed draw order and count: reflector noise (4), clutter (4 per detection), permutation
    n_refl = rng.standard_normal(4)
    n_c = model.clutter_count
    c_r = rng.uniform(*model.clutter_range_m, n_c)
    c_az = rng.uniform(-1.0, 1.0, n_c) * math.radians(model.azimuth_fov_deg)
    c_el = rng.uniform(-1.0, 1.0, n_c) * math.radians(model.elevation_fov_deg)
    c_rcs = rng.uniform(*model.clutter_rcs_dbsm, n_c)
    order = rng.permutation(n_c + 1)
    r_m = np.append(c_r, r + model.range_sigma_m * n_refl[0])
    az_m = np.append(c_az, az + math.radians(model.azimuth_sigma_deg) * n_refl[1])
    el_m = np.append(c_el, el + math.radians(model.elevation_sigma_deg) * n_refl[2])
    rcs = np.append(c_rcs, model.reflector_rcs_dbsm + model.reflector_rcs_sigma_db * n_refl[3])
    keep = order[order < n_c] if not visible else order
    r_m, az_m, el_m, rcs = r_m[keep], az_m[keep], el_m[keep], rcs[keep]
    if model.dims == 2:
        pts = np.stack([r_m * np.cos(az_m), r_m * np.sin(az_m)], axis=1)
    else:
        rho = r_m * np.cos(el_m)
        pts = np.stack([rho * np.cos(az_m), rho * np.sin(az_m), r_m * np.sin(el_m)], axis=1)
    return RadarFrame(
        sensor=sensor,
        t_ns=t_ns,
        points=pts.reshape(-1, model.dims),
        rcs_dbsm=rcs,
        frame_id=frame_id or sensor,
    )
