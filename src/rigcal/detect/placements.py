"""Board placements found automatically in a recording.

The original tool needed a person to toggle recording at each board placement. Here each
sensor's detections are split into *stable periods* - consecutive detections that stay within a
tolerance of each other for at least a minimum time - and the periods of all sensors are matched
by time overlap into placements. Within a period the detections are averaged (after dropping
frames far from the period's median, e.g. while the board starts to move). Time windows can also
be given by hand.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from rigcal.dataset import BoardGeometry, Dataset, SensorDetections, SensorKind
from rigcal.detect.result import BoardDetection
from rigcal.errors import InputError

NS = 1_000_000_000


@dataclass(frozen=True)
class StabilityRule:
    """When a run of detections counts as the board standing still.

    tolerance_m: largest distance of a detection's anchor (centroid of the 4 centres, or the
    radar point) from the run's median; min_duration_s: shortest stable period;
    max_gap_s: longest gap between consecutive detections inside one period (at least 2.5
    frame intervals of the sensor, so slow sensors still form periods); min_frames.
    """

    tolerance_m: float = 0.03
    radar_tolerance_m: float = 0.10
    min_duration_s: float = 1.0
    max_gap_s: float = 0.6
    min_frames: int = 3


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class StablePeriod:
    sensor: str
    start_ns: int
    end_ns: int
    points: np.ndarray  # averaged detection in the sensor frame
    frames: int  # detections averaged
    rejected: int  # detections in the period dropped as off the median
    spread_m: float  # RMS distance of the kept anchors from their mean

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Placement:
    """One board placement: a time window and each sensor's stable period in it (if any)."""

    index: int
    start_ns: int
    end_ns: int
    periods: Mapping[str, StablePeriod] = field(default_factory=dict)


def _anchor(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    return p.reshape(-1, p.shape[-1]).mean(axis=0) if p.ndim == 2 else p


def _summarise(sensor: str, dets: Sequence[BoardDetection], tol: float) -> StablePeriod | None:
    anchors = np.array([_anchor(d.points) for d in dets])
    med = np.median(anchors, axis=0)
    keep = np.linalg.norm(anchors - med, axis=1) <= tol
    if not np.any(keep):
        return None
    pts = np.mean([d.points for d, k in zip(dets, keep) if k], axis=0)
    kept = anchors[keep]
    return StablePeriod(
        sensor=sensor,
        start_ns=dets[0].t_ns,
        end_ns=dets[-1].t_ns,
        points=pts,
        frames=int(keep.sum()),
        rejected=int((~keep).sum()),
        spread_m=float(np.sqrt(np.mean(np.sum((kept - kept.mean(axis=0)) ** 2, axis=1)))),
    )


def stable_periods(
    sensor: str, detections: Iterable[BoardDetection], rule: StabilityRule, radar: bool = False
) -> list[StablePeriod]:
    """Split one sensor's detections (any order) into stable periods."""
    dets = sorted(detections, key=lambda d: d.t_ns)
    tol = rule.radar_tolerance_m if radar else rule.tolerance_m
    # a slow sensor's frames are further apart: the gap allowed follows its frame interval
    max_gap = rule.max_gap_s
    if len(dets) > 2:
        dt = np.diff([d.t_ns for d in dets]) / NS
        max_gap = max(max_gap, 2.5 * float(np.median(dt)))
    out: list[StablePeriod] = []
    run: list[BoardDetection] = []
    run_anchors: list[np.ndarray] = []

    def close_run() -> None:
        if len(run) >= rule.min_frames and (run[-1].t_ns - run[0].t_ns) / NS >= rule.min_duration_s:
            p = _summarise(sensor, run, tol)
            if p is not None and p.frames >= rule.min_frames:
                out.append(p)

    for d in dets:
        a = _anchor(d.points)
        if run:
            gap = (d.t_ns - run[-1].t_ns) / NS
            ref = np.median(np.array(run_anchors[-10:]), axis=0)
            if gap > max_gap or np.linalg.norm(a - ref) > tol:
                close_run()
                run, run_anchors = [], []
        run.append(d)
        run_anchors.append(a)
    if run:
        close_run()
    return out


def match_placements(periods: Mapping[str, Sequence[StablePeriod]], min_sensors: int = 1) -> list[Placement]:
    """Group the stable periods of all sensors into placements by time overlap.

    Periods overlapping in time (directly or through another sensor's period) form one
    placement; a sensor with several periods in one placement keeps the longest overlap.
    """
    items = [(p.start_ns, p.end_ns, s, p) for s, ps in periods.items() for p in ps]
    items.sort(key=lambda x: x[0])
    groups: list[list[tuple[int, int, str, StablePeriod]]] = []
    end = None
    for it in items:
        if groups and end is not None and it[0] <= end:
            groups[-1].append(it)
            end = max(end, it[1])
        else:
            groups.append([it])
            end = it[1]
    out = []
    for g in groups:
        start = min(i[0] for i in g)
        stop = max(i[1] for i in g)
        chosen: dict[str, StablePeriod] = {}
        for _, _, s, p in g:
            if s not in chosen or p.duration_s > chosen[s].duration_s:
                chosen[s] = p
        if len(chosen) >= min_sensors:
            out.append(Placement(len(out), start, stop, chosen))
    return out


def placements_from_windows(
    detections: Mapping[str, Sequence[BoardDetection]],
    windows_ns: Sequence[tuple[int, int]],
    rule: StabilityRule,
    kinds: Mapping[str, SensorKind],
) -> list[Placement]:
    """Placements from time windows given by hand (start, end in ns)."""
    out = []
    for k, (a, b) in enumerate(windows_ns):
        if b <= a:
            raise InputError(f"time window {k}: end {b} is not after start {a}")
        chosen = {}
        for s, dets in detections.items():
            inside = sorted((d for d in dets if a <= d.t_ns <= b), key=lambda d: d.t_ns)
            if len(inside) >= 1:
                tol = rule.radar_tolerance_m if kinds[s].is_radar else rule.tolerance_m
                p = _summarise(s, inside, tol)
                if p is not None:
                    chosen[s] = p
        out.append(Placement(k, int(a), int(b), chosen))
    return out


@dataclass(frozen=True)
class SensorSpec:
    name: str
    kind: SensorKind
    frame_id: str = ""
    max_elevation_rad: float | None = None


def dataset_from_placements(
    placements: Sequence[Placement],
    sensors: Sequence[SensorSpec],
    board: BoardGeometry = BoardGeometry(),
    reference: str | None = None,
    source: str = "",
) -> Dataset:
    """The K placements as a :class:`Dataset` (NaN where a sensor had no stable period)."""
    if not placements:
        raise InputError(f"{source or 'recording'}: no board placement found")
    out = []
    for spec in sensors:
        shape = spec.kind.point_shape
        pts = np.full((len(placements),) + shape, np.nan)
        for k, pl in enumerate(placements):
            p = pl.periods.get(spec.name)
            if p is not None:
                pts[k] = p.points
        extra = {} if spec.max_elevation_rad is None else {"max_elevation_rad": spec.max_elevation_rad}
        out.append(
            SensorDetections(
                name=spec.name,
                kind=spec.kind,
                points=pts,
                frame_id=spec.frame_id or spec.name,
                source=source,
                **extra,
            )
        )
    return Dataset(tuple(out), board=board, reference=reference, source=source)
