"""The report's figures as plotly figure specifications (plain dicts: ``data`` traces and a
``layout``), built from the report data (:mod:`rigcal.report.data`).

plotly's own Python objects are not used: importing ``plotly.graph_objects`` costs more than a
calibration, and the page only needs the JSON plotly.js reads (``Plotly.newPlot(div, data,
layout)``); the trace and layout keys are plotly.js's documented schema.
"""

from __future__ import annotations

from typing import Any, Mapping

#: sensor colours (colour-blind safe), cycled
COLOURS = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#D55E00", "#56B4E9", "#F0E442", "#000000")
AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
_MARKERS_3D = {"lidar": "circle", "camera": "square", "radar": "diamond", "radar3d": "diamond-open"}
_BASE_LAYOUT = {"margin": {"l": 50, "r": 10, "t": 40, "b": 45}, "font": {"size": 12},
                "paper_bgcolor": "white", "hovermode": "closest"}


def _layout(title: str, **extra: Any) -> dict[str, Any]:
    return {**_BASE_LAYOUT, "title": {"text": title, "font": {"size": 14}}, **extra}


def _lines(polylines: list) -> tuple[list, list, list]:
    """x, y, z lists of several polylines separated by None (one trace for all)."""
    xs: list = []
    ys: list = []
    zs: list = []
    for line in polylines:
        for p in line:
            xs.append(p[0])
            ys.append(p[1])
            zs.append(p[2])
        xs.append(None)
        ys.append(None)
        zs.append(None)
    return xs, ys, zs


def _colour(i: int) -> str:
    return COLOURS[i % len(COLOURS)]


