"""report.html in a real headless browser (Debian's chromium, driven by playwright).

Each page (calibrate with a 2D radar, absolute, mocap, and the shared Prius data) is opened from
file://; the test fails on any console error, page error, failed request or request to anything
but file:/data:/blob:/about:, waits until every plotly figure is drawn, counts the figures, bars
and markers against calibration.yaml, checks that the 3D scene's WebGL canvas shows a picture,
and that the numbers of the pose table equal calibration.yaml to the printed precision. Skips
with a reason when chromium or playwright is missing (`.ci/run` installs chromium).
"""

from __future__ import annotations

import io
import json
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

ROOT = Path(__file__).resolve().parents[2]
PRIUS = ROOT / "examples" / "prius" / "rig.yaml"
SHARED = ROOT.parent / "shared" / "data" / "tudelft_prius"
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]
ALLOWED = ("file:", "data:", "blob:", "about:")

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e .[test])")
if CHROMIUM is None:
    pytest.skip("no chromium on this machine (Debian: apt-get install chromium; .ci/run installs it)",
                allow_module_level=True)


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def open_report(browser, path: Path):
    """The page loaded and drawn; fails on any console error, page error, failed or foreign
    request. Returns (page, seconds from navigation to every figure drawn)."""
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    problems: list[str] = []
    page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url}"))
    page.on("request", lambda r: None if r.url.startswith(ALLOWED) else problems.append(f"request: {r.url}"))
    page.route(re.compile(r"^(?!file:|data:|blob:|about:)"),
               lambda route: (problems.append(f"request: {route.request.url}"), route.abort()))
    start = time.perf_counter()
    page.goto(path.resolve().as_uri())
    page.wait_for_function("document.body.dataset.rendered === 'true'", timeout=60_000)
    seconds = time.perf_counter() - start
    page.wait_for_timeout(50)  # late console messages
    assert not problems, problems
    return page, seconds


def check_common(page, folder: Path, table: str = "poses", result_file: str = "calibration.yaml",
                 rpy_std_decimals: int = 2) -> dict:
    cal = yaml.safe_load((folder / result_file).read_text())
    n = int(page.get_attribute("body", "data-figures"))
    assert n >= 3
    assert page.locator(".js-plotly-plot").count() == n
    # every 2D figure drew its SVG; every 3D one its WebGL canvas
    for div in page.locator(".js-plotly-plot").all():
        if div.get_attribute("id") == "fig-scene":
            canvas = div.locator("canvas").first
            box = canvas.bounding_box()
            assert box and box["width"] > 300 and box["height"] > 300
        else:
            assert div.locator("svg.main-svg path").count() > 3, div.get_attribute("id")
    # the verdict is the first thing on the page
    status = cal["verdict"]["status"] if result_file == "calibration.yaml" else cal["relative"]["verdict"]["status"]
    assert page.inner_text("#verdict-status").startswith("FLAGGED" if status == "flagged" else "consistent")
    # the pose table shows calibration.yaml's numbers at the printed precision
    sensors = cal["sensors"]
    rows = page.locator(f"#{table} tr[data-sensor]")
    assert rows.count() == len(sensors)
    for name, s in sensors.items():
        row = page.locator(f'#{table} tr[data-sensor="{name}"]')

        def cell(key: str) -> str:
            return row.locator(f'td[data-key="{key}"]').inner_text().strip()

        for i, k in enumerate(("x_m", "y_m", "z_m")):
            assert cell(k) == f"{s['xyz_m'][i]:.4f}", (name, k)
            assert cell(f"std_{k}") == ("bnd" if k[0] in s["bounded"] else f"{s['std'][k] * 1000:.1f}"), (name, k)
        for i, k in enumerate(("roll_deg", "pitch_deg", "yaw_deg")):
            assert cell(k) == f"{s['rpy_deg'][i]:.3f}", (name, k)
            b = k.split("_")[0] in s["bounded"]
            assert cell(f"std_{k}") == ("bnd" if b else f"{s['std'][k]:.{rpy_std_decimals}f}"), (name, k)
    return cal


