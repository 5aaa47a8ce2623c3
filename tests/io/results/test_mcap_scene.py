"""The Foxglove verification scene (``rigcal export --format mcap``), read back with the ``mcap``
reader and Foxglove's protobuf schemas (``foxglove-schemas-protobuf``), independently of the
SDK that wrote it: every message must decode with the schema in the file and with Foxglove's
published one, re-encode to the same bytes, and hold valid values."""

from __future__ import annotations

import dataclasses
import importlib
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import write_dataset
from rigcal.io.recordings.bag import write_recording
from rigcal.io.results.calibration import write_results
from rigcal.io.results.mcap_scene import (
    DETECTION_TOPIC,
    RED_AT_RMSE,
    RESIDUAL_TOPIC,
    TF_TOPIC,
    error_colour,
    radar_arc,
)
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.recording import RadarFrame
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

mcap_reader = pytest.importorskip("mcap.reader")
mcap_protobuf = pytest.importorskip("mcap_protobuf.decoder")
pytest.importorskip("foxglove_schemas_protobuf")
pytest.importorskip("foxglove")

NS = 1_000_000_000


# --------------------------------------------------------------------------------------------
# reading a scene back, checking every message


def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _finite(*values) -> bool:
    return all(math.isfinite(v) for v in values)


def _check_colour(c) -> None:
    assert all(0.0 <= v <= 1.0 for v in (c.r, c.g, c.b, c.a)) and c.a > 0


def _check_message(name: str, msg) -> None:
    """What Foxglove needs of each schema's values (beyond decoding)."""
    if name == "FrameTransforms":
        for t in msg.transforms:
            q = t.rotation
            assert t.parent_frame_id and t.child_frame_id and t.parent_frame_id != t.child_frame_id
            assert abs(math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2) - 1) < 1e-12
            assert _finite(t.translation.x, t.translation.y, t.translation.z)
    elif name == "SceneUpdate":
        assert msg.entities
        for e in msg.entities:
            assert e.frame_id and e.id and e.timestamp.nanos < NS
            for s in e.spheres:
                assert _finite(s.pose.position.x, s.pose.position.y, s.pose.position.z) and s.size.x > 0
                _check_colour(s.color)
            for ln in e.lines:
                assert len(ln.points) >= 2 and ln.thickness > 0
                assert all(_finite(p.x, p.y, p.z) for p in ln.points)
                if ln.type == 2:  # LINE_LIST: pairs of points
                    assert len(ln.points) % 2 == 0
                _check_colour(ln.color)
    elif name == "PointCloud":
        assert msg.frame_id and msg.point_stride >= 4 * len(msg.fields)
        assert len(msg.data) % msg.point_stride == 0
        assert [f.name for f in msg.fields[:3]] == ["x", "y", "z"]
        assert all(f.offset + 4 <= msg.point_stride for f in msg.fields)
    elif name == "RawImage":
        assert msg.frame_id and msg.encoding in ("mono8", "bgr8")
        assert msg.step == msg.width * (1 if msg.encoding == "mono8" else 3)
        assert len(msg.data) == msg.step * msg.height
    else:
        raise AssertionError(f"unexpected schema {name}")


