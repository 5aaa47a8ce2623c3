"""Input limits in one place: what rigcal accepts from a file before it parses or trusts it.

Every reader goes through :func:`regular_file` / :func:`read_limited` (regular files only, a size
budget per kind of file), YAML through :func:`rigcal.io._text.load_yaml` (a node budget that counts
aliases at their expanded size, a nesting limit) and numeric fields through :func:`check_finite`
(finite, and within the magnitude that makes sense for the unit). A value outside these limits is
refused with an :class:`~rigcal.errors.InputError` naming the file or field, before any work
(or memory) is spent on it.

The limits are generous for real data (a 1-hour 200 Hz mocap CSV, a 100-million-point scan) and
small enough that a hostile file fails in well under a second.
"""

from __future__ import annotations

import errno
import math
import os
import stat
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from rigcal.errors import InputError

MiB = 1 << 20

#: Largest file accepted, per kind of input (bytes).
MAX_BYTES = MappingProxyType({
    "text": 256 * MiB,  # YAML, CSV, JSON, URDF: manifests, detections, mocap streams, labels
    "yaml": 64 * MiB,
    "point cloud": 4096 * MiB,  # PCD/PLY/NPY/XYZ scans (a 100 M point scan is ~1.6 GB)
    "image": 512 * MiB,
})

#: YAML: the most nodes a document may expand to (aliases counted at their expanded size).
YAML_MAX_NODES = 1_000_000
#: YAML: deepest nesting of sequences and mappings.
YAML_MAX_DEPTH = 64
#: Most elements (rows x columns) in one numeric table or array read from a file.
MAX_ELEMENTS = 2_000_000_000

#: Largest magnitude accepted for a value in a unit (beyond it the value is a unit mistake or an
#: attack: 1.797e308 m is finite but breaks every SVD it enters).
MAX_ABS = MappingProxyType({
    "m": 1.0e5,  # 100 km: positions, ranges, lengths
    "px": 1.0e6,  # image coordinates and focal lengths
    "rad": 1.0e3,  # angles (a few turns at most)
    "deg": 1.0e5,
    "s": 1.0e11,  # stamps in seconds (year 5138) and durations
    "ns": 1.0e20,  # stamps in nanoseconds
    "1": 1.0e12,  # unit-less values (intensities, scores, counts)
})


