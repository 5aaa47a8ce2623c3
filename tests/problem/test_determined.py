"""Undetermined is not a result: the ``determined`` check judges each sensor's pose against the
bound of its kind, leaves a 2D radar's bounded directions out, and says which placements
would fix a weak pose."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.errors import InputError
from rigcal.problem.consistency import PASS, UNDETERMINED
from rigcal.problem.determined import DETERMINED_BOUND, determined_check, parse_bound, placement_advice


def _dataset(radar_points):
    K = len(radar_points)
    rng = np.random.default_rng(0)
    lidar = rng.normal(size=(K, 4, 3)) + [5.0, 0.0, 0.0]
    return Dataset((SensorDetections("lidar1", SensorKind.LIDAR, lidar),
                    SensorDetections("radar1", SensorKind.RADAR, np.asarray(radar_points, dtype=float))))


def _cov(trans_m, rot_deg):
    return np.diag([np.radians(rot_deg)] * 3 + [trans_m] * 3) ** 2


STD0 = {"x_m": 0.0, "y_m": 0.0, "z_m": 0.0, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}


def test_a_2d_radar_is_judged_on_its_in_plane_pose_only():
    ds = _dataset(np.random.default_rng(1).uniform([3, -2], [9, 2], size=(12, 2)))
    cov = _cov(0.02, 0.5)
    cov[0, 0] = cov[1, 1] = np.radians(30.0) ** 2  # roll, pitch: bounded by the field of view
    cov[5, 5] = 1.0  # z: bounded
    c = determined_check(ds, {"radar1": STD0}, {"lidar1": np.zeros((6, 6)), "radar1": cov}, "lidar1")
    assert c.status == PASS
    assert {e.item for e in c.evidence} == {"radar1 x", "radar1 y", "radar1 yaw"}


def test_an_undetermined_radar_is_named_with_advice():
    at_one_spot = np.tile([6.0, 1.0], (29, 1)) + np.random.default_rng(2).normal(0, 0.01, (29, 2))
    ds = _dataset(at_one_spot)
    c = determined_check(ds, {"radar1": STD0}, {"lidar1": np.zeros((6, 6)), "radar1": _cov(0.5, 20.0)}, "lidar1")
    assert c.status == UNDETERMINED
    assert c.detail.startswith("radar1: yaw (std 20.00 deg), x (std 500 mm), y (std 500 mm)")
    assert "not determined to 100 mm / 2 deg" in c.detail
    assert "all 29 boards radar1 saw are at one spot in its view" in c.detail


def test_bounds_are_per_kind_and_configurable():
    ds = _dataset(np.random.default_rng(1).uniform([3, -2], [9, 2], size=(12, 2)))
    covs = {"lidar1": np.zeros((6, 6)), "radar1": _cov(0.2, 1.0)}
    assert determined_check(ds, {"radar1": STD0}, covs, "lidar1").status == UNDETERMINED
    assert determined_check(ds, {"radar1": STD0}, covs, "lidar1", {"radar": (0.3, 3.0)}).status == PASS
    assert DETERMINED_BOUND["lidar"] == (0.05, 1.0)


def test_advice_follows_the_board_layout():
    ray = np.array([[r, 0.2 * r] for r in np.linspace(3, 9, 10)])
    assert "lie on one ray from it" in placement_advice(_dataset(ray), "radar1", ["y"])
    few = placement_advice(_dataset(np.array([[4.0, 1.0], [5.0, -1.0], [6.0, 0.0]])), "radar1", ["yaw"])
    assert few.startswith("radar1 saw only 3 boards")


def test_parse_bound():
    assert parse_bound("50/1") == (None, (0.05, 1.0))
    assert parse_bound("radar:150/3") == ("radar", (0.15, 3.0))
    with pytest.raises(InputError, match="unknown sensor kind 'sonar'"):
        parse_bound("sonar:1/1")
    with pytest.raises(InputError, match="expected \\[KIND:\\]MM/DEG"):
        parse_bound("50mm")
    with pytest.raises(InputError, match="must be positive"):
        parse_bound("0/1")


@pytest.fixture(scope="module")
def prius():
    from rigcal.sim.rig import make_rig_placements, prius_like_rig

    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    return sensors, make_rig_placements(rng, sensors, 29, min_fraction=1.0)


def _undetermined_or_refused(dataset, mode):
    """The detail of the ``determined`` check, or the message of the refusal (a joint solve
    that does not converge on such data names the radar's least determined direction)."""
    from rigcal.errors import ConvergenceError
    from rigcal.problem.calibrate import CalibrationOptions, calibrate

    try:
        r = calibrate(dataset, CalibrationOptions(mode=mode))
    except ConvergenceError as exc:
        return "refused", str(exc)
    return r.verdict.status, next(c for c in r.verdict.checks if c.name == "determined").detail


@pytest.mark.parametrize("mode", ["mcpe", "fcpe", "pse"])
def test_boards_on_one_ray_leave_the_radar_undetermined(prius, mode):
    from rigcal.sim.rig import board_area_center, make_board_placements, simulate

    sensors, _ = prius
    rng = np.random.default_rng(4)
    ray = make_board_placements(rng, 29, board_area_center(sensors), distance_m=(3, 9), azimuth_spread_deg=0,
                                elevation_spread_deg=0.0, heading_deg=10)
    status, text = _undetermined_or_refused(simulate(sensors, ray, rng=rng).dataset, mode)
    assert status in ("undetermined", "refused") and "radar1" in text
    if status == "undetermined":
        assert text.startswith("radar1: ") and "lie on one ray from it" in text
        assert "camera1" not in text  # the lidar's centres determine the camera


def test_boards_at_one_pose_leave_the_radar_undetermined(prius):
    from rigcal.sim.rig import simulate

    sensors, T = prius
    sim = simulate(sensors, np.repeat(T[:1], 29, axis=0), rng=np.random.default_rng(5))
    status, text = _undetermined_or_refused(sim.dataset, "mcpe")
    assert status == "undetermined"
    assert "all 29 boards radar1 saw are at one spot in its view" in text