def read_scene(path: Path) -> dict:
    """{topic: [(log_time, decoded message)]}, metadata records; fails on any invalid message."""
    from foxglove_schemas_protobuf import __name__ as schemas_package  # noqa: F401

    messages: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[mcap_protobuf.DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            assert schema.name.startswith("foxglove.")
            name = schema.name.split(".", 1)[1]
            published = getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
            ours = published.FromString(message.data)
            assert ours.SerializeToString() == message.data, f"{channel.topic}: not a valid {schema.name}"
            assert decoded.SerializeToString() == message.data
            _check_message(name, ours)
            messages.setdefault(channel.topic, []).append((message.log_time, ours))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    frames = {TF_TOPIC}  # every frame an entity or cloud names is in the frame tree
    tree = {t.child_frame_id for _, m in messages[TF_TOPIC] for t in m.transforms} | {
        t.parent_frame_id for _, m in messages[TF_TOPIC] for t in m.transforms}
    for topic, items in messages.items():
        if topic in frames:
            continue
        for _, m in items:
            ids = [e.frame_id for e in m.entities] if hasattr(m, "entities") else [m.frame_id]
            assert set(ids) <= tree, (topic, ids, tree)
    return {"messages": messages, "metadata": metadata}


def _transforms(scene) -> dict[tuple[str, str], np.ndarray]:
    out = {}
    for _, m in scene["messages"][TF_TOPIC]:
        for t in m.transforms:
            T = np.eye(4)
            T[:3, :3] = _quat_matrix(t.rotation)
            T[:3, 3] = (t.translation.x, t.translation.y, t.translation.z)
            out[(t.parent_frame_id, t.child_frame_id)] = T
    return out


def _meta(entity) -> dict[str, str]:
    return {kv.key: kv.value for kv in entity.metadata}


# --------------------------------------------------------------------------------------------
# a calibrated rig and its detections


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    rng = np.random.default_rng(11)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 10, min_fraction=1.0), rng=rng)
    missed = []  # a board the camera missed
    for sensor in sim.dataset.sensors:
        if sensor.name == "camera1":
            points = np.array(sensor.points)
            points[3] = np.nan
            sensor = dataclasses.replace(sensor, points=points)
        missed.append(sensor)
    dataset = dataclasses.replace(sim.dataset, sensors=tuple(missed))
    result = calibrate(dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=0))
    tmp = tmp_path_factory.mktemp("scene")
    write_results(result, tmp / "results")
    manifest = write_dataset(dataset, tmp / "detections")
    return result, dataset, tmp / "results" / "calibration.yaml", manifest


def _export(tmp_path, calibration, *extra) -> Path:
    out = tmp_path / "scene.mcap"
    assert run(["export", str(calibration), "--format", "mcap", *map(str, extra), "--out", str(out)]) == 0
    return out


def test_the_frame_tree_equals_calibration_yaml(tmp_path, calibrated):
    result, _, calibration, _ = calibrated
    scene = read_scene(_export(tmp_path, calibration))
    data = yaml.safe_load(calibration.read_text())
    parent = data["sensors"][data["reference"]]["frame_id"]
    got = _transforms(scene)
    expected = {(parent, s["frame_id"]): np.array(s["T_reference_sensor"]) for s in data["sensors"].values()
                if s["frame_id"] != parent}
    assert set(got) == set(expected) and len(got) == len(result.sensors) - 1
    for key, T in expected.items():
        np.testing.assert_allclose(got[key], T, rtol=0, atol=1e-9, err_msg=str(key))
    assert [t for t, _ in scene["messages"][TF_TOPIC]] == [0]
    assert set(scene["messages"]) == {TF_TOPIC}  # no detections given: the tree alone
    assert scene["metadata"]["rigcal.calibration"]["text"] == calibration.read_text()
    assert scene["metadata"]["rigcal.verdict"]["status"] == result.verdict.status


def test_detections_and_residuals_of_every_board(tmp_path, calibrated):
    result, dataset, calibration, manifest = calibrated
    scene = read_scene(_export(tmp_path, calibration, "--detections", manifest))
    msgs = scene["messages"]
    data = yaml.safe_load(calibration.read_text())
    for s in dataset.sensors:
        items = msgs[DETECTION_TOPIC.format(s.name)]
        entities = [e for _, m in items for e in m.entities]
        assert len(entities) == int(s.valid.sum()) and all(t == 0 for t, _ in items)
        assert {e.frame_id for e in entities} == {data["sensors"][s.name]["frame_id"]}
        assert all(e.lifetime.seconds == 0 and e.lifetime.nanos == 0 for e in entities)  # for ever
        for e in entities:
            k = int(_meta(e)["board"])
            assert _meta(e)["sensor"] == s.name and s.valid[k]
            if s.kind.value in ("lidar", "camera"):  # four circle centres and the reflector
                centres = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                                    for p in e.spheres[:4]])
                np.testing.assert_allclose(centres, s.points[k], atol=1e-12)
                assert len(e.spheres) == 5 and not e.lines
            elif s.kind.value == "radar":  # the arc over the elevation field of view
                (arc,) = e.lines
                pts = np.array([[p.x, p.y, p.z] for p in arc.points])
                rng_m = np.linalg.norm(pts, axis=1)
                np.testing.assert_allclose(rng_m, np.linalg.norm(s.points[k]), rtol=1e-12)
                np.testing.assert_allclose(np.arctan2(pts[:, 1], pts[:, 0]), math.atan2(*s.points[k][::-1]),
                                           atol=1e-12)
                el = np.arcsin(pts[:, 2] / rng_m)
                assert el.min() == pytest.approx(-s.max_elevation_rad) and el.max() == pytest.approx(s.max_elevation_rad)
    residuals = [e for _, m in msgs[RESIDUAL_TOPIC] for e in m.entities]
    expected = {(pair, k) for pair, boards in result.per_board_m.items() for k in boards}
    assert {(_meta(e)["pair"], int(_meta(e)["board"])) for e in residuals} == expected
    rmse = result.rmse_m
    for e in residuals:
        meta = _meta(e)
        err = float(meta["error_m"])
        assert err == pytest.approx(result.per_board_m[meta["pair"]][int(meta["board"])], rel=1e-9, abs=1e-12)
        assert float(meta["red_at_m"]) == pytest.approx(RED_AT_RMSE * rmse[meta["pair"]], rel=1e-9)
        (line,) = e.lines
        c = line.color
        assert (c.r, c.g, c.b, c.a) == pytest.approx(error_colour(err, float(meta["red_at_m"])), abs=1e-6)
        # the segments' lengths are the anchors' errors: their RMS is the board's error
        p = np.array([[q.x, q.y, q.z] for q in line.points])
        lengths = np.linalg.norm(p[1::2] - p[0::2], axis=1)
        assert math.sqrt(np.mean(lengths**2)) == pytest.approx(err, rel=1e-6, abs=1e-9)
    assert len(msgs[RESIDUAL_TOPIC]) == dataset.num_boards  # one message per board


