from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt
from rigcal.recording import RadarFrame
from rigcal.sim.raw import (
    RadarModel,
    Scene,
    automotive_2d,
    automotive_3d,
    detections,
    reflector_visible,
)

from .conftest import facing_board

T_RADAR = from_rt(np.eye(3), [0.0, 0.0, 0.5])
EXACT = dict(
    range_sigma_m=0.0,
    azimuth_sigma_deg=0.0,
    elevation_sigma_deg=0.0,
    reflector_rcs_sigma_db=0.0,
    clutter_count=0,
)


def test_reflector_at_the_right_range_and_azimuth():
    scene = Scene(facing_board(5.0, 0.5, lateral_m=1.0))
    model = automotive_2d(**EXACT)
    frame = detections(model, T_RADAR, scene, np.random.default_rng(0), 7, "radar1")
    assert isinstance(frame, RadarFrame) and frame.points.shape == (1, 2)
    assert frame.sensor == "radar1" and frame.t_ns == 7
    rng_true = math.hypot(5.105, 1.0)
    az_true = math.atan2(1.0, 5.105)
    assert np.allclose(frame.points[0], rng_true * np.array([math.cos(az_true), math.sin(az_true)]))
    assert frame.rcs_dbsm[0] == pytest.approx(15.0)


def test_2d_radar_reports_the_3d_range_within_its_elevation_fov():
    d = 5.105
    inside = Scene(facing_board(5.0, 0.5 + d * math.tan(math.radians(8.0))))
    outside = Scene(facing_board(5.0, 0.5 + d * math.tan(math.radians(10.0))))
    below = Scene(facing_board(5.0, 0.5 - d * math.tan(math.radians(10.0))))
    model = automotive_2d(**EXACT)
    f = detections(model, T_RADAR, inside, np.random.default_rng(0))
    assert f.points.shape == (1, 2)
    assert f.points[0, 0] == pytest.approx(d / math.cos(math.radians(8.0)))
    for scene in (outside, below):
        assert not reflector_visible(model, T_RADAR, scene)
        assert detections(model, T_RADAR, scene, np.random.default_rng(0)).points.shape == (0, 2)


def test_reflector_needs_the_board_to_face_the_radar():
    T = facing_board(5.0, 0.5).copy()
    T[:3, :3] = T[:3, :3] @ np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])
    model = automotive_2d(**EXACT)
    assert reflector_visible(model, T_RADAR, Scene(facing_board(5.0, 0.5)))
    assert not reflector_visible(model, T_RADAR, Scene(T))  # board turned by 90 deg


def test_reflector_outside_azimuth_fov_or_range():
    model = automotive_2d(**EXACT, max_range_m=10.0)
    assert not reflector_visible(model, T_RADAR, Scene(facing_board(3.0, 0.5, lateral_m=6.0)))
    assert not reflector_visible(model, T_RADAR, Scene(facing_board(12.0, 0.5)))


def test_3d_radar():
    scene = Scene(facing_board(5.0, 1.0))
    f = detections(automotive_3d(**EXACT), T_RADAR, scene, np.random.default_rng(0))
    assert f.points.shape == (1, 3)
    assert np.allclose(f.points[0], [5.105, 0.0, 0.5])


def test_noise_statistics():
    scene = Scene(facing_board(6.0, 0.5))
    model = automotive_2d(range_sigma_m=0.04, azimuth_sigma_deg=0.5, clutter_count=0)
    rng = np.random.default_rng(3)
    pts = np.array([detections(model, T_RADAR, scene, rng).points[0] for _ in range(2000)])
    r = np.linalg.norm(pts, axis=1)
    az = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    assert np.mean(r) == pytest.approx(6.105, abs=0.005)
    assert np.std(r) == pytest.approx(0.04, rel=0.1)
    assert np.std(az) == pytest.approx(0.5, rel=0.1)


def test_clutter_count_rcs_and_ranges():
    model = automotive_2d(
        clutter_count=12, clutter_rcs_dbsm=(-10.0, 5.0), clutter_range_m=(1.0, 30.0)
    )
    hidden = Scene(facing_board(5.0, 3.0))  # reflector far outside the elevation field of view
    visible_scene = Scene(facing_board(5.0, 0.5))
    rng = np.random.default_rng(11)
    closer = 0
    for _ in range(50):
        f = detections(model, T_RADAR, hidden, rng)
        assert f.points.shape == (12, 2)
        assert np.all((f.rcs_dbsm >= -10.0) & (f.rcs_dbsm <= 5.0))
        r = np.linalg.norm(f.points, axis=1)
        assert np.all((r >= 1.0) & (r <= 30.0))
        az = np.degrees(np.arctan2(f.points[:, 1], f.points[:, 0]))
        assert np.all(np.abs(az) <= 60.0)
        closer += int(np.sum(r < 5.0))
        g = detections(model, T_RADAR, visible_scene, rng)
        assert g.points.shape == (13, 2)
        strong = g.rcs_dbsm > 8.0
        assert strong.sum() == 1  # the reflector, above every clutter RCS
        assert np.linalg.norm(g.points[strong][0]) == pytest.approx(5.105, abs=0.2)
    assert closer > 20  # clutter closer than the board exists


def test_detections_are_deterministic():
    scene = Scene(facing_board(5.0, 0.5))
    a = detections(automotive_2d(), T_RADAR, scene, np.random.default_rng(4))
    b = detections(automotive_2d(), T_RADAR, scene, np.random.default_rng(4))
    c = detections(automotive_2d(), T_RADAR, scene, np.random.default_rng(5))
    assert np.array_equal(a.points, b.points) and np.array_equal(a.rcs_dbsm, b.rcs_dbsm)
    assert not np.array_equal(a.points, c.points)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"dims": 4}, "dims must be 2 or 3"),
        ({"range_sigma_m": -0.1}, "range_sigma_m must be >= 0"),
        ({"elevation_fov_deg": 0.0}, "elevation_fov_deg must be in"),
        ({"clutter_count": -1}, "clutter_count must be an integer >= 0"),
        ({"clutter_rcs_dbsm": (5.0, -5.0)}, "clutter_rcs_dbsm must be finite with low <= high"),
        ({"clutter_range_m": 3.0}, "clutter_range_m must be a \\(low, high\\) pair"),
        ({"min_range_m": 10.0, "max_range_m": 5.0}, "min_range_m < max_range_m"),
    ],
)
def test_radar_model_validation(kwargs, match):
    with pytest.raises(InputError, match=match):
        RadarModel(**kwargs)


def test_detections_validation():
    scene = Scene(facing_board(5.0, 0.5))
    with pytest.raises(InputError, match="model must be a RadarModel"):
        detections(None, T_RADAR, scene, np.random.default_rng(0))
    with pytest.raises(InputError, match="T_world_radar: expected a 4x4 matrix"):
        detections(automotive_2d(), np.eye(3), scene, np.random.default_rng(0))
