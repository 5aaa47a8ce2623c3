"""``report.html``: one self-contained page from the report data (:mod:`rigcal.report.data`).

The page is a Jinja2 template (``templates/report.html.j2``, package data) with plotly.js
embedded once, inline - the partial build shipped inside rigcal's package (:data:`BUNDLE`,
committed with its licenses, rebuilt identically from ``tools/plotly-bundle``) - and the figures
(:mod:`rigcal.report.figures`) as JSON that a few lines hand to ``Plotly.newPlot``. It loads
nothing from any address (a Content-Security-Policy forbids it). The verdict and the tables
come before the script, and plotly.js is only started after the first frame, so they show at
once while the figures are drawn.

jinja2 is imported when a page is rendered; rigcal does not depend on the plotly Python package
(the figures are plain plotly.js JSON).
"""

from __future__ import annotations

import json
import math
import re
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

from rigcal.errors import InputError
from rigcal.report.data import FORMAT, KINDS, VERSION
from rigcal.report.figures import all_figures

TEMPLATE = "report.html.j2"
STD_KEYS = ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg")
#: plotly.js built with only the trace types the pages draw (:data:`BUNDLE_TRACES`), package data
#: made by ``tools/plotly-bundle``: 1.8 MB instead of 4.8 MB, and a browser starts it in a third
#: of the time of the full plotly.min.js (about 0.35 s instead of 1.0-1.2 s on the benchmark
#: machine), which was most of opening a report
BUNDLE = Path(__file__).parent / "js" / "plotly-rigcal.min.js"
BUNDLE_TRACES = frozenset({"scatter", "bar", "scatter3d", "mesh3d"})


def _version(text: str) -> str:
    head, marker = text[:400], "plotly.js v"
    return head.split(marker, 1)[1].split()[0] if marker in head else ""


@lru_cache(maxsize=1)
def plotly_js() -> tuple[str, str]:
    """(plotly.js text, its version): rigcal's partial build (:data:`BUNDLE`, package data).
    InputError when it cannot be read (a broken installation)."""
    try:
        text = BUNDLE.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{BUNDLE}: cannot read rigcal's plotly.js ({exc.strerror or exc}); "
                         "reinstall rigcal (the file is part of its package)") from None
    return text, _version(text)


def _fmt(x: Any, spec: str) -> str:
    return format(float(x), spec) if isinstance(x, (int, float)) and math.isfinite(x) else "-"


def pose_rows(sensors: Mapping[str, Any], rpy_std_decimals: int = 2) -> list[dict[str, Any]]:
    """Table rows: x, y, z [m] (4 decimals), roll, pitch, yaw [deg] (3), std x, y, z [mm] (1),
    std roll, pitch, yaw [deg] (``rpy_std_decimals``); ``bnd`` where a direction is only bounded
    - the precision of the terminal summary."""
    rows = []
    for name, s in sensors.items():
        xyz, rpy, std = s["xyz_m"], s["rpy_deg"], s.get("std", {})
        bounded = s.get("bounded", {}) or {}

        def sd(key: str, text: str) -> str:
            return "bnd" if key.split("_")[0] in bounded else text

        cells = [(k, _fmt(v, ".4f")) for k, v in zip(("x_m", "y_m", "z_m"), xyz)]
        cells += [(k, _fmt(v, ".3f")) for k, v in zip(("roll_deg", "pitch_deg", "yaw_deg"), rpy)]
        cells += [(f"std_{k}", sd(k, _fmt(std.get(k, math.nan) * 1000 if std.get(k) is not None else None, ".1f")))
                  for k in ("x_m", "y_m", "z_m")]
        cells += [(f"std_{k}", sd(k, _fmt(std.get(k), f".{rpy_std_decimals}f")))
                  for k in ("roll_deg", "pitch_deg", "yaw_deg")]
        rows.append({"name": name, "cells": cells})
    return rows


def _bounded_text(key: str, value: Any) -> str:
    """One bounded quantity of a result file (``{low, high, estimate}``; an older file's
    ``[low, high]`` offsets are printed as such)."""
    from rigcal.problem.uncertainty import format_bounded

    if isinstance(value, Mapping):
        return format_bounded(key, float(value["low"]), float(value["high"]), float(value["estimate"]))
    lo, hi = value
    return f"{key} offsets {lo:+.3g} .. {hi:+.3g} {'m' if key in ('x', 'y', 'z') else 'deg'}"


