"""Raw data to calibration, end to end (issue: detectors, bags, automatic placements).

One simulated recording of the Prius-like raw rig (HDL-64E-like lidar, 1936x1216 stereo pair,
2D radar with clutter), written as real bags, detected, calibrated, compared with the truth.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.dataset import Dataset, SensorKind
from rigcal.demo import RAW_TOPICS, demo_raw_rig, detection_errors, frames_by_topic, raw_rig_yaml
from rigcal.detect.pipeline import run_detection
from rigcal.geometry.se3 import invert
from rigcal.io.recordings.bag import write_recording
from rigcal.io.recordings.open_any import open_any
from rigcal.io.config.rig_config import parse_rig_config
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.compare import errors_against_truth
from rigcal.recording import RadarFrame
from rigcal.sensors.radar import project_2d
from rigcal.sim.raw import raw_rig_placements, simulate_recording
from rigcal.targets.circle_board import board_centres, reflector_in_board

pytestmark = pytest.mark.slow  # long: run in CI (CI=1 make test) and make test-all

PLACEMENTS = 8


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    rng = np.random.default_rng(21)
    sensors = demo_raw_rig()
    placements = raw_rig_placements(rng, sensors, PLACEMENTS)
    rec = simulate_recording(sensors, placements, rng, dwell_s=2.5, transition_s=1.5)
    tmp = tmp_path_factory.mktemp("e2e")
    rig = parse_rig_config(raw_rig_yaml(sensors), str(tmp / "rig.yaml"), tmp)
    bag = write_recording(tmp / "rec.bag", frames_by_topic(rec.frames), "rosbag1")
    with open_any(bag) as r:
        run = run_detection(r, rig)
    return rec, rig, run, tmp


def test_placements_are_found_automatically(scenario):
    rec, _, run, _ = scenario
    assert len(run.placements) == PLACEMENTS
    truth_index = [rec.timeline.placement_at((p.start_ns + p.end_ns) // 2) for p in run.placements]
    assert truth_index == list(range(PLACEMENTS))
    for name in ("lidar1", "camera1", "radar1"):
        assert run.stats[name].placements == PLACEMENTS, (name, run.stats[name])


def test_detection_accuracy_against_the_truth(scenario):
    rec, _, run, _ = scenario
    err = detection_errors(run, rec)
    assert np.median(err["lidar1"]) <= 0.01 and np.median(err["camera1"]) <= 0.01
    assert np.median(err["radar1"]) <= 0.03


def test_radar_picks_the_reflector_among_clutter(scenario):
    rec, _, run, _ = scenario
    radar = next(s for s in rec.sensors if s.name == "radar1")
    T_rig_radar = radar.T_rig_sensor
    by_t = {r.t_ns: r for r in run.results["radar1"]}
    frames = [
        (f, T, k)
        for f, T, k in zip(rec.frames, rec.frame_T_rig_board, rec.frame_placement)
        if isinstance(f, RadarFrame) and k >= 0
    ]
    closer_clutter = 0
    right = 0
    for f, T_rig_board, _ in frames:
        T = invert(T_rig_radar) @ T_rig_board
        truth = project_2d((T[:3, :3] @ reflector_in_board(rec.board) + T[:3, 3])[None])[0]
        det = by_t[f.t_ns]
        right += det.ok and np.linalg.norm(det.points - truth) < 0.10
        closer_clutter += np.any(np.linalg.norm(f.points, axis=1) < np.linalg.norm(truth) - 0.5)
    assert right >= 0.95 * len(frames), (right, len(frames))
    assert closer_clutter > 0.3 * len(frames)  # "closest" alone would be fooled


def test_ros1_and_ros2_mcap_bags_give_the_same_detections(scenario):
    rec, rig, run, tmp = scenario
    # the ROS2 mcap bag of the same frames: lidar and radar (the stereo pair is the slow part
    # and goes through the same PointCloud2/Image decoding in both formats)
    keep = {RAW_TOPICS["lidar1"], RAW_TOPICS["radar1"]}
    topics = {t: f for t, f in frames_by_topic(rec.frames).items() if t in keep}
    small = dataclasses.replace(rig, sensors=tuple(s for s in rig.sensors if s.name != "camera1"))
    datasets = []
    for fmt, name in (("rosbag1", "small.bag"), ("rosbag2-mcap", "small_mcap")):
        bag = write_recording(tmp / name, topics, fmt)
        with open_any(bag) as r:
            datasets.append(run_detection(r, small).dataset)
    a, b = datasets
    assert a.num_boards == b.num_boards == PLACEMENTS
    for s in ("lidar1", "radar1"):
        np.testing.assert_array_equal(a.sensor(s).points, b.sensor(s).points)
        np.testing.assert_array_equal(a.sensor(s).points, run.dataset.sensor(s).points)


def _detection_level_dataset(rec, run, rng) -> Dataset:
    """The same placements measured by a detection-level simulation: the truth plus Gaussian
    noise of each sensor's measured detection error (RMS per coordinate)."""
    err = detection_errors(run, rec)
    out = []
    for spec in run.dataset.sensors:
        raw = next(s for s in rec.sensors if s.name == spec.name)
        sigma = float(np.sqrt(np.mean(err[spec.name] ** 2) / (2 if spec.kind == SensorKind.RADAR else 3)))
        pts = np.full(spec.points.shape, np.nan)
        for k, pl in enumerate(run.placements):
            kk = rec.timeline.placement_at((pl.start_ns + pl.end_ns) // 2)
            T = invert(raw.T_rig_sensor) @ rec.T_rig_board[kk]
            if spec.kind.is_point_cloud:
                truth = board_centres(rec.board) @ T[:3, :3].T + T[:3, 3]
            else:
                truth = project_2d((T[:3, :3] @ reflector_in_board(rec.board) + T[:3, 3])[None])[0]
            pts[k] = truth + rng.normal(0, sigma, truth.shape)
        out.append(dataclasses.replace(spec, points=pts))
    return dataclasses.replace(run.dataset, sensors=tuple(out))


def test_end_to_end_calibration_is_close_to_detection_level(scenario):
    rec, _, run, _ = scenario
    result = calibrate(run.dataset, CalibrationOptions(mode="fcpe"))
    e2e = errors_against_truth(result, rec.truth)
    levels = []
    for seed in range(5):
        ds = _detection_level_dataset(rec, run, np.random.default_rng(seed))
        levels.append(errors_against_truth(calibrate(ds, CalibrationOptions(mode="fcpe")), rec.truth))
    cam_level = np.median([lv["camera1"].translation_m for lv in levels])
    radar_level = np.median([lv["radar1"].in_plane_m for lv in levels])
    assert e2e["camera1"].translation_m <= 2.0 * cam_level + 0.005, (e2e["camera1"], cam_level)
    assert e2e["camera1"].rotation_deg <= 0.2
    assert e2e["radar1"].in_plane_m <= 2.0 * radar_level + 0.005, (e2e["radar1"], radar_level)
    # the radar's yaw follows its tilt, which only the field of view bounds: with 12 boards the
    # lowest-cost tilt may be ~8 deg off and the yaw 0.4 deg - inside what the result reports
    assert e2e["radar1"].yaw_deg <= 0.5
    from rigcal.study.board_coverage import judge_sensor

    T_true = invert(rec.truth[result.reference]) @ rec.truth["radar1"]
    assert judge_sensor(result, "radar1", T_true) == (True, True)


def test_the_foxglove_scene_of_a_camera_recording_has_its_images_in_the_optical_frames(scenario):
    """``export --format mcap --recording``'s scene on a recording with a stereo camera: one
    left image per placement, full size, in the frame the writers publish the camera's data in,
    at a time inside its placement; the lidar's and radar's clouds alike (read back with the
    ``mcap`` reader, every message re-encoded by Foxglove's published schemas)."""
    pytest.importorskip("foxglove")
    mcap_reader = pytest.importorskip("mcap.reader")
    mcap_protobuf = pytest.importorskip("mcap_protobuf.decoder")
    from rigcal.io.results.calibration import write_results
    from rigcal.io.results.calibration_files import read_calibration_transforms
    from rigcal.io.results.frames import plan_with_checks
    from rigcal.io.results.mcap_scene import IMAGE_TOPIC, POINTS_TOPIC, TF_TOPIC, build_scene, write_scene

    rec, rig, run, tmp = scenario
    result = calibrate(run.dataset, CalibrationOptions(mode="fcpe"))
    calibration = write_results(result, tmp / "cal")[0]
    plan, _ = plan_with_checks(read_calibration_transforms(calibration), None, None)
    measured = {s.frame_id: s.measured for s in (plan.reference, *plan.sensors)}
    with open_any(tmp / "rec.bag") as recording:
        scene = build_scene(calibration, plan.transforms, detection=run, recording=recording, rig=rig,
                            measured=measured)
    out = write_scene(tmp / "scene.mcap", scene)
    messages: dict[str, list] = {}
    with open(out, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[mcap_protobuf.DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert decoded.SerializeToString() == message.data, channel.topic
            messages.setdefault(channel.topic, []).append((message.log_time, schema.name, decoded))
    windows = [(p.start_ns, p.end_ns) for p in run.placements]
    assert len(windows) == PLACEMENTS
    tree = {t.child_frame_id for _, _, m in messages[TF_TOPIC] for t in m.transforms}
    cameras = [s.name for s in run.dataset.sensors if s.kind == SensorKind.CAMERA]
    assert cameras
    for name in cameras:
        images = messages[IMAGE_TOPIC.format(name)]
        assert len(images) == PLACEMENTS
        frame = measured[result.sensors[name].frame_id]
        for (t, schema, im), (start, end) in zip(images, windows):
            assert schema == "foxglove.RawImage" and start <= t <= end
            assert im.frame_id == frame and frame in tree
            assert (im.width, im.height) == (1936, 1216) and len(im.data) == im.step * im.height
            assert im.timestamp.seconds * 1_000_000_000 + im.timestamp.nanos == t
    for s in run.dataset.sensors:
        if s.kind != SensorKind.CAMERA:
            clouds = messages[POINTS_TOPIC.format(s.name)]
            assert len(clouds) == PLACEMENTS and all(schema == "foxglove.PointCloud" for _, schema, _ in clouds)
