"""Synthetic lidar scenes for the extractor tests: a VLP-16-like ray caster over a diamond plate,
a cylinder, a ground plane and clutter boxes, with seeded range noise.

Exposed through the ``sim`` fixture (a namespace of functions) because the tests run with
``--import-mode=importlib``, where sibling modules are not importable.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rigcal.geometry.se3 import from_rt, invert, se3_exp, transform_points
from rigcal.geometry.so3 import so3_exp

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "vicon_sim"

# The diamond of the simulated checkerboard target: a 0.5 m square plate turned 45 degrees in
# the target frame's x-y plane, corners in order around it (CheckerboardTargetSim.json's
# keypoints_lidar; restated so the lidar tests run without ../shared).
DIAMOND_CORNERS = np.array(
    [
        [0.116, -0.25205339, 0.0],
        [0.46953339, 0.1015, 0.0],
        [0.116, 0.45505339, 0.0],
        [-0.23755339, 0.1015, 0.0],
    ]
)
# A cylinder: axis along the target z axis, radius 5.75 cm, from z = -0.4956 m to 0 (the body of
# cylinder_target_rotated.pcd without its end flanges).
CYL_RADIUS = 0.0575
CYL_Z = (-0.4956, 0.0)

VLP16_ELEVATIONS_DEG = np.arange(-15.0, 15.1, 2.0)


def vlp16_rays(azimuth_step_deg: float = 0.2) -> np.ndarray:
    """Unit ray directions (M, 3) of one VLP-16 revolution (x forward, y left, z up)."""
    az = np.radians(np.arange(-180.0, 180.0, azimuth_step_deg))
    el = np.radians(VLP16_ELEVATIONS_DEG)
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)
    return d.reshape(-1, 3)


def _to_local(T_sensor_obj: np.ndarray, dirs: np.ndarray):
    R, t = T_sensor_obj[:3, :3], T_sensor_obj[:3, 3]
    return -R.T @ t, dirs @ R  # origin (3,), directions (M, 3) in the object frame


def hit_polygon(T_sensor_obj, corners_obj, dirs):
    """Ranges (M,) of rays hitting a convex planar polygon (z = 0 in its frame), inf otherwise."""
    o, d = _to_local(T_sensor_obj, dirs)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
    p = o[None, :2] + t[:, None] * d[:, :2]
    c = np.asarray(corners_obj)[:, :2]
    e0, e1 = c[1] - c[0], c[2] - c[1]
    turn = np.sign(e0[0] * e1[1] - e0[1] * e1[0])  # +1 counter-clockwise corners
    inside = np.ones(len(d), dtype=bool)
    for k in range(len(c)):
        a, b = c[k], c[(k + 1) % len(c)]
        cross = (b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])
        inside &= cross * turn >= 0
    ok = inside & (t > 0) & np.isfinite(t)
    return np.where(ok, t, np.inf)


def hit_cylinder(T_sensor_obj, radius, z_range, dirs):
    """Ranges (M,) of rays hitting a capped cylinder (axis z in its frame)."""
    o, d = _to_local(T_sensor_obj, dirs)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2.0 * (o[0] * d[:, 0] + o[1] * d[:, 1])
    c = o[0] ** 2 + o[1] ** 2 - radius**2
    disc = b * b - 4 * a * c
    out = np.full(len(d), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        for t in ((-b - sq) / (2 * a), (-b + sq) / (2 * a)):
            z = o[2] + t * d[:, 2]
            ok = np.isfinite(t) & (t > 0) & (z >= z_range[0]) & (z <= z_range[1])
            out = np.where(ok & (t < out), t, out)
        for zc in z_range:
            t = (zc - o[2]) / d[:, 2]
            p = o[None, :2] + t[:, None] * d[:, :2]
            ok = np.isfinite(t) & (t > 0) & (np.sum(p * p, axis=1) <= radius**2)
            out = np.where(ok & (t < out), t, out)
    return out


def hit_ground(height_m, dirs):
    """Ranges (M,) of rays hitting the floor ``z = -height_m``."""
    with np.errstate(divide="ignore"):
        t = -height_m / dirs[:, 2]
    return np.where(dirs[:, 2] < -1e-9, t, np.inf)


def hit_box(lo, hi, dirs):
    """Ranges (M,) of rays hitting an axis-aligned box [lo, hi] in the sensor frame."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.asarray(lo)[None, :] / dirs
        t2 = np.asarray(hi)[None, :] / dirs
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    ok = (tmax >= tmin) & (tmax > 0)
    return np.where(ok, np.where(tmin > 0, tmin, tmax), np.inf)


def scan(ranges_list, dirs, rng, noise_m=0.005, max_range_m=100.0):
    """The nearest hit per ray plus Gaussian range noise: points (N, 3) and the index (M,) of
    the object each ray hit (-1: none)."""
    R = np.stack(ranges_list, axis=0)
    which = np.argmin(R, axis=0)
    r = R[which, np.arange(R.shape[1])]
    ok = np.isfinite(r) & (r < max_range_m)
    r_noisy = r[ok] + rng.normal(0.0, noise_m, size=int(np.sum(ok)))
    return dirs[ok] * r_noisy[:, None], np.where(ok, which, -1)[ok]


