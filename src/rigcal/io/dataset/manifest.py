"""Dataset manifests (``rig.yaml``): which sensors a rig has and where their detections are.

Example::

    sensors:
      - {name: lidar1, kind: lidar, detections: lidar1.csv}
      - {name: camera1, kind: camera, detections: camera1.csv, frame_id: left}
      - {name: radar1, kind: radar, detections: radar1.csv, elevation_fov_deg: 9}
      - {name: radar2, kind: radar3d, detections: radar2.csv}
      - {name: lidar2, kind: lidar, detections: acc.yaml, topic: /lidar_detector/lidar_pattern}
    reference: lidar1                                     # optional
    board: {spacing_m: 0.24, reflector_offset_m: 0.105}   # optional; any BoardGeometry field
    ignore: ignore.yaml                                   # optional, the original ignore file

Fields of a sensor:

* ``name`` (required): unique; no whitespace or path separators;
* ``kind`` (required): ``lidar``, ``camera``, ``radar`` (2D) or ``radar3d``;
* ``detections`` (required): a path relative to the manifest's directory (or absolute);
  ``.csv`` is read by :mod:`rigcal.io.dataset.detections_csv`, ``.yaml``/``.yml`` by
  :mod:`rigcal.io.dataset.accumulator`;
* ``topic``: the accumulator topic; required when that file has more than one topic, refused
  for CSV files;
* ``frame_id``: defaults to the accumulator entries' ``frame_id`` for accumulator input, else
  to ``name``;
* ``elevation_fov_deg``: the largest |elevation| a radar sees, in degrees (a half-angle, like the
  original tool's ``max_elevation``); in (0, 90]; default 9;
* ``prior``: tolerances (1 sigma) of the sensor's nominal mounting given with ``--initial``,
  e.g. ``{z_m: 0.01, roll_deg: 0.5, pitch_deg: 0.5}`` along / about the sensor's own axes
  (:mod:`rigcal.problem.priors`; 0 holds a direction).

The ignore file's boards are excluded with :meth:`Dataset.with_excluded` by :func:`load_manifest`
and :func:`parse_manifest`; the ``*_with_ignored`` variants return the dataset without them plus
the ignore map, so that callers can tell ignored boards from outliers found later.
"""

from __future__ import annotations

import math
import os
import re
import stat
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
import yaml

from rigcal.dataset import (
    DEFAULT_MAX_ELEVATION_DEG,
    BoardGeometry,
    Dataset,
    SensorDetections,
    SensorKind,
)
from rigcal.errors import InputError
from rigcal.io._text import (
    check_keys,
    is_number,
    load_yaml,
    nonempty_string,
    read_text,
    type_name,
)
from rigcal.io.dataset.accumulator import accumulator_points_for_kind, parse_accumulator_yaml
from rigcal.io.atomic import atomic_write_text, mark_output
from rigcal.io.dataset.detections_csv import format_detections_csv, parse_detections_csv
from rigcal.io.dataset.ignore import parse_ignore_yaml
from rigcal.io.limits import path_stat
from rigcal.problem.priors import check_prior

MANIFEST_NAME = "rig.yaml"

_TOP_KEYS = ("sensors", "reference", "board", "ignore")
_SENSOR_KEYS = ("name", "kind", "detections", "frame_id", "elevation_fov_deg", "topic", "prior")
_BOARD_KEYS = tuple(f.name for f in fields(BoardGeometry))
_CSV_SUFFIXES = (".csv",)
_YAML_SUFFIXES = (".yaml", ".yml")
_BAD_NAME = re.compile(r"[\s/\\]")


@dataclass(frozen=True)
class _SensorEntry:
    """One validated ``sensors[i]`` entry (no file read yet)."""

    index: int
    name: str
    kind: SensorKind
    detections: str
    frame_id: str | None
    elevation_fov_deg: float | None
    topic: str | None
    prior: Mapping[str, float] | None = None


@dataclass(frozen=True)
class _Manifest:
    sensors: tuple[_SensorEntry, ...]
    reference: str | None
    board: BoardGeometry
    ignore: str | None


