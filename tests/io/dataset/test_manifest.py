"""Dataset manifests (rig.yaml): loading, every error, write -> load round trips, real data."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rigcal.dataset import BoardGeometry, Dataset, SensorDetections, SensorKind
from rigcal.errors import InputError
from rigcal.io.dataset.detections_csv import format_detections_csv
from rigcal.io.dataset.manifest import (
    dataset_from_files,
    load_manifest,
    load_manifest_with_ignored,
    parse_manifest,
    write_dataset,
)

SHARED = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "tudelft_prius"

K = 5


def points(kind: SensorKind, num_boards: int = K, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.normal(scale=2.0, size=(num_boards,) + kind.point_shape)
    pts[2] = np.nan
    return pts


def write_csv(directory: Path, name: str, kind: SensorKind, num_boards: int = K) -> np.ndarray:
    pts = points(kind, num_boards, seed=len(name))
    (directory / name).write_text(format_detections_csv(pts, kind))
    return pts


ACC = """
/lidar_detector/lidar_pattern:
{lidar}
/radar_detector/radar_pattern:
{radar}
"""


def accumulator_text(num_boards: int = K) -> str:
    lidar = "".join(
        f"  - frame_id: velodyne\n    points: [{', '.join(f'{{x: {k}, y: {i}, z: 1}}' for i in range(4))}]\n"
        for k in range(num_boards)
    )
    radar = "".join(
        f"  - frame_id: radar_front\n    points: [{{x: {k}, y: 0.5, z: 9}}]\n" for k in range(num_boards)
    )
    return ACC.format(lidar=lidar.rstrip("\n"), radar=radar.rstrip("\n"))


@pytest.fixture
def rig(tmp_path: Path) -> Path:
    """A directory with detections for five sensors and a manifest using every feature."""
    write_csv(tmp_path, "lidar1.csv", SensorKind.LIDAR)
    (tmp_path / "cams").mkdir()
    write_csv(tmp_path / "cams", "camera1.csv", SensorKind.CAMERA)
    write_csv(tmp_path, "radar1.csv", SensorKind.RADAR)
    write_csv(tmp_path, "radar2.csv", SensorKind.RADAR3D)
    (tmp_path / "acc.yaml").write_text(accumulator_text())
    (tmp_path / "ignore.yaml").write_text("lidar1: [4, 5]\nradar1: {boards: [0]}\n")
    (tmp_path / "rig.yaml").write_text(
        """sensors:
  - {name: lidar1, kind: lidar, detections: lidar1.csv}
  - {name: camera1, kind: camera, detections: cams/camera1.csv, frame_id: left}
  - {name: radar1, kind: radar, detections: radar1.csv, elevation_fov_deg: 7.5}
  - {name: radar2, kind: radar3d, detections: radar2.csv}
  - {name: lidar2, kind: lidar, detections: acc.yaml, topic: /lidar_detector/lidar_pattern}
  - {name: radar3, kind: RADAR, detections: acc.yaml, topic: /radar_detector/radar_pattern, frame_id: r3}
