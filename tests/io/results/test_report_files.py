"""report.json and report.html beside a result (rigcal.io.results.report): written from the
report data, read back from report.json, or from calibration.yaml alone for a folder written
before reports; folders that are not results are named in the error."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.results.calibration import write_results
from rigcal.io.results.report import read_report_data, write_report
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.report.data import calibration_report
from rigcal.report.page import render_report
from rigcal.sim import make_rig_placements, prius_like_rig, simulate


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)


@pytest.fixture(scope="module")
def fitted(sim):
    return calibrate(sim.dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=0))


def _pose_cell(html: str, sensor: str, key: str) -> str:
    section = html.split('<section id="poses">', 1)[1].split("</section>", 1)[0]
    row = section.split(f'data-sensor="{sensor}"', 1)[1].split("</tr>", 1)[0]
    return row.split(f'data-key="{key}">', 1)[1].split("<", 1)[0]




def test_read_back_from_report_json_and_from_calibration_yaml(fitted, sim, tmp_path):
    write_results(fitted, tmp_path / "a")
    write_report(calibration_report(fitted, sim.dataset), tmp_path / "a")
    data = read_report_data(tmp_path / "a")
    assert data["kind"] == "calibrate" and data["scene"]["sensors"]
    assert render_report(data) == (tmp_path / "a" / "report.html").read_text()
    # a folder from before reports: the result file alone
    write_results(fitted, tmp_path / "b")
    data = read_report_data(tmp_path / "b")
    assert "scene" not in data and "not stored" in data["note"]
    html = render_report(data)
    assert _pose_cell(html, "camera1", "x_m") == f"{fitted.sensors['camera1'].xyz_m[0]:.4f}"


@pytest.mark.parametrize(("setup", "message"), [
    (lambda d: None, r"not a rigcal result folder: expected report.json"),
    (lambda d: (d / "report.json").write_text("{nope"), r"report.json: not valid JSON"),
    (lambda d: (d / "report.json").write_text('{"format": "other"}'), r"report.json: format: expected 'rigcal-report'"),
    (lambda d: (d / "report.json").write_text('{"format": "rigcal-report", "version": 9}'), r"version: expected 1"),
    (lambda d: (d / "report.json").write_text('{"format": "rigcal-report", "version": 1, "kind": "x"}'),
     r"kind: expected one of calibrate, mocap, absolute"),
    (lambda d: (d / "calibration.yaml").write_text("source: a\ntarget: b\n"), r"calibration.yaml: expected rigcal's"),
])
def test_bad_result_folders_are_named(tmp_path, setup, message):
    setup(tmp_path)
    with pytest.raises(InputError, match=message):
        read_report_data(tmp_path)


def test_not_a_folder(tmp_path):
    (tmp_path / "f.txt").write_text("x")
    with pytest.raises(InputError, match=r"f.txt: not a folder"):
        read_report_data(tmp_path / "f.txt")
