"""Hostile input to ``rigcal report`` (issue #22): an ``--out`` that is one of the result's own
files, a hand-edited report.json or study.json with a 5000-digit integer or deep nesting, and
markup in a sensor name that the page's plotly.js would act on (a CSS ``url(...)`` fetch, a
link)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

#: a sensor name as a hostile hand edit of report.json might write it
EVIL_NAME = ('lidar1<span style="background-image:url(http://127.0.0.1:9/x.png)">L</span>'
             '<a href="http://127.0.0.1:9/">here</a><img src=x onerror=alert(1)>')


@pytest.fixture(scope="module")
def result(tmp_path_factory) -> Path:
    rng = np.random.default_rng(23)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    root = tmp_path_factory.mktemp("report")
    manifest = write_dataset(sim.dataset, root / "data")
    from rigcal.cli.main import run

    assert run(["calibrate", str(manifest), "--out", str(root / "res"), "--cv-folds", "0"]) == 0
    return root / "res"


def _copy(result: Path, to: Path) -> Path:
    to.mkdir()
    for p in result.iterdir():
        (to / p.name).write_bytes(p.read_bytes())
    return to


@pytest.mark.parametrize("name", ["calibration.yaml", "report.json", "lidar1.yaml"])
def test_report_never_writes_over_its_inputs(cli, refused, result, tmp_path, name):
    """Was: exit 0, the calibration replaced by HTML."""
    res = _copy(result, tmp_path / "res")
    before = {p.name: p.read_bytes() for p in res.iterdir()}
    refused(cli("report", res, "--out", res / name), f"--out {res / name}", "is a file of the result folder", code=1)
    assert {p.name: p.read_bytes() for p in res.iterdir()} == before


def test_report_replaces_an_earlier_page_but_no_other_file(cli, refused, result, tmp_path):
    res = _copy(result, tmp_path / "res")
    page = tmp_path / "page.html"
    page.write_text("<!DOCTYPE html>\n<p>an earlier page</p>")
    assert cli("report", res, "--out", page).returncode == 0
    assert "rigcal report" in page.read_text()
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    refused(cli("report", res, "--out", notes), str(notes), "is not an HTML page", code=1)
    assert notes.read_text() == "mine"
    refused(cli("report", res, "--out", res), "is a folder", code=1)


@pytest.mark.parametrize("edit, expected", [
    (lambda text: text.replace('"num_boards":8', '"num_boards":' + "9" * 5000), "4300 digits"),
    (lambda text: '{"a":' * 100000 + "1" + "}" * 100000, "nested too deeply"),
    (lambda text: text[:-2] + ',"deep":' + "[" * 100 + "]" * 100 + "}\n", "nested more than 64 levels"),
])
def test_hand_edited_report_json_is_one_line_naming_it(cli, refused, result, tmp_path, edit, expected):
    """Was: a traceback (the integer), "input nested too deeply for 'report'" without the file."""
    res = _copy(result, tmp_path / "res")
    text = (res / "report.json").read_text()
    assert '"num_boards":8' in text
    (res / "report.json").write_text(edit(text))
    before = (res / "report.html").read_bytes()
    refused(cli("report", res), str(res / "report.json"), expected, code=1)
    assert (res / "report.html").read_bytes() == before


@pytest.mark.parametrize("doc, expected", [
    ('{"rows": [{"table": "III", "draws": ' + "7" * 5000 + "}]}", "4300 digits"),
    ("[" * 100000 + "]" * 100000, "nested too deeply"),
])
def test_hand_edited_study_json_is_one_line_naming_it(cli, refused, tmp_path, doc, expected):
    study = tmp_path / "study"
    study.mkdir()
    (study / "study.json").write_text(doc)
    refused(cli("report", study), str(study / "study.json"), expected, code=1)
    assert sorted(p.name for p in study.iterdir()) == ["study.json"]


def _strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from _strings(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _strings(v)


def evil_report(result: Path, to: Path) -> Path:
    """A copy of ``result`` whose report.json names lidar1 :data:`EVIL_NAME`, its page rebuilt."""
    res = _copy(result, to)
    text = (res / "report.json").read_text()
    (res / "report.json").write_text(text.replace('"lidar1"', json.dumps(EVIL_NAME)))
    from rigcal.cli.main import run

    assert run(["report", str(res)]) == 0
    return res


def test_markup_in_a_sensor_name_is_inert_in_every_context(result, tmp_path):
    """Was: plotly.js drew the name's <span style="...url(...)"> (14 blocked fetches on the
    shared data). The name is escaped in HTML text and attributes, and in the figures' JSON
    its tags are text (plotly.js shows &lt; as "<"): no tag with attributes is left."""
    res = evil_report(result, tmp_path / "res")
    html = (res / "report.html").read_text()
    assert EVIL_NAME not in html
    page, rest = html.split('<script type="application/json" id="figure-data">', 1)
    head = page.split("<script>", 1)[0]  # the page before the embedded plotly.js
    assert "<span style" not in head and "<a href" not in head and "<img src=x" not in head
    assert 'data-sensor="lidar1&lt;span style=&#34;background-image' in head  # an attribute, escaped
    figures = json.loads(rest.split("</script>", 1)[0])
    texts = list(_strings([(f["data"], f["layout"]) for f in figures]))  # what plotly.js draws
    assert any("lidar1&lt;span style=" in t for t in texts)
    tags = {m.group(1).strip().lower() for t in texts for m in re.finditer(r"<([^<>]*)>", t)}
    assert tags <= {"br", "extra", "/extra", "b", "/b"}, tags
    csp = re.search(r'http-equiv="Content-Security-Policy" content="([^"]+)"', html).group(1)
    assert "default-src 'none'" in csp and "http" not in csp and "base-uri 'none'" in csp
