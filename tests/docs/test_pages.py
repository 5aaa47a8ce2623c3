"""docs/install.md and docs/foxglove.md: their tested command blocks run as written, in order,
in one folder, and leave what the pages say."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from rigcal.cli.main import run

DOCS = Path(__file__).resolve().parents[2] / "docs"


def commands_of(page: str) -> list[list[str]]:
    text = (DOCS / page).read_text()
    blocks = re.findall(r"<!-- tested:.*?-->\s*```bash\n(.*?)```\s*<!-- /tested -->", text, re.S)
    assert blocks, f"docs/{page} lost its tested block"
    return [shlex.split(ln)[1:] for b in blocks for ln in b.splitlines() if ln.startswith("rigcal ")]


def _run_page(page: str, tmp_path, monkeypatch, capsys) -> str:
    monkeypatch.chdir(tmp_path)
    for argv in commands_of(page):
        assert run(argv) == 0, (argv, capsys.readouterr().err)
    return capsys.readouterr()


def test_install_page_runs_as_written(tmp_path, monkeypatch, capsys):
    pytest.importorskip("foxglove")
    captured = _run_page("install.md", tmp_path, monkeypatch, capsys)
    assert captured.out.count("open this page in a browser (the other modes: mcpe/, pse/):") == 1
    assert "demo_out/fcpe/report.html" in captured.out
    stages = captured.err  # -v: each stage with its time, as the page shows
    for text in ("rigcal calibrate ...", "reading 3 sensors x 29 boards:", "PSE fit with outlier screening",
                 "cross-validation (5 folds):", "rigcal calibrate: "):
        assert text in stages, text
    assert (tmp_path / "results" / "report.html").stat().st_size <= 2_000_000
    assert (tmp_path / "scene.mcap").stat().st_size > 0


def test_foxglove_page_runs_as_written(tmp_path, monkeypatch, capsys):
    pytest.importorskip("foxglove")
    reader = pytest.importorskip("mcap.reader")
    _run_page("foxglove.md", tmp_path, monkeypatch, capsys)
    topics = {}
    for name in ("tree.mcap", "scene.mcap"):
        with open(tmp_path / name, "rb") as f:
            summary = reader.make_reader(f).get_summary()
            topics[name] = {c.topic: c for c in summary.channels.values()}
    assert set(topics["tree.mcap"]) == {"/tf_static"}
    assert set(topics["scene.mcap"]) == {"/tf_static", "/rigcal/residuals", "/rigcal/detections/lidar1",
                                         "/rigcal/detections/camera1", "/rigcal/detections/radar1"}
    page = (DOCS / "foxglove.md").read_text()
    for topic in topics["scene.mcap"]:  # every topic written is documented
        assert f"`{topic.replace('lidar1', '<sensor>').replace('camera1', '<sensor>').replace('radar1', '<sensor>')}`" in page
