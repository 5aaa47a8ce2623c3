"""Point cloud files: PCD (v0.7), PLY and NPY, read into and written from :class:`PointCloudFrame`.

Formats
-------
* **PCD** v0.7 (the Point Cloud Library's format): a text header (``VERSION``, ``FIELDS``,
  ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``, ``HEIGHT``, ``VIEWPOINT``, ``POINTS``, ``DATA``) then
  the points as ``ascii`` (one point a line), ``binary`` (packed little-endian records, row-major)
  or ``binary_compressed`` (two uint32 sizes, then one LZF block holding the fields column by
  column). Fields may come in any order; ``_`` fields are padding and are skipped; a field with
  ``COUNT`` k > 1 becomes k fields ``name_0 .. name_{k-1}``. ``HEIGHT`` > 1 is an organised
  cloud: ``organized_shape`` = (HEIGHT, WIDTH), row-major. ``VIEWPOINT`` is checked, not applied.
* **PLY**: the ``vertex`` element of an ``ascii``, ``binary_little_endian`` or
  ``binary_big_endian`` file, with ``x y z`` and any other scalar properties.
* **NPY**: an (N, 3) or (H, W, 3) numeric array, or a structured array (N,) or (H, W) with
  fields ``x``, ``y``, ``z`` (and any others).

Every field other than ``x``, ``y``, ``z`` lands in ``PointCloudFrame.fields`` under its own name
with its own dtype (e.g. ``intensity`` float32, ``ring`` uint16, ``rgb`` float32 as PCL packs it).
Points are read as they are stored: NaN points stay (organised clouds need them).

Parsers take bytes and return values (:func:`parse_pcd_bytes`, :func:`parse_ply_bytes`,
:func:`parse_npy_bytes`); writers build bytes (:func:`pcd_bytes`, :func:`ply_bytes`,
:func:`npy_bytes`) and write them atomically. Every problem raises
:class:`rigcal.errors.InputError` naming the file (``source``).

LZF (used by ``binary_compressed``) is a stream of tokens, each starting with a control byte
``c``: ``c < 32`` is a literal run of ``c + 1`` bytes that follow; otherwise ``c >> 5`` is a
length code L (7 means "add the next byte") and the back reference copies ``L + 2`` bytes from
``((c & 31) << 8 | next byte) + 1`` bytes back in the output (the copy may overlap itself). A
token of 3 bytes yields at most 264, so a block of ``m`` bytes decompresses to at most ``88 m``
bytes: a header announcing more is refused before anything is allocated, and decompression never
writes past the announced size. The compiled liblzf of the ``python-neo-lzf`` package (a
dependency) does the work; without it a pure-Python codec is used (the same format, about a
second per megabyte).

ASCII data are parsed by NumPy's ``loadtxt`` when they are well formed; any problem (a bad token,
a short line, a value out of the field's range) is diagnosed by a line-by-line parser that names
the point and the field.

The ``ring`` field (the laser index of a spinning lidar) is written as ``U 2`` (uint16, as the
Velodyne and Ouster drivers publish it) and read into uint16 whatever integer type a file uses,
when its values fit (0..65535; otherwise it keeps the file's type).
"""

from __future__ import annotations

import io
import math
import os
import re
import struct
import warnings
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from rigcal.errors import InputError
from rigcal.io.limits import MAX_ELEMENTS, check_count, check_finite, check_points, read_limited
from rigcal.io.atomic import atomic_write_bytes
from rigcal.recording import PointCloudFrame, RadarFrame

try:  # python-neo-lzf: liblzf, compiled
    import lzf as _clzf
except ImportError:  # pragma: no cover - the package is a dependency
    _clzf = None

__all__ = [
    "DEFAULT_RCS_FIELDS",
    "lzf_compress",
    "lzf_decompress",
    "npy_bytes",
    "parse_npy_bytes",
    "parse_pcd_bytes",
    "parse_ply_bytes",
    "pcd_bytes",
    "ply_bytes",
    "radar_frame_from_cloud",
    "read_point_cloud",
    "write_npy",
    "write_pcd",
    "write_ply",
]

POINT_CLOUD_SUFFIXES = (".pcd", ".ply", ".npy")
"""File name suffixes :func:`read_point_cloud` understands (case-insensitive)."""

DEFAULT_RCS_FIELDS = ("rcs", "RCS", "rcs0")
"""Field names tried, in order, for a radar's radar cross-section when none is configured."""

_XYZ = ("x", "y", "z")
_PCD_DATA_KINDS = ("ascii", "binary", "binary_compressed")
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
             "POINTS", "DATA")
