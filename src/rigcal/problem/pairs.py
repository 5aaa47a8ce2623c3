"""What each sensor pair can compare, as plain arrays (shared by initialisation, residuals and
evaluation so that the RMSE reported is exactly the cost minimised).

For a pair of sensors, every common valid board contributes *anchors*: points known in one
sensor's frame (the ``frame`` sensor) and measured by the other (the ``observer``):

======================  ===========================  ==========================  ==========
pair                    frame points                 observer measures           model
======================  ===========================  ==========================  ==========
lidar/camera - same     4 circle centres             4 circle centres            point3d
lidar/camera - radar2d  reflector g(centres)         (x, y) = range (cos, sin)   radar2d
lidar/camera - radar3d  reflector g(centres)         reflector xyz               point3d
radar3d - radar2d       reflector xyz                (x, y)                      radar2d
radar3d - radar3d       reflector xyz                reflector xyz               point3d
radar2d - radar2d       (no 3D point: not comparable)
======================  ===========================  ==========================  ==========
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.problem.residuals import MODEL_POINT, MODEL_RADAR2D
from rigcal.targets.circle_board import reflectors_from_centres


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PairData:
    """Anchors of one sensor pair over its common valid boards."""

    label: str  # "a-b" in dataset order
    frame: str  # sensor whose frame holds ``points``
    observer: str  # sensor that measured ``measured``
    model: str
    points: np.ndarray  # (n, 3) in the frame sensor
    measured: np.ndarray  # (n, d) in the observer
    board: np.ndarray  # (n,) board index of each anchor
    per_board: int  # anchors per board (4 or 1)

    @property
    def boards(self) -> np.ndarray:
        return np.unique(self.board)

    @property
    def num_boards(self) -> int:
        return int(self.boards.size)


def comparable(a: SensorDetections, b: SensorDetections) -> bool:
    return not (a.kind == SensorKind.RADAR and b.kind == SensorKind.RADAR)


def pair_label(dataset: Dataset, a: str, b: str) -> str:
    order = dataset.names
    x, y = sorted((a, b), key=order.index)
    return f"{x}-{y}"


def _rank(kind: SensorKind) -> int:
    # the observer is the sensor that measures less: 2D radar, then 3D radar, then the rest
    return {SensorKind.RADAR: 2, SensorKind.RADAR3D: 1}.get(kind, 0)


def reflector_points(s: SensorDetections, dataset: Dataset) -> np.ndarray:
    """(K, 3) reflector positions in the sensor's frame (NaN where not detected)."""
    if s.kind.is_point_cloud:
        return reflectors_from_centres(s.points, dataset.board)
    if s.kind == SensorKind.RADAR3D:
        return np.array(s.points)
    raise ValueError(f"sensor '{s.name}' (2D radar) has no 3D reflector position")


def pair_data(dataset: Dataset, a: str, b: str, boards: np.ndarray | None = None) -> PairData | None:
    """Anchors for sensors ``a`` and ``b`` on their common valid boards; None if not comparable.

    ``boards`` optionally restricts to a subset of board indices. On all boards the result is
    computed once per dataset (its arrays read-only).
    """
    if boards is None:
        key = ("pair_data", a, b)
        if key not in dataset.derived:
            found = _pair_data(dataset, a, b, None)
            if found is not None:
                for arr in (found.points, found.measured, found.board):
                    arr.setflags(write=False)
            dataset.derived[key] = found
        return dataset.derived[key]
    return _pair_data(dataset, a, b, boards)


def _pair_data(dataset: Dataset, a: str, b: str, boards: np.ndarray | None) -> PairData | None:
    sa, sb = dataset.sensor(a), dataset.sensor(b)
    if not comparable(sa, sb):
        return None
    label = pair_label(dataset, a, b)
    # choose frame/observer: the less informative sensor observes; ties keep dataset order
    first, second = sorted((sa, sb), key=lambda s: dataset.names.index(s.name))
    frame, obs = (first, second) if _rank(first.kind) <= _rank(second.kind) else (second, first)
    common = frame.valid & obs.valid
    if boards is not None:
        sel = np.zeros_like(common)
        sel[np.asarray(boards, dtype=int)] = True
        common &= sel
    ks = np.flatnonzero(common)
    if frame.kind.is_point_cloud and obs.kind.is_point_cloud:
        pts = frame.points[ks].reshape(-1, 3)
        meas = obs.points[ks].reshape(-1, 3)
        board = np.repeat(ks, 4)
        per = 4
        model = MODEL_POINT
    else:
        pts = reflector_points(frame, dataset)[ks]
        meas = obs.points[ks]
        board = ks
        per = 1
        model = MODEL_RADAR2D if obs.kind == SensorKind.RADAR else MODEL_POINT
    return PairData(label, frame.name, obs.name, model, pts, meas, board, per)


def all_pairs(dataset: Dataset) -> list[tuple[str, str]]:
    """Every comparable sensor pair, in dataset order (:attr:`Dataset.pairs`, derived once)."""
    return list(dataset.pairs)
