"""Property-based fuzzing of every parser (issue #11).

Property: for any bytes, a parser returns a value or raises :class:`rigcal.errors.RigcalError`;
any other exception, a warning (RuntimeWarning from numpy included: warnings are errors here), a
hang or a memory blow-up fails. Inputs are valid files mutated (bit flips, truncation, inserted
huge numbers, spliced garbage) and plain random bytes. Every test runs inside ``limited``
(a forked child with a memory and time limit); hypothesis is derandomized, so runs repeat.
"""

from __future__ import annotations

import json
import warnings
from types import SimpleNamespace

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigcal.errors import RigcalError

EXAMPLES = 150
FUZZ = settings(derandomize=True, deadline=None, max_examples=EXAMPLES, database=None,
                suppress_health_check=list(HealthCheck))
MEMORY_MB = 768
SECONDS = 60

HUGE_TOKENS = [b"1.797e308", b"-1.797e308", b"1e999", b"inf", b"-inf", b"nan", b"NaN",
               b"9" * 400, b"18446744073709551616", b"-1", b"0", b"4294967295", b"1e-320"]


# -------------------------------------------------------------------------------- mutations
@st.composite
def mutated(draw, seeds: list[bytes]) -> bytes:
    """A seed file with a few mutations, or random bytes."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=512))
    data = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.integers(0, 4))
        pos = draw(st.integers(0, max(len(data), 1) - 1)) if data else 0
        if op == 0 and data:  # bit flip
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == 1:  # truncation
            data = data[:pos]
        elif op == 2:  # a huge / odd number replaces the token at pos
            end = pos
            while end < len(data) and data[end:end + 1] not in (b" ", b",", b"\n", b"\r"):
                end += 1
            data[pos:end] = draw(st.sampled_from(HUGE_TOKENS))
        elif op == 3:  # garbage spliced in
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        else:  # line endings: CR only, CRLF
            data = data.replace(b"\n", draw(st.sampled_from([b"\r", b"\r\n"])))
    return bytes(data)


def _check(fn, *args) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            try:
                fn(*args)
            except RigcalError:
                pass


def _text(data: bytes) -> str:
    return data.decode("utf-8", "replace")


def run_fuzz(limited, seeds, target, text: bool = False, examples: int = EXAMPLES):
    @settings(FUZZ, max_examples=examples)
    @given(mutated(seeds))
    def fuzz(data):
        _check(target, _text(data) if text else data)

    limited(fuzz, MEMORY_MB, SECONDS)


# -------------------------------------------------------------------------------- seeds
def _cloud():
    from rigcal.recording import PointCloudFrame

    rng = np.random.default_rng(11)
    pts = rng.uniform(-4, 4, (6, 3))
    return PointCloudFrame("l", 0, pts, {"intensity": rng.uniform(0, 1, 6).astype(np.float32),
                                         "ring": np.arange(6, dtype=np.uint16)})


def test_fuzz_detections_csv(limited):
    from rigcal.io.dataset.detections_csv import parse_detections_csv

    seeds = [b"1,2,3,4\n5,6,7,8\n9,10,11,nan\n", b"1.5,2\n3,4\n", b"1,2,3\n4,5,6\n7,8,9\n"]

    def target(text):
        for kind in ("lidar", "radar", "radar3d"):
            try:
                parse_detections_csv(text, kind, "f.csv")
            except RigcalError:
                pass

    run_fuzz(limited, seeds, target, text=True)


def test_fuzz_radar_and_labels_csv(limited):
    from rigcal.absolute.labels import parse_labels_csv, parse_labels_yaml
    from rigcal.io.recordings.folder import parse_radar_csv

    seeds = [b"x,y,z,rcs\n1,2,0.1,15\n3,4,0.2,nan\n", b"label,x,y,z\nrear_left,1,2,3\n",
             b"rear_left: [1, 2, 3]\nfront_left: [[1, 2, 3], [1, 2, 4]]\n"]

    def target(text):
        for fn, args in ((parse_radar_csv, ("r.csv", "r", 0, 3)), (parse_labels_csv, ("l.csv",)),
                         (parse_labels_yaml, ("l.yaml",))):
            try:
                fn(text, *args)
            except RigcalError:
                pass

    run_fuzz(limited, seeds, target, text=True)


MANIFEST = b"""sensors:
  - {name: lidar1, kind: lidar, detections: l.csv}
  - {name: radar1, kind: radar, detections: r.csv, elevation_fov_deg: 9}
