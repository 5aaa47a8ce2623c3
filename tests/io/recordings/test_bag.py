"""ROS bags and PointCloud2: write -> read round trips through real ROS1 and ROS2 (sqlite3, mcap)
bags, unusual PointCloud2 layouts, stamps and time order, and every error path."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rigcal.errors import InputError
from rigcal.io.recordings.bag import (
    CameraInfo,
    decode_compressed_image_msg,
    decode_image_msg,
    open_bag,
    write_recording,
)
from rigcal.io.recordings.pointcloud2 import decode_pointcloud2, encode_pointcloud2, make_header
from rigcal.recording import ImageFrame, PointCloudFrame, RadarFrame, StereoFrame

ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
FORMATS = ["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"]
T0 = 1_700_000_000_000_000_000


def bag_path(tmp_path: Path, fmt: str, name: str = "rec") -> Path:
    return tmp_path / (f"{name}.bag" if fmt == "rosbag1" else name)


def f32(a) -> np.ndarray:
    """float64 values that survive a float32 round trip (PointCloud2 xyz default)."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def make_frames(seed: int = 0):
    rng = np.random.default_rng(seed)
    clouds = []
    for k in range(3):
        pts = f32(rng.normal(scale=4.0, size=(40, 3)))
        pts[5] = np.nan
        clouds.append(PointCloudFrame(
            "lidar", T0 + k * 100_000_000, pts,
            {"intensity": rng.random(40).astype(np.float32),
             "ring": rng.integers(0, 32, 40).astype(np.uint16),
             "time": rng.random(40)},
            frame_id="velodyne"))
    stereo = PointCloudFrame("stereo", T0 + 50_000_000, f32(rng.normal(size=(12, 3))),
                             {"rgb": rng.random(12).astype(np.float32)}, organized_shape=(3, 4),
                             frame_id="left_optical")
    images = [ImageFrame("camera", T0 + k * 100_000_000 + 10, rng.integers(0, 256, (6, 8, 3),
                                                                         dtype=np.uint8),
                         frame_id="camera") for k in range(2)]
    mono = ImageFrame("camera", T0 + 250_000_000, rng.integers(0, 256, (6, 8), dtype=np.uint8),
                      frame_id="camera")
    radar2 = [RadarFrame("radar", T0 + k * 70_000_000, f32(rng.normal(size=(5, 2))),
                         f32(rng.normal(size=5) * 10), frame_id="radar") for k in range(3)]
    radar3 = RadarFrame("radar3d", T0 + 20, f32(rng.normal(size=(4, 3))),
                        f32([1, 2, np.nan, 4]), frame_id="radar3d")
    info = CameraInfo(8, 6, [[500, 0, 4], [0, 501, 3], [0, 0, 1]], [0.1, -0.2, 0.001, 0.002, 0.0],
                      frame_id="camera", t_ns=T0)
    return {
        "/velodyne_points": clouds,
        "/stereo/points": [stereo],
        "/camera/image_raw": images + [mono],
        "/camera/image_raw/compressed": images,
        "/radar/detections": radar2,
        "/radar3d/detections": [radar3],
        "/camera/camera_info": [info],
    }


SENSORS = {
    "lidar": ("/velodyne_points", "lidar"),
    "stereo": ("/stereo/points", "camera"),
    "camera": ("/camera/image_raw", "camera"),
    "camera_png": ("/camera/image_raw/compressed", "camera"),
    "radar": ("/radar/detections", "radar"),
    "radar3d": ("/radar3d/detections", "radar3d"),
}