def _refuse_detection_rig(data: Mapping[Any, Any], source: str) -> None:
    """A detection rig (sensors with recording topics, no detection files) given as a manifest
    is named as such, with the commands that take it."""
    sensors = data.get("sensors")
    raw_keys = {"topic", "input", "right_topic", "intrinsics", "camera_info_topic", "detector"}
    if isinstance(sensors, list) and any(
        isinstance(s, dict) and "detections" not in s and raw_keys & set(s) for s in sensors
    ):
        raise InputError(
            f"{source}: looks like a detection rig (sensors with recording topics, no "
            "'detections' files), not a dataset manifest; use it with --rig: rigcal calibrate "
            f"RECORDING --rig {source} --out DIR, or rigcal detect RECORDING --rig {source} "
            "--out DIR"
        )


#: longest sensor name (characters; at most twice as many bytes in UTF-8): it names the sensor's
#: files (``<sensor>.yaml``), which a file system holds up to 255 bytes
MAX_SENSOR_NAME = 100


def check_sensor_name(name: Any, where: str) -> str:
    """``name`` if it can name a sensor (and its files): a non-empty string of at most
    :data:`MAX_SENSOR_NAME` characters (and twice as many bytes in UTF-8) without whitespace,
    control characters (NUL included) or path separators, not ``.`` or ``..``; else
    InputError naming ``where``."""
    name = nonempty_string(name, where)
    if _BAD_NAME.search(name) or name in (".", "..") or not name.isprintable():
        raise InputError(
            f"{where}: sensor name {name!r} must not contain whitespace or path separators (nor control characters)"
        )
    if len(name) > MAX_SENSOR_NAME or len(name.encode("utf-8")) > 2 * MAX_SENSOR_NAME:
        raise InputError(
            f"{where}: sensor name {name[:20]!r}... is {len(name)} characters long; expected at most "
            f"{MAX_SENSOR_NAME} (it names the sensor's files)"
        )
    return name


def _parse_sensor(i: int, raw: Any, source: str) -> _SensorEntry:
    where = f"{source}: sensors[{i}]"
    if not isinstance(raw, dict):
        raise InputError(
            f"{where}: expected a mapping with name, kind, detections, got {type_name(raw)}"
        )
    for key in ("name", "kind", "detections"):
        if key not in raw:
            raise InputError(
                f"{where}: missing required key '{key}' (required: name, kind, detections)"
            )
    check_keys(raw, _SENSOR_KEYS, where)
    name = check_sensor_name(raw["name"], f"{where}.name")
    kind = SensorKind.parse(nonempty_string(raw["kind"], f"{where}.kind"), f"{where}.kind")
    detections = nonempty_string(raw["detections"], f"{where}.detections")
    if "\x00" in detections:
        raise InputError(f"{where}.detections: {detections!r} contains a NUL byte; expected a file path")
    suffix = Path(detections).suffix.lower()
    if suffix not in _CSV_SUFFIXES + _YAML_SUFFIXES:
        raise InputError(
            f"{where}.detections: '{detections}' must end in .csv (detection CSV) or "
            f".yaml/.yml (accumulator YAML)"
        )
    frame_id = raw.get("frame_id")
    if frame_id is not None:
        frame_id = nonempty_string(frame_id, f"{where}.frame_id")
    topic = raw.get("topic")
    if topic is not None:
        topic = nonempty_string(topic, f"{where}.topic")
        if suffix in _CSV_SUFFIXES:
            raise InputError(
                f"{where}.topic: only accumulator YAML detections have topics, "
                f"'{detections}' is a CSV file"
            )
    elevation = raw.get("elevation_fov_deg")
    if elevation is not None or "elevation_fov_deg" in raw:
        if not is_number(elevation) or not math.isfinite(elevation) or not 0 < elevation <= 90:
            raise InputError(
                f"{where}.elevation_fov_deg: expected a number of degrees in (0, 90] "
                f"(the largest |elevation| the radar sees), got {elevation!r}"
            )
        elevation = float(elevation)
    prior = check_prior(raw["prior"], f"{where}.prior") if "prior" in raw else None
    return _SensorEntry(i, name, kind, detections, frame_id, elevation, topic, prior)


