"""Hostile files for every reader, driven through the CLI (issue #11).

Each case writes a small valid input, spoils one file, runs ``rigcal`` in a subprocess under the
harness's memory and time limits and asserts the contract: exit code not 0, one
``rigcal: error:`` line naming the file (and line, key or sensor), no traceback or warning, and
the ``--out`` folder not created.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
import pytest

from rigcal.io.recordings.bag import CameraInfo, write_recording
from rigcal.io.clouds import pcd_bytes, ply_bytes
from rigcal.recording import ImageFrame, PointCloudFrame, RadarFrame

NS = 1_000_000_000
LONG = "n" * 300  # longer than NAME_MAX (255) on every common file system
HUGE = "1.797e308"


# -------------------------------------------------------------------------------- inputs
def _table(rows: int, cols: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-5, 5, (rows, cols))


def _csv(table: np.ndarray, end: str = "\n") -> str:
    return "".join(",".join(repr(float(v)) for v in row) + end for row in table)


def _with(text: str, line: int, column: int, value: str, end: str = "\n") -> str:
    rows = [r.split(",") for r in text.split(end) if r]
    rows[line - 1][column - 1] = value
    return "".join(",".join(r) + end for r in rows)


MANIFEST = """sensors:
  - {name: lidar1, kind: lidar, detections: lidar1.csv}
  - {name: lidar2, kind: lidar, detections: lidar2.csv}
  - {name: radar1, kind: radar, detections: radar1.csv}
"""


@pytest.fixture
def manifest(tmp_path):
    (tmp_path / "lidar1.csv").write_text(_csv(_table(3, 16, 1)))
    (tmp_path / "lidar2.csv").write_text(_csv(_table(3, 16, 2)))
    (tmp_path / "radar1.csv").write_text(_csv(_table(2, 4, 3)))
    (tmp_path / "rig.yaml").write_text(MANIFEST)
    return tmp_path / "rig.yaml"


def _radar_csv(x: float = 4.0, end: str = "\n") -> str:
    return end.join(["x,y,rcs", f"{x!r},0.5,15.0", "2.0,-1.0,-5.0"]) + end


def _radar_folder(root: Path, frames: int = 40, end: str = "\n",
                  sensors: tuple[str, ...] = ("radar1",)) -> Path:
    """A folder recording of 2D radars at 10 Hz seeing the reflector at 4 m, 0.5 m."""
    for name in sensors:
        folder = root / "rec" / name
        folder.mkdir(parents=True)
        for k in range(frames):
            (folder / f"{NS + k * NS // 10}.csv").write_bytes(_radar_csv(end=end).encode())
    return root / "rec"


RADAR_RIG = """sensors:
  - {name: radar1, kind: radar, topic: radar1, detector: {rcs_min_dbsm: 5}}
