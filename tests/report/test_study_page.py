"""study.html from a study's JSON: tables of every row, Table III and Figs. 7/8 as figures with
the paper's values, one-line errors on malformed JSON, and `rigcal report STUDY_DIR`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rigcal.cli.main import run
from rigcal.errors import InputError
from rigcal.report.study_page import check_study, render_study, study_figures, tables


def make_study() -> dict:
    rows = []
    for cfg in ("FCPE", "PSE"):
        for pair in ("lidar1-camera1", "lidar1-radar1"):
            base = dict(config=cfg, mode=cfg.lower(), reference=None, pair=pair, heldout_median_mm=None,
                        heldout_mad_mm=None, paper_spread_mm=None, failures=0)
            rows.append({**base, "table": "III", "median_mm": 16.25, "mad_mm": 0.31, "paper_mm": 16.1,
                         "draws": 10})
            for k in (3, 5, 10):
                rows.append({**base, "table": "fig7", "k": k, "median_mm": 30.0 / k, "mad_mm": 1.0,
                             "paper_mm": 20.0 if k == 10 else None, "draws": 5})
            for s in (0.0, 0.01, 0.02):
                rows.append({**base, "table": "fig8", "sigma_m": s, "median_mm": 16.0 + 500 * s,
                             "mad_mm": 0.5, "paper_mm": None, "draws": 5})
    rows.append({"table": "mocap", "target": "diamond", "sensor": "lidar", "median_mm": 2.08, "trials": 12})
    return {"meta": {"study": "prius", "seed": 0, "draws": 10}, "rows": rows}


def test_tables_group_rows_and_show_their_numbers():
    t = {x["title"]: x for x in tables(make_study()["rows"])}
    assert list(t) == ["Table III", "Fig. 7", "Fig. 8", "mocap"]
    iii = t["Table III"]
    assert iii["columns"][:2] == ["config", "mode"] and "reference" not in iii["columns"]  # all None
    assert len(iii["rows"]) == 4 and iii["rows"][0][iii["columns"].index("median_mm")] == "16.25"
    assert t["Fig. 8"]["rows"][1][t["Fig. 8"]["columns"].index("sigma_m")] == "10 mm"
    assert t["mocap"]["columns"] == ["target", "sensor", "median_mm", "trials"]


def test_figures_follow_the_rows_with_the_paper_values():
    figs = {f["id"]: f for f in study_figures(make_study()["rows"])}
    assert list(figs) == ["fig-table-iii", "fig-fig7", "fig-fig8"]
    bars = [t for t in figs["fig-table-iii"]["data"] if t["type"] == "bar"]
    assert [t["name"] for t in bars] == ["lidar1-camera1", "lidar1-radar1"]
    assert bars[0]["y"] == [16.25, 16.25] and bars[0]["error_y"]["array"] == [0.31, 0.31]
    lines = [t for t in figs["fig-fig7"]["data"] if t["mode"] == "lines+markers"]
    assert len(lines) == 4 and lines[0]["x"] == [3, 5, 10] and lines[0]["y"] == [10.0, 6.0, 3.0]
    paper = [t for t in figs["fig-fig7"]["data"] if t["name"].endswith("(paper)")]
    assert paper and paper[0]["x"] == [10] and paper[0]["y"] == [20.0]
    assert figs["fig-fig8"]["data"][0]["x"] == [0.0, 10.0, 20.0]  # sigma in mm


def test_page_is_self_contained_and_shows_every_row():
    html = render_study(make_study())
    assert "<script src" not in html and "http://" not in html.split("<script>")[0]
    assert html.count('<table class="rows"') == 4
    assert "16.25" in html and "prius" in html


@pytest.mark.parametrize("bad, match", [
    ([], "expected a study"),
    ({"rows": []}, "rows: expected a non-empty list"),
    ({"rows": [{"median_mm": 1.0}]}, r"rows\[0\]: expected a mapping with a 'table'"),
    ({"rows": [{"table": "III"}], "meta": 3}, "meta: expected a mapping"),
])
def test_malformed_studies_are_one_error(bad, match):
    with pytest.raises(InputError, match=match):
        check_study(bad, "s.json")


def test_rigcal_report_writes_study_html(tmp_path: Path, capsys):
    (tmp_path / "study.json").write_text(json.dumps(make_study()))
    assert run(["report", str(tmp_path)]) == 0
    assert (tmp_path / "study.html").is_file() and "study page written" in capsys.readouterr().out
    (tmp_path / "study.json").write_text("{not json")
    assert run(["report", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "study.json: not valid JSON" in err and "Traceback" not in err