def parse_board(raw: Any, source: str) -> BoardGeometry:
    """The ``board:`` section of a manifest or detection rig (any :class:`BoardGeometry` field,
    in metres); the defaults when it is missing."""
    if raw is None:
        return BoardGeometry()
    if not isinstance(raw, dict):
        raise InputError(
            f"{source}: board: expected a mapping ({', '.join(_BOARD_KEYS)}), got {type_name(raw)}"
        )
    check_keys(raw, _BOARD_KEYS, f"{source}: board")
    for key, value in raw.items():
        if not is_number(value):
            raise InputError(
                f"{source}: board.{key}: expected a number in metres, "
                f"got {type_name(value)} {value!r}"
            )
    try:
        return BoardGeometry(**{k: float(v) for k, v in raw.items()})
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def _parse_spec(text: str, source: str) -> _Manifest:
    """Validate a manifest's structure (pure: reads no other file)."""
    data = load_yaml(text, source)
    if data is None:
        raise InputError(f"{source}: empty manifest, expected a mapping with a 'sensors' list")
    if not isinstance(data, dict):
        raise InputError(
            f"{source}: expected a mapping with a 'sensors' list at the top level, "
            f"got {type_name(data)}"
        )
    if "sensors" not in data:
        raise InputError(f"{source}: missing required key 'sensors' (a list of sensors)")
    _refuse_detection_rig(data, source)
    check_keys(data, _TOP_KEYS, source)
    raw_sensors = data["sensors"]
    if not isinstance(raw_sensors, list) or not raw_sensors:
        raise InputError(
            f"{source}: sensors: expected a non-empty list of {{name, kind, detections}}, "
            f"got {type_name(raw_sensors)}"
        )
    sensors = tuple(_parse_sensor(i, raw, source) for i, raw in enumerate(raw_sensors))
    names = [s.name for s in sensors]
    for s in sensors:
        first = names.index(s.name)
        if first != s.index:
            raise InputError(
                f"{source}: sensors[{s.index}].name: '{s.name}' is already used by sensors[{first}]"
            )
    reference = data.get("reference")
    if reference is not None:
        reference = nonempty_string(reference, f"{source}: reference")
        if reference not in names:
            raise InputError(
                f"{source}: reference: unknown sensor '{reference}' (sensors: {', '.join(names)})"
            )
    ignore = data.get("ignore")
    if ignore is not None:
        ignore = nonempty_string(ignore, f"{source}: ignore")
        if "\x00" in ignore:
            raise InputError(f"{source}: ignore: {ignore!r} contains a NUL byte; expected a file path")
    return _Manifest(sensors, reference, parse_board(data.get("board"), source), ignore)


def _resolve(base_dir: Path, relative: str) -> Path:
    p = Path(relative).expanduser()
    return p if p.is_absolute() else base_dir / p


def _select_topic(
    topics: Mapping[str, tuple[str, np.ndarray]], topic: str | None, path: Path
) -> tuple[str, str, np.ndarray]:
    """(topic, frame_id, points) of the wanted (or only) topic of an accumulator file."""
    listing = ", ".join(topics)
    if topic is None:
        if len(topics) != 1:
            raise InputError(
                f"{path}: {len(topics)} topics ({listing}); say which one with 'topic'"
            )
        topic = next(iter(topics))
    elif topic not in topics:
        raise InputError(f"{path}: no topic '{topic}' (topics: {listing})")
    frame_id, points = topics[topic]
    return topic, frame_id, points


def _load_sensor(
    entry: _SensorEntry,
    source: str,
    base_dir: Path,
    cache: dict[Path, dict[str, tuple[str, np.ndarray]]],
) -> SensorDetections:
    where = f"{source}: sensors[{entry.index}].detections"
    path = _resolve(base_dir, entry.detections)
    frame_id = entry.frame_id
    try:
        if path.suffix.lower() in _CSV_SUFFIXES:
            text = read_text(path, "detection CSV file")
            points = parse_detections_csv(text, entry.kind, str(path))
        else:
            if path not in cache:
                cache[path] = parse_accumulator_yaml(
                    read_text(path, "accumulator YAML file"), str(path)
                )
            topic, file_frame, raw = _select_topic(cache[path], entry.topic, path)
            points = accumulator_points_for_kind(raw, entry.kind, str(path), topic)
            frame_id = frame_id or file_frame
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    elevation = entry.elevation_fov_deg
    return SensorDetections(
        name=entry.name,
        kind=entry.kind,
        points=points,
        frame_id=frame_id or entry.name,
        max_elevation_rad=math.radians(
            DEFAULT_MAX_ELEVATION_DEG if elevation is None else elevation
        ),
        source=str(path),
        prior=entry.prior or {},
    )


