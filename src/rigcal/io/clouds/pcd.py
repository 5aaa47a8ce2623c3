"""PCD v0.7 files (the Point Cloud Library's format; see :mod:`rigcal.io.clouds`)."""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import numpy as np

from rigcal.errors import InputError
from rigcal.io.atomic import atomic_write_bytes
from rigcal.io.clouds._ascii import _ascii_column, _ascii_format, _ascii_table, _narrow, _wide_dtype
from rigcal.io.clouds._columns import _columns_of, _frame_from_columns, _records, _xyz_dtype
from rigcal.io.clouds.lzf import lzf_compress, lzf_decompress
from rigcal.recording import PointCloudFrame

_PCD_DATA_KINDS = ("ascii", "binary", "binary_compressed")
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
             "POINTS", "DATA")
_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_MAX_HEADER_BYTES = 1 << 16



def _pcd_header(data: bytes, source: str) -> tuple[dict[str, tuple[int, list[str]]], int]:
    """The header (key -> (line number, values)) and the offset of the data after DATA."""
    header: dict[str, tuple[int, list[str]]] = {}
    pos = 0
    line_no = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            if pos >= len(data):
                raise InputError(f"{source}: not a PCD file: the header has no DATA line")
            end = len(data)
        if end > _MAX_HEADER_BYTES:
            raise InputError(f"{source}: not a PCD file: no DATA line in the first 64 KiB")
        line_no += 1
        raw = data[pos:end]
        pos = end + 1
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise InputError(
                f"{source}: bad PCD header line {line_no}: not ASCII text"
                + ("" if header else " (is this a PCD file?)")
            ) from None
        if not text or text.startswith("#"):
            continue
        key, *values = text.split()
        if key not in _PCD_KEYS:
            raise InputError(
                f"{source}: bad PCD header line {line_no} '{text[:60]}': unknown keyword "
                f"'{key}' (expected one of {', '.join(_PCD_KEYS)})"
            )
        if key in header:
            raise InputError(f"{source}: bad PCD header line {line_no}: '{key}' given twice")
        header[key] = (line_no, values)
        if key == "DATA":
            return header, pos


def _pcd_where(header: dict[str, tuple[int, list[str]]], key: str, source: str) -> str:
    line_no, values = header[key]
    return f"{source}: bad PCD header line {line_no} '{' '.join([key, *values])[:60]}'"


def _pcd_ints(header: dict[str, tuple[int, list[str]]], key: str, source: str,
              count: int) -> list[int]:
    values = header[key][1]
    if len(values) != count:
        raise InputError(
            f"{_pcd_where(header, key, source)}: expected {count} value(s), got {len(values)}"
        )
    try:
        out = [int(v) for v in values]
    except ValueError:
        raise InputError(f"{_pcd_where(header, key, source)}: expected integers") from None
    if any(v < 0 for v in out):
        raise InputError(f"{_pcd_where(header, key, source)}: expected non-negative integers")
    return out


def _pcd_layout(header: dict[str, tuple[int, list[str]]], source: str
                ) -> tuple[list[str], list[np.dtype], list[int], int, int, int, str]:
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "DATA"):
        if key not in header:
            raise InputError(f"{source}: PCD header has no {key} line")
    names = header["FIELDS"][1]
    nf = len(names)
    if nf == 0:
        raise InputError(f"{_pcd_where(header, 'FIELDS', source)}: no field names")
    sizes = _pcd_ints(header, "SIZE", source, nf)
    types = header["TYPE"][1]
    if len(types) != nf:
        raise InputError(
            f"{_pcd_where(header, 'TYPE', source)}: expected {nf} value(s) (one per field), "
            f"got {len(types)}"
        )
    counts = _pcd_ints(header, "COUNT", source, nf) if "COUNT" in header else [1] * nf
    dtypes = []
    for name, size, typ, count in zip(names, sizes, types, counts):
        code = _PCD_TYPES.get((typ.upper(), size))
        if code is None:
            raise InputError(
                f"{source}: field '{name}': unsupported TYPE {typ} with SIZE {size} (supported: "
                "F 4/8, I 1/2/4/8, U 1/2/4/8)"
            )
        if count < 1:
            raise InputError(f"{source}: field '{name}': COUNT must be at least 1, got {count}")
        dtypes.append(np.dtype("<" + code))
    (width,) = _pcd_ints(header, "WIDTH", source, 1)
    (height,) = _pcd_ints(header, "HEIGHT", source, 1)
    if "POINTS" in header:
        (npoints,) = _pcd_ints(header, "POINTS", source, 1)
        if npoints != width * height:
            raise InputError(
                f"{_pcd_where(header, 'POINTS', source)}: differs from WIDTH x HEIGHT = "
                f"{width} x {height}"
            )
    if "VIEWPOINT" in header:
        vp = header["VIEWPOINT"][1]
        try:
            ok = len(vp) == 7 and all(math.isfinite(float(v)) for v in vp)
        except ValueError:
            ok = False
        if not ok:
            raise InputError(
                f"{_pcd_where(header, 'VIEWPOINT', source)}: expected 7 numbers "
                "(tx ty tz qw qx qy qz)"
            )
    data = header["DATA"][1]
    if len(data) != 1 or data[0].lower() not in _PCD_DATA_KINDS:
        raise InputError(
            f"{_pcd_where(header, 'DATA', source)}: expected one of {', '.join(_PCD_DATA_KINDS)}"
        )
    return names, dtypes, counts, width, height, width * height, data[0].lower()


