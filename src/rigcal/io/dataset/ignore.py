"""The original tool's ignore file: detections to leave out, per sensor.

A YAML mapping ``sensor name -> list of CSV column indices`` (0-based), e.g.::

    lidar1: [0, 1, 2, 3, 112, 113, 114, 115]   # lidar/camera: column c is board c // 4
    radar1: [5, 6]                             # radar/radar3d: column c is board c
    camera1: {boards: [3]}                     # rigcal extension: board indices directly

Naming any column of a board ignores the whole board. An empty file ignores nothing.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from rigcal.dataset import Dataset
from rigcal.errors import InputError
from rigcal.io._text import load_yaml, read_text, type_name

_POINTS_PER_BOARD = 4


def _indices(raw: Any, where: str, limit: int, unit: str) -> list[int]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise InputError(f"{where}: expected a list of {unit} indices, got {type_name(raw)}")
    out = []
    for i, value in enumerate(raw):
        if not isinstance(value, int) or isinstance(value, bool):
            raise InputError(
                f"{where}[{i}]: expected an integer {unit} index, got {type_name(value)} {value!r}"
            )
        if not 0 <= value < limit:
            raise InputError(
                f"{where}[{i}]: {unit} index {value} out of range (expected 0..{limit - 1})"
            )
        out.append(value)
    return out


def parse_ignore_yaml(text: str, source: str, dataset: Dataset) -> dict[str, list[int]]:
    """Board indices to ignore per sensor, sorted and unique, from ignore-file ``text``.

    Only sensors named in the file appear in the result. Column indices are checked against the
    dataset's K boards (4K columns for lidar/camera, K for radars).
    """
    data = load_yaml(text, source)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(
            f"{source}: expected a mapping sensor name -> list of column indices, "
            f"got {type_name(data)}"
        )
    known = ", ".join(dataset.names)
    num_boards = dataset.num_boards
    out: dict[str, list[int]] = {}
    for name, value in data.items():
        if not isinstance(name, str) or name not in dataset.names:
            raise InputError(f"{source}: unknown sensor {name!r} (sensors: {known})")
        sensor = dataset.sensor(name)
        where = f"{source}: {name}"
        if isinstance(value, dict):
            unknown = sorted(str(k) for k in value if k != "boards")
            if unknown:
                raise InputError(
                    f"{where}: unknown key(s) {', '.join(unknown)} (allowed: boards)"
                )
            boards = _indices(value.get("boards"), f"{where}.boards", num_boards, "board")
        else:
            per_board = _POINTS_PER_BOARD if sensor.kind.is_point_cloud else 1
            columns = _indices(value, where, num_boards * per_board, "column")
            boards = [c // per_board for c in columns]
        out[name] = sorted(set(boards))
    return out


def read_ignore_file(path: str | os.PathLike[str], dataset: Dataset) -> dict[str, list[int]]:
    """Read an ignore file; see :func:`parse_ignore_yaml`."""
    p = Path(path)
    return parse_ignore_yaml(read_text(p, "ignore file"), str(p), dataset)
