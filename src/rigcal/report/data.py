"""The report's data: everything ``report.html`` shows, as plain JSON-safe values.

A report is built once from a result (and, when the run has them, its detections and raw
measurements) and written as ``report.json`` beside ``calibration.yaml``; the page
(:mod:`rigcal.report.page`) is rendered from that data alone, so ``rigcal report DIR``
rebuilds it without the original inputs. Layout (``version`` 1)::

    format: "rigcal-report", version: 1, kind: calibrate | mocap | absolute
    title: str
    result: CalibrationResult.to_dict()            # verdict, poses, std, relative, residuals
    absolute: AbsoluteResult.to_dict() without "relative"   (kind absolute)
    scene: {frame, sensors: [...], radars: [...]}  # detections in the reference frame
    coverage: {sensor: {...}}                      # board directions, weak directions, hint
    mocap: {holds: [...], measurements: [...], overlays: [...]}   (kind mocap)

Points are in metres in the result's reference frame, angles in degrees. Numbers meant for
figures are rounded to 0.1 mm; numbers the page prints as the result come from ``result`` at
full precision.
"""

from __future__ import annotations

import base64
import math
from typing import Any, Iterable, Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.geometry.se3 import invert, transform_points
from rigcal.problem.result import CalibrationResult

FORMAT = "rigcal-report"
VERSION = 1
KINDS = ("calibrate", "mocap", "absolute")

#: samples along a 2D radar's elevation arc
ARC_SAMPLES = 9
#: a direction is weakly determined above these std (as rigcal.problem.uncertainty)
WEAK_TRANSLATION_M = 0.05
WEAK_ROTATION_DEG = 1.0
#: noise assumed for a hint when the result has no noise estimate for the sensor [m]
DEFAULT_SIGMA_M = 0.01