# --------------------------------------------------------------------------------------------
# with a recording


RADAR_RIG = """
sensors:
  - {name: radar1, kind: radar, topic: /r1, detector: {rcs_min_dbsm: 5}}
  - {name: radar2, kind: radar3d, topic: /r2, detector: {rcs_min_dbsm: 5}}
"""


def _radar_bag(path, placements=4):
    rng = np.random.default_rng(0)
    frames = {"/r1": [], "/r2": []}
    t = 1.0
    for k in range(placements):
        target = np.array([4.0 + k, (-1) ** k * 0.5, 0.1])
        for topic, sensor, rate, dim in (("/r1", "radar1", 13.0, 2), ("/r2", "radar2", 10.0, 3)):
            for i in range(int(3 * rate)):
                clutter = rng.uniform([1, -3, -0.5], [8, 3, 0.5], (5, 3))[:, :dim]
                pts = np.vstack([target[:dim] + rng.normal(0, 0.02, dim), clutter])
                r = np.concatenate([[15.0], rng.uniform(-10, 3, 5)])
                frames[topic].append(RadarFrame(sensor, int((t + i / rate) * NS), pts, r))
        t += 4.5
    return write_recording(path, frames, "rosbag1")


def test_a_recording_scene_has_its_clouds_and_detections_at_their_times(tmp_path, capsys):
    bag = _radar_bag(tmp_path / "rec.bag")
    rig = tmp_path / "rig.yaml"
    rig.write_text(RADAR_RIG)
    assert run(["calibrate", str(bag), "--rig", str(rig), "--out", str(tmp_path / "cal"), "--cv-folds", "0",
                "--force"]) in (0, 3)
    out = _export(tmp_path, tmp_path / "cal" / "calibration.yaml", "--recording", bag, "--rig", rig)
    assert "written to" in capsys.readouterr().out
    scene = read_scene(out)
    msgs = scene["messages"]
    first = min(t for items in msgs.values() for t, _ in items)
    assert [t for t, _ in msgs[TF_TOPIC]] == [first]  # the tree before everything else
    # four placements: each radar's cloud once per placement, from the middle of its window
    marks = {name: [(t, e) for t, m in msgs[DETECTION_TOPIC.format(name)] for e in m.entities]
             for name in ("radar1", "radar2")}
    assert [len(v) for v in marks.values()] == [4, 4]
    windows = sorted({(t, t + e.lifetime.seconds * NS + e.lifetime.nanos) for v in marks.values() for t, e in v})
    assert len(windows) == 4 and all(b > a for a, b in windows)
    for name in ("radar1", "radar2"):
        clouds = msgs[f"/rigcal/points/{name}"]
        assert len(clouds) == 4
        for (t, cloud), (start, end) in zip(clouds, windows):
            assert (start + end) // 2 <= t < end and cloud.timestamp.seconds * NS + cloud.timestamp.nanos == t
            assert len(cloud.data) // cloud.point_stride == 6  # the reflector and 5 clutter points
            assert [f.name for f in cloud.fields] == ["x", "y", "z", "rcs_dbsm"]
    for t, e in marks["radar2"]:  # entity and message share the placement's start
        assert e.timestamp.seconds * NS + e.timestamp.nanos == t