"""


def _rig(root: Path, text: str = RADAR_RIG) -> Path:
    p = root / "detect_rig.yaml"
    p.write_text(text)
    return p


def _cloud_bytes(kind: str, value: float) -> tuple[str, bytes]:
    pts = np.random.default_rng(4).uniform(-3, 3, (20, 3))
    pts[7, 1] = value
    frame = PointCloudFrame("lidar1", 0, pts)
    if kind == "ply":
        return ".ply", ply_bytes(frame, "ascii")
    if kind == "npy":
        buf = io.BytesIO()
        np.save(buf, pts)
        return ".npy", buf.getvalue()
    with np.errstate(over="ignore"):
        return ".pcd", pcd_bytes(frame, kind, xyz_dtype=np.float64)


def _npy_with_header(header: str) -> bytes:
    head = header.encode("latin1")
    head += b" " * (-(10 + len(head) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(head)) + head + b"\x00" * 64


# -------------------------------------------------------------------------------- calibrate
CALIBRATE_CASES = [
    ("lidar2.csv", lambda t: _with(t, 2, 5, HUGE), ["lidar2.csv", "line 2, column 5"]),
    ("lidar2.csv", lambda t: _with(t, 1, 1, "-1e300"), ["lidar2.csv", "line 1, column 1"]),
    ("lidar2.csv", lambda t: _with(t, 3, 16, "inf"), ["lidar2.csv", "line 3, column 16"]),
    ("radar1.csv", lambda t: _with(t, 2, 2, HUGE), ["radar1.csv", "line 2, column 2"]),
    # old-Mac CR line ends: parsed like LF, so the huge value is still found on its line
    ("lidar1.csv", lambda t: _with(t, 3, 2, HUGE).replace("\n", "\r"),
     ["lidar1.csv", "line 3, column 2"]),
]


@pytest.mark.parametrize("name, spoil, names", CALIBRATE_CASES,
                         ids=[f"{c[0]}-{k}" for k, c in enumerate(CALIBRATE_CASES)])
def test_calibrate_refuses_hostile_detections(manifest, cli, refused, name, spoil, names):
    path = manifest.parent / name
    path.write_text(spoil(path.read_text()), newline="")
    out = manifest.parent / "out"
    refused(cli("calibrate", manifest, "--out", out), *names)
    assert not out.exists()


def test_calibrate_refuses_a_huge_initial_translation(manifest, cli, refused):
    T = np.eye(4).tolist()
    T[0][3] = 1e300
    init = manifest.parent / "initial.yaml"
    init.write_text(f"sensors:\n  lidar1: {{T_reference_sensor: {np.eye(4).tolist()}}}\n"
                    f"  lidar2: {{T_reference_sensor: {T}}}\n")
    out = manifest.parent / "out"
    refused(cli("calibrate", manifest, "--initial", init, "--out", out),
            "initial.yaml", "sensors.lidar2.T_reference_sensor")
    assert not out.exists()


def test_cr_only_detections_calibrate_like_lf(manifest, cli):
    for name in ("lidar1.csv", "lidar2.csv", "radar1.csv"):
        p = manifest.parent / name
        p.write_text(p.read_text().replace("\n", "\r"), newline="")
    proc = cli("calibrate", manifest, "--out", manifest.parent / "out", "--cv-folds", "0",
               "--no-plot")
    err = proc.stderr.decode()
    assert "Traceback" not in err and "rows" not in err and "line" not in err, err


@pytest.mark.parametrize("where", ["manifest", "out"])
def test_calibrate_long_names_are_one_line(manifest, cli, refused, where):
    long_path = manifest.parent / LONG
    args = (long_path, "--out", manifest.parent / "out") if where == "manifest" else (
        manifest, "--out", long_path)
    line = refused(cli("calibrate", *args), LONG)
    assert "too long" in line
    assert not (manifest.parent / "out").exists()


# -------------------------------------------------------------------------------- detect
def _spoil_radar_file(rec: Path, text: str) -> Path:
    p = sorted((rec / "radar1").iterdir())[5]
    p.write_bytes(text.encode())
    return p


DETECT_FILE_CASES = [
    ("huge radar x", lambda: _radar_csv(x=1.797e308), ["line 2", "'x'"]),
    ("inf radar x", lambda: "x,y,rcs\n1.0,inf,3\n", ["line 2", "'y'"]),
    ("CR-only radar CSV with a huge rcs", lambda: "x,y,rcs\r1.0,2.0,1e300\r", ["line 2", "'rcs'"]),
    ("malformed radar CSV", lambda: 'x,y,rcs\n1,"2\n', ["line"]),
]


@pytest.mark.parametrize("what, content, names", DETECT_FILE_CASES,
                         ids=[c[0] for c in DETECT_FILE_CASES])
def test_detect_refuses_hostile_radar_csv(tmp_path, cli, refused, what, content, names):
    rec = _radar_folder(tmp_path)
    bad = _spoil_radar_file(rec, content())
    out = tmp_path / "out"
    refused(cli("detect", rec, "--rig", _rig(tmp_path), "--out", out), bad.name, *names)
    assert not out.exists()


LIDAR_RIG = """sensors:
  - {name: lidar1, kind: lidar, topic: lidar1}
