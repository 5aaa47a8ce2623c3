"""Atomic file writes: readers see either the old file or the complete new one, never a part.

The data go to a temporary file in the target's directory (same file system), are flushed to
disk, then ``os.replace`` moves them over the target in one step. On any error the temporary
file is removed and the target is left as it was. Missing parent directories are created. A new
file gets the usual permissions (``0o666`` minus the umask); an existing file keeps its mode.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
import stat
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

from rigcal import interrupts
from rigcal.errors import InputError
from rigcal.io.limits import path_stat


_BUFFERS = (bytes, bytearray, memoryview)


def _make_parent(target: Path) -> None:
    """Create ``target``'s missing parent folders (InputError naming the folder on failure)."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(
            f"{target.parent}: cannot create output directory: {exc.strerror or exc}"
        ) from None


def atomic_write_bytes(path: str | os.PathLike[str],
                       data: bytes | bytearray | memoryview | list | tuple,
                       durable: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path. OS errors raise InputError.

    ``data`` may be a list or tuple of byte buffers, written one after the other (a header and
    a large array's memory without joining them first). The file is written beside ``path``
    and renamed over it, so a killed process leaves the old file or the new one, never a part.
    ``durable`` (default) also flushes it to the disk before the rename (``fsync``), so that a
    power cut cannot leave an empty file either; bulk data that can be written again (point
    clouds) may skip that: on a slow disk it costs more than encoding the data."""
    target = Path(path)
    parts = list(data) if isinstance(data, (list, tuple)) else [data]
    for part in parts:
        if not isinstance(part, _BUFFERS):
            raise TypeError(f"atomic_write_bytes: data must be bytes, got {type(part).__name__}")
    _make_parent(target)
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
            for part in parts:
                fh.write(part)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        interrupts.raise_if_requested()
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise InputError(f"{target}: cannot write file: {exc.strerror or exc}") from exc
        raise
    if target.parent.absolute() not in _STAGES.get():
        _fsync_directory(target.parent)  # (a stage is synced once, before it is published)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically; returns the path.

    Newlines are written as given (no platform translation)."""
    if not isinstance(text, str):
        raise TypeError(f"atomic_write_text: text must be str, got {type(text).__name__}")
    return atomic_write_bytes(path, text.encode("utf-8"))


#: the staged folders being written in this context: their files' renames need no directory
#: sync each, the whole stage is synced once before it is published
_STAGES: ContextVar[frozenset[Path]] = ContextVar("rigcal_stages", default=frozenset())


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


#: Name of the marker file in every folder rigcal writes as one set; an existing folder holding
#: it (or empty) may be replaced by a new set, any other existing folder is refused.
OUTPUT_MARKER = ".rigcal-output"


def mark_output(folder: str | os.PathLike[str]) -> Path:
    """Mark ``folder`` as written by rigcal (:data:`OUTPUT_MARKER`), so that a later run may
    replace it; every writer of a set of result files calls this."""
    return atomic_write_bytes(Path(folder) / OUTPUT_MARKER, b"written by rigcal as one set of files\n")


def check_replaceable(path: str | os.PathLike[str]) -> None:
    """InputError unless ``path`` is free for a set of files (:func:`staged_folder`): nothing
    there, an empty folder, or a folder rigcal wrote (:data:`OUTPUT_MARKER`)."""
    _replaceable(Path(path))


def _replaceable(target: Path) -> None:
    try:
        st = target.stat()
    except FileNotFoundError:
        return
    except OSError as exc:
        from rigcal.io.limits import os_error_text

        raise InputError(f"{target}: cannot use as output folder: {os_error_text(exc)}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{target}: exists and is not a folder; expected an output folder")
    try:
        entries = [e.name for e in os.scandir(target)]
    except OSError as exc:
        raise InputError(f"{target}: cannot read output folder: {exc.strerror or exc}") from None
    if entries and OUTPUT_MARKER not in entries:
        shown = ", ".join(sorted(entries)[:3]) + (", ..." if len(entries) > 3 else "")
        raise InputError(
            f"{target}: output folder already holds files rigcal did not write ({shown}); "
            "give a new or empty folder"
        )


def check_output_folder(path: str | os.PathLike[str], inputs: tuple = (), what: str = "--out") -> Path:
    """Refuse, before any work, an output folder that :func:`staged_folder` would refuse after
    it: a file there, a folder holding files rigcal did not write, one of ``inputs`` (paths the
    run reads), or a place that cannot be written (its nearest existing parent is not a folder,
    or not writable). Returns the path; InputError naming ``what`` and the path otherwise."""
    target = Path(path)
    st = path_stat(target, f"{what} folder")
    for source in inputs:
        try:
            same = st is not None and os.path.samefile(target, source)
            inside = st is not None and Path(target).resolve() in Path(source).resolve().parents
        except (OSError, ValueError):
            same = inside = False
        if same or inside:
            how = "is" if same else "holds"
            raise InputError(f"{what} {target}: {how} an input of this run ({source}); give another output folder")
    try:
        _replaceable(target)
    except InputError as exc:
        raise InputError(f"{what} {exc}") from None
    parent = target.absolute().parent
    while True:
        pst = path_stat(parent, f"{what} folder's parent")
        if pst is not None or parent == parent.parent:
            break
        parent = parent.parent
    if pst is None or not stat.S_ISDIR(pst.st_mode):
        raise InputError(f"{what} {target}: cannot create it: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{what} {target}: cannot create it: no permission to write in {parent}")
    return target


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                          ctypes.c_uint]
    rc = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _publish(stage: Path, target: Path) -> None:
    """Move the complete folder ``stage`` to ``target``; an earlier rigcal output there is
    replaced (swapped out in one step where the OS allows, then deleted)."""
    for _ in range(100):
        try:
            os.rename(stage, target)  # succeeds if target is absent or an empty folder
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
        _replaceable(target)
        if _exchange(stage, target):
            shutil.rmtree(stage, ignore_errors=True)  # stage now holds the previous set
            return
        old = target.parent / f".{target.name}.{secrets.token_hex(6)}.old"
        try:
            os.rename(target, old)
        except FileNotFoundError:
            continue  # another writer moved it away first: try again
        shutil.rmtree(old, ignore_errors=True)
    raise InputError(f"{target}: could not replace the output folder (other writers keep changing it)")


@contextmanager
def staged_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write a set of files as one: yields a new temporary folder beside ``path``; when the
    ``with`` block ends normally the folder (marked with :data:`OUTPUT_MARKER`) becomes ``path``
    in one rename, replacing an earlier rigcal output there. On any error or interrupt the
    temporary folder is removed and ``path`` is left as it was, so ``path`` holds a complete set
    or nothing. An existing folder that holds other files is refused (InputError)."""
    target = Path(path)
    _replaceable(target)
    _make_parent(target)
    stage = target.parent / f".{target.name}.{secrets.token_hex(6)}.partial"
    try:
        stage.mkdir()
    except OSError as exc:
        raise InputError(f"{target}: cannot create output folder: {exc.strerror or exc}") from None
    token = _STAGES.set(_STAGES.get() | {stage.absolute()})
    try:
        yield stage
        mark_output(stage)
        _fsync_directory(stage)
        interrupts.raise_if_requested()
        _publish(stage, target)
    except BaseException as exc:
        _STAGES.reset(token)
        shutil.rmtree(stage, ignore_errors=True)
        if isinstance(exc, OSError):
            raise InputError(f"{target}: cannot write output folder: {exc.strerror or exc}") from exc
        raise
    _STAGES.reset(token)
    _fsync_directory(target.parent)
