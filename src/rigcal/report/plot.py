"""Plots of a calibration: every sensor's detections mapped into the reference frame.

Like Fig. 6a of Domhof et al.: when the calibration is right, the detections of the same board by
different sensors coincide. matplotlib is imported here only, inside the function, with the
non-interactive Agg backend.
"""

from __future__ import annotations

import io
import logging
import math
import os
from pathlib import Path

import numpy as np

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import transform_points
from rigcal.problem.result import CalibrationResult

log = logging.getLogger(__name__)

_MARKERS = {
    SensorKind.LIDAR: "o",
    SensorKind.CAMERA: "s",
    SensorKind.RADAR: "^",
    SensorKind.RADAR3D: "D",
}
_ARC_SAMPLES = 9


def _detections_in_reference(
    det: SensorDetections, T_ref_sensor: np.ndarray, boards: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) of ``boards`` in the reference frame and, for a 2D radar, their elevation
    arcs (M, A, 3); other kinds get no arcs."""
    pts = np.asarray(det.points)[boards]
    if det.kind.is_point_cloud:
        return transform_points(T_ref_sensor, pts.reshape(-1, 3)), np.zeros((0, _ARC_SAMPLES, 3))
    if det.kind is SensorKind.RADAR3D:
        return transform_points(T_ref_sensor, pts.reshape(-1, 3)), np.zeros((0, _ARC_SAMPLES, 3))
    # 2D radar: the reported (x, y) on the radar plane, plus the arc of possible elevations
    on_plane = np.concatenate([pts, np.zeros((pts.shape[0], 1))], axis=1)
    rng = np.linalg.norm(pts, axis=1)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    el = np.linspace(-det.max_elevation_rad, det.max_elevation_rad, _ARC_SAMPLES)
    arcs = rng[:, None, None] * np.stack(
        [
            np.cos(el)[None, :] * np.cos(az)[:, None],
            np.cos(el)[None, :] * np.sin(az)[:, None],
            np.broadcast_to(np.sin(el)[None, :], (pts.shape[0], _ARC_SAMPLES)),
        ],
        axis=-1,
    )
    arcs_ref = transform_points(T_ref_sensor, arcs.reshape(-1, 3)).reshape(arcs.shape)
    return transform_points(T_ref_sensor, on_plane), arcs_ref


def plot_calibration(
    dataset: Dataset,
    result: CalibrationResult,
    path: str | os.PathLike[str],
    *,
    dpi: int = 120,
) -> Path:
    """Write a PNG of all valid detections in the reference frame; returns the path written.

    Two panels, top view (x, y) and side view (x, z) of the reference frame, equal aspect.
    Lidar / camera: the four circle centres of each board; 3D radar: the reflector; 2D radar: the
    reported point on the radar plane (z = 0 in the radar frame) with the arc of elevations within
    the radar's field of view it could come from. Boards in ``result.outliers`` are drawn with an
    ``x``; boards excluded otherwise (ignore file, undetected) are left out. Each sensor's pose is
    drawn as an axis triad (x red, y green, z blue) with its name. The title gives the mode,
    the reference and the RMSE of every pair.
    """
    # the object-oriented API on the Agg canvas: no pyplot, no global backend state
    from matplotlib import rcParams
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    missing = [n for n in dataset.names if n not in result.sensors]
    if len(missing) == len(dataset.names):
        raise InputError(
            f"plot: the result calibrates none of the dataset's sensors {list(dataset.names)} "
            f"(result sensors: {sorted(result.sensors)})"
        )
    for name in missing:
        log.warning("plot: sensor '%s' has no estimate in the result; not drawn", name)

    fig = Figure(figsize=(13, 6.5))
    FigureCanvasAgg(fig)
    ax_top, ax_side = fig.subplots(1, 2)
    if True:  # one figure per call, dropped on return (no pyplot registry to close)
        colours = rcParams["axes.prop_cycle"].by_key()["color"]
        all_pts = []
        for i, det in enumerate(dataset.sensors):
            if det.name not in result.sensors:
                continue
            colour = colours[i % len(colours)]
            T = np.asarray(result.sensors[det.name].T_reference_sensor, dtype=float)
            outliers = set(int(b) for b in result.outliers.get(det.name, ()))
            detected = det.detected
            idx_out = np.array(
                sorted(b for b in outliers if 0 <= b < det.num_boards and detected[b]), dtype=int
            )
            valid = det.valid.copy()
            valid[list(outliers & set(range(det.num_boards)))] = False
            idx_in = np.flatnonzero(valid)
            marker = _MARKERS[det.kind]
            label = f"{det.name} ({det.kind.value}, {idx_in.size} boards)"
            pts_in, arcs_in = _detections_in_reference(det, T, idx_in)
            pts_out, arcs_out = _detections_in_reference(det, T, idx_out)
            all_pts.extend([pts_in, pts_out, T[None, :3, 3]])
            for ax, (a, b) in ((ax_top, (0, 1)), (ax_side, (0, 2))):
                ax.scatter(
                    pts_in[:, a], pts_in[:, b], s=14, marker=marker, color=colour,
                    label=label, alpha=0.8, linewidths=0,
                )
                if pts_out.size:
                    ax.scatter(
                        pts_out[:, a], pts_out[:, b], s=40, marker="x", color=colour,
                        label=f"{det.name} outliers ({idx_out.size})",
                    )
                for arc, style in ((arcs_in, "-"), (arcs_out, ":")):
                    if len(arc):  # every elevation arc of the sensor as one artist
                        ax.add_collection(LineCollection(
                            arc[:, :, [a, b]], colors=colour, linestyles=style, lw=0.8, alpha=0.6,
                        ))
        extent = np.concatenate([p for p in all_pts if p.size], axis=0)
        span = float(np.ptp(extent, axis=0).max()) if extent.shape[0] > 1 else 1.0
        triad = max(0.05 * span, 0.1)
        for ax, (a, b) in ((ax_top, (0, 1)), (ax_side, (0, 2))):
            segments, seg_colours = [], []
            for name, est in result.sensors.items():
                T = np.asarray(est.T_reference_sensor, dtype=float)
                origin = T[:3, 3]
                for axis, c in zip(range(3), ("tab:red", "tab:green", "tab:blue")):
                    tip = origin + triad * T[:3, axis]
                    segments.append([(origin[a], origin[b]), (tip[a], tip[b])])
                    seg_colours.append(c)
                ax.annotate(name, (origin[a], origin[b]), textcoords="offset points",
                            xytext=(4, 4), fontsize=8)
            ax.add_collection(LineCollection(segments, colors=seg_colours, lw=1.5))
            ax.autoscale_view()
        ref = result.reference
        ax_top.set_title(f"top view (x, y) of {ref}")
        ax_top.set_xlabel("x [m]")
        ax_top.set_ylabel("y [m]")
        ax_side.set_title(f"side view (x, z) of {ref}")
        ax_side.set_xlabel("x [m]")
        ax_side.set_ylabel("z [m]")
        for ax in (ax_top, ax_side):
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(True, lw=0.4, alpha=0.5)
        ax_top.legend(loc="lower left", fontsize=8)  # "best" searches every artist: slow
        rmse = ", ".join(
            f"{pair} {1000.0 * v:.1f} mm" if math.isfinite(v) else f"{pair} n/a"
            for pair, v in result.rmse_m.items()
        )
        fig.suptitle(
            f"{result.mode.upper()} calibration, reference {ref}"
            + (f"\nRMSE: {rmse}" if rmse else ""),
            fontsize=11,
        )
        fig.subplots_adjust(left=0.06, right=0.985, bottom=0.08, top=0.87, wspace=0.18)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)

    from rigcal.io.atomic import atomic_write_bytes

    return atomic_write_bytes(path, buf.getvalue())