def check_scene_and_residuals(page, cal: dict) -> None:
    """The 3D scene shows every used board of every sensor (hover text: board and residual),
    its canvas holds a picture; one bar per (pair, board), the RMSE next to cross-validation."""
    traces = page.evaluate("document.getElementById('fig-scene').data.map(t => "
                           "({name: t.name, type: t.type, meta: t.meta || null, n: (t.x || []).length, "
                           "text: (t.text || []).slice(0, 1)}))")
    used = {t["meta"]["sensor"]: t for t in traces if t["meta"] and t["meta"]["status"] == "used"}
    for name in cal["sensors"]:
        t = used[name]
        assert t["text"][0].startswith(f"{name} board ") and " mm" in t["text"][0]
    assert any(t["name"].startswith("radar1 elevation arcs") for t in traces if t["name"])
    assert any(t["type"] == "mesh3d" for t in traces)  # the field-of-view wedge
    png = page.locator("#fig-scene").screenshot()
    from PIL import Image

    im = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    assert len(np.unique(im.reshape(-1, 3), axis=0)) > 50  # a drawn scene, not a blank canvas
    # one bar per board and pair, as per_board_m
    bars = page.evaluate("document.getElementById('fig-boards').data.filter(t => t.type === 'bar')"
                         ".map(t => [t.name, t.x.length])")
    assert dict(bars) == {p: len(v) for p, v in cal["per_board_m"].items()}
    drawn = page.locator("#fig-boards .barlayer .point").count()
    assert drawn == sum(len(v) for v in cal["per_board_m"].values())
    assert page.locator("#fig-rmse .barlayer .point").count() == len(cal["rmse_m"]) * (
        2 if cal["cross_validation_rmse_m"] else 1)
    for pair, v in cal["rmse_m"].items():
        assert page.inner_text(f'#errors tr[data-pair="{pair}"] td[data-key="rmse"]') == f"{v * 1000:.2f}"


@pytest.fixture(scope="module")
def calibrate_folder(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report_calibrate")
    rng = np.random.default_rng(21)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 10, min_fraction=1.0), rng=rng)
    manifest = write_dataset(sim.dataset, tmp / "data")
    assert run(["calibrate", str(manifest), "--cv-folds", "3", "--out", str(tmp / "out")]) == 0
    return tmp / "out"


@pytest.mark.slow  # 8-15 s on the shared 2-core machine: calibrating, launching chromium, a page load
def test_calibrate_report_in_a_browser(browser, calibrate_folder):
    page, seconds = open_report(browser, calibrate_folder / "report.html")
    cal = check_common(page, calibrate_folder)
    check_scene_and_residuals(page, cal)
    # coverage: one marker per used board, and the suggested next board, per sensor
    data = json.loads((calibrate_folder / "report.json").read_text())
    for name, cov in data["coverage"].items():
        n = page.locator(f"#fig-coverage-{name} .scatterlayer .point").count()
        assert n == len(cov["boards"]) + (1 if "hint" in cov else 0), name
    assert page.locator("#directions tr[data-sensor]").count() == 3
    # the relative transforms table equals calibration.yaml's relative section
    rel = page.locator("#relative tr[data-sensor]")
    assert rel.count() == len(cal["relative"])
    for key, r in cal["relative"].items():
        row = page.locator(f'#relative tr[data-sensor="{r["to"]} <- {r["from"]}"]')
        assert row.locator('td[data-key="x_m"]').inner_text() == f"{r['xyz_m'][0]:.4f}"
        # bnd where a bounded direction moves the value more than its std (docs/uncertainty.md)
        assert row.locator('td[data-key="std_yaw_deg"]').inner_text() == (
            "bnd" if "yaw" in r["bounded"] else f"{r['std']['yaw_deg']:.2f}")
    print(f"calibrate report: {seconds:.2f} s to load and draw")
    page.close()


@pytest.mark.slow  # ~10 s: the absolute demo, then a page load
def test_absolute_report_in_a_browser(browser, tmp_path):
    assert run(["demo", "--absolute", "--boards", "8", "--out", str(tmp_path / "d")]) == 0
    folder = tmp_path / "d" / "absolute"
    page, _ = open_report(browser, folder / "report.html")
    check_common(page, folder, table="body-poses", result_file="absolute.yaml", rpy_std_decimals=3)
    assert page.locator("#poses tr[data-sensor]").count() == 4  # the rig + the external scanner
    page.close()


@pytest.mark.slow  # ~10 s: calibrating the 29 Prius boards, then a page load
def test_prius_report_in_a_browser(browser, tmp_path):
    if not SHARED.is_dir():
        pytest.skip("../shared/data/tudelft_prius not present")
    out = tmp_path / "prius"
    assert run(["calibrate", str(PRIUS), "--out", str(out)]) == 0
    page, seconds = open_report(browser, out / "report.html")
    cal = check_common(page, out)
    check_scene_and_residuals(page, cal)
    assert sum(len(v) for v in cal["per_board_m"].values()) == 3 * 29
    print(f"Prius report: {seconds:.2f} s to load and draw, {(out / 'report.html').stat().st_size / 1e6:.1f} MB")
    page.close()