def _r(x: Any, nd: int = 4) -> Any:
    """Rounded plain floats (nested lists), NaN/inf as None."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        v = float(a)
        return round(v, nd) if math.isfinite(v) else None
    return [_r(v, nd) for v in a]


# --------------------------------------------------------------------------------------------
# detections in the reference frame


def radar_arcs(points_xy: np.ndarray, max_elevation_rad: float, samples: int = ARC_SAMPLES) -> np.ndarray:
    """(N, samples, 3) in a 2D radar's frame: for each reported (x, y) (N, 2), the arc of points
    at its range and azimuth over the elevations within +-``max_elevation_rad`` (the radar does
    not measure elevation; the reflector lies somewhere on the arc)."""
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    rng = np.linalg.norm(pts, axis=1)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    el = np.linspace(-max_elevation_rad, max_elevation_rad, samples)
    return rng[:, None, None] * np.stack(
        [
            np.cos(el)[None, :] * np.cos(az)[:, None],
            np.cos(el)[None, :] * np.sin(az)[:, None],
            np.broadcast_to(np.sin(el)[None, :], (pts.shape[0], samples)),
        ],
        axis=-1,
    )


def radar_wedge(points_xy: np.ndarray, max_elevation_rad: float, samples: int = 13) -> dict[str, Any]:
    """The part of a 2D radar's field of view the boards used, in its own frame: the two
    surfaces at +-``max_elevation_rad`` from the origin out to 1.15 x the farthest detection,
    over the detections' azimuths widened by 10 deg each way. Returns ``edges`` (the wedge's
    outline: lists of points) and ``rings`` (range arcs on the radar plane every metre)."""
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    if pts.size == 0:
        az_lo, az_hi, r_max = -math.radians(45), math.radians(45), 10.0
    else:
        az = np.arctan2(pts[:, 1], pts[:, 0])
        az_lo, az_hi = float(az.min()) - math.radians(10), float(az.max()) + math.radians(10)
        r_max = 1.15 * float(np.linalg.norm(pts, axis=1).max())
    az = np.linspace(az_lo, az_hi, samples)
    edges = []
    for el in (-max_elevation_rad, max_elevation_rad):
        far = r_max * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full_like(az, np.sin(el))], 1)
        edges.append(np.vstack([[0.0, 0.0, 0.0], far, [0.0, 0.0, 0.0]]))
    rings = []
    for r in np.arange(1.0, r_max + 1e-9, 1.0):
        rings.append(np.stack([r * np.cos(az), r * np.sin(az), np.zeros_like(az)], 1))
    return {"edges": edges, "rings": rings, "range_max_m": r_max,
            "azimuth_deg": [math.degrees(az_lo), math.degrees(az_hi)]}


def _board_residual_text(result: CalibrationResult, sensor: str, board: int) -> str:
    parts = []
    for pair, per in result.per_board_m.items():
        if sensor in pair.split("-") and board in per and math.isfinite(per[board]):
            parts.append(f"{pair} {per[board] * 1000:.1f} mm")
    return ", ".join(parts) if parts else "no pair residual"


def scene_data(dataset: Dataset, result: CalibrationResult) -> dict[str, Any]:
    """Every calibrated sensor's detections in the reference frame, per board, with the sensor
    poses, 2D radars' elevation arcs and field-of-view wedges (all in the reference frame)."""
    sensors, radars = [], []
    for det in dataset.sensors:
        est = result.sensors.get(det.name)
        if est is None:
            continue
        T = np.asarray(est.T_reference_sensor, dtype=float)
        outliers = {int(b) for b in result.outliers.get(det.name, ())}
        ignored = {int(b) for b in result.ignored.get(det.name, ())}
        boards, points, status, hover = [], [], [], []
        detected = det.detected
        pts_all = np.asarray(det.points, dtype=float)
        for k in np.flatnonzero(detected):
            k = int(k)
            if k in ignored:
                continue
            p = pts_all[k].reshape(-1, pts_all.shape[-1])
            if det.kind is SensorKind.RADAR:
                p = np.concatenate([p, np.zeros((p.shape[0], 1))], axis=1)
            boards.append(k)
            points.append(_r(transform_points(T, p)))
            status.append("outlier" if k in outliers else "used")
            hover.append(f"{det.name} board {k}: {_board_residual_text(result, det.name, k)}")
        sensors.append({
            "name": det.name, "kind": det.kind.value, "T_reference_sensor": _r(T, 6),
            "boards": boards, "points": points, "status": status, "hover": hover,
        })
        if det.kind is SensorKind.RADAR:
            xy = pts_all[[b for b in boards]] if boards else np.zeros((0, 2))
            arcs = radar_arcs(xy.reshape(-1, 2), det.max_elevation_rad)
            wedge = radar_wedge(xy.reshape(-1, 2), det.max_elevation_rad)
            radars.append({
                "name": det.name,
                "max_elevation_deg": math.degrees(det.max_elevation_rad),
                "boards": boards,
                "arcs": [_r(transform_points(T, a)) for a in arcs],
                "edges": [_r(transform_points(T, e)) for e in wedge["edges"]],
                "rings": [_r(transform_points(T, r)) for r in wedge["rings"]],
                "range_max_m": wedge["range_max_m"],
                "azimuth_deg": wedge["azimuth_deg"],
            })
    return {"frame": result.reference, "sensors": sensors, "radars": radars}


# --------------------------------------------------------------------------------------------
# coverage and where to put the next board


