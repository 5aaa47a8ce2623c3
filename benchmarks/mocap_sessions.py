"""The rendered motion-capture sessions end to end: error, reported std and NEES per sensor.

For each seed, ``rigcal.sim.mocap_scene.write_mocap_scene(dir, seed=S, holds=N)`` writes a
session (rendered images, a ray-cast VLP-16 with 15 mm of range noise, an exact MCS by default)
and ``rigcal.mocap.pipeline.run_mocap`` calibrates it from the scene's default initial
calibration. Prints, per sensor, the final error (mm / deg), the reported std (root sum of
squares over the axes), the NEES of the 6-DOF error under the reported covariance and whether
the truth lies inside the 95 % region (NEES <= 12.59), then the fraction inside and the median
NEES per degree of freedom per sensor kind (0.89 when the covariance is right).

For a camera, ``shared`` compares the error with its parts: the estimate's error, linearised
at the truth, is a sum over the holds (each hold's corner errors through the least-squares
gain); ``shared`` is that sum's NEES over the sum of the parts' NEES (both under the reported
covariance). About 1 when the holds' errors are independent, as the noise model takes them;
above 1 when the holds share an error (a detector bias every view has).

Usage: python benchmarks/mocap_sessions.py [--seeds 1-8] [--holds 4]
"""

from __future__ import annotations

import argparse
import math
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.mocap.config import load_mocap_config
from rigcal.mocap.pipeline import run_mocap
from rigcal.geometry.se3 import invert, se3_exp
from rigcal.problem.compare import pose_error
from rigcal.sim.mocap_scene import write_mocap_scene
from rigcal.study.coverage import CHI2_95_6, nees


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def _rss(std: dict, keys) -> float:
    return math.sqrt(sum(std[k] ** 2 for k in keys))


def _pixels(camera, T_robot_camera: np.ndarray, obs) -> np.ndarray:
    T = invert(T_robot_camera) @ obs.T_robot_target
    return camera.project(obs.keypoints_target @ T[:3, :3].T + T[:3, 3])[0].ravel()


def shared_error_ratio(camera, T_true: np.ndarray, cov: np.ndarray, observations) -> float:
    """NEES of the linearised error over the sum of its per-hold parts' NEES (see the module
    docstring); ``observations`` one camera's, with keypoints."""
    A = np.zeros((6, 6))
    parts: dict[str, np.ndarray] = {}
    for o in observations:
        base = _pixels(camera, T_true, o)
        J = np.zeros((base.size, 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = 1e-6
            J[:, k] = (_pixels(camera, T_true @ se3_exp(d), o) - base) / 1e-6
        A += J.T @ J
        parts[o.hold] = parts.get(o.hold, 0.0) + J.T @ (np.asarray(o.measured, float).ravel() - base)
    gain = np.linalg.inv(A)
    info = np.linalg.inv(cov)
    c = [gain @ p for p in parts.values()]
    total = sum(c)
    return float(total @ info @ total / sum(x @ info @ x for x in c))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-8", help="seeds, e.g. 1-8 or 1,3,7")
    ap.add_argument("--holds", type=int, default=4, help="holds per sensor")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print(f"{'seed':>4} {'sensor':8} {'error mm':>9} {'deg':>7} {'std mm':>8} {'deg':>7} {'NEES6':>7}  inside  shared")
    by_kind: dict[str, list[float]] = {"lidar": [], "camera": []}
    ratios: list[float] = []
    t0 = time.perf_counter()
    for seed in _seeds(args.seeds):
        with tempfile.TemporaryDirectory() as d:
            scene = write_mocap_scene(Path(d) / "s", seed=seed, holds=args.holds)
            config = load_mocap_config(scene.config_path)
            run = run_mocap(config)
        for name, est in run.result.sensors.items():
            e1 = pose_error(run.final[name], scene.truth[name])
            d2 = nees(est.T_reference_sensor, scene.truth[name], est.covariance)[0]
            kind = "lidar" if name.startswith("lidar") else "camera"
            by_kind[kind].append(d2)
            std_mm = 1000 * _rss(est.std, ("x_m", "y_m", "z_m"))
            std_deg = _rss(est.std, ("roll_deg", "pitch_deg", "yaw_deg"))
            shared = ""
            if kind == "camera":
                own = [o for o in run.observations if o.sensor == name and o.keypoints_target is not None]
                ratios.append(shared_error_ratio(config.sensor(name).camera, scene.truth[name], est.covariance, own))
                shared = f"{ratios[-1]:6.2f}"
            print(f"{seed:4d} {name:8} {e1.translation_m * 1e3:9.2f} {e1.rotation_deg:7.3f} {std_mm:8.2f} "
                  f"{std_deg:7.3f} {d2:7.2f}  {'yes' if d2 <= CHI2_95_6 else 'NO ':6} {shared}", flush=True)
    for kind, v in by_kind.items():
        if v:
            a = np.array(v)
            print(f"{kind}: {np.mean(a <= CHI2_95_6):.2f} inside ({len(a)}), median NEES/dof {np.median(a) / 6:.2f}")
    if ratios:
        r = np.array(ratios)
        print(f"camera shared: median {np.median(r):.2f}, above 1 in {int(np.sum(r > 1))} of {len(r)}")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
