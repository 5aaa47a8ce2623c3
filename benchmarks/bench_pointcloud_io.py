"""Time point cloud file I/O: PCD (ascii, binary, binary_compressed) and PLY, read and write.

A simulated-looking scan of N points (default 1 M): x, y, z float32, intensity float32,
ring uint16, written to and read from a temporary folder (the file system's page cache is warm,
so this measures parsing and encoding, not the disk). Prints min / median / max seconds over
``--runs`` runs for rigcal and, when it is installed, pypcd4 (for comparison only; rigcal does
not use it). rigcal's default write flushes the file to disk (fsync) before renaming it into
place; pypcd4 does neither, so the PCD writes are also timed with ``durable=False``.
Usage: python benchmarks/bench_pointcloud_io.py [--points N] [--runs N] [--only KIND ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from rigcal.io import clouds as pc
from rigcal.recording import PointCloudFrame

KINDS = ("pcd ascii", "pcd binary", "pcd binary_compressed", "ply binary", "ply ascii")


def _times(fn: Callable[[], object], runs: int) -> tuple[float, float, float]:
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return min(out), statistics.median(out), max(out)


def _cloud(n: int) -> PointCloudFrame:
    rng = np.random.default_rng(0)
    # a scan-like cloud: 16 rings, smooth ranges (compressible like a real scan, not noise)
    az = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = (np.arange(n) % 16).astype(np.uint16)
    el = np.radians(-15.0 + 2.0 * ring)
    r = 5 + 3 * np.sin(3 * az) + rng.normal(0, 0.01, n)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    pts = pts.astype(np.float32).astype(np.float64)
    intensity = rng.integers(0, 256, n).astype(np.float32)
    return PointCloudFrame(sensor="lidar", t_ns=0, points_xyz=pts,
                           fields={"intensity": intensity, "ring": ring})


def _row(label: str, t: tuple[float, float, float], size: int | None = None) -> None:
    mb = f"{size / 1e6:9.1f}" if size is not None else f"{'':9}"
    print(f"{label:44} {t[0]:8.3f} {t[1]:8.3f} {t[2]:8.3f} {mb}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--only", nargs="*", choices=KINDS, default=list(KINDS))
    args = ap.parse_args()
    frame = _cloud(args.points)
    try:
        import pypcd4
    except ImportError:
        pypcd4 = None
    lzf = pc.LZF_BACKEND
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}; rigcal LZF: {lzf}; "
          f"pypcd4: {getattr(pypcd4, '__version__', 'installed') if pypcd4 else 'not installed'}")
    print(f"{args.points} points (x y z intensity F4, ring U2), {args.runs} runs")
    print(f"{'':44} {'min s':>8} {'median s':>8} {'max s':>8} {'MB':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in args.only:
            fmt, data = kind.split()
            path = Path(tmp) / f"cloud_{data}.{fmt}"
            write = (lambda: pc.write_pcd(path, frame, data)) if fmt == "pcd" else (
                lambda: pc.write_ply(path, frame, "binary_little_endian" if data == "binary"
                                     else data, xyz_dtype=np.float32))
            _row(f"rigcal {kind} write", _times(write, args.runs))
            if fmt == "pcd":  # the default write also fsyncs; pypcd4 does not
                _row(f"rigcal {kind} write (durable=False)",
                     _times(lambda: pc.write_pcd(path, frame, data, durable=False), args.runs))
            size = path.stat().st_size
            _row(f"rigcal {kind} read", _times(lambda: pc.read_point_cloud(path, "lidar"),
                                                args.runs), size)
            if pypcd4 is None or fmt != "pcd":
                continue
            def build():  # pypcd4's own cloud from the same float64 arrays rigcal writes from
                return pypcd4.PointCloud.from_points(
                    [frame.points_xyz[:, 0].astype(np.float32), frame.points_xyz[:, 1].astype(
                        np.float32), frame.points_xyz[:, 2].astype(np.float32),
                     frame.fields["intensity"], frame.fields["ring"]],
                    ("x", "y", "z", "intensity", "ring"),
                    (np.float32, np.float32, np.float32, np.float32, np.uint16))

            cloud = build()
            other = Path(tmp) / f"pypcd4_{data}.pcd"
            _row(f"pypcd4 {kind} write", _times(
                lambda: cloud.save(other, encoding=pypcd4.Encoding(data)), args.runs))
            _row(f"pypcd4 {kind} write (from the arrays)", _times(
                lambda: build().save(other, encoding=pypcd4.Encoding(data)), args.runs))
            _row(f"pypcd4 {kind} read",
                 _times(lambda: pypcd4.PointCloud.from_path(other).numpy(), args.runs),
                 other.stat().st_size)
            # the same files both ways: the codec's speed depends on the bytes it is given
            _row(f"rigcal {kind} read (pypcd4's file)",
                 _times(lambda: pc.read_point_cloud(other, "lidar"), args.runs))
            _row(f"pypcd4 {kind} read (rigcal's file)",
                 _times(lambda: pypcd4.PointCloud.from_path(path).numpy(), args.runs))
            # what pypcd4 wrote, rigcal reads (and the other way round)
            theirs = pc.read_point_cloud(other, "lidar")
            ours = pypcd4.PointCloud.from_path(path).numpy()
            tol = 1e-5 if data == "ascii" else 0.0  # pypcd4 writes ascii with fewer digits
            assert np.allclose(theirs.points_xyz, frame.points_xyz, rtol=0, atol=tol)
            assert np.array_equal(ours[:, 4], frame.fields["ring"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
