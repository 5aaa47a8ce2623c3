"""Writing and reading the report files beside a result: ``report.json`` (the report data,
:mod:`rigcal.report.data`) and ``report.html`` (:mod:`rigcal.report.page`).

:func:`write_report` writes both (atomically, texts built first); :func:`read_report_data`
reads a result folder back: its ``report.json``, or - for a folder written before reports
existed - the result file (``absolute.yaml`` or ``calibration.yaml``) alone.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from rigcal.errors import InputError
from rigcal.io._text import json_safe
from rigcal.io.atomic import atomic_write_text

REPORT_JSON_NAME = "report.json"
REPORT_HTML_NAME = "report.html"


def report_json_text(data: Mapping[str, Any]) -> str:
    """Strict, compact JSON of the report data (NaN and infinities as null)."""
    return json.dumps(json_safe(dict(data)), separators=(",", ":"), allow_nan=False) + "\n"


def write_report(data: Mapping[str, Any], out_dir: str | os.PathLike[str],
                 html_name: str = REPORT_HTML_NAME) -> list[Path]:
    """Write ``report.json`` and ``report.html`` into ``out_dir``; returns their paths. The page
    is rendered from the JSON text's data, exactly what ``rigcal report`` rebuilds it from."""
    from rigcal.report.page import render_report

    out = Path(out_dir)
    text = report_json_text(data)
    html = render_report(json.loads(text), str(out / REPORT_JSON_NAME))
    return [atomic_write_text(out / REPORT_JSON_NAME, text), atomic_write_text(out / html_name, html)]


def write_calibration_set(result, dataset, out_dir: str | os.PathLike[str],
                          raw_images: list | None = None, urdf=None) -> list[Path]:
    """A calibration's whole output: ``calibration.yaml``, ``<sensor>.yaml``,
    ``calibration.launch`` (:func:`rigcal.io.results.calibration.write_results`) and the report
    (``report.json``, ``report.html``) of ``result`` on ``dataset``, with the raw-data images
    (:func:`rigcal.report.raw.raw_overlays`) when given. What ``rigcal calibrate``, ``calibrate
    --batch`` and the demo write. ``urdf`` (a parsed URDF, e.g. the robot's given as
    ``--initial``) names the frames in the result files (:mod:`rigcal.io.results.frames`)."""
    from rigcal.io.results.calibration import write_results
    from rigcal.report.data import calibration_report
    from rigcal.report.raw import with_raw

    report = calibration_report(result, dataset)
    if raw_images is not None:
        report = with_raw(report, raw_images)
    return write_results(result, out_dir, urdf) + write_report(report, out_dir)


def read_report_data(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The report data of a result folder of ``rigcal calibrate``, ``mocap`` or ``absolute``:
    its ``report.json``; without one, the result file alone (no detections). InputError naming
    the folder and what was expected when it holds neither."""
    from rigcal.io._text import load_json, load_yaml, read_text
    from rigcal.report.data import result_only_report
    from rigcal.report.page import check_report_data

    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder; expected the output folder of rigcal calibrate, "
                         "mocap or absolute")
    path = root / REPORT_JSON_NAME
    if path.exists():
        data = load_json(read_text(path, "report data"), str(path))
        return dict(check_report_data(data, str(path)))
    absolute, calibration = root / "absolute.yaml", root / "calibration.yaml"
    if absolute.exists():
        abs_data = load_yaml(read_text(absolute, "absolute calibration"), str(absolute))
        if not isinstance(abs_data, dict) or not isinstance(abs_data.get("relative"), dict) \
                or not isinstance(abs_data.get("sensors"), dict):
            raise InputError(f"{absolute}: expected rigcal's absolute.yaml (sensors and relative)")
        return result_only_report("absolute", abs_data["relative"], abs_data)
    if calibration.exists():
        cal = load_yaml(read_text(calibration, "calibration result"), str(calibration))
        if not isinstance(cal, dict) or not isinstance(cal.get("sensors"), dict) or "reference" not in cal:
            raise InputError(f"{calibration}: expected rigcal's calibration.yaml (reference and sensors); "
                             "another tool's file cannot be reported")
        kind = "mocap" if (root / "extrinsics.json").exists() else "calibrate"
        return result_only_report(kind, cal)
    raise InputError(f"{root}: not a rigcal result folder: expected {REPORT_JSON_NAME} (or calibration.yaml / "
                     "absolute.yaml) as written by rigcal calibrate, mocap or absolute")


__all__ = ["REPORT_HTML_NAME", "REPORT_JSON_NAME", "read_report_data", "report_json_text", "write_report"]
