"""Folder recordings: one subfolder per sensor; write -> read round trips, timestamps from file
names, the shared frames() API, and every error path."""

from __future__ import annotations


import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.recordings.bag import write_recording
from rigcal.io.recordings.open_any import open_any
from rigcal.io.recordings.folder import (
    open_folder,
    parse_radar_csv,
    radar_csv_text,
    time_ns_from_name,
    write_folder_recording,
    write_radar_csv,
)
from rigcal.io.clouds import write_pcd, write_ply
from rigcal.recording import ImageFrame, PointCloudFrame, RadarFrame

T0 = 1_596_000_000_000_000_000


def f32(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def make_frames(seed: int = 0):
    rng = np.random.default_rng(seed)
    lidar = [PointCloudFrame("lidar", T0 + k * 100_000_000, f32(rng.normal(size=(30, 3))),
                             {"intensity": rng.random(30).astype(np.float32)}) for k in range(3)]
    camera = [ImageFrame("camera", T0 + k * 100_000_000 + 5,
                         rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)) for k in range(2)]
    camera.append(ImageFrame("camera", T0 + 260_000_000, rng.integers(0, 256, (5, 7),
                                                                      dtype=np.uint8)))
    radar = [RadarFrame("radar", T0 + k * 70_000_000, rng.normal(size=(4, 2)),
                        np.append(rng.normal(size=3), np.nan)) for k in range(3)]
    radar3d = [RadarFrame("radar3d", T0 + 1, rng.normal(size=(2, 3)), rng.normal(size=2))]
    return {"velodyne": lidar, "cam0": camera, "radar_front": radar, "radar3d": radar3d}


SENSORS = {"lidar": ("velodyne", "lidar"), "camera": ("cam0", "camera"),
           "radar": ("radar_front", "radar"), "radar3d": ("radar3d", "radar3d")}


def assert_same(a, b) -> None:
    assert type(a) is type(b) and a.sensor == b.sensor and a.t_ns == b.t_ns
    if isinstance(a, PointCloudFrame):
        assert np.array_equal(a.points_xyz, b.points_xyz, equal_nan=True)
        assert {k: v.tolist() for k, v in a.fields.items()} == {
            k: v.tolist() for k, v in b.fields.items()}
    elif isinstance(a, ImageFrame):
        assert np.array_equal(a.image, b.image)
    else:
        assert np.array_equal(a.points, b.points)
        assert np.array_equal(a.rcs_dbsm, b.rcs_dbsm, equal_nan=True)


@pytest.mark.parametrize("cloud_format", ["pcd", "npy"])
def test_folder_round_trip(tmp_path, cloud_format):
    written = make_frames()
    root = write_folder_recording(tmp_path / "rec", written, point_cloud_format=cloud_format)
    with open_folder(root) as rec:
        assert rec.topics() == {"cam0": "image", "radar3d": "radar_csv",
                                "radar_front": "radar_csv", "velodyne": "points"}
        assert rec.count("velodyne") == 3 and rec.count("cam0") == 3
        frames = list(rec.frames(SENSORS))
    expected = [f for sensor, (folder, _) in SENSORS.items() for f in written[folder]]
    assert [f.t_ns for f in frames] == sorted(f.t_ns for f in expected)
    for sensor in SENSORS:
        got = [f for f in frames if f.sensor == sensor]
        want = [f for f in expected if f.sensor == sensor]
        assert len(got) == len(want)
        for a, b in zip(want, got):
            assert_same(a, b)


def test_time_window_and_same_api_as_bags(tmp_path):
    written = make_frames()
    folder = write_folder_recording(tmp_path / "rec", written)
    bag = write_recording(tmp_path / "rec.bag", {
        "/velodyne": written["velodyne"], "/radar": [
            RadarFrame("radar", f.t_ns, f32(f.points), f32(f.rcs_dbsm))
            for f in written["radar_front"]]})
    results = []
    for path, topics in [(folder, ("velodyne", "radar_front")), (bag, ("/velodyne", "/radar"))]:
        with open_any(path) as rec:
            results.append([(type(f).__name__, f.sensor, f.t_ns - T0) for f in rec.frames(
                {"l": (topics[0], "lidar"), "r": (topics[1], "radar")},
                start_ns=T0 + 70_000_000, end_ns=T0 + 200_000_000)])
    assert results[0] == results[1] == [
        ("RadarFrame", "r", 70_000_000), ("PointCloudFrame", "l", 100_000_000),
        ("RadarFrame", "r", 140_000_000)]


