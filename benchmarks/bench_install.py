"""Install size, wheel and page sizes of rigcal as a user gets it (issue 24: a lean install).

Builds the wheel of this checkout, installs it into a fresh virtual environment (``python -m
venv``, then ``pip install rigcal-*.whl``: the base install), measures the environment with
``du -s`` and its largest packages, then adds each extra (images, plots, fleet, mcap) in turn and
measures again. In the base environment it runs ``rigcal demo --detections-only`` (29 boards)
and reports the sizes of the report.html pages it wrote (plotly.js comes from the wheel), and
times ``rigcal --version``.

Usage: python benchmarks/bench_install.py [--keep DIR]   (needs the package registry or a
warm pip cache; takes 1-3 minutes). Prints the machine first.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from timing import cpu_model

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = ("images", "plots", "fleet", "mcap")
MB = 1024 * 1024


def du_bytes(path: Path) -> int:
    """``du -s --block-size=1``: the disk the folder takes."""
    out = subprocess.run(["du", "-s", "--block-size=1", str(path)], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[0])


def site_packages(venv: Path) -> Path:
    return next((venv / "lib").glob("python*/site-packages"))


def largest(venv: Path, n: int = 8) -> list[tuple[str, int]]:
    sp = site_packages(venv)
    sizes = [(p.name, du_bytes(p)) for p in sp.iterdir() if p.is_dir() and not p.name.endswith(".dist-info")]
    return sorted(sizes, key=lambda kv: -kv[1])[:n]


def pip(venv: Path, *args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                    *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def machine() -> str:
    cpu = cpu_model()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.system()} {platform.release()}, python {platform.python_version()}, {os.cpu_count()} cpu(s) "
            f"{cpu}, load average {load:.1f}, {time.strftime('%Y-%m-%d')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", metavar="DIR", help="build the venv in DIR and keep it (default: a temporary folder)")
    args = ap.parse_args()
    print(machine())
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rigcal-install-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        wheels = work / "wheel"
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(wheels), str(ROOT)],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wheel = next(wheels.glob("rigcal-*.whl"))
        print(f"wheel {wheel.name}: {wheel.stat().st_size / MB:.2f} MiB")
        venv = work / "venv"
        if venv.exists():
            shutil.rmtree(venv)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        empty = du_bytes(venv)
        seconds = pip(venv, str(wheel))
        base = du_bytes(venv)
        print(f"fresh venv (pip, setuptools): {empty / MB:.0f} MiB")
        print(f"base install (pip install {wheel.name}): venv {base / MB:.0f} MiB (du -s), "
              f"rigcal and its dependencies {(base - empty) / MB:.0f} MiB; pip took {seconds:.1f} s "
              "(packages from the pip cache or registry)")
        print("  largest: " + ", ".join(f"{name} {size / MB:.0f}" for name, size in largest(venv)) + " (MiB)")
        # a report page from the installed wheel
        rigcal = venv / "bin" / "rigcal"
        demo = work / "demo"
        shutil.rmtree(demo, ignore_errors=True)
        subprocess.run([str(rigcal), "demo", "--detections-only", "--out", str(demo)], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        pages = sorted(demo.glob("*/report.html"))
        print("report.html from the base install (demo --detections-only, 29 boards): "
              + ", ".join(f"{p.parent.name} {p.stat().st_size / 1e6:.2f} MB" for p in pages))
        js = next(site_packages(venv).glob("rigcal/report/js/plotly-rigcal.min.js"))
        print(f"  of which plotly.js (partial build in the wheel): {js.stat().st_size / 1e6:.2f} MB")
        times = []
        for _ in range(10):
            t0 = time.perf_counter()
            subprocess.run([str(rigcal), "--version"], check=True, stdout=subprocess.DEVNULL)
            times.append(time.perf_counter() - t0)
        print(f"rigcal --version: median {statistics.median(times):.3f} s (min {min(times):.3f}) over 10 runs")
        before = base
        for extra in EXTRAS:
            seconds = pip(venv, f"{wheel}[{extra}]")
            now = du_bytes(venv)
            print(f"+ rigcal[{extra}]: +{(now - before) / MB:.0f} MiB -> venv {now / MB:.0f} MiB ({seconds:.1f} s)")
            before = now
        print(f"rigcal[all]: venv {before / MB:.0f} MiB")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
