"""A recording as a folder of files: one subfolder per sensor, one file per frame.

::

    recording/
      lidar/     1596000000.100000.pcd  1596000000.200000.pcd ...   (pcd, ply, npy)
      camera/    1596000000.100000.png  ...                         (png, jpg; or point clouds)
      radar/     1596000000.100000.csv  ...                         (x, y[, z], rcs columns)

Which subfolder belongs to which sensor is given to :meth:`FolderRecording.frames` exactly like
bag topics: ``{sensor: (subfolder, kind)}``, so detection code reads folders and bags alike.

* Files are taken in natural name order (``img_2`` before ``img_10``); hidden files and other
  suffixes are ignored.
* Timestamps come from the file names: an integer stem is nanoseconds (``1596000000100000000``),
  a decimal stem is seconds (``1596000000.100000``, read exactly to the nanosecond). If any file
  of a subfolder has another name, every frame of that subfolder gets its index (0, 1, 2, ...)
  as ``t_ns``, so frames of different sensors pair up by index.
* Point clouds (``.pcd``, ``.ply``, ``.npy``) become PointCloudFrame (lidar, camera) or, with an
  RCS field, RadarFrame (radar, radar3d); images (``.png``, ``.jpg``, ``.jpeg``, camera only)
  become ImageFrame (mono or BGR, 8-bit); radar CSVs (header row with ``x``, ``y``, ``z`` for a
  3D radar, and an RCS column ``rcs``/``RCS``/``rcs0``) become RadarFrame.
"""

from __future__ import annotations

import csv
import heapq
import io
import logging
import math
import os
import re
import stat
from pathlib import Path
from types import TracebackType
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.limits import MAX_ABS, path_stat, read_limited
from rigcal.io._text import read_text
from rigcal.io.atomic import atomic_write_bytes, atomic_write_text
from rigcal.io.clouds import (
    DEFAULT_RCS_FIELDS,
    POINT_CLOUD_SUFFIXES,
    npy_bytes,
    pcd_bytes,
    radar_frame_from_cloud,
    read_point_cloud,
)
from rigcal.io.recordings.images import IMAGE_SUFFIXES, decode_image_bytes, encode_png
from rigcal.recording import Frame, ImageFrame, PointCloudFrame, RadarFrame

__all__ = [
    "FolderRecording",
    "open_folder",
    "parse_radar_csv",
    "radar_csv_text",
    "time_ns_from_name",
    "write_folder_recording",
    "write_radar_csv",
]

log = logging.getLogger(__name__)

RADAR_SUFFIXES = (".csv",)
_CONTENT = {**{s: "points" for s in POINT_CLOUD_SUFFIXES},
            **{s: "image" for s in IMAGE_SUFFIXES}, **{s: "radar_csv" for s in RADAR_SUFFIXES}}


# --------------------------------------------------------------------------------------------
# pure parsers


def time_ns_from_name(stem: str) -> int | None:
    """A file stem as a time: integer nanoseconds or decimal seconds (exact); else None."""
    if re.fullmatch(r"\d+", stem):
        return int(stem)
    match = re.fullmatch(r"(\d+)\.(\d+)", stem)
    if match:
        return int(match.group(1)) * 1_000_000_000 + int(match.group(2)[:9].ljust(9, "0"))
    return None


