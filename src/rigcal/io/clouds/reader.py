"""Reading any cloud file by its suffix, and radar detections from a cloud."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

import numpy as np

from rigcal.errors import InputError
from rigcal.io.clouds._columns import _read_bytes
from rigcal.io.clouds.npy import parse_npy_bytes
from rigcal.io.clouds.pcd import parse_pcd_bytes
from rigcal.io.clouds.ply import parse_ply_bytes
from rigcal.io.limits import check_finite
from rigcal.recording import PointCloudFrame, RadarFrame

POINT_CLOUD_SUFFIXES = (".pcd", ".ply", ".npy")
"""File name suffixes :func:`read_point_cloud` understands (case-insensitive)."""

DEFAULT_RCS_FIELDS = ("rcs", "RCS", "rcs0")
"""Field names tried, in order, for a radar's radar cross-section when none is configured."""


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