def _verdict(result: Mapping[str, Any]) -> dict[str, Any]:
    v = result.get("verdict") or {}
    status = v.get("status", "unchecked")
    if status == "flagged":
        failed = [c["name"] for c in v.get("checks", []) if c.get("status") == "fail"]
        headline = f"FLAGGED: the result contradicts its own noise model ({', '.join(failed)})"
    elif status == "undetermined":
        headline = "UNDETERMINED: the data do not determine every pose to its bound (determined)"
    elif status == "consistent":
        headline = "consistent: every check agrees with the noise model"
    else:
        headline = "not checked"
    return {"status": status, "headline": headline, "checks": v.get("checks", []),
            "evidence": _evidence(v), "noise": _noise_rows(v)}


def _evidence(v: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per check, the numbers it judged: item, statistic, threshold (a statistic above its
    threshold is marked)."""
    out = []
    for c in v.get("checks", []):
        rows = [{"item": e.get("item", ""), "statistic": _fmt(e.get("statistic"), ".4g"),
                 "threshold": _fmt(e.get("threshold"), ".4g"), "what": e.get("what", ""),
                 "over": bool(abs(e.get("statistic") or 0.0) > (e.get("threshold") or math.inf))}
                for e in c.get("evidence", [])]
        if rows:
            out.append({"name": c.get("name", ""), "status": c.get("status", ""), "rows": rows})
    return out


def _noise_rows(v: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The noise model the verdict used, per sensor and component (std with the range the data
    support)."""
    rows = []
    for sensor, comps in (v.get("noise") or {}).items():
        for comp, n in comps.items():
            deg = comp in ("azimuth", "elevation")
            conv = (lambda x: _fmt(x, ".3f")) if deg else (lambda x: _fmt(None if x is None else x * 1000, ".2f"))
            unit = "deg" if deg else ("mm at 1 m" if comp == "depth" else "mm")
            rows.append({"sensor": sensor, "component": comp, "unit": unit, "estimate": conv(n.get("estimate")),
                         "low": conv(n.get("low")), "high": conv(n.get("high")),
                         "identified": "yes" if n.get("identified") else "no (a pair's split)"})
    return rows


def _context(data: Mapping[str, Any]) -> dict[str, Any]:
    result = data["result"]
    sensors = result.get("sensors", {})
    bounded = [f"{name}: " + ", ".join(_bounded_text(d, v) for d, v in s["bounded"].items())
               for name, s in sensors.items() if s.get("bounded")]
    weak = []
    for name, s in sensors.items():
        std = s.get("std", {})
        items = [f"{k[0]} {std[k] * 1000:.0f} mm" for k in ("x_m", "y_m", "z_m")
                 if k.split("_")[0] not in (s.get("bounded") or {}) and (std.get(k) or 0) > 0.05]
        items += [f"{k[:-4]} {std[k]:.2f} deg" for k in ("roll_deg", "pitch_deg", "yaw_deg")
                  if k.split("_")[0] not in (s.get("bounded") or {}) and (std.get(k) or 0) > 1.0]
        if items:
            weak.append(f"{name}: " + ", ".join(items))
    blocks = []
    absolute = data.get("absolute")
    if absolute:
        body = absolute.get("body_frame", {})
        blocks.append({
            "id": "body-poses", "frame": body.get("name", "body"),
            "title": f"Poses in the body frame '{body.get('name', '')}' (T_body_sensor)",
            "caption": (f"{body.get('definition', '')}; wheelbase {_fmt(body.get('wheelbase_m'), '.4f')} m, "
                        f"ground rms {_fmt((body.get('ground_rms_m') or math.nan) * 1000, '.1f')} mm. "
                        "Numbers: absolute.yaml."),
            "rows": pose_rows(absolute.get("sensors", {}), rpy_std_decimals=3),
        })
    blocks.append({
        "id": "poses", "frame": result.get("reference", ""),
        "title": f"Poses in the frame of {result.get('reference')} (T_reference_sensor)",
        "caption": "Each sensor's pose in the reference sensor's frame; std from the estimated noise "
                   "model (bnd: only bounded, see above). Numbers: calibration.yaml.",
        "rows": pose_rows(sensors),
    })
    relative = result.get("relative", {})
    if relative:
        rel = {f"{r['to']} <- {r['from']}": r for r in relative.values()}
        locked = [f"{k} (pitch {_fmt(r['rpy_deg'][1], '+.1f')} deg): rotation std about {r['from']}'s x, y, z "
                  + "/".join(_fmt(v, ".2f") for v in r.get("rotation_std_deg", [])) + " deg"
                  for k, r in rel.items() if r.get("gimbal_lock")]
        blocks.append({
            "id": "relative", "frame": "", "title": "Relative transforms between sensors (T_to_from)",
            "caption": "Sensor 'from' in the frame of sensor 'to', with the std propagated from both "
                       "poses' joint covariance (the same as the poses', correlations included); bnd: a "
                       "bounded direction moves the value more than its std."
                       + (" Near gimbal lock (Euler roll and yaw ill-defined): " + "; ".join(locked) + "."
                          if locked else ""),
            "rows": pose_rows(rel),
        })
    errors = []
    cv = result.get("cross_validation_rmse_m", {})
    for pair, v in result.get("rmse_m", {}).items():
        per = result.get("per_board_m", {}).get(pair, {})
        worst = max(((int(k), e) for k, e in per.items() if e is not None), key=lambda kv: kv[1], default=None)
        errors.append({"pair": pair, "rmse": _fmt(None if v is None else v * 1000, ".2f"),
                       "cv": _fmt(None if cv.get(pair) is None else cv[pair] * 1000, ".2f"),
                       "worst": "-" if worst is None else f"#{worst[0]}: {worst[1] * 1000:.1f} mm"})
    if data.get("kind") == "mocap":  # the measured residuals, with their units
        for row in errors:
            row["rmse"] = row["rmse"] + " mm"
        for pair, v in result.get("reprojection_px", {}).items():
            errors.append({"pair": pair, "rmse": f"{_fmt(v, '.4g')} px", "cv": "-", "worst": "-"})
    else:
        for pair, v in result.get("reprojection_px", {}).items():
            errors.append({"pair": pair, "rmse": f"{_fmt(v, '.3f')} px (reprojection)", "cv": "-", "worst": "-"})
    outliers = "; ".join(f"{s}: boards {list(b)}" for s, b in result.get("outliers", {}).items() if b)
    coverage_rows = []
    for name, cov in data.get("coverage", {}).items():
        w = cov.get("weakest")
        axis = lambda v: "(" + ", ".join(f"{c:+.2f}" for c in v) + ")"  # noqa: E731
        coverage_rows.append({
            "name": name, "boards": len(cov.get("boards", [])),
            "rotation": "-" if not w else f"{w['rotation']['std']:.3f} deg about {axis(w['rotation']['axis_sensor'])} "
                                          f"(sensor frame)",
            "translation": "-" if not w else f"{w['translation']['std']:.1f} mm along "
                                             f"{axis(w['translation']['axis_sensor'])} (sensor frame)",
            "hint": (cov.get("hint") or {}).get("text") or cov.get("note", ""),
        })
    figures = all_figures(data)
    ids = [f["id"] for f in figures]
    mocap = data.get("mocap")
    holds = []
    for h in (mocap or {}).get("holds", []):
        scale, unit = (1000.0, "mm") if h["unit"] == "m" else (1.0, h["unit"])
        holds.append({**h, "text": f"{h['rms_final'] * scale:.3f} {unit}"})
    # inside <script>: no "<" at all (no "</script>", no "<!--"), JSON's own escape keeps the text
    figures_json = figures_script_json(figures)
    js, js_version = plotly_js()
    return {
        "title": data.get("title", "rigcal report"),
        "version": data.get("rigcal", ""),
        "kind": data["kind"],
        "note": data.get("note", ""),
        "reference": result.get("reference", ""),
        "num_boards": result.get("num_boards", 0),
        "converged": bool(result.get("converged")),
        "verdict": _verdict(result),
        "bounded": bounded,
        "weak": weak,
        "warnings": list(result.get("warnings", [])) + [w for w in (absolute or {}).get("warnings", [])
                                                        if w not in result.get("warnings", [])],
        "not_calibrated": result.get("not_calibrated", {}),
        "pose_blocks": blocks,
        "error_rows": errors,
        "outliers": outliers,
        "scene_figure": "fig-scene" if "fig-scene" in ids else None,
        "residual_figures": [i for i in ids if i in ("fig-rmse", "fig-boards")],
        "mocap_figures": [i for i in ids if i.startswith("fig-measurements-") or i == "fig-holds"],
        "coverage_figures": [i for i in ids if i.startswith("fig-coverage-")],
        "coverage_rows": coverage_rows,
        "mocap": mocap,
        "holds": holds,
        "overlays": (mocap or {}).get("overlays", []),
        "raw_images": (data.get("raw") or {}).get("images", []),
        "figures": figures,
        "figures_json": figures_json,
        "plotly_js": js,
        "plotly_version": js_version,
        "result_file": "absolute.yaml and calibration.yaml" if absolute else "calibration.yaml",
    }


#: the tags plotly.js may draw from the figures' texts: the ones rigcal writes itself (line
#: breaks, hover boxes' <extra>), none with attributes
PLOTLY_TAGS = frozenset({"br", "br/", "br /", "extra", "/extra", "b", "/b", "i", "/i", "sub", "/sub", "sup", "/sup"})
_TAG = re.compile(r"<([^<>]*)>")


def _inert_tag(match: re.Match) -> str:
    inner = match.group(1)
    return match.group(0) if inner.strip().lower() in PLOTLY_TAGS else f"&lt;{inner}&gt;"


def plotly_text(value: Any) -> Any:
    """``value`` (a figure spec) with every string's markup that plotly.js would act on made
    inert: plotly.js draws the tags in a text (``<span style=...>``, ``<a href=...>``) - a
    hand-edited report.json's sensor name could make the page fetch ``url(...)`` or link
    elsewhere; such a tag becomes text (``&lt;span ...&gt;``, which plotly shows as written).
    Only :data:`PLOTLY_TAGS` stay tags. Pure: returns a new value."""
    if isinstance(value, str):
        return _TAG.sub(_inert_tag, value) if "<" in value else value
    if isinstance(value, dict):
        return {k: plotly_text(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plotly_text(v) for v in value]
    return value


def figures_script_json(figures: list) -> str:
    """Figure specs as JSON safe inside a ``<script>`` element (no ``<`` at all), their texts'
    markup inert (:func:`plotly_text`)."""
    safe = [{**f, "data": plotly_text(f.get("data", [])), "layout": plotly_text(f.get("layout", {}))} for f in figures]
    return json.dumps(safe, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


@lru_cache(maxsize=2)
def _template(name: str = TEMPLATE):
    import jinja2

    # compiled once per user and template version into the temp folder (Jinja2's own bytecode
    # cache, a per-user 0700 directory): compiling the page template costs ~50 ms every run
    try:
        cache = jinja2.FileSystemBytecodeCache()
    except OSError:  # no usable temp folder: compile every time
        cache = None
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("rigcal.report", "templates"), bytecode_cache=cache,
        autoescape=True, trim_blocks=False, lstrip_blocks=False, undefined=jinja2.StrictUndefined,
    )
    return env.get_template(name)


def check_report_data(data: Any, source: str) -> Mapping[str, Any]:
    """``data`` if it is a report of this version (:data:`rigcal.report.data.FORMAT`), else an
    InputError naming ``source`` and the field."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a rigcal report (a mapping with format '{FORMAT}'), "
                         f"got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise InputError(f"{source}: format: expected '{FORMAT}', got {data.get('format')!r}")
    if data.get("version") != VERSION:
        raise InputError(f"{source}: version: expected {VERSION}, got {data.get('version')!r} "
                         "(written by another rigcal version: run the calibration again)")
    if data.get("kind") not in KINDS:
        raise InputError(f"{source}: kind: expected one of {', '.join(KINDS)}, got {data.get('kind')!r}")
    if not isinstance(data.get("result"), dict) or not isinstance(data["result"].get("sensors"), dict):
        raise InputError(f"{source}: result: expected the calibration result (a mapping with sensors)")
    return data


def render_report(data: Mapping[str, Any], source: str = "report data") -> str:
    """The HTML text of ``report.html`` for the report ``data``. Malformed data (e.g. a
    hand-edited ``report.json``) raises InputError naming ``source``."""
    import jinja2

    check_report_data(data, source)
    try:
        return _template().render(**_context(data))
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, jinja2.TemplateError) as exc:
        raise InputError(f"{source}: malformed report data ({type(exc).__name__}: {exc})") from None


__all__ = ["check_report_data", "plotly_js", "pose_rows", "render_report"]