def _xyz_block(body, names, dtypes, counts, n: int, point_size: int) -> np.ndarray | None:
    """x, y, z of binary records as one strided (N, 3) view of ``body`` when they are
    consecutive single fields of one float type (the usual layout), else None."""
    try:
        i = names.index("x")
    except ValueError:
        return None
    if (list(names[i:i + 3]) != ["x", "y", "z"] or any(names.count(a) != 1 for a in "xyz")
            or any(c != 1 for c in counts[i:i + 3])):
        return None
    dt = dtypes[i]
    if dt.kind != "f" or dtypes[i + 1] != dt or dtypes[i + 2] != dt or n == 0:
        return None
    offset = sum(d.itemsize * c for d, c in zip(dtypes[:i], counts[:i]))
    return np.ndarray((n, 3), dtype=dt, buffer=body, offset=offset, strides=(point_size, dt.itemsize))


def parse_pcd_bytes(data: bytes, source: str, sensor: str = "", t_ns: int = 0,
                    frame_id: str = "") -> PointCloudFrame:
    """Parse the bytes of a PCD file into a :class:`PointCloudFrame`.

    ``source`` names the file in error messages. See the module docstring for the format."""
    data = bytes(data)
    header, offset = _pcd_header(data, source)
    names, dtypes, counts, width, height, n, kind = _pcd_layout(header, source)
    body = memoryview(data)[offset:]  # no copy
    point_size = sum(dt.itemsize * c for dt, c in zip(dtypes, counts))
    columns: list[tuple[str, np.ndarray]] = []
    if kind == "binary":
        need = n * point_size
        if len(body) < need:
            raise InputError(
                f"{source}: truncated PCD data: DATA binary needs {need} bytes for {n} points "
                f"of {point_size} bytes, got {len(body)}"
            )
        record = np.dtype({
            "names": [f"f{k}" for k in range(len(names))],
            "formats": [dt if c == 1 else (dt, (c,)) for dt, c in zip(dtypes, counts)],
        })
        table = np.frombuffer(body, dtype=record, count=n)
        columns = [(name, table[f"f{k}"]) for k, name in enumerate(names)]
        xyz = _xyz_block(body, names, dtypes, counts, n, point_size)
        if xyz is not None:  # x, y, z side by side: one (N, 3) view instead of three columns
            organized = (height, width) if height > 1 else None
            rest = [c for c in columns if c[0] not in ("x", "y", "z")]
            return _frame_from_columns(rest, source, sensor, t_ns, organized, frame_id, xyz=xyz)
    elif kind == "binary_compressed":
        if len(body) < 8:
            raise InputError(
                f"{source}: truncated PCD data: DATA binary_compressed needs an 8-byte size "
                f"header, got {len(body)} bytes"
            )
        packed, unpacked = struct.unpack("<II", body[:8])
        if len(body) - 8 < packed:
            raise InputError(
                f"{source}: truncated PCD data: {packed} compressed bytes announced, "
                f"{len(body) - 8} present"
            )
        need = n * point_size
        if unpacked != need:
            raise InputError(
                f"{source}: PCD binary_compressed announces {unpacked} uncompressed bytes, "
                f"expected {need} for {n} points of {point_size} bytes"
            )
        raw = lzf_decompress(body[8:8 + packed], need, source) if need else b""
        pos = 0
        for name, dt, c in zip(names, dtypes, counts):
            size = n * dt.itemsize * c
            col = np.frombuffer(raw, dtype=dt, count=n * c, offset=pos)
            columns.append((name, col if c == 1 else col.reshape(n, c)))
            pos += size
    else:  # ascii
        body = bytes(body)
        wide = [_wide_dtype(dt) for dt, c in zip(dtypes, counts) for _ in range(c)]
        table = _ascii_table(body, n, wide)
        if table is not None:
            col0 = 0
            for name, dt, c in zip(names, dtypes, counts):
                block = np.column_stack([table[f"f{col0 + j}"] for j in range(c)])
                values = _narrow(block, dt)
                if values is None:  # out of the field's range: the slow path names the value
                    break
                col0 += c
                columns.append((name, values[:, 0] if c == 1 else values))
            else:
                organized = (height, width) if height > 1 else None
                return _frame_from_columns(columns, source, sensor, t_ns, organized, frame_id)
            columns = []
        try:
            text = body.decode("ascii")
        except UnicodeDecodeError as exc:
            raise InputError(f"{source}: PCD ascii data is not ASCII text (byte {exc.start})"
                             ) from None
        total = sum(counts)
        rows = [line.split() for line in text.splitlines() if line.strip()]
        if len(rows) < n:
            raise InputError(
                f"{source}: truncated PCD data: DATA ascii has {len(rows)} point lines, "
                f"expected {n}"
            )
        for k, row in enumerate(rows[:n]):
            if len(row) != total:
                raise InputError(
                    f"{source}: PCD ascii point {k} has {len(row)} values, expected {total}"
                )
        table = np.array(rows[:n], dtype=str).reshape(n, total)
        col0 = 0
        for name, dt, c in zip(names, dtypes, counts):
            values = _ascii_column(table[:, col0:col0 + c], dt, f"{source}: PCD ascii field "
                                   f"'{name}' (TYPE {dt.kind.upper()} SIZE {dt.itemsize})")
            col0 += c
            columns.append((name, values[:, 0] if c == 1 else values))
    organized = (height, width) if height > 1 else None
    return _frame_from_columns(columns, source, sensor, t_ns, organized, frame_id)


