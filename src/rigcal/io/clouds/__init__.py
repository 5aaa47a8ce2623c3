"""Point cloud files (one module per format): PCD (v0.7), PLY and NPY, read into and written from :class:`PointCloudFrame`.

Formats
-------
* **PCD** v0.7 (the Point Cloud Library's format): a text header (``VERSION``, ``FIELDS``,
  ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``, ``HEIGHT``, ``VIEWPOINT``, ``POINTS``, ``DATA``) then
  the points as ``ascii`` (one point a line), ``binary`` (packed little-endian records, row-major)
  or ``binary_compressed`` (two uint32 sizes, then one LZF block holding the fields column by
  column). Fields may come in any order; ``_`` fields are padding and are skipped; a field with
  ``COUNT`` k > 1 becomes k fields ``name_0 .. name_{k-1}``. ``HEIGHT`` > 1 is an organised
  cloud: ``organized_shape`` = (HEIGHT, WIDTH), row-major. ``VIEWPOINT`` is checked, not applied.
* **PLY**: the ``vertex`` element of an ``ascii``, ``binary_little_endian`` or
  ``binary_big_endian`` file, with ``x y z`` and any other scalar properties.
* **NPY**: an (N, 3) or (H, W, 3) numeric array, or a structured array (N,) or (H, W) with
  fields ``x``, ``y``, ``z`` (and any others).

Every field other than ``x``, ``y``, ``z`` lands in ``PointCloudFrame.fields`` under its own name
with its own dtype (e.g. ``intensity`` float32, ``ring`` uint16, ``rgb`` float32 as PCL packs it).
Points are read as they are stored: NaN points stay (organised clouds need them).

Parsers take bytes and return values (:func:`parse_pcd_bytes`, :func:`parse_ply_bytes`,
:func:`parse_npy_bytes`); writers build bytes (:func:`pcd_bytes`, :func:`ply_bytes`,
:func:`npy_bytes`) and write them atomically. Every problem raises
:class:`rigcal.errors.InputError` naming the file (``source``).

LZF (used by ``binary_compressed``) is a stream of tokens, each starting with a control byte
``c``: ``c < 32`` is a literal run of ``c + 1`` bytes that follow; otherwise ``c >> 5`` is a
length code L (7 means "add the next byte") and the back reference copies ``L + 2`` bytes from
``((c & 31) << 8 | next byte) + 1`` bytes back in the output (the copy may overlap itself). A
token of 3 bytes yields at most 264, so a block of ``m`` bytes decompresses to at most ``88 m``
bytes: a header announcing more is refused before anything is allocated, and decompression never
writes past the announced size. The compiled liblzf of the ``python-neo-lzf`` package (a
dependency) does the work; without it a pure-Python codec is used (the same format, about a
second per megabyte).

ASCII data are parsed by NumPy's ``loadtxt`` when they are well formed; any problem (a bad token,
a short line, a value out of the field's range) is diagnosed by a line-by-line parser that names
the point and the field.

The ``ring`` field (the laser index of a spinning lidar) is written as ``U 2`` (uint16, as the
Velodyne and Ouster drivers publish it) and read into uint16 whatever integer type a file uses,
when its values fit (0..65535; otherwise it keeps the file's type).
"""

from __future__ import annotations

from rigcal.io.clouds.lzf import LZF_BACKEND, lzf_compress, lzf_decompress
from rigcal.io.clouds.npy import npy_bytes, parse_npy_bytes, write_npy
from rigcal.io.clouds.pcd import parse_pcd_bytes, pcd_bytes, write_pcd
from rigcal.io.clouds.ply import parse_ply_bytes, ply_bytes, write_ply
from rigcal.io.clouds.reader import (
    DEFAULT_RCS_FIELDS,
    POINT_CLOUD_SUFFIXES,
    radar_frame_from_cloud,
    read_point_cloud,
)

__all__ = [
    "DEFAULT_RCS_FIELDS",
    "LZF_BACKEND",
    "POINT_CLOUD_SUFFIXES",
    "lzf_compress",
    "lzf_decompress",
    "npy_bytes",
    "parse_npy_bytes",
    "parse_pcd_bytes",
    "parse_ply_bytes",
    "pcd_bytes",
    "ply_bytes",
    "radar_frame_from_cloud",
    "read_point_cloud",
    "write_npy",
    "write_pcd",
    "write_ply",
]