@pytest.mark.slow  # the motion-capture session takes ~30 s
def test_mocap_report_in_a_browser(browser, tmp_path):
    from rigcal.sim.mocap_scene import two_sensor_rig, write_mocap_scene

    scene = write_mocap_scene(tmp_path / "scene", two_sensor_rig(), seed=0, holds=3, exclusive=False)
    out = tmp_path / "out"
    assert run(["mocap", str(scene.config_path), "--out", str(out), "--max-overlays", "1"]) in (0, 4)
    page, _ = open_report(browser, out / "report.html")
    check_common(page, out)
    data = json.loads((out / "report.json").read_text())
    # every kept measurement has its initial and final bar
    for name in {m["sensor"] for m in data["mocap"]["measurements"]}:
        n = sum(1 for m in data["mocap"]["measurements"] if m["sensor"] == name)
        assert page.locator(f"#fig-measurements-{name} .barlayer .point").count() == 2 * n
    imgs = page.locator("#overlays img")
    assert imgs.count() == len(data["mocap"]["overlays"]) >= 1
    assert all(page.evaluate("img => img.naturalWidth > 0", img.element_handle()) for img in imgs.all())
    page.close()


@pytest.mark.parametrize(("body", "needle"), [
    ('<img src="http://127.0.0.1:9/x.png">', "request: http://127.0.0.1:9/x.png"),
    ("<script>console.error('boom')</script>", "console error: boom"),
    ("<script>null.x</script>", "page error"),
])
def test_the_harness_fails_on_requests_and_errors(browser, tmp_path, body, needle):
    """The checks above can fail: a foreign request, a console error or a script error is caught."""
    page = tmp_path / "p.html"
    page.write_text(f"<!DOCTYPE html><html><body>{body}<script>document.body.dataset.rendered = 'true'"
                    "</script></body></html>")
    with pytest.raises(AssertionError, match=re.escape(needle)):
        open_report(browser, page)


@pytest.mark.slow
def test_study_page_in_the_browser(browser, tmp_path):
    """study.html: every figure drawn (SVG), one table row per study row, nothing requested."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("study_page_tests", Path(__file__).with_name("test_study_page.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    study = mod.make_study()
    (tmp_path / "study.json").write_text(json.dumps(study))
    assert run(["report", str(tmp_path)]) == 0
    page, _ = open_report(browser, tmp_path / "study.html")
    assert page.locator(".js-plotly-plot").count() == int(page.get_attribute("body", "data-figures")) == 3
    for div in page.locator(".js-plotly-plot").all():
        assert div.locator("svg.main-svg path").count() > 3, div.get_attribute("id")
    assert page.locator("table.rows tr").count() == len(study["rows"]) + 4  # a header per table
    page.close()


@pytest.mark.slow  # calibrating, launching chromium, a page load
def test_markup_in_a_sensor_name_fetches_nothing(browser, calibrate_folder, tmp_path):
    """Issue #22: a hand-edited report.json whose sensor name holds ``<span style="...url(http://...)">``
    and a link: the page used to hand the markup to plotly.js, which drew it - the CSP blocked 5
    image fetches (14 on the shared data). Now the name is text everywhere: no request, no CSP
    violation, no console error (open_report fails on any), and the name shows as written."""
    evil = ('<span style="background-image:url(http://127.0.0.1:9/x.png)">L</span>'
            '<a href="http://127.0.0.1:9/">here</a>')
    res = tmp_path / "res"
    res.mkdir()
    for p in calibrate_folder.iterdir():
        if p.is_file():
            (res / p.name).write_bytes(p.read_bytes())
    text = (res / "report.json").read_text()
    (res / "report.json").write_text(text.replace('"lidar1"', json.dumps("lidar1" + evil)))
    assert run(["report", str(res)]) == 0
    page, _ = open_report(browser, res / "report.html")  # fails on a request or a CSP violation's console error
    assert page.locator(".js-plotly-plot a").count() == 0
    assert page.locator(".js-plotly-plot [style*=url]").count() == 0
    assert "lidar1<span" in page.inner_text("#fig-scene")  # shown as written
    page.close()