def parse_radar_csv(text: str, source: str, sensor: str = "", t_ns: int = 0, dims: int = 2,
                    rcs_field: str | Sequence[str] | None = None, frame_id: str = "") -> RadarFrame:
    """A radar detection list from CSV text: a header row naming the columns (``x``, ``y``,
    ``z`` if ``dims`` is 3, and the RCS column ``rcs_field`` or one of rcs, RCS, rcs0), then one
    detection a row. Other columns are ignored; ``nan`` is allowed; blank lines are skipped."""
    # universal newlines: LF, CRLF and old-Mac CR line ends all end a row
    reader = csv.reader(io.StringIO(text, newline=None))
    try:
        rows = [(reader.line_num, row) for row in reader if any(cell.strip() for cell in row)]
    except csv.Error as exc:
        raise InputError(f"{source}: line {reader.line_num}: malformed CSV: {exc}") from None
    if not rows:
        raise InputError(f"{source}: empty radar CSV, expected a header row (x, y, ..., rcs)")
    header_line, header = rows[0]
    names = [h.strip() for h in header]
    candidates = DEFAULT_RCS_FIELDS if rcs_field is None else (
        (rcs_field,) if isinstance(rcs_field, str) else tuple(rcs_field)
    )
    rcs_name = next((c for c in candidates if c in names), None)
    wanted = ["x", "y", "z"][:dims]
    missing = [c for c in wanted if c not in names] + ([] if rcs_name else [
        " or ".join(candidates)])
    if missing:
        raise InputError(
            f"{source}: line {header_line}: radar CSV has columns {names}, missing "
            f"{', '.join(missing)}"
        )
    columns = [names.index(c) for c in [*wanted, rcs_name]]
    values = np.empty((len(rows) - 1, len(columns)))
    for r, (line, row) in enumerate(rows[1:]):
        if len(row) != len(names):
            raise InputError(
                f"{source}: line {line}: {len(row)} values, expected {len(names)} (one per column)"
            )
        for c, col in enumerate(columns):
            cell = row[col].strip()
            try:
                values[r, c] = float(cell)
            except ValueError:
                raise InputError(
                    f"{source}: line {line}, column '{names[col]}': expected a number, got "
                    f"{cell!r}"
                ) from None
            unit = "1" if c == dims else "m"  # rcs [dBsm] or a coordinate [m]
            if not (abs(values[r, c]) <= MAX_ABS[unit] or math.isnan(values[r, c])):
                raise InputError(
                    f"{source}: line {line}, column '{names[col]}': expected a finite number "
                    f"within ±{MAX_ABS[unit]:g}{' m' if unit == 'm' else ''} or nan, got {cell!r}"
                )
    return RadarFrame(sensor=sensor, t_ns=t_ns, points=values[:, :dims], rcs_dbsm=values[:, dims],
                      frame_id=frame_id)


def radar_csv_text(frame: RadarFrame) -> str:
    """CSV text of a radar frame (x, y[, z], rcs; full float precision), as
    :func:`parse_radar_csv` reads it."""
    names = ["x", "y", "z"][:frame.points.shape[1]] + ["rcs"]
    table = np.hstack([frame.points, frame.rcs_dbsm[:, None]])
    lines = [",".join(names)] + [",".join(_float_text(v) for v in row) for row in table]
    return "\n".join(lines) + "\n"


def _float_text(value: float) -> str:
    return "nan" if math.isnan(value) else repr(float(value))


def write_radar_csv(path: str | os.PathLike[str], frame: RadarFrame) -> Path:
    """Write a radar frame as CSV (see :func:`radar_csv_text`) atomically; returns the path."""
    return atomic_write_text(path, radar_csv_text(frame))


# --------------------------------------------------------------------------------------------
# the recording


def _natural_key(name: str) -> list[Any]:
    return [(0, int(tok), tok) if tok.isdigit() else (1, 0, tok)
            for tok in re.split(r"(\d+)", name) if tok]


def _kind(value: SensorKind | str, where: str) -> SensorKind:
    return value if isinstance(value, SensorKind) else SensorKind.parse(value, where)