def _angles(points_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth, elevation [deg] and range [m] of points (N, 3) in a sensor frame whose viewing
    direction is x (lidar, radar) or z (camera optical frame: handled by the caller)."""
    x, y, z = points_sensor[:, 0], points_sensor[:, 1], points_sensor[:, 2]
    rng = np.linalg.norm(points_sensor, axis=1)
    return np.degrees(np.arctan2(y, x)), np.degrees(np.arcsin(np.clip(z / np.maximum(rng, 1e-12), -1, 1))), rng


def _to_view(kind: SensorKind, p: np.ndarray) -> np.ndarray:
    """Points in a frame with x forward, y left, z up: a camera's optical frame (z forward, x
    right, y down) is turned; others are returned as they are."""
    if kind is SensorKind.CAMERA:
        return np.stack([p[:, 2], -p[:, 0], -p[:, 1]], axis=1)
    return p


def _from_view(kind: SensorKind, p: np.ndarray) -> np.ndarray:
    if kind is SensorKind.CAMERA:
        return np.stack([-p[:, 1], -p[:, 2], p[:, 0]], axis=1)
    return p


def _sigma(result: CalibrationResult, name: str) -> float:
    comps = result.noise_model.get(name, {})
    vals = [v for k, v in comps.items() if k in ("x", "y", "z", "lateral", "range") and math.isfinite(v)]
    return max(float(np.mean(vals)), 1e-3) if vals else DEFAULT_SIGMA_M


def _point_jacobian(p_sensor: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(3, 6) derivative of ``R p + t`` w.r.t. the right perturbation (omega, v) of the pose."""
    px = np.array([[0, -p_sensor[2], p_sensor[1]], [p_sensor[2], 0, -p_sensor[0]], [-p_sensor[1], p_sensor[0], 0]])
    return np.hstack([-R @ px, R])


def _score(C: np.ndarray) -> float:
    """The covariance's size in the units of the weak thresholds: rotation variance / (1 deg)^2
    plus translation variance / (5 cm)^2."""
    return float(np.trace(C[:3, :3]) / math.radians(WEAK_ROTATION_DEG) ** 2
                 + np.trace(C[3:, 3:]) / WEAK_TRANSLATION_M**2)


def weakest_directions(covariance: np.ndarray, T_reference_sensor: np.ndarray) -> dict[str, Any]:
    """The least determined rotation axis and translation direction of a pose from its (6, 6)
    right-perturbation covariance (rotation first): unit vectors in the sensor and the reference
    frame with their std [deg, mm]."""
    C = 0.5 * (np.asarray(covariance, dtype=float) + np.asarray(covariance, dtype=float).T)
    R = np.asarray(T_reference_sensor, dtype=float)[:3, :3]
    out = {}
    for key, block, scale, unit in (("rotation", C[:3, :3], math.degrees(1.0), "deg"),
                                    ("translation", C[3:, 3:], 1000.0, "mm")):
        w, V = np.linalg.eigh(block)
        v = V[:, -1] * (1 if V[np.argmax(np.abs(V[:, -1])), -1] >= 0 else -1)
        out[key] = {"std": float(math.sqrt(max(w[-1], 0.0)) * scale), "unit": unit,
                    "axis_sensor": _r(v), "axis_reference": _r(R @ v)}
    return out


def _axis_name(v: Iterable[float]) -> str:
    v = np.asarray(list(v), dtype=float)
    i = int(np.argmax(np.abs(v)))
    return ("x", "y", "z")[i] if abs(v[i]) > 0.9 else "(" + ", ".join(f"{c:+.2f}" for c in v) + ")"


def _hull(points: np.ndarray) -> np.ndarray:
    """(h, 2) the convex hull of (n, 2) points, counter-clockwise (monotone chain); fewer than 3
    vertices when the points are (nearly) collinear."""
    pts = sorted(set(map(tuple, np.round(np.asarray(points, dtype=float), 12))))
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    upper: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=float)


def _inside_hull(hull: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) bool: each of (n, 2) ``points`` inside (or on) the counter-clockwise convex ``hull``
    (with at least 3 vertices; else nothing is inside)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(hull) < 3:
        return np.zeros(len(points), dtype=bool)
    a, b = hull, np.roll(hull, -1, axis=0)
    edge = b - a
    rel = points[:, None, :] - a[None, :, :]
    side = edge[None, :, 0] * rel[:, :, 1] - edge[None, :, 1] * rel[:, :, 0]
    scale = max(1.0, float(np.abs(hull).max()))
    return np.all(side >= -1e-12 * scale, axis=1)