"""

CLOUD_CASES = [
    ("pcd-ascii-huge", lambda: _cloud_bytes("ascii", 1.797e308), ["point 7", "y"]),
    ("pcd-binary-inf", lambda: _cloud_bytes("binary", float("inf")), ["point 7", "y = inf"]),
    ("pcd-compressed-huge", lambda: _cloud_bytes("binary_compressed", -1e300), ["point 7"]),
    ("ply-ascii-huge", lambda: _cloud_bytes("ply", 1e300), ["point 7"]),
    ("npy-huge", lambda: _cloud_bytes("npy", 1e300), ["point 7"]),
    ("npy-malformed-header", lambda: (".npy", _npy_with_header("{'descr': '<f8', 'fortran_order"
                                                               ": False, 'shape': (2, 3, }")),
     ["not a valid .npy array"]),
    ("npy-huge-shape", lambda: (".npy", _npy_with_header(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000000, 3), }")),
     ["element count"]),
    ("npy-shape-past-the-data", lambda: (".npy", _npy_with_header(
        "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000, 3), }")),
     ["truncated"]),
    ("pcd-ascii-f4-overflow", lambda: (".pcd", b"VERSION 0.7\nFIELDS x y z i\nSIZE 4 4 4 4\n"
                                       b"TYPE F F F F\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"
                                       b"DATA ascii\n1 2 3 1e300\n"), ["out of range"]),
    ("pcd-lzf-bomb", lambda: (".pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
                              b"WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary_compressed\n"
                              + struct.pack("<II", 4000, 12) + b"\x00A" + b"\xe0\xff\x00" * 1333),
     ["LZF"]),
]


@pytest.mark.parametrize("what, make, names", CLOUD_CASES, ids=[c[0] for c in CLOUD_CASES])
def test_detect_refuses_hostile_point_clouds(tmp_path, cli, refused, what, make, names):
    folder = tmp_path / "rec" / "lidar1"
    folder.mkdir(parents=True)
    suffix, data = make()
    bad = folder / f"{NS}{suffix}"
    bad.write_bytes(data)
    out = tmp_path / "out"
    refused(cli("detect", tmp_path / "rec", "--rig", _rig(tmp_path, LIDAR_RIG), "--out", out),
            bad.name, *names)
    assert not out.exists()


RIG_CASES = [
    ("window NaN", "placements: {windows_s: [[1.0, .nan]]}", ["placements.windows_s[0][1]"]),
    ("window inf", "placements: {windows_s: [[1.0, 2.0], [-.inf, 3]]}",
     ["placements.windows_s[1][0]"]),
    ("window reversed", "placements: {windows_s: [[1.0, 2.0], [3.5, 3.0]]}",
     ["placements.windows_s[1]", "not after start"]),
    ("window past the end", "placements: {windows_s: [[1.0, 4.0], [100.0, 105.0]]}",
     ["placements.windows_s[1]", "spans 1.000 to 4.900 s"]),
    ("range window reversed",
     None, ["sensor 'radar1'", "range_min_m/range_max_m", "[5, 1]"]),
    ("range NaN", "", ["sensor 'radar1'", "range_max_m"]),
    ("stability NaN", "placements: {stability: {tolerance_m: .nan}}",
     ["placements.stability", "tolerance_m"]),
]


@pytest.mark.parametrize("what, extra, names", RIG_CASES, ids=[c[0] for c in RIG_CASES])
def test_detect_refuses_hostile_rig_values(tmp_path, cli, refused, what, extra, names):
    rec = _radar_folder(tmp_path)
    if what == "range window reversed":
        text = RADAR_RIG.replace("{rcs_min_dbsm: 5}", "{range_min_m: 5, range_max_m: 1}")
    elif what == "range NaN":
        text = RADAR_RIG.replace("{rcs_min_dbsm: 5}", "{range_max_m: .nan}")
    else:
        text = RADAR_RIG + extra + "\n"
    rig = _rig(tmp_path, text)
    out = tmp_path / "out"
    refused(cli("detect", rec, "--rig", rig, "--out", out), rig.name, *names)
    assert not out.exists()


def test_detect_cr_only_radar_csvs_are_read(tmp_path, cli):
    rec = _radar_folder(tmp_path, end="\r", sensors=("radar1", "radar2"))
    out = tmp_path / "out"
    rig = _rig(tmp_path, RADAR_RIG + RADAR_RIG.split("\n", 1)[1].replace("radar1", "radar2"))
    proc = cli("detect", rec, "--rig", rig, "--out", out)
    assert proc.returncode == 0, proc.stderr.decode()
    assert (out / "radar1.csv").is_file()


def test_ros2_folder_without_metadata_is_named(tmp_path, cli, refused):
    rec = tmp_path / "rec2"
    rec.mkdir()
    (rec / "rec2_0.db3").write_bytes(b"SQLite format 3\x00")
    out = tmp_path / "out"
    line = refused(cli("detect", rec, "--rig", _rig(tmp_path), "--out", out),
                   "rec2", "ROS 2 bag", "rec2_0.db3", "metadata.yaml is missing")
    assert "not in the recording" not in line
    assert not out.exists()


@pytest.mark.parametrize("where", ["recording", "rig", "out"])
def test_detect_long_names_are_one_line(tmp_path, cli, refused, where):
    rec, rig, out = _radar_folder(tmp_path), _rig(tmp_path), tmp_path / "out"
    if where == "recording":
        rec = tmp_path / LONG
    elif where == "rig":
        rig = tmp_path / LONG
    else:
        out = tmp_path / LONG
    refused(cli("detect", rec, "--rig", rig, "--out", out), LONG)
    assert not (tmp_path / "out").exists()


def test_long_sensor_folder_name_is_one_line(tmp_path, cli, refused):
    rec = _radar_folder(tmp_path)
    rig = _rig(tmp_path, RADAR_RIG.replace("topic: radar1", f"topic: {LONG}"))
    refused(cli("detect", rec, "--rig", rig, "--out", tmp_path / "out"), LONG)


# -------------------------------------------------------------------------------- bags
def _image(t_ns: int) -> ImageFrame:
    return ImageFrame("cam", t_ns, np.full((6, 8), 128, np.uint8))


def test_topic_of_the_wrong_type_names_sensor_topic_and_types(tmp_path, cli, refused):
    bag = write_recording(tmp_path / "rec.bag", {"/cam": [_image(NS)]}, "rosbag1")
    rig = _rig(tmp_path, "sensors:\n  - {name: lidar1, kind: lidar, topic: /cam}\n")
    out = tmp_path / "out"
    refused(cli("detect", bag, "--rig", rig, "--out", out), "detect_rig.yaml", "sensor 'lidar1'",
            "/cam", "sensor_msgs/msg/Image", "sensor_msgs/msg/PointCloud2")
    assert not out.exists()


def test_folder_of_images_for_a_radar_names_the_kinds(tmp_path, cli, refused):
    folder = tmp_path / "rec" / "radar1"
    folder.mkdir(parents=True)
    (folder / "1.png").write_bytes(b"\x89PNG")
    refused(cli("detect", tmp_path / "rec", "--rig", _rig(tmp_path), "--out", tmp_path / "out"),
            "sensor 'radar1'", "image", "points or radar_csv")


def _camera_bag(tmp_path: Path, info_topic: str = "/cam/info", info: object = None) -> Path:
    info = info if info is not None else CameraInfo(
        8, 6, [[500, 0, 4], [0, 501, 3], [0, 0, 1]], [0.1, -0.2, 0.001, 0.002, 0.0],
        frame_id="cam", t_ns=NS)
    items = {"/cam/image": [_image(NS + k * NS // 10) for k in range(3)], info_topic: [info]}
    return write_recording(tmp_path / "cam.bag", items, "rosbag1")


CAM_RIG = """sensors:
  - {name: cam, kind: camera, topic: /cam/image, camera_info_topic: %s}
