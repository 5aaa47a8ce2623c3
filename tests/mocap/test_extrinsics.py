"""Extrinsics graphs: the original tool's JSON (shared examples, layout and direction), lookups
that compose and invert, JSON round trips, and every failure path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry import Transform, from_rt, so3_exp
from rigcal.mocap import (
    Extrinsics,
    extrinsics_json_text,
    parse_extrinsics_json,
    read_extrinsics_json,
    write_extrinsics_json,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "vicon_sim"


def shared(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"shared data {path} not present")
    return path


def pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return from_rt(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def _entry(to, frm, T):
    return {"to_frame": to, "from_frame": frm, "transform": np.asarray(T).reshape(-1).tolist()}


# -- the shared files ----------------------------------------------------------------------------


def test_shared_initial_calibration_layout_and_direction():
    ext = read_extrinsics_json(shared("initial_calibration_EXAMPLE.json"))
    assert ext.frames == ("base_link", "camera_link", "imu_link", "velodyne_link",
                          "vicon/robot/robot")
    assert dict(ext.metadata) == {"type": "extrinsic_calibration", "date": "2019_07_25",
                                  "method": "manual"}
    # row-major: the translation is the 4th column
    T_base_velo = ext.lookup("base_link", "velodyne_link")
    np.testing.assert_allclose(T_base_velo[:3, 3], [0.217, 0.0, 0.356])
    # T_to_from: the lidar's forward axis (x) becomes the camera's optical axis (z), the lidar's
    # up axis (z) the camera's up (-y): camera_link is an optical frame looking forward
    T_cam_velo = ext.lookup("camera_link", "velodyne_link")
    np.testing.assert_allclose(T_cam_velo[:3, :3] @ [1, 0, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(T_cam_velo[:3, :3] @ [0, 0, 1], [0, -1, 0], atol=1e-12)
    # the mocap body's rotation (5 printed decimals) is re-orthonormalised
    R = ext.lookup("base_link", "vicon/robot/robot")[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    assert np.degrees(np.arctan2(R[1, 0], R[0, 0])) == pytest.approx(10.0, abs=0.01)
    # a chain through four edges, inverting two of them
    T = ext.lookup("imu_link", "vicon/robot/robot")
    expected = (ext.transforms[("imu_link", "camera_link")]
                @ ext.transforms[("camera_link", "velodyne_link")]
                @ np.linalg.inv(ext.transforms[("base_link", "velodyne_link")])
                @ ext.transforms[("base_link", "vicon/robot/robot")])
    np.testing.assert_allclose(T, expected, atol=1e-12)
    assert ext.path("imu_link", "vicon/robot/robot") == [
        "vicon/robot/robot", "base_link", "velodyne_link", "camera_link", "imu_link"]


def test_shared_roben_extrinsics():
    ext = read_extrinsics_json(shared("roben_extrinsics.json"))
    assert len(ext) == 9
    assert {f"ladybug_cam{i}" for i in range(6)} < set(ext.frames)
    # here the mocap body is the "to" frame: T_vicon_base
    T = ext.lookup("ladybug_cam3", "vicon/roben/roben")
    np.testing.assert_allclose(
        T, ext.transforms[("ladybug_cam3", "ladybug_link")]
        @ ext.transforms[("ladybug_link", "m3d_link")] @ ext.transforms[("m3d_link", "base_link")]
        @ np.linalg.inv(ext.transforms[("vicon/roben/roben", "base_link")]), atol=1e-12)
    for T in ext.transforms.values():
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0)


# -- lookups -----------------------------------------------------------------------------------


def test_lookup_composes_inverts_and_checks_frames():
    T_ab, T_cb, T_cd = pose(1), pose(2), pose(3)
    ext = Extrinsics({("a", "b"): T_ab, ("c", "b"): T_cb, ("c", "d"): T_cd})
    np.testing.assert_allclose(ext.lookup("a", "d"), T_ab @ np.linalg.inv(T_cb) @ T_cd,
                               atol=1e-12)
    np.testing.assert_allclose(ext.lookup("d", "a") @ ext.lookup("a", "d"), np.eye(4),
                               atol=1e-12)
    np.testing.assert_array_equal(ext.lookup("b", "b"), np.eye(4))
    tr = ext.transform("a", "d")
    assert isinstance(tr, Transform) and (tr.to_frame, tr.from_frame) == ("a", "d")
    # lookups return new arrays; stored ones are read-only
    out = ext.lookup("a", "b")
    out[0, 0] = 5.0
    assert ext.transforms[("a", "b")][0, 0] != 5.0
    with pytest.raises(ValueError):
        ext.transforms[("a", "b")][0, 0] = 1.0
    with pytest.raises(TypeError):
        ext.transforms[("x", "y")] = np.eye(4)  # type: ignore[index]
    # with_transform replaces the pair whatever its direction
    ext2 = ext.with_transform("b", "a", np.eye(4))
    assert ("a", "b") not in ext2.transforms and ("b", "a") in ext2.transforms
    assert ("a", "b") in ext.transforms


def test_lookup_errors():
    ext = Extrinsics({("a", "b"): pose(1), ("c", "d"): pose(2)}, source="ext.json")
    with pytest.raises(InputError, match=r"ext\.json: unknown to frame 'x'; known frames: "
                                         r"\['a', 'b', 'c', 'd'\]"):
        ext.lookup("x", "a")
    with pytest.raises(InputError, match=r"unknown from frame 'y'"):
        ext.lookup("a", "y")
    with pytest.raises(InputError, match=r"ext\.json: no chain of transforms connects 'c' to 'a'; "
                                         r"'c' connects only to \['c', 'd'\]"):
        ext.lookup("a", "c")


def test_loops_take_the_shortest_path():
    T_ab, T_bc = pose(1), pose(2)
    ext = Extrinsics({("a", "b"): T_ab, ("b", "c"): T_bc, ("a", "c"): T_ab @ T_bc})
    assert ext.path("a", "c") == ["c", "a"]


# -- JSON ---------------------------------------------------------------------------------------


def test_json_round_trip(tmp_path):
    ext = Extrinsics({("base", "lidar"): pose(1), ("cam", "lidar"): pose(2)},
                     metadata={"date": "2024_01_01", "method": "rigcal"})
    path = write_extrinsics_json(tmp_path / "ext.json", ext)
    back = read_extrinsics_json(path)
    assert back.source == str(path)
    assert dict(back.metadata) == {"date": "2024_01_01", "method": "rigcal",
                                   "type": "extrinsic_calibration"}
    for key, T in ext.transforms.items():
        np.testing.assert_array_equal(back.transforms[key], T)
    doc = json.loads(extrinsics_json_text(ext))
    assert doc["calibrations"][0]["transform"][12:] == [0.0, 0.0, 0.0, 1.0]  # row-major


def test_bare_list_is_accepted():
    text = json.dumps([_entry("a", "b", pose(4))])
    ext = parse_extrinsics_json(text, "list.json")
    assert list(ext.transforms) == [("a", "b")] and dict(ext.metadata) == {}


def _doc(*entries):
    return json.dumps({"type": "extrinsic_calibration", "calibrations": list(entries)})


NON_RIGID = np.eye(4)
NON_RIGID[0, 0] = 1.01
REFLECTION = np.diag([1.0, 1.0, -1.0, 1.0])
BAD_ROW = np.eye(4)
BAD_ROW[3, 0] = 0.5


@pytest.mark.parametrize(
    "text, match",
    [
        (_doc({"to_frame": "a", "from_frame": "b", "transform": [1, 0, 0, 0] * 3}),
         r"x\.json: calibrations\[0\]\.transform: expected 16 numbers \(row-major 4x4\), got 12"),
        (_doc(_entry("a", "b", NON_RIGID)),
         r"calibrations\[0\]\.transform \(a <- b\): not rigid: the 3x3 block must be a rotation "
         r"\(orthonormal within 0\.001, det \+1\), got \|R\^T R - I\| = 0\.0201"),
        (_doc(_entry("a", "b", REFLECTION)), r"not rigid: .* det = -1"),
        (_doc(_entry("a", "b", BAD_ROW)), r"not rigid: last row must be \[0, 0, 0, 1\]"),
        (_doc({"from_frame": "b", "transform": [0] * 16}),
         r"x\.json: calibrations\[0\]: missing key 'to_frame'"),
        (_doc({"to_frame": "a", "from_frame": "", "transform": [0] * 16}),
         r"calibrations\[0\]\.from_frame: frame name must be a non-empty string"),
        (_doc({"to_frame": "a", "from_frame": "b", "transform": "eye"}),
         r"calibrations\[0\]\.transform: expected a list of 16 numbers"),
        (_doc({"to_frame": "a", "from_frame": "b", "transform": [True] * 16}),
         r"calibrations\[0\]\.transform: expected 16 numbers"),
        (_doc(_entry("a", "b", np.eye(4)), _entry("b", "a", np.eye(4))),
         r"calibrations\[1\]: a second transform between 'b' and 'a'"),
        (_doc(_entry("a", "a", np.eye(4))), r"transform from 'a' to itself"),
        (_doc(), r"x\.json: calibrations: expected a non-empty list"),
        (json.dumps({"type": "x"}), r"x\.json: missing key 'calibrations'"),
        (json.dumps({"calibrations": [1]}), r"calibrations\[0\]: expected an object, got int"),
        ('{"calibrations": [}', r"x\.json: line 1, column 19: invalid JSON"),
        ('{"type": 1, "type": 2}', r"x\.json: duplicate key 'type'"),
    ],
)
def test_json_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_extrinsics_json(text, "x.json")


def test_read_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"none\.json: extrinsics JSON not found"):
        read_extrinsics_json(tmp_path / "none.json")


def test_value_validation():
    with pytest.raises(InputError, match=r"keys must be \(to_frame, from_frame\)"):
        Extrinsics({"ab": np.eye(4)})  # type: ignore[dict-item]
    with pytest.raises(InputError, match=r"expected a 4x4 matrix, got shape \(3, 3\)"):
        Extrinsics({("a", "b"): np.eye(3)})
    with pytest.raises(InputError, match=r"two transforms between 'b' and 'a'"):
        Extrinsics({("a", "b"): np.eye(4), ("b", "a"): np.eye(4)})
    with pytest.raises(InputError, match=r"expected finite numbers"):
        Extrinsics({("a", "b"): np.full((4, 4), np.nan)})
