"""Initial extrinsics: a graph of rigid transforms between named frames, and its readers.

:class:`Extrinsics` maps ``(to_frame, from_frame)`` to ``T_to_from`` (4x4, ``p_to = T @ p_from``)
and answers :meth:`Extrinsics.lookup` for any two connected frames by composing and inverting
along the graph (fewest edges first).

Sources:

* the original tool's extrinsics JSON (``initial_calibration_EXAMPLE.json``,
  ``roben_extrinsics.json``)::

      {"type": "extrinsic_calibration", "date": "2019_07_25", "method": "manual",
       "calibrations": [{"to_frame": "base_link", "from_frame": "velodyne_link",
                         "transform": [16 numbers]}, ...]}

  (a bare list of the ``calibrations`` entries is read too). ``transform`` is the 4x4 matrix in
  **row-major** order (the last four numbers are ``0, 0, 0, 1``) and it is ``T_to_from``: it maps
  a point given in ``from_frame`` into ``to_frame``, i.e. it is the pose of ``from_frame`` in
  ``to_frame``. Evidence in the shared example: ``camera_link`` <- ``velodyne_link`` has rotation
  rows (0 -1 0), (0 0 -1), (1 0 0), which sends the lidar's forward axis x to the camera's
  optical axis z and the lidar's up axis z to the camera's up (-y); read the other way round
  the camera would look sideways with its image "down" pointing backwards. Likewise
  ``base_link`` <- ``velodyne_link`` puts the lidar 0.356 m above and 0.217 m ahead of the base.
  Translations are metres. The files print rotations with about 5 decimals, so the rotation
  block is accepted when ``|R^T R - I| <= 1e-3`` and then replaced by the nearest rotation.
* static TF in a bag (:func:`read_extrinsics_from_bag`): every ``/tf_static`` transform
  ``parent -> child`` is ``T_parent_child`` (the key ``(parent, child)``).
"""

from __future__ import annotations

import json
import logging
import os
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.frames import Transform
from rigcal.geometry.se3 import as_rigid, invert

__all__ = [
    "Extrinsics",
    "extrinsics_json_text",
    "parse_extrinsics_json",
    "read_extrinsics_from_bag",
    "read_extrinsics_json",
    "write_extrinsics_json",
]

log = logging.getLogger(__name__)

RIGID_TOL = 1e-3
"""Largest ``|R^T R - I|`` accepted for a rotation block written with few decimals."""