reference: camera1
board: {spacing_m: 0.3, reflector_offset_m: 0.1}
ignore: ignore.yaml
"""
    )
    return tmp_path


def test_load_manifest_fields(rig):
    ds = load_manifest(rig / "rig.yaml")
    assert ds.names == ("lidar1", "camera1", "radar1", "radar2", "lidar2", "radar3")
    assert [s.kind for s in ds.sensors] == [
        SensorKind.LIDAR, SensorKind.CAMERA, SensorKind.RADAR, SensorKind.RADAR3D,
        SensorKind.LIDAR, SensorKind.RADAR,
    ]
    assert [s.frame_id for s in ds.sensors] == [
        "lidar1", "left", "radar1", "radar2", "velodyne", "r3",
    ]
    assert ds.sensor("radar1").max_elevation_rad == math.radians(7.5)
    assert ds.sensor("radar2").max_elevation_rad == math.radians(9.0)
    assert ds.board == BoardGeometry(spacing_m=0.3, reflector_offset_m=0.1)
    assert ds.reference == "camera1"
    assert ds.source == str(rig / "rig.yaml")
    assert ds.sensor("camera1").source == str(rig / "cams" / "camera1.csv")
    np.testing.assert_array_equal(
        ds.sensor("radar1").points, points(SensorKind.RADAR, seed=len("radar1.csv"))
    )
    np.testing.assert_array_equal(ds.sensor("radar3").points[:, 1], 0.5)  # x, y of the reflector
    assert ds.sensor("lidar2").points.shape == (K, 4, 3)
    # the ignore file is applied ...
    assert ds.sensor("lidar1").excluded == frozenset({1})
    assert ds.sensor("radar1").excluded == frozenset({0})
    # ... and load_manifest_with_ignored keeps it apart
    raw, ignored = load_manifest_with_ignored(rig)  # a directory means its rig.yaml
    assert ignored == {"lidar1": [1], "radar1": [0]}
    assert all(not s.excluded for s in raw.sensors)
    applied = raw.with_excluded(ignored)
    assert [s.excluded for s in applied.sensors] == [s.excluded for s in ds.sensors]


def test_parse_manifest_uses_source_and_base_dir(rig):
    text = "sensors:\n  - {name: a, kind: lidar, detections: lidar1.csv}\n  - {name: b, kind: radar, detections: radar1.csv}\n"
    ds = parse_manifest(text, "inline", rig)
    assert ds.source == "inline" and ds.reference is None and ds.board == BoardGeometry()
    assert ds.sensor("b").frame_id == "b"


def test_single_topic_accumulator_needs_no_topic(tmp_path):
    (tmp_path / "acc.yaml").write_text(
        "/only:\n" + "".join(f"  - {{frame_id: rad, points: [{{x: {k}, y: 1, z: 2}}]}}\n" for k in range(K))
    )
    write_csv(tmp_path, "l.csv", SensorKind.LIDAR)
    ds = parse_manifest(
        "sensors:\n  - {name: l, kind: lidar, detections: l.csv}\n"
        "  - {name: r, kind: radar3d, detections: acc.yaml}\n",
        "rig.yaml",
        tmp_path,
    )
    assert ds.sensor("r").frame_id == "rad"
    np.testing.assert_array_equal(ds.sensor("r").points[:, 2], 2.0)


def write_manifest(rig: Path, text: str) -> Path:
    path = rig / "m.yaml"
    path.write_text(text)
    return path


S_L = "  - {name: lidar1, kind: lidar, detections: lidar1.csv}\n"
S_R = "  - {name: radar1, kind: radar, detections: radar1.csv}\n"


@pytest.mark.parametrize(
    "text, message",
    [
        ("sensors: [\n", r"m\.yaml: line \d+, column \d+: invalid YAML"),
        ("", r"m\.yaml: empty manifest"),
        ("- a\n- b\n", r"m\.yaml: expected a mapping with a 'sensors' list at the top level, got a list"),
        ("reference: lidar1\n", r"m\.yaml: missing required key 'sensors'"),
        ("sensors: []\n", r"m\.yaml: sensors: expected a non-empty list"),
        ("sensors:\n" + S_L + S_R + "extra: 1\n", r"m\.yaml: unknown key\(s\) 'extra' \(allowed: sensors, reference, board, ignore\)"),
        ("sensors:\n" + S_L + "  - lidar2\n", r"m\.yaml: sensors\[1\]: expected a mapping with name, kind, detections, got a string"),
        ("sensors:\n" + S_L + "  - {kind: radar, detections: radar1.csv}\n", r"m\.yaml: sensors\[1\]: missing required key 'name'"),
        ("sensors:\n" + S_L + "  - {name: r, detections: radar1.csv}\n", r"sensors\[1\]: missing required key 'kind'"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar}\n", r"sensors\[1\]: missing required key 'detections'"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, fov: 3}\n", r"sensors\[1\]: unknown key\(s\) 'fov' \(allowed: name, kind, detections, frame_id, elevation_fov_deg, topic, prior\)"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, prior: {height_m: 1}}\n", r"sensors\[1\]\.prior: unknown direction 'height_m' \(expected one of: roll_deg, pitch_deg, yaw_deg, x_m, y_m, z_m\)"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, prior: {z_m: -1}}\n", r"sensors\[1\]\.prior\.z_m: expected a tolerance in m >= 0 \(0 holds it\), got -1"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, prior: {roll_deg: .inf}}\n", r"sensors\[1\]\.prior\.roll_deg: expected a tolerance in deg >= 0"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, prior: 0.01}\n", r"sensors\[1\]\.prior: expected a mapping of tolerances"),
        ("sensors:\n" + S_L + S_R + "  - {name: s, kind: sonar, detections: radar1.csv}\n", r"m\.yaml: sensors\[2\]\.kind: unknown sensor kind 'sonar' \(expected one of: lidar, camera, radar, radar3d\)$"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, elevation_fov_deg: -3}\n", r"sensors\[1\]\.elevation_fov_deg: expected a number of degrees in \(0, 90\] .* got -3"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, elevation_fov_deg: wide}\n", r"sensors\[1\]\.elevation_fov_deg: .* got 'wide'"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, elevation_fov_deg: null}\n", r"sensors\[1\]\.elevation_fov_deg: .* got None"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: nothere.csv}\n", r"m\.yaml: sensors\[1\]\.detections: .*nothere\.csv: detection CSV file not found"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.txt}\n", r"sensors\[1\]\.detections: 'radar1\.txt' must end in \.csv .* or \.yaml/\.yml"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, topic: /x}\n", r"sensors\[1\]\.topic: only accumulator YAML detections have topics"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: acc.yaml}\n", r"sensors\[1\]\.detections: .*acc\.yaml: 2 topics \(/lidar_detector/lidar_pattern, /radar_detector/radar_pattern\); say which one with 'topic'"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: acc.yaml, topic: /nope}\n", r"acc\.yaml: no topic '/nope' \(topics: "),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: acc.yaml, topic: /lidar_detector/lidar_pattern}\n", r"sensors\[1\]\.detections: .*a radar needs 1 point"),
        ("sensors:\n" + S_L + "  - {name: r, kind: radar, detections: lidar1.csv}\n", r"sensors\[1\]\.detections: .*lidar1\.csv: expected 2 rows \(x, y\) for a radar, got 3"),
        ("sensors:\n" + S_L + S_R + "  - {name: short, kind: radar, detections: short.csv}\n", r"m\.yaml: sensors have different numbers of board placements \(lidar1: 5, radar1: 5, short: 3\)"),
        ("sensors:\n" + S_L + S_R + "reference: camera9\n", r"m\.yaml: reference: unknown sensor 'camera9' \(sensors: lidar1, radar1\)"),
        ("sensors:\n" + S_L + S_L, r"m\.yaml: sensors\[1\]\.name: 'lidar1' is already used by sensors\[0\]"),
        ("sensors:\n" + S_L + "  - {name: a/b, kind: radar, detections: radar1.csv}\n", r"sensors\[1\]\.name: sensor name 'a/b' must not contain whitespace or path separators"),
        ("sensors:\n" + S_L + "  - {name: 7, kind: radar, detections: radar1.csv}\n", r"sensors\[1\]\.name: expected a non-empty string, got an integer 7"),
        ("sensors:\n" + S_L, r"m\.yaml: calibration needs at least two sensors, got 1"),
        ("sensors:\n" + S_L + S_R + "board: {spacing_m: -0.2}\n", r"m\.yaml: board\.spacing_m must be a positive number, got -0\.2"),
        ("sensors:\n" + S_L + S_R + "board: {spacing_m: big}\n", r"m\.yaml: board\.spacing_m: expected a number in metres, got a string 'big'"),
        ("sensors:\n" + S_L + S_R + "board: {side_m: 1}\n", r"m\.yaml: board: unknown key\(s\) 'side_m' \(allowed: spacing_m, reflector_offset_m, hole_diameter_m, width_m, height_m\)"),
        ("sensors:\n" + S_L + S_R + "board: [1]\n", r"m\.yaml: board: expected a mapping"),
        ("sensors:\n" + S_L + S_R + "ignore: missing.yaml\n", r"m\.yaml: ignore: .*missing\.yaml: ignore file not found"),
        ("sensors:\n" + S_L + S_R + "ignore: bad_ignore.yaml\n", r"m\.yaml: ignore: .*bad_ignore\.yaml: unknown sensor 'camera1' \(sensors: lidar1, radar1\)"),
    ],
)
def test_manifest_errors(rig, text, message):
    write_csv(rig, "short.csv", SensorKind.RADAR, num_boards=3)
    (rig / "bad_ignore.yaml").write_text("camera1: [0]\n")
    path = write_manifest(rig, text)
    with pytest.raises(InputError, match=message):
        load_manifest(path)


def test_unknown_kind_message_is_exactly_one_line(rig):
    text = "sensors:\n" + S_L + S_R + "  - {name: s, kind: sonar, detections: radar1.csv}\n"
    with pytest.raises(InputError) as info:
        parse_manifest(text, "rig.yaml", rig)
    assert str(info.value) == (
        "rig.yaml: sensors[2].kind: unknown sensor kind 'sonar' "
        "(expected one of: lidar, camera, radar, radar3d)"
    )


def test_missing_manifest(tmp_path):
    with pytest.raises(InputError, match=r"rig\.yaml: manifest not found"):
        load_manifest(tmp_path / "rig.yaml")
    with pytest.raises(InputError, match=r"rig\.yaml: manifest not found"):
        load_manifest(tmp_path)  # a directory without rig.yaml


def make_dataset() -> Dataset:
    rng = np.random.default_rng(7)
    lidar = rng.normal(size=(K, 4, 3))
    lidar[0, 1, 2] = np.nan  # a partially missing board survives as is
    radar = rng.normal(size=(K, 2)) * 1e-7
    radar[3] = np.nan
    return Dataset(
        sensors=(
            SensorDetections("lidar_top", SensorKind.LIDAR, lidar, frame_id="velodyne"),
            # large but within the readers' limit (rigcal.io.limits.MAX_ABS["m"] = 1e5 m)
            SensorDetections("cam", SensorKind.CAMERA, rng.normal(size=(K, 4, 3)) * 2e4),
            SensorDetections(
                "front radar".replace(" ", "_"), SensorKind.RADAR, radar,
                max_elevation_rad=0.1234567891234,
            ),
            SensorDetections("r3", SensorKind.RADAR3D, rng.normal(size=(K, 3)), frame_id="/radar/3d"),
        ),
        board=BoardGeometry(spacing_m=0.25, reflector_offset_m=0.0, hole_diameter_m=0.12,
                            width_m=1.2, height_m=1.4),
        reference="cam",
    )


def assert_same_dataset(a: Dataset, b: Dataset) -> None:
    assert a.names == b.names
    assert a.board == b.board
    assert a.reference == b.reference
    for s, t in zip(a.sensors, b.sensors):
        assert (s.kind, s.frame_id, s.max_elevation_rad) == (t.kind, t.frame_id, t.max_elevation_rad)
        np.testing.assert_array_equal(s.points, t.points)


def test_write_dataset_round_trip(tmp_path):
    ds = make_dataset()
    manifest = write_dataset(ds, tmp_path / "out")
    assert manifest == tmp_path / "out" / "rig.yaml"
    assert sorted(p.name for p in manifest.parent.iterdir()) == [
        ".rigcal-output", "cam.csv", "front_radar.csv", "lidar_top.csv", "r3.csv", "rig.yaml",
    ]  # the marker lets a later run replace this folder
    back = load_manifest(manifest)
    assert_same_dataset(ds, back)
    assert back.source == str(manifest)
    # writing what was read gives the same files
    again = write_dataset(back, tmp_path / "again")
    assert again.read_text() == manifest.read_text()


def test_manifest_prior_is_read_and_written_back(tmp_path, rig):
    text = "sensors:\n" + S_L + "  - {name: r, kind: radar, detections: radar1.csv, prior: {pitch_deg: 0.5, z_m: 0.01}}\n"
    ds = load_manifest(write_manifest(rig, text))
    assert ds.sensor("r").prior == {"pitch_deg": 0.5, "z_m": 0.01} and ds.sensor("lidar1").prior == {}
    back = load_manifest(write_dataset(ds, tmp_path / "out"))
    assert back.sensor("r").prior == {"pitch_deg": 0.5, "z_m": 0.01}
    assert "prior" not in (tmp_path / "out" / "rig.yaml").read_text().split("name: lidar1")[1].split("\n")[0]


def test_write_dataset_does_not_write_exclusions(tmp_path):
    ds = make_dataset().with_excluded({"cam": [1, 2]})
    back, ignored = load_manifest_with_ignored(write_dataset(ds, tmp_path))
    assert ignored == {}
    assert all(not s.excluded for s in back.sensors)


def test_write_dataset_refuses_clashing_file_names(tmp_path):
    rng = np.random.default_rng(0)
    ds = Dataset(sensors=(
        SensorDetections("Lidar", SensorKind.LIDAR, rng.normal(size=(2, 4, 3))),
        SensorDetections("lidar", SensorKind.LIDAR, rng.normal(size=(2, 4, 3))),
    ))
    with pytest.raises(InputError, match=r"sensors 'Lidar' and 'lidar' would write the same file"):
        write_dataset(ds, tmp_path)
    bad = Dataset(sensors=(
        SensorDetections("a/b", SensorKind.RADAR, np.zeros((2, 2))),
        SensorDetections("c", SensorKind.RADAR, np.zeros((2, 2))),
    ))
    with pytest.raises(InputError, match=r"must not contain whitespace or path separators"):
        write_dataset(bad, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_dataset_from_files(rig):
    ds = dataset_from_files(
        lidar=[rig / "lidar1.csv", str(rig / "lidar1.csv")],
        camera=rig / "cams" / "camera1.csv",
        radar=[rig / "radar1.csv"],
        radar3d=[rig / "radar2.csv"],
        reference="camera1",
    )
    assert ds.names == ("lidar1", "lidar2", "camera1", "radar1", "radar3d_1")
    assert ds.reference == "camera1"
    assert ds.sensor("radar3d_1").kind is SensorKind.RADAR3D
    assert ds.sensor("lidar2").source == str(rig / "lidar1.csv")


def test_dataset_from_files_accumulator_and_errors(rig):
    single = rig / "single.yaml"
    single.write_text(
        "/only:\n" + "".join(f"  - {{frame_id: rad, points: [{{x: {k}, y: 1, z: 2}}]}}\n" for k in range(K))
    )
    ds = dataset_from_files(lidar=[rig / "lidar1.csv"], radar=[single])
    assert ds.sensor("radar1").frame_id == "rad"
    np.testing.assert_array_equal(ds.sensor("radar1").points[:, 0], np.arange(K))
    with pytest.raises(InputError, match=r"acc\.yaml: 2 topics .* write a rig\.yaml manifest"):
        dataset_from_files(lidar=[rig / "lidar1.csv"], radar=[rig / "acc.yaml"])
    write_csv(rig, "short.csv", SensorKind.RADAR, num_boards=3)
    with pytest.raises(InputError, match=r"different numbers of board placements .*\(files: lidar1=.*lidar1\.csv, radar1=.*short\.csv\)"):
        dataset_from_files(lidar=[rig / "lidar1.csv"], radar=[rig / "short.csv"])
    with pytest.raises(InputError, match=r"reference sensor 'radar7' is not one of the sensors \(lidar1, radar1\)"):
        dataset_from_files(lidar=[rig / "lidar1.csv"], radar=[rig / "radar1.csv"], reference="radar7")
    with pytest.raises(InputError, match=r"radar1\.txt: radar detections must be a \.csv or \.yaml/\.yml file"):
        dataset_from_files(lidar=[rig / "lidar1.csv"], radar=[rig / "radar1.txt"])
    with pytest.raises(InputError, match=r"gone\.csv: detection CSV file not found"):
        dataset_from_files(lidar=[rig / "gone.csv"], radar=[rig / "radar1.csv"])


def test_real_data_manifest(tmp_path):
    if not SHARED.is_dir():
        pytest.skip("../shared not present")
    det = SHARED / "detections"
    (tmp_path / "ignore.yaml").write_text("lidar1: [0,1,2,3,112,113,114,115]\nradar1: [5,6]\n")
    (tmp_path / "rig.yaml").write_text(
        f"""sensors:
  - {{name: lidar1, kind: lidar, detections: {det / 'lidar.csv'}, frame_id: velodyne}}
  - {{name: camera1, kind: camera, detections: {det / 'camera.csv'}, frame_id: left}}
  - {{name: radar1, kind: radar, detections: {det / 'radar.csv'}}}
