"""The original tool's detection CSV files.

Comma-separated floats, one row per coordinate, one column per detected point:

* ``lidar`` / ``camera``: 3 rows (x, y, z) x 4K columns; board k is columns 4k..4k+3, ordered
  top-left, top-right, bottom-left, bottom-right;
* ``radar`` (2D): 2 rows (x, y) x K columns;
* ``radar3d``: 3 rows (x, y, z) x K columns.

``nan`` (any case) marks a missed detection. Blank lines are skipped and one trailing comma per
row is tolerated; lines may end in LF, CRLF or CR. Values beyond ±1e5 m
(:data:`rigcal.io.limits.MAX_ABS`) and infinities are refused. Parsed points use the layouts of :mod:`rigcal.dataset`: (K, 4, 3), (K, 2) or
(K, 3) in metres, in the sensor's frame.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io._text import read_text
from rigcal.io.limits import MAX_ABS

_POINTS_PER_BOARD = 4


def _kind(kind: SensorKind | str, source: str) -> SensorKind:
    return kind if isinstance(kind, SensorKind) else SensorKind.parse(kind, source)


def _row_names(kind: SensorKind) -> tuple[str, ...]:
    return ("x", "y") if kind is SensorKind.RADAR else ("x", "y", "z")


def _article(kind: SensorKind) -> str:
    return "an" if kind.value[0] in "aeiou" else "a"


def _layout(kind: SensorKind) -> str:
    names = _row_names(kind)
    columns = "4K columns (4 circle centres per board)" if kind.is_point_cloud else "K columns"
    return f"{len(names)} rows ({', '.join(names)}) x {columns}"


def _parse_cell(cell: str, source: str, line: int, column: int) -> float:
    text = cell.strip()
    if not text:
        raise InputError(
            f"{source}: line {line}, column {column}: empty cell, expected a number or nan"
        )
    try:
        if "_" in text:  # float() accepts digit separators; a CSV should not
            raise ValueError
        value = float(text)
    except ValueError:
        raise InputError(
            f"{source}: line {line}, column {column}: expected a number or nan, got {text!r}"
        ) from None
    if math.isinf(value) or abs(value) > MAX_ABS["m"]:
        raise InputError(
            f"{source}: line {line}, column {column}: expected a finite number or nan, got "
            f"{text!r} (coordinates must lie within ±{MAX_ABS['m']:g} m)"
        )
    return value


def parse_detections_csv(text: str, kind: SensorKind | str, source: str) -> np.ndarray:
    """Detections of ``kind`` from CSV ``text``; ``source`` names the file in messages.

    Returns a new read-only float array (K, 4, 3) for lidar/camera, (K, 2) for radar, (K, 3)
    for radar3d, NaN where not detected. Line and column numbers in messages are 1-based.
    """
    kind = _kind(kind, source)
    if text.startswith("\ufeff"):
        text = text[1:]
    rows: list[tuple[int, list[str]]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.endswith(","):
            stripped = stripped[:-1]
        rows.append((line_no, stripped.split(",") if stripped.strip() else []))
    if not rows:
        raise InputError(
            f"{source}: empty file, expected {_layout(kind)} of comma-separated numbers "
            f"for {_article(kind)} {kind.value}"
        )
    first_line, first_cells = rows[0]
    for line_no, cells in rows[1:]:
        if len(cells) != len(first_cells):
            raise InputError(
                f"{source}: rows have different lengths: line {line_no} has {len(cells)} "
                f"columns, line {first_line} has {len(first_cells)}"
            )
    names = _row_names(kind)
    if len(rows) != len(names):
        raise InputError(
            f"{source}: expected {len(names)} rows ({', '.join(names)}) for "
            f"{_article(kind)} {kind.value}, got {len(rows)}"
        )
    num_columns = len(first_cells)
    per_board = _POINTS_PER_BOARD if kind.is_point_cloud else 1
    if num_columns == 0:
        raise InputError(
            f"{source}: no columns: expected at least one board "
            f"({per_board} column{'s' if per_board > 1 else ''} per board for "
            f"{_article(kind)} {kind.value}), got 0"
        )
    if num_columns % per_board:
        raise InputError(
            f"{source}: expected a multiple of {per_board} columns for {_article(kind)} "
            f"{kind.value} (4 circle centres per board: TL, TR, BL, BR), got {num_columns}"
        )
    table = np.array(
        [
            [_parse_cell(cell, source, line_no, j + 1) for j, cell in enumerate(cells)]
            for line_no, cells in rows
        ],
        dtype=float,
    )
    return _points_from_table(table, kind)


def _points_from_table(table: np.ndarray, kind: SensorKind) -> np.ndarray:
    """(rows, columns) CSV table -> dataset layout (a new read-only array)."""
    if kind.is_point_cloud:
        points = table.T.reshape(-1, _POINTS_PER_BOARD, 3)
    else:
        points = table.T
    points = np.ascontiguousarray(points, dtype=float)
    points.setflags(write=False)
    return points


def _table_from_points(points: np.ndarray, kind: SensorKind) -> np.ndarray:
    """Dataset layout -> (rows, columns) CSV table."""
    if kind.is_point_cloud:
        return points.reshape(-1, 3).T
    return points.T


def format_detections_csv(points: np.ndarray, kind: SensorKind | str) -> str:
    """CSV text of ``points`` in the layout of ``kind`` (inverse of :func:`parse_detections_csv`).

    Values are written with ``%.17g`` so they read back bit for bit; NaN as ``nan``.
    """
    kind = _kind(kind, "format_detections_csv")
    pts = np.asarray(points, dtype=float)
    expected = kind.point_shape
    if pts.ndim != 1 + len(expected) or pts.shape[1:] != expected:
        raise InputError(
            f"{kind.value} detections must have shape (K, {', '.join(map(str, expected))}), "
            f"got {pts.shape}"
        )
    if pts.shape[0] == 0:
        raise InputError(f"{kind.value} detections: no boards to write (K = 0)")
    if np.isinf(pts).any():
        raise InputError(
            f"{kind.value} detections contain infinite values; use NaN for missed detections"
        )
    table = _table_from_points(pts, kind)
    return "".join(",".join("%.17g" % v for v in row) + "\n" for row in table)


def read_detections_csv(path: str | os.PathLike[str], kind: SensorKind | str) -> np.ndarray:
    """Read a detection CSV file; see :func:`parse_detections_csv`."""
    p = Path(path)
    return parse_detections_csv(read_text(p, "detection CSV file"), _kind(kind, str(p)), str(p))