def test_timestamps_from_names_and_index_fallback(tmp_path):
    cloud = PointCloudFrame("x", 0, [[1, 2, 3]])
    secs = tmp_path / "rec" / "secs"
    for name in ("1596.5.ply", "1596.123456789.ply", "1595.999999999999.ply"):
        write_ply(secs / name, cloud)
    ns = tmp_path / "rec" / "ns"
    for name in ("200.pcd", "1000.pcd", "30.pcd"):
        write_pcd(ns / name, cloud)
    idx = tmp_path / "rec" / "idx"
    for name in ("scan_10.pcd", "scan_2.pcd", "scan_1.pcd"):
        write_pcd(idx / name, cloud)
    (idx / "notes.txt").write_text("ignored")
    (idx / ".hidden.pcd").write_text("ignored")
    (tmp_path / "rec" / "empty").mkdir()
    with open_folder(tmp_path / "rec") as rec:
        assert rec.topics() == {"idx": "points", "ns": "points", "secs": "points"}
        assert [t for t, _ in rec.timed_files("secs")] == [
            1595_999_999_999, 1596_123_456_789, 1596_500_000_000]
        assert [(t, p.name) for t, p in rec.timed_files("ns")] == [
            (30, "30.pcd"), (200, "200.pcd"), (1000, "1000.pcd")]
        assert [(t, p.name) for t, p in rec.timed_files("idx")] == [
            (0, "scan_1.pcd"), (1, "scan_2.pcd"), (2, "scan_10.pcd")]
        frames = list(rec.frames({"a": ("idx", "lidar"), "b": ("ns", "lidar")}))
    assert [(f.sensor, f.t_ns) for f in frames] == [
        ("a", 0), ("a", 1), ("a", 2), ("b", 30), ("b", 200), ("b", 1000)]


def test_time_ns_from_name():
    assert time_ns_from_name("1596123456789012345") == 1596123456789012345
    assert time_ns_from_name("1596.123456") == 1596_123_456_000
    assert time_ns_from_name("0.000000001") == 1
    assert time_ns_from_name("frame_1") is None
    assert time_ns_from_name("-1") is None and time_ns_from_name("1e9") is None


def test_point_cloud_files_as_radar_and_images_as_mono_bgr(tmp_path):
    import cv2

    cloud = PointCloudFrame("r", 0, [[1, 2, 3], [4, 5, 6]], {"RCS": np.array([1.5, -3.0])})
    write_pcd(tmp_path / "rec" / "radar" / "5.pcd", cloud, xyz_dtype=np.float64)
    cam = tmp_path / "rec" / "cam"
    cam.mkdir()
    rng = np.random.default_rng(3)
    bgra = rng.integers(0, 256, (4, 5, 4), dtype=np.uint8)
    cv2.imwrite(str(cam / "1.png"), bgra)
    cv2.imwrite(str(cam / "2.jpg"), np.full((4, 5, 3), 90, np.uint8))
    with open_folder(tmp_path / "rec") as rec:
        (r3,) = rec.frames({"r": ("radar", "radar3d")})
        (r2,) = rec.frames({"r": ("radar", "radar")}, rcs_field="RCS")
        img_png, img_jpg = rec.frames({"c": ("cam", "camera")})
    assert r3.points.tolist() == [[1, 2, 3], [4, 5, 6]] and r3.rcs_dbsm.tolist() == [1.5, -3]
    assert r2.points.shape == (2, 2) and r2.t_ns == 5
    assert np.array_equal(img_png.image, bgra[:, :, :3])
    assert img_jpg.image.shape == (4, 5, 3)


def test_remove_nan_in_folder_clouds(tmp_path):
    cloud = PointCloudFrame("l", 0, [[1, 2, 3], [np.nan] * 3], {"i": np.array([1.0, 2.0])},
                            organized_shape=(2, 1))
    write_pcd(tmp_path / "rec" / "l" / "1.pcd", cloud)
    with open_folder(tmp_path / "rec") as rec:
        (kept,) = rec.frames({"l": ("l", "lidar")})
        (dense,) = rec.frames({"l": ("l", "lidar")}, remove_nan=True)
    assert len(kept) == 2 and kept.organized_shape == (2, 1)
    assert len(dense) == 1 and dense.fields["i"].tolist() == [1.0]