reference: lidar1
ignore: ignore.yaml
"""
    )
    ds = load_manifest(tmp_path / "rig.yaml")
    assert ds.num_boards == 29
    assert ds.sensor("lidar1").points.shape == (29, 4, 3)
    assert ds.sensor("radar1").points.shape == (29, 2)
    assert ds.sensor("lidar1").excluded == frozenset({0, 28})
    assert ds.sensor("radar1").excluded == frozenset({5, 6})
    assert int(ds.sensor("lidar1").valid.sum()) == 27
    # and it round-trips through write_dataset (exclusions aside)
    raw, _ = load_manifest_with_ignored(tmp_path / "rig.yaml")
    assert_same_dataset(raw, load_manifest(write_dataset(raw, tmp_path / "copy")))


def test_real_accumulator_in_manifest(tmp_path):
    if not SHARED.is_dir():
        pytest.skip("../shared not present")
    acc = SHARED / "detections" / "accumulator_example.yaml"
    (tmp_path / "rig.yaml").write_text(
        f"""sensors:
  - {{name: lidar1, kind: lidar, detections: {acc}, topic: /lidar_detector/lidar_pattern}}
  - {{name: camera1, kind: camera, detections: {acc}, topic: /stereo_detector/stereo_pattern}}
  - {{name: radar1, kind: radar, detections: {acc}, topic: /radar_detector/radar_pattern}}
"""
    )
    ds = load_manifest(tmp_path / "rig.yaml")
    assert ds.num_boards == 12
    assert [s.frame_id for s in ds.sensors] == ["velodyne", "left", "radar"]