"""


def test_camera_info_topic_gives_the_camera(tmp_path, cli):
    """End to end: the camera model comes from the bag's CameraInfo (was an ImportError); the
    blank images then hold no board, which is the one error reported."""
    bag = _camera_bag(tmp_path)
    proc = cli("detect", bag, "--rig", _rig(tmp_path, CAM_RIG % "/cam/info"), "--out",
               tmp_path / "out")
    err = proc.stderr.decode()
    assert proc.returncode == 1 and "Traceback" not in err and "ImportError" not in err, err
    assert "no board placement found" in err and "cam: 0 detections in 3 frames" in err, err


@pytest.mark.parametrize("topic, names", [
    ("/cam/missing", ["sensor 'cam'", "/cam/missing", "not in bag"]),
    ("/cam/image", ["sensor 'cam'", "/cam/image", "sensor_msgs/msg/CameraInfo"]),
])
def test_camera_info_topic_missing_or_of_another_type(tmp_path, cli, refused, topic, names):
    bag = _camera_bag(tmp_path)
    out = tmp_path / "out"
    refused(cli("detect", bag, "--rig", _rig(tmp_path, CAM_RIG % topic), "--out", out), *names)
    assert not out.exists()


def test_uncalibrated_camera_info_is_refused(tmp_path, cli, refused):
    bag = _camera_bag(tmp_path, info=CameraInfo(8, 6, np.zeros((3, 3)), [], frame_id="cam",
                                                t_ns=NS))
    refused(cli("detect", bag, "--rig", _rig(tmp_path, CAM_RIG % "/cam/info"), "--out",
                tmp_path / "out"), "sensor 'cam'", "/cam/info", "fx = 0")


def test_radar_bag_with_huge_points_is_refused(tmp_path, cli, refused):
    frames = [RadarFrame("radar1", NS + k * NS // 10, [[4.0, 0.5], [2.0, 1.0]], [15.0, 0.0])
              for k in range(10)]
    frames[4] = RadarFrame("radar1", frames[4].t_ns, [[4.0, 0.5], [1e300, 1.0]], [15.0, 0.0])
    bag = write_recording(tmp_path / "r.bag", {"/r": frames}, "rosbag1", xyz_dtype=np.float64)
    rig = _rig(tmp_path, RADAR_RIG.replace("topic: radar1", "topic: /r"))
    refused(cli("detect", bag, "--rig", rig, "--out", tmp_path / "out"), "r.bag", "/r",
            "point 1")


# -------------------------------------------------------------------------------- absolute
ABS_MANIFEST = """sensors:
  - {name: lidar1, kind: lidar, detections: lidar1.csv}
  - {name: leica, kind: lidar, detections: lidar2.csv}
