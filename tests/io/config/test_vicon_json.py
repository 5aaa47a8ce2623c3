"""The original mocap tool's JSON: the shared target definitions and template clouds (measured
against the definitions), the optimizer settings, round trips and every failure path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rigcal.errors import InputError
from rigcal.io.clouds import read_point_cloud
from rigcal.io.config.vicon_json import (
    OptimizerConfig,
    optimizer_config_json_text,
    parse_optimizer_config,
    parse_vicon_target,
    read_optimizer_config,
    read_vicon_target,
    vicon_target_json_text,
    write_vicon_target,
)
from rigcal.targets.definition import TargetKind
from rigcal.targets.surface import surface_distance_m
from rigcal.targets.templates import cylinder_target, diamond_target

DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "vicon_sim"


def shared(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"shared data {path} not present")
    return path


# -- the shared target definitions ---------------------------------------------------------------


def test_shared_diamond_definition():
    t = read_vicon_target(shared("CheckerboardTargetSim.json"))
    assert t.name == "CheckerboardTargetSim"
    assert t.kind is TargetKind.CHECKERBOARD_DIAMOND and t.planar and t.use_lidar_keypoints
    assert t.dims["rows"] == 6 and t.dims["cols"] == 7 and t.dims["square_m"] == 0.029
    assert t.dims["side_m"] == pytest.approx(0.5, abs=1e-8)
    # the four lidar keypoints form a 0.5 m square (the file's +x corner is 20 um off)
    c = t.lidar_keypoints
    sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
    np.testing.assert_allclose(sides, 0.5, atol=3e-5)
    np.testing.assert_allclose([np.linalg.norm(c[0] - c[2]), np.linalg.norm(c[1] - c[3])],
                               0.5 * np.sqrt(2), atol=3e-5)
    assert np.all(c[:, 2] == 0.0)
    # checkerboard inner corners: rows * cols, spaced one square apart
    k = t.camera_keypoints
    assert len(k) == t.dims["rows"] * t.dims["cols"] == 42
    np.testing.assert_allclose(np.diff(k[:7, 0]), 0.029, atol=1e-12)
    # the analytic definition reproduces the file's keypoints
    ref = diamond_target(0.5, 0.029, 6, 7)
    np.testing.assert_allclose(k, ref.camera_keypoints, atol=1e-12)
    np.testing.assert_allclose(c, ref.lidar_keypoints, atol=3e-5)
    # no template_cloud in the file: the analytic template, on the plate
    assert surface_distance_m(t, t.template).max() < 1e-9
    # the file's crop box is +-5 cm around the origin: it holds none of its own keypoints
    assert t.crop_box.bounds() == (-0.05, 0.05, -0.05, 0.05, -0.05, 0.05)
    assert not t.crop_box.contains(c).any()
    assert t.crop_image_px == (20.0, 20.0)


def test_shared_diamond_template_cloud_matches_the_definition():
    t = read_vicon_target(shared("CheckerboardTargetSim.json"),
                          template=shared("checkerboard_target_simulation.pcd"))
    pts = t.template
    assert pts.shape == (100014, 3)
    # measured: the plate is a sheet 1.1 mm thick at z = 0 (z from -0.1 mm to +1 mm)
    assert np.abs(pts[:, 2]).max() < 1.1e-3
    assert surface_distance_m(t, pts).max() < 1.1e-3
    # and it fills the diamond: every keypoint has a template point within 2 mm
    tree = cKDTree(pts[:, :2])
    for kp in (t.lidar_keypoints, t.camera_keypoints):
        d, _ = tree.query(kp[:, :2])
        assert d.max() < 2e-3
    np.testing.assert_allclose(pts[:, :2].mean(axis=0), [0.116, 0.1015], atol=2e-3)


def test_shared_checkerboard_example():
    path = shared("CheckerboardTarget_EXAMPLE.json")
    # its template_cloud is not shipped and it has no lidar keypoints: the diamond size is unknown
    with pytest.raises(InputError, match=r"CheckerboardTarget_EXAMPLE\.json: no template: "
                                         r"template_cloud 'checkerboard_target_EXAMPLE\.pcd' not "
                                         r"found and analytic checkerboard_diamond target needs "
                                         r"dims side_m, square_m, rows, cols; missing side_m; pass "
                                         r"template= or dims="):
        read_vicon_target(path)
    t = read_vicon_target(path, dims={"side_m": 0.5})
    assert t.kind is TargetKind.CHECKERBOARD_DIAMOND
    assert dict(t.dims) == {"rows": 5, "cols": 6, "square_m": 0.029, "side_m": 0.5}
    assert len(t.camera_keypoints) == 30 and t.lidar_keypoints is None
    assert not t.use_lidar_keypoints and t.lidar_points is t.template
    assert t.crop_box.bounds() == (-0.5, 0.75, -0.5, 0.75, -0.15, 0.15)
    assert t.crop_box.contains(t.template).all()
    assert t.crop_image_px == (0.0, 0.0)


def test_shared_cylinder_definition_and_template_cloud():
    path = shared("CylinderTarget.json")
    with pytest.raises(InputError, match=r"CylinderTarget\.json: no template: template_cloud is "
                                         r"empty and analytic cylinder target needs dims "
                                         r"radius_m, height_m; missing radius_m, height_m"):
        read_vicon_target(path)
    cloud = shared("cylinder_target_rotated.pcd")
    t = read_vicon_target(path, template=cloud)
    assert t.kind is TargetKind.CYLINDER and not t.planar
    assert t.lidar_keypoints is None and t.camera_keypoints is None
    assert not t.use_lidar_keypoints
    assert t.crop_box.bounds() == (-0.5, 0.5, -0.3, 0.3, -0.3, 0.3)
    pts = t.template
    # measured on the shared cloud: a 56.4 mm tube along z from z = -0.4956 to -0.0003 m whose
    # axis sits 1 mm off in y, with 63.5 mm collars over the last 29 mm at each end
    body = (pts[:, 2] < -0.04) & (pts[:, 2] > -0.46)
    r = np.hypot(pts[body, 0], pts[body, 1])
    assert np.median(r) == pytest.approx(0.0564, abs=2e-4)
    defined = read_vicon_target(path, template=cloud,
                                dims={"radius_m": 0.0564, "height_m": 0.4953})
    d = surface_distance_m(defined, pts)
    assert d[body].max() < 1.5e-3  # the tube: within the 1 mm axis offset
    assert np.median(d) < 1e-3
    assert d.max() < 9e-3  # the collars stick out 7 mm
    # the analytic cylinder of the same size agrees with the shared cloud
    analytic = cylinder_target(0.0564, 0.4953)
    d2, _ = cKDTree(analytic.template).query(pts[body])
    assert np.percentile(d2, 95) < 4e-3
    # the file's crop box keeps only the top 0.3 m of this cylinder (a box for an x-axis one)
    inside = t.crop_box.contains(pts)
    assert pts[inside, 2].min() >= -0.3 and not inside.all()


# -- templates: passed in, referenced, round trips ---------------------------------------------


def _doc(**changes):
    doc = {"crop_scan": [-0.5, 0.5, -0.5, 0.5, -0.1, 0.1], "crop_image": [10, 10],
           "template_cloud": "", "is_target_2d": True, "use_lidar_keypoints": True,
           "keypoints_lidar": [{"x": 0.0, "y": 0.0, "z": 0.0}],
           "keypoints_camera": [{"x": 0.1, "y": 0.0, "z": 0.0}]}
    doc.update(changes)
    return json.dumps(doc)


def test_template_sources(tmp_path):
    pts = np.random.default_rng(1).normal(size=(50, 3))
    t = parse_vicon_target(_doc(), "t.json", template=pts)
    assert t.kind is TargetKind.CUSTOM and t.name == "t"
    np.testing.assert_array_equal(t.template, pts)
    with pytest.raises(InputError, match=r"t\.json: no template: template_cloud is empty and a "
                                         r"custom target has no analytic template"):
        parse_vicon_target(_doc(), "t.json")
    # a referenced cloud is read from the JSON's folder; a template argument wins over it
    target = diamond_target()
    json_path = write_vicon_target(tmp_path / "diamond.json", target, template_cloud="tpl.pcd")
    back = read_vicon_target(json_path)
    np.testing.assert_array_equal(back.template, target.template)  # float64 PCD: exact
    other = read_vicon_target(json_path, template=pts)
    np.testing.assert_array_equal(other.template, pts)
    frame = read_point_cloud(tmp_path / "tpl.pcd", "x")
    np.testing.assert_array_equal(read_vicon_target(json_path, template=frame).template,
                                  target.template)
    # text parsing does not touch the file system unless told where to look
    text = json_path.read_text()
    with pytest.raises(InputError, match=r"template_cloud 'tpl\.pcd' not looked up"):
        parse_vicon_target(text, "d.json", kind="custom")
    assert len(parse_vicon_target(text, "d.json", template_dir=tmp_path).template) == len(
        target.template)


@pytest.mark.parametrize("make", [lambda: diamond_target(),
                                  lambda: cylinder_target(0.05, 0.4)])
def test_round_trip(tmp_path, make):
    target = make()
    path = write_vicon_target(tmp_path / "t.json", target, template_cloud="t.pcd")
    back = read_vicon_target(path, name=target.name)
    assert back.kind is target.kind and back.name == target.name
    assert back.planar == target.planar and back.use_lidar_keypoints == target.use_lidar_keypoints
    for a, b in ((back.lidar_keypoints, target.lidar_keypoints),
                 (back.camera_keypoints, target.camera_keypoints)):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(back.template, target.template)
    assert back.crop_box.bounds() == target.crop_box.bounds()
    for k, v in target.dims.items():  # inferred again from the keypoints (diamond)
        if k in back.dims:
            assert back.dims[k] == pytest.approx(v, abs=1e-12)
    assert json.loads(vicon_target_json_text(back, "t.pcd")) == json.loads(path.read_text())


def test_kind_override_and_dims_conflict():
    text = (DATA / "CheckerboardTargetSim.json")
    if not text.exists():
        pytest.skip("shared data not present")
    src = text.read_text()
    t = parse_vicon_target(src, "sim.json", kind="custom", template=[[0, 0, 0]])
    assert t.kind is TargetKind.CUSTOM and t.dims["rows"] == 6
    with pytest.raises(InputError, match=r"sim\.json: dims\['rows'\] = 5 contradicts 6 inferred "
                                         r"from the keypoints"):
        parse_vicon_target(src, "sim.json", dims={"rows": 5})
    with pytest.raises(InputError, match=r"sim\.json: unknown target kind 'cone'"):
        parse_vicon_target(src, "sim.json", kind="cone")


def test_lidar_keypoints_off_the_diamond_make_a_custom_target():
    t = diamond_target()
    doc = json.loads(vicon_target_json_text(t))
    doc["keypoints_lidar"][0]["x"] += 0.01
    back = parse_vicon_target(json.dumps(doc), "moved.json", template=t.template)
    assert back.kind is TargetKind.CUSTOM and "side_m" not in back.dims


def test_use_lidar_keypoints_without_keypoints_is_relaxed(caplog):
    with caplog.at_level("WARNING"):
        t = parse_vicon_target(_doc(keypoints_lidar=[], unknown_key=1), "t.json",
                               template=[[0, 0, 0]])
    assert not t.use_lidar_keypoints and t.lidar_keypoints is None
    assert "use_lidar_keypoints is true but keypoints_lidar is empty" in caplog.text
    assert "ignoring unknown keys ['unknown_key']" in caplog.text


@pytest.mark.parametrize(
    "text, match",
    [
        (_doc(crop_scan=[0, 1, 0, 1]), r"t\.json: 'crop_scan' must have 6 numbers, got 4"),
        (_doc(crop_scan=[0, 1, 1, 0, 0, 1]),
         r"t\.json: 'crop_scan' \[x_min, x_max, y_min, y_max, z_min, z_max\]: crop box: y min "
         r"must be below max"),
        (_doc(crop_scan="box"), r"'crop_scan' must be a list of numbers, got 'box'"),
        (_doc(crop_image=[1]), r"'crop_image' must have 2 numbers, got 1"),
        (_doc(template_cloud=3), r"'template_cloud' must be a file name or \"\", got 3"),
        (_doc(is_target_2d="yes"), r"'is_target_2d' must be true or false, got 'yes'"),
        (_doc(keypoints_camera=[{"x": 0, "y": 0}]),
         r"t\.json: keypoints_camera\[0\]: missing key 'z'"),
        (_doc(keypoints_lidar=[{"x": 0, "y": "a", "z": 0}]),
         r"keypoints_lidar\[0\]\.y must be a number, got 'a'"),
        (_doc(keypoints_lidar=[[0, 0, 0]]), r"keypoints_lidar\[0\] must be an object"),
        (_doc(keypoints_lidar={}), r"'keypoints_lidar' must be a list of \{x, y, z\}"),
        (json.dumps({"crop_scan": [0, 1, 0, 1, 0, 1]}), r"t\.json: missing key 'crop_image'"),
        ("[1, 2]", r"t\.json: expected a JSON object, got list"),
        ('{"crop_scan": [0, 1,]}', r"t\.json: line 1, column 21: invalid JSON"),
    ],
)
def test_target_json_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_vicon_target(text, "t.json", template=[[0, 0, 0]])


def test_missing_files(tmp_path):
    with pytest.raises(InputError, match=r"none\.json: target JSON not found"):
        read_vicon_target(tmp_path / "none.json")
    with pytest.raises(InputError, match=r"none\.json: optimizer config not found"):
        read_optimizer_config(tmp_path / "none.json")


# -- optimizer settings ------------------------------------------------------------------------


def test_shared_optimizer_config():
    cfg = read_optimizer_config(shared("OptimizerConfig.json"))
    assert cfg == OptimizerConfig()  # the defaults are the shared file's values
    assert cfg.max_correspondence_iterations == 10
    assert cfg.max_pixel_cor_dist_px == 1000.0 and cfg.max_point_cor_dist_m == 100.0
    assert cfg.error_tol_rot_deg == (0.001, 0.001, 0.001)
    assert cfg.error_tol_trans_m == (0.0001, 0.0001, 0.0001)
    assert cfg.template_downsample_size_m == (0.003, 0.003, 0.003)
    assert cfg.match_centroids and not cfg.match_centroids_on_first_iter_only
    assert cfg.image_noise_px is None and cfg.lidar_noise_m is None and dict(cfg.extra) == {}
    back = parse_optimizer_config(optimizer_config_json_text(cfg), "rt")
    assert back == cfg
    assert json.loads(optimizer_config_json_text(cfg)) == json.loads(
        shared("OptimizerConfig.json").read_text())
    with pytest.raises(AttributeError):
        cfg.match_centroids = False  # type: ignore[misc]


def test_optimizer_config_optional_and_extra_keys():
    doc = json.loads(optimizer_config_json_text(OptimizerConfig()))
    doc.update(image_noise=[1.0, 1.5], lidar_noise=[0.01, 0.01, 0.02], ceres_threads=4)
    cfg = parse_optimizer_config(json.dumps(doc), "o.json")
    assert cfg.image_noise_px == (1.0, 1.5) and cfg.lidar_noise_m == (0.01, 0.01, 0.02)
    assert dict(cfg.extra) == {"ceres_threads": 4}
    assert json.loads(optimizer_config_json_text(cfg)) == doc


def _opt(**changes):
    doc = json.loads(optimizer_config_json_text(OptimizerConfig()))
    for k, v in changes.items():
        if v is None:
            doc.pop(k)
        else:
            doc[k] = v
    return json.dumps(doc)


@pytest.mark.parametrize(
    "text, match",
    [
        (_opt(match_centroids=None), r"o\.json: missing key 'match_centroids'"),
        (_opt(error_tol=None), r"o\.json: missing key 'error_tol'"),
        (_opt(error_tol=[0.001] * 5), r"'error_tol' must have 6 numbers, got 5"),
        (_opt(error_tol=[0.001] * 5 + [0]), r"'error_tol' must be 6 numbers > 0"),
        (_opt(match_centroids=1), r"'match_centroids' must be true or false, got 1"),
        (_opt(max_correspondence_iterations=2.5),
         r"'max_correspondence_iterations' must be a whole number >= 0, got 2\.5"),
        (_opt(max_point_cor_dist="far"), r"'max_point_cor_dist' must be a number >= 0"),
        (_opt(template_downsample_size=[0.003, 0.003]),
         r"'template_downsample_size' must have 3 numbers, got 2"),
        (_opt(image_noise=[1.0, -1.0]), r"'image_noise' must not be negative"),
        ("[]", r"o\.json: expected a JSON object, got list"),
    ],
)
def test_optimizer_config_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_optimizer_config(text, "o.json")
