"""How far OpenCV's checkerboard corners fall from the truth in rendered views, by square size.

Renders the rendered sessions' target (``write_mocap_scene``'s 0.5 m diamond, 7 x 6 inner
corners of 29 mm) with ``rigcal.sim.mocap.render_image`` in random views 1.6-3.2 m from the
sessions' 1024 x 768 pinhole camera (f = 1176 px), tilted up to 30 deg and turned any way, and
locates the corners with ``extract_checkerboard`` twice: with its refinement off
(``cv2.findChessboardCornersSB`` with ``CALIB_CB_ACCURACY``) and with it on at every size
(``cv2.cornerSubPix`` after it, window 0.4 squares - what it does below ``SMALL_SQUARE_PX``). Per bin of square size [px] it prints the
corners' RMS error [px], the mean error of the grid's border corners along the direction away
from the grid's centre (> 0: pushed outward; a bias every view of that size shares) and of its
interior corners, the RMS over views of the whole grid's shift (the length of the mean of a
view's corner errors: an error that looks like the pose's and does not average over holds),
and the RMS translation error [mm] of a single view's pose from the corners
(the mean of ``--frames`` noisy renders, the MCS exact). These are the figures docs/mocap.md
quotes on why the rendered sessions' cameras' 95 % regions were narrow and where the
extractor's refinement stops (``SMALL_SQUARE_PX``).

Usage: python benchmarks/corner_bias.py [--views 120] [--frames 4] [--seed 3]
"""

from __future__ import annotations

import argparse
import platform
import time

import cv2
import numpy as np

from rigcal.extract.camera import extract_checkerboard, grid_square_px
from rigcal.geometry.se3 import invert, se3_exp
from rigcal.geometry.so3 import so3_exp
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sim.mocap import render_image
from rigcal.targets.templates import diamond_target

BINS = ((6.0, 11.0), (11.0, 13.0), (13.0, 16.0), (16.0, 20.0), (20.0, 40.0))


def _view(rng: np.random.Generator, camera, keypoints: np.ndarray) -> np.ndarray | None:
    """A random T_camera_target with every corner in the image, or None."""
    R = so3_exp(np.r_[rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)]) @ np.diag([1.0, -1.0, -1.0])
    ray = np.r_[rng.uniform(-0.25, 0.25, 2), 1.0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = rng.uniform(1.6, 3.2) * ray / np.linalg.norm(ray) - R @ keypoints.mean(axis=0)
    _, ok = camera.project(keypoints @ T[:3, :3].T + T[:3, 3])
    return T if ok.all() else None


def _pose_jacobian(camera, T: np.ndarray, keypoints: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(2K, 6) derivative of the corners' pixels with respect to a move of the camera."""
    def pixels(T_ct):
        return camera.project(keypoints @ T_ct[:3, :3].T + T_ct[:3, 3])[0].ravel()
    base = pixels(T)
    J = np.zeros((base.size, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        J[:, k] = (pixels(invert(se3_exp(d)) @ T) - base) / h
    return J


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=120, help="random views drawn")
    ap.add_argument("--frames", type=int, default=4, help="noisy renders per view (a hold)")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, "
          f"opencv {cv2.__version__}")
    camera = PinholeCamera.from_intrinsics(1024, 768, 1176.0, 1176.0, 511.5, 383.5)
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    kp = np.asarray(target.camera_keypoints, dtype=float)
    inner = np.zeros((6, 7), dtype=bool)
    inner[1:-1, 1:-1] = True
    border = ~inner.ravel()
    rng = np.random.default_rng(args.seed)
    rows: list[tuple] = []
    t0 = time.perf_counter()
    for _ in range(args.views):
        T = _view(rng, camera, kp)
        if T is None:
            continue
        truth = camera.project(kp @ T[:3, :3].T + T[:3, 3])[0]
        square = grid_square_px(truth, (7, 6))
        found: dict[str, list] = {"sb": [], "subpix": []}
        for _ in range(args.frames):
            frame = render_image(camera, T, target, rng)
            ms = [extract_checkerboard(frame, camera, (7, 6), kp, T, estimate_pose=False, refine_below_square_px=below)
                  for below in (0.0, np.inf)]
            if not all(hasattr(m, "keypoints") for m in ms) or not ms[1].quality["corners_subpix"]:
                break  # not found, or a refined corner ran off (the extractor kept SB's)
            for key, m in zip(found, ms):
                found[key].append(m.keypoints - truth)
        else:
            J = _pose_jacobian(camera, T, kp)
            from_centre = truth - truth.mean(axis=0)
            out = from_centre / np.linalg.norm(from_centre, axis=1, keepdims=True)
            row = [square]
            for errors in found.values():
                e = np.asarray(errors)
                mean = e.mean(axis=0)
                radial = np.sum(mean * out, axis=1)
                dt = np.linalg.lstsq(J, mean.ravel(), rcond=None)[0][3:]
                row += [float(np.sqrt(np.mean(e ** 2))), float(radial[border].mean()), float(radial[~border].mean()),
                        float(np.linalg.norm(mean.mean(axis=0))), 1000 * float(np.linalg.norm(dt))]
            rows.append(tuple(row))
    a = np.array(rows)
    print(f"{len(a)} views, {args.frames} renders each, {time.perf_counter() - t0:.0f} s")
    print(f"{'square px':>10} {'views':>5} | {'SB rms px':>9} {'border out':>10} {'interior':>8} {'shift':>6} {'pose mm':>7} | "
          f"{'subpix rms':>10} {'border out':>10} {'interior':>8} {'shift':>6} {'pose mm':>7}")
    for lo, hi in BINS:
        s = a[(a[:, 0] >= lo) & (a[:, 0] < hi)]
        if not len(s):
            continue
        cells = []
        for c in (1, 6):
            cells.append(f"{s[:, c].mean():9.3f} {s[:, c + 1].mean():+10.4f} {s[:, c + 2].mean():+8.4f} "
                         f"{np.sqrt(np.mean(s[:, c + 3] ** 2)):6.4f} {np.sqrt(np.mean(s[:, c + 4] ** 2)):7.2f}")
        print(f"{lo:4.0f}-{hi:<5.0f} {len(s):5d} | {cells[0]} | {cells[1]:>10}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
