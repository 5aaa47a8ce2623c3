"""Radar board detector: the corner reflector among the detections of one radar frame.

Keep the detections inside the RCS window and the range (and optional azimuth) window, then
pick one by the selection rule - by default the closest, since the board is assumed to be the
nearest strong reflector (Domhof et al. 2021, III-B).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.detect.result import BoardDetection, DetectionFailure, DetectionResult
from rigcal.errors import ConfigError
from rigcal.recording import RadarFrame

SELECTION_RULES = ("closest", "farthest", "highest_rcs", "lowest_rcs")


@dataclass(frozen=True)
class RadarDetectorConfig:
    """Windows in dBsm, metres and degrees (None = unbounded); ``select`` one of
    ``closest`` (default), ``farthest``, ``highest_rcs``, ``lowest_rcs``."""

    rcs_min_dbsm: float | None = None
    rcs_max_dbsm: float | None = None
    range_min_m: float = 0.5
    range_max_m: float | None = None
    azimuth_min_deg: float | None = None
    azimuth_max_deg: float | None = None
    select: str = "closest"

    def __post_init__(self) -> None:
        if self.select not in SELECTION_RULES:
            raise ConfigError(
                f"radar detector: select '{self.select}' is not one of {', '.join(SELECTION_RULES)}"
            )
        for lo, hi, lo_key, hi_key in (
            (self.rcs_min_dbsm, self.rcs_max_dbsm, "rcs_min_dbsm", "rcs_max_dbsm"),
            (self.range_min_m, self.range_max_m, "range_min_m", "range_max_m"),
            (self.azimuth_min_deg, self.azimuth_max_deg, "azimuth_min_deg", "azimuth_max_deg"),
        ):
            for value, key in ((lo, lo_key), (hi, hi_key)):
                if value is None and key != "range_min_m":
                    continue
                if (isinstance(value, bool) or not isinstance(value, (int, float))
                        or not math.isfinite(value)):
                    raise ConfigError(
                        f"radar detector: {key} is {value!r}, expected a finite number"
                        + ("" if key == "range_min_m" else " or null (unbounded)")
                    )
            if lo is not None and hi is not None and lo > hi:
                raise ConfigError(
                    f"radar detector: {lo_key.rsplit('_', 2)[0]} window {lo_key}/{hi_key} "
                    f"[{lo}, {hi}] is empty; expected {lo_key} <= {hi_key}"
                )


def detect_board_radar(frame: RadarFrame, config: RadarDetectorConfig = RadarDetectorConfig()) -> DetectionResult:
    """The reflector's detection (x, y) or (x, y, z) in the radar frame, or why there is none."""
    pts = frame.points
    n = pts.shape[0]
    if n == 0:
        return DetectionFailure(frame.sensor, frame.t_ns, "no_detections", "the radar frame is empty")
    rng = np.linalg.norm(pts, axis=1)
    az = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    rcs = frame.rcs_dbsm
    keep = np.ones(n, dtype=bool)
    c = config
    if c.rcs_min_dbsm is not None or c.rcs_max_dbsm is not None:
        known = np.isfinite(rcs)
        keep &= known
        if c.rcs_min_dbsm is not None:
            keep &= np.where(known, rcs >= c.rcs_min_dbsm, False)
        if c.rcs_max_dbsm is not None:
            keep &= np.where(known, rcs <= c.rcs_max_dbsm, False)
    keep &= rng >= c.range_min_m
    if c.range_max_m is not None:
        keep &= rng <= c.range_max_m
    if c.azimuth_min_deg is not None:
        keep &= az >= c.azimuth_min_deg
    if c.azimuth_max_deg is not None:
        keep &= az <= c.azimuth_max_deg
    if not np.any(keep):
        return DetectionFailure(
            frame.sensor,
            frame.t_ns,
            "no_candidate",
            f"none of {n} detections inside the windows (RCS {_window(c.rcs_min_dbsm, c.rcs_max_dbsm)} "
            f"dBsm, range {_window(c.range_min_m, c.range_max_m)} m); RCS seen "
            f"{_span(rcs)} dBsm, range seen {_span(rng)} m",
        )
    idx = np.flatnonzero(keep)
    key = {
        "closest": rng[idx],
        "farthest": -rng[idx],
        "highest_rcs": -np.nan_to_num(rcs[idx], nan=-np.inf),
        "lowest_rcs": np.nan_to_num(rcs[idx], nan=np.inf),
    }[c.select]
    i = int(idx[int(np.argmin(key))])
    return BoardDetection(
        frame.sensor,
        frame.t_ns,
        pts[i],
        {"range_m": float(rng[i]), "rcs_dbsm": float(rcs[i]), "candidates": float(idx.size)},
    )


def _window(lo, hi) -> str:
    return f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


def _span(v: np.ndarray) -> str:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return "n/a"
    return f"{v.min():.3g}..{v.max():.3g}"

