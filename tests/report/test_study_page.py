"""study.html from a study's JSON: tables of every row, Table III and Figs. 7/8 as figures with
the paper's values, one-line errors on malformed JSON, and `rigcal report STUDY_DIR`."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
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


def _meta_rows(html: str) -> dict[str, str]:
    table = html.split('<table id="meta">', 1)[1].split("</table>", 1)[0]
    return dict(re.findall(r'<th class="text">(.*?)</th><td class="text">(.*?)</td>', table))


def test_page_shows_no_absolute_path():
    """study.html is shared: the manifest the study ran on is shown by its name, not by where it
    was on the machine that ran it (study.json keeps what was given); other text is untouched."""
    study = make_study()
    study["meta"].update(manifest="/home/someone/rigs/prius/rig.yaml", scheduler="tcp://10.0.0.5:8786",
                         windows="C:\\Users\\someone\\rig.yaml", relative="examples/prius/rig.yaml")
    html = render_study(study)
    meta = _meta_rows(html)
    assert meta["manifest"] == "rig.yaml" and meta["windows"] == "rig.yaml"
    assert meta["relative"] == "examples/prius/rig.yaml" and meta["scheduler"] == "tcp://10.0.0.5:8786"
    assert "/home/someone" not in html and "Users" not in html


def test_meta_mappings_are_shown_and_unset_values_left_out():
    """The draws each table used (a mapping) are shown, not a bare '-'; a value that is not set
    (None, as in an older study.json) is left out."""
    study = make_study()
    study["meta"].update(draws={"III": 200, "fig7": 100, "fig8": 100}, unset=None,
                         wall_time_s={"II": 0.4, "III + fig7 + fig8": 491.2}, fig7_k=[3, 4, 5])
    meta = _meta_rows(render_study(study))
    assert meta["draws"] == "III: 200, fig7: 100, fig8: 100"
    assert meta["wall_time_s"] == "II: 0.40, III + fig7 + fig8: 491.20"
    assert "unset" not in meta and "fig7_k" not in meta and "-" not in meta.values()


def test_notes_are_a_section_of_the_page():
    study = make_study()
    study["meta"]["notes"] = ["Why the paper's MCPE rows differ: <evidence>.", "Second note."]
    html = render_study(study)
    notes = html.split('<section id="notes">', 1)[1].split("</section>", 1)[0]
    assert notes.count('<p class="note">') == 2 and "&lt;evidence&gt;" in notes  # escaped
    assert "notes" not in _meta_rows(html)
    assert '<section id="notes">' not in render_study(make_study())  # none, no section


def test_prius_meta_names_the_draws_each_table_used():
    from rigcal.study.prius import DEFAULT_DRAWS, MCPE_NOTE, study_meta

    meta = study_meta("examples/prius/rig.yaml", ("II", "III", "fig7", "fig8"), None, 10, 0, "serial", {})
    assert meta["draws"] == {"III": 200, "fig7": 100, "fig8": 100} == DEFAULT_DRAWS
    assert meta["manifest"] == "examples/prius/rig.yaml" and meta["notes"] == [MCPE_NOTE]
    assert study_meta("m.yaml", ("fig7",), 3, 10, 0, "serial", {})["draws"] == {"fig7": 3}
    only_ii = study_meta("m.yaml", ("II",), None, 10, 0, "serial", {"II": 0.4})
    assert "draws" not in only_ii and "notes" not in only_ii  # Table II draws nothing
    rows = _meta_rows(render_study({"meta": meta, "rows": make_study()["rows"]}))
    assert rows["draws"] == "III: 200, fig7: 100, fig8: 100"
    for evidence in ("33 of 200", "multi_sensor_calibration"):
        assert evidence in MCPE_NOTE


def test_rigcal_study_prius_page_has_no_absolute_path_and_the_draws(tmp_path: Path):
    """End to end on a simulated rig (12 boards) given by its absolute path."""
    from rigcal.io.dataset.manifest import write_dataset
    from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

    rng = np.random.default_rng(5)
    sensors = prius_like_rig()
    manifest = write_dataset(simulate(sensors, make_rig_placements(rng, sensors, 12, min_fraction=1.0),
                                      rng=rng).dataset, tmp_path / "data")
    out = tmp_path / "study"
    assert run(["study", "prius", str(manifest.resolve()), "--table", "III", "--draws", "1", "--boards", "5",
                "--scheduler", "serial", "--out", str(out)]) == 0
    html = (out / "study.html").read_text()
    assert str(tmp_path) not in html
    meta = _meta_rows(html)
    assert meta["manifest"] == manifest.name and meta["draws"] == "III: 1"
    assert "MCPE" in html.split('<section id="notes">', 1)[1].split("</section>", 1)[0]