"""


@pytest.mark.parametrize("what", ["labels-csv", "labels-yaml", "labels-csv-cr", "scan"])
def test_absolute_refuses_hostile_labels_and_scan(manifest, cli, refused, what):
    root = manifest.parent
    (root / "abs.yaml").write_text(ABS_MANIFEST)
    scan_suffix, scan = _cloud_bytes("binary", 1e300 if what == "scan" else 1.0)
    (root / f"scan{scan_suffix}").write_bytes(scan)
    labels = root / ("labels.yaml" if what == "labels-yaml" else "labels.csv")
    if what == "labels-yaml":
        labels.write_text("rear_left: [1.0, 1e300, 0.3]\n")
        names = ["labels.yaml", "rear_left"]
    else:
        end = "\r" if what == "labels-csv-cr" else "\n"
        labels.write_text(end.join(["label,x,y,z", "rear_left,1,2,3", f"rear_right,1,{HUGE},3"])
                          + end, newline="")
        names = ["labels.csv", "line 3"]
    if what == "scan":
        labels.write_text("label,x,y,z\nrear_left,1,2,3\n")
        names = [f"scan{scan_suffix}", "point 7"]
    out = root / "out"
    refused(cli("absolute", root / "abs.yaml", "--external", "leica", "--scan",
                root / f"scan{scan_suffix}", "--labels", labels, "--out", out), *names)
    assert not out.exists()
