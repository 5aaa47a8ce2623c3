"""A scanning lidar on a flat plate or a thin cylinder: range along the ray (and, on the plate,
ring ends) against the point's distance to the surface.

Lidar-only motion-capture sessions: the paper rig's VLP-16 (rigcal.sim.mocap.paper_rig) sees a
checkerboard diamond held still ``--holds`` times at 1.6-3 m, ``--frames`` revolutions per hold,
each ray-cast (a random firing phase per revolution) with ``--range-noise`` of range noise
along the ray, told 10 mm; an exact MCS; the calibration starts 2 cm / 2 deg off. Each session
is calibrated twice from the same observations: with the rays between which each ring leaves
the plate (``edge_rays``: every point's range along its ray, the plate's outline from the ring
ends) and without them (every point's distance to the plate's surface). Prints, per variant,
the median error and reported std (root sum of squares of the translation stds), the median
NEES per degree of freedom (0.89 when the covariance is right) and the fraction of truths inside
the reported 95 % region.

``--target cylinder``: the paper's cylinder (a 56.4 mm tube, 495 mm long; no ring ends) instead
of the diamond, calibrated with every point's range along its ray to the tube
(``MocapOptions.curved_ranges``, the default) and with its distance to the surface.

Usage: python benchmarks/mocap_lidar_plate.py [--sessions N] [--seed S] [--holds H] [--frames F]
       [--range-noise M] [--target diamond|cylinder]
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from rigcal.dataset import SensorKind
from rigcal.errors import RigcalError
from rigcal.extract.lidar import ring_edge_rays
from rigcal.geometry.se3 import from_rt, invert, se3_exp, se3_log
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.problem.mocap import MocapOptions, MocapSensor, TargetObservation, calibrate_mocap_fit
from rigcal.sim.mocap import (CYLINDER_HEIGHT_M, CYLINDER_RADIUS_M, LIDAR, SURFACE_TARGET, Placement, cast_lidar,
                              paper_rig, sample_target_pose)
from rigcal.sim.raw.lidar import vlp16
from rigcal.targets.surface import TargetSurface
from rigcal.targets.templates import cylinder_target, diamond_target

CHI2_95_6 = 12.591587243743977


def session(seed: int, holds: int, frames: int, range_noise_m: float, kind: str = "diamond"):
    """(observations with ring ends on the diamond, the truth, the initial calibration, the
    target)."""
    rng = np.random.default_rng([seed, 1])
    rig = paper_rig(lidar=vlp16(range_sigma_m=range_noise_m))
    if kind == "cylinder":
        target = cylinder_target(CYLINDER_RADIUS_M, CYLINDER_HEIGHT_M, name="cylinder")
    else:
        target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    placement = Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0)
    T_rl = rig.T_robot_lidar
    obs = []
    for h in range(holds):
        yaw = rng.uniform(-math.pi, math.pi)
        T_mr = from_rt(matrix_from_rpy(np.array([0.0, 0.0, yaw])), [*rng.uniform(-2, 2, 2), 0.0])
        T_mt = sample_target_pose(rig, LIDAR, target, T_mr, rng, placement)
        for k in range(frames):
            cloud = cast_lidar(rig.lidar, T_mr @ T_rl, target, T_mt, (), rng, range_sigma_m=range_noise_m)
            pts = cloud.points_xyz[cloud.fields["surface"] == SURFACE_TARGET]
            rays = None if kind == "cylinder" else ring_edge_rays(pts, math.radians(2.0),
                                                                  math.radians(rig.lidar.azimuth_step_deg))
            obs.append(TargetObservation("lidar", target.name, int((h * 10 + k) * 2.5e8), invert(T_mr) @ T_mt, pts,
                                         hold=str(h), edge_rays=rays))
    d = rng.normal(size=6)
    d[:3] *= math.radians(2.0) / np.linalg.norm(d[:3])
    d[3:] *= 0.02 / np.linalg.norm(d[3:])
    return obs, T_rl, T_rl @ se3_exp(d), target


def judge(obs, T_true, T_init, target, options=MocapOptions()):
    fit = calibrate_mocap_fit([MocapSensor("lidar", SensorKind.LIDAR, sigma=0.01)], obs, {"lidar": T_init},
                              {target.name: TargetSurface.of(target)}, options)
    est = fit.result.sensors["lidar"]
    e = se3_log(invert(est.T_reference_sensor) @ T_true)
    nees = float(e @ np.linalg.solve(est.covariance, e))
    return float(np.linalg.norm(e[3:])), float(np.sqrt(np.trace(est.covariance[3:, 3:]))), nees


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sessions", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--holds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--range-noise", type=float, default=0.015)
    ap.add_argument("--target", choices=("diamond", "cylinder"), default="diamond")
    args = ap.parse_args(argv)
    print(f"{platform.machine()}, Python {platform.python_version()}; {args.sessions} lidar-only sessions "
          f"({args.target}), {args.holds} holds x {args.frames} revolutions, {1000 * args.range_noise:g} mm "
          f"range noise, seed {args.seed}")
    first = "ring ends" if args.target == "diamond" else "range along ray"
    rows = {first: [], "surface distance": []}
    failed = {k: [] for k in rows}
    t0 = time.perf_counter()
    with threadpool_limits(limits=1):
        for k in range(args.sessions):
            obs, T_true, T_init, target = session(args.seed * 100_000 + k, args.holds, args.frames,
                                                  args.range_noise, args.target)
            plain = [TargetObservation(o.sensor, o.target, o.t_ns, o.T_robot_target, o.measured, hold=o.hold)
                     for o in obs]
            for name, these, options in ((first, obs, MocapOptions()),
                                         ("surface distance", plain, MocapOptions(curved_ranges=False))):
                try:
                    rows[name].append(judge(these, T_true, T_init, target, options))
                except RigcalError as exc:
                    failed[name].append(f"session {k}: {exc}")
    for name, r in rows.items():
        a = np.array(r).reshape(-1, 3)
        print(f"  {name:17} error {1000 * np.median(a[:, 0]):.2f} mm (max {1000 * a[:, 0].max():.2f}), "
              f"std {1000 * np.median(a[:, 1]):.2f} mm, NEES/dof {np.median(a[:, 2]) / 6:.2f}, "
              f"inside {np.mean(a[:, 2] <= CHI2_95_6):.3f} of {len(a)}; {len(failed[name])} failed")
        for why in failed[name]:
            print(f"    {why}")
    print(f"  {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