class FolderRecording:
    """An open folder recording (a context manager; nothing to release, for symmetry with
    :class:`rigcal.io.recordings.bag.Recording`)."""

    def __init__(self, root: Path) -> None:
        self.path = root
        self._closed = False

    def close(self) -> None:
        self._closed = True

    def __enter__(self) -> "FolderRecording":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def _subfolders(self) -> list[Path]:
        if self._closed:
            raise InputError(f"{self.path}: recording is closed")
        try:
            return sorted((p for p in self.path.iterdir() if p.is_dir()
                           and not p.name.startswith(".")), key=lambda p: _natural_key(p.name))
        except OSError as exc:
            raise InputError(f"{self.path}: cannot list folder: {exc.strerror or exc}") from exc

    def _files(self, folder: Path) -> list[Path]:
        try:
            files = [p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")
                     and p.suffix.lower() in _CONTENT]
        except OSError as exc:
            raise InputError(f"{folder}: cannot list folder: {exc.strerror or exc}") from exc
        return sorted(files, key=lambda p: _natural_key(p.name))

    def topics(self) -> dict[str, str]:
        """Subfolder -> what it holds (``points``, ``image``, ``radar_csv``, or several joined by
        ``+``); subfolders without frame files are left out."""
        out = {}
        for folder in self._subfolders():
            kinds = sorted({_CONTENT[p.suffix.lower()] for p in self._files(folder)})
            if kinds:
                out[folder.name] = "+".join(kinds)
        return out

    def _folder(self, topic: str) -> Path:
        if self._closed:
            raise InputError(f"{self.path}: recording is closed")
        folder = self.path / topic
        st = None if Path(topic).is_absolute() or ".." in Path(topic).parts else path_stat(
            folder, "sensor folder")
        if st is None or not stat.S_ISDIR(st.st_mode):
            raise InputError(
                f"{self.path}: folder '{topic}' not in recording; folders: {sorted(self.topics())}"
            )
        return folder

    def count(self, topic: str) -> int:
        """Number of frame files in subfolder ``topic``."""
        return len(self._files(self._folder(topic)))

    def timed_files(self, topic: str) -> list[tuple[int, Path]]:
        """(t_ns, file) of subfolder ``topic`` in time order (see the module docstring)."""
        files = self._files(self._folder(topic))
        times = [time_ns_from_name(p.stem) for p in files]
        if any(t is None for t in times):
            if files:
                log.info("%s: file names are not all timestamps; using the index as time",
                         self.path / topic)
            return list(enumerate(files))
        order = sorted(range(len(files)), key=lambda k: (times[k], k))
        return [(int(times[k]), files[k]) for k in order]  # type: ignore[arg-type]

    def frames(
        self,
        sensor_topics: Mapping[str, tuple[str, SensorKind | str]],
        start_ns: int | None = None,
        end_ns: int | None = None,
        *,
        rcs_field: str | Sequence[str] | None = None,
        remove_nan: bool = False,
    ) -> Iterator[Frame]:
        """Frames of the given sensors in order of ``t_ns``, within ``[start_ns, end_ns)`` when
        given; ``sensor_topics`` maps a sensor to ``(subfolder, kind)``. Files are read lazily."""
        streams = []
        for s_index, (sensor, spec) in enumerate(sensor_topics.items()):
            try:
                topic, kind_value = spec
            except (TypeError, ValueError):
                raise InputError(
                    f"{self.path}: sensor '{sensor}': expected (subfolder, kind), got {spec!r}"
                ) from None
            kind = _kind(kind_value, f"{self.path}: sensor '{sensor}'")
            timed = [(t, p) for t, p in self.timed_files(topic)
                     if (start_ns is None or t >= start_ns) and (end_ns is None or t < end_ns)]
            for _, p in timed:
                content = _CONTENT[p.suffix.lower()]
                if (content == "image" and kind is not SensorKind.CAMERA) or (
                        content == "radar_csv" and not kind.is_radar):
                    what = "an image" if content == "image" else "a radar CSV"
                    raise InputError(
                        f"{p}: {what} file, but sensor '{sensor}' is a {kind.value}"
                    )
            streams.append([(t, s_index, k, sensor, kind, p) for k, (t, p) in enumerate(timed)])
        return (self._load(p, sensor, kind, t, rcs_field, remove_nan)
                for t, _, _, sensor, kind, p in heapq.merge(*streams))

    @staticmethod
    def _load(path: Path, sensor: str, kind: SensorKind, t_ns: int,
              rcs_field: str | Sequence[str] | None, remove_nan: bool) -> Frame:
        content = _CONTENT[path.suffix.lower()]
        dims = 3 if kind is SensorKind.RADAR3D else 2
        if content == "image":
            data = read_limited(path, "image", "image")
            return ImageFrame(sensor=sensor, t_ns=t_ns, image=decode_image_bytes(data, str(path)))
        if content == "radar_csv":
            return parse_radar_csv(read_text(path, "radar CSV"), str(path), sensor, t_ns, dims,
                                   rcs_field)
        cloud = read_point_cloud(path, sensor, t_ns)
        if remove_nan:
            keep = np.isfinite(cloud.points_xyz).all(axis=1)
            if not keep.all():
                cloud = PointCloudFrame(sensor=sensor, t_ns=t_ns, points_xyz=cloud.points_xyz[keep],
                                        fields={k: v[keep] for k, v in cloud.fields.items()},
                                        frame_id=cloud.frame_id)
        if kind.is_radar:
            return radar_frame_from_cloud(cloud, dims, rcs_field, str(path))
        return cloud


