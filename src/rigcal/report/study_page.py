"""``study.html``: the page of a study (``rigcal study prius`` / ``rigcal study mocap``) from its
``study.json`` (``{"meta": ..., "rows": [...]}``, every number of the study).

Tables of every row, grouped by the row's ``table`` (Table II, Table III, Fig. 7, Fig. 8, the
motion-capture tables), and figures next to the paper's values where the rows carry them:

* Table III: the median RMSE per configuration and pair with its MAD as error bar, the paper's
  value as a marker;
* Fig. 7 / Fig. 8: the median RMSE against the number of boards K / the lidar noise sigma, one
  line per configuration and pair with the MAD as error bars, the paper's values as markers.

The study's settings (``meta``) head the page: scalars and flat mappings (e.g. ``draws: III: 200,
fig7: 100``), an absolute path as its file name only; ``meta["notes"]`` (a list of paragraphs,
e.g. why the paper's MCPE rows differ) follow as a "Notes" section.

Same page machinery as ``report.html`` (:mod:`rigcal.report.page`): Jinja2, plotly.js embedded,
no network request.
"""

from __future__ import annotations

import math
from pathlib import PurePosixPath, PureWindowsPath
from typing import Any, Mapping, Sequence

from rigcal.errors import InputError
from rigcal.report.figures import COLOURS, _layout

TEMPLATE = "study.html.j2"
#: the x axis of a figure's rows: (row key, axis title, scale to the axis unit)
FIGURE_AXES = {"fig7": ("k", "boards per set K", 1.0), "fig8": ("sigma_m", "lidar noise sigma [mm]", 1000.0)}
_TITLES = {"II": "Table II", "III": "Table III", "fig7": "Fig. 7", "fig8": "Fig. 8"}
#: columns shown first, in this order; any other key of the rows follows
_LEAD = ("config", "mode", "reference", "target", "sensor", "pair", "k", "sigma_m", "median_mm", "mad_mm",
         "heldout_median_mm", "heldout_mad_mm", "paper_mm", "paper_spread_mm", "draws", "failures")