def assert_same_frame(a, b) -> None:
    assert type(a) is type(b)
    assert a.t_ns == b.t_ns and a.frame_id == b.frame_id
    if isinstance(a, PointCloudFrame):
        assert np.array_equal(a.points_xyz, b.points_xyz, equal_nan=True)
        assert list(a.fields) == list(b.fields)
        for k in a.fields:
            assert a.fields[k].dtype == b.fields[k].dtype
            assert np.array_equal(a.fields[k], b.fields[k], equal_nan=True)
        assert a.organized_shape == b.organized_shape
    elif isinstance(a, ImageFrame):
        assert a.image.dtype == b.image.dtype and np.array_equal(a.image, b.image)
    else:
        assert np.array_equal(a.points, b.points)
        assert np.array_equal(a.rcs_dbsm, b.rcs_dbsm, equal_nan=True)


# -- bags: round trips -----------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_bag_round_trip_gives_the_same_frames(tmp_path, fmt):
    written = make_frames()
    path = write_recording(bag_path(tmp_path, fmt), written, fmt)
    with open_bag(path) as rec:
        assert rec.topics() == {
            "/velodyne_points": "sensor_msgs/msg/PointCloud2",
            "/stereo/points": "sensor_msgs/msg/PointCloud2",
            "/camera/image_raw": "sensor_msgs/msg/Image",
            "/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
            "/radar/detections": "sensor_msgs/msg/PointCloud2",
            "/radar3d/detections": "sensor_msgs/msg/PointCloud2",
            "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
        }
        assert rec.count("/velodyne_points") == 3 and rec.count("/camera/image_raw") == 3
        frames = list(rec.frames(SENSORS))
        info = rec.camera_info("/camera/camera_info")

    expected = []
    for sensor, (topic, _) in SENSORS.items():
        for f in written[topic]:
            if isinstance(f, PointCloudFrame):
                f = PointCloudFrame(sensor, f.t_ns, f.points_xyz, f.fields, f.organized_shape,
                                    f.frame_id)
            elif isinstance(f, ImageFrame):
                f = ImageFrame(sensor, f.t_ns, f.image, f.frame_id)
            expected.append(f)
    assert [f.t_ns for f in frames] == sorted(f.t_ns for f in expected)
    for sensor in SENSORS:
        got = [f for f in frames if f.sensor == sensor]
        want = [f for f in expected if f.sensor == sensor]
        assert len(got) == len(want), sensor
        for a, b in zip(want, got):
            assert_same_frame(a, b)
    radar2 = [f for f in frames if f.sensor == "radar"][0]
    assert radar2.points.shape == (5, 2)
    src = written["/camera/camera_info"][0]
    assert (info.width, info.height, info.distortion_model) == (8, 6, "plumb_bob")
    assert np.array_equal(info.K, src.K) and np.array_equal(info.D, src.D)
    assert np.array_equal(info.P, src.P) and info.frame_id == "camera" and info.t_ns == T0


@pytest.mark.parametrize("fmt", FORMATS)
def test_raw_messages_of_chosen_topics_in_bag_order(tmp_path, fmt):
    path = write_recording(bag_path(tmp_path, fmt), make_frames(), fmt)
    with open_bag(path) as rec:
        got = list(rec.messages(["/camera/camera_info", "/radar/detections"]))
        with pytest.raises(InputError, match="topic /x not in bag"):
            list(rec.messages(["/x"]))
    assert sorted((t, m) for t, m, _, _ in got) == [("/camera/camera_info", "sensor_msgs/msg/CameraInfo")] + [
        ("/radar/detections", "sensor_msgs/msg/PointCloud2")] * 3
    stamps = [r for _, _, r, _ in got]
    assert stamps == sorted(stamps) and len(got) == 4
    info = next(m for t, _, _, m in got if t == "/camera/camera_info")
    assert int(info.width) == 8 and int(info.height) == 6


@pytest.mark.parametrize("fmt", FORMATS)
def test_time_window_and_subset_of_sensors(tmp_path, fmt):
    path = write_recording(bag_path(tmp_path, fmt), make_frames(), fmt)
    with open_bag(path) as rec:
        got = list(rec.frames({"l": ("/velodyne_points", "lidar"), "r": ("/radar/detections",
                                                                          "radar")},
                              start_ns=T0 + 70_000_000, end_ns=T0 + 200_000_000))
    assert [(f.sensor, f.t_ns - T0) for f in got] == [
        ("r", 70_000_000), ("l", 100_000_000), ("r", 140_000_000)]


