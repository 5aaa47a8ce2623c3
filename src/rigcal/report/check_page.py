"""``check.html`` (one vehicle's check) and ``fleet.html`` (one row per vehicle, worst first,
linking to each vehicle's ``check.html``) from their JSON data.

Same page machinery as ``report.html`` (:mod:`rigcal.report.page`: Jinja2 with autoescape, the
shared style); the pages are tables only, with a Content-Security-Policy that allows no script
and loads nothing from any address. The data are what ``check.json`` / ``fleet.json`` hold
(:meth:`rigcal.problem.check.CheckResult.to_dict`, :func:`fleet_summary`).
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, Sequence

from rigcal.errors import InputError, printable

CHECK_TEMPLATE = "check.html.j2"
FLEET_TEMPLATE = "fleet.html.j2"
#: a vehicle's status in a fleet, from the worst to the best
FLEET_ORDER = ("moved", "failed", "not checked", "cannot tell", "unchanged")
_CSS = {"moved": "fail", "failed": "fail", "not checked": "note", "cannot tell": "note", "unchanged": "pass"}


def _num(v: Any, spec: str, scale: float = 1.0) -> str:
    return format(float(v) * scale, spec) if isinstance(v, (int, float)) and math.isfinite(v) else "-"


def detectable_text(translation_m: Any, rotation_deg: Any) -> str:
    """The smallest detectable change as text (``-`` when not tested)."""
    if translation_m is None and rotation_deg is None:
        return "-"
    return f"{_num(translation_m, '.0f', 1000.0)} mm / {_num(rotation_deg, '.2f')} deg"


def _direction(s: Mapping[str, Any], reference: str) -> str:
    if s.get("status") == "cannot tell" or s.get("translation_m") is None:
        return "-"
    t = ", ".join(f"{x * 1000:+.0f}" for x in s["translation_m"])
    axis = ", ".join(f"{x:+.2f}" for x in s.get("axis_sensor") or [0, 0, 0])
    return f"origin ({t}) mm in {reference}'s frame; {_num(s.get('rotation_deg'), '.2f')} deg about ({axis})"


def render_check(data: Mapping[str, Any], source: str = "check.json", title: str | None = None) -> str:
    """The HTML text of ``check.html`` for a check's data."""
    import jinja2

    from rigcal import __version__
    from rigcal.report.page import _template

    try:
        status = data["status"]
        sensors = [{
            "name": name, "css": _CSS.get(s["status"], ""), "headline": s["headline"],
            "direction": _direction(s, data["reference"]),
            "detectable": detectable_text(s.get("detectable_translation_m"), s.get("detectable_rotation_deg")),
            "boards": s.get("boards", 0), "partners": ", ".join(s.get("partners", [])) or "-",
        } for name, s in data["sensors"].items()]
        pairs = [{"label": k, "boards": p["boards"], "rms": _num(p["rms_m"], ".1f", 1000.0),
                  "before": _num(p["reduced_chi2_before"], ".2f"), "after": _num(p["reduced_chi2_after"], ".2f")}
                 for k, p in data["pairs"].items()]
        moved = data.get("moved", [])
        headline = {"moved": f"MOVED: {', '.join(moved)}", "cannot tell": "cannot tell for some sensors (none found moved)",
                    "unchanged": "unchanged: every sensor where it was calibrated"}.get(status, status)
        power = (f"These {data['num_boards']} boards find moves of "
                 f"{detectable_text(data.get('detectable_translation_m'), data.get('detectable_rotation_deg'))} "
                 f"or more on every sensor told (moved or unchanged), {data['power']:.0%} of the time, with false alarms on "
                 f"at most {data['alpha']:.0%} of unchanged rigs.")
        return _template(CHECK_TEMPLATE).render(
            title=printable(title or f"check of {data.get('calibration', '')}"), version=__version__,
            calibration=printable(data.get("calibration", "")), data=printable(data.get("data", "")),
            num_boards=data["num_boards"],
            css={"moved": "flagged", "unchanged": "consistent"}.get(status, ""), headline=headline, power=power,
            power_pct=f"{data['power']:.0%}", warnings=list(data.get("warnings", [])), sensors=sensors, pairs=pairs)
    except (KeyError, TypeError, ValueError, AttributeError, jinja2.TemplateError) as exc:
        raise InputError(f"{source}: malformed check data ({type(exc).__name__}: {exc})") from None