_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_MAX_HEADER_BYTES = 1 << 16
_RING = "ring"

LZF_BACKEND = "liblzf (python-neo-lzf)" if _clzf is not None else "pure Python"
"""Which LZF codec :func:`lzf_compress` / :func:`lzf_decompress` use."""

_LZF_MAX_RATIO = 88  # a 3-byte back reference yields at most 264 bytes


# --------------------------------------------------------------------------------------------
# LZF


def lzf_decompress(data: bytes | bytearray | memoryview, expected_size: int | None = None,
                   source: str = "LZF data") -> bytes:
    """Decompress one LZF block; ``expected_size`` (if given) must match the output length, and
    no more than it is ever produced (a "bomb" stops there).

    Corrupt input (a reference before the start, a token cut short) raises InputError naming
    ``source``. With ``expected_size`` the compiled codec is used when installed."""
    src = bytes(data)
    n = len(src)
    if expected_size is not None:
        if expected_size > _LZF_MAX_RATIO * n:
            raise InputError(
                f"{source}: LZF data of {n} bytes cannot decompress to the announced "
                f"{expected_size} bytes (at most {_LZF_MAX_RATIO} x {n})"
            )
        if _clzf is not None:
            return _lzf_decompress_compiled(src, expected_size, source)
    out = bytearray()
    i = 0
    while i < n:
        ctrl = src[i]
        i += 1
        if ctrl < 32:  # literal run
            run = ctrl + 1
            if i + run > n:
                raise InputError(
                    f"{source}: corrupt LZF data: literal run of {run} bytes at input byte "
                    f"{i - 1} goes past the end ({n} bytes)"
                )
            out += src[i:i + run]
            i += run
            if expected_size is not None and len(out) > expected_size:
                break
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise InputError(f"{source}: corrupt LZF data: truncated back reference at end")
            length += src[i]
            i += 1
        if i >= n:
            raise InputError(f"{source}: corrupt LZF data: truncated back reference at end")
        distance = ((ctrl & 0x1F) << 8 | src[i]) + 1
        i += 1
        length += 2
        start = len(out) - distance
        if start < 0:
            raise InputError(
                f"{source}: corrupt LZF data: back reference {distance} bytes before output "
                f"byte {len(out)}"
            )
        if expected_size is not None and len(out) + length > expected_size:
            break  # reported below: more data than announced
        if distance >= length:
            out += out[start:start + length]
        else:  # overlapping copy repeats the last `distance` bytes
            pattern = bytes(out[start:])
            out += (pattern * (length // distance + 1))[:length]
    if expected_size is not None and (len(out) != expected_size or i < n):
        got = f"{len(out)} bytes" if i >= n else f"more than {expected_size} bytes"
        raise InputError(
            f"{source}: LZF data decompress to {got}, expected {expected_size}"
        )
    return bytes(out)


_LZF_MAX_DISTANCE = 1 << 13
_LZF_MAX_MATCH = 264
_LZF_MAX_LITERAL = 32


def _emit_literals(out: bytearray, chunk: bytes) -> None:
    for k in range(0, len(chunk), _LZF_MAX_LITERAL):
        part = chunk[k:k + _LZF_MAX_LITERAL]
        out.append(len(part) - 1)
        out += part


def _match_length(data: bytes, a: int, b: int, limit: int) -> int:
    """Length of the common prefix of data[a:] and data[b:], at most ``limit``."""
    length = 0
    step = 32
    while length + step <= limit and data[a + length:a + length + step] == data[
        b + length:b + length + step
    ]:
        length += step
    while length < limit and data[a + length] == data[b + length]:
        length += 1
    return length


def _lzf_decompress_compiled(src: bytes, expected_size: int, source: str) -> bytes:
    if expected_size == 0 or not src:
        if src or expected_size:
            got = "more than 0 bytes" if src else "0 bytes"
            raise InputError(f"{source}: LZF data decompress to {got}, expected {expected_size}")
        return b""
    try:
        out = _clzf.decompress(src, expected_size)
    except ValueError:
        raise InputError(
            f"{source}: corrupt LZF data (a back reference before the start of the output or a "
            "token cut short)"
        ) from None
    except MemoryError:
        raise InputError(
            f"{source}: not enough memory to decompress the announced {expected_size} bytes"
        ) from None
    if out is None:  # liblzf stops where the output would pass expected_size
        raise InputError(
            f"{source}: LZF data decompress to more than {expected_size} bytes, expected "
            f"{expected_size}"
        )
    if len(out) != expected_size:
        raise InputError(
            f"{source}: LZF data decompress to {len(out)} bytes, expected {expected_size}"
        )
    return out


def lzf_compress(data: bytes | bytearray | memoryview) -> bytes:
    """Compress ``data`` into one LZF block (liblzf when installed; otherwise greedy matching
    over a hash of 3-byte keys in pure Python, about a second per megabyte)."""
    src = bytes(data)
    n = len(src)
    if _clzf is not None and n:
        # incompressible data grow by at most 1 byte in 32 (a literal run's control byte)
        out = _clzf.compress(src, n + n // 16 + 64)
        if out is not None:
            return out
    out = bytearray()
    table: dict[bytes, int] = {}
    literal_start = 0
    i = 0
    while i + 2 < n:
        key = src[i:i + 3]
        candidate = table.get(key)
        table[key] = i
        if candidate is None or i - candidate > _LZF_MAX_DISTANCE:
            i += 1
            continue
        length = 3 + _match_length(src, candidate + 3, i + 3, min(_LZF_MAX_MATCH, n - i) - 3)
        _emit_literals(out, src[literal_start:i])
        code = length - 2
        offset = i - candidate - 1
        if code < 7:
            out.append((code << 5) | (offset >> 8))
        else:
            out.append((7 << 5) | (offset >> 8))
            out.append(code - 7)
        out.append(offset & 0xFF)
        end = i + length
        for j in range(max(i + 1, end - 2), min(end, n - 2)):  # keep the table fresh
            table[src[j:j + 3]] = j
        i = literal_start = end
    _emit_literals(out, src[literal_start:])
    return bytes(out)


# --------------------------------------------------------------------------------------------
# shared helpers


def _frame_from_columns(columns: Sequence[tuple[str, np.ndarray]], source: str, sensor: str,
                        t_ns: int, organized_shape: tuple[int, int] | None,
                        frame_id: str = "") -> PointCloudFrame:
    """A frame from named columns (N,) or (N, k); padding ``_`` columns are dropped."""
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


# --------------------------------------------------------------------------------------------
# PCD


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


def _wide_dtype(dt: np.dtype) -> np.dtype:
    """The dtype ASCII values of ``dt`` are parsed into before their range is checked."""
    if dt.kind == "f":
        return np.dtype(np.float64)
    return np.dtype(np.uint64 if dt == np.dtype("<u8") else np.int64)


def _ascii_table(body: bytes, n: int, wide: Sequence[np.dtype]) -> np.ndarray | None:
    """The first ``n`` non-blank lines of ASCII ``body`` as a structured (n,) array with
    fields ``f0, f1, ...`` of the ``wide`` dtypes (one per value of a line), or None if the
    lines are not exactly that (a bad token, a short or long line, too few lines, non-ASCII
    bytes): then the caller's line-by-line parser says what is wrong."""
    if n == 0 or not body.isascii():
        return None
    if b"\r" in body:  # loadtxt splits lines at \n only
        body = body.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    record = np.dtype([(f"f{k}", dt) for k, dt in enumerate(wide)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "blank lines do not count towards max_rows"
        try:
            table = np.loadtxt(io.BytesIO(body), dtype=record, comments=None, max_rows=n,
                               ndmin=1)
        except (ValueError, OverflowError, TypeError, MemoryError):
            return None
    return table if table.shape == (n,) else None


def _narrow(wide: np.ndarray, dt: np.dtype) -> np.ndarray | None:
    """``wide`` (float64 / int64 / uint64 values) as ``dt``, or None if a value is out of its
    range (a finite float beyond float32, an integer that does not fit)."""
    if dt.kind == "f":
        if dt.itemsize < 8:
            with np.errstate(invalid="ignore"):
                if np.any(np.isfinite(wide) & (np.abs(wide) > np.finfo(dt).max)):
                    return None
        with np.errstate(under="ignore"):  # 1e-320 becomes 0 in float32, as C's strtof does
            return wide.astype(dt)
    if dt.itemsize < 8:
        info = np.iinfo(dt)
        if wide.size and (wide.min() < info.min or wide.max() > info.max):
            return None
    elif dt.kind == "u" and wide.dtype.kind == "i" and wide.size and wide.min() < 0:
        return None
    return wide.astype(dt)


def _ascii_column(block: np.ndarray, dt: np.dtype, where: str) -> np.ndarray:
    """Text tokens -> values of ``dt``; a bad token or an integer out of range is named."""
    try:
        if dt.kind == "f":
            wide_f = block.astype(np.float64)
            limit = np.finfo(dt).max
            with np.errstate(invalid="ignore"):
                too_big = np.isfinite(wide_f) & (np.abs(wide_f) > limit)
            if too_big.any():  # would overflow (with a RuntimeWarning) into inf
                raise InputError(f"{where}: value {str(block[too_big][0])!r} out of range for "
                                 f"F{dt.itemsize * 8}")
            with np.errstate(under="ignore"):  # a tiny value becomes 0 in float32
                return wide_f.astype(dt)
        wide = block.astype(np.uint64 if dt == np.dtype("<u8") else np.int64)
    except (ValueError, OverflowError):
        wide = None
    if wide is None:
        for token in block.ravel():
            try:
                float(token) if dt.kind == "f" else int(token)
            except ValueError:
                raise InputError(f"{where}: bad value {str(token)!r}") from None
        raise InputError(f"{where}: value out of range")
    values = wide.astype(dt)
    if np.any(values.astype(wide.dtype) != wide) or (dt.kind == "u" and np.any(wide < 0)):
        raise InputError(f"{where}: value out of range for {dt.kind.upper()}{dt.itemsize * 8}")
    return values


def _ascii_format(dt: np.dtype) -> str:
    if dt.kind == "f":
        return "%.9g" if dt.itemsize == 4 else "%.17g"
    return "%d"


def pcd_bytes(frame: PointCloudFrame, data: str = "binary", xyz_dtype: object = np.float32,
              source: str = "PCD") -> bytes:
    """The bytes of a PCD v0.7 file holding ``frame``: x, y, z (``xyz_dtype``, float32 as PCL
    expects, or float64) then every field with its own type.

    ``data`` is ``'binary'``, ``'ascii'`` (floats with round-trip precision) or
    ``'binary_compressed'`` (LZF). Organised frames keep WIDTH x HEIGHT."""
    return b"".join(_pcd_parts(frame, data, xyz_dtype, source))


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


# --------------------------------------------------------------------------------------------
# PLY

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


# --------------------------------------------------------------------------------------------
# NPY


def _npy_array(data: bytes, source: str) -> np.ndarray:
    """The array of ``.npy`` bytes; the header is read and checked (shape within
    :data:`~rigcal.io.limits.MAX_ELEMENTS`, data present in the file) before anything is
    allocated, so a header declaring a huge shape costs nothing."""
    if data.startswith(b"PK\x03\x04"):
        raise InputError(f"{source}: expected one array (.npy), got an archive (.npz)")
    fmt = np.lib.format
    buf = io.BytesIO(data)
    try:
        major, _ = fmt.read_magic(buf)
        if major == 1:
            shape, fortran, dtype = fmt.read_array_header_1_0(buf)
        elif major in (2, 3):
            shape, fortran, dtype = fmt.read_array_header_2_0(buf)
        else:
            raise ValueError(f"unsupported .npy format version {major}")
    except Exception as exc:  # noqa: BLE001 - numpy's header parser raises many kinds
        detail = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise InputError(f"{source}: not a valid .npy array: {detail}") from None
    offset = buf.tell()
    if dtype.hasobject:
        raise InputError(f"{source}: not a valid .npy array: it holds pickled Python objects "
                         f"(dtype {dtype}); expected numbers")
    if dtype.itemsize == 0:
        raise InputError(f"{source}: not a valid .npy array: dtype {dtype} has no data; "
                         "expected numbers")
    count = math.prod(shape)
    check_count(count, source, f".npy element count of shape {tuple(shape)}", MAX_ELEMENTS)
    need = count * dtype.itemsize
    if len(data) - offset < need:
        raise InputError(
            f"{source}: truncated .npy data: shape {tuple(shape)} of {dtype} needs {need} bytes, "
            f"got {len(data) - offset}"
        )
    try:
        flat = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        if fortran:
            return flat.reshape(shape[::-1]).transpose()
        return flat.reshape(shape)
    except ValueError as exc:
        raise InputError(f"{source}: not a valid .npy array: {exc}") from None


def parse_npy_bytes(data: bytes, source: str, sensor: str = "", t_ns: int = 0,
                    frame_id: str = "") -> PointCloudFrame:
    """Parse a ``.npy`` file: (N, 3) or (H, W, 3) numbers, or a structured (N,) or (H, W) array
    with fields x, y, z (other fields become frame fields). Pickled objects are refused."""
    arr = _npy_array(bytes(data), source)
    organized = None
    if arr.dtype.names:
        if arr.ndim not in (1, 2):
            raise InputError(
                f"{source}: a structured point array must be (N,) or (H, W), got {arr.shape}"
            )
        if arr.ndim == 2:
            organized = (int(arr.shape[0]), int(arr.shape[1]))
        flat = arr.reshape(-1)
        columns = []
        for name in arr.dtype.names:
            col = np.asarray(flat[name])
            if col.ndim > 2:
                raise InputError(f"{source}: field '{name}' has shape {col.shape[1:]} per point")
            columns.append((name, col))
        return _frame_from_columns(columns, source, sensor, t_ns, organized, frame_id)
    if arr.dtype.kind not in "iuf":
        raise InputError(f"{source}: expected a numeric array, got dtype {arr.dtype}")
    if arr.ndim == 3 and arr.shape[2] == 3:
        organized = (int(arr.shape[0]), int(arr.shape[1]))
        arr = arr.reshape(-1, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(
            f"{source}: expected an (N, 3) x, y, z array or a structured array with fields "
            f"x, y, z, got shape {arr.shape}"
        )
    return PointCloudFrame(sensor=sensor, t_ns=t_ns,
                           points_xyz=check_points(arr.astype(np.float64), source),
                           organized_shape=organized, frame_id=frame_id)


def npy_bytes(frame: PointCloudFrame, source: str = "NPY") -> bytes:
    """The bytes of a ``.npy`` file holding ``frame`` losslessly: an (N, 3) (or (H, W, 3))
    float64 array without fields, else a structured array x, y, z (float64) + fields."""
    shape = frame.organized_shape or (len(frame),)
    if frame.fields:
        cols = _columns_of(frame, np.dtype("<f8"), source)
        table = np.empty(len(frame), dtype=[(name, c.dtype) for name, c in cols])
        for name, c in cols:
            table[name] = c
        arr = table.reshape(shape)
    else:
        arr = np.asarray(frame.points_xyz, dtype="<f8").reshape(*shape, 3)
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def write_npy(path: str | os.PathLike[str], frame: PointCloudFrame, durable: bool = True) -> Path:
    """Write ``frame`` as ``.npy`` (see :func:`npy_bytes`) atomically; returns the path.
    ``durable=False`` skips the fsync (see :func:`rigcal.io.atomic.atomic_write_bytes`)."""
    return atomic_write_bytes(path, npy_bytes(frame, source=str(path)), durable)


# --------------------------------------------------------------------------------------------
# dispatch and radar


def read_point_cloud(path: str | os.PathLike[str], sensor: str, t_ns: int = 0,
                     frame_id: str = "") -> PointCloudFrame:
    """Read a ``.pcd``, ``.ply`` or ``.npy`` file (chosen by suffix) into a PointCloudFrame."""
    p = Path(path)
    suffix = p.suffix.lower()
    parsers = {".pcd": parse_pcd_bytes, ".ply": parse_ply_bytes, ".npy": parse_npy_bytes}
    if suffix not in parsers:
        raise InputError(
            f"{p}: unknown point cloud format '{p.suffix}' (expected {', '.join(parsers)})"
        )
    return parsers[suffix](_read_bytes(p, "point cloud file"), str(p), sensor, t_ns, frame_id)


def radar_frame_from_cloud(cloud: PointCloudFrame, dims: int = 2,
                           rcs_field: str | Iterable[str] | None = None,
                           source: str = "") -> RadarFrame:
    """A radar detection list from a point cloud with an RCS field.

    ``dims`` 2 takes x, y (a 2D radar), 3 takes x, y, z. ``rcs_field`` names the RCS field or a
    list of candidates (default :data:`DEFAULT_RCS_FIELDS`); the first present is used."""
    if dims not in (2, 3):
        raise InputError(f"{source or cloud.sensor}: radar dims must be 2 or 3, got {dims}")
    candidates = DEFAULT_RCS_FIELDS if rcs_field is None else (
        (rcs_field,) if isinstance(rcs_field, str) else tuple(rcs_field)
    )
    name = next((c for c in candidates if c in cloud.fields), None)
    if name is None:
        raise InputError(
            f"{source or cloud.sensor}: radar point cloud has fields "
            f"{['x', 'y', 'z', *cloud.fields]}, expected an RCS field "
            f"({' or '.join(candidates)})"
        )
    rcs = check_finite(np.asarray(cloud.fields[name], dtype=np.float64),
                       source or cloud.sensor, f"RCS field '{name}' of point", "1", allow_nan=True)
    return RadarFrame(sensor=cloud.sensor, t_ns=cloud.t_ns, points=cloud.points_xyz[:, :dims],
                      rcs_dbsm=rcs,
                      frame_id=cloud.frame_id)
