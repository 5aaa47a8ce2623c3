"""The detection pipeline over an in-memory recording (radar sensors: their detector is simple,
so this tests the plumbing: topics, progress, statistics, placements, dataset, errors)."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.detect.pipeline import run_detection
from rigcal.errors import InputError
from rigcal.io.config.rig_config import parse_rig_config
from rigcal.recording import RadarFrame

NS = 1_000_000_000
RIG = """
sensors:
  - {name: radar1, kind: radar, topic: /r1, detector: {rcs_min_dbsm: 5}}
  - {name: radar2, kind: radar3d, topic: /r2, detector: {rcs_min_dbsm: 5}}
"""


class FakeRecording:
    def __init__(self, frames_by_topic):
        self._frames = frames_by_topic

    def topics(self):
        return {t: "sensor_msgs/msg/PointCloud2" for t in self._frames}

    def count(self, topic):
        return len(self._frames[topic])

    def frames(self, sensor_topics):
        out = []
        for sensor, (topic, _kind) in sensor_topics.items():
            for t, pts, rcs in self._frames[topic]:
                out.append(RadarFrame(sensor, t, pts, rcs))
        return iter(sorted(out, key=lambda f: f.t_ns))


def _scenario(rng, placements=4, dwell=3.0, move=1.5):
    frames = {"/r1": [], "/r2": []}
    t = 0.0
    for k in range(placements):
        target = np.array([4.0 + k, (-1) ** k * 0.5, 0.1])
        for topic, rate, dim in (("/r1", 13.0, 2), ("/r2", 10.0, 3)):
            for i in range(int(dwell * rate)):
                clutter = rng.uniform([1, -3, -0.5], [8, 3, 0.5], (5, 3))[:, :dim]
                pts = np.vstack([target[:dim] + rng.normal(0, 0.02, dim), clutter])
                rcs = np.concatenate([[15.0], rng.uniform(-10, 3, 5)])
                frames[topic].append((int((t + i / rate) * NS), pts, rcs))
        t += dwell + move  # nothing is detected while the board moves
    return frames


def test_pipeline_finds_every_placement_and_counts(tmp_path):
    rig = parse_rig_config(RIG, "rig.yaml", tmp_path)
    rec = FakeRecording(_scenario(np.random.default_rng(0)))
    seen = []
    run = run_detection(rec, rig, progress=lambda d, t: seen.append((d, t)))
    assert len(run.placements) == 4 and run.dataset.num_boards == 4
    assert seen[-1][0] == seen[-1][1] == sum(len(v) for v in rec._frames.values())
    st = run.stats["radar1"]
    assert st.frames == len(rec._frames["/r1"]) and st.detections == st.frames and st.placements == 4
    pts = run.dataset.sensor("radar2").points
    assert np.allclose(pts[:, 0], [4, 5, 6, 7], atol=0.02)


def test_missing_topic_names_sensor_and_topics(tmp_path):
    rig = parse_rig_config(RIG.replace("/r2", "/nope"), "rig.yaml", tmp_path)
    rec = FakeRecording(_scenario(np.random.default_rng(0)))
    with pytest.raises(InputError, match=r"sensor 'radar2': topic /nope is not in the recording \(topics: /r1, /r2\)"):
        run_detection(rec, rig)


def test_board_never_found_is_a_clear_error(tmp_path):
    rig = parse_rig_config(RIG.replace("rcs_min_dbsm: 5", "rcs_min_dbsm: 50"), "rig.yaml", tmp_path)
    rec = FakeRecording(_scenario(np.random.default_rng(0), placements=2))
    with pytest.raises(InputError, match="no board placement found.*radar1: 0 detections in"):
        run_detection(rec, rig)


def test_unknown_detector_setting_is_refused(tmp_path):
    rig = parse_rig_config(RIG.replace("rcs_min_dbsm: 5}}\n  - {name: radar2", "colour: 5}}\n  - {name: radar2"), "rig.yaml", tmp_path)
    with pytest.raises(InputError, match=r"unknown detector setting\(s\) \['colour'\]"):
        run_detection(FakeRecording(_scenario(np.random.default_rng(0), placements=1)), rig)
