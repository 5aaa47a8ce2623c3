"""The benchmark scripts whose figures the docs quote run as written (a tiny case each)."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _run(monkeypatch, capsys, script: str, *args: str) -> str:
    """What ``python benchmarks/SCRIPT ARGS`` prints; fails unless it exits 0."""
    monkeypatch.setattr(sys, "argv", [script, *args])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(BENCH / script), run_name="__main__")
    assert exc.value.code == 0
    return capsys.readouterr().out


@pytest.mark.slow
def test_the_rendered_sessions_benchmark_prints_every_sensor_and_the_summary(monkeypatch, capsys):
    out = _run(monkeypatch, capsys, "mocap_sessions.py", "--seeds", "7", "--holds", "4")
    rows = [line.split() for line in out.splitlines() if line.startswith("   7 ")]
    assert {r[1] for r in rows} == {"lidar1", "camera1", "camera2"}
    for r in rows:
        assert float(r[6]) >= 0.0 and r[7] in ("yes", "NO")  # NEES6 and inside
        if r[1].startswith("camera"):
            assert float(r[8]) > 0.0  # how much the holds' errors share
    assert "lidar: " in out and "camera: " in out and "median NEES/dof" in out and "camera shared: " in out


@pytest.mark.slow
def test_the_corner_bias_benchmark_prints_a_row_per_square_size(monkeypatch, capsys):
    out = _run(monkeypatch, capsys, "corner_bias.py", "--views", "8", "--frames", "1")
    rows = [line.split("|") for line in out.splitlines() if "|" in line and not line.lstrip().startswith("square")]
    assert rows, out
    for r in rows:
        sb_rms, subpix_rms = float(r[1].split()[0]), float(r[2].split()[0])
        assert 0.0 < sb_rms < 0.5 and 0.0 < subpix_rms < 0.5  # corners found within half a pixel


def test_the_coverage_benchmark_prints_counts_with_their_interval_and_dumps_every_nees(monkeypatch, capsys, tmp_path):
    # one motion-capture session under a clock offset: the fraction as "k of n" with its 95 %
    # Wilson interval (for n = 1: 0.207-1.000 or 0.000-0.793), the offsets said in words (none
    # determined is not "nan ms"), and the JSON with one NEES per estimate
    import json

    dump = tmp_path / "nees.json"
    out = _run(monkeypatch, capsys, "coverage.py", "--trials", "0", "--mocap-trials", "1", "--mocap-holds", "4",
               "--mocap-models", "clock_offset", "--mocap-json", str(dump))
    line = next(x for x in out.splitlines() if x.lstrip().startswith("clock_offset"))
    for kind in ("lidar", "camera"):
        part = line.split(kind + " ", 1)[1]
        assert ("[1 of 1, 95 % interval 0.207-1.000]" in part.split(")")[0]
                or "[0 of 1, 95 % interval 0.000-0.793]" in part.split(")")[0]), line
    assert "nan" not in line and ("none determined" in line or " determined, the largest error " in line)
    data = json.loads(dump.read_text())
    assert data["seed"] == 0 and data["holds"] == 4 and data["hold_sigma_floor"] == [0.0, 0.0]
    assert data["estimator"] == "ls"  # the default
    errors = data["errors_m"]["clock_offset"]
    assert {k: len(v) for k, v in errors.items()} == {"lidar": 1, "camera": 1}
    for kind, (e,) in errors.items():  # the line's median of one estimate, in mm
        assert 0.0 < e < 0.05 and f"error {1000 * e:.2f} mm" in line.split(kind + " ", 1)[1]
    assert {k: len(v) for k, v in data["nees_3dof"]["clock_offset"].items()} == {"lidar": 1, "camera": 1}
    nees = data["nees_6dof"]["clock_offset"]
    assert set(nees) == {"lidar", "camera"}
    assert {k: len(v) for k, v in data["pooled"]["clock_offset"].items()} == {"lidar": 1, "camera": 1}
    for kind, values in nees.items():
        assert len(values) == 1 and values[0] >= 0.0
        inside = values[0] <= 12.5916  # chi-square 95 % for 6 DOF
        assert (f"[{int(inside)} of 1," in line.split(kind + " ", 1)[1]), (kind, values, line)


def test_the_coverage_benchmark_refuses_an_unwritable_json_path_before_it_runs(monkeypatch, capsys, tmp_path):
    # a folder where the file should go: one line naming it, exit 2, no session run, nothing written
    from rigcal.study import coverage

    monkeypatch.setattr(coverage, "mocap_coverage", lambda *a, **k: pytest.fail("ran before checking the path"))
    monkeypatch.setattr(sys, "argv", ["coverage.py", "--trials", "0", "--mocap-trials", "1",
                                      "--mocap-json", str(tmp_path)])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(BENCH / "coverage.py"), run_name="__main__")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--mocap-json" in err[0] and str(tmp_path) in err[0] and "is a directory" in err[0]
    assert list(tmp_path.iterdir()) == []


def test_the_coverage_benchmark_pools_runs_into_the_docs_table(monkeypatch, capsys, tmp_path):
    # two seeds' files, one model each: one row per model with the counts of both runs together
    import json

    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"seed": 0, "holds": 8, "nees_6dof": {"hold_bias": {"lidar": [3.0, 20.0], "camera": [6.0]}},
                             "nees_3dof": {"hold_bias": {"lidar": [1.0, 9.0], "camera": [1.0]}}, "estimator": "gls",
                             "errors_m": {"hold_bias": {"lidar": [0.001, 0.004], "camera": [0.002]}}}))
    b.write_text(json.dumps({"seed": 1, "holds": 8, "nees_6dof": {"hold_bias": {"lidar": [4.0], "camera": [5.0]}},
                             "nees_3dof": {"hold_bias": {"lidar": [1.0]}}, "estimator": "gls",
                             "errors_m": {"hold_bias": {"lidar": [0.003]}}}))  # the camera's not written
    out = _run(monkeypatch, capsys, "coverage.py", "--pool", str(a), str(b))
    assert "motion capture (gls)" in out and "pooled over seeds 0, 1" in out
    row = next(x for x in out.splitlines() if x.startswith("| `hold_bias`"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1].startswith("0.667 (2 of 3; ") and cells[2] == "0.667" and cells[3] == "0.67 (1.92, 0.67)"
    assert cells[4] == "3.00 mm"
    assert cells[5].startswith("1.000 (2 of 2; ") and cells[6] == "1.000 (of 1)" and cells[7] == "0.92 (1.00, 0.83)"
    assert cells[8] == "2.00 mm (of 1)"
    assert "`pixel`" not in out  # no run had it


def test_the_coverage_benchmark_refuses_a_file_it_cannot_pool_in_one_line(monkeypatch, capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    monkeypatch.setattr(sys, "argv", ["coverage.py", "--pool", str(bad)])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(BENCH / "coverage.py"), run_name="__main__")
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "--mocap-json" in err[0]