reference: lidar1
board: {spacing_m: 0.24, reflector_offset_m: 0.105}
"""
RIG = b"""sensors:
  - {name: lidar1, kind: lidar, topic: /points, detector: {roi_min_xyz: [-2, 3, -3]}}
  - {name: cam, kind: camera, input: stereo_pair, topic: /l, right_topic: /r,
     stereo: {fx: 1400, fy: 1400, cx: 968, cy: 608, baseline_m: 0.12}}
  - {name: radar1, kind: radar, topic: /radar, detector: {rcs_min_dbsm: 5, range_max_m: 10}}
reference: lidar1
base: &b {tolerance_m: 0.03}
placements:
  stability: {<<: *b, min_duration_s: 1.0}
  windows_s: [[12.0, 15.5], [20.0, 23.0]]
"""


def test_fuzz_yaml_manifest_and_rig(limited, tmp_path):
    from rigcal.io._text import load_yaml
    from rigcal.io.dataset.manifest import parse_manifest
    from rigcal.io.config.rig_config import parse_rig_config

    (tmp_path / "l.csv").write_text("1,2,3,4\n5,6,7,8\n9,10,11,12\n")
    (tmp_path / "r.csv").write_text("4\n1\n")
    rig = RIG.replace(b"reference: lidar1\nbase", b"base")  # 'base' is no rig key: mutate too

    def target(text):
        for fn in (lambda t: load_yaml(t, "y.yaml"),
                   lambda t: parse_manifest(t, "rig.yaml", tmp_path),
                   lambda t: parse_rig_config(t, "detect.yaml", tmp_path)):
            try:
                fn(text)
            except RigcalError:
                pass

    run_fuzz(limited, [MANIFEST, RIG, rig, b"a: &a [*a]\n", b"- [[[[1]]]]\n"], target,
             text=True)


def test_fuzz_camera_files(limited):
    from rigcal.io.config.intrinsics import parse_camera_info_yaml_text, parse_intrinsics_ini_text

    ini = (b"[image]\nwidth\n640\nheight\n480\n[cam]\ncamera matrix\n500 0 320\n0 500 240\n0 0 1\n"
           b"distortion\n0.1 -0.2 0.001 0.002 0.0\n")
    yml = (b"image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: "
           b"[500, 0, 320, 0, 500, 240, 0, 0, 1]}\ndistortion_model: plumb_bob\n"
           b"distortion_coefficients: {rows: 1, cols: 5, data: [0.1, -0.2, 0.001, 0.002, 0]}\n")

    def target(text):
        for fn in (parse_intrinsics_ini_text, parse_camera_info_yaml_text):
            try:
                fn(text, "c")
            except RigcalError:
                pass

    run_fuzz(limited, [ini, yml], target, text=True)


def test_fuzz_pcd(limited):
    from rigcal.io.clouds import parse_pcd_bytes, pcd_bytes

    cloud = _cloud()
    seeds = [pcd_bytes(cloud, kind) for kind in ("ascii", "binary", "binary_compressed")]
    run_fuzz(limited, seeds, lambda data: parse_pcd_bytes(data, "c.pcd"), examples=250)


def test_fuzz_ply(limited):
    from rigcal.io.clouds import parse_ply_bytes, ply_bytes

    cloud = _cloud()
    seeds = [ply_bytes(cloud, kind) for kind in ("ascii", "binary_little_endian")]
    run_fuzz(limited, seeds, lambda data: parse_ply_bytes(data, "c.ply"), examples=200)


def test_fuzz_npy(limited):
    from rigcal.io.clouds import npy_bytes, parse_npy_bytes
    from rigcal.recording import PointCloudFrame

    cloud = _cloud()
    organised = PointCloudFrame("l", 0, np.arange(12.0).reshape(4, 3), organized_shape=(2, 2))
    seeds = [npy_bytes(cloud), npy_bytes(organised)]
    run_fuzz(limited, seeds, lambda data: parse_npy_bytes(data, "c.npy"), examples=250)


def test_fuzz_npy_headers(limited):
    """Header dictionaries built from parts: shapes of any size, odd dtypes, nesting."""
    import struct

    from rigcal.io.clouds import parse_npy_bytes

    descr = st.sampled_from(["'<f8'", "'<f4'", "'|O'", "'<c16'", "'|V0'", "'S3'", "'<f8', 'x'",
                             "[('x', '<f4'), ('y', '<f4'), ('z', '<f4')]", "[('x', '|O')]",
                             "[('x', '<f8', (1000000000,))]", "'(3,)<f8'", "'<M8[s]'"])
    dim = st.integers(0, 2**62) | st.integers(0, 8)

    @settings(FUZZ, max_examples=200)
    @given(descr, st.lists(dim, max_size=4), st.booleans(), st.binary(max_size=256))
    def fuzz(d, shape, fortran, body):
        header = "{'descr': %s, 'fortran_order': %s, 'shape': (%s), }" % (
            d, fortran, "".join(f"{n}, " for n in shape))
        head = header.encode() + b" " * (-(10 + len(header) + 1) % 64) + b"\n"
        data = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(head)) + head + body
        _check(parse_npy_bytes, data, "h.npy")

    limited(fuzz, MEMORY_MB, SECONDS)


URDF = b"""<?xml version="1.0"?>
<robot name="car">
  <link name="base_link"/>
  <link name="lidar"/>
  <joint name="lidar_joint" type="fixed">
    <parent link="base_link"/>
    <child link="lidar"/>
    <origin xyz="1.0 0.0 1.8" rpy="0 0.01 0"/>
  </joint>
