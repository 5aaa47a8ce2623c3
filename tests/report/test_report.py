"""report.json / report.html: the report data built from a result with known ground truth, the
page's numbers and figures, and reading a result folder back (the browser test is
test_report_browser.py)."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import invert, transform_points
from rigcal.io.results.calibration import write_results
from rigcal.io.results.report import report_json_text, write_report
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.result import STD_KEYS, CalibrationResult, SensorEstimate
from rigcal.report.data import calibration_report, radar_arcs, sensor_coverage, weakest_directions
from rigcal.report.figures import all_figures
from rigcal.report.page import check_report_data, pose_rows, render_report
from rigcal.sim import make_rig_placements, move_boards, prius_like_rig, simulate


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)


@pytest.fixture(scope="module")
def fitted(sim):
    return calibrate(sim.dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=3))


def _truth_result(sim, outliers=None) -> CalibrationResult:
    ds = sim.dataset
    ref = ds.names[0]
    return CalibrationResult(
        mode="fcpe", reference=ref, converged=True,
        sensors={n: SensorEstimate(n, ds.sensor(n).kind, n, sim.truth_T(ref, n), np.eye(6) * 1e-6,
                                   {k: 0.001 for k in STD_KEYS}) for n in ds.names},
        rmse_m={}, per_board_m={}, outliers=outliers or {}, num_boards=ds.num_boards,
    )


# --------------------------------------------------------------------------------------------
# the data


def test_detections_of_one_board_coincide_in_the_reference_frame(sim):
    result = _truth_result(sim)
    scene = calibration_report(result, sim.dataset)["scene"]
    by_name = {s["name"]: s for s in scene["sensors"]}
    lidar, camera = by_name["lidar1"], by_name["camera1"]
    assert lidar["boards"] == list(range(12)) and camera["boards"] == list(range(12))
    for k in range(12):
        a = np.mean(lidar["points"][k], axis=0)
        b = np.mean(camera["points"][k], axis=0)
        assert np.linalg.norm(a - b) < 0.08, k  # the simulated noise, not a frame error
    # the sensor poses are the truth, so a wrong pose would move the camera's boards away
    moved = _truth_result(sim)
    T = sim.truth_T("lidar1", "camera1").copy()
    T[:3, 3] += [0.5, 0, 0]
    moved.sensors["camera1"] = SensorEstimate("camera1", SensorKind.CAMERA, "camera1", T, np.eye(6), moved.sensors["camera1"].std)
    cam_moved = {s["name"]: s for s in calibration_report(moved, sim.dataset)["scene"]["sensors"]}["camera1"]
    shift = np.mean(np.asarray(cam_moved["points"]) - np.asarray(camera["points"]), axis=(0, 1))
    np.testing.assert_allclose(shift, [0.5, 0.0, 0.0], atol=2e-4)  # points rounded to 0.1 mm


def test_radar_arcs_keep_the_measured_range_and_azimuth_within_the_field_of_view():
    xy = np.array([[3.0, 1.0], [5.0, -2.0]])
    arcs = radar_arcs(xy, math.radians(9.0), samples=7)
    assert arcs.shape == (2, 7, 3)
    r = np.linalg.norm(arcs, axis=2)
    np.testing.assert_allclose(r, np.linalg.norm(xy, axis=1)[:, None] * np.ones((1, 7)))
    az = np.arctan2(arcs[..., 1], arcs[..., 0])
    np.testing.assert_allclose(az, np.arctan2(xy[:, 1], xy[:, 0])[:, None] * np.ones((1, 7)), atol=1e-12)
    el = np.degrees(np.arcsin(arcs[..., 2] / r))
    np.testing.assert_allclose(el[:, [0, -1]], [[-9, 9], [-9, 9]], atol=1e-9)


def test_radar_wedge_and_arcs_in_the_reference_frame(sim):
    result = _truth_result(sim)
    scene = calibration_report(result, sim.dataset)["scene"]
    radar = scene["radars"][0]
    T = result.sensors[radar["name"]].T_reference_sensor
    det = sim.dataset.sensor(radar["name"])
    for k, arc in zip(radar["boards"], radar["arcs"]):
        in_radar = transform_points(invert(T), np.asarray(arc, dtype=float))
        np.testing.assert_allclose(np.linalg.norm(in_radar, axis=1), np.linalg.norm(det.points[k]), atol=2e-4)
    # the wedge's outline starts at the radar and reaches beyond the farthest detection
    edge = transform_points(invert(T), np.asarray(radar["edges"][0], dtype=float))
    assert np.linalg.norm(edge[0]) < 1e-3
    assert np.linalg.norm(edge, axis=1).max() > np.linalg.norm(det.points, axis=1).max()
    el = np.degrees(np.arcsin(edge[1:-1, 2] / np.linalg.norm(edge[1:-1], axis=1)))
    np.testing.assert_allclose(np.abs(el), radar["max_elevation_deg"], atol=0.01)


def test_outlier_boards_are_marked_in_the_scene(sim):
    ds = move_boards(sim.dataset, "camera1", [3], [0.4, 0.0, 0.0])
    result = _truth_result(sim, outliers={"camera1": (3,)})
    cam = {s["name"]: s for s in calibration_report(result, ds)["scene"]["sensors"]}["camera1"]
    assert cam["status"][cam["boards"].index(3)] == "outlier"
    assert cam["status"].count("outlier") == 1
    fig = next(f for f in all_figures(calibration_report(result, ds)) if f["id"] == "fig-scene")
    outlier_traces = [t for t in fig["data"] if t.get("meta", {}).get("status") == "outlier"]
    assert [t["meta"]["sensor"] for t in outlier_traces] == ["camera1"]
    assert len(outlier_traces[0]["x"]) == 4  # the board's four circle centres


def test_weakest_directions_follow_the_covariance():
    C = np.diag([1e-6, 4e-4, 1e-6, 1e-6, 1e-6, 9e-4])  # pitch (about y) and z are the weak ones
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # sensor y is reference -x
    w = weakest_directions(C, T)
    assert np.allclose(np.abs(w["rotation"]["axis_sensor"]), [0, 1, 0])
    assert np.allclose(np.abs(w["rotation"]["axis_reference"]), [1, 0, 0])
    assert w["rotation"]["std"] == pytest.approx(math.degrees(0.02))
    assert np.allclose(np.abs(w["translation"]["axis_sensor"]), [0, 0, 1])
    assert w["translation"]["std"] == pytest.approx(30.0)


def test_the_hint_points_where_the_covariance_shrinks(sim, fitted):
    det = sim.dataset.sensor("camera1")
    boards = list(range(det.num_boards))
    centres = np.asarray(det.points).reshape(det.num_boards, 4, 3).mean(axis=1)
    cov = sensor_coverage(det, fitted, centres, boards)
    hint = cov["hint"]
    assert 0.0 < hint["variance_reduction"] < 1.0
    assert "next board for camera1" in hint["text"]
    # within the viewed azimuths widened by 15 deg
    az = np.asarray(cov["azimuth_deg"])
    assert az.min() - 15.01 <= hint["azimuth_deg"] <= az.max() + 15.01
    # a board at the hint (reference frame) lies at the median range from the camera
    p_cam = transform_points(invert(fitted.sensors["camera1"].T_reference_sensor), np.asarray([hint["point_reference"]]))
    assert np.linalg.norm(p_cam) == pytest.approx(np.median(cov["range_m"]), rel=1e-3)
    # the reference has no hint: its pose is fixed
    ref = sensor_coverage(sim.dataset.sensor("lidar1"), fitted, centres, boards)
    assert "hint" not in ref and "reference" in ref["note"]


# --------------------------------------------------------------------------------------------
# the page


def _cells(html: str, table_id: str) -> dict[str, dict[str, str]]:
    section = html.split(f'<section id="{table_id}">', 1)[1].split("</section>", 1)[0]
    out: dict[str, dict[str, str]] = {}
    for name, row in re.findall(r'<tr data-sensor="([^"]+)">(.*?)</tr>', section, re.S):
        out[name] = dict(re.findall(r'<td data-key="([^"]+)">([^<]*)</td>', row))
    return out


def test_page_numbers_equal_calibration_yaml(fitted, sim, tmp_path):
    write_results(fitted, tmp_path)
    write_report(calibration_report(fitted, sim.dataset), tmp_path)
    cal = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    html = (tmp_path / "report.html").read_text()
    cells = _cells(html, "poses")
    assert set(cells) == set(cal["sensors"])
    for name, s in cal["sensors"].items():
        for i, k in enumerate(("x_m", "y_m", "z_m")):
            assert cells[name][k] == f"{s['xyz_m'][i]:.4f}"
            assert cells[name][f"std_{k}"] == ("bnd" if k[0] in s["bounded"] else f"{s['std'][k] * 1000:.1f}")
        for i, k in enumerate(("roll_deg", "pitch_deg", "yaw_deg")):
            assert cells[name][k] == f"{s['rpy_deg'][i]:.3f}"
            bounded = k.split("_")[0] in s["bounded"]
            assert cells[name][f"std_{k}"] == ("bnd" if bounded else f"{s['std'][k]:.2f}")
    assert "radar1" in cal["sensors"] and cells["radar1"]["std_z_m"] == "bnd"
    # the verdict comes first, before any table or figure
    assert html.index('id="verdict"') < html.index('id="poses"') < html.index('id="residuals"')
    assert f"{cal['verdict']['status']}:" in html


def test_page_is_self_contained(fitted, sim):
    html = render_report(json.loads(report_json_text(calibration_report(fitted, sim.dataset))))
    assert "Content-Security-Policy" in html and "default-src 'none'" in html
    # nothing is loaded from anywhere: no src/href attributes except data: URIs
    tags = re.findall(r"<(?:script|link|img|iframe)\b[^>]*>", html)
    assert not [t for t in tags if re.search(r"\b(src|href)=\"(?!data:)", t)], tags
    assert html.count("<script>") == 2 and "Plotly.newPlot" in html
    n = int(re.search(r'data-figures="(\d+)"', html).group(1))
    assert n == len(re.findall(r'<div id="fig-[^"]+" class="figure">', html)) >= 5


def test_the_embedded_plotly_js_has_every_trace_type_the_pages_draw(fitted, sim):
    from rigcal.report import figures, study_page
    from rigcal.report.page import BUNDLE, BUNDLE_TRACES, plotly_js

    text, version = plotly_js()  # rigcal's partial build, committed package data
    assert text == BUNDLE.read_text(encoding="utf-8")
    assert re.fullmatch(r"\d+\.\d+\.\d+", version) and "</script" not in text.lower()
    drawn = {t.get("type", "scatter") for f in all_figures(calibration_report(fitted, sim.dataset)) for t in f["data"]}
    assert {"scatter", "bar", "scatter3d", "mesh3d"} <= drawn <= BUNDLE_TRACES
    # every trace type written anywhere in the figure code (error bars' "data", axes' "log" aside)
    source = Path(figures.__file__).read_text() + Path(study_page.__file__).read_text()
    assert set(re.findall(r'"type": "(\w+)"', source)) - {"data", "log"} <= BUNDLE_TRACES


def test_an_unreadable_plotly_bundle_is_one_clear_error(monkeypatch, tmp_path):
    from rigcal.report import page

    monkeypatch.setattr(page, "BUNDLE", tmp_path / "absent.min.js")
    page.plotly_js.cache_clear()
    try:
        with pytest.raises(InputError, match=r"absent\.min\.js: cannot read rigcal's plotly\.js .*reinstall rigcal"):
            page.plotly_js()
    finally:
        page.plotly_js.cache_clear()


def test_figures_count_every_board(fitted, sim):
    figs = {f["id"]: f for f in all_figures(calibration_report(fitted, sim.dataset))}
    bars = [t for t in figs["fig-boards"]["data"] if t["type"] == "bar"]
    assert [t["name"] for t in bars] == list(fitted.per_board_m)
    for t in bars:
        assert len(t["x"]) == len(fitted.per_board_m[t["name"]])
        np.testing.assert_allclose(t["y"], [fitted.per_board_m[t["name"]][k] * 1000 for k in t["x"]], atol=1e-3)
    rmse = figs["fig-rmse"]["data"]
    assert [t["name"] for t in rmse][1].startswith("cross-validated")
    assert set(f"fig-coverage-{n}" for n in ("lidar1", "camera1", "radar1")) <= set(figs)


def test_flagged_result_says_so_first(sim):
    result = _truth_result(sim)
    from rigcal.problem.consistency import Check, Verdict

    flagged = CalibrationResult(**{**result.__dict__, "verdict": Verdict((Check("pairs", "fail", "way off"),))})
    html = render_report(json.loads(report_json_text(calibration_report(flagged, sim.dataset))))
    head = html.split('id="poses"', 1)[0]
    assert "FLAGGED: the result contradicts its own noise model (pairs)" in head
    assert 'class="verdict flagged"' in head


def test_malformed_report_data_is_an_input_error():
    data = {"format": "rigcal-report", "version": 1, "kind": "calibrate", "result": {"sensors": {"a": {}}}}
    with pytest.raises(InputError, match=r"src.json: malformed report data \(KeyError"):
        render_report(data, "src.json")
    with pytest.raises(InputError, match="result: expected the calibration result"):
        check_report_data({**data, "result": []}, "x")


def test_pose_rows_mark_bounded_directions():
    rows = pose_rows({"r": {"xyz_m": [1, 2, 3], "rpy_deg": [0, 0, 0],
                            "std": {k: 0.001 for k in STD_KEYS}, "bounded": {"z": [-1, 1], "roll": [-2, 2]}}})
    cells = dict(rows[0]["cells"])
    assert cells["std_z_m"] == "bnd" and cells["std_roll_deg"] == "bnd"
    assert cells["std_x_m"] == "1.0" and cells["x_m"] == "1.0000"


def test_hand_edited_report_data_cannot_break_out_of_the_page(fitted, sim):
    data = json.loads(report_json_text(calibration_report(fitted, sim.dataset)))
    evil = "</script><script>alert(1)</script><!--"
    data["result"]["warnings"] = [evil]
    data["scene"]["sensors"][0]["hover"] = [evil] * len(data["scene"]["sensors"][0]["hover"])
    html = render_report(data)
    assert evil not in html
    assert "&lt;/script&gt;&lt;script&gt;alert(1)" in html  # the warning, escaped
    figures = html.split('id="figure-data">', 1)[1].split("</script>", 1)[0]
    assert "<" not in figures
    # once parsed, the same text with its tags inert (plotly.js shows "&lt;" as "<", never as a tag)
    assert "&lt;/script&gt;&lt;script&gt;alert(1)&lt;/script&gt;<!--" in json.loads(figures)[-1]["data"][0]["text"]
    # a check without its detail: one error naming the file, no traceback
    data["result"]["verdict"]["checks"] = [{"name": "pairs", "status": "pass"}]
    with pytest.raises(InputError, match=r"r.json: malformed report data \(UndefinedError"):
        render_report(data, "r.json")
