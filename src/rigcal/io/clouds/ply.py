"""PLY files: the ``vertex`` element (see :mod:`rigcal.io.clouds`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rigcal.errors import InputError
from rigcal.io.atomic import atomic_write_bytes
from rigcal.io.clouds._ascii import _ascii_column, _ascii_format, _ascii_table, _narrow, _wide_dtype
from rigcal.io.clouds._columns import (
    _columns_of,
    _frame_from_columns,
    _records,
    _xyz_dtype,
)
from rigcal.recording import PointCloudFrame

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
              "u4": "uint", "f4": "float", "f8": "double"}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


def parse_ply_bytes(data: bytes, source: str, sensor: str = "", t_ns: int = 0,
                    frame_id: str = "") -> PointCloudFrame:
    """Parse the ``vertex`` element of a PLY file into a :class:`PointCloudFrame`.

    Elements before ``vertex`` are skipped (in binary files only if they have no list
    properties); list properties of ``vertex`` itself are refused."""
    data = bytes(data)
    if not data.startswith(b"ply"):
        raise InputError(f"{source}: not a PLY file (does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise InputError(f"{source}: PLY header has no end_header line")
    nl = data.find(b"\n", end)
    offset = len(data) if nl < 0 else nl + 1
    try:
        head_lines = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError(f"{source}: PLY header is not ASCII text") from None
    fmt: str | None = None
    elements: list[tuple[str, int, list[tuple[str, str | None]]]] = []
    for line_no, line in enumerate(head_lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        where = f"{source}: bad PLY header line {line_no} '{line.strip()[:60]}'"
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _PLY_FORMATS:
                raise InputError(
                    f"{where}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0'"
                )
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise InputError(f"{where}: expected 'element <name> <count>'")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise InputError(f"{where}: property before any element")
            if len(words) == 5 and words[1] == "list":
                elements[-1][2].append((words[4], None))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise InputError(
                    f"{where}: expected 'property <type> <name>' with type one of "
                    f"{', '.join(sorted(set(_PLY_TYPES)))}"
                )
        else:
            raise InputError(f"{where}: unknown keyword '{words[0]}'")
    if fmt is None:
        raise InputError(f"{source}: PLY header has no format line")
    index = next((k for k, e in enumerate(elements) if e[0] == "vertex"), None)
    if index is None:
        raise InputError(
            f"{source}: PLY file has elements {[e[0] for e in elements]}, expected 'vertex'"
        )
    _, n, props = elements[index]
    lists = [name for name, typ in props if typ is None]
    if lists:
        raise InputError(f"{source}: PLY vertex list properties {lists} are not supported")
    body = data[offset:]
    order = _PLY_FORMATS[fmt]
    columns: list[tuple[str, np.ndarray]] = []
    table = None
    if fmt == "ascii" and not any(e[1] for e in elements[:index]):  # vertex data come first
        table = _ascii_table(body, n, [_wide_dtype(np.dtype(t)) for _, t in props])  # type: ignore[arg-type]
    if table is not None:
        for k, (name, typ) in enumerate(props):
            values = _narrow(table[f"f{k}"], np.dtype(typ))  # type: ignore[arg-type]
            if values is None:  # out of range: the line-by-line parser below names the value
                columns = []
                break
            columns.append((name, values))
        else:
            return _frame_from_columns(columns, source, sensor, t_ns, None, frame_id)
    if fmt == "ascii":
        try:
            rows = body.decode("ascii").splitlines()
        except UnicodeDecodeError:
            raise InputError(f"{source}: PLY ascii data is not ASCII text") from None
        skip = sum(e[1] for e in elements[:index])
        rows = [r for r in rows if r.strip()][skip:skip + n]
        if len(rows) < n:
            raise InputError(
                f"{source}: truncated PLY data: {len(rows)} vertex lines, expected {n}"
            )
        tokens = [r.split() for r in rows]
        for k, row in enumerate(tokens):
            if len(row) != len(props):
                raise InputError(
                    f"{source}: PLY vertex {k} has {len(row)} values, expected {len(props)}"
                )
        table = np.array(tokens, dtype=str).reshape(n, len(props))
        for k, (name, typ) in enumerate(props):
            dt = np.dtype(typ)  # type: ignore[arg-type]
            col = _ascii_column(table[:, k:k + 1], dt, f"{source}: PLY vertex property '{name}'")
            columns.append((name, col[:, 0]))
    else:
        skip = 0
        for name, count, eprops in elements[:index]:
            if any(t is None for _, t in eprops):
                raise InputError(
                    f"{source}: PLY element '{name}' before 'vertex' has list properties; "
                    "cannot skip it in a binary file"
                )
            skip += count * sum(np.dtype(t).itemsize for _, t in eprops)  # type: ignore[arg-type]
        record = np.dtype({"names": [f"f{k}" for k in range(len(props))],
                           "formats": [order + str(t) for _, t in props]})
        need = skip + n * record.itemsize
        if len(body) < need:
            raise InputError(
                f"{source}: truncated PLY data: {n} vertices need {need} bytes, got {len(body)}"
            )
        table = np.frombuffer(body, dtype=record, count=n, offset=skip)
        columns = [(name, table[f"f{k}"]) for k, (name, _) in enumerate(props)]
    return _frame_from_columns(columns, source, sensor, t_ns, None, frame_id)


def ply_bytes(frame: PointCloudFrame, data: str = "binary_little_endian",
              xyz_dtype: object = np.float64, source: str = "PLY") -> bytes:
    """The bytes of a PLY file with one ``vertex`` element: x, y, z (``xyz_dtype``, float64 by
    default: lossless) then every field. ``data`` is ``'binary_little_endian'`` or ``'ascii'``.

    PLY has no 64-bit integers: int64/uint64 fields are refused."""
    if data not in ("ascii", "binary_little_endian"):
        raise InputError(
            f"{source}: PLY data must be 'ascii' or 'binary_little_endian', got {data!r}"
        )
    cols = _columns_of(frame, _xyz_dtype(xyz_dtype, source), source)
    for name, c in cols:
        if c.dtype.kind in "iu" and c.dtype.itemsize == 8:
            raise InputError(f"{source}: field '{name}' is {c.dtype}; PLY has no 64-bit integers")
    n = len(frame)
    lines = ["ply", f"format {data} 1.0", "comment written by rigcal", f"element vertex {n}"]
    lines += [f"property {_PLY_NAMES[c.dtype.str[1:]]} {name}" for name, c in cols]
    lines.append("end_header")
    head = ("\n".join(lines) + "\n").encode("ascii")
    if data == "binary_little_endian":
        return b"".join([head, _records(cols, n)])
    fmt = " ".join(_ascii_format(c.dtype) for _, c in cols)
    values = [c.tolist() for _, c in cols]
    return head + "".join(fmt % row + "\n" for row in zip(*values)).encode("ascii")


def write_ply(path: str | os.PathLike[str], frame: PointCloudFrame,
              data: str = "binary_little_endian", xyz_dtype: object = np.float64,
              durable: bool = True) -> Path:
    """Write ``frame`` as a PLY file (see :func:`ply_bytes`) atomically; returns the path.
    ``durable=False`` skips the fsync (see :func:`rigcal.io.atomic.atomic_write_bytes`)."""
    return atomic_write_bytes(path, ply_bytes(frame, data, xyz_dtype, source=str(path)), durable)


