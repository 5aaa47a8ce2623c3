"""report.html written by `rigcal calibrate` and `rigcal absolute` (the demo), and rebuilt by
`rigcal report RESULT_DIR`; one-line errors for folders that are not results. (`rigcal mocap`'s
report: tests/cli/test_mocap_cli.py; the page in a browser: tests/report/test_report_browser.py.)"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, move_boards, prius_like_rig, simulate


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(5)
    sensors = prius_like_rig()
    return simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0), rng=rng)


def test_calibrate_writes_the_report_and_report_rebuilds_it(tmp_path, sim, capsys):
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    out = tmp_path / "out"
    assert run(["calibrate", str(manifest), "--cv-folds", "2", "--out", str(out)]) == 0
    html = (out / "report.html").read_text()
    data = json.loads((out / "report.json").read_text())
    assert data["format"] == "rigcal-report" and data["kind"] == "calibrate"
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert data["result"]["sensors"]["camera1"]["xyz_m"] == cal["sensors"]["camera1"]["xyz_m"]
    assert [s["name"] for s in data["scene"]["sensors"]] == ["lidar1", "camera1", "radar1"]
    capsys.readouterr()
    # rebuilt from the folder alone: the same page
    (out / "report.html").unlink()
    assert run(["report", str(out)]) == 0
    assert (out / "report.html").read_text() == html
    assert f"report written to {out / 'report.html'}" in capsys.readouterr().out
    assert run(["report", str(out), "--out", str(tmp_path / "elsewhere" / "r.html")]) == 0
    assert (tmp_path / "elsewhere" / "r.html").read_text() == html


def test_a_flagged_result_written_with_force_says_so_first(tmp_path, sim, capsys):
    bad = write_dataset(move_boards(sim.dataset, "lidar1", [3], [0.8, 0.0, 0.0]), tmp_path / "bad")
    out = tmp_path / "out"
    code = run(["calibrate", str(bad), "--keep-outliers", "--cv-folds", "0", "--force", "--out", str(out)])
    assert code == 3
    html = (out / "report.html").read_text()
    head = html.split('id="poses"', 1)[0]
    assert 'class="verdict flagged"' in head and "FLAGGED" in head and "board 3" in head


@pytest.mark.parametrize(("make", "needle"), [
    (lambda p: p.mkdir(), "not a rigcal result folder: expected report.json"),
    (lambda p: None, "not a folder"),
    (lambda p: (p.mkdir(), (p / "report.json").write_text("[1, 2]")), "report.json: expected a rigcal report"),
])
def test_report_on_something_else_is_one_line(tmp_path, capsys, make, needle):
    target = tmp_path / "folder"
    make(target)
    assert run(["report", str(target)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rigcal: error: ") and "Traceback" not in err
    assert str(target) in err and needle in err
    assert not (target / "report.html").exists()


def test_absolute_writes_a_report_with_the_body_frame_poses(tmp_path, capsys):
    assert run(["demo", "--absolute", "--boards", "8", "--out", str(tmp_path / "d")]) == 0
    capsys.readouterr()
    results = tmp_path / "d" / "absolute"
    data = json.loads((results / "report.json").read_text())
    assert data["kind"] == "absolute" and data["absolute"]["body_frame"]["name"] == "base_link"
    html = (results / "report.html").read_text()
    body = html.split('<section id="body-poses">', 1)[1].split("</section>", 1)[0]
    absolute = yaml.safe_load((results / "absolute.yaml").read_text())
    for name, s in absolute["sensors"].items():
        assert f'<td data-key="x_m">{s["xyz_m"][0]:.4f}</td>' in body.split(f'data-sensor="{name}"', 1)[1]
    # and rebuilt through the command
    (results / "report.html").unlink()
    assert run(["report", str(results)]) == 0
    assert (results / "report.html").read_text() == html


def test_report_of_a_folder_from_before_reports(tmp_path, sim, capsys):
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    out = tmp_path / "out"
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--out", str(out)]) == 0
    (out / "report.json").unlink()
    (out / "report.html").unlink()
    capsys.readouterr()
    assert run(["report", str(out)]) == 0
    assert "detections were not stored" in capsys.readouterr().out
    assert 'id="poses"' in (out / "report.html").read_text()


def test_help_has_an_example(capsys):
    with pytest.raises(SystemExit) as exc:
        run(["report", "--help"])
    assert exc.value.code == 0
    assert "rigcal report results/" in capsys.readouterr().out


def test_report_json_paths_are_portable(tmp_path, sim):
    """report.json holds no absolute path of the machine that wrote it."""
    manifest = write_dataset(sim.dataset, tmp_path / "data")
    out = tmp_path / "out"
    assert run(["calibrate", str(manifest), "--cv-folds", "0", "--out", str(out)]) == 0
    assert str(tmp_path) not in (out / "report.json").read_text()
    assert Path(out / "report.html").stat().st_size > 1_000_000  # plotly.js is inside