def scene_figure(data: Mapping[str, Any]) -> dict[str, Any] | None:
    """Every board's detections of every sensor in the reference frame (3D, rotatable), the
    sensor poses as axis triads, 2D radars' elevation arcs and field-of-view wedges; for a
    motion-capture run the targets' templates at each hold and the lidar points."""
    scene = data.get("scene")
    if not scene:
        return None
    traces: list[dict[str, Any]] = []
    span = 1.0
    all_pts = []
    for i, s in enumerate(scene["sensors"]):
        colour = _colour(i)
        for status, symbol, size in (("used", _MARKERS_3D.get(s["kind"], "circle"), 3), ("outlier", "x", 5)):
            xs, ys, zs, text = [], [], [], []
            for pts, st, hov in zip(s["points"], s["status"], s["hover"]):
                if st != status:
                    continue
                for p in pts:
                    xs.append(p[0])
                    ys.append(p[1])
                    zs.append(p[2])
                    text.append(hov)
                    all_pts.append(p)
            if not xs:
                continue
            n_boards = sum(1 for st in s["status"] if st == status)
            traces.append({
                "type": "scatter3d", "mode": "markers", "x": xs, "y": ys, "z": zs,
                "name": f"{s['name']} ({n_boards} boards)" if status == "used"
                else f"{s['name']} outliers ({n_boards})",
                "text": text, "hovertemplate": "%{text}<extra></extra>",
                "marker": {"size": size, "color": colour, "symbol": symbol},
                "meta": {"sensor": s["name"], "status": status, "boards": n_boards},
            })
    for r in scene.get("radars", []):
        i = next((k for k, s in enumerate(scene["sensors"]) if s["name"] == r["name"]), 0)
        xs, ys, zs = _lines(r["arcs"])
        traces.append({"type": "scatter3d", "mode": "lines", "x": xs, "y": ys, "z": zs,
                       "name": f"{r['name']} elevation arcs (+-{r['max_elevation_deg']:.0f} deg)",
                       "line": {"color": _colour(i), "width": 3}, "hoverinfo": "skip"})
        xs, ys, zs = _lines(r["edges"] + r["rings"])
        traces.append({"type": "scatter3d", "mode": "lines", "x": xs, "y": ys, "z": zs,
                       "name": f"{r['name']} field of view and range arcs (1 m)",
                       "line": {"color": _colour(i), "width": 1, "dash": "dot"}, "hoverinfo": "skip",
                       "opacity": 0.6})
        # the wedge's two surfaces as one translucent mesh: a fan from the origin per surface
        vx, vy, vz, ii, jj, kk = [], [], [], [], [], []
        for edge in r["edges"]:
            base = len(vx)
            for p in edge[:-1]:
                vx.append(p[0])
                vy.append(p[1])
                vz.append(p[2])
            for k in range(1, len(edge) - 2):
                ii.append(base)
                jj.append(base + k)
                kk.append(base + k + 1)
        traces.append({"type": "mesh3d", "x": vx, "y": vy, "z": vz, "i": ii, "j": jj, "k": kk,
                       "color": _colour(i), "opacity": 0.08, "name": f"{r['name']} field of view",
                       "hoverinfo": "skip", "showlegend": False})
    for t, tpl in enumerate(scene.get("templates", [])):
        pts = tpl["points"]
        all_pts.extend(pts)
        traces.append({"type": "scatter3d", "mode": "markers", "x": [p[0] for p in pts],
                       "y": [p[1] for p in pts], "z": [p[2] for p in pts],
                       "name": f"{tpl['target']} template (MCS), hold {tpl['hold']}",
                       "legendgroup": "templates", "showlegend": t == 0,
                       "marker": {"size": 1.5, "color": "#7f7f7f"},
                       "hovertemplate": f"{tpl['target']} hold {tpl['hold']}<extra></extra>"})
    for i, (name, pts) in enumerate(scene.get("measured", {}).items()):
        all_pts.extend(pts)
        traces.append({"type": "scatter3d", "mode": "markers", "x": [p[0] for p in pts],
                       "y": [p[1] for p in pts], "z": [p[2] for p in pts],
                       "name": f"{name} points (final calibration)",
                       "marker": {"size": 2, "color": _colour(i)}, "hoverinfo": "name"})
    origins = [s["T_reference_sensor"] for s in scene["sensors"]]
    all_pts.extend([[T[0][3], T[1][3], T[2][3]] for T in origins])
    if all_pts:
        lo = [min(p[a] for p in all_pts if p[a] is not None) for a in range(3)]
        hi = [max(p[a] for p in all_pts if p[a] is not None) for a in range(3)]
        span = max(max(h - l for h, l in zip(hi, lo)), 0.5)
    triad = max(0.06 * span, 0.1)
    for axis in range(3):
        lines = []
        for T in origins:
            o = [T[0][3], T[1][3], T[2][3]]
            lines.append([o, [o[a] + triad * T[a][axis] for a in range(3)]])
        xs, ys, zs = _lines(lines)
        traces.append({"type": "scatter3d", "mode": "lines", "x": xs, "y": ys, "z": zs,
                       "name": "sensor axes (x red, y green, z blue)" if axis == 0 else "",
                       "legendgroup": "axes", "showlegend": axis == 0,
                       "line": {"color": AXIS_COLOURS[axis], "width": 5}, "hoverinfo": "skip"})
    # the sensors' names at their origins: scene annotations (SVG text that follows the 3D view),
    # not a scatter3d text trace - plotly.js turns every WebGL text string into triangles, the
    # costliest part of drawing the scene
    names = [{"x": T[0][3], "y": T[1][3], "z": T[2][3], "text": s["name"], "showarrow": False,
              "yanchor": "bottom", "font": {"size": 12}}
             for T, s in zip(origins, scene["sensors"])]
    layout = _layout(
        f"detections in the frame of {scene['frame']} (drag to rotate, scroll to zoom)",
        height=620,
        scene={"aspectmode": "data", "xaxis": {"title": {"text": "x [m]"}},
               "yaxis": {"title": {"text": "y [m]"}}, "zaxis": {"title": {"text": "z [m]"}},
               "camera": {"eye": {"x": -1.2, "y": -1.2, "z": 0.9}}, "annotations": names},
        legend={"itemsizing": "constant"},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
    )
    return {"id": "fig-scene", "data": traces, "layout": layout}