def test_float64_xyz_and_overwrite_is_atomic(tmp_path):
    rng = np.random.default_rng(8)
    cloud = PointCloudFrame("l", T0, rng.normal(size=(10, 3)), frame_id="f")
    path = write_recording(tmp_path / "a.bag", {"/p": [cloud]}, xyz_dtype=np.float64)
    with open_bag(path) as rec:
        (back,) = rec.frames({"l": ("/p", "lidar")})
    assert np.array_equal(back.points_xyz, cloud.points_xyz)
    # a failing write leaves the old bag untouched and no temporary files behind
    bad = PointCloudFrame("l", T0, [[1, 2, 3]], {"big": np.array([1], np.int64)})
    before = path.read_bytes()
    with pytest.raises(InputError, match=r"a\.bag: cannot write bag: topic /p: sensor 'l': "
                                         "field 'big' has dtype int64, which PointCloud2 "
                                         "cannot hold"):
        write_recording(path, {"/p": [cloud, bad]})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bag"]
    # a successful write replaces it (file and directory bags alike)
    write_recording(path, {"/q": [cloud]})
    with open_bag(path) as rec:
        assert list(rec.topics()) == ["/q"]
    d = write_recording(tmp_path / "d", {"/p": [cloud]}, "rosbag2-mcap")
    write_recording(d, {"/q": [cloud]}, "rosbag2-sqlite3")
    with open_bag(d) as rec:
        assert list(rec.topics()) == ["/q"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bag", "d"]


# -- stamps and order (bags written message by message) --------------------------------------


def write_raw(path: Path, fmt: str, messages, typestore=None) -> Path:
    """messages: (topic, msgtype, receive_ns, message); rosbags' writers used directly."""
    if fmt == "rosbag1":
        from rosbags.rosbag1 import Writer

        store = typestore or ROS1
        writer = Writer(path)
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        store = typestore or ROS2
        plugin = StoragePlugin.MCAP if fmt == "rosbag2-mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        serialize = store.serialize_cdr
    conns = {}
    with writer:
        for topic, msgtype, recv, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], recv, serialize(msg, msgtype))
    return path


def store_of(fmt):
    return ROS1 if fmt == "rosbag1" else ROS2


def cloud_msg(store, stamp_ns, x):
    frame = PointCloudFrame("s", stamp_ns, [[x, 0, 0]], frame_id="f")
    return encode_pointcloud2(frame, store)


@pytest.mark.parametrize("fmt", FORMATS)
def test_header_stamps_not_receive_times_and_zero_stamp_fallback(tmp_path, fmt):
    store = store_of(fmt)
    pc = "sensor_msgs/msg/PointCloud2"
    # /a arrives 0.5 s late, so bag order differs from stamp order; /c has no stamp
    messages = [
        ("/b", pc, T0 + 100, cloud_msg(store, T0 + 100, 1)),
        ("/a", pc, T0 + 500_000_000, cloud_msg(store, T0 + 50, 2)),
        ("/b", pc, T0 + 600_000_000, cloud_msg(store, T0 + 600_000_000, 3)),
        ("/c", pc, T0 + 700_000_000, cloud_msg(store, 0, 4)),
        ("/a", pc, T0 + 1_100_000_000, cloud_msg(store, T0 + 550_000_000, 5)),
    ]
    path = write_raw(bag_path(tmp_path, fmt), fmt, messages)
    with open_bag(path) as rec:
        got = list(rec.frames({"a": ("/a", "lidar"), "b": ("/b", "lidar"), "c": ("/c", "lidar")}))
    assert [(f.sensor, f.t_ns - T0, f.points_xyz[0, 0]) for f in got] == [
        ("a", 50, 2), ("b", 100, 1), ("a", 550_000_000, 5), ("b", 600_000_000, 3),
        ("c", 700_000_000, 4)]