def parse_manifest_with_ignored(
    text: str, source: str, base_dir: str | os.PathLike[str]
) -> tuple[Dataset, dict[str, list[int]]]:
    """The dataset described by manifest ``text`` WITHOUT the ignore file applied, and the
    ignore map (sensor -> sorted board indices; empty without an ``ignore`` key).

    Detection and ignore paths are relative to ``base_dir``; those files are read.
    """
    spec = _parse_spec(text, source)
    base = Path(base_dir)
    cache: dict[Path, dict[str, tuple[str, np.ndarray]]] = {}
    sensors = tuple(_load_sensor(e, source, base, cache) for e in spec.sensors)
    dataset = Dataset(sensors=sensors, board=spec.board, reference=spec.reference, source=source)
    ignored: dict[str, list[int]] = {}
    if spec.ignore is not None:
        path = _resolve(base, spec.ignore)
        try:
            ignored = parse_ignore_yaml(read_text(path, "ignore file"), str(path), dataset)
        except InputError as exc:
            raise InputError(f"{source}: ignore: {exc}") from None
    return dataset, ignored


def parse_manifest(text: str, source: str, base_dir: str | os.PathLike[str]) -> Dataset:
    """The dataset described by manifest ``text``, with the ignore file's boards excluded."""
    dataset, ignored = parse_manifest_with_ignored(text, source, base_dir)
    return dataset.with_excluded(ignored) if ignored else dataset