def open_folder(path: str | os.PathLike[str]) -> FolderRecording:
    """Open a folder recording (see the module docstring)."""
    root = Path(path)
    st = path_stat(root, "recording folder")
    if st is None:
        raise InputError(f"{root}: recording folder not found")
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{root}: not a folder (a folder recording has one subfolder per sensor)")
    return FolderRecording(root)


def write_folder_recording(
    root: str | os.PathLike[str],
    frames_by_folder: Mapping[str, Iterable[Frame]],
    *,
    point_cloud_format: str = "pcd",
    pcd_data: str = "binary",
) -> Path:
    """Write frames as a folder recording: files named by ``t_ns`` (19-digit nanoseconds) in one
    subfolder per key. PointCloudFrame -> ``.pcd`` (``pcd_data``; x, y, z float32) or ``.npy``
    (lossless), ImageFrame -> ``.png``, RadarFrame -> ``.csv``. A subfolder that already holds
    frame files is refused (their frames would mix). Returns ``root``."""
    if point_cloud_format not in ("pcd", "npy"):
        raise InputError(f"{root}: point_cloud_format must be 'pcd' or 'npy', got "
                         f"{point_cloud_format!r}")
    base = Path(root)
    for name, frames in frames_by_folder.items():
        folder = base / name
        if not name or Path(name).is_absolute() or ".." in Path(name).parts:
            raise InputError(f"{base}: bad subfolder name {name!r}")
        if folder.is_dir() and any(p.suffix.lower() in _CONTENT for p in folder.iterdir()):
            raise InputError(f"{folder}: already holds frame files; choose an empty folder")
        written: set[str] = set()
        for frame in frames:
            if frame.t_ns < 0:
                raise InputError(f"{folder}: negative time {frame.t_ns} ns")
            stem = f"{frame.t_ns:019d}"
            if stem in written:
                raise InputError(f"{folder}: two frames at t_ns {frame.t_ns}")
            written.add(stem)
            if isinstance(frame, PointCloudFrame):
                if point_cloud_format == "npy":
                    atomic_write_bytes(folder / f"{stem}.npy", npy_bytes(frame, str(folder)))
                else:
                    atomic_write_bytes(folder / f"{stem}.pcd",
                                       pcd_bytes(frame, pcd_data, source=str(folder)))
            elif isinstance(frame, ImageFrame):
                png = folder / f"{stem}.png"
                atomic_write_bytes(png, encode_png(frame.image, str(png)))
            elif isinstance(frame, RadarFrame):
                atomic_write_text(folder / f"{stem}.csv", radar_csv_text(frame))
            else:
                raise InputError(
                    f"{folder}: cannot write {type(frame).__name__} (expected PointCloudFrame, "
                    "ImageFrame or RadarFrame)"
                )
    return base
