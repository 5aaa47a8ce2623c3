"""The original tool's ROS accumulator YAML."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.dataset.accumulator import (
    accumulator_points_for_kind,
    parse_accumulator_yaml,
    read_accumulator_yaml,
)

SHARED = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "tudelft_prius"

GOOD = """
/lidar:
  - frame_id: velodyne
    points:
      - {x: 1, y: 2, z: 3}
      - {x: 4, y: 5, z: 6}
  - frame_id: velodyne
    points: []
  - frame_id: velodyne
    points:
      - {y: 8, x: 7, z: .nan}
      - {x: 10, y: 11, z: 12}
/radar:
  - frame_id: "radar"
    points:
      - {x: 3.5, y: -0.25, z: 9.0}
"""


def test_parse_topics_frames_and_points():
    topics = parse_accumulator_yaml(GOOD, "acc.yaml")
    assert list(topics) == ["/lidar", "/radar"]
    frame, pts = topics["/lidar"]
    assert frame == "velodyne"
    assert pts.shape == (3, 2, 3)
    np.testing.assert_array_equal(pts[0], [[1, 2, 3], [4, 5, 6]])
    assert np.isnan(pts[1]).all()  # empty points list = missed detection
    assert pts[2, 0, 0] == 7 and pts[2, 0, 1] == 8 and np.isnan(pts[2, 0, 2])
    assert not pts.flags.writeable
    assert topics["/radar"][0] == "radar"


def test_points_for_kind():
    four = np.arange(2 * 4 * 3, dtype=float).reshape(2, 4, 3)
    one = np.arange(2 * 1 * 3, dtype=float).reshape(2, 1, 3)
    for kind in (SensorKind.LIDAR, SensorKind.CAMERA):
        np.testing.assert_array_equal(accumulator_points_for_kind(four, kind, "a", "/t"), four)
    np.testing.assert_array_equal(
        accumulator_points_for_kind(one, SensorKind.RADAR, "a", "/t"), [[0, 1], [3, 4]]
    )
    np.testing.assert_array_equal(
        accumulator_points_for_kind(one, "radar3d", "a", "/t"), [[0, 1, 2], [3, 4, 5]]
    )


@pytest.mark.parametrize(
    "points, kind, message",
    [
        (np.zeros((2, 1, 3)), SensorKind.LIDAR, r"acc\.yaml: /t: a lidar needs 4 points .* got 1"),
        (np.zeros((2, 4, 3)), SensorKind.RADAR, r"acc\.yaml: /t: a radar needs 1 point .* got 4"),
        (np.zeros((2, 2, 3)), SensorKind.RADAR3D, r"a radar3d needs 1 point .* got 2"),
        (np.zeros((2, 4)), SensorKind.CAMERA, r"expected points of shape \(K, P, 3\), got \(2, 4\)"),
    ],
)
def test_points_for_kind_errors(points, kind, message):
    with pytest.raises(InputError, match=message):
        accumulator_points_for_kind(points, kind, "acc.yaml", "/t")


ENTRY = "/t:\n  - frame_id: f\n    points:\n      - {x: 1, y: 2, z: 3}\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("", r"acc\.yaml: empty file, expected a mapping topic -> list"),
        ("- 1\n- 2\n", r"acc\.yaml: expected a mapping topic -> list .* got a list"),
        ("/t:\n  - frame_id: f\n    points: [\n", r"acc\.yaml: line \d+, column \d+: invalid YAML"),
        ("/t: 3\n", r"acc\.yaml: /t: expected a list of \{frame_id, points\} entries, got an integer"),
        ("/t: []\n", r"acc\.yaml: /t: no entries"),
        ("/t:\n  - 5\n", r"acc\.yaml: /t\[0\]: expected a mapping \{frame_id, points\}, got an integer"),
        ("/t:\n  - {points: []}\n", r"/t\[0\]: missing key\(s\) frame_id"),
        ("/t:\n  - {frame_id: f}\n", r"/t\[0\]: missing key\(s\) points"),
        ("/t:\n  - {frame_id: 5, points: []}\n", r"/t\[0\]\.frame_id: expected a non-empty string, got 5"),
        (ENTRY + "  - frame_id: g\n    points: [{x: 1, y: 2, z: 3}]\n", r"/t\[1\]\.frame_id: 'g' differs from 'f' of entry 0"),
        ("/t:\n  - {frame_id: f, points: 7}\n", r"/t\[0\]\.points: expected a list of \{x, y, z\} points, got an integer"),
        ("/t:\n  - {frame_id: f, points: [3]}\n", r"/t\[0\]\.points\[0\]: expected a mapping \{x, y, z\}"),
        ("/t:\n  - {frame_id: f, points: [{x: 1, y: 2}]}\n", r"/t\[0\]\.points\[0\]: missing key\(s\) z"),
        ("/t:\n  - {frame_id: f, points: [{x: 1, y: a, z: 2}]}\n", r"/t\[0\]\.points\[0\]\.y: expected a number, got a string 'a'"),
        ("/t:\n  - {frame_id: f, points: [{x: 1, y: true, z: 2}]}\n", r"\.y: expected a number, got a boolean"),
        ("/t:\n  - {frame_id: f, points: [{x: .inf, y: 1, z: 2}]}\n", r"\.x: expected a finite number or nan"),
        (ENTRY + "  - frame_id: f\n    points: [{x: 1, y: 2, z: 3}, {x: 1, y: 2, z: 3}]\n", r"/t\[1\]\.points: 2 points, but entry 0 has 1"),
        ("/t:\n  - {frame_id: f, points: []}\n", r"/t: every entry has an empty points list"),
        ("/t: []\n/t: []\n", r"acc\.yaml: line 2, column 1: invalid YAML: duplicate key '/t'"),
        ("1: []\n", r"topic names must be strings"),
    ],
)
def test_parse_errors(text, message):
    with pytest.raises(InputError, match=message):
        parse_accumulator_yaml(text, "acc.yaml")


def test_string_nan_is_accepted():
    frame, pts = parse_accumulator_yaml(
        "/t:\n  - {frame_id: f, points: [{x: nan, y: NaN, z: 1}]}\n", "a"
    )["/t"]
    assert np.isnan(pts[0, 0, :2]).all() and pts[0, 0, 2] == 1


def test_read_wrapper(tmp_path):
    path = tmp_path / "acc.yaml"
    path.write_text(GOOD)
    assert set(read_accumulator_yaml(path)) == {"/lidar", "/radar"}
    with pytest.raises(InputError, match=r"nope\.yaml: accumulator YAML file not found"):
        read_accumulator_yaml(tmp_path / "nope.yaml")


def test_real_accumulator_example():
    if not SHARED.is_dir():
        pytest.skip("../shared not present")
    topics = read_accumulator_yaml(SHARED / "detections" / "accumulator_example.yaml")
    assert set(topics) == {
        "/lidar_detector/lidar_pattern",
        "/radar_detector/radar_pattern",
        "/stereo_detector/stereo_pattern",
    }
    frame, lidar = topics["/lidar_detector/lidar_pattern"]
    assert frame == "velodyne" and lidar.shape == (12, 4, 3)
    assert topics["/stereo_detector/stereo_pattern"][0] == "left"
    radar_frame, radar = topics["/radar_detector/radar_pattern"]
    assert radar_frame == "radar" and radar.shape == (12, 1, 3)
    assert accumulator_points_for_kind(radar, SensorKind.RADAR, "acc", "/radar").shape == (12, 2)
    assert accumulator_points_for_kind(lidar, SensorKind.LIDAR, "acc", "/lidar").shape == (12, 4, 3)
    assert np.isfinite(lidar).all()
    np.testing.assert_allclose(lidar[0, 0], [-0.133534, 5.792896, -0.769509])