def check_study(study: Any, source: str) -> Mapping[str, Any]:
    """``study`` if it is a study's JSON (a mapping with a ``rows`` list of mappings, each with a
    ``table``), else InputError naming ``source`` and the field."""
    if not isinstance(study, dict):
        raise InputError(f"{source}: expected a study (a mapping with 'meta' and 'rows'), got {type(study).__name__}")
    rows = study.get("rows")
    if not isinstance(rows, list) or not rows:
        raise InputError(f"{source}: rows: expected a non-empty list of rows")
    for i, r in enumerate(rows):
        if not isinstance(r, dict) or not isinstance(r.get("table"), str):
            raise InputError(f"{source}: rows[{i}]: expected a mapping with a 'table' name")
    if not isinstance(study.get("meta", {}), dict):
        raise InputError(f"{source}: meta: expected a mapping")
    return study


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _cell(key: str, v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "-"
        if key == "sigma_m":
            return f"{v * 1000:g} mm"
        return f"{v:.2f}" if abs(v) < 1e4 else f"{v:.4g}"
    if isinstance(v, (list, dict)):
        return "..."
    return str(v)


def _is_absolute_path(v: str) -> bool:
    return "\n" not in v and (PurePosixPath(v).is_absolute() or PureWindowsPath(v).is_absolute())


def _meta_value(key: str, v: Any) -> str | None:
    """A ``meta`` value as the page shows it, or None (not shown: None, lists, nested mappings,
    the notes). An absolute path is shown as its file name: the page is shared, and a path on the
    machine that ran the study says nothing to its reader (study.json keeps what was given)."""
    if v is None:  # not set (e.g. an option left at its default): nothing to show
        return None
    if isinstance(v, str):
        return PureWindowsPath(v).name if _is_absolute_path(v) else v  # (it splits at / and \\)
    if isinstance(v, dict):
        if not v or any(isinstance(x, (list, dict)) for x in v.values()):
            return None
        return ", ".join(f"{k}: {_meta_value(str(k), x)}" for k, x in v.items())
    if isinstance(v, list):
        return None
    return _cell(key, v)


def _notes(meta: Mapping[str, Any]) -> list[str]:
    notes = meta.get("notes")
    return [str(n) for n in notes] if isinstance(notes, list) else []


def _series_name(r: Mapping[str, Any]) -> str:
    head = r.get("config") or r.get("mode") or r.get("target") or ""
    return f"{head} {r.get('pair') or r.get('sensor') or ''}".strip()


def tables(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One table per ``table`` value, in first-seen order: ``{"id", "title", "columns", "rows"}``
    with every key any of its rows has (the leading ones first) and the cells as text."""
    out: list[dict[str, Any]] = []
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r["table"], []).append(r)
    for name, part in groups.items():
        keys = [k for k in _LEAD if any(k in r for r in part)]
        keys += sorted({k for r in part for k in r} - set(keys) - {"table"})
        keys = [k for k in keys if not all(r.get(k) is None for r in part)]
        out.append({
            "id": "table-" + "".join(c if c.isalnum() else "-" for c in name.lower()),
            "title": _TITLES.get(name, name),
            "columns": keys,
            "rows": [[_cell(k, r.get(k)) for k in keys] for r in part],
        })
    return out


def _bar_figure(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """Table III: median +- MAD per configuration (x) and pair (one bar trace per pair)."""
    part = [r for r in rows if r["table"] == "III" and _num(r.get("median_mm")) is not None]
    if not part:
        return None
    pairs = list(dict.fromkeys(r.get("pair", "") for r in part))
    traces = []
    for i, pair in enumerate(pairs):
        sel = [r for r in part if r.get("pair", "") == pair]
        traces.append({"type": "bar", "name": pair, "x": [r.get("config", r.get("mode")) for r in sel],
                       "y": [r["median_mm"] for r in sel], "marker": {"color": COLOURS[i % len(COLOURS)]},
                       "error_y": {"type": "data", "array": [_num(r.get("mad_mm")) or 0.0 for r in sel]},
                       "offsetgroup": str(i), "hovertemplate": "%{x}<br>" + pair + ": %{y:.2f} mm<extra></extra>"})
        paper = [r for r in sel if _num(r.get("paper_mm")) is not None]
        if paper:
            traces.append({"type": "scatter", "mode": "markers", "name": f"{pair} (paper)",
                           "x": [r.get("config", r.get("mode")) for r in paper], "y": [r["paper_mm"] for r in paper],
                           "marker": {"symbol": "line-ew-open", "size": 22, "color": "#000",
                                      "line": {"width": 2, "color": COLOURS[i % len(COLOURS)]}},
                           "offsetgroup": str(i), "hovertemplate": "paper: %{y:.1f} mm<extra></extra>"})
    return {"id": "fig-table-iii", "data": traces,
            "layout": _layout("Table III: median RMSE over the draws (error bar: MAD; bar marks: paper)",
                              barmode="group", yaxis={"title": {"text": "RMSE [mm]"}}, height=420)}


def _line_figure(rows: Sequence[Mapping[str, Any]], table: str) -> dict[str, Any] | None:
    """Fig. 7 / Fig. 8: median RMSE against K / sigma, one line per configuration and pair."""
    key, title, scale = FIGURE_AXES[table]
    part = [r for r in rows if r["table"] == table and _num(r.get(key)) is not None
            and _num(r.get("median_mm")) is not None]
    if not part:
        return None
    series = list(dict.fromkeys(_series_name(r) for r in part))
    traces = []
    for i, name in enumerate(series):
        sel = sorted((r for r in part if _series_name(r) == name), key=lambda r: r[key])
        colour = COLOURS[i % len(COLOURS)]
        traces.append({"type": "scatter", "mode": "lines+markers", "name": name,
                       "x": [r[key] * scale for r in sel], "y": [r["median_mm"] for r in sel],
                       "error_y": {"type": "data", "array": [_num(r.get("mad_mm")) or 0.0 for r in sel],
                                   "thickness": 1},
                       "line": {"color": colour}, "marker": {"size": 5}})
        paper = [r for r in sel if _num(r.get("paper_mm")) is not None]
        if paper:
            traces.append({"type": "scatter", "mode": "markers", "name": f"{name} (paper)",
                           "x": [r[key] * scale for r in paper], "y": [r["paper_mm"] for r in paper],
                           "marker": {"symbol": "diamond-open", "size": 9, "color": colour}})
    label = _TITLES[table]
    return {"id": f"fig-{table}", "data": traces,
            "layout": _layout(f"{label}: median RMSE (error bars: MAD; open diamonds: paper)",
                              xaxis={"title": {"text": title}}, yaxis={"title": {"text": "RMSE [mm]"}},
                              height=460)}


def study_figures(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    figs = [_bar_figure(rows), _line_figure(rows, "fig7"), _line_figure(rows, "fig8")]
    return [f for f in figs if f is not None]


def render_study(study: Mapping[str, Any], source: str = "study.json", title: str | None = None) -> str:
    """The HTML text of ``study.html`` for a study's JSON. Malformed JSON raises InputError
    naming ``source``."""
    import jinja2

    from rigcal import __version__
    from rigcal.report.page import _template, figures_script_json, plotly_js

    check_study(study, source)
    rows = study["rows"]
    figures = study_figures(rows)
    js, js_version = plotly_js()
    meta = study.get("meta", {})
    try:
        return _template(TEMPLATE).render(
            title=title or str(meta.get("study") or meta.get("name") or "rigcal study"),
            version=__version__,
            meta=[(str(k), shown) for k, v in meta.items()
                  if k != "notes" and (shown := _meta_value(str(k), v)) is not None],
            notes=_notes(meta),
            tables=tables(rows),
            figures=[f["id"] for f in figures],
            figures_json=figures_script_json(figures),
            plotly_js=js,
            plotly_version=js_version,
        )
    except (KeyError, TypeError, ValueError, jinja2.TemplateError) as exc:
        raise InputError(f"{source}: malformed study ({type(exc).__name__}: {exc})") from None


__all__ = ["FIGURE_AXES", "check_study", "render_study", "study_figures", "tables"]
