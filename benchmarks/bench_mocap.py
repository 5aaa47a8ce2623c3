"""Time the motion-capture calibration solve (calibrate_mocap) on simulated VLP-16 captures.

Simulates 30 captures of the diamond and of the cylinder (rigcal.sim.mocap, exact ranges),
extracts them once with the mocap-guided extractors from an initial calibration 3 cm / 5 deg
off, then prints the median milliseconds of calibrate_mocap for: the diamond's corners (known
correspondences), the diamond's points and the cylinder's points with the paper's
centroid-aligned matching and with the surface distance (the default; the cylinder then by
each point's range along its ray).

Usage: python benchmarks/bench_mocap.py [--runs N] [--measurements N]
"""

from __future__ import annotations

import argparse
import platform

import numpy as np
import scipy

from rigcal.dataset import SensorKind
from rigcal.problem.mocap import MocapOptions, MocapSensor, TargetObservation, calibrate_mocap
from rigcal.sim.mocap import LIDAR, paper_rig, paper_targets, simulate_mocap
from rigcal.study.mocap_study import extract_observation, perturb_calibration
from rigcal.targets.surface import TargetSurface
from timing import median_ms


def _observations(target, mode: str, n: int, T_init, seed: int) -> list[TargetObservation]:
    rig = paper_rig()
    sim = simulate_mocap(rig, target, 2 * n + 5, np.random.default_rng(seed), sensors=(LIDAR,))
    out = []
    for c in sim.captures:
        o = extract_observation(c, sim, LIDAR, T_init, lidar_measurement=mode)
        if isinstance(o, TargetObservation):
            out.append(o)
        if len(out) == n:
            break
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--measurements", type=int, default=30)
    args = ap.parse_args()
    rig, targets = paper_rig(), paper_targets()
    T_true = rig.T_robot_sensor(LIDAR)
    T_init = perturb_calibration(T_true, np.random.default_rng(1))
    name = rig.name_of(LIDAR)
    cases = [
        ("diamond, 4 corners", targets.diamond, "keypoints", "surface", 0.003),
        ("diamond, points, centroid-aligned (paper)", targets.diamond, "points", "centroid", 0.0005),
        ("diamond, points, surface distance (default)", targets.diamond, "points", "surface", 0.0005),
        ("cylinder, points, centroid-aligned (paper)", targets.cylinder, "points", "centroid", 0.0005),
        ("cylinder, points, surface then range along the ray (default)", targets.cylinder, "points", "surface", 0.0005),
    ]
    print(f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"numpy {np.__version__}, scipy {scipy.__version__}; {args.measurements} measurements, "
          f"median of {args.runs} runs")
    print(f"{'case':<48} {'points':>7} {'solve [ms]':>11} {'error [mm]':>11}")
    for label, target, mode, corr, sigma in cases:
        obs = _observations(target, mode, args.measurements, T_init, seed=3)
        sensor = MocapSensor(name, SensorKind.LIDAR, sigma=sigma)
        templates = {} if mode == "keypoints" else {target.name: TargetSurface.of(target)}
        options = MocapOptions(correspondences=corr)

        def run():
            return calibrate_mocap([sensor], obs, {name: T_init}, templates, options)

        ms = median_ms(run, args.runs)
        T = run().sensors[name].T_reference_sensor
        err = float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])) * 1e3
        print(f"{label:<48} {sum(len(o.measured) for o in obs):>7} {ms:>11.1f} {err:>11.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
