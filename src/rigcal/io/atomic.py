"""Atomic file writes: readers see either the old file or the complete new one, never a part.

The data go to a temporary file in the target's directory (same file system), are flushed to
disk, then ``os.replace`` moves them over the target in one step. On any error the temporary
file is removed and the target is left as it was. Missing parent directories are created. A new
file gets the usual permissions (``0o666`` minus the umask); an existing file keeps its mode.
"""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from rigcal.errors import InputError
from rigcal.io.limits import path_stat


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path. OS errors raise InputError."""
    target = Path(path)
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"atomic_write_bytes: data must be bytes, got {type(data).__name__}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(
            f"{target.parent}: cannot create output directory: {exc.strerror or exc}"
        ) from exc
    st = path_stat(target, "output file")
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(f"{target}: is a directory, cannot write a file there")
    mode = st.st_mode & 0o7777 if st is not None else None
    tmp = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        raise InputError(f"{target}: cannot write file: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise InputError(f"{target}: cannot write file: {exc.strerror or exc}") from exc
        raise
    _fsync_directory(target.parent)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically; returns the path.

    Newlines are written as given (no platform translation)."""
    if not isinstance(text, str):
        raise TypeError(f"atomic_write_text: text must be str, got {type(text).__name__}")
    return atomic_write_bytes(path, text.encode("utf-8"))


def _fsync_directory(directory: Path) -> None:
    """Best effort: make the rename itself durable (POSIX only; ignored where unsupported)."""
    if os.name != "posix":
        return
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
