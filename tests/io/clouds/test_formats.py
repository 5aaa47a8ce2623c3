"""Point cloud files (PCD, PLY, NPY) and LZF: write -> read round trips, hand-made layouts, the
shared example clouds, and every error path."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.clouds import (
    lzf_compress,
    lzf_decompress,
    npy_bytes,
    parse_npy_bytes,
    parse_pcd_bytes,
    parse_ply_bytes,
    pcd_bytes,
    ply_bytes,
    radar_frame_from_cloud,
    read_point_cloud,
    write_npy,
    write_pcd,
    write_ply,
)
from rigcal.recording import PointCloudFrame

DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data"


def make_cloud(seed: int = 0, n: int = 60, organized: tuple[int, int] | None = None,
               nan: bool = True, int64: bool = True) -> PointCloudFrame:
    """xyz exactly representable in float32 (PCD stores float32), NaN points, fields of many
    types."""
    rng = np.random.default_rng(seed)
    if organized:
        n = organized[0] * organized[1]
    pts = rng.normal(scale=5.0, size=(n, 3)).astype(np.float32).astype(np.float64)
    if nan:
        pts[::7] = np.nan
    fields = {
        "intensity": rng.random(n).astype(np.float32),
        "ring": rng.integers(0, 128, n).astype(np.uint16),
        "label": rng.integers(-100, 100, n).astype(np.int8),
        "t": rng.random(n),  # float64
        "flag": rng.integers(0, 255, n).astype(np.uint8),
        "i32": rng.integers(-(2**31), 2**31 - 1, n).astype(np.int32),
    }
    if int64:
        fields["stamp"] = rng.integers(0, 2**62, n).astype(np.uint64)
    return PointCloudFrame(sensor="lidar", t_ns=0, points_xyz=pts, fields=fields,
                           organized_shape=organized, frame_id="")


def assert_same(a: PointCloudFrame, b: PointCloudFrame) -> None:
    assert np.array_equal(a.points_xyz, b.points_xyz, equal_nan=True)
    assert list(a.fields) == list(b.fields)
    for k in a.fields:
        assert a.fields[k].dtype == b.fields[k].dtype, k
        assert np.array_equal(a.fields[k], b.fields[k], equal_nan=True), k
    assert a.organized_shape == b.organized_shape


# -- LZF -------------------------------------------------------------------------------------


def test_lzf_decodes_hand_made_stream():
    # literal "abc", then a back reference of 6 bytes, 3 back (overlapping copy)
    assert lzf_decompress(b"\x02abc\x80\x02") == b"abcabcabc"
    # literal "a", then a long reference: length code 7 + 10 (+2) = 19 bytes, 1 back
    assert lzf_decompress(b"\x00a\xe0\x0a\x00") == b"a" * 20


@pytest.mark.parametrize("kind", ["random", "repetitive", "floats", "empty", "tiny"])
def test_lzf_round_trip(kind):
    rng = np.random.default_rng(1)
    data = {
        "random": rng.integers(0, 256, 5000, dtype=np.uint8).tobytes(),
        "repetitive": b"abcd" * 3000 + bytes(9000) + b"xyz",
        "floats": np.repeat(rng.normal(size=300).astype(np.float32), 5).tobytes(),
        "empty": b"",
        "tiny": b"ab",
    }[kind]
    packed = lzf_compress(data)
    assert lzf_decompress(packed, len(data)) == data
    if kind == "repetitive":
        assert len(packed) < len(data) / 20


def test_lzf_corrupt_streams_raise():
    with pytest.raises(InputError, match=r"x\.pcd: corrupt LZF data: back reference 3 bytes"):
        lzf_decompress(b"\x80\x02", source="x.pcd")
    with pytest.raises(InputError, match="literal run of 5 bytes .* goes past the end"):
        lzf_decompress(b"\x04ab")
    with pytest.raises(InputError, match="truncated back reference"):
        lzf_decompress(b"\x00a\xe0")
    with pytest.raises(InputError, match="decompress to 3 bytes, expected 4"):
        lzf_decompress(b"\x02abc", 4)


def test_lzf_refuses_an_impossible_announced_size_before_decompressing():
    # 3-byte tokens yield at most 264 bytes: 31 bytes cannot become 1 MB
    with pytest.raises(InputError, match=r"b\.pcd: LZF data of 31 bytes cannot decompress to "
                                         r"the announced 1000000 bytes"):
        lzf_decompress(b"\x00a" + b"\xe0\xff\x00" * 9 + b"\x00a", 1_000_000, "b.pcd")


@pytest.mark.parametrize("compiled", [True, False])
def test_lzf_bomb_stops_at_the_announced_size(monkeypatch, compiled):
    from rigcal.io.clouds import lzf as pointcloud

    if compiled and pointcloud._clzf is None:
        pytest.skip("python-neo-lzf not installed")
    if not compiled:
        monkeypatch.setattr(pointcloud, "_clzf", None)
    bomb = b"\x00A" + b"\xe0\xff\x00" * 1333  # ~350 kB from 4 kB
    with pytest.raises(InputError, match="LZF data decompress to more than 12 bytes"):
        lzf_decompress(bomb, 12, "x.pcd")
    with pytest.raises(InputError, match="x.pcd: corrupt LZF data"):
        lzf_decompress(b"\x80\x02" + bytes(10), 12, "x.pcd")  # reference before the start
    with pytest.raises(InputError, match="decompress to 3 bytes, expected 4"):
        lzf_decompress(b"\x02abc", 4)


def test_compiled_and_pure_python_lzf_read_each_other(monkeypatch):
    from rigcal.io.clouds import lzf as pointcloud

    if pointcloud._clzf is None:
        pytest.skip("python-neo-lzf not installed")
    rng = np.random.default_rng(5)
    data = (np.repeat(rng.normal(size=2000).astype(np.float32), 3).tobytes()
            + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes() + bytes(5000))
    compiled = lzf_compress(data)
    with monkeypatch.context() as m:
        m.setattr(pointcloud, "_clzf", None)
        python = lzf_compress(data)
        assert lzf_decompress(compiled, len(data)) == data
    assert lzf_decompress(python, len(data)) == data
    # incompressible data still make a valid (slightly larger) block
    noise = rng.integers(0, 256, 10000, dtype=np.uint8).tobytes()
    assert lzf_decompress(lzf_compress(noise), len(noise)) == noise


def test_pcd_round_trip_without_the_compiled_lzf(monkeypatch):
    from rigcal.io.clouds import lzf as pointcloud

    monkeypatch.setattr(pointcloud, "_clzf", None)
    cloud = make_cloud(seed=9)
    assert_same(cloud, parse_pcd_bytes(pcd_bytes(cloud, "binary_compressed"), "m"))


# -- PCD -------------------------------------------------------------------------------------


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
@pytest.mark.parametrize("organized", [None, (6, 10)])
def test_pcd_round_trip_is_bit_exact(tmp_path, data, organized):
    cloud = make_cloud(seed=2, organized=organized)
    path = write_pcd(tmp_path / "c.pcd", cloud, data=data)
    back = read_point_cloud(path, "lidar", t_ns=7)
    assert back.sensor == "lidar" and back.t_ns == 7
    assert_same(cloud, back)
    header = path.read_bytes().split(b"DATA")[0].decode()
    assert f"DATA {data}" in path.read_bytes().decode("latin-1")
    assert "FIELDS x y z intensity ring label t flag i32 stamp" in header
    assert "TYPE F F F F U I F U I U" in header


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_float64_xyz_round_trip(data):
    rng = np.random.default_rng(3)
    cloud = PointCloudFrame("l", 0, rng.normal(size=(20, 3)))
    back = parse_pcd_bytes(pcd_bytes(cloud, data, xyz_dtype=np.float64), "mem")
    assert np.array_equal(back.points_xyz, cloud.points_xyz)


def test_pcd_empty_cloud_round_trip():
    cloud = PointCloudFrame("l", 0, np.zeros((0, 3)), {"i": np.zeros(0, np.float32)})
    for data in ("ascii", "binary", "binary_compressed"):
        assert_same(cloud, parse_pcd_bytes(pcd_bytes(cloud, data), "mem"))


def pcd_header(fields, size, typ, count, n, data, width=None, height=1, extra=""):
    width = n if width is None else width
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {typ}\nCOUNT {count}\n"
        f"WIDTH {width}\nHEIGHT {height}\n{extra}VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
        f"DATA {data}\n"
    ).encode()


def test_pcd_padding_count_and_field_order_binary():
    rng = np.random.default_rng(4)
    n = 9
    rec = np.dtype([("i", "<f4"), ("pad", "u1", (3,)), ("z", "<f8"), ("y", "<f4"),
                    ("normal", "<f4", (3,)), ("x", "<f4"), ("ring", "<u2")])
    table = np.zeros(n, rec)
    for name in ("i", "y", "x"):
        table[name] = rng.normal(size=n)
    table["z"] = rng.normal(size=n)
    table["normal"] = rng.normal(size=(n, 3))
    table["ring"] = np.arange(n)
    head = pcd_header("i _ z y normal x ring", "4 1 8 4 4 4 2", "F U F F F F U", "1 3 1 1 3 1 1",
                      n, "binary")
    cloud = parse_pcd_bytes(head + table.tobytes(), "mem.pcd")
    assert np.array_equal(cloud.points_xyz[:, 0], table["x"].astype(float))
    assert np.array_equal(cloud.points_xyz[:, 1], table["y"].astype(float))
    assert np.array_equal(cloud.points_xyz[:, 2], table["z"])
    assert list(cloud.fields) == ["i", "normal_0", "normal_1", "normal_2", "ring"]
    assert np.array_equal(cloud.fields["normal_1"], table["normal"][:, 1])
    assert cloud.fields["ring"].dtype == np.uint16


@pytest.mark.parametrize("xyz_type", ["<f4", "<f8"])
def test_pcd_binary_adjacent_xyz_after_other_fields(xyz_type):
    # x y z side by side after a 2-byte field, 19- or 31-byte records: read as one strided
    # block; the values equal the records' and the points are a new, read-only float64 array
    rng = np.random.default_rng(5)
    n = 11
    rec = np.dtype([("ring", "<u2"), ("x", xyz_type), ("y", xyz_type), ("z", xyz_type), ("t", "u1")])
    table = np.zeros(n, rec)
    for name in ("x", "y", "z"):
        table[name] = rng.normal(size=n)
    table["t"] = np.arange(n)
    size = np.dtype(xyz_type).itemsize
    head = pcd_header("ring x y z t", f"2 {size} {size} {size} 1", "U F F F U", "1 1 1 1 1", n, "binary")
    data = head + table.tobytes()
    cloud = parse_pcd_bytes(data, "mem.pcd")
    expected = np.stack([table[a].astype(float) for a in "xyz"], axis=1)
    assert np.array_equal(cloud.points_xyz, expected)
    assert cloud.points_xyz.dtype == np.float64 and cloud.points_xyz.flags.c_contiguous
    assert not cloud.points_xyz.flags.writeable
    assert list(cloud.fields) == ["ring", "t"]
    assert np.array_equal(cloud.fields["t"], np.arange(n))
    # a duplicated coordinate field is still refused by name
    twice = pcd_header("x x y z", "4 4 4 4", "F F F F", "1 1 1 1", 1, "binary") + bytes(16)
    with pytest.raises(InputError, match="field 'x' appears twice"):
        parse_pcd_bytes(twice, "mem.pcd")


def test_pcd_hand_made_compressed_is_column_major():
    n = 4
    x = np.arange(n, dtype="<f4")
    y = x + 10
    z = x + 20
    pad = np.zeros(n, "<u2")
    raw = z.tobytes() + pad.tobytes() + x.tobytes() + y.tobytes()
    packed = lzf_compress(raw)
    head = pcd_header("z _ x y", "4 2 4 4", "F U F F", "1 1 1 1", n, "binary_compressed")
    cloud = parse_pcd_bytes(head + struct.pack("<II", len(packed), len(raw)) + packed, "m")
    assert np.array_equal(cloud.points_xyz, np.stack([x, y, z], 1).astype(float))
    assert dict(cloud.fields) == {}


def test_pcd_ascii_hand_made_organised_with_nan_and_comments():
    text = pcd_header("x y z rgb ring", "4 4 4 4 2", "F F F F U", "1 1 1 1 1", 4, "ascii",
                      width=2, height=2)
    text = text.replace(b"VERSION", b"# a comment\nVERSION")
    body = b"1 2 3 4.2e-41 0\nnan nan nan 0 1\n\n-1.5 2.5e3 0 1 2\n7 8 9 0 65535\n"
    cloud = parse_pcd_bytes(text + body, "m")
    assert cloud.organized_shape == (2, 2)
    assert np.isnan(cloud.points_xyz[1]).all()
    assert cloud.points_xyz[2].tolist() == [-1.5, 2500.0, 0.0]
    assert cloud.fields["ring"].tolist() == [0, 1, 2, 65535]


def test_ring_is_written_as_uint16_and_read_from_any_integer_type():
    n = 5
    pts = np.arange(3 * n, dtype=float).reshape(n, 3)
    cloud = PointCloudFrame("l", 0, pts, {"ring": np.arange(n, dtype=np.int32)})
    for data in ("ascii", "binary", "binary_compressed"):
        raw = pcd_bytes(cloud, data)
        header = raw.split(b"DATA")[0].decode()
        assert "FIELDS x y z ring" in header and "SIZE 4 4 4 2" in header
        assert "TYPE F F F U" in header
        back = parse_pcd_bytes(raw, "m")
        assert back.fields["ring"].dtype == np.uint16
        assert back.fields["ring"].tolist() == list(range(n))
    assert "property ushort ring" in ply_bytes(cloud).split(b"end_header")[0].decode()
    # a file with an INT32 ring (what rigcal wrote before) reads as uint16 too
    for typ, dt in (("I 4", "<i4"), ("U 4", "<u4"), ("I 2", "<i2"), ("U 1", "<u1")):
        t, size = typ.split()
        rec = np.zeros(n, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", dt)])
        rec["ring"] = np.arange(n)
        head = pcd_header("x y z ring", f"4 4 4 {size}", f"F F F {t}", "1 1 1 1", n, "binary")
        back = parse_pcd_bytes(head + rec.tobytes(), "m")
        assert back.fields["ring"].dtype == np.uint16, typ
        assert back.fields["ring"].tolist() == list(range(n))
    # values that do not fit in uint16 keep their type, on writing and reading
    odd = PointCloudFrame("l", 0, pts, {"ring": np.array([-1, 0, 1, 2, 70000], np.int32)})
    back = parse_pcd_bytes(pcd_bytes(odd, "binary"), "m")
    assert back.fields["ring"].dtype == np.int32
    assert back.fields["ring"].tolist() == [-1, 0, 1, 2, 70000]


@pytest.mark.parametrize("newline", [b"\n", b"\r\n", b"\r"])
def test_pcd_ascii_fast_parser_matches_the_line_by_line_one(monkeypatch, newline):
    from rigcal.io.clouds import pcd as pointcloud

    cloud = make_cloud(seed=8, n=300)
    head, body = pcd_bytes(cloud, "ascii").split(b"DATA ascii\n")
    lines = body.split(b"\n")
    # blank lines, extra spaces and lines past POINTS (ignored) as PCL-ish writers leave them
    body = newline.join(lines[:5] + [b"", b"   "] + [b"  " + ln + b" \t" for ln in lines[5:]]
                        + [b"1 2 3", b""])
    data = head + b"DATA ascii\n" + body
    fast = parse_pcd_bytes(data, "m")
    assert_same(cloud, fast)
    monkeypatch.setattr(pointcloud, "_ascii_table", lambda *a: None)
    slow = parse_pcd_bytes(data, "m")
    assert_same(fast, slow)


def test_ascii_values_that_underflow_float32_become_zero():
    head = pcd_header("x y z i", "4 4 4 4", "F F F F", "1 1 1 1", 2, "ascii")
    with np.errstate(all="raise"):
        cloud = parse_pcd_bytes(head + b"1e-320 1 2 1e-50\n0 0 0 0\n", "m")
    assert cloud.points_xyz[0].tolist() == [0.0, 1.0, 2.0]
    assert cloud.fields["i"][0] == 0.0
    ply = (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           b"property float z\nend_header\n1e-320 1 2\n")
    with np.errstate(all="raise"):
        assert parse_ply_bytes(ply, "m").points_xyz.tolist() == [[0.0, 1.0, 2.0]]


def test_pcd_missing_count_line_means_one():
    head = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nDATA ascii\n"
    assert parse_pcd_bytes(head + b"1 2 3\n", "m").points_xyz.tolist() == [[1, 2, 3]]


def shared(name: str) -> Path:
    path = DATA / "vicon_sim" / name
    if not path.exists():
        pytest.skip(f"shared data {path} not present")
    return path


@pytest.mark.parametrize("name, n, fields", [
    ("checkerboard_target_simulation.pcd", 100014, ["rgb"]),
    ("cylinder_target_rotated.pcd", 32200, ["Scalar_field_#3", "Scalar_field_#2",
                                            "Scalar_field"]),
])
def test_shared_pcd_files_parse(name, n, fields, capsys):
    cloud = read_point_cloud(shared(name), "lidar")
    with capsys.disabled():
        print(f"\n{name}: {len(cloud)} points, fields x y z {' '.join(cloud.fields)}")
    assert len(cloud) == n
    assert list(cloud.fields) == fields
    assert np.isfinite(cloud.points_xyz).all()
    assert np.abs(cloud.points_xyz).max() < 100  # metres, a target-sized scene
    assert cloud.organized_shape is None
    # re-written in every PCD flavour it reads back the same
    for data in ("binary", "binary_compressed"):
        assert_same(cloud, parse_pcd_bytes(pcd_bytes(cloud, data), "mem"))


# -- PLY -------------------------------------------------------------------------------------


@pytest.mark.parametrize("data", ["ascii", "binary_little_endian"])
def test_ply_round_trip_is_bit_exact(tmp_path, data):
    cloud = make_cloud(seed=5, int64=False)
    rng = np.random.default_rng(5)
    cloud = PointCloudFrame("l", 0, cloud.points_xyz + rng.normal(size=cloud.points_xyz.shape),
                            cloud.fields)  # float64 values: PLY writes double by default
    path = write_ply(tmp_path / "c.ply", cloud, data=data)
    assert_same(cloud, read_point_cloud(path, "l"))


def test_ply_float32_xyz_and_hand_made_files():
    cloud = PointCloudFrame("l", 0, [[1.5, 2, 3]], {"intensity": np.array([7], np.uint8)})
    back = parse_ply_bytes(ply_bytes(cloud, "ascii", xyz_dtype=np.float32), "m")
    assert_same(cloud, back)
    # an element before 'vertex' (ascii) and a face element after it
    text = (b"ply\nformat ascii 1.0\ncomment hi\nelement camera 1\nproperty float fx\n"
            b"element vertex 2\nproperty double y\nproperty float x\nproperty uchar red\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            b"end_header\n9.5\n1 2 255 3\n4 5 0 6\n3 0 1 1\n")
    c = parse_ply_bytes(text, "m.ply")
    assert c.points_xyz.tolist() == [[2, 1, 3], [5, 4, 6]]
    assert c.fields["red"].tolist() == [255, 0]
    # binary big endian with a fixed-size element first
    rec = np.dtype([("x", ">f4"), ("y", ">f4"), ("z", ">f4")])
    verts = np.array([(1, 2, 3), (4, 5, 6)], rec)
    head = (b"ply\nformat binary_big_endian 1.0\nelement marker 2\nproperty short id\n"
            b"element vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
            b"end_header\n")
    c = parse_ply_bytes(head + np.array([1, 2], ">i2").tobytes() + verts.tobytes(), "m")
    assert c.points_xyz.tolist() == [[1, 2, 3], [4, 5, 6]]


# -- NPY -------------------------------------------------------------------------------------


@pytest.mark.parametrize("organized", [None, (5, 12)])
@pytest.mark.parametrize("with_fields", [True, False])
def test_npy_round_trip_is_bit_exact(tmp_path, organized, with_fields):
    cloud = make_cloud(seed=6, organized=organized)
    rng = np.random.default_rng(6)
    cloud = PointCloudFrame("l", 0, cloud.points_xyz + rng.normal(size=(len(cloud), 3)),
                            cloud.fields if with_fields else {}, organized_shape=organized)
    path = write_npy(tmp_path / "c.npy", cloud)
    assert_same(cloud, read_point_cloud(path, "l"))


def test_npy_plain_and_structured_inputs(tmp_path):
    arr = np.arange(12, dtype=np.float32).reshape(4, 3)
    np.save(tmp_path / "a.npy", arr)
    assert read_point_cloud(tmp_path / "a.npy", "l").points_xyz.tolist() == arr.tolist()
    rec = np.zeros(3, [("intensity", "<f4"), ("z", "<f8"), ("x", "<f8"), ("y", "<f8"),
                       ("rgb", "u1", (3,))])
    rec["rgb"] = [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    c = parse_npy_bytes(npy_bytes_raw(rec), "m")
    assert list(c.fields) == ["intensity", "rgb_0", "rgb_1", "rgb_2"]
    assert c.fields["rgb_2"].tolist() == [3, 6, 9]


def npy_bytes_raw(arr) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


# -- radar from a cloud ----------------------------------------------------------------------


def test_radar_frame_from_cloud_picks_rcs_field():
    cloud = PointCloudFrame("r", 5, [[1, 2, 3], [4, 5, 6]], {"RCS": np.array([1.0, -2.0])},
                            frame_id="radar")
    r2 = radar_frame_from_cloud(cloud)
    assert r2.points.tolist() == [[1, 2], [4, 5]] and r2.rcs_dbsm.tolist() == [1, -2]
    assert r2.t_ns == 5 and r2.frame_id == "radar"
    r3 = radar_frame_from_cloud(cloud, dims=3, rcs_field="RCS")
    assert r3.points.shape == (2, 3)
    with pytest.raises(InputError, match=r"src: radar point cloud has fields \['x', 'y', 'z', "
                                         r"'RCS'\], expected an RCS field \(power\)"):
        radar_frame_from_cloud(cloud, rcs_field="power", source="src")
    with pytest.raises(InputError, match="radar dims must be 2 or 3"):
        radar_frame_from_cloud(cloud, dims=4)


# -- errors ----------------------------------------------------------------------------------

GOOD = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, "binary")


@pytest.mark.parametrize("data, match", [
    (pcd_header("a b c", "4 4 4", "F F F", "1 1 1", 1, "binary") + bytes(12),
     r"bad\.pcd: point cloud has fields \['a', 'b', 'c'\], expected x, y, z"),
    (GOOD + bytes(20), r"bad\.pcd: truncated PCD data: DATA binary needs 24 bytes for 2 "
                       r"points of 12 bytes, got 20"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, "ascii") + b"1 2 3\n",
     "truncated PCD data: DATA ascii has 1 point lines, expected 2"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 1, "ascii") + b"1 2\n",
     "PCD ascii point 0 has 2 values, expected 3"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 1, "ascii") + b"1 2 abc\n",
     r"PCD ascii field 'z' \(TYPE F SIZE 4\): bad value 'abc'"),
    (pcd_header("x y z r", "4 4 4 1", "F F F U", "1 1 1 1", 1, "ascii") + b"1 2 3 300\n",
     r"field 'r' .*value out of range for U8"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, "binary_compressed") + b"\x01\x00",
     "truncated PCD data: DATA binary_compressed needs an 8-byte size header"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, "binary_compressed")
     + struct.pack("<II", 50, 24) + b"\x00" * 10, "50 compressed bytes announced, 10 present"),
    (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, "binary_compressed")
     + struct.pack("<II", 2, 20) + b"\x00a", "announces 20 uncompressed bytes, expected 24"),
    (GOOD.replace(b"VERSION 0.7", b"COLOR red"),
     r"bad\.pcd: bad PCD header line 2 'COLOR red': unknown keyword 'COLOR'"),
    (GOOD.replace(b"SIZE 4 4 4", b"SIZE 4 four 4"),
     r"bad PCD header line 4 'SIZE 4 four 4': expected integers"),
    (GOOD.replace(b"SIZE 4 4 4", b"SIZE 4 4"), r"bad PCD header line 4 'SIZE 4 4': expected 3"),
    (GOOD.replace(b"TYPE F F F", b"TYPE F F"), r"bad PCD header line 5 'TYPE F F': expected 3"),
    (GOOD.replace(b"SIZE 4 4 4", b"SIZE 4 4 2"),
     r"field 'z': unsupported TYPE F with SIZE 2 \(supported: F 4/8"),
    (GOOD.replace(b"TYPE F F F", b"TYPE F F X"), "field 'z': unsupported TYPE X with SIZE 4"),
    (GOOD.replace(b"POINTS 2", b"POINTS 3"),
     r"bad PCD header line 10 'POINTS 3': differs from WIDTH x HEIGHT = 2 x 1"),
    (GOOD.replace(b"DATA binary", b"DATA packed"),
     r"bad PCD header line 11 'DATA packed': expected one of ascii, binary, binary_compressed"),
    (GOOD.replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0"),
     r"bad PCD header line 9 'VIEWPOINT 0 0': expected 7 numbers"),
    (GOOD.replace(b"WIDTH 2\n", b""), "PCD header has no WIDTH line"),
    (GOOD.replace(b"DATA binary\n", b""), "not a PCD file: the header has no DATA line"),
    (GOOD.replace(b"WIDTH 2", b"WIDTH 2\nWIDTH 2"), "bad PCD header line 8: 'WIDTH' given twice"),
    (b"\x89PNG\r\n\x1a\n\xff\xfe", r"bad PCD header line 1: not ASCII text \(is this a PCD"),
    (GOOD.replace(b"COUNT 1 1 1", b"COUNT 1 0 1"), "field 'y': COUNT must be at least 1"),
])
def test_pcd_errors(data, match):
    with pytest.raises(InputError, match=match):
        parse_pcd_bytes(data, "bad.pcd")


@pytest.mark.parametrize("data, match", [
    (b"PCD", r"bad\.ply: not a PLY file"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no end_header line"),
    (b"ply\nelement vertex 1\nproperty float x\nend_header\n", "PLY header has no format line"),
    (b"ply\nformat binary_middle_endian 1.0\nend_header\n",
     "bad PLY header line 2 'format binary_middle_endian 1.0'"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n",
     "bad PLY header line 4 'property half x': expected 'property <type> <name>'"),
    (b"ply\nformat ascii 1.0\nelement face 1\nend_header\n",
     r"PLY file has elements \['face'\], expected 'vertex'"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar int idx\nend_header\n",
     r"PLY vertex list properties \['idx'\] are not supported"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n1 2 3\n", "truncated PLY data: 1 vertex lines, expected 2"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
     b"end_header\n1 2\n", r"point cloud has fields \['x', 'y'\], expected x, y, z"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n1 2 q\n", "PLY vertex property 'z': bad value 'q'"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
     b"property float y\nproperty float z\nend_header\n" + bytes(12),
     "truncated PLY data: 2 vertices need 24 bytes, got 12"),
    (b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int i\n"
     b"element vertex 1\nproperty float x\nend_header\n",
     "PLY element 'face' before 'vertex' has list properties"),
    (b"ply\nformat ascii 1.0\nbanana\nend_header\n", "bad PLY header line 3 'banana'"),
])
def test_ply_errors(data, match):
    with pytest.raises(InputError, match=match):
        parse_ply_bytes(data, "bad.ply")


@pytest.mark.parametrize("arr, match", [
    (np.zeros((4, 2)), r"expected an \(N, 3\) x, y, z array .* got shape \(4, 2\)"),
    (np.zeros(3, [("x", "f8"), ("y", "f8")]),
     r"point cloud has fields \['x', 'y'\], expected x, y, z"),
    (np.array(["a", "b"]), "expected a numeric array, got dtype <U1"),
])
def test_npy_errors(arr, match):
    with pytest.raises(InputError, match=match):
        parse_npy_bytes(npy_bytes_raw(arr), "bad.npy")


def test_npy_refuses_pickles_and_garbage():
    with pytest.raises(InputError, match=r"bad\.npy: not a valid \.npy array"):
        parse_npy_bytes(npy_bytes_raw(np.array([{"x": 1}], dtype=object)), "bad.npy")
    with pytest.raises(InputError, match=r"bad\.npy: not a valid \.npy array"):
        parse_npy_bytes(b"hello", "bad.npy")


def test_read_point_cloud_file_errors(tmp_path):
    with pytest.raises(InputError, match=r"nope\.pcd: point cloud file not found"):
        read_point_cloud(tmp_path / "nope.pcd", "l")
    (tmp_path / "c.xyz").write_text("1 2 3\n")
    with pytest.raises(InputError, match=r"c\.xyz: unknown point cloud format '\.xyz'"):
        read_point_cloud(tmp_path / "c.xyz", "l")
    (tmp_path / "d.pcd").mkdir()
    with pytest.raises(InputError, match=r"d\.pcd: is a directory"):
        read_point_cloud(tmp_path / "d.pcd", "l")


def test_writer_errors(tmp_path):
    cloud = PointCloudFrame("l", 0, [[1, 2, 3]], {"big": np.array([1], np.int64)})
    with pytest.raises(InputError, match=r"c\.ply: field 'big' is int64; PLY has no 64-bit"):
        write_ply(tmp_path / "c.ply", cloud)
    assert not (tmp_path / "c.ply").exists()
    with pytest.raises(InputError, match="PCD data must be one of ascii, binary, "
                                         "binary_compressed, got 'zip'"):
        write_pcd(tmp_path / "c.pcd", cloud, data="zip")
    with pytest.raises(InputError, match="xyz_dtype must be float32 or float64, got float16"):
        pcd_bytes(cloud, xyz_dtype=np.float16)
    bad = PointCloudFrame("l", 0, [[1, 2, 3]], {"a b": np.array([1.0])})
    with pytest.raises(InputError, match=r"field name 'a b' cannot be written"):
        pcd_bytes(bad)
    cplx = PointCloudFrame("l", 0, [[1, 2, 3]], {"c": np.array([1j])})
    with pytest.raises(InputError, match="field 'c' has dtype complex128"):
        ply_bytes(cplx)
    with pytest.raises(InputError, match="PLY data must be 'ascii' or 'binary_little_endian'"):
        ply_bytes(cloud, data="binary_big_endian")
    assert parse_npy_bytes(npy_bytes(cloud), "m").fields["big"].dtype == np.int64
