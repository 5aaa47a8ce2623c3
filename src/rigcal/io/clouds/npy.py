"""NPY files: (N, 3) / (H, W, 3) arrays or structured arrays with x, y, z (see
:mod:`rigcal.io.clouds`)."""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np

from rigcal.errors import InputError
from rigcal.io.atomic import atomic_write_bytes
from rigcal.io.clouds._columns import _columns_of, _frame_from_columns
from rigcal.io.limits import MAX_ELEMENTS, check_count, check_points
from rigcal.recording import PointCloudFrame


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


