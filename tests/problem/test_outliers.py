"""Outlier detection by consensus: displaced detections are found exactly, and excluding them
gives the calibration the clean data give."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.evaluate import evaluate_pairs
from rigcal.sim.rig import make_rig_placements, move_boards, prius_like_rig, simulate

#: two lidar boards displaced by 4 m, two radar boards by 1 m and 5 m (distinct boards, so that
#: each corrupted board has exactly one culprit)
LIDAR_BOARDS = (3, 11)
RADAR_1M, RADAR_5M = 7, 19
EXPECTED = {"lidar1": LIDAR_BOARDS, "radar1": (RADAR_1M, RADAR_5M)}


def corrupt(dataset):
    bad = move_boards(dataset, "lidar1", LIDAR_BOARDS, [0.0, 4.0, 0.0])
    bad = move_boards(bad, "radar1", [RADAR_1M], [0.6, 0.8])
    return move_boards(bad, "radar1", [RADAR_5M], [3.0, -4.0])


@pytest.fixture(scope="module")
def sim_case():
    """A Prius-like simulated rig (every board seen by every sensor) and its clean calibrations."""
    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    placements = make_rig_placements(rng, sensors, 30, min_fraction=1.0)
    dataset = simulate(sensors, placements, rng=rng).dataset
    cache = {}

    def clean(mode):
        if mode not in cache:
            cache[mode] = calibrate(dataset, CalibrationOptions(mode=mode))
        return cache[mode]

    return dataset, clean


@pytest.fixture(params=["sim", "real"])
def case(request):
    """(dataset, mode -> calibration of the clean dataset)."""
    if request.param == "sim":
        return request.getfixturevalue("sim_case")
    return request.getfixturevalue("real_dataset"), request.getfixturevalue("real_calibration")


def _poses(result):
    return {k: v.T_reference_sensor for k, v in result.sensors.items()}


@pytest.mark.parametrize("mode", ["mcpe", "fcpe", "pse"])
def test_displaced_boards_are_found_exactly(case, mode):
    dataset, clean_of = case
    assert all(s.valid.all() for s in dataset.sensors)
    clean = clean_of(mode)
    assert clean.outliers == {}

    r = calibrate(corrupt(dataset), CalibrationOptions(mode=mode))
    assert r.outliers == EXPECTED

    # on the remaining boards, the calibration is as good as the clean data's
    remaining = dataset.with_excluded(r.outliers)
    rm_clean, _ = evaluate_pairs(remaining, _poses(clean))
    rm_found, _ = evaluate_pairs(remaining, _poses(r))
    assert set(rm_found) == {"lidar1-camera1", "lidar1-radar1", "camera1-radar1"}
    for pair, v in rm_clean.items():
        assert rm_found[pair] == pytest.approx(v, rel=0.02), pair
    # the reported RMSE is computed without the outliers
    for pair, v in r.rmse_m.items():
        assert v == pytest.approx(rm_found[pair], rel=1e-9)


def test_without_detection_the_corruption_spoils_the_calibration(case):
    dataset, clean_of = case
    clean = clean_of("fcpe")
    r = calibrate(corrupt(dataset), CalibrationOptions(mode="fcpe", detect_outliers=False))
    assert r.outliers == {}
    remaining = dataset.with_excluded(EXPECTED)
    rm_clean, _ = evaluate_pairs(remaining, _poses(clean))
    rm_kept, _ = evaluate_pairs(remaining, _poses(r))
    # even on the good boards, every pair is several times worse than the clean calibration
    for pair, v in rm_clean.items():
        assert rm_kept[pair] > 3 * v, (pair, rm_kept[pair], v)