def _frame_ok(name: Any, what: str) -> str:
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{what}: frame name must be a non-empty string, got {name!r}")
    return name


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class Extrinsics:
    """Rigid transforms between named frames: ``transforms[(to, from)] = T_to_from``.

    At most one transform per pair of frames (in either direction); the graph may have several
    components and loops (a lookup then takes a path with the fewest edges). Matrices are
    read-only; ``metadata`` keeps the JSON file's other top-level fields (type, date, method)."""

    transforms: Mapping[tuple[str, str], np.ndarray]
    source: str = ""
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = self.source or "extrinsics"
        clean: dict[tuple[str, str], np.ndarray] = {}
        pairs: dict[frozenset[str], tuple[str, str]] = {}
        for key, T in dict(self.transforms).items():
            if not (isinstance(key, tuple) and len(key) == 2):
                raise InputError(f"{where}: keys must be (to_frame, from_frame), got {key!r}")
            to, frm = (_frame_ok(k, f"{where}: transform {key!r}") for k in key)
            if to == frm:
                raise InputError(f"{where}: transform from '{frm}' to itself")
            pair = frozenset((to, frm))
            if pair in pairs:
                raise InputError(
                    f"{where}: two transforms between '{to}' and '{frm}' ({pairs[pair][0]} <- "
                    f"{pairs[pair][1]} and {to} <- {frm}); give one"
                )
            pairs[pair] = (to, frm)
            clean[(to, frm)] = as_rigid(T, f"{where}: transform {to} <- {frm}", RIGID_TOL)
        object.__setattr__(self, "transforms", MappingProxyType(clean))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    # -- graph
    @property
    def frames(self) -> tuple[str, ...]:
        """Every frame named by a transform, sorted."""
        return tuple(sorted({f for key in self.transforms for f in key}))

    def _neighbours(self) -> dict[str, list[tuple[str, np.ndarray]]]:
        """frame -> [(neighbour, T_neighbour_frame)]"""
        nb: dict[str, list[tuple[str, np.ndarray]]] = {}
        for (to, frm), T in self.transforms.items():
            nb.setdefault(frm, []).append((to, T))
            nb.setdefault(to, []).append((frm, invert(T)))
        return nb

    def _known(self, frame: str, role: str) -> None:
        if frame not in self.frames:
            raise InputError(
                f"{self.source or 'extrinsics'}: unknown {role} frame '{frame}'; known frames: "
                f"{list(self.frames)}"
            )

    def path(self, to: str, from_: str) -> list[str]:
        """Frames from ``from_`` to ``to`` along the graph (fewest edges), both included."""
        self._known(to, "to")
        self._known(from_, "from")
        nb = self._neighbours()
        prev: dict[str, str | None] = {from_: None}
        queue = deque([from_])
        while queue:
            f = queue.popleft()
            if f == to:
                break
            for g, _ in sorted(nb.get(f, []), key=lambda x: x[0]):
                if g not in prev:
                    prev[g] = f
                    queue.append(g)
        if to not in prev:
            reach = sorted(prev)
            raise InputError(
                f"{self.source or 'extrinsics'}: no chain of transforms connects '{from_}' to "
                f"'{to}'; '{from_}' connects only to {reach}"
            )
        out = [to]
        while out[-1] != from_:
            out.append(prev[out[-1]])  # type: ignore[arg-type]
        return out[::-1]

    def lookup(self, to: str, from_: str) -> np.ndarray:
        """``T_to_from`` (a new (4, 4) array), composed and inverted along the graph."""
        frames = self.path(to, from_)
        nb = self._neighbours()
        T = np.eye(4)
        for a, b in zip(frames, frames[1:]):  # a -> b: T_b_from = T_b_a @ T_a_from
            T_b_a = next(M for g, M in nb[a] if g == b)
            T = T_b_a @ T
        return T

    def transform(self, to: str, from_: str) -> Transform:
        """:meth:`lookup` as a frame-checked :class:`rigcal.geometry.Transform`."""
        return Transform(self.lookup(to, from_), to, from_)

    def with_transform(self, to: str, from_: str, T: Any) -> "Extrinsics":
        """A new Extrinsics with ``T_to_from`` set (replacing any transform between the two)."""
        d = {k: v for k, v in self.transforms.items() if set(k) != {to, from_}}
        d[(to, from_)] = T
        return Extrinsics(d, self.source, self.metadata)

    def __len__(self) -> int:
        return len(self.transforms)


# --------------------------------------------------------------------------------------------
# the original tool's JSON


