"""The report's "where to put the next board" hint lies inside the sensor's field of view: on a
simulated rig, the suggested board's four circles (a radar's reflector) are where the simulated
sensor would see them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.geometry.se3 import invert, transform_points
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.report.data import _from_view, _hull, _inside_hull, _to_view, coverage_data
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate


def _in_fov(sensor, p: np.ndarray) -> bool:
    """The simulator's field-of-view rule (rigcal.sim.rig.visible) for points (n, 3)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if sensor.kind is SensorKind.CAMERA:
        az, el = np.arctan2(x, z), np.arctan2(-y, z)
        ok = z > 0
    else:
        az, el = np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))
        ok = np.ones(len(p), dtype=bool)
    ok &= np.abs(az) <= math.radians(sensor.max_azimuth_deg) + 1e-9
    if sensor.kind is not SensorKind.RADAR:
        ok &= (el <= math.radians(sensor.max_elevation_deg) + 1e-9) & (el >= math.radians(sensor.min_elevation_deg) - 1e-9)
    return bool(np.all(ok))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_next_board_hint_is_inside_the_field_of_view(seed):
    rng = np.random.default_rng(seed)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 14), rng=rng, reference="lidar1")
    result = calibrate(sim.dataset, CalibrationOptions(mode="fcpe"))
    cov = coverage_data(sim.dataset, result)
    checked = 0
    for s in sensors:
        hint = cov[s.name].get("hint")
        if hint is None:
            continue
        T = result.sensors[s.name].T_reference_sensor
        centre = transform_points(invert(T), np.asarray(hint["point_reference"], dtype=float)[None])[0]
        if s.kind is SensorKind.RADAR:
            pts = centre[None]
        else:  # the board facing the sensor: its four circles around the centre
            offsets = np.array([[0, a * 0.12, b * 0.12] for a in (-1, 1) for b in (-1, 1)])
            pts = _from_view(s.kind, _to_view(s.kind, centre[None]) + offsets)
        assert _in_fov(s, pts), (s.name, hint["text"])
        checked += 1
    assert checked == 2  # camera and radar (the reference lidar gets none)


def test_hull_and_inside():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=float)
    hull = _hull(square)
    assert len(hull) == 4
    inside = _inside_hull(hull, np.array([[0.5, 0.5], [1.0, 1.0], [1.01, 0.5], [-0.01, 0.2]]))
    assert inside.tolist() == [True, True, False, False]
    assert not _inside_hull(_hull(np.array([[0, 0], [1, 1], [2, 2]], dtype=float)), np.array([[1.0, 1.0]])).any()