def _outlier_boards(result: Mapping[str, Any], pair: str) -> set[int]:
    out: set[int] = set()
    for s in pair.split("-"):
        out |= {int(b) for b in result.get("outliers", {}).get(s, [])}
    return out


def residual_figures(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The error per pair (fit RMSE next to the leave-boards-out cross-validated RMSE) and per
    board (one bar trace per pair, boards excluded as outliers marked with an x)."""
    result = data["result"]
    figs = []
    rmse = result.get("rmse_m", {})
    if rmse:
        pairs = list(rmse)
        traces = [{"type": "bar", "name": "fit RMSE", "x": pairs,
                   "y": [None if rmse[p] is None else round(rmse[p] * 1000, 3) for p in pairs],
                   "marker": {"color": "#0072B2"}, "hovertemplate": "%{x}: %{y:.2f} mm<extra>fit</extra>"}]
        cv = result.get("cross_validation_rmse_m", {})
        if cv:
            traces.append({"type": "bar", "name": "cross-validated RMSE (leave boards out)", "x": pairs,
                           "y": [round(cv[p] * 1000, 3) if cv.get(p) is not None else None for p in pairs],
                           "marker": {"color": "#E69F00"},
                           "hovertemplate": "%{x}: %{y:.2f} mm<extra>cross-validated</extra>"})
        figs.append({"id": "fig-rmse", "data": traces, "layout": _layout(
            "error per pair: fit and cross-validation", barmode="group", height=340,
            yaxis={"title": {"text": "RMSE [mm]"}, "rangemode": "tozero"})})
    per_board = result.get("per_board_m", {})
    if any(per_board.values()):
        traces = []
        for i, (pair, errs) in enumerate(per_board.items()):
            boards = sorted(int(k) for k in errs)
            if not boards:
                continue
            vals = [errs.get(k, errs.get(str(k))) for k in boards]  # int keys, or str after JSON
            traces.append({"type": "bar", "name": pair, "x": boards,
                           "y": [None if v is None else round(v * 1000, 3) for v in vals],
                           "marker": {"color": _colour(i)},
                           "hovertemplate": f"{pair} board %{{x}}: %{{y:.1f}} mm<extra></extra>"})
            out = sorted(_outlier_boards(result, pair) & set(boards))
            if out:
                traces.append({"type": "scatter", "mode": "markers", "name": f"{pair} outliers (excluded)",
                               "x": out, "y": [round(errs.get(k, errs.get(str(k))) * 1000, 3) for k in out],
                               "marker": {"symbol": "x", "size": 11, "color": "#d62728", "line": {"width": 2}},
                               "hovertemplate": f"{pair} board %{{x}}: outlier, %{{y:.1f}} mm<extra></extra>"})
        figs.append({"id": "fig-boards", "data": traces, "layout": _layout(
            "error per board and pair (x: excluded as an outlier)", barmode="group", height=380,
            xaxis={"title": {"text": "board"}, "dtick": 1},
            yaxis={"title": {"text": "RMS error [mm]"}, "rangemode": "tozero"})})
    return figs


def coverage_figures(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per sensor, where its boards were in its view: azimuth and elevation (a 2D radar: azimuth
    and range), seen from the sensor (left on the left), with the suggested next placement."""
    figs = []
    for i, (name, cov) in enumerate(data.get("coverage", {}).items()):
        if not cov.get("boards"):
            continue
        radar2d = cov["kind"] == "radar"
        y = cov["range_m"] if radar2d else cov["elevation_deg"]
        item = cov.get("item", "board")
        labels = cov.get("labels") or [str(b) for b in cov["boards"]]
        traces = [{"type": "scatter", "mode": "markers+text", "name": f"{item}s", "x": cov["azimuth_deg"], "y": y,
                   "text": labels, "textposition": "top center",
                   "textfont": {"size": 9}, "marker": {"size": 9, "color": _colour(i)},
                   "hovertemplate": f"{item} %{{text}}: azimuth %{{x:.1f}} deg, "
                   + ("range %{y:.2f} m" if radar2d else "elevation %{y:.1f} deg") + "<extra></extra>"}]
        hint = cov.get("hint")
        if hint:
            traces.append({"type": "scatter", "mode": "markers", "name": f"suggested next {item}",
                           "x": [hint["azimuth_deg"]], "y": [hint["range_m"] if radar2d else hint["elevation_deg"]],
                           "marker": {"symbol": "star", "size": 16, "color": "#d62728"},
                           "hovertemplate": f"suggested next {item}<extra></extra>"})
        figs.append({"id": f"fig-coverage-{name}", "data": traces, "layout": _layout(
            f"{name}: {item}s in its view", height=320, showlegend=True,
            legend={"orientation": "h", "y": -0.25},
            xaxis={"title": {"text": "azimuth [deg] (left is +)"}, "autorange": "reversed", "zeroline": True},
            yaxis={"title": {"text": "range [m]" if radar2d else "elevation [deg]"}, "zeroline": True})})
    return figs


def mocap_figures(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per sensor, every kept measurement's residual under the initial and the final calibration
    (m shown as mm, camera px), and the RMS per hold."""
    m = data.get("mocap")
    if not m:
        return []
    figs = []
    sensors = list(dict.fromkeys(x["sensor"] for x in m["measurements"]))
    for name in sensors:
        rows = [x for x in m["measurements"] if x["sensor"] == name]
        unit = rows[0]["unit"]
        scale = 1000.0 if unit == "m" else 1.0
        shown = "mm" if unit == "m" else unit
        labels = [f"{x['target']} {x['t_s']:.1f}s" + (f" ({x['hold']})" if x["hold"] else "") for x in rows]
        traces = [{"type": "bar", "name": key, "x": labels,
                   "y": [None if x[key] is None else round(x[key] * scale, 4) for x in rows],
                   "marker": {"color": colour},
                   "hovertemplate": f"%{{x}}: %{{y:.3f}} {shown}<extra>{key}</extra>"}
                  for key, colour in (("initial", "#E69F00"), ("final", "#0072B2"))]
        figs.append({"id": f"fig-measurements-{name}", "data": traces, "layout": _layout(
            f"{name}: residual per kept measurement, initial and final calibration", barmode="group",
            height=320, xaxis={"tickangle": -45, "automargin": True},
            yaxis={"title": {"text": f"RMS residual [{shown}]"}, "rangemode": "tozero", "type": "log"
                   if any(x["final"] and x["initial"] and x["initial"] > 30 * x["final"] for x in rows) else "linear"})})
    holds = m.get("holds", [])
    if holds:
        traces = []
        for i, name in enumerate(dict.fromkeys(h["sensor"] for h in holds)):
            rows = [h for h in holds if h["sensor"] == name]
            scale = 1000.0 if rows[0]["unit"] == "m" else 1.0
            shown = "mm" if rows[0]["unit"] == "m" else rows[0]["unit"]
            traces.append({"type": "bar", "name": f"{name} [{shown}]", "x": [f"{name}: {h['hold']}" for h in rows],
                           "y": [round(h["rms_final"] * scale, 4) for h in rows], "marker": {"color": _colour(i)},
                           "hovertemplate": f"%{{x}}: %{{y:.3f}} {shown}<extra></extra>"})
        figs.append({"id": "fig-holds", "data": traces, "layout": _layout(
            "RMS residual per hold, final calibration (lidar mm, camera px)", height=320,
            xaxis={"tickangle": -45, "automargin": True}, yaxis={"rangemode": "tozero"})})
    return figs


def all_figures(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Every figure of the page (each ``{"id", "data", "layout"}``), in the order they are drawn:
    the 3D scene last - creating its WebGL context and drawing it take the longest (about 0.5 s
    with a software renderer), so the 2D figures are drawn before it."""
    figs = residual_figures(data) + mocap_figures(data) + coverage_figures(data)
    scene = scene_figure(data)
    return figs + ([scene] if scene is not None else [])


__all__ = ["all_figures", "coverage_figures", "mocap_figures", "residual_figures", "scene_figure"]