def _kind_name(st_mode: int) -> str:
    if stat.S_ISDIR(st_mode):
        return "a directory"
    if stat.S_ISFIFO(st_mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(st_mode):
        return "a character device"
    if stat.S_ISBLK(st_mode):
        return "a block device"
    if stat.S_ISSOCK(st_mode):
        return "a socket"
    return "not a regular file"


def os_error_text(exc: OSError) -> str:
    """A short reason for an OSError (the file name is added by the caller)."""
    if exc.errno == errno.ENAMETOOLONG:
        return "file name too long for the file system"
    return exc.strerror or str(exc)


def path_stat(path: str | os.PathLike[str], what: str = "file") -> os.stat_result | None:
    """``os.stat`` of ``path``, or None if nothing is there. Any other failure (a name longer than
    the file system allows - which ``Path.exists()`` raises on Python < 3.12 -, a permission
    problem, a loop of links) is an InputError naming the path."""
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except (OSError, ValueError) as exc:  # ValueError: an embedded NUL byte
        reason = os_error_text(exc) if isinstance(exc, OSError) else "invalid path (it contains a NUL byte)"
        raise InputError(f"{Path(path)}: cannot use {what}: {reason}") from None


def regular_file(path: str | os.PathLike[str], what: str = "file", kind: str = "text") -> Path:
    """``path`` as a Path after checking it names an existing regular file within the size budget
    of ``kind`` (a key of :data:`MAX_BYTES`). FIFOs, devices, sockets and directories are refused
    without being opened (opening a FIFO would block; reading /dev/zero never ends)."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise InputError(f"{p}: {what} not found") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {os_error_text(exc)}") from None
    except ValueError:  # an embedded NUL byte
        raise InputError(f"{str(p)!r}: cannot read {what}: the path contains a NUL byte") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: is {_kind_name(st.st_mode)}, expected a {what} (a regular file)")
    limit = MAX_BYTES[kind]
    if st.st_size > limit:
        raise InputError(
            f"{p}: {what} is {st.st_size / MiB:.0f} MiB, more than the {limit / MiB:.0f} MiB "
            f"rigcal reads for a {kind} file"
        )
    return p


def read_limited(path: str | os.PathLike[str], what: str = "file", kind: str = "text") -> bytes:
    """The bytes of ``path`` (see :func:`regular_file`); never reads past the size budget even if
    the file grows while it is read."""
    p = regular_file(path, what, kind)
    limit = MAX_BYTES[kind]
    try:
        with open(p, "rb") as fh:
            # read(n) allocates n bytes up front: ask for the file's size (+1 to see growth),
            # never for the whole budget
            size = os.fstat(fh.fileno()).st_size
            data = fh.read(min(size, limit) + 1)
            while len(data) <= limit:  # the file grew while it was read
                more = fh.read(min(16 * MiB, limit + 1 - len(data)))
                if not more:
                    break
                data += more
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {os_error_text(exc)}") from None
    if len(data) > limit:
        raise InputError(f"{p}: {what} is larger than the {limit / MiB:.0f} MiB rigcal reads")
    return data


def check_count(n: int, source: str, what: str, limit: int = MAX_ELEMENTS) -> int:
    """Refuse a declared element count (a header's ``POINTS``, a row count) above ``limit``."""
    if n < 0 or n > limit:
        raise InputError(f"{source}: {what} is {n}, expected 0 to {limit}")
    return n


def check_finite(values: Any, source: str, field: str, unit: str = "m",
                 allow_nan: bool = False) -> np.ndarray:
    """``values`` as a float array after checking every entry is finite (NaN allowed only when
    ``allow_nan``: a missing detection) and within :data:`MAX_ABS` ``[unit]``. The input is not
    modified; the message names ``source``, ``field``, the first bad index and the limit."""
    arr = np.asarray(values, dtype=float)
    limit = MAX_ABS[unit]
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(arr) <= limit)
    if allow_nan:
        bad &= ~np.isnan(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        value = float(arr[idx]) if arr.ndim else float(arr)
        where = f"[{', '.join(map(str, idx))}]" if idx else ""
        expected = f"a finite value within ±{limit:g} {unit}"
        raise InputError(f"{source}: {field}{where} is {value!r}, expected {expected}")
    return arr


def check_scalar(value: Any, source: str, field: str, unit: str = "m") -> float:
    """One finite number within :data:`MAX_ABS` ``[unit]``, as a float."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{source}: {field} is {value!r}, expected a number") from None
    if not (math.isfinite(x) and abs(x) <= MAX_ABS[unit]):
        raise InputError(
            f"{source}: {field} is {value!r}, expected a finite value within ±{MAX_ABS[unit]:g} {unit}"
        )
    return x


def check_points(points: Any, source: str, what: str = "point") -> np.ndarray:
    """Point coordinates (N, k) [m] as a float array after checking each is NaN or finite within
    :data:`MAX_ABS` ``["m"]``. NaN is allowed: it marks an invalid point (organised clouds, a
    PointCloud2 with ``is_dense`` false); infinities and absurd magnitudes are refused, naming
    the first bad point and axis."""
    arr = np.asarray(points, dtype=float)
    limit = MAX_ABS["m"]
    if arr.size and arr.ndim:
        # fast path: fmin/fmax skip NaN (NaN only if every entry is NaN) and need no temporaries
        lo, hi = np.fmin.reduce(arr, axis=None), np.fmax.reduce(arr, axis=None)
        if (math.isnan(lo) and math.isnan(hi)) or (-limit <= lo and hi <= limit):
            return arr
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(arr) <= limit) & ~np.isnan(arr)
    if bad.any():
        i, k = (int(v) for v in np.argwhere(bad.reshape(arr.shape[0], -1))[0])
        axis = "xyz"[k] if arr.ndim == 2 and arr.shape[1] <= 3 else str(k)
        raise InputError(
            f"{source}: {what} {i} has {axis} = {float(arr.reshape(arr.shape[0], -1)[i, k])!r}, expected "
            f"a finite coordinate within ±{limit:g} m (NaN marks an invalid point)"
        )
    return arr