def test_ros2_bag_without_embedded_definitions_uses_humble(tmp_path):
    path = write_recording(tmp_path / "old", make_frames(), "rosbag2-sqlite3")
    db = next(path.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    with open_bag(path) as rec:
        frames = list(rec.frames({"lidar": ("/velodyne_points", "lidar")}))
        assert rec.camera_info("/camera/camera_info").width == 8
    assert len(frames) == 3


CUSTOM = "float64 range\nfloat64 azimuth\nfloat32 rcs\n"


@pytest.mark.parametrize("fmt", FORMATS)
def test_custom_types_are_read_from_the_bag_definitions(tmp_path, fmt):
    store = get_typestore(Stores.ROS1_NOETIC if fmt == "rosbag1" else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(CUSTOM, "my_radar/msg/Target"))
    msg = store.types["my_radar/msg/Target"](range=5.0, azimuth=0.1, rcs=3.0)
    path = write_raw(bag_path(tmp_path, fmt), fmt, [("/t", "my_radar/msg/Target", T0, msg)],
                     typestore=store)
    with open_bag(path) as rec:
        assert rec.topics() == {"/t": "my_radar/msg/Target"}
        with pytest.raises(InputError, match=r"topic /t \(sensor 'r'\) has type "
                                             "my_radar/msg/Target; expected sensor_msgs/msg/"
                                             "PointCloud2, sensor_msgs/msg/Image or"):
            list(rec.frames({"r": ("/t", "radar")}))


# -- bag errors ------------------------------------------------------------------------------


def test_not_a_bag(tmp_path):
    with pytest.raises(InputError, match=r"missing\.bag: bag not found"):
        open_bag(tmp_path / "missing.bag")
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"this is not a bag at all")
    with pytest.raises(InputError, match=r"junk\.bag is not a ROS1 or ROS2 bag: "):
        open_bag(junk)
    (tmp_path / "dir").mkdir()
    with pytest.raises(InputError, match=r"dir is not a ROS1 or ROS2 bag: directory has no "
                                         "metadata.yaml"):
        open_bag(tmp_path / "dir")
    renamed = tmp_path / "rec.bagfile"
    renamed.write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    with pytest.raises(InputError, match=r"rec\.bagfile is not a ROS1 or ROS2 bag: it looks "
                                         r"like a ROS1 bag; name it \*\.bag"):
        open_bag(renamed)
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    with pytest.raises(InputError, match=r"meta is not a ROS1 or ROS2 bag: "):
        open_bag(tmp_path / "meta" / "metadata.yaml")


def test_corrupt_bag(tmp_path):
    rng = np.random.default_rng(9)
    clouds = [PointCloudFrame("l", T0 + k, f32(rng.normal(size=(2000, 3)))) for k in range(5)]
    path = write_recording(tmp_path / "c.bag", {"/p": clouds})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"c\.bag (is not a ROS1 or ROS2 bag|: cannot read)"):
        with open_bag(path) as rec:
            list(rec.frames({"l": ("/p", "lidar")}))


