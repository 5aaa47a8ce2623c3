"""rigcal.study.fleet: the simulated fleet of the power / false-alarm benchmark (benchmarks/fleet.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.study.fleet import check_vehicle, fleet_dataset, fleet_rates, moved_sensor, moved_vehicles, roc, simulate_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return simulate_vehicle(0, 1)


def test_moves_are_within_the_issue_ranges_and_radar_ones_marked():
    v = simulate_vehicle(0, 2)
    seen_unmeasured = False
    for k in range(40):
        name, move, detectable = moved_sensor(v, np.random.default_rng(k))
        assert 0.002 <= np.linalg.norm(move[3:]) <= 0.030
        assert 0.1 <= np.degrees(np.linalg.norm(move[:3])) <= 2.0
        if not detectable:
            seen_unmeasured = True
            assert name.startswith("radar") and move[2] == 0.0 and move[3] == 0.0 and move[4] == 0.0
    assert seen_unmeasured


def test_check_vehicle_records_and_rates(vehicle):
    rows = check_vehicle(vehicle, 0, boards=(10,))
    assert [(r["boards"], r["case"]) for r in rows] == [(10, "clean"), (10, "moved")]
    clean, moved = rows
    assert clean["sensor"] is None and moved["sensor"] in [s.name for s in vehicle.sensors]
    assert 0.0 < clean["p_min_adjusted"] <= 1.0 and clean["compute_s"] > 0
    rates = fleet_rates(rows, 10, moved_fraction=0.0)
    assert rates["vehicles"] == 1 and rates["false_alarm"] in (0.0, 1.0)
    curve = roc(rows, 10, (1e-3, 0.05, 1.5))
    assert curve[-1]["false_alarm"] == 1.0  # every p-value is below 1.5


def test_the_fleet_moves_a_tenth_and_its_data_follow(vehicle):
    chosen = moved_vehicles(list(range(200)), 0.1, 0)
    assert len(chosen) == 20 and chosen == moved_vehicles(list(range(200)), 0.1, 0)
    data, sensor = fleet_dataset(vehicle, 0, 4, moved=True)
    same, none = fleet_dataset(vehicle, 0, 4, moved=False)
    assert none is None and sensor in data.names and data.num_boards == same.num_boards == 4
