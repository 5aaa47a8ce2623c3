"""report.html of the 29-board Prius run: its size, the time to write it, and the time a headless
browser takes to open it (navigation until every plotly figure is drawn).

Calibrates the shared Prius detections once (FCPE), writes report.json + report.html, then opens
the page ``--loads`` times in Debian's chromium (playwright, software WebGL) in one browser, a
new tab each time, and prints min / median / max, with the first paint (the verdict and the
tables on screen), the part spent before the figures start (the first frame, then parsing and
running the embedded plotly.js) and drawing the 3D scene.
Usage: python benchmarks/bench_report.py [--loads N]   (needs ../shared, chromium, playwright)
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

MANIFEST = Path(__file__).resolve().parents[1] / "examples" / "prius" / "rig.yaml"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]
#: wraps Plotly.newPlot as plotly.js defines it, to record when each figure starts and is drawn
#: (page time, ms)
PROBE = """
window.__figs = {};
let plotly;
Object.defineProperty(window, "Plotly", {
  configurable: true,
  get() { return plotly; },
  set(v) {  // plotly.js assigns window.Plotly once, before the page's figures start
    const newPlot = v.newPlot;
    v.newPlot = function (id, ...rest) {
      const t0 = performance.now();
      return newPlot.call(v, id, ...rest).then(r => { window.__figs[id] = [t0, performance.now()]; return r; });
    };
    plotly = v;
  },
});
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loads", type=int, default=7)
    args = ap.parse_args()
    if not (MANIFEST.parent.parents[2] / "shared" / "data").is_dir():
        print("../shared/data not found beside the repository")
        return 1
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(chromium).exists():
        print("chromium not found (Debian: apt-get install chromium)")
        return 1
    from playwright.sync_api import sync_playwright

    from rigcal.io.dataset.manifest import load_manifest
    from rigcal.io.results.calibration import write_results
    from rigcal.io.results.report import write_report
    from rigcal.problem.calibrate import CalibrationOptions, calibrate
    from rigcal.report.data import calibration_report

    dataset = load_manifest(MANIFEST)
    result = calibrate(dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=5))
    print(f"python {platform.python_version()}, {os.cpu_count()} cpu(s), {platform.processor() or platform.machine()}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        write_results(result, out)
        t = time.perf_counter()
        data = calibration_report(result, dataset)
        t_data = time.perf_counter() - t
        t = time.perf_counter()
        write_report(data, out)
        t_write = time.perf_counter() - t
        html = out / "report.html"
        print(f"report.html {html.stat().st_size / 1e6:.2f} MB (report.json {(out / 'report.json').stat().st_size / 1e3:.0f} kB); "
              f"report data {t_data * 1000:.0f} ms, page rendered and written {t_write * 1000:.0f} ms "
              "(in-process, jinja2 already imported after the first)")
        loads, first, before, scene = [], [], [], []
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=ARGS)
            for k in range(args.loads + 1):
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.add_init_script(PROBE)
                t = time.perf_counter()
                page.goto(html.as_uri())
                page.wait_for_function("document.body.dataset.rendered === 'true'", timeout=120_000)
                dt = time.perf_counter() - t
                figs = page.evaluate("window.__figs")
                paint = page.evaluate("(performance.getEntriesByName('first-contentful-paint')[0] || {}).startTime")
                page.close()
                if k == 0:
                    continue  # warm-up: the browser's first page
                loads.append(dt)
                first.append(paint / 1000 if paint is not None else float("nan"))
                before.append(min(v[0] for v in figs.values()) / 1000)
                s = figs.get("fig-scene")
                scene.append((s[1] - s[0]) / 1000 if s else float("nan"))
            browser.close()
    print(f"{'open report.html (29 boards)':<40} {'min':>6} {'median':>6} {'max':>6}  (s, {args.loads} loads)")
    for name, v in (("navigation -> every figure drawn", loads), ("  first paint (verdict, tables)", first),
                    ("  of which before the first figure", before),
                    ("  3D scene drawn (newPlot)", scene)):
        print(f"{name:<40} {min(v):6.2f} {statistics.median(v):6.2f} {max(v):6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
