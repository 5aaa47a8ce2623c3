"""The original tool's ignore file (CSV column indices) and the {boards: [...]} extension."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.dataset import Dataset, SensorDetections, SensorKind
from rigcal.errors import InputError
from rigcal.io.dataset.ignore import parse_ignore_yaml, read_ignore_file


def make_dataset(num_boards: int = 5) -> Dataset:
    rng = np.random.default_rng(1)
    return Dataset(
        sensors=(
            SensorDetections("lidar1", SensorKind.LIDAR, rng.normal(size=(num_boards, 4, 3))),
            SensorDetections("camera1", SensorKind.CAMERA, rng.normal(size=(num_boards, 4, 3))),
            SensorDetections("radar1", SensorKind.RADAR, rng.normal(size=(num_boards, 2))),
            SensorDetections("radar3d_1", SensorKind.RADAR3D, rng.normal(size=(num_boards, 3))),
        )
    )


def test_original_example_columns_to_boards():
    ds = make_dataset(29)
    got = parse_ignore_yaml("lidar1: [0,1,2,3,112,113,114,115]\nradar1: [5,6]", "ign.yaml", ds)
    assert got == {"lidar1": [0, 28], "radar1": [5, 6]}


def test_sorted_unique_boards_forms_and_nulls():
    ds = make_dataset(5)
    text = (
        "camera1: [19, 4, 5, 0]\n"
        "radar3d_1: {boards: [4, 1, 4]}\n"
        "lidar1: null\n"
        "radar1: []\n"
    )
    got = parse_ignore_yaml(text, "ign.yaml", ds)
    assert got == {"camera1": [0, 1, 4], "radar3d_1": [1, 4], "lidar1": [], "radar1": []}
    assert parse_ignore_yaml("", "ign.yaml", ds) == {}
    assert parse_ignore_yaml("radar1: {boards: null}", "ign.yaml", ds) == {"radar1": []}


def test_applied_with_dataset_with_excluded():
    ds = make_dataset(5)
    ignored = parse_ignore_yaml("lidar1: [4, 7]\nradar1: {boards: [0]}", "ign.yaml", ds)
    out = ds.with_excluded(ignored)
    assert out.sensor("lidar1").excluded == frozenset({1})
    assert out.sensor("radar1").excluded == frozenset({0})
    assert out.sensor("camera1").excluded == frozenset()


@pytest.mark.parametrize(
    "text, message",
    [
        ("sonar1: [1]", r"ign\.yaml: unknown sensor 'sonar1' \(sensors: lidar1, camera1, radar1, radar3d_1\)"),
        ("3: [1]", r"unknown sensor 3"),
        ("lidar1: [1.5]", r"ign\.yaml: lidar1\[0\]: expected an integer column index, got a number 1\.5"),
        ("radar1: [0, a]", r"radar1\[1\]: expected an integer column index, got a string 'a'"),
        ("radar1: [true]", r"radar1\[0\]: expected an integer column index, got a boolean"),
        ("lidar1: [20]", r"lidar1\[0\]: column index 20 out of range \(expected 0\.\.19\)"),
        ("radar1: [5]", r"radar1\[0\]: column index 5 out of range \(expected 0\.\.4\)"),
        ("radar3d_1: [-1]", r"radar3d_1\[0\]: column index -1 out of range"),
        ("camera1: {boards: [5]}", r"camera1\.boards\[0\]: board index 5 out of range \(expected 0\.\.4\)"),
        ("camera1: {board: [1]}", r"camera1: unknown key\(s\) board \(allowed: boards\)"),
        ("camera1: 3", r"camera1: expected a list of column indices, got an integer"),
        ("- lidar1", r"ign\.yaml: expected a mapping sensor name -> list of column indices, got a list"),
        ("lidar1: [1\n", r"ign\.yaml: line \d+, column \d+: invalid YAML"),
    ],
)
def test_errors(text, message):
    with pytest.raises(InputError, match=message):
        parse_ignore_yaml(text, "ign.yaml", make_dataset(5))


def test_read_wrapper(tmp_path):
    ds = make_dataset(5)
    path = tmp_path / "ignore.yaml"
    path.write_text("radar1: [2]\n")
    assert read_ignore_file(path, ds) == {"radar1": [2]}
    with pytest.raises(InputError, match=r"absent\.yaml: ignore file not found"):
        read_ignore_file(tmp_path / "absent.yaml", ds)
