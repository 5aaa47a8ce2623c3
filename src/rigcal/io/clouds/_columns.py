"""Shared by the cloud formats: named columns to a :class:`PointCloudFrame` and back."""

from __future__ import annotations

import os
import re
from typing import Sequence

import numpy as np

from rigcal.errors import InputError
from rigcal.io.limits import check_points, read_limited
from rigcal.recording import PointCloudFrame

_XYZ = ("x", "y", "z")
_RING = "ring"


# shared helpers


def _frame_from_columns(columns: Sequence[tuple[str, np.ndarray]], source: str, sensor: str,
                        t_ns: int, organized_shape: tuple[int, int] | None,
                        frame_id: str = "", xyz: np.ndarray | None = None) -> PointCloudFrame:
    """A frame from named columns (N,) or (N, k); padding ``_`` columns are dropped. ``xyz``:
    the coordinates as one (N, 3) array, when ``columns`` hold no x, y, z."""
    named: dict[str, np.ndarray] = {}
    for name, col in columns:
        if name == "_":
            continue
        parts = [(name, col)] if col.ndim == 1 else [
            (f"{name}_{k}", col[:, k]) for k in range(col.shape[1])
        ]
        for part_name, part in parts:
            if part_name in named:
                raise InputError(f"{source}: field '{part_name}' appears twice")
            named[part_name] = part
    if xyz is not None:
        points = check_points(np.array(xyz, dtype=float), source)  # one cast, a new array
    else:
        missing = [a for a in _XYZ if a not in named]
        if missing:
            raise InputError(
                f"{source}: point cloud has fields {list(named)}, expected x, y, z"
            )
        for a in _XYZ:
            if named[a].dtype.kind not in "iuf":
                raise InputError(f"{source}: field '{a}' has dtype {named[a].dtype}, expected numbers")
        xyz = np.empty((named["x"].shape[0], 3))
        for k, a in enumerate(_XYZ):
            xyz[:, k] = named[a]
        points = check_points(xyz, source)
    points.setflags(write=False)  # new memory, handed to the frame without another copy
    fields = {}
    for name, col in named.items():
        if name in _XYZ:
            continue
        if name == _RING:
            col = _ring_u16(col)
        col = np.ascontiguousarray(col, dtype=col.dtype.newbyteorder("="))
        col.setflags(write=False)
        fields[name] = col
    return PointCloudFrame(sensor=sensor, t_ns=t_ns, points_xyz=points, fields=fields,
                           organized_shape=organized_shape, frame_id=frame_id)


def _ring_u16(col: np.ndarray) -> np.ndarray:
    """An integer ``ring`` column as uint16 if its values fit (else unchanged)."""
    if col.ndim != 1 or col.dtype.kind not in "iu" or col.dtype == np.dtype("<u2") or (
        col.size and (int(col.min()) < 0 or int(col.max()) > 0xFFFF)
    ):
        return col
    return col.astype("<u2")


def _columns_of(frame: PointCloudFrame, xyz_dtype: np.dtype, source: str, cast_xyz: bool = True
                ) -> list[tuple[str, np.ndarray]]:
    """x, y, z (as ``xyz_dtype``) then the frame's fields, each (N,), checked for writing.
    ``cast_xyz=False``: x, y, z stay views of the frame's float64 points (the caller casts)."""
    pts = frame.points_xyz
    cols = [(a, pts[:, k].astype(xyz_dtype, copy=False) if cast_xyz else pts[:, k])
            for k, a in enumerate(_XYZ)]
    for name, values in frame.fields.items():
        if name in _XYZ:
            raise InputError(f"{source}: field '{name}' clashes with a coordinate")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_#.\-]*", name) or name == "_":
            raise InputError(
                f"{source}: field name {name!r} cannot be written (letters, digits, _ # . - only)"
            )
        arr = np.asarray(values)
        if arr.dtype == np.bool_:
            arr = arr.astype(np.uint8)
        if arr.dtype.kind not in "iuf" or arr.dtype.itemsize not in (1, 2, 4, 8) or (
            arr.dtype.kind == "f" and arr.dtype.itemsize < 4
        ):
            raise InputError(
                f"{source}: field '{name}' has dtype {arr.dtype}; expected int8..int64, "
                "uint8..uint64, float32 or float64"
            )
        if name == _RING:
            arr = _ring_u16(arr)
        cols.append((name, arr.astype(arr.dtype.newbyteorder("<"), copy=False)))
    return cols


def _xyz_dtype(xyz_dtype: object, source: str) -> np.dtype:
    dt = np.dtype(xyz_dtype)  # type: ignore[call-overload]
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise InputError(f"{source}: xyz_dtype must be float32 or float64, got {dt}")
    return dt.newbyteorder("<")


def _read_bytes(path: str | os.PathLike[str], what: str) -> bytes:
    return read_limited(path, what, "point cloud")


def _records(cols: Sequence[tuple[str, np.ndarray]], n: int,
             xyz: np.ndarray | None = None, xyz_dtype: np.dtype | None = None) -> memoryview:
    """The columns packed row by row (one record per point), as a memoryview of new memory.
    With ``xyz`` (N, 3), the first three columns (x, y, z) are filled from it by one cast to
    ``xyz_dtype`` (the same bytes as three fields of that dtype)."""
    names = [f"f{k}" for k in range(len(cols))]
    formats: list = [c.dtype for _, c in cols]
    first = 0
    if xyz is not None:
        names, formats, first = ["xyz", *names[3:]], [(xyz_dtype, (3,)), *formats[3:]], 3
    table = np.empty(n, dtype=np.dtype({"names": names, "formats": formats}))
    if xyz is not None:
        table["xyz"] = xyz
    for name, (_, c) in zip(names[1 if first else 0:], cols[first:]):
        table[name] = c
    return table.data.cast("B")
