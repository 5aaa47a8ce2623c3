"""Writing what ``rigcal check`` and ``rigcal diff`` found: ``check.json`` / ``check.html`` of one
vehicle, ``diff.json``, and ``fleet.json`` / ``fleet.html`` of a fleet (:mod:`rigcal.report.check_page`).
Each file atomically; the texts are built before anything is written."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping
from urllib.parse import quote

from rigcal.io._text import json_safe
from rigcal.io.atomic import atomic_write_text

CHECK_JSON_NAME = "check.json"
CHECK_HTML_NAME = "check.html"
FLEET_JSON_NAME = "fleet.json"
FLEET_HTML_NAME = "fleet.html"


def json_text(data: Mapping[str, Any]) -> str:
    """Strict, indented JSON (NaN and infinities as null)."""
    return json.dumps(json_safe(dict(data)), indent=1, allow_nan=False) + "\n"


def write_check(data: Mapping[str, Any], out_dir: str | os.PathLike[str], title: str | None = None) -> list[Path]:
    """``check.json`` and ``check.html`` of a check's data (``CheckResult.to_dict()``) in
    ``out_dir``; the page is rendered from the JSON text's data."""
    from rigcal.report.check_page import render_check

    out = Path(out_dir)
    text = json_text(data)
    html = render_check(json.loads(text), str(out / CHECK_JSON_NAME), title)
    return [atomic_write_text(out / CHECK_JSON_NAME, text), atomic_write_text(out / CHECK_HTML_NAME, html)]


def vehicle_link(name: str) -> str:
    """The relative link from ``fleet.html`` to a vehicle's ``check.html`` (the folder name
    percent-encoded: a name is never read as a scheme or a path)."""
    return f"./{quote(name, safe='')}/{CHECK_HTML_NAME}"


def write_fleet(summary: Mapping[str, Any], out_dir: str | os.PathLike[str]) -> list[Path]:
    """``fleet.json`` and ``fleet.html`` of :func:`rigcal.report.check_page.fleet_summary`."""
    from rigcal.report.check_page import render_fleet

    out = Path(out_dir)
    text = json_text(summary)
    html = render_fleet(json.loads(text), str(out / FLEET_JSON_NAME))
    return [atomic_write_text(out / FLEET_JSON_NAME, text), atomic_write_text(out / FLEET_HTML_NAME, html)]


__all__ = ["CHECK_HTML_NAME", "CHECK_JSON_NAME", "FLEET_HTML_NAME", "FLEET_JSON_NAME", "json_text", "vehicle_link",
           "write_check", "write_fleet"]
