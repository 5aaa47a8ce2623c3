"""The external scanner as a calibration sensor: a dense static scan of the board, and its detector.

Absolute calibration (paper, III-E and IV-B) needs a sensor that sees both the vehicle and the
calibration boards: a terrestrial laser scanner (a Leica P40 in the paper). To the relative
calibration it is one more lidar - it detects the four circle centres of each board - whose
frame is the **external frame** in which the vehicle's wheels and ground are labelled.

* :class:`DenseScannerModel` / :func:`leica_p40`: a static scanner casting a regular grid of
  rays (``angle_step_deg``, 0.05 deg for the P40-like model; azimuth = ``atan2(y, x)``,
  elevation = ``atan2(z, hypot(x, y))`` in the scanner frame: x forward, y left, z up, a
  levelled scanner) with Gaussian range noise (``range_sigma_m``, 2 mm). A full dome at
  0.05 deg is 26 million rays, so a scan covers only an angular window (:class:`AngularWindow`),
  by default the board's plate seen from the scanner plus ``window_margin_deg`` on each side
  (:func:`board_window`): at 3 m that is about 0.4 million rays.
* :func:`scan_dense`: one station's scan of a :class:`~rigcal.sim.raw.scene.Scene` (board,
  ground, back wall) as a :class:`~rigcal.recording.PointCloudFrame` in the scanner frame, with
  an ``intensity`` field and, like an exported terrestrial scan, **no** ``ring`` field.
* :func:`detect_board_dense`: the board's four circle centres in a dense scan, with
  :func:`rigcal.detect.lidar.detect_board_lidar` and the settings of
  :func:`dense_detector_config`: rings are recovered by elevation binning (the scan's rows
  share one elevation exactly, the gap between rows is the angular step, so the binning gap is
  half a step), the plane and circle tolerances are tightened to the scanner's millimetre noise
  (the original tool's Leica settings use 2 cm for the plate plane and 1 cm for the circles),
  and the ground is removed with a 3 cm band.

Accuracy on simulated scans (``tests/absolute/test_external.py``): board centres at 3-8 m
within 0.13 mm of the truth (median over 11 boards x 4 centres; worst 0.36 mm). The hole edge
of one row lies half-way between the last plate return and the first return through the hole
(error within half an angular step, uniform, +-2.6 mm at 6 m), and a hole is crossed by 20-60
rows, so its centre is good to a fraction of a millimetre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.detect.lidar import LidarDetectorConfig, detect_board_lidar
from rigcal.detect.result import DetectionResult
from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid
from rigcal.recording import PointCloudFrame
from rigcal.sim.raw.lidar import range_returns
from rigcal.sim.raw.scene import Scene, check_sim_call

__all__ = [
    "AngularWindow",
    "DenseScannerModel",
    "board_window",
    "dense_detector_config",
    "detect_board_dense",
    "leica_p40",
    "scan_dense",
]

#: Most rays one call of :func:`scan_dense` casts (about 0.4 GB of float64 work arrays).
MAX_RAYS = 4_000_000


def _finite(v: Any, what: str, *, positive: bool = False, lo: float | None = None) -> float:
    ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    x = float(v) if ok else float("nan")
    if not math.isfinite(x) or (positive and x <= 0) or (lo is not None and x < lo):
        bound = " > 0" if positive else (f" >= {lo:g}" if lo is not None else "")
        raise InputError(f"{what} must be a finite number{bound}, got {v!r}")
    return x


@dataclass(frozen=True)
class DenseScannerModel:
    """A static terrestrial laser scanner (P40-like).

    * ``angle_step_deg``: spacing of the ray grid in azimuth and elevation [deg] (0.05 deg is
      4.4 mm at 5 m; the P40's finest setting is about 0.0045 deg, its usual 6 mm at 10 m);
    * ``range_sigma_m``: Gaussian range noise [m];
    * ``min_range_m`` / ``max_range_m``: returns outside are lost;
    * ``max_incidence_deg``: returns at a steeper incidence on a surface are lost;
    * ``window_margin_deg``: margin around the plate of the default window (:func:`board_window`).
    """

    angle_step_deg: float = 0.05
    range_sigma_m: float = 0.002
    min_range_m: float = 0.4
    max_range_m: float = 120.0
    max_incidence_deg: float = 85.0
    window_margin_deg: float = 2.0
    name: str = "leica_p40"

    def __post_init__(self) -> None:
        where = f"dense scanner '{self.name}'"
        step = _finite(self.angle_step_deg, f"{where}: angle_step_deg", positive=True)
        if step > 5.0:
            raise InputError(f"{where}: angle_step_deg must be at most 5 deg, got {step!r}")
        _finite(self.range_sigma_m, f"{where}: range_sigma_m", lo=0.0)
        lo = _finite(self.min_range_m, f"{where}: min_range_m", lo=0.0)
        hi = _finite(self.max_range_m, f"{where}: max_range_m", positive=True)
        if not lo < hi:
            raise InputError(
                f"{where}: min_range_m ({lo}) must be below max_range_m ({hi})"
            )
        inc = _finite(self.max_incidence_deg, f"{where}: max_incidence_deg", positive=True)
        if inc > 90.0:
            raise InputError(f"{where}: max_incidence_deg must be in (0, 90], got {inc!r}")
        _finite(self.window_margin_deg, f"{where}: window_margin_deg", lo=0.0)
        for name in ("angle_step_deg", "range_sigma_m", "min_range_m", "max_range_m",
                     "max_incidence_deg", "window_margin_deg"):
            object.__setattr__(self, name, float(getattr(self, name)))


def leica_p40(angle_step_deg: float = 0.05, range_sigma_m: float = 0.002) -> DenseScannerModel:
    """A Leica-P40-like scanner: ``angle_step_deg`` grid (0.05 deg), ``range_sigma_m`` (2 mm)
    range noise, 0.4-120 m."""
    return DenseScannerModel(angle_step_deg=angle_step_deg, range_sigma_m=range_sigma_m)


class AngularWindow(NamedTuple):
    """The part of the scanner's dome a scan covers, in the scanner frame [deg]:
    ``azimuth_deg`` (min, max) - may run past +-180 (it is used through sin / cos) - and
    ``elevation_deg`` (min, max) within (-90, 90)."""

    azimuth_deg: tuple[float, float]
    elevation_deg: tuple[float, float]


def _check_window(window: Any) -> AngularWindow:
    try:
        (a0, a1), (e0, e1) = window
        a0, a1, e0, e1 = (float(v) for v in (a0, a1, e0, e1))
    except (TypeError, ValueError):
        raise InputError(
            f"window: expected ((az_min, az_max), (el_min, el_max)) in degrees, got {window!r}"
        ) from None
    if not all(math.isfinite(v) for v in (a0, a1, e0, e1)):
        raise InputError(f"window: angles must be finite, got {window!r}")
    if not (a0 < a1 and a1 - a0 <= 360.0):
        raise InputError(
            f"window: azimuth must be (min, max) with min < max spanning at most 360 deg, "
            f"got ({a0}, {a1})"
        )
    if not (-90.0 < e0 < e1 < 90.0):
        raise InputError(
            f"window: elevation must be (min, max) with -90 < min < max < 90 deg, got ({e0}, {e1})"
        )
    return AngularWindow((a0, a1), (e0, e1))


def board_window(
    T_world_scanner: np.ndarray, scene: Scene, margin_deg: float = 2.0
) -> AngularWindow:
    """The angular box around the board's plate seen from the scanner at ``T_world_scanner``
    (scanner frame -> world), widened by ``margin_deg`` on each side (so some wall and ground
    around the plate are scanned too; the detector needs returns through the holes)."""
    T = as_rigid(T_world_scanner, "board_window: T_world_scanner")
    margin = _finite(margin_deg, "board_window: margin_deg", lo=0.0)
    corners = scene.plate_corners_world()
    p = (corners - T[:3, 3]) @ T[:3, :3]  # into the scanner frame
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    ref = float(np.degrees(np.arctan2(p[:, 1].sum(), p[:, 0].sum())))
    rel = (az - ref + 180.0) % 360.0 - 180.0
    if np.ptp(rel) >= 180.0 - 2 * margin:
        raise InputError(
            "board_window: the board spans more than 180 deg of azimuth seen from the scanner "
            "(is the scanner inside the plate?)"
        )
    e0 = max(float(el.min()) - margin, -89.0)
    e1 = min(float(el.max()) + margin, 89.0)
    a0 = ref + float(rel.min()) - margin
    a1 = ref + float(rel.max()) + margin
    return AngularWindow((a0, a1), (e0, e1))


def _grid(lo: float, hi: float, step: float) -> np.ndarray:
    """Grid angles [deg]: the multiples of ``step`` within [lo, hi] (a fixed scanner grid)."""
    k0 = math.ceil(lo / step - 1e-9)
    k1 = math.floor(hi / step + 1e-9)
    return step * np.arange(k0, k1 + 1, dtype=float)


def scan_dense(
    model: DenseScannerModel,
    T_world_scanner: np.ndarray,
    scene: Scene,
    rng: np.random.Generator,
    *,
    window: AngularWindow | tuple | None = None,
    t_ns: int = 0,
    sensor: str = "external",
    frame_id: str = "",
) -> PointCloudFrame:
    """One station's dense scan of ``scene`` from ``T_world_scanner`` (scanner frame -> world)
    as a :class:`~rigcal.recording.PointCloudFrame` in the scanner frame [m].

    Rays: every azimuth and elevation on the ``model.angle_step_deg`` grid inside ``window``
    (default :func:`board_window` with the model's margin); rays that hit nothing, land outside
    the range limits or meet a surface beyond ``max_incidence_deg`` give no return. Points are
    ``(range + noise) * direction``, ordered by elevation row then azimuth; field ``intensity``
    (float32, ``255 * reflectivity * |cos incidence|``). Draws one normal per ray cast from
    ``rng`` whatever is hit, so a seed reproduces the scan. More than :data:`MAX_RAYS` rays is an
    InputError (use a coarser step or a smaller window).
    """
    T = check_sim_call(
        f"scan_dense '{sensor}'", model, DenseScannerModel, scene, rng, T_world_scanner,
        "T_world_scanner",
    )
    win = (
        board_window(T, scene, model.window_margin_deg) if window is None else _check_window(window)
    )
    step = model.angle_step_deg
    az = np.radians(_grid(*win.azimuth_deg, step))
    el = np.radians(_grid(*win.elevation_deg, step))
    n = az.size * el.size
    if n == 0:
        raise InputError(
            f"scan_dense '{sensor}': the window {tuple(win)} holds no ray of the "
            f"{step} deg grid"
        )
    if n > MAX_RAYS:
        raise InputError(
            f"scan_dense '{sensor}': the window {np.round(win.azimuth_deg, 2).tolist()} x "
            f"{np.round(win.elevation_deg, 2).tolist()} deg at {step} deg is {n} rays, more "
            f"than {MAX_RAYS}; use a coarser angle_step_deg or a smaller window"
        )
    ce, se = np.cos(el)[:, None], np.sin(el)[:, None]
    dirs = np.stack(
        np.broadcast_arrays(ce * np.cos(az)[None, :], ce * np.sin(az)[None, :], se), axis=-1
    ).reshape(-1, 3)
    noise = rng.standard_normal(n)
    pts, intensity, _ = range_returns(model, T, scene, dirs, noise)
    return PointCloudFrame(
        sensor=sensor,
        t_ns=t_ns,
        points_xyz=pts,
        fields={"intensity": intensity},
        frame_id=frame_id or sensor,
    )


def dense_detector_config(angle_step_deg: float = 0.05, **overrides: Any) -> LidarDetectorConfig:
    """Recommended :class:`~rigcal.detect.lidar.LidarDetectorConfig` for a dense scan with an
    ``angle_step_deg`` grid and millimetre noise; ``overrides`` replace single fields.

    ============================  =========  ==========================================
    field                         value      why
    ============================  =========  ==========================================
    ``ring_gap_deg``              step / 2   rows are one step apart in elevation
    ``ground_threshold_m``        0.03       mm noise: a thin ground band suffices
    ``plane_threshold_m``         0.01       the original's Leica setting is 0.02
    ``circle_threshold_m``        0.005      edge points scatter +-step/2 * range
    ``square_tolerance_m``        0.01       per-hole centres are good to ~1 mm
    ``jump_m``                    0.05       the wall behind a hole is far further
    ``vote_cell_m``               0.005      finer Hough cells for finer edges
    ``max_range_m``               20         a garage; boards are 3-10 m away
    ============================  =========  ==========================================
    """
    step = _finite(angle_step_deg, "dense_detector_config: angle_step_deg", positive=True)
    base = LidarDetectorConfig(
        max_range_m=20.0,
        ground_threshold_m=0.03,
        plane_threshold_m=0.01,
        circle_threshold_m=0.005,
        square_tolerance_m=0.01,
        jump_m=0.05,
        ring_gap_deg=step / 2.0,
        vote_cell_m=0.005,
    )
    try:
        return replace(base, **overrides)
    except TypeError as exc:
        raise InputError(f"dense_detector_config: {exc}") from None


def detect_board_dense(
    frame: PointCloudFrame,
    board: BoardGeometry = BoardGeometry(),
    config: LidarDetectorConfig | None = None,
) -> DetectionResult:
    """The board's four circle centres (4, 3) [m] in a dense scan (scanner frame), TL, TR, BL,
    BR as seen from the scanner, or a :class:`~rigcal.detect.result.DetectionFailure` with its
    reason: :func:`~rigcal.detect.lidar.detect_board_lidar` with ``config`` (default
    :func:`dense_detector_config` at 0.05 deg). A ``ring`` field in the frame is used when
    present; else rows are recovered from the elevations."""
    if not isinstance(frame, PointCloudFrame):
        raise InputError(
            f"detect_board_dense: expected a PointCloudFrame, got {type(frame).__name__}"
        )
    cfg = dense_detector_config() if config is None else config
    if not isinstance(cfg, LidarDetectorConfig):
        raise InputError(
            f"detect_board_dense: config must be a LidarDetectorConfig, got {type(cfg).__name__}"
        )
    return detect_board_lidar(frame, board, cfg)
