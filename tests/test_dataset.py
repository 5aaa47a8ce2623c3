"""rigcal.dataset.Dataset.pairs: the comparable sensor pairs, derived once per dataset."""

from __future__ import annotations

import numpy as np

from rigcal.dataset import Dataset, SensorDetections, SensorKind


def _sensor(name: str, kind: SensorKind, k: int = 3) -> SensorDetections:
    rows = {SensorKind.RADAR: (k, 2), SensorKind.RADAR3D: (k, 3)}.get(kind, (k, 4, 3))
    return SensorDetections(name, kind, np.ones(rows))


def test_pairs_in_dataset_order_without_two_2d_radars():
    ds = Dataset((_sensor("lidar1", SensorKind.LIDAR), _sensor("radar1", SensorKind.RADAR),
                  _sensor("radar2", SensorKind.RADAR), _sensor("radar3", SensorKind.RADAR3D)))
    assert ds.pairs == (("lidar1", "radar1"), ("lidar1", "radar2"), ("lidar1", "radar3"),
                        ("radar1", "radar3"), ("radar2", "radar3"))
    assert ds.pairs is ds.pairs  # derived once
