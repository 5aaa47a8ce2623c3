"""Time and check stereo board detection on simulated 1936x1216 pairs (the raw demo's camera).

Renders ``--pairs`` pairs (default 12) of the demo's stereo camera (fx 1400 px, 0.24 m
baseline) with the board at the demo's random placements, then for each pair runs

* ``full``: SGBM over the whole image (:func:`point_cloud_from_pair`) + the stereo detector;
* ``roi``: :func:`rigcal.detect.stereo.detect_board_stereo_pair` (coarse disparity to find the
  board, full-resolution SGBM only around it) - what the detection pipeline runs,

and prints per method the wall time per pair (min / median / max over the pairs, each the
median of ``--runs`` runs) and the hole-centre errors against the simulation's truth (median /
max over all holes). Rendered pairs are cached in ``--cache`` (rendering dominates otherwise).
Usage: python benchmarks/bench_stereo_detection.py [--pairs N] [--runs N] [--cache DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.demo import demo_raw_rig
from rigcal.detect.result import BoardDetection
from rigcal.detect import stereo
from rigcal.recording import StereoFrame
from rigcal.sensors.stereo import point_cloud_from_pair
from rigcal.sim.raw import raw_rig_placements, render_stereo, scene_for_placements


def _pairs(n: int, cache: Path | None):
    """(pair, truth (4, 3) in the left optical frame) for ``n`` placements, seeded."""
    cam = next(s for s in demo_raw_rig() if s.name == "camera1")
    rig = cam.model.stereo_rig()
    path = cache / f"stereo_pairs_{n}.npz" if cache else None
    if path is not None and path.is_file():
        z = np.load(path)
        return rig, [(StereoFrame("camera1", k, z["left"][k], z["right"][k]), z["truth"][k])
                     for k in range(n)]
    rng = np.random.default_rng(12)
    placements = raw_rig_placements(rng, list(demo_raw_rig()), n)
    scene = scene_for_placements(placements)
    T_cam_rig = np.linalg.inv(cam.T_rig_sensor)
    out = []
    for k, T in enumerate(placements):
        sc = scene.with_board(T)
        pair = render_stereo(cam.model, cam.T_rig_sensor, sc, rng, k, "camera1")
        truth = sc.hole_centres_world() @ T_cam_rig[:3, :3].T + T_cam_rig[:3, 3]
        out.append((pair, truth))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, left=np.stack([p.left for p, _ in out]),
                            right=np.stack([p.right for p, _ in out]),
                            truth=np.stack([t for _, t in out]))
    return rig, out


def _errors(det, truth: np.ndarray) -> np.ndarray:
    """Distances [m] of the detected holes to the nearest true hole (order checked apart)."""
    d = np.linalg.norm(np.asarray(det.points)[:, None] - truth[None], axis=2)
    return d.min(axis=1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/rigcal-bench-cache"))
    ap.add_argument("--methods", nargs="*", default=["full", "roi"], choices=["full", "roi"])
    args = ap.parse_args()
    rig, pairs = _pairs(args.pairs, args.cache)
    board = BoardGeometry()
    import cv2

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}, OpenCV {cv2.__version__} "
          f"({cv2.getNumThreads()} threads)")
    print(f"{len(pairs)} pairs {rig.width}x{rig.height}, fx {rig.fx:g} px, baseline "
          f"{rig.baseline_m} m, boards at {min(np.linalg.norm(t.mean(0)) for _, t in pairs):.1f}"
          f"-{max(np.linalg.norm(t.mean(0)) for _, t in pairs):.1f} m")
    methods = {
        "full": lambda p: stereo.detect_board_stereo(point_cloud_from_pair(p, rig), board),
        "roi": lambda p: stereo.detect_board_stereo_pair(p, rig, board),
    }
    print(f"{'method':8} {'min s':>7} {'median s':>8} {'max s':>7} {'detected':>9} "
          f"{'median err mm':>14} {'max err mm':>11} {'ordered':>8}")
    for name in args.methods:
        fn = methods[name]
        times, errs, found, ordered = [], [], 0, 0
        for pair, truth in pairs:
            ts = []
            for _ in range(args.runs):
                t = time.perf_counter()
                det = fn(pair)
                ts.append(time.perf_counter() - t)
            times.append(statistics.median(ts))
            if isinstance(det, BoardDetection):
                found += 1
                errs.extend(_errors(det, truth))
                d = np.linalg.norm(np.asarray(det.points)[:, None] - truth[None], axis=2)
                ordered += int(np.array_equal(np.argmin(d, axis=1), np.arange(4)))
            else:
                print(f"  {name}: pair {pair.t_ns} not detected: {det.reason}: {det.detail}")
        e = np.array(errs) * 1000
        print(f"{name:8} {min(times):7.3f} {statistics.median(times):8.3f} {max(times):7.3f} "
              f"{found:>4}/{len(pairs):<4} {np.median(e) if e.size else float('nan'):14.2f} "
              f"{e.max() if e.size else float('nan'):11.2f} {ordered:>8}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
