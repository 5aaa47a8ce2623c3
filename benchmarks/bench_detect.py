"""Time the board detectors on simulated raw data (and the mono detector on the real images).

Prints median milliseconds per frame: HDL-64E-like scan (~130k points) -> lidar detector;
1936x1216 stereo pair -> SGBM point cloud -> stereo detector; 1936x1216 real image -> mono
detector (when ../shared is present and the mono detector is installed).
Usage: python benchmarks/bench_detect.py [--runs N]
"""

from __future__ import annotations

import argparse
import platform
from pathlib import Path

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.demo import demo_raw_rig
from rigcal.detect.lidar import detect_board_lidar
from rigcal.detect.stereo import detect_board_stereo
from rigcal.sensors.stereo import point_cloud_from_pair
from rigcal.sim.raw import raw_rig_placements, render_stereo, scan, scene_for_placements
from timing import median_ms

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "tudelft_prius" / "mono"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=9)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    sensors = {s.name: s for s in demo_raw_rig()}
    placements = raw_rig_placements(rng, list(sensors.values()), 3)
    scene = scene_for_placements(placements)
    board = BoardGeometry()
    print(f"machine: {platform.machine()}, {platform.system()}, python {platform.python_version()}")
    print(f"{'detector':44} {'median ms':>10}")
    lidar = sensors["lidar1"]
    for k, T in enumerate(placements):
        frame = scan(lidar.model, lidar.T_rig_sensor, scene.with_board(T), rng, 0, "lidar1")
        ms = median_ms(lambda: detect_board_lidar(frame, board), args.runs)
        print(f"{f'lidar, {len(frame)} points, board {k}':44} {ms:10.1f}")
    cam = sensors["camera1"]
    rig = cam.model.stereo_rig()
    pair = render_stereo(cam.model, cam.T_rig_sensor, scene.with_board(placements[0]), rng, 0, "camera1")
    cloud = point_cloud_from_pair(pair, rig)
    print(f"{'stereo SGBM point cloud, 1936x1216':44} {median_ms(lambda: point_cloud_from_pair(pair, rig), args.runs):10.1f}")
    print(f"{'stereo detector on that cloud':44} {median_ms(lambda: detect_board_stereo(cloud, board), args.runs):10.1f}")
    try:
        import cv2

        from rigcal.detect.mono import detect_board_mono
        from rigcal.io.config.intrinsics import read_intrinsics
        from rigcal.recording import ImageFrame
    except ImportError:
        print("mono detector: not available")
        return 0
    if SHARED.is_dir():
        camera = read_intrinsics(SHARED / "intrinsics.ini")
        for name in ("example_image1.png", "example_image2.png"):
            img = cv2.imread(str(SHARED / name), cv2.IMREAD_GRAYSCALE)
            frame = ImageFrame("camera1", 0, img)
            ms = median_ms(lambda: detect_board_mono(frame, camera, board), args.runs)
            print(f"{f'mono, real {img.shape[1]}x{img.shape[0]} {name}':44} {ms:10.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