# --------------------------------------------------------------------------------------------
# failures and pieces


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("rigcal: error:") and "Traceback" not in err, err
    return lines[0]


def test_mcap_needs_out_and_recording_needs_rig(tmp_path, calibrated, capsys):
    _, _, calibration, manifest = calibrated
    assert run(["export", str(calibration), "--format", "mcap"]) == 1
    assert "--out FILE" in _one_line(capsys)
    assert run(["export", str(calibration), "--format", "mcap", "--recording", "x.bag", "--out",
                str(tmp_path / "s.mcap")]) == 1
    assert "--recording and --rig go together" in _one_line(capsys)
    assert run(["export", str(calibration), "--format", "yaml", "--detections", str(manifest)]) == 1
    assert "apply to --format mcap only" in _one_line(capsys)
    assert not (tmp_path / "s.mcap").exists()


def test_detections_of_a_sensor_the_calibration_does_not_have(tmp_path, calibrated, capsys):
    _, _, calibration, manifest = calibrated
    other = tmp_path / "calibration.yaml"
    data = yaml.safe_load(calibration.read_text())
    del data["sensors"]["radar1"]
    other.write_text(yaml.safe_dump(data))
    assert run(["export", str(other), "--format", "mcap", "--detections", str(manifest), "--out",
                str(tmp_path / "s.mcap")]) == 1
    line = _one_line(capsys)
    assert "['radar1']" in line and "not in the calibration" in line
    assert not (tmp_path / "s.mcap").exists()


def test_without_the_sdk_the_extra_is_named(monkeypatch, tmp_path, calibrated, capsys):
    import sys

    _, _, calibration, _ = calibrated
    monkeypatch.setitem(sys.modules, "foxglove", None)
    assert run(["export", str(calibration), "--format", "mcap", "--out", str(tmp_path / "s.mcap")]) == 1
    assert 'pip install "rigcal[mcap]"' in _one_line(capsys)


def test_radar_arc_and_error_colour():
    arc = radar_arc(np.array([3.0, 4.0]), math.radians(9), n=5)
    np.testing.assert_allclose(np.linalg.norm(arc, axis=1), 5.0)
    np.testing.assert_allclose(np.degrees(np.arcsin(arc[:, 2] / 5.0)), [-9, -4.5, 0, 4.5, 9], atol=1e-12)
    np.testing.assert_allclose(np.arctan2(arc[:, 1], arc[:, 0]), math.atan2(4, 3))
    assert error_colour(0.0, 1.0) == (0.0, 1.0, 0.0, 1.0)
    assert error_colour(0.5, 1.0) == (1.0, 1.0, 0.0, 1.0)
    assert error_colour(7.0, 1.0) == error_colour(float("nan"), 1.0) == (1.0, 0.0, 0.0, 1.0)


def test_clouds_and_images_as_foxglove_messages(tmp_path):
    """A scene's clouds (non-finite points dropped, every field float32) and images (mono8 and
    bgr8, row-major bytes) as Foxglove PointCloud and RawImage messages in their frames."""
    from rigcal.io.results.mcap_scene import Scene, SceneCloud, SceneImage, StaticTransform, write_scene

    rng = np.random.default_rng(2)
    pts = rng.normal(size=(50, 3))
    pts[7] = np.nan
    intensity = rng.uniform(0, 255, 50)
    mono = rng.integers(0, 255, (12, 16), dtype=np.uint8)
    bgr = rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)
    T = np.eye(4)
    T[:3, 3] = (0.5, -0.25, 1.0)
    scene = Scene(5 * NS, (StaticTransform("lidar1", "camera1", T), StaticTransform("lidar1", "camera2", T)),
                  clouds=(SceneCloud("lidar1", "lidar1", 6 * NS, pts, {"intensity": intensity}),),
                  images=(SceneImage("camera1", "camera1", 7 * NS, mono), SceneImage("camera2", "camera2", 8 * NS, bgr)))
    read = read_scene(write_scene(tmp_path / "s.mcap", scene))["messages"]
    ((t, cloud),) = read["/rigcal/points/lidar1"]
    assert t == 6 * NS and cloud.frame_id == "lidar1" and cloud.point_stride == 16
    data = np.frombuffer(cloud.data, dtype=np.dtype([(n, "<f4") for n in ("x", "y", "z", "intensity")]))
    keep = np.arange(50) != 7
    np.testing.assert_array_equal(data["x"], pts[keep, 0].astype(np.float32))
    np.testing.assert_array_equal(data["intensity"], intensity[keep].astype(np.float32))
    ((t1, m1),) = read["/rigcal/image/camera1"]
    ((t2, m2),) = read["/rigcal/image/camera2"]
    assert (t1, m1.encoding, m1.width, m1.height, m1.frame_id) == (7 * NS, "mono8", 16, 12, "camera1")
    assert m1.data == mono.tobytes() and (m2.encoding, m2.step, m2.data) == ("bgr8", 48, bgr.tobytes())
    assert [t for t, _ in read[TF_TOPIC]] == [5 * NS]


