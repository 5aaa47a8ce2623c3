from __future__ import annotations

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.detect.placements import (
    NS,
    SensorSpec,
    StabilityRule,
    dataset_from_placements,
    match_placements,
    placements_from_windows,
    stable_periods,
)
from rigcal.detect.result import BoardDetection
from rigcal.errors import InputError

SQUARE = np.array([[-0.12, 0.12, 0], [0.12, 0.12, 0], [-0.12, -0.12, 0], [0.12, -0.12, 0]])


def _track(sensor, rate_hz, placements, rng, noise, t0=0.0, dwell=3.0, move=1.5, radar=False):
    """Detections of a board held still at each placement for `dwell` s, moving in between."""
    out = []
    t = t0
    dt = 1.0 / rate_hz
    for k, c in enumerate(placements):
        for i in range(int(dwell / dt)):
            p = c[:2] if radar else c + SQUARE
            out.append(BoardDetection(sensor, int((t + i * dt) * NS), p + rng.normal(0, noise, np.shape(p))))
        t += dwell
        if k + 1 < len(placements):
            nxt = placements[k + 1]
            for i in range(int(move / dt)):
                a = (i + 1) / (move / dt + 1)
                c_m = (1 - a) * c + a * nxt
                p = c_m[:2] if radar else c_m + SQUARE
                out.append(BoardDetection(sensor, int((t + i * dt) * NS), p))
            t += move
    return out


@pytest.fixture
def scenario():
    rng = np.random.default_rng(3)
    centres = [np.array([4.0 + k * 0.4, (-1) ** k * 0.8, 0.2]) for k in range(6)]
    lidar = _track("lidar1", 10, centres, rng, 0.005)
    cam = _track("camera1", 15, centres, rng, 0.008, t0=0.03)
    radar = _track("radar1", 13, centres, rng, 0.02, t0=0.07, radar=True)
    return centres, {"lidar1": lidar, "camera1": cam, "radar1": radar}


def test_every_placement_is_found_once_per_sensor(scenario):
    centres, dets = scenario
    rule = StabilityRule()
    periods = {
        s: stable_periods(s, d, rule, radar=(s == "radar1")) for s, d in dets.items()
    }
    assert all(len(p) == len(centres) for p in periods.values()), {s: len(p) for s, p in periods.items()}
    placements = match_placements(periods)
    assert len(placements) == len(centres)
    for pl, c in zip(placements, centres):
        assert set(pl.periods) == {"lidar1", "camera1", "radar1"}
        assert np.linalg.norm(pl.periods["lidar1"].points.mean(axis=0) - c) < 0.01
        assert np.linalg.norm(pl.periods["radar1"].points - c[:2]) < 0.03
    ds = dataset_from_placements(
        placements,
        [SensorSpec("lidar1", SensorKind.LIDAR), SensorSpec("camera1", SensorKind.CAMERA),
         SensorSpec("radar1", SensorKind.RADAR)],
        source="test",
    )
    assert ds.num_boards == len(centres) and np.all(ds.sensor("camera1").valid)


def test_moving_board_frames_do_not_make_placements():
    rng = np.random.default_rng(0)
    # a board moving steadily for 10 s: no stable period
    dets = [
        BoardDetection("lidar1", int(t * NS), SQUARE + [3 + 0.3 * t, 0, 0] + rng.normal(0, 0.003, (4, 3)))
        for t in np.arange(0, 10, 0.1)
    ]
    assert stable_periods("lidar1", dets, StabilityRule()) == []


def test_short_pauses_are_not_placements(scenario):
    rng = np.random.default_rng(1)
    dets = _track("lidar1", 10, [np.array([4.0, 0, 0])], rng, 0.004, dwell=0.5)
    assert stable_periods("lidar1", dets, StabilityRule(min_duration_s=1.0)) == []


def test_a_sensor_missing_a_placement_gets_nan(scenario):
    centres, dets = scenario
    rule = StabilityRule()
    # the radar never saw placement 2 (drop its detections there)
    t2 = (2 * 4.5) * NS, (2 * 4.5 + 3.0) * NS
    radar = [d for d in dets["radar1"] if not (t2[0] <= d.t_ns <= t2[1])]
    periods = {s: stable_periods(s, d, rule, radar=(s == "radar1")) for s, d in dets.items()}
    periods["radar1"] = stable_periods("radar1", radar, rule, radar=True)
    placements = match_placements(periods)
    assert len(placements) == len(centres)
    assert "radar1" not in placements[2].periods
    ds = dataset_from_placements(
        placements, [SensorSpec("lidar1", SensorKind.LIDAR), SensorSpec("radar1", SensorKind.RADAR)]
    )
    assert not ds.sensor("radar1").valid[2] and ds.sensor("radar1").valid.sum() == len(centres) - 1


def test_windows_given_by_hand(scenario):
    centres, dets = scenario
    windows = [(int((k * 4.5 + 0.5) * NS), int((k * 4.5 + 2.5) * NS)) for k in range(len(centres))]
    kinds = {"lidar1": SensorKind.LIDAR, "camera1": SensorKind.CAMERA, "radar1": SensorKind.RADAR}
    placements = placements_from_windows(dets, windows, StabilityRule(), kinds)
    for pl, c in zip(placements, centres):
        assert np.linalg.norm(pl.periods["camera1"].points.mean(axis=0) - c) < 0.01
    with pytest.raises(InputError, match="time window 0"):
        placements_from_windows(dets, [(5, 5)], StabilityRule(), kinds)


def test_no_placement_is_an_error():
    with pytest.raises(InputError, match="no board placement found"):
        dataset_from_placements([], [SensorSpec("lidar1", SensorKind.LIDAR)], source="rec.bag")