def test_topic_and_kind_errors(tmp_path):
    path = write_recording(tmp_path / "r.bag", make_frames())
    with open_bag(path) as rec:
        with pytest.raises(InputError, match=r"r\.bag: topic /x not in bag; topics: "
                                             r"\['/camera/camera_info', '/camera/image_raw'"):
            list(rec.frames({"lidar": ("/x", "lidar")}))
        with pytest.raises(InputError, match="topic /x not in bag"):
            rec.count("/x")
        with pytest.raises(InputError, match=r"topic /camera/camera_info \(sensor 'c'\) carries "
                                             r"CameraInfo, not frames; read it with camera_info"):
            list(rec.frames({"c": ("/camera/camera_info", "camera")}))
        with pytest.raises(InputError, match=r"topic /camera/image_raw carries images, but "
                                             "sensor 'l' is a lidar"):
            list(rec.frames({"l": ("/camera/image_raw", "lidar")}))
        with pytest.raises(InputError, match=r"r\.bag: /velodyne_points: radar point cloud has "
                                             r"fields \['x', 'y', 'z', 'intensity', 'ring', "
                                             r"'time'\], expected an RCS field \(rcs or RCS or "
                                             r"rcs0\)"):
            list(rec.frames({"r": ("/velodyne_points", "radar")}))
        with pytest.raises(InputError, match="sensor 'l': unknown sensor kind 'sonar'"):
            list(rec.frames({"l": ("/velodyne_points", "sonar")}))
        with pytest.raises(InputError, match=r"sensor 'l': expected \(topic, kind\)"):
            list(rec.frames({"l": "/velodyne_points"}))
        with pytest.raises(InputError, match="topic /velodyne_points is given for sensors 'a' "
                                             "and 'b'"):
            list(rec.frames({"a": ("/velodyne_points", "lidar"),
                             "b": ("/velodyne_points", "lidar")}))
        with pytest.raises(InputError, match=r"topic /velodyne_points has type sensor_msgs/msg/"
                                             "PointCloud2, expected sensor_msgs/msg/CameraInfo"):
            rec.camera_info("/velodyne_points")
        radar = list(rec.frames({"r": ("/radar/detections", "radar")}, ))
        assert len(radar) == 3
    with pytest.raises(InputError, match=r"r\.bag: recording is closed"):
        rec.topics()


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2-mcap"])
def test_message_content_errors(tmp_path, fmt):
    store = store_of(fmt)
    header = make_header(store, T0, "f")
    no_xyz = store.types["sensor_msgs/msg/PointCloud2"](
        header=header, height=1, width=1,
        fields=[store.types["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7,
                                                           count=1)
                for k, n in enumerate("abc")],
        is_bigendian=False, point_step=12, row_step=12, data=np.zeros(12, np.uint8),
        is_dense=True)
    mono16 = store.types["sensor_msgs/msg/Image"](
        header=header, height=2, width=2, encoding="mono16", is_bigendian=0, step=4,
        data=np.zeros(8, np.uint8))
    bad_jpeg = store.types["sensor_msgs/msg/CompressedImage"](
        header=header, format="jpeg", data=np.frombuffer(b"not a jpeg", np.uint8))
    path = write_raw(bag_path(tmp_path, fmt), fmt, [
        ("/p", "sensor_msgs/msg/PointCloud2", T0, no_xyz),
        ("/i", "sensor_msgs/msg/Image", T0, mono16),
        ("/j", "sensor_msgs/msg/CompressedImage", T0, bad_jpeg),
    ])
    with open_bag(path) as rec:
        with pytest.raises(InputError, match=r": /p: point cloud has fields \['a', 'b', 'c'\], "
                                             "expected x, y, z"):
            list(rec.frames({"l": ("/p", "lidar")}))
        with pytest.raises(InputError, match=r": /i: unsupported image encoding 'mono16' "
                                             r"\(supported: mono8, bgr8, rgb8"):
            list(rec.frames({"c": ("/i", "camera")}))
        with pytest.raises(InputError, match=r": /j \(jpeg\): cannot decode image"):
            list(rec.frames({"c": ("/j", "camera")}))
        with pytest.raises(InputError, match="topic /p has no messages|has type"):
            rec.camera_info("/p")


