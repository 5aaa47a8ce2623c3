from __future__ import annotations

import math

import pytest

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.io.config.rig_config import load_rig_config, parse_rig_config

GOOD = """
sensors:
  - {name: lidar1, kind: lidar, topic: /velodyne_points, frame_id: velodyne,
     detector: {radius_min_m: 0.06}}
  - {name: camera1, kind: camera, topic: /cam/image, intrinsics: cam.ini}
  - name: camera2
    kind: camera
    input: stereo_pair
    topic: /left
    right_topic: /right
    stereo: {fx: 1400, fy: 1400, cx: 968, cy: 608, baseline_m: 0.12}
  - {name: radar1, kind: radar, topic: /radar, elevation_fov_deg: 4.5,
     detector: {rcs_min_dbsm: 5}}
reference: lidar1
placements:
  stability: {tolerance_m: 0.02, min_frames: 5}
  windows_s: [[1.0, 2.5], [4, 6]]
"""


@pytest.fixture
def base(tmp_path):
    (tmp_path / "cam.ini").write_text("[image]\n")
    return tmp_path


def test_parses_every_field(base):
    rig = parse_rig_config(GOOD, "rig.yaml", base)
    assert [s.name for s in rig.sensors] == ["lidar1", "camera1", "camera2", "radar1"]
    lidar, cam, stereo, radar = rig.sensors
    assert lidar.kind == SensorKind.LIDAR and lidar.input == "cloud" and lidar.frame_id == "velodyne"
    assert dict(lidar.detector) == {"radius_min_m": 0.06}
    assert cam.input == "mono" and cam.intrinsics == base / "cam.ini"
    assert stereo.input == "stereo_pair" and stereo.right_topic == "/right"
    assert stereo.stereo["baseline_m"] == 0.12
    assert radar.max_elevation_rad == pytest.approx(math.radians(4.5))
    assert rig.reference == "lidar1"
    assert rig.stability.tolerance_m == 0.02 and rig.stability.min_frames == 5
    assert rig.windows_ns == ((1_000_000_000, 2_500_000_000), (4_000_000_000, 6_000_000_000))


def test_load_from_file(base):
    (base / "rig.yaml").write_text(GOOD)
    assert load_rig_config(base / "rig.yaml").source.endswith("rig.yaml")


@pytest.mark.parametrize(
    "text, match",
    [
        ("sensors: []", "non-empty list"),
        ("sensors:\n  - {name: l, kind: lidar}", "missing required key 'topic'"),
        ("sensors:\n  - {name: l, kind: sonar, topic: /x}", "unknown sensor kind 'sonar'"),
        ("sensors:\n  - {name: l, kind: lidar, topic: /x, colour: red}", "unknown key"),
        ("sensors:\n  - {name: c, kind: camera, topic: /x}", "needs intrinsics"),
        ("sensors:\n  - {name: c, kind: camera, topic: /x, intrinsics: nope.ini}", "file not found"),
        ("sensors:\n  - {name: c, kind: camera, input: stereo_pair, topic: /x}", "needs right_topic"),
        ("sensors:\n  - {name: c, kind: camera, input: stereo_pair, topic: /x, right_topic: /y}", "stereo"),
        ("sensors:\n  - {name: l, kind: lidar, input: mono, topic: /x}", "not an input of a lidar"),
        ("sensors:\n  - {name: r, kind: radar, topic: /x, elevation_fov_deg: 0}", "elevation_fov_deg"),
        ("sensors:\n  - {name: l, kind: lidar, topic: /x}\nreference: cam", "unknown sensor 'cam'"),
        ("sensors:\n  - {name: l, kind: lidar, topic: /x}\nplacements: {windows_s: [1, 2]}", "windows_s"),
        ("sensors:\n  - {name: l, kind: lidar, topic: /x}\nplacements: {stability: {speed: 1}}", "unknown key"),
        ("sensors: [\n", "invalid YAML"),
    ],
)
def test_bad_configuration_names_the_field(base, text, match):
    with pytest.raises(InputError, match=match):
        parse_rig_config(text, "rig.yaml", base)
