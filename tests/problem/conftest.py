"""Shared fixtures of the problem tests: the real TU Delft Prius detections and a cache of
calibrations of them, so that each (mode, options) runs once per test session."""

from __future__ import annotations

from pathlib import Path

import pytest

from rigcal.io.dataset.manifest import dataset_from_files
from rigcal.problem.calibrate import CalibrationOptions, calibrate

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "tudelft_prius"


@pytest.fixture(scope="session")
def real_dataset():
    """lidar1, camera1, radar1 of the original tool's example data (29 boards)."""
    det = REAL / "detections"
    if not all((det / f).is_file() for f in ("lidar.csv", "camera.csv", "radar.csv")):
        pytest.skip("../shared/data not present")
    return dataset_from_files(
        lidar=[det / "lidar.csv"], camera=[det / "camera.csv"], radar=[det / "radar.csv"]
    )


@pytest.fixture(scope="session")
def real_calibration(real_dataset):
    """``get(mode, **options)``: the calibration of the real data, computed once per key."""
    cache = {}

    def get(mode: str, **options):
        key = (mode, tuple(sorted(options.items())))
        if key not in cache:
            cache[key] = calibrate(real_dataset, CalibrationOptions(mode=mode, **options))
        return cache[key]

    return get