def parse_extrinsics_json(text: str, source: str = "extrinsics JSON") -> Extrinsics:
    """Extrinsics from the original tool's JSON text (see the module docstring)."""
    from rigcal.io.config.vicon_json import load_json

    data = load_json(text, source)
    metadata: dict[str, Any] = {}
    if isinstance(data, dict):
        if "calibrations" not in data:
            raise InputError(f"{source}: missing key 'calibrations' (a list of {{to_frame, "
                             "from_frame, transform}})")
        metadata = {k: v for k, v in data.items() if k != "calibrations"}
        entries = data["calibrations"]
        key = "calibrations"
    else:
        entries, key = data, ""
    if not isinstance(entries, list) or not entries:
        raise InputError(
            f"{source}: {key or 'top level'}: expected a non-empty list of {{to_frame, "
            f"from_frame, transform}}, got {type(entries).__name__}"
        )
    transforms: dict[tuple[str, str], np.ndarray] = {}
    for i, entry in enumerate(entries):
        where = f"{source}: {key}[{i}]" if key else f"{source}: [{i}]"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected an object, got {type(entry).__name__}")
        for k in ("to_frame", "from_frame", "transform"):
            if k not in entry:
                raise InputError(f"{where}: missing key '{k}'")
        to = _frame_ok(entry["to_frame"], f"{where}.to_frame")
        frm = _frame_ok(entry["from_frame"], f"{where}.from_frame")
        values = entry["transform"]
        if not isinstance(values, list):
            raise InputError(f"{where}.transform: expected a list of 16 numbers (row-major 4x4), "
                             f"got {type(values).__name__}")
        if len(values) != 16:
            raise InputError(f"{where}.transform: expected 16 numbers (row-major 4x4), got "
                             f"{len(values)}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            raise InputError(f"{where}.transform: expected 16 numbers, got {values!r}")
        if (to, frm) in transforms or (frm, to) in transforms:
            raise InputError(f"{where}: a second transform between '{to}' and '{frm}'")
        transforms[(to, frm)] = as_rigid(np.reshape(values, (4, 4)),
                                         f"{where}.transform ({to} <- {frm})", RIGID_TOL)
    return Extrinsics(transforms, source, metadata)


def read_extrinsics_json(path: str | os.PathLike[str]) -> Extrinsics:
    """Read the original tool's extrinsics JSON file."""
    from rigcal.io._text import read_text

    p = Path(path)
    return parse_extrinsics_json(read_text(p, "extrinsics JSON"), str(p))


def extrinsics_json_text(extrinsics: Extrinsics, metadata: Mapping[str, Any] | None = None
                         ) -> str:
    """JSON text in the original tool's layout (``metadata`` defaults to the value's own, with
    ``type: extrinsic_calibration``); numbers in shortest round-trip form."""
    meta = dict(extrinsics.metadata if metadata is None else metadata)
    meta.setdefault("type", "extrinsic_calibration")
    doc = dict(meta)
    doc["calibrations"] = [
        {"to_frame": to, "from_frame": frm,
         "transform": [float(v) for v in np.asarray(T).reshape(-1)]}
        for (to, frm), T in extrinsics.transforms.items()
    ]
    return json.dumps(doc, indent=2) + "\n"


def write_extrinsics_json(path: str | os.PathLike[str], extrinsics: Extrinsics) -> Path:
    """Write :func:`extrinsics_json_text` atomically; returns the path."""
    from rigcal.io.atomic import atomic_write_text

    return atomic_write_text(path, extrinsics_json_text(extrinsics))


# --------------------------------------------------------------------------------------------
# TF in a bag


def read_extrinsics_from_bag(path: str | os.PathLike[str],
                             topics: Sequence[str] = ("/tf_static",), *,
                             static_topics: Iterable[str] = ("/tf_static",),
                             constant_tol_m: float = 1e-9) -> Extrinsics:
    """Extrinsics from the TF tree in a bag: ``T_parent_child`` for every transform on
    ``topics`` (``tf2_msgs/TFMessage``), keyed ``(parent, child)``.

    Transforms on ``static_topics`` are taken as they are (the last one wins if a transform is
    re-published). Transforms on other topics (e.g. ``/tf``, where the original tool's
    simulated bags publish ground-truth calibrations) are kept only when they never change over
    the bag (every matrix entry within ``constant_tol_m`` of the first); moving transforms such
    as mocap poses are skipped and logged."""
    from rigcal.io.recordings.bag import open_bag
    from rigcal.mocap.streams import _read_tf_edges, _tf_topics

    with open_bag(path) as rec:
        source = str(rec.path)
        present = _tf_topics(rec, topics, source)
        static = [t for t in static_topics if t in present]
        edges = _read_tf_edges(rec, present, static, source)
    transforms: dict[tuple[str, str], np.ndarray] = {}
    moving: list[str] = []
    for child, parent in edges.parent.items():
        if child in edges.static:
            transforms[(parent, child)] = edges.static[child]
            continue
        _, T = edges.dynamic[child].valid_samples(source)
        if np.max(np.abs(T - T[0])) <= constant_tol_m:
            transforms[(parent, child)] = T[0]
        else:
            moving.append(f"{parent} -> {child}")
    if moving:
        log.info("%s: skipped %d moving transforms: %s", source, len(moving), ", ".join(moving))
    if not transforms:
        raise InputError(
            f"{source}: no static transforms on {', '.join(present)}"
            + (f" (moving ones skipped: {', '.join(moving)})" if moving else "")
        )
    return Extrinsics(transforms, source)
