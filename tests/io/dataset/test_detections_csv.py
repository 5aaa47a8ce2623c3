"""The original tool's detection CSVs: layout, round trips, every error, the real data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.dataset.detections_csv import (
    format_detections_csv,
    parse_detections_csv,
    read_detections_csv,
)

SHARED = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "tudelft_prius"


def prius_detections() -> Path:
    if not SHARED.is_dir():
        pytest.skip("../shared not present")
    return SHARED / "detections"


def random_points(kind: SensorKind, num_boards: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.normal(scale=3.0, size=(num_boards,) + kind.point_shape)
    pts[1] = np.nan  # a missed board
    return pts


@pytest.mark.parametrize("kind", list(SensorKind))
def test_round_trip_is_exact(kind):
    pts = random_points(kind, 6)
    text = format_detections_csv(pts, kind)
    back = parse_detections_csv(text, kind, "mem.csv")
    assert back.shape == pts.shape
    np.testing.assert_array_equal(back, pts)  # NaN == NaN here, floats bit for bit
    assert not back.flags.writeable


def test_lidar_layout_columns_4k_to_4k_plus_3():
    # 2 boards; value = 100 * row + column so every cell is identifiable
    table = np.array([[100 * r + c for c in range(8)] for r in range(3)], dtype=float)
    text = "\n".join(",".join(str(v) for v in row) for row in table)
    pts = parse_detections_csv(text, SensorKind.LIDAR, "t.csv")
    assert pts.shape == (2, 4, 3)
    # board 1, point 2 (bottom-left) is column 6: (x, y, z) = (6, 106, 206)
    np.testing.assert_array_equal(pts[1, 2], [6, 106, 206])
    np.testing.assert_array_equal(pts[0, 0], [0, 100, 200])


def test_radar_layouts():
    pts2 = parse_detections_csv("1,2,3\n4,5,6\n", SensorKind.RADAR, "r.csv")
    np.testing.assert_array_equal(pts2, [[1, 4], [2, 5], [3, 6]])
    pts3 = parse_detections_csv("1,2\n3,4\n5,6", "radar3d", "r3.csv")
    np.testing.assert_array_equal(pts3, [[1, 3, 5], [2, 4, 6]])


def test_nan_spellings_whitespace_bom_crlf_trailing_comma_blank_lines():
    text = "\ufeff1, NaN ,\r\n\r\n nan,2,\r\n\n"
    pts = parse_detections_csv(text, SensorKind.RADAR, "r.csv")
    assert pts.shape == (2, 2)
    assert pts[0, 0] == 1 and np.isnan(pts[0, 1]) and np.isnan(pts[1, 0]) and pts[1, 1] == 2


@pytest.mark.parametrize(
    "text, kind, message",
    [
        ("", "lidar", r"bad\.csv: empty file, expected 3 rows \(x, y, z\)"),
        ("  \n\n", "radar", r"bad\.csv: empty file, expected 2 rows \(x, y\)"),
        ("1,2,3\n4,5\n6,7,8", "radar3d", r"bad\.csv: rows have different lengths: line 2 has 2 columns, line 1 has 3"),
        ("1,2\n3,abc", "radar", r"bad\.csv: line 2, column 2: expected a number or nan, got 'abc'"),
        ("1,2\n3, ,4", "radar", r"line 2 has 3 columns"),
        ("1,,2\n3,4,5", "radar", r"bad\.csv: line 1, column 2: empty cell"),
        ("1,inf\n3,4", "radar", r"line 1, column 2: expected a finite number or nan, got 'inf'"),
        ("1_0,2\n3,4", "radar", r"line 1, column 1: expected a number or nan, got '1_0'"),
        ("1,2,3,4\n5,6,7,8", "lidar", r"bad\.csv: expected 3 rows \(x, y, z\) for a lidar, got 2"),
        ("1\n2\n3", "radar", r"bad\.csv: expected 2 rows \(x, y\) for a radar, got 3"),
        ("1\n2", "radar3d", r"expected 3 rows \(x, y, z\) for a radar3d, got 2"),
        ("1,2,3,4,5\n1,2,3,4,5\n1,2,3,4,5", "camera", r"bad\.csv: expected a multiple of 4 columns for a camera .* got 5"),
        (",\n,\n,", "lidar", r"bad\.csv: no columns: expected at least one board .* got 0"),
    ],
)
def test_parse_errors(text, kind, message):
    with pytest.raises(InputError, match=message):
        parse_detections_csv(text, kind, "bad.csv")


def test_unknown_kind_string():
    with pytest.raises(InputError, match=r"unknown sensor kind 'sonar'"):
        parse_detections_csv("1\n2", "sonar", "x.csv")


def test_read_wrapper_round_trip_and_file_errors(tmp_path):
    pts = random_points(SensorKind.CAMERA, 3)
    path = tmp_path / "cam.csv"
    path.write_text(format_detections_csv(pts, SensorKind.CAMERA))
    np.testing.assert_array_equal(read_detections_csv(path, SensorKind.CAMERA), pts)
    with pytest.raises(InputError, match=r"missing\.csv: detection CSV file not found"):
        read_detections_csv(tmp_path / "missing.csv", SensorKind.LIDAR)
    with pytest.raises(InputError, match=r"is a directory"):
        read_detections_csv(tmp_path, SensorKind.LIDAR)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match=r"bin\.csv: detection CSV file is not UTF-8"):
        read_detections_csv(binary, SensorKind.LIDAR)
    with pytest.raises(InputError, match=r"cam\.csv: expected 2 rows"):
        read_detections_csv(path, SensorKind.RADAR)


def test_format_errors():
    with pytest.raises(InputError, match=r"lidar detections must have shape \(K, 4, 3\), got \(2, 3\)"):
        format_detections_csv(np.zeros((2, 3)), SensorKind.LIDAR)
    with pytest.raises(InputError, match=r"no boards"):
        format_detections_csv(np.zeros((0, 2)), SensorKind.RADAR)
    with pytest.raises(InputError, match=r"infinite"):
        format_detections_csv(np.array([[np.inf, 0.0]]), SensorKind.RADAR)


def test_format_is_full_precision():
    text = format_detections_csv(np.array([[0.1, 1 / 3]]), SensorKind.RADAR)
    assert text == "0.10000000000000001\n0.33333333333333331\n"


@pytest.mark.parametrize(
    "name, kind, shape",
    [
        ("lidar.csv", SensorKind.LIDAR, (29, 4, 3)),
        ("camera.csv", SensorKind.CAMERA, (29, 4, 3)),
        ("radar.csv", SensorKind.RADAR, (29, 2)),
        ("radar_3D.csv", SensorKind.RADAR3D, (29, 3)),
    ],
)
def test_real_data(name, kind, shape):
    path = prius_detections() / name
    pts = read_detections_csv(path, kind)
    assert pts.shape == shape
    # re-formatting reproduces the numbers exactly
    again = parse_detections_csv(format_detections_csv(pts, kind), kind, "again")
    np.testing.assert_array_equal(again, pts)


def test_real_lidar_board_zero_is_a_square_of_024():
    pts = read_detections_csv(prius_detections() / "lidar.csv", SensorKind.LIDAR)
    tl, tr, bl, br = pts[0]
    assert np.linalg.norm(tr - tl) == pytest.approx(0.24, abs=0.03)
    assert np.linalg.norm(bl - tl) == pytest.approx(0.24, abs=0.03)
    assert np.linalg.norm(br - tl) == pytest.approx(0.24 * np.sqrt(2), abs=0.04)