</robot>
"""


def test_fuzz_urdf(limited):
    from rigcal.io.results.urdf import forward_kinematics, parse_urdf

    def target(text):
        urdf = parse_urdf(text, "r.urdf")
        forward_kinematics(urdf, "base_link", "lidar")

    run_fuzz(limited, [URDF], target, text=True)


# -------------------------------------------------------------------------------- bag messages
def _typestores():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC), get_typestore(Stores.ROS2_HUMBLE)


def _bag_seeds():
    """Serialised messages (ROS 1 and CDR) of every type the readers convert."""
    from rigcal.io.recordings import bag
    from rigcal.io.recordings.pointcloud2 import encode_pointcloud2
    from rigcal.recording import ImageFrame

    cloud = _cloud()
    img = ImageFrame("c", 5, np.arange(24, dtype=np.uint8).reshape(4, 6))
    info = bag.CameraInfo(6, 4, [[500, 0, 3], [0, 500, 2], [0, 0, 1]], [0.1, 0, 0, 0, 0])
    out = []
    for ts, serialize in zip(_typestores(), ("serialize_ros1", "serialize_cdr")):
        msgs = {
            bag.POINTCLOUD2: encode_pointcloud2(cloud, ts),
            bag.IMAGE: bag._image_msg(img, ts),
            bag.COMPRESSED_IMAGE: bag._compressed_image_msg(img, ts, "/c/compressed"),
            bag.CAMERA_INFO: bag._camera_info_msg(info, ts),
        }
        for msgtype, msg in msgs.items():
            out.append((serialize, msgtype, getattr(ts, serialize)(msg, msgtype)))
    return out


def _convert(ts, serialize: str, msgtype: str, raw: bytes) -> None:
    """What Recording does with one raw message: deserialise (a failure is wrapped into an
    InputError there, so any exception of the decoder is acceptable here) then convert."""
    from rigcal.io.recordings import bag
    from rigcal.io.config.intrinsics import camera_from_info
    from rigcal.io.clouds import radar_frame_from_cloud
    from rigcal.io.recordings.pointcloud2 import decode_pointcloud2

    deserialize = getattr(ts, serialize.replace("serialize", "deserialize"))
    try:
        msg = deserialize(raw, msgtype)
    except Exception:  # noqa: BLE001 - Recording._messages turns this into one InputError line
        return
    if msgtype == bag.POINTCLOUD2:
        cloud = decode_pointcloud2(msg, "s", 0, "b.bag: /p")
        try:
            radar_frame_from_cloud(cloud, 3, None, "b.bag: /p")
        except RigcalError:
            pass
    elif msgtype == bag.IMAGE:
        bag.decode_image_msg(msg, "s", 0, "b.bag: /i")
    elif msgtype == bag.COMPRESSED_IMAGE:
        bag.decode_compressed_image_msg(msg, "s", 0, "b.bag: /c")
    else:
        camera_from_info(bag._camera_info_from_msg(msg, 0), "b.bag: /info")


def test_fuzz_bag_messages(limited):
    stores = dict(zip(("serialize_ros1", "serialize_cdr"), _typestores()))
    seeds = _bag_seeds()

    @settings(FUZZ, max_examples=300)
    @given(st.sampled_from(range(len(seeds))), st.data())
    def fuzz(k, data):
        serialize, msgtype, raw = seeds[k]
        mutated_raw = data.draw(mutated([bytes(raw)]))
        _check(_convert, stores[serialize], serialize, msgtype, mutated_raw)

    limited(fuzz, MEMORY_MB, SECONDS)


def test_fuzz_pointcloud2_layouts(limited):
    """PointCloud2 messages with arbitrary (duck-typed) layout numbers and data."""
    from rigcal.io.recordings.pointcloud2 import decode_pointcloud2

    u32 = st.integers(0, 2**32 - 1) | st.integers(0, 64)
    field = st.builds(SimpleNamespace, name=st.sampled_from(["x", "y", "z", "rcs", "x_0", ""]),
                      offset=u32, datatype=st.integers(0, 9), count=u32)

    @settings(FUZZ, max_examples=300)
    @given(u32, u32, u32, u32, st.booleans(), st.lists(field, max_size=5),
           st.binary(max_size=512))
    def fuzz(height, width, point_step, row_step, big, fields, data):
        msg = SimpleNamespace(height=height, width=width, point_step=point_step,
                              row_step=row_step, is_bigendian=big, fields=fields, data=data,
                              header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0),
                                                     frame_id="f"))
        _check(decode_pointcloud2, msg, "s", 0, "b.bag: /p")

    limited(fuzz, MEMORY_MB, SECONDS)


def test_mutation_strategy_is_seeded():
    """The mutations are reproducible (derandomized hypothesis draws the same examples)."""
    seen = []

    @settings(FUZZ, max_examples=5)
    @given(mutated([b"1,2,3\n"]))
    def collect(data):
        seen.append(data)

    collect()
    first = list(seen)
    seen.clear()
    collect()
    assert seen == first


# -------------------------------------------------------------------------------- issue #22: the new commands
def _report_json_seed() -> bytes:
    from rigcal.problem.calibrate import CalibrationOptions, calibrate
    from rigcal.io.results.report import report_json_text
    from rigcal.report.data import calibration_report
    from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

    rng = np.random.default_rng(3)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 6, min_fraction=1.0), rng=rng)
    result = calibrate(sim.dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=0))
    return report_json_text(calibration_report(result, sim.dataset)).encode()


def test_fuzz_report_and_study_json(limited):
    """``rigcal report``'s inputs: a (mutated) report.json or study.json is rendered or refused
    with a RigcalError - a 5000-digit integer, deep nesting, NaN, wrong types included."""
    from rigcal.io._text import load_json
    from rigcal.report.page import check_report_data, render_report
    from rigcal.report.study_page import render_study

    study = (b'{"meta": {"study": "x", "seed": 0}, "rows": [{"table": "III", "config": "FCPE", "pair": "a-b", '
             b'"median_mm": 1.5, "mad_mm": 0.2, "paper_mm": 1.0, "draws": 3}, {"table": "fig7", "k": 3, '
             b'"config": "PSE", "pair": "a-b", "median_mm": 2.0}]}')
    seeds = [_report_json_seed(), study, b'{"rows": [' * 40 + b"]" * 40, b'{"n": ' + b"9" * 5000 + b"}"]

    def target(text):
        data = load_json(text, "report.json")
        if isinstance(data, dict) and "rows" in data:
            render_study(data, "study.json")
        else:
            render_report(check_report_data(data, "report.json"), "report.json")

    run_fuzz(limited, seeds, target, text=True, examples=80)


def test_fuzz_scheduler_addresses():
    """``--scheduler``: any text is an address (scheme, host, port in range) or an InputError;
    nothing is contacted here."""
    from rigcal.errors import InputError
    from rigcal.study.scale import parse_scheduler_address

    parts = st.tuples(st.sampled_from(["", "tcp://", "tls://", "ucx://", "inproc://", "ws://", "TCP://", "://"]),
                      st.sampled_from(["", "127.0.0.1", "node7", "[::1]", "a\nb", "a\x00b", "h/x", ":"]),
                      st.sampled_from(["", ":", ":8786", ":0", ":65536", ":-1", ":80a", ":99999999999999", "::1"]))
    addresses = st.one_of(st.text(max_size=30), parts.map("".join))

    @settings(FUZZ, max_examples=250)
    @given(addresses)
    def fuzz(address):
        try:
            scheme, host, port = parse_scheduler_address(address)
        except InputError as exc:
            assert "\n" not in str(exc) or "\n" in address  # (the CLI escapes it on output)
            return
        assert scheme in ("tcp", "tls", "ucx") and host and 1 <= port <= 65535

    fuzz()


def test_fuzz_fleet_arguments(tmp_path):
    """``--batch`` arguments: whatever they are (missing, files, NUL, control characters, the
    same folder twice), every argument becomes an entry or a note and nothing raises."""
    from rigcal.fleet import fleet_entries

    (tmp_path / "car1").mkdir()
    (tmp_path / "car1" / "rig.yaml").write_text("sensors: []\n")
    (tmp_path / "notes.txt").write_text("x")
    names = st.sampled_from(["car1", "car1/", "car1/rig.yaml", "notes.txt", "nope", "car\n1", "a\x00b", ".", "..",
                             "x" * 300, "car1/../car1"])

    @settings(FUZZ, max_examples=80)
    @given(st.lists(st.one_of(names, st.text(max_size=12)), min_size=1, max_size=6))
    def fuzz(args):
        entries, notes = fleet_entries([str(tmp_path / a) for a in args])
        assert len(entries) + len(notes) <= len(args)
        named = [e.name for e in entries if e.problem is None]
        assert len(named) == len(set(named))  # two entries never write to the same OUT/<name>/
        for e in entries:
            assert e.problem is None or str(e.path) in e.problem or e.problem.startswith("'")
        assert all("\n" not in n for n in notes)

    fuzz()


def test_fuzz_study_options():
    """``rigcal study``'s numeric options: any value parses within its documented range or is a
    usage error naming the option."""
    import argparse
    import contextlib
    import io

    from rigcal.cli.study import MAX_MEASUREMENTS, MAX_SEED, MAX_TRIALS, mocap_parser

    values = st.one_of(st.integers(-2**70, 2**70).map(str), st.sampled_from(["1e9", "nan", "-0", "", "0x10", "٣"]))

    @settings(FUZZ, max_examples=300)
    @given(st.sampled_from(["--seed", "--trials", "--measurements"]), values)
    def fuzz(option, value):
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                args = mocap_parser().parse_args([option, value])
        except SystemExit as exc:
            assert exc.code == 2 and f"argument {option}" in err.getvalue()
            return
        assert isinstance(args, argparse.Namespace)
        assert 0 <= args.seed <= MAX_SEED and 1 <= args.trials <= MAX_TRIALS
        assert all(1 <= n <= MAX_MEASUREMENTS for n in args.measurements)

    fuzz()


# -------------------------------------------------------------------------------- check and diff
def _stored_seed(tmp_path):
    """A compact calibration.yaml (only the fields check and diff read, leaf lists in flow
    style, so that mutations land on them) and new detections of the same rig."""
    from rigcal.io._text import dump_yaml
    from rigcal.io.results.calibration import result_to_yaml_text
    from rigcal.problem.calibrate import CalibrationOptions, calibrate
    from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

    sensors = prius_like_rig()
    rng = np.random.default_rng(5)
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    result = calibrate(sim.dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=0))
    import yaml

    full = yaml.safe_load(result_to_yaml_text(result))
    keep = {"reference", "mode", "num_boards", "sensors", "relative", "noise_model"}
    compact = {k: v for k, v in full.items() if k in keep}
    for s in compact["sensors"].values():
        for k in [k for k in s if k not in ("kind", "frame_id", "T_reference_sensor", "covariance", "held", "bounded")]:
            del s[k]
    for r in compact["relative"].values():
        for k in [k for k in r if k not in ("to", "from", "covariance")]:
            del r[k]
    rng = np.random.default_rng(6)
    new = simulate(sensors, make_rig_placements(rng, sensors, 4, min_fraction=1.0), rng=rng).dataset
    return dump_yaml(compact, flow=None).encode(), new


def test_fuzz_stored_calibration(limited, tmp_path):
    """``rigcal check`` / ``diff``'s reader: a (mutated) calibration.yaml is refused with a
    RigcalError or read as a calibration that check, diff and the check page then handle
    without an exception or a floating-point warning."""
    from rigcal.io.results.check_report import json_text
    from rigcal.io.results.stored import parse_stored_calibration
    from rigcal.problem.check import check
    from rigcal.problem.diff import diff
    from rigcal.report.check_page import render_check

    seed, dataset = _stored_seed(tmp_path)
    original = parse_stored_calibration(seed.decode(), "seed.yaml")
    seeds = [seed, seed.replace(b"num_boards: 8", b"num_boards: " + b"9" * 5000),
             b"reference: a\nsensors: {a: " * 30 + b"}" * 30]

    def target(text):
        stored = parse_stored_calibration(text, "calibration.yaml")
        for name, s in stored.sensors.items():
            assert np.all(np.isfinite(s.covariance)) and np.all(np.isfinite(s.T_reference_sensor))
            assert name.isprintable() and np.min(np.linalg.eigvalsh(s.covariance)) > -1e-6
        data = check(stored, dataset).to_dict()
        render_check(json.loads(json_text(data)))
        diff(stored, stored)
        diff(original, stored)

    run_fuzz(limited, seeds, target, text=True, examples=100)


def test_fuzz_check_and_diff_arguments(limited, tmp_path):
    """``rigcal check`` / ``diff`` / ``check --batch`` with any mix of arguments (inputs swapped,
    files for folders, missing paths, control characters, --out onto an input, --alpha out of
    range, schedulers that cannot be used): an exit code the help documents, never an
    exception, and no input changed."""
    import contextlib
    import io
    import shutil
    from pathlib import Path

    from rigcal.cli.main import run
    from rigcal.io.atomic import mark_output
    from rigcal.io.dataset.manifest import write_dataset

    seed, dataset = _stored_seed(tmp_path)
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "calibration.yaml").write_bytes(seed)
    mark_output(tmp_path / "cal")  # as rigcal calibrate leaves it
    write_dataset(dataset, tmp_path / "data")
    shutil.copytree(tmp_path / "data", tmp_path / "fleet" / "car1")
    shutil.copytree(tmp_path / "cal", tmp_path / "calib" / "car1")
    (tmp_path / "notes.txt").write_text("mine")

    pristine = tmp_path.parent / f"{tmp_path.name}-pristine"
    shutil.copytree(tmp_path, pristine)
    before = {p: p.read_bytes() for p in sorted(tmp_path.rglob("*")) if p.is_file()}

    def inputs(args: list[str]) -> set[Path]:
        """The files a run reads: every path argument but --out's value, and what is below it."""
        given = {Path(a) for i, a in enumerate(args) if a.startswith(str(tmp_path)) and args[i - 1] != "--out"}
        return {p for p in before if any(p == g or g in p.parents for g in given)}

    def restore() -> None:  # every example starts from the same files (a run may replace a rigcal folder
        shutil.rmtree(tmp_path)  # that is not one of its inputs: --out onto a marked folder)
        shutil.copytree(pristine, tmp_path)

    paths = st.sampled_from([str(tmp_path / p) for p in ("cal", "cal/calibration.yaml", "data", "data/rig.yaml",
                                                          "fleet/car1", "notes.txt", "nope", "fleet", "calib",
                                                          "car\n1", "out/a", "out/b[/x]")])
    calibrations = st.sampled_from([str(tmp_path / p) for p in ("cal", "cal/calibration.yaml")])
    data = st.sampled_from([str(tmp_path / p) for p in ("data", "data/rig.yaml", "cal")])
    alphas = st.sampled_from(["0.05", "0", "0.5", "nan", "-1", "abc", "1e-300", "0.4999"])

    def maybe(option, values):
        return st.one_of(st.just([]), values.map(lambda v: [option, v]))

    @st.composite
    def argv(draw):
        command = draw(st.sampled_from(["check", "check", "check --batch", "diff"]))
        if command == "check --batch":
            return ["check", "--scheduler", "serial", *draw(maybe("--scheduler", st.sampled_from(
                ["tls://127.0.0.1:1", "x:y:z", "", "inproc://a"]))), *draw(maybe("--calibrations", paths)),
                *draw(maybe("--out", paths)), *draw(maybe("--alpha", alphas)), *draw(st.sampled_from([[], ["--json"]])),
                "--batch", *draw(st.lists(paths, min_size=1, max_size=3))]
        positional = draw(st.one_of(st.tuples(calibrations, data).map(list), st.lists(paths, max_size=3)))
        extra = draw(maybe("--alpha", alphas))
        if command == "check":
            extra += draw(maybe("--out", paths)) + draw(maybe("--rig", paths)) + draw(st.sampled_from([[], ["--json"]]))
        return [command, *positional, *extra]

    @settings(FUZZ, max_examples=50)
    @given(argv())
    def fuzz(args):
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
            try:
                code = run(args)
            except SystemExit as exc:  # argparse: a usage error
                code = exc.code
        assert code in (0, 1, 2, 4, 6, 7), (args, code, err.getvalue())
        if code == 1:
            assert err.getvalue().count("rigcal: error:") >= 1, (args, err.getvalue())
        changed = [str(p) for p in inputs(args) if not p.is_file() or p.read_bytes() != before[p]]
        restore()
        assert not changed, (args, changed)

    limited(fuzz, MEMORY_MB, 240)