def test_write_errors(tmp_path):
    cloud = PointCloudFrame("l", T0, [[1, 2, 3]])
    with pytest.raises(InputError, match="unknown bag format 'rosbag3' \\(expected one of "
                                         "rosbag1, rosbag2-sqlite3, rosbag2-mcap\\)"):
        write_recording(tmp_path / "a.bag", {"/p": [cloud]}, "rosbag3")
    with pytest.raises(InputError, match=r"a\.db: a rosbag1 file must end in \.bag"):
        write_recording(tmp_path / "a.db", {"/p": [cloud]})
    with pytest.raises(InputError, match=r"a\.bag: a ROS2 bag is a directory"):
        write_recording(tmp_path / "a.bag", {"/p": [cloud]}, "rosbag2-mcap")
    img = ImageFrame("c", T0, np.zeros((2, 2), np.uint8))
    with pytest.raises(InputError, match=r"topic /p mixes message types"):
        write_recording(tmp_path / "a.bag", {"/p": [cloud, img]})
    stereo = StereoFrame("s", T0, np.zeros((2, 2), np.uint8), np.zeros((2, 2), np.uint8))
    with pytest.raises(InputError, match="topic /s: cannot write StereoFrame to a bag"):
        write_recording(tmp_path / "a.bag", {"/s": [stereo]})
    with pytest.raises(InputError, match="topic 'p' must start with '/'"):
        write_recording(tmp_path / "a.bag", {"p": [cloud]})
    with pytest.raises(InputError, match=r"topic /p: negative time -1 ns"):
        write_recording(tmp_path / "a.bag", {"/p": [PointCloudFrame("l", -1, [[1, 2, 3]])]})
    assert list(tmp_path.iterdir()) == []


# -- PointCloud2 layouts ---------------------------------------------------------------------


def pointfield(store, name, offset, datatype, count=1):
    return store.types["sensor_msgs/msg/PointField"](name=name, offset=offset, datatype=datatype,
                                                     count=count)


@pytest.mark.parametrize("store", [ROS1, ROS2], ids=["ros1", "ros2"])
@pytest.mark.parametrize("bigendian", [False, True])
def test_pointcloud2_unusual_layout(store, bigendian):
    """intensity first, padding, float64 xyz, uint16 ring, a count-2 field, padded rows,
    organised 2 x 3, any byte order - and the same after a serialize/deserialize cycle."""
    rng = np.random.default_rng(11)
    o = ">" if bigendian else "<"
    rec = np.dtype({"names": ["intensity", "x", "y", "z", "ring", "vel"],
                    "formats": [o + "f4", o + "f8", o + "f8", o + "f8", o + "u2", (o + "i2", 2)],
                    "offsets": [0, 8, 16, 24, 34, 36], "itemsize": 48})
    h, w = 2, 3
    table = np.zeros(h * w, rec)
    for name in ("intensity", "x", "y", "z"):
        table[name] = rng.normal(size=h * w)
    table["x"][4] = np.nan
    table["ring"] = rng.integers(0, 65535, h * w)
    table["vel"] = rng.integers(-300, 300, (h * w, 2))
    row_step = w * 48 + 5
    data = np.zeros(h * row_step, np.uint8)
    raw = np.frombuffer(table.tobytes(), np.uint8).reshape(h, w * 48)
    for r in range(h):
        data[r * row_step: r * row_step + w * 48] = raw[r]
    msg = store.types["sensor_msgs/msg/PointCloud2"](
        header=make_header(store, T0 + 5, "os_sensor"), height=h, width=w,
        fields=[pointfield(store, "intensity", 0, 7), pointfield(store, "x", 8, 8),
                pointfield(store, "y", 16, 8), pointfield(store, "z", 24, 8),
                pointfield(store, "ring", 34, 4), pointfield(store, "vel", 36, 3, 2)],
        is_bigendian=bigendian, point_step=48, row_step=row_step, data=data, is_dense=False)
    typ = "sensor_msgs/msg/PointCloud2"
    if store is ROS1:
        again = store.deserialize_ros1(store.serialize_ros1(msg, typ), typ)
    else:
        again = store.deserialize_cdr(store.serialize_cdr(msg, typ), typ)
    for m in (msg, again):
        cloud = decode_pointcloud2(m, "lidar")
        assert cloud.t_ns == T0 + 5 and cloud.frame_id == "os_sensor"
        assert cloud.organized_shape == (2, 3)
        xyz = np.stack([table["x"], table["y"], table["z"]], 1).astype(float)
        assert np.array_equal(cloud.points_xyz, xyz, equal_nan=True)
        assert list(cloud.fields) == ["intensity", "ring", "vel_0", "vel_1"]
        assert cloud.fields["ring"].dtype == np.uint16
        assert np.array_equal(cloud.fields["ring"], table["ring"])
        assert np.array_equal(cloud.fields["intensity"], table["intensity"])
        assert np.array_equal(cloud.fields["vel_1"], table["vel"][:, 1])
        dense = decode_pointcloud2(m, "lidar", t_ns=1, remove_nan=True)
        assert len(dense) == 5 and dense.organized_shape is None and dense.t_ns == 1
        assert np.array_equal(dense.fields["ring"], np.delete(table["ring"], 4))