def pcd_bytes(frame: PointCloudFrame, data: str = "binary", xyz_dtype: object = np.float32,
              source: str = "PCD") -> bytes:
    """The bytes of a PCD v0.7 file holding ``frame``: x, y, z (``xyz_dtype``, float32 as PCL
    expects, or float64) then every field with its own type.

    ``data`` is ``'binary'``, ``'ascii'`` (floats with round-trip precision) or
    ``'binary_compressed'`` (LZF). Organised frames keep WIDTH x HEIGHT."""
    return b"".join(_pcd_parts(frame, data, xyz_dtype, source))


def _pcd_parts(frame: PointCloudFrame, data: str, xyz_dtype: object, source: str
               ) -> list[bytes | memoryview]:
    """The PCD file of :func:`pcd_bytes` as a header and a body (not joined)."""
    if data not in _PCD_DATA_KINDS:
        raise InputError(f"{source}: PCD data must be one of {', '.join(_PCD_DATA_KINDS)}, "
                         f"got {data!r}")
    xyz_dt = _xyz_dtype(xyz_dtype, source)
    cols = _columns_of(frame, xyz_dt, source, cast_xyz=data != "binary")
    dtypes = [xyz_dt] * 3 + [c.dtype for _, c in cols[3:]]
    n = len(frame)
    height, width = frame.organized_shape if frame.organized_shape else (1, n)
    type_letter = {"f": "F", "i": "I", "u": "U"}
    lines = [
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        "FIELDS " + " ".join(name for name, _ in cols),
        "SIZE " + " ".join(str(dt.itemsize) for dt in dtypes),
        "TYPE " + " ".join(type_letter[dt.kind] for dt in dtypes),
        "COUNT " + " ".join("1" for _ in cols),
        f"WIDTH {width}",
        f"HEIGHT {height}",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {n}",
        f"DATA {data}",
    ]
    head = ("\n".join(lines) + "\n").encode("ascii")
    if data == "binary":
        return [head, _records(cols, n, xyz=frame.points_xyz, xyz_dtype=xyz_dt)]
    if data == "binary_compressed":
        raw = b"".join([np.ascontiguousarray(c).data.cast("B") for _, c in cols])
        packed = lzf_compress(raw) if raw else b""
        return [head + struct.pack("<II", len(packed), len(raw)), packed]
    fmt = " ".join(_ascii_format(c.dtype) for _, c in cols)
    values = [c.tolist() for _, c in cols]
    body = "".join(fmt % row + "\n" for row in zip(*values))
    return [head, body.encode("ascii")]


def write_pcd(path: str | os.PathLike[str], frame: PointCloudFrame, data: str = "binary",
              xyz_dtype: object = np.float32, durable: bool = True) -> Path:
    """Write ``frame`` as a PCD file (see :func:`pcd_bytes`) atomically; returns the path.
    ``durable=False`` skips the fsync (see :func:`rigcal.io.atomic.atomic_write_bytes`)."""
    return atomic_write_bytes(path, _pcd_parts(frame, data, xyz_dtype, source=str(path)), durable)


