"""PointCloudFrame is a value: its arrays are read-only and nobody else can write to them."""

from __future__ import annotations

import numpy as np

from rigcal.io.clouds import parse_pcd_bytes, pcd_bytes
from rigcal.recording import PointCloudFrame


def _frame(points, **fields):
    return PointCloudFrame(sensor="l", t_ns=0, points_xyz=points, fields=fields)


def test_writable_inputs_are_copied():
    pts = np.zeros((4, 3))
    ring = np.arange(4, dtype=np.uint16)
    f = _frame(pts, ring=ring)
    pts[0, 0] = 7.0
    ring[0] = 9
    assert f.points_xyz[0, 0] == 0.0 and f.fields["ring"][0] == 0
    assert not f.points_xyz.flags.writeable and not f.fields["ring"].flags.writeable


def test_a_read_only_view_of_writable_memory_is_copied():
    base = np.zeros((4, 3))
    view = base[:]
    view.setflags(write=False)
    f = _frame(view)
    base[1, 1] = 5.0
    assert f.points_xyz[1, 1] == 0.0


def test_sealed_arrays_are_shared_not_copied():
    sealed = np.arange(12, dtype=float).reshape(4, 3).copy()  # owns its memory
    sealed.setflags(write=False)
    assert _frame(sealed).points_xyz is sealed
    from_bytes = np.frombuffer(bytes(16), dtype=np.float32)  # immutable bytes underneath
    assert _frame(np.zeros((4, 3)), intensity=from_bytes).fields["intensity"] is from_bytes


def test_a_parsed_cloud_is_immutable():
    src = _frame(np.arange(12, dtype=float).reshape(4, 3), intensity=np.ones(4, np.float32))
    for data in ("binary", "binary_compressed", "ascii"):
        f = parse_pcd_bytes(pcd_bytes(src, data), "t.pcd")
        assert not f.points_xyz.flags.writeable
        assert all(not v.flags.writeable for v in f.fields.values())
        np.testing.assert_array_equal(f.points_xyz, src.points_xyz)