def _view_region(kind: SensorKind, region_points: np.ndarray):
    """``inside(points (n, 3) in the sensor frame) -> (n,) bool``: within the part of the view
    where the sensor detected something. A camera: inside the convex hull of the detected
    points on its normalised image plane (x / z, y / z; the image is convex there, so the hull
    lies in it); a lidar or 3D radar: inside the azimuth and elevation ranges of the detections;
    a 2D radar: inside their azimuth range."""
    p = np.asarray(region_points, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if kind is SensorKind.CAMERA:
        front = p[p[:, 2] > 1e-9]
        hull = _hull(front[:, :2] / front[:, 2:3]) if len(front) else np.zeros((0, 2))

        def inside(q: np.ndarray) -> np.ndarray:
            q = np.asarray(q, dtype=float).reshape(-1, 3)
            ok = q[:, 2] > 1e-9
            out = np.zeros(len(q), dtype=bool)
            out[ok] = _inside_hull(hull, q[ok, :2] / q[ok, 2:3])
            return out

        return inside
    az, el, _ = _angles(p) if len(p) else (np.zeros(0),) * 3
    tol = 1e-9

    def inside_box(q: np.ndarray) -> np.ndarray:
        a, e, _ = _angles(np.asarray(q, dtype=float).reshape(-1, 3))
        if not len(az):
            return np.zeros(len(a), dtype=bool)
        ok = (a >= az.min() - tol) & (a <= az.max() + tol)
        if kind is not SensorKind.RADAR:
            ok &= (e >= el.min() - tol) & (e <= el.max() + tol)
        return ok

    return inside_box


def sensor_coverage(det: SensorDetections | Any, result: CalibrationResult, board_points: np.ndarray,
                    boards: list[int], item: str = "board", region_points: np.ndarray | None = None,
                    ) -> dict[str, Any]:
    """Where the boards were in one sensor's view, its least determined directions and a hint
    where the next board helps most.

    ``board_points`` (K, 3): each used board's centre in the sensor's frame. The hint scores
    candidate board positions at the median board range, in the part of the view where the
    sensor detected boards (:func:`_view_region` of ``region_points``, every detected point in
    the sensor's frame, default ``board_points``: all four circles of a candidate board must lie
    there, so the hint is inside the sensor's field of view - a camera's image; without
    ``region_points`` its centre among the board centres), by how much one
    more board there would shrink the pose covariance, to first order:
    ``C' = (C^-1 + J^T J / sigma^2)^-1`` with ``J`` the four circle centres' (a radar's
    reflector's) Jacobian w.r.t. the pose and ``sigma`` the sensor's estimated noise; the
    candidate with the smallest ``C'`` (rotation in units of 1 deg, translation of 5 cm) wins.
    """
    est = result.sensors[det.name]
    view = _to_view(det.kind, board_points) if len(board_points) else np.zeros((0, 3))
    az, el, rng = _angles(view) if len(view) else (np.zeros(0),) * 3
    out: dict[str, Any] = {
        "kind": det.kind.value,
        "boards": boards,
        "azimuth_deg": _r(az, 2),
        "elevation_deg": _r(el, 2) if det.kind is not SensorKind.RADAR else [],
        "range_m": _r(rng, 3),
        "bounded": {d: [float(lo), float(hi)] for d, (lo, hi) in est.bounded.items()},
    }
    if det.name == result.reference:
        out["note"] = "the reference: its pose is fixed (every other pose is relative to it)"
        return out
    T = np.asarray(est.T_reference_sensor, dtype=float)
    # held and bounded directions have no meaningful covariance: left out
    held = set(est.held) | set(est.bounded)
    free = [i for i, n in enumerate(("roll", "pitch", "yaw", "x", "y", "z")) if n not in held]
    Cf = np.asarray(est.covariance, dtype=float)[np.ix_(free, free)]
    C = np.zeros((6, 6))
    C[np.ix_(free, free)] = Cf
    out["weakest"] = weakest_directions(C, T)
    if len(view) == 0 or not free:
        out["note"] = "no board used" if len(view) == 0 else "no free direction"
        return out
    try:
        info = np.linalg.inv(Cf + 1e-18 * np.eye(len(free)))
    except np.linalg.LinAlgError:
        out["note"] = "covariance singular: no hint"
        return out
    sigma = _sigma(result, det.name)
    r0 = float(np.median(rng))
    in_view = _view_region(det.kind, board_points if region_points is None else region_points)
    # candidates: a grid over the viewed directions, and the boards' own directions (seen)
    az_c = np.unique(np.concatenate([np.linspace(az.min(), az.max(), 13), az]))
    el_c = (np.array([0.0]) if det.kind is SensorKind.RADAR else
            np.unique(np.concatenate([np.linspace(el.min(), el.max(), 9), el])))
    spacing = 0.24 * 0.5
    offsets = np.array([[0, s1 * spacing, s2 * spacing] for s1 in (-1, 1) for s2 in (-1, 1)])
    base = _score(C)
    best = None
    for a in az_c:
        for e in el_c:
            d = np.array([math.cos(math.radians(e)) * math.cos(math.radians(a)),
                          math.cos(math.radians(e)) * math.sin(math.radians(a)), math.sin(math.radians(e))])
            centre_view = r0 * d
            if det.kind is SensorKind.RADAR:
                pts_view = centre_view[None]
            else:
                pts_view = centre_view + offsets
            pts = _from_view(det.kind, pts_view)
            # every circle inside the viewed region (without the detected points: the centre)
            if not np.all(in_view(pts if region_points is not None else _from_view(det.kind, centre_view[None]))):
                continue
            J = np.vstack([_point_jacobian(p, np.eye(3)) for p in pts])
            if det.kind is SensorKind.RADAR:  # a 2D radar measures the plane's x, y only
                J = np.vstack([_point_jacobian(p, np.eye(3))[:2] for p in pts])
            J = J[:, free]
            Cn = np.zeros((6, 6))
            Cn[np.ix_(free, free)] = np.linalg.inv(info + J.T @ J / sigma**2)
            s = _score(Cn)
            if best is None or s < best[0]:
                best = (s, a, e, _from_view(det.kind, centre_view[None])[0])
    if best is None:
        out["note"] = "no board position inside the viewed region to suggest"
        return out
    s, a, e, p_sensor = best
    p_ref = transform_points(T, p_sensor[None])[0]
    gain = 1.0 - s / base if base > 0 else 0.0
    w = out["weakest"]
    text = (f"next {item} for {det.name}: azimuth {a:+.0f} deg, "
            + (f"elevation {e:+.0f} deg, " if det.kind is not SensorKind.RADAR else "")
            + f"range {r0:.1f} m (reference frame x {p_ref[0]:.2f}, y {p_ref[1]:.2f}, z {p_ref[2]:.2f} m)"
            + f" - shrinks the pose variance by {100 * gain:.0f} %; least determined now: rotation about "
            + f"{_axis_name(w['rotation']['axis_sensor'])} ({w['rotation']['std']:.2f} deg), translation along "
            + f"{_axis_name(w['translation']['axis_sensor'])} ({w['translation']['std']:.1f} mm)")
    if est.bounded:
        text += ("; its " + ", ".join(est.bounded) + " are only bounded by the elevation field of view: "
                 "reflectors near both edges of it (high and low, near and far) narrow the bounds")
    out["hint"] = {"azimuth_deg": float(a), "elevation_deg": float(e), "range_m": r0,
                   "point_reference": _r(p_ref), "variance_reduction": float(gain), "text": text}
    return out


def coverage_data(dataset: Dataset, result: CalibrationResult) -> dict[str, Any]:
    """:func:`sensor_coverage` for every calibrated sensor (board centres: the mean of the four
    circle centres; a radar's reflector)."""
    out = {}
    for det in dataset.sensors:
        if det.name not in result.sensors:
            continue
        ignored = set(result.ignored.get(det.name, ())) | set(result.outliers.get(det.name, ()))
        boards = [int(k) for k in np.flatnonzero(det.valid) if int(k) not in ignored]
        pts = np.asarray(det.points, dtype=float)
        if det.kind.is_point_cloud:
            centres = pts[boards].reshape(len(boards), -1, 3).mean(axis=1) if boards else np.zeros((0, 3))
        elif det.kind is SensorKind.RADAR:
            centres = np.concatenate([pts[boards].reshape(-1, 2), np.zeros((len(boards), 1))], axis=1)
        else:
            centres = pts[boards].reshape(-1, 3)
        seen = pts[boards].reshape(-1, pts.shape[-1]) if boards else np.zeros((0, pts.shape[-1]))
        if det.kind is SensorKind.RADAR:
            seen = np.concatenate([seen, np.zeros((len(seen), 1))], axis=1)
        out[det.name] = sensor_coverage(det, result, centres, boards, region_points=seen)
    return out


# --------------------------------------------------------------------------------------------
# reports


def _header(kind: str, title: str) -> dict[str, Any]:
    from rigcal import __version__

    return {"format": FORMAT, "version": VERSION, "kind": kind, "title": title, "rigcal": __version__}


def calibration_report(result: CalibrationResult, dataset: Dataset | None = None) -> dict[str, Any]:
    """The report of a board calibration (``rigcal calibrate``); with the ``dataset`` it holds the
    detections in the reference frame and the coverage, without only the result."""
    data = _header("calibrate", f"{result.mode.upper()} calibration, reference {result.reference}")
    data["result"] = result.to_dict()
    if dataset is not None:
        data["scene"] = scene_data(dataset, result)
        data["coverage"] = coverage_data(dataset, result)
    return data


def absolute_report(result: Any, dataset: Dataset | None = None) -> dict[str, Any]:
    """The report of an absolute calibration (:class:`rigcal.absolute.result.AbsoluteResult`):
    the poses in the body frame first, then the relative calibration (reference: the external
    scanner) with its detections."""
    data = calibration_report(result.relative, dataset)
    data.update(_header("absolute", f"absolute calibration: every sensor in the body frame "
                                    f"'{result.body_frame}'"))
    absolute = result.to_dict()
    absolute.pop("relative", None)
    data["absolute"] = absolute
    return data


def mocap_report(run: Any, overlays: Mapping[str, bytes] | None = None) -> dict[str, Any]:
    """The report of a motion-capture calibration (:class:`rigcal.mocap.pipeline.MocapRun`): the
    result, every kept measurement's residual under the initial and the final calibration,
    grouped per hold, the targets' templates placed by the MCS at each hold with the lidar
    points mapped by the final calibration (robot frame), and the overlay images
    (``overlays``: file name -> PNG bytes) embedded."""
    result = run.result
    data = _header("mocap", f"motion-capture calibration, reference {result.reference}")
    data["result"] = result.to_dict()
    final = run.final
    measurements = []
    kept = [d for d in run.diagnostics if d.kept]
    for d, obs in zip(kept, run.observations):
        measurements.append({
            "sensor": d.sensor, "kind": d.kind, "target": d.target,
            "t_s": round((d.t_ns - run.first_t_ns) / 1e9, 3), "hold": obs.hold or "",
            "initial": _r(d.residual_initial, 6), "final": _r(d.residual_final, 6), "unit": d.unit,
        })
    holds: dict[tuple[str, str], list[float]] = {}
    for m in measurements:
        if m["final"] is not None:
            holds.setdefault((m["sensor"], m["hold"] or f"{m['target']}@{m['t_s']:.0f}s"), []).append(m["final"])
    hold_rows = [{"sensor": s, "hold": h, "measurements": len(v),
                  "rms_final": float(np.sqrt(np.mean(np.square(v)))),
                  "unit": next(m["unit"] for m in measurements if m["sensor"] == s)}
                 for (s, h), v in holds.items()]
    # the scene in the robot frame: sensor triads, each hold's template, lidar points
    targets = {name: spec.target for name, spec in run.config.targets.items()}
    placed, seen = [], set()
    for obs in run.observations:
        key = (obs.target, obs.hold or obs.t_ns)
        T_rt = np.asarray(obs.T_robot_target, dtype=float)
        if key not in seen:
            seen.add(key)
            tmpl = _template_points(targets.get(obs.target))
            if tmpl is not None:
                placed.append({"target": obs.target, "hold": str(obs.hold),
                               "points": _r(transform_points(T_rt, tmpl), 3)})
    lidar_pts = {}
    for obs in run.observations:
        if obs.measured.shape[1] == 3 and obs.sensor in final:
            p = transform_points(final[obs.sensor], np.asarray(obs.measured, dtype=float))
            lst = lidar_pts.setdefault(obs.sensor, [])
            if sum(len(x) for x in lst) < 4000:
                lst.append(p[:: max(1, len(p) // 200)])
    data["scene"] = {
        "frame": result.reference,
        "sensors": [{"name": n, "kind": e.kind.value, "T_reference_sensor": _r(e.T_reference_sensor, 6),
                     "boards": [], "points": [], "status": [], "hover": []}
                    for n, e in result.sensors.items()],
        "radars": [],
        "templates": placed,
        "measured": {n: _r(np.concatenate(v), 3) for n, v in lidar_pts.items() if v},
    }
    data["coverage"] = mocap_coverage(run)
    data["mocap"] = {
        "measurements": measurements,
        "holds": hold_rows,
        "overlays": [{"name": n, "png_base64": base64.b64encode(b).decode("ascii")}
                     for n, b in sorted((overlays or {}).items())],
    }
    return data


def mocap_coverage(run: Any) -> dict[str, Any]:
    """:func:`sensor_coverage` of a motion-capture run: where each hold put the target in each
    sensor's view (the MCS target pose seen through the final calibration), the sensor's least
    determined directions and where one more hold helps most (the target taken as a board-sized
    set of four keypoints)."""
    from types import SimpleNamespace

    final = run.final
    out = {}
    for name, est in run.result.sensors.items():
        T_sensor_robot = invert(final[name])
        centres, holds, seen = [], [], set()
        for obs in run.observations:
            key = obs.hold or f"{obs.target}@{obs.t_ns}"
            if obs.sensor != name or key in seen:
                continue
            seen.add(key)
            holds.append(key)
            centres.append(transform_points(T_sensor_robot, np.asarray(obs.T_robot_target, dtype=float)[None, :3, 3])[0])
        sensor = SimpleNamespace(name=name, kind=est.kind, max_elevation_rad=0.0)
        cov = sensor_coverage(sensor, run.result, np.asarray(centres).reshape(-1, 3), list(range(len(centres))),
                              item="target hold")
        cov["labels"] = holds
        cov["item"] = "hold"
        out[name] = cov
    return out


def _template_points(target: Any, limit: int = 300) -> np.ndarray | None:
    if target is None:
        return None
    for attr in ("template", "lidar_keypoints"):
        pts = getattr(target, attr, None)
        if pts is not None:
            pts = np.asarray(pts, dtype=float).reshape(-1, 3)
            if len(pts) > limit:
                pts = pts[np.linspace(0, len(pts) - 1, limit).round().astype(int)]
            return pts
    return None


def result_only_report(kind: str, result_dict: Mapping[str, Any], absolute: Mapping[str, Any] | None = None,
                       ) -> dict[str, Any]:
    """A report from a result file alone (``calibration.yaml`` / ``absolute.yaml`` of a run
    that wrote no ``report.json``): the verdict, poses and residuals, no detections."""
    title = (f"{str(result_dict.get('mode', '')).upper()} calibration, reference {result_dict.get('reference')}"
             if kind != "absolute" else "absolute calibration")
    data = _header(kind, title)
    data["result"] = dict(result_dict)
    if absolute is not None:
        data["absolute"] = {k: v for k, v in absolute.items() if k != "relative"}
    data["note"] = "built from the result file alone: the detections were not stored (no report.json)"
    return data


__all__ = [
    "FORMAT",
    "KINDS",
    "VERSION",
    "absolute_report",
    "calibration_report",
    "coverage_data",
    "mocap_coverage",
    "mocap_report",
    "radar_arcs",
    "radar_wedge",
    "result_only_report",
    "scene_data",
    "sensor_coverage",
    "weakest_directions",
]