def test_radar_csv_round_trip_and_parsing(tmp_path):
    frame = RadarFrame("r", 0, [[1.1, 2.2, 3.3], [1e-17, -4, 5]], [0.1, np.nan])
    path = write_radar_csv(tmp_path / "r.csv", frame)
    back = parse_radar_csv(path.read_text(), "r.csv", "r", 0, dims=3)
    assert np.array_equal(back.points, frame.points)
    assert np.array_equal(back.rcs_dbsm, frame.rcs_dbsm, equal_nan=True)
    assert radar_csv_text(frame).splitlines()[0] == "x,y,z,rcs"
    text = " id , x, y, rcs0, v\n1, 1, 2, 3, 9\n\n2, 4, 5, nan, 9\n"
    r = parse_radar_csv(text, "m", dims=2)
    assert r.points.tolist() == [[1, 2], [4, 5]] and np.isnan(r.rcs_dbsm[1])
    assert len(parse_radar_csv("x,y,rcs\n", "m").points) == 0


@pytest.mark.parametrize("text, dims, match", [
    ("", 2, r"bad\.csv: empty radar CSV, expected a header row"),
    ("x,y\n1,2\n", 2, r"bad\.csv: line 1: radar CSV has columns \['x', 'y'\], missing "
                      "rcs or RCS or rcs0"),
    ("x,y,rcs\n1,2,3\n", 3, r"line 1: radar CSV has columns \['x', 'y', 'rcs'\], missing z"),
    ("x,y,rcs\n1,2\n", 2, r"bad\.csv: line 2: 2 values, expected 3"),
    ("x,y,rcs\n1,2,3\n1,abc,3\n", 2, r"bad\.csv: line 3, column 'y': expected a number, got "
                                     "'abc'"),
])
def test_radar_csv_errors(text, dims, match):
    with pytest.raises(InputError, match=match):
        parse_radar_csv(text, "bad.csv", dims=dims)


def test_folder_errors(tmp_path):
    with pytest.raises(InputError, match=r"nope: recording folder not found"):
        open_folder(tmp_path / "nope")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(InputError, match=r"file\.txt: not a folder"):
        open_folder(tmp_path / "file.txt")
    root = write_folder_recording(tmp_path / "rec", make_frames())
    (root / "velodyne" / "bad.png").write_bytes(b"x")
    with open_folder(root) as rec:
        with pytest.raises(InputError, match=r"rec: folder 'lidar' not in recording; folders: "
                                             r"\['cam0', 'radar3d', 'radar_front', 'velodyne'\]"):
            list(rec.frames({"l": ("lidar", "lidar")}))
        with pytest.raises(InputError, match="folder '../rec' not in recording"):
            rec.count("../rec")
        with pytest.raises(InputError, match=r"bad\.png: an image file, but sensor 'l' is a "
                                             "lidar"):
            list(rec.frames({"l": ("velodyne", "lidar")}))
        with pytest.raises(InputError, match=r"\.csv: a radar CSV file, but sensor 'c' is a "
                                             "camera"):
            list(rec.frames({"c": ("radar_front", "camera")}))
        with pytest.raises(InputError, match="sensor 'c': unknown sensor kind 'eye'"):
            list(rec.frames({"c": ("cam0", "eye")}))
        with pytest.raises(InputError, match=r"sensor 'c': expected \(subfolder, kind\)"):
            list(rec.frames({"c": ("cam0",)}))
    with pytest.raises(InputError, match="rec: recording is closed"):
        rec.topics()
    (root / "velodyne" / "bad.png").unlink()
    (root / "velodyne" / "9.pcd").write_bytes(b"VERSION 0.7\nFIELDS x\nDATA ascii\n")
    with open_folder(root) as rec:
        with pytest.raises(InputError, match=r"9\.pcd: PCD header has no SIZE line"):
            list(rec.frames({"l": ("velodyne", "lidar")}))


def test_write_folder_errors(tmp_path):
    frames = make_frames()
    root = write_folder_recording(tmp_path / "rec", frames)
    with pytest.raises(InputError, match=r"velodyne: already holds frame files; choose an empty "
                                         "folder"):
        write_folder_recording(root, {"velodyne": frames["velodyne"]})
    c = PointCloudFrame("l", 5, [[1, 2, 3]])
    with pytest.raises(InputError, match="two frames at t_ns 5"):
        write_folder_recording(tmp_path / "r2", {"l": [c, c]})
    with pytest.raises(InputError, match="bad subfolder name '../x'"):
        write_folder_recording(tmp_path / "r3", {"../x": [c]})
    with pytest.raises(InputError, match="point_cloud_format must be 'pcd' or 'npy', got 'ply'"):
        write_folder_recording(tmp_path / "r4", {"l": [c]}, point_cloud_format="ply")
    with pytest.raises(InputError, match="negative time -1 ns"):
        write_folder_recording(tmp_path / "r5", {"l": [PointCloudFrame("l", -1, [[1, 2, 3]])]})