@pytest.mark.parametrize("store", [ROS1, ROS2], ids=["ros1", "ros2"])
def test_pointcloud2_encode_decode_all_datatypes(store):
    rng = np.random.default_rng(12)
    fields = {name: rng.integers(lo, hi, 7).astype(dt) for name, dt, lo, hi in [
        ("i8", np.int8, -128, 127), ("u8", np.uint8, 0, 255), ("i16", np.int16, -3000, 3000),
        ("u16", np.uint16, 0, 65535), ("i32", np.int32, -(2**31), 2**31 - 1),
        ("u32", np.uint32, 0, 2**32 - 1)]}
    fields["f32"] = rng.normal(size=7).astype(np.float32)
    fields["f64"] = rng.normal(size=7)
    fields["ok"] = np.array([True, False] * 3 + [True])
    frame = PointCloudFrame("l", T0, f32(rng.normal(size=(7, 3))), fields, frame_id="x")
    msg = encode_pointcloud2(frame, store)
    assert [f.datatype for f in msg.fields] == [7, 7, 7, 1, 2, 3, 4, 5, 6, 7, 8, 2]
    assert msg.point_step == 3 * 4 + 1 + 1 + 2 + 2 + 4 + 4 + 4 + 8 + 1 and msg.is_dense
    back = decode_pointcloud2(msg, "l")
    for k, v in fields.items():
        want = v.astype(np.uint8) if v.dtype == np.bool_ else v
        assert back.fields[k].dtype == want.dtype and np.array_equal(back.fields[k], want)
    assert np.array_equal(back.points_xyz, frame.points_xyz)


def test_pointcloud2_empty_and_count_zero():
    empty = encode_pointcloud2(PointCloudFrame("l", T0, np.zeros((0, 3)),
                                               {"rcs": np.zeros(0, np.float32)}), ROS2)
    back = decode_pointcloud2(empty)
    assert len(back) == 0 and back.fields["rcs"].dtype == np.float32
    msg = encode_pointcloud2(PointCloudFrame("l", T0, [[1, 2, 3]]), ROS2)
    for f in msg.fields:
        f.count = 0  # some drivers leave count at 0
    assert decode_pointcloud2(msg).points_xyz.tolist() == [[1, 2, 3]]


def layout_msg(**changes):
    msg = encode_pointcloud2(PointCloudFrame("l", T0, [[1, 2, 3], [4, 5, 6]],
                                             {"i": np.array([1, 2], np.float32)}), ROS2)
    for key, value in changes.items():
        setattr(msg, key, value)
    return msg


@pytest.mark.parametrize("changes, match", [
    ({"data": np.zeros(20, np.uint8)},
     r"src: truncated point cloud: 1 x 2 points of 16 bytes \(row_step 32\) need 32 bytes, "
     "got 20"),
    ({"row_step": 20}, "src: row_step 20 is less than width x point_step = 2 x 16"),
    ({"point_step": 10}, r"src: field 'z' \(4 bytes at offset 8\) does not fit in point_step 10"),
])
def test_pointcloud2_layout_errors(changes, match):
    with pytest.raises(InputError, match=match):
        decode_pointcloud2(layout_msg(**changes), source="src")


