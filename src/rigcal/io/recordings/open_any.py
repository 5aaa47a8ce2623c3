"""Open any recording: a ROS bag (:mod:`.bag`) or a folder of files (:mod:`.folder`).

Both kinds offer the same reading API (``topics()``, ``count(topic)`` and
``frames(sensor_topics, start_ns, end_ns)``, as a context manager), so code that detects boards
or reads mocap streams opens a path here and never asks which kind it got.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from rigcal.errors import InputError
from rigcal.io.limits import os_error_text, path_stat
from rigcal.io.recordings.bag import Recording, open_bag
from rigcal.io.recordings.folder import FolderRecording

__all__ = ["open_any"]

_ROS2_STORAGE = (".db3", ".mcap")


def open_any(path: str | os.PathLike[str]) -> Recording | FolderRecording:
    """A bag (``.bag``/``.db3``/``.mcap`` file, or a directory with ``metadata.yaml``) via
    :func:`rigcal.io.recordings.bag.open_bag`, else a folder recording.

    A directory holding ``.db3``/``.mcap`` files but no ``metadata.yaml`` is refused as a ROS 2
    bag with its metadata missing (not read as an empty folder recording)."""
    p = Path(path)
    st = path_stat(p, "recording")
    if st is None:
        raise InputError(f"{p}: recording folder not found (expected a .bag file, a ROS 2 bag "
                         "folder or a folder with one subfolder per sensor)")
    if stat.S_ISDIR(st.st_mode) and path_stat(p / "metadata.yaml", "recording") is None:
        try:
            storage = sorted(c.name for c in p.iterdir()
                             if c.suffix.lower() in _ROS2_STORAGE and c.is_file())
        except OSError as exc:
            raise InputError(f"{p}: cannot list folder: {os_error_text(exc)}") from None
        if storage:
            shown = ", ".join(storage[:3]) + (", ..." if len(storage) > 3 else "")
            raise InputError(
                f"{p}: looks like a ROS 2 bag (has {shown}) but metadata.yaml is missing; "
                "expected a ROS 2 bag folder with metadata.yaml (`ros2 bag reindex` "
                "rebuilds it), a .bag file or a folder with one subfolder per sensor"
            )
        return FolderRecording(p)
    return open_bag(p)
