from __future__ import annotations

import numpy as np
import pytest

from rigcal.detect.radar import RadarDetectorConfig, detect_board_radar
from rigcal.errors import ConfigError
from rigcal.recording import RadarFrame


def _frame(points, rcs):
    return RadarFrame("radar1", 5, np.asarray(points, float), np.asarray(rcs, float))


def test_picks_the_reflector_inside_the_rcs_window_among_closer_clutter():
    f = _frame([[2.0, 0.5], [5.0, 0.2], [3.0, -1.0], [9.0, 1.0]], [-5.0, 15.0, 0.0, 18.0])
    det = detect_board_radar(f, RadarDetectorConfig(rcs_min_dbsm=5.0))
    assert det.ok and np.allclose(det.points, [5.0, 0.2])
    assert det.quality["candidates"] == 2


@pytest.mark.parametrize(
    "rule, expected",
    [("closest", [2.0, 0.5]), ("farthest", [9.0, 1.0]), ("highest_rcs", [9.0, 1.0]), ("lowest_rcs", [2.0, 0.5])],
)
def test_selection_rules(rule, expected):
    f = _frame([[2.0, 0.5], [5.0, 0.2], [9.0, 1.0]], [-5.0, 15.0, 18.0])
    det = detect_board_radar(f, RadarDetectorConfig(select=rule))
    assert np.allclose(det.points, expected)


def test_range_and_azimuth_windows():
    f = _frame([[2.0, 0.0], [5.0, 0.0], [0.0, 5.0]], [10.0, 10.0, 10.0])
    det = detect_board_radar(f, RadarDetectorConfig(range_min_m=3.0, azimuth_min_deg=-30, azimuth_max_deg=30))
    assert np.allclose(det.points, [5.0, 0.0])


def test_3d_radar_keeps_z():
    f = _frame([[5.0, 0.2, 0.3]], [12.0])
    assert np.allclose(detect_board_radar(f).points, [5.0, 0.2, 0.3])


def test_failures_name_what_was_seen():
    empty = _frame(np.zeros((0, 2)), np.zeros(0))
    assert detect_board_radar(empty).reason == "no_detections"
    f = _frame([[2.0, 0.5]], [-5.0])
    fail = detect_board_radar(f, RadarDetectorConfig(rcs_min_dbsm=5.0))
    assert not fail.ok and fail.reason == "no_candidate"
    assert "RCS seen -5" in fail.detail


def test_bad_config_is_refused():
    with pytest.raises(ConfigError, match="select 'nearest'"):
        RadarDetectorConfig(select="nearest")
    with pytest.raises(ConfigError, match="range window"):
        RadarDetectorConfig(range_min_m=5, range_max_m=1)