def test_pointcloud2_field_errors():
    msg = layout_msg()
    msg.fields[3].datatype = 9
    with pytest.raises(InputError, match="src: field 'i' has unknown datatype 9"):
        decode_pointcloud2(msg, source="src")
    msg = layout_msg()
    msg.fields[3].name = "x"
    with pytest.raises(InputError, match="src: field 'x' appears twice"):
        decode_pointcloud2(msg, source="src")
    msg = layout_msg()
    msg.fields[0].count = 2
    with pytest.raises(InputError, match="field 'x' .*does not fit|field 'x' has count 2"):
        decode_pointcloud2(msg, source="src")
    msg = layout_msg()
    msg.fields[0].name = "X"
    with pytest.raises(InputError, match=r"point cloud has fields \['X', 'y', 'z', 'i'\], "
                                         "expected x, y, z"):
        decode_pointcloud2(msg, source="src")
    with pytest.raises(InputError, match="xyz_dtype must be float32 or float64"):
        encode_pointcloud2(PointCloudFrame("l", 0, [[1, 2, 3]]), ROS2, xyz_dtype=np.int32)
    with pytest.raises(InputError, match="negative time"):
        make_header(ROS2, -5, "f")


# -- image messages --------------------------------------------------------------------------


@pytest.mark.parametrize("encoding, channels", [("rgb8", 3), ("bgra8", 4), ("rgba8", 4),
                                                ("mono8", 1), ("8UC3", 3)])
def test_image_encodings_and_row_padding(encoding, channels):
    rng = np.random.default_rng(13)
    h, w, step = 3, 4, 4 * channels + 3
    pixels = rng.integers(0, 256, (h, w, channels), dtype=np.uint8)
    data = np.zeros((h, step), np.uint8)
    data[:, : w * channels] = pixels.reshape(h, -1)
    msg = ROS2.types["sensor_msgs/msg/Image"](
        header=make_header(ROS2, T0, "cam"), height=h, width=w, encoding=encoding,
        is_bigendian=0, step=step, data=data.reshape(-1))
    frame = decode_image_msg(msg, "c")
    expected = {"rgb8": pixels[:, :, ::-1], "bgra8": pixels[:, :, :3],
                "rgba8": pixels[:, :, 2::-1], "mono8": pixels[:, :, 0],
                "8UC3": pixels}[encoding]
    assert np.array_equal(frame.image, expected) and frame.t_ns == T0
    msg.data = msg.data[:-5]
    with pytest.raises(InputError, match="img: truncated image: 3 rows"):
        decode_image_msg(msg, "c", source="img")
    msg.step = 1
    with pytest.raises(InputError, match="img: image step 1 is less than width x channels"):
        decode_image_msg(msg, "c", source="img")


def test_compressed_jpeg_and_depth_refused():
    import cv2

    img = np.full((8, 8, 3), 120, np.uint8)
    ok, buf = cv2.imencode(".jpg", img)
    msg = ROS1.types["sensor_msgs/msg/CompressedImage"](
        header=make_header(ROS1, T0, "cam"), format="rgb8; jpeg compressed bgr8",
        data=buf.reshape(-1))
    frame = decode_compressed_image_msg(msg, "c")
    assert frame.image.shape == (8, 8, 3) and np.abs(frame.image.astype(int) - 120).max() <= 2
    msg.format = "16UC1; compressedDepth"
    with pytest.raises(InputError, match=r"unsupported compressed image format '16UC1; "
                                         r"compressedDepth' \(depth\)"):
        decode_compressed_image_msg(msg, "c")


def test_camera_info_validates_shapes():
    with pytest.raises(InputError, match="camera info 'cam': K needs 9 values, got 4"):
        CameraInfo(4, 3, [1, 2, 3, 4], [], frame_id="cam")