def test_a_bad_image_is_refused_with_its_topic(tmp_path):
    from rigcal.errors import InputError
    from rigcal.io.results.mcap_scene import Scene, SceneImage, write_scene

    scene = Scene(0, (), images=(SceneImage("camera1", "camera1", 0, np.zeros((4, 4), dtype=np.float32)),))
    with pytest.raises(InputError, match=r"image of 'camera1' must be uint8 \(H, W\) or \(H, W, 3\), got float32"):
        write_scene(tmp_path / "s.mcap", scene)
    assert not (tmp_path / "s.mcap").exists()


def test_one_frame_per_sensor_and_placement_from_the_middle_of_its_window(tmp_path):
    """What a recording scene takes from each placement: each sensor's first frame from the
    window's middle on - a mono image, a stereo pair's left image, a cloud, a 2D radar's
    detections on its plane - in the sensor's calibrated frame."""
    from rigcal.detect.placements import Placement
    from rigcal.io.config.rig_config import parse_rig_config
    from rigcal.io.results.mcap_scene import _recording_frames
    from rigcal.recording import ImageFrame, PointCloudFrame, StereoFrame

    rig = parse_rig_config("""
sensors:
  - {name: lidar1, kind: lidar, topic: /l}
  - {name: cam, kind: camera, topic: /c, camera_info_topic: /ci}
  - name: stereo
    kind: camera
    input: stereo_pair
    topic: /sl
    right_topic: /sr
    stereo: {fx: 100, fy: 100, cx: 50, cy: 40, baseline_m: 0.1}
  - {name: radar1, kind: radar, topic: /r}
""", str(tmp_path / "rig.yaml"), tmp_path)
    img = np.zeros((8, 10), dtype=np.uint8)
    stream = []
    for t in range(0, 100):
        stream += [PointCloudFrame("lidar1", t * NS, np.full((3, 3), t, dtype=float)),
                   ImageFrame("cam", t * NS, img + t),
                   ImageFrame("stereo#left", t * NS, img + 1), ImageFrame("stereo#right", t * NS, img + 2),
                   RadarFrame("radar1", t * NS, np.array([[float(t), 1.0]]), np.array([10.0]))]

    class Recording:
        asked: list = []

        def frames(self, topics, start_ns=None, end_ns=None):
            self.asked.append(dict(topics))
            return (f for f in stream if start_ns <= f.t_ns < end_ns and f.sensor in topics)

    frames = {"lidar1": "laser", "cam": "cam_optical", "stereo": "stereo_left", "radar1": "radar"}
    placements = (Placement(0, 10 * NS, 20 * NS), Placement(1, 40 * NS, 61 * NS))
    clouds, images = _recording_frames(Recording(), rig, placements, frames)
    assert "stereo#right" not in Recording.asked[0] and "stereo#left" in Recording.asked[0]
    assert [(c.topic_name, c.frame_id, c.t_ns) for c in clouds] == [
        ("lidar1", "laser", 15 * NS), ("radar1", "radar", 15 * NS), ("lidar1", "laser", 51 * NS),
        ("radar1", "radar", 51 * NS)]  # the second window's middle is 50.5 s
    np.testing.assert_array_equal(clouds[1].points_xyz, [[15.0, 1.0, 0.0]])  # on the radar's plane
    assert clouds[1].fields["rcs_dbsm"].tolist() == [10.0]
    assert [(i.topic_name, i.frame_id, i.t_ns, int(i.image[0, 0])) for i in images] == [
        ("cam", "cam_optical", 15 * NS, 15), ("stereo", "stereo_left", 15 * NS, 1),
        ("cam", "cam_optical", 51 * NS, 51), ("stereo", "stereo_left", 51 * NS, 1)]