def vehicle_row(name: str, check: Mapping[str, Any] | None, error: str | None = None,
                status: str | None = None, href: str | None = None) -> dict[str, Any]:
    """One vehicle's row of ``fleet.json``: its status, worst sensor and its verdict, the boards
    and the smallest change the check could find (from its ``check.json`` data, or the error)."""
    if check is None:
        return {"vehicle": name, "status": status or "failed", "sensor": None, "headline": error or "",
                "boards": None, "detectable_translation_m": None, "detectable_rotation_deg": None,
                "moved": [], "report": None, "rank": None}
    worst_name, worst = next(iter(check["sensors"].items()))
    return {"vehicle": name, "status": check["status"], "sensor": worst_name, "headline": worst["headline"],
            "boards": check["num_boards"], "detectable_translation_m": check.get("detectable_translation_m"),
            "detectable_rotation_deg": check.get("detectable_rotation_deg"), "moved": list(check.get("moved", [])),
            "report": href, "rank": -(worst.get("sigma") or 0.0) if worst["status"] == "moved" else None}


def fleet_summary(rows: Sequence[Mapping[str, Any]], alpha: float, note: str = "") -> dict[str, Any]:
    """``fleet.json``: the vehicles worst first (moved - the most significant first -, failed,
    not checked, cannot tell, unchanged) and the count of each status."""
    def key(r: Mapping[str, Any]) -> tuple:
        return (FLEET_ORDER.index(r["status"]) if r["status"] in FLEET_ORDER else len(FLEET_ORDER),
                r.get("rank") or 0.0, str(r["vehicle"]))

    ordered = sorted(rows, key=key)
    counts = {s: sum(r["status"] == s for r in rows) for s in FLEET_ORDER}
    return {"format": "rigcal-fleet-check", "vehicles": [{k: v for k, v in r.items() if k != "rank"} for r in ordered],
            "counts": counts, "alpha": float(alpha), "note": note}


def _link(href: Any) -> str | None:
    """A vehicle's link as :func:`rigcal.io.results.check_report.vehicle_link` makes it (a
    relative ``./<percent-encoded name>/check.html``), else none: no scheme, host or other path."""
    if isinstance(href, str) and re.fullmatch(r"\./[A-Za-z0-9._~%-]+/check\.html", href) and "/../" not in href:
        return href
    return None


def render_fleet(summary: Mapping[str, Any], source: str = "fleet.json") -> str:
    """The HTML text of ``fleet.html`` for :func:`fleet_summary`'s data."""
    import jinja2

    from rigcal import __version__
    from rigcal.report.page import _template

    try:
        vehicles = [{
            "name": printable(v["vehicle"]), "status": v["status"], "css": _CSS.get(v["status"], ""),
            "sensor": printable(v.get("sensor") or "-"), "headline": printable(v.get("headline") or ""),
            "boards": v.get("boards") if v.get("boards") is not None else "-",
            "detectable": detectable_text(v.get("detectable_translation_m"), v.get("detectable_rotation_deg")),
            "href": _link(v.get("report")),
        } for v in summary["vehicles"]]
        counts = ", ".join(f"{n} {s}" for s, n in summary["counts"].items() if n)
        return _template(FLEET_TEMPLATE).render(version=__version__, total=len(vehicles), counts=counts,
                                                vehicles=vehicles, note=printable(summary.get("note", "")))
    except (KeyError, TypeError, ValueError, AttributeError, jinja2.TemplateError) as exc:
        raise InputError(f"{source}: malformed fleet data ({type(exc).__name__}: {exc})") from None


__all__ = ["FLEET_ORDER", "detectable_text", "fleet_summary", "render_check", "render_fleet", "vehicle_row"]