def _manifest_path(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    st = path_stat(p, "manifest")
    return p / MANIFEST_NAME if st is not None and stat.S_ISDIR(st.st_mode) else p


def load_manifest_with_ignored(
    path: str | os.PathLike[str],
) -> tuple[Dataset, dict[str, list[int]]]:
    """Read a manifest (a file, or a directory holding ``rig.yaml``); see
    :func:`parse_manifest_with_ignored`. ``Dataset.source`` is the manifest's path."""
    p = _manifest_path(path)
    return parse_manifest_with_ignored(read_text(p, "manifest"), str(p), p.parent)


def load_manifest(path: str | os.PathLike[str]) -> Dataset:
    """Read a manifest with the ignore file's boards excluded; see :func:`parse_manifest`."""
    dataset, ignored = load_manifest_with_ignored(path)
    return dataset.with_excluded(ignored) if ignored else dataset


def _as_paths(value: Any) -> list[Path]:
    if value is None:
        return []
    if isinstance(value, (str, os.PathLike)):
        return [Path(value)]
    return [Path(v) for v in value]


def _sensor_from_file(name: str, kind: SensorKind, path: Path) -> SensorDetections:
    suffix = path.suffix.lower()
    frame_id = name
    if suffix in _CSV_SUFFIXES:
        points = parse_detections_csv(read_text(path, "detection CSV file"), kind, str(path))
    elif suffix in _YAML_SUFFIXES:
        topics = parse_accumulator_yaml(read_text(path, "accumulator YAML file"), str(path))
        if len(topics) != 1:
            raise InputError(
                f"{path}: {len(topics)} topics ({', '.join(topics)}); pass a file with one "
                "topic, or write a rig.yaml manifest that names the topic of each sensor"
            )
        topic, (frame_id, raw) = next(iter(topics.items()))
        points = accumulator_points_for_kind(raw, kind, str(path), topic)
    else:
        raise InputError(
            f"{path}: {kind.value} detections must be a .csv or .yaml/.yml file"
        )
    return SensorDetections(
        name=name, kind=kind, points=points, frame_id=frame_id, source=str(path)
    )


def dataset_from_files(
    lidar: Iterable[str | os.PathLike[str]] | str | os.PathLike[str] | None = None,
    camera: Iterable[str | os.PathLike[str]] | str | os.PathLike[str] | None = None,
    radar: Iterable[str | os.PathLike[str]] | str | os.PathLike[str] | None = None,
    radar3d: Iterable[str | os.PathLike[str]] | str | os.PathLike[str] | None = None,
    reference: str | None = None,
) -> Dataset:
    """A dataset from detection files, as the original tool's command line takes them.

    Sensors are named ``lidar1, lidar2, ..., camera1, ..., radar1, ..., radar3d_1, ...`` in
    argument order. Files are CSV or accumulator YAML with a single topic (the sensor's
    ``frame_id`` is then the file's; for CSV it is the name). Radars get the default elevation
    field of view and the board the default geometry.
    """
    groups = (
        (SensorKind.LIDAR, "lidar", lidar),
        (SensorKind.CAMERA, "camera", camera),
        (SensorKind.RADAR, "radar", radar),
        (SensorKind.RADAR3D, "radar3d_", radar3d),
    )
    sensors = []
    for kind, prefix, paths in groups:
        for i, path in enumerate(_as_paths(paths), start=1):
            sensors.append(_sensor_from_file(f"{prefix}{i}", kind, path))
    if reference is not None and reference not in [s.name for s in sensors]:
        raise InputError(
            f"reference sensor '{reference}' is not one of the sensors "
            f"({', '.join(s.name for s in sensors) or 'none'})"
        )
    try:
        return Dataset(sensors=tuple(sensors), reference=reference)
    except InputError as exc:
        files = ", ".join(f"{s.name}={s.source}" for s in sensors)
        raise InputError(f"{exc} (files: {files})") from None


def _degrees_for(rad: float) -> float:
    """Degrees ``d`` with ``math.radians(d) == rad`` when one is near, for exact round trips."""
    deg = math.degrees(rad)
    for direction in (math.inf, -math.inf):
        candidate = deg
        for _ in range(4):
            if math.radians(candidate) == rad:
                return candidate
            candidate = math.nextafter(candidate, direction)
    return deg


def _check_file_names(dataset: Dataset) -> None:
    seen: dict[str, str] = {}
    for s in dataset.sensors:
        check_sensor_name(s.name, f"sensor '{s.name}'")
        key = s.name.lower()
        if key in seen:
            raise InputError(
                f"sensors '{seen[key]}' and '{s.name}' would write the same file on a "
                "case-insensitive file system; rename one"
            )
        seen[key] = s.name


def format_manifest(dataset: Dataset, detection_files: Mapping[str, str]) -> str:
    """Manifest text for ``dataset`` with ``detection_files[name]`` as each sensor's file."""
    default_elevation = math.radians(DEFAULT_MAX_ELEVATION_DEG)
    sensors = []
    for s in dataset.sensors:
        entry: dict[str, Any] = {
            "name": s.name,
            "kind": s.kind.value,
            "detections": detection_files[s.name],
            "frame_id": s.frame_id,
        }
        if s.kind.is_radar or s.max_elevation_rad != default_elevation:
            entry["elevation_fov_deg"] = _degrees_for(float(s.max_elevation_rad))
        if s.prior:
            entry["prior"] = {k: float(v) for k, v in s.prior.items()}
        sensors.append(entry)
    data: dict[str, Any] = {"sensors": sensors}
    if dataset.reference is not None:
        data["reference"] = dataset.reference
    data["board"] = {k: float(v) for k, v in asdict(dataset.board).items()}
    header = (
        "# rigcal dataset manifest. Detection paths are relative to this file.\n"
        "# Boards excluded from the dataset (ignore file, outliers) are not recorded here.\n"
    )
    body = yaml.safe_dump(
        data, sort_keys=False, default_flow_style=None, allow_unicode=True, width=10_000
    )
    return header + body


def write_dataset(dataset: Dataset, out_dir: str | os.PathLike[str]) -> Path:
    """Write ``out_dir/rig.yaml`` and one ``<sensor>.csv`` per sensor (atomically); returns the
    manifest's path.

    :func:`load_manifest` reads back the same names, kinds, frame ids, elevation fields of view,
    board geometry, reference and detections (NaNs included, floats bit for bit). Excluded
    boards are NOT written: exclusions are not detections; save them separately (e.g. as an
    ignore file) if they must survive.
    """
    out = Path(out_dir)
    _check_file_names(dataset)
    files = {s.name: f"{s.name}.csv" for s in dataset.sensors}
    for s in dataset.sensors:
        atomic_write_text(out / files[s.name], format_detections_csv(s.points, s.kind))
    path = atomic_write_text(out / MANIFEST_NAME, format_manifest(dataset, files))
    mark_output(out)
    return path
