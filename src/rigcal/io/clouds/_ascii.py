"""ASCII point tables (PCD ``ascii``, PLY ``ascii``): NumPy's fast parser when the text is well
formed, then each column narrowed to its field's type with the value that does not fit named."""

from __future__ import annotations

import io
import warnings
from typing import Sequence

import numpy as np

from rigcal.errors import InputError


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