def facing_pose(position, yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0):
    """T_sensor_target of a target at ``position`` whose z axis points back at the sensor
    (target x -> sensor -y, y -> sensor z, z -> sensor -x), then turned by yaw (about the
    sensor z), pitch (about the target x) and roll (about the target z)."""
    base = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    R = (
        so3_exp(np.radians(yaw_deg) * np.array([0, 0, 1.0]))
        @ base
        @ so3_exp(np.radians(pitch_deg) * np.array([1.0, 0, 0]))
        @ so3_exp(np.radians(roll_deg) * np.array([0, 0, 1.0]))
    )
    return from_rt(R, np.asarray(position, dtype=float))


def upright_cylinder_pose(position, tilt_deg=0.0):
    """T_sensor_target of a cylinder whose axis (target z) points up (sensor z), top end at
    ``position``, tilted about the sensor x axis by ``tilt_deg``."""
    R = so3_exp(np.radians(tilt_deg) * np.array([1.0, 0, 0]))
    return from_rt(R, np.asarray(position, dtype=float))


def perturb_calibration(T_sensor_target, rng, max_t_m=0.03, max_rot_deg=5.0):
    """The expected pose an initial calibration off by up to +-max_t_m per axis and
    +-max_rot_deg per axis (uniform, as in the paper's experiments) predicts:
    ``exp(delta) @ T`` - the error acts in the sensor frame, about the sensor origin."""
    delta = np.concatenate(
        [np.radians(rng.uniform(-max_rot_deg, max_rot_deg, 3)), rng.uniform(-max_t_m, max_t_m, 3)]
    )
    return se3_exp(delta) @ T_sensor_target


def diamond_template(spacing_m=0.003):
    """Dense points (M, 3) covering the diamond plate (z = 0)."""
    c = DIAMOND_CORNERS
    lo, hi = c[:, :2].min(axis=0), c[:, :2].max(axis=0)
    xs, ys = np.arange(lo[0], hi[0], spacing_m), np.arange(lo[1], hi[1], spacing_m)
    g = np.stack(np.meshgrid(xs, ys), -1)
    g = g.reshape(-1, 2)
    centre = c[:, :2].mean(axis=0)
    # the diamond is a square turned 45 deg: |du| + |dv| <= half diagonal
    half = np.linalg.norm(c[0, :2] - centre)
    keep = np.abs(g[:, 0] - centre[0]) + np.abs(g[:, 1] - centre[1]) <= half
    g = g[keep]
    return np.concatenate([g, np.zeros((len(g), 1))], axis=1)


def cylinder_template(spacing_m=0.004):
    """Dense points (M, 3) on the cylinder's side and end caps."""
    n_around = int(math.ceil(2 * math.pi * CYL_RADIUS / spacing_m))
    ang = np.linspace(0, 2 * math.pi, n_around, endpoint=False)
    zs = np.arange(CYL_Z[0], CYL_Z[1] + 1e-9, spacing_m)
    A, Z = np.meshgrid(ang, zs)
    side = np.stack([CYL_RADIUS * np.cos(A), CYL_RADIUS * np.sin(A), Z], -1).reshape(-1, 3)
    g = np.arange(-CYL_RADIUS, CYL_RADIUS + 1e-9, spacing_m)
    X, Y = np.meshgrid(g, g)
    disc = np.stack([X.ravel(), Y.ravel()], 1)
    disc = disc[np.sum(disc**2, 1) <= CYL_RADIUS**2]
    caps = [np.concatenate([disc, np.full((len(disc), 1), z)], 1) for z in CYL_Z]
    return np.concatenate([side] + caps, axis=0)


def clutter(dirs):
    """Ranges of a few boxes away from the targets: a wall, a cabinet, a post."""
    return [
        hit_box([7.0, -6.0, -1.2], [7.3, 6.0, 2.0], dirs),
        hit_box([1.5, -3.5, -1.2], [2.3, -2.5, 0.6], dirs),
        hit_box([4.5, 2.0, -1.2], [4.7, 2.2, 1.5], dirs),
        hit_box([-3.0, -1.0, -1.2], [-2.0, 1.0, 0.5], dirs),
    ]


def pose_error(T_est, T_true):
    """(translation error [m], rotation error [deg]) of T_est against T_true."""
    dR = T_est[:3, :3].T @ T_true[:3, :3]
    ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1) / 2))))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), ang


@pytest.fixture(scope="session")
def sim():
    return SimpleNamespace(
        SHARED=SHARED,
        DIAMOND_CORNERS=DIAMOND_CORNERS,
        CYL_RADIUS=CYL_RADIUS,
        CYL_Z=CYL_Z,
        vlp16_rays=vlp16_rays,
        hit_polygon=hit_polygon,
        hit_cylinder=hit_cylinder,
        hit_ground=hit_ground,
        hit_box=hit_box,
        scan=scan,
        facing_pose=facing_pose,
        upright_cylinder_pose=upright_cylinder_pose,
        perturb_calibration=perturb_calibration,
        diamond_template=diamond_template,
        cylinder_template=cylinder_template,
        clutter=clutter,
        pose_error=pose_error,
        invert=invert,
        transform_points=transform_points,
    )
