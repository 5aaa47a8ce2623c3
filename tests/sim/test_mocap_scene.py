"""The simulated motion-capture session written to a folder (rigcal.sim.mocap_scene), and the
`rigcal mocap` pipeline on its default three-sensor rig with no shared view.

The default scene (seed 7, four holds per sensor - what `rigcal demo --mocap` runs): a VLP-16
looking forward with its returns limited to +-50 deg, a pinhole camera looking left and a radtan
camera looking right; the diamond is held four times in each sensor's view and never where
another sensor can see it.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry.se3 import invert, se3_log
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.io.config.camchain import read_camera_file
from rigcal.mocap import read_extrinsics_json
from rigcal.mocap.config import load_mocap_config
from rigcal.mocap.pipeline import run_mocap
from rigcal.problem.compare import pose_error
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sim.mocap_scene import (
    RobotPath,
    SceneSensor,
    SceneTiming,
    default_rig,
    two_sensor_rig,
    write_mocap_scene,
)
from rigcal.targets.templates import cylinder_target

NAMES = ("lidar1", "camera1", "camera2")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    calls = []
    s = write_mocap_scene(tmp_path_factory.mktemp("three"), seed=7, holds=4,
                          progress=lambda d, t: calls.append((d, t)))
    return s, calls


@pytest.fixture(scope="module")
def run(scene):
    s, _ = scene
    return run_mocap(load_mocap_config(s.config_path))


def _rss(std, keys):
    return math.sqrt(sum(std[k] ** 2 for k in keys))


@pytest.mark.slow
def test_every_sensor_is_calibrated_to_the_robot_frame(scene, run):
    s, _ = scene
    assert tuple(run.result.sensors) == NAMES and run.result.reference == "robot"
    assert run.result.converged
    assert run.result.verdict.status == "consistent", run.result.verdict.failed
    errors = {}
    for name in NAMES:
        e0 = pose_error(run.initial[name], s.truth[name])
        e1 = pose_error(run.final[name], s.truth[name])
        std = run.result.sensors[name].std
        std_mm = 1000 * _rss(std, ("x_m", "y_m", "z_m"))
        std_deg = _rss(std, ("roll_deg", "pitch_deg", "yaw_deg"))
        errors[name] = (e0, e1, std_mm, std_deg)
        print(f"{name}: {e0.translation_m * 1e3:.1f} mm {e0.rotation_deg:.2f} deg -> "
              f"{e1.translation_m * 1e3:.2f} mm {e1.rotation_deg:.4f} deg; std {std_mm:.2f} mm "
              f"{std_deg:.4f} deg")
    # The scene has a VLP-16's 15 mm range noise and an exact MCS (write_mocap_scene's default).
    # Measured with seed 7 (initial -> final; reported std, root sum of squares over the axes;
    # NEES of the 6-DOF error), with the per-hold affine error of a camera's grid (issue #23):
    #   lidar1  27.2 mm 5.09 deg -> 0.25 mm 0.008 deg;  std 1.11 mm 0.036 deg; NEES 3.48
    #   (3.78 mm, std 13.4 mm, NEES 1.90 before the range along the ray and ring ends)
    #   camera1 32.5 mm 5.35 deg -> 0.49 mm 0.011 deg;  std 0.43 mm 0.012 deg; NEES 16.5
    #   camera2 30.7 mm 3.53 deg -> 0.10 mm 0.004 deg;  std 0.62 mm 0.016 deg; NEES 1.14
    # seeds 1-8: lidar 0.41-1.59 mm / <= 0.052 deg (std 0.8-2.2 mm), cameras 0.08-0.56 mm / <= 0.011 deg. Before
    # the affine component the cameras' NEES was 0.01-0.13 (std ~10x the error) - camera1 0.11,
    # camera2 0.07 here. One sensor's NEES is checked against a two-sided 99.8 % band of
    # chi2(6), [0.38, 22.5]: a right covariance puts 5 % of the truths outside its 95 % region
    # (camera1 here: 16.5, the 1.1 % tail), and a region 10x too wide is as wrong
    for name, (e0, e1, std_mm, std_deg) in errors.items():
        t0, r0 = e0.translation_m * 1e3, e0.rotation_deg
        t1, r1 = e1.translation_m * 1e3, e1.rotation_deg
        lidar = name == "lidar1"
        assert t0 > 15 and r0 > 3  # the initial calibration is really off
        assert t1 < 0.25 * t0 and r1 < 0.05 * r0, name  # far below the perturbation
        assert t1 < (3.0 if lidar else 1.0) and r1 < (0.1 if lidar else 0.05), name
        # The reported covariance counts each hold's shared error and each frame's MCS error
        # besides the sensor's own noise: the truth is within the band above; the old
        # covariance (one noise scale, every frame independent) put the cameras' truth 20-70
        # std away
        est = run.result.sensors[name]
        e = se3_log(invert(est.T_reference_sensor) @ s.truth[name])
        nees = float(e @ np.linalg.solve(est.covariance, e))
        assert nees < 22.46, name  # chi2(6) 99.9 %
        # the lidar too since its range along the ray and ring ends (seed 7: 3.5; was 1.90 with
        # a 13.4 mm std; benchmarks/mocap_sessions.py, seeds 1-8: median NEES6 5.0)
        assert nees > 0.38, name  # chi2(6) 0.1 %
        assert std_mm < (5.0 if lidar else 10.0) and std_deg < (0.15 if lidar else 0.3), name
        naive = run.fit.sensors[name].covariance_naive
        if name != "lidar1":
            assert float(e @ np.linalg.solve(naive, e)) > 12.59, name


def _still(scene):
    """(start_ns, end_ns, sensor) of every span the target stands still: the holds, the first
    one from the session's start and the last one to its end."""
    spans = [(h.start_ns, h.end_ns, h.sensor) for h in scene.holds]
    spans[0] = (scene.t0_ns, *spans[0][1:])
    spans[-1] = (spans[-1][0], scene.end_ns + 1, spans[-1][2])
    return spans


@pytest.mark.slow
def test_the_sensors_share_no_view(scene, run):
    s, _ = scene
    assert [h.sensor for h in s.holds] == [n for n in NAMES for _ in range(4)]
    for a, b, sensor in _still(s):
        for name in NAMES:
            t = s.frames[name]
            seen = s.target_seen[name][(t >= a) & (t < b)]
            if name == sensor:
                assert seen.all()  # the target is in its own sensor's data while it stands
            else:
                assert not seen.any(), (sensor, name)  # and in no other sensor's data
    # so every kept measurement comes from a hold of its own sensor
    kept = [d for d in run.diagnostics if d.kept]
    assert {d.sensor for d in kept} == set(NAMES)
    for d in kept:
        spans = [sensor for a, b, sensor in _still(s) if a <= d.t_ns < b]
        assert spans == [d.sensor], (d.sensor, d.t_ns)
    counts = run.counts
    for name in NAMES:
        assert counts[name]["kept"] >= 12 and counts[name]["target_not_in_view"] > 60


@pytest.mark.slow
def test_the_folder_holds_what_rigcal_mocap_reads(scene):
    s, calls = scene
    total = sum(len(t) for t in s.frames.values())
    assert calls[-1] == (total, total) and len(calls) == total
    for p in (s.config_path, s.bag_path, s.target_path, s.initial_path, *s.intrinsics.values()):
        assert p.is_file() and p.parent == s.folder
    assert not [p for p in s.folder.iterdir() if p.name.startswith(".")]  # no staging left
    cfg = load_mocap_config(s.config_path)
    assert [x.name for x in cfg.sensors] == list(NAMES)
    lidar = cfg.sensors[0].lidar
    np.testing.assert_allclose(np.degrees(lidar.azimuth_fov_rad), (-50.0, 50.0))
    for sensor in default_rig()[1:]:
        (camera,) = read_camera_file(s.intrinsics[sensor.name]).cameras.values()
        assert camera == sensor.model
    assert type(cfg.sensors[1].camera) is PinholeCamera and cfg.sensors[2].camera.name == "radtan"
    init = read_extrinsics_json(s.initial_path)
    for sensor in s.sensors:
        T0 = init.lookup("base_link", sensor.frame_id)
        np.testing.assert_allclose(T0, s.initial[sensor.name], atol=1e-12)
        T = s.truth[sensor.name]
        # uniform per axis: up to 3 cm and 5 deg
        assert np.all(np.abs(T0[:3, 3] - T[:3, 3]) <= 0.03)
        assert np.all(np.abs(np.degrees(rpy_from_matrix(T[:3, :3].T @ T0[:3, :3]))) <= 5.0 + 1e-9)
    assert len(s.moves) == len(s.holds) - 1
    assert s.gap is not None and s.holds[1].start_ns < s.gap[0] < s.gap[1] < s.holds[1].end_ns


QUICK = SceneTiming(hold_s=0.6, move_s=0.3, lead_s=0.2, sensor_hz=2, gap_hold=None)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_writer_is_seeded(tmp_path):
    a = write_mocap_scene(tmp_path / "a", two_sensor_rig(), seed=3, holds=1, timing=QUICK, exclusive=False)
    b = write_mocap_scene(tmp_path / "b", two_sensor_rig(), seed=3, holds=1, timing=QUICK, exclusive=False)
    c = write_mocap_scene(tmp_path / "c", two_sensor_rig(), seed=4, holds=1, timing=QUICK, exclusive=False)
    for name in ("run.bag", "initial.json", "mocap.yaml", "diamond.json", "camera1.yaml"):
        assert _digest(a.folder / name) == _digest(b.folder / name), name
    assert _digest(a.bag_path) != _digest(c.bag_path)
    assert not np.array_equal(a.initial["lidar1"], c.initial["lidar1"])
    # writing again over an existing scene replaces it
    again = write_mocap_scene(tmp_path / "a", two_sensor_rig(), seed=3, holds=1, timing=QUICK, exclusive=False)
    assert _digest(again.bag_path) == _digest(b.bag_path)
    assert a.gap is None and a.robot.at(0.0)[2, 3] == 0.0


def _sensor(**kw):
    lidar = two_sensor_rig()[0]
    args = dict(name="x", kind="lidar", T_robot_sensor=lidar.T_robot_sensor, model=lidar.model,
                topic="/x", frame_id="x_link")
    args.update(kw)
    return SceneSensor(**args)


def test_bad_sensors_are_refused():
    lidar, camera = two_sensor_rig()
    with pytest.raises(InputError, match="kind must be 'lidar' or 'camera', got 'radar'"):
        _sensor(kind="radar")
    with pytest.raises(InputError, match="a camera's model must be a CameraModel, got LidarModel"):
        _sensor(kind="camera")
    with pytest.raises(InputError, match="a lidar's model must be a LidarModel"):
        _sensor(model=camera.model)
    with pytest.raises(InputError, match="only a lidar has an azimuth window"):
        _sensor(kind="camera", model=camera.model, azimuth_fov_deg=(-10, 10))
    with pytest.raises(InputError, match=r"azimuth_fov_deg: expected -180 <= lo < hi <= 180"):
        _sensor(azimuth_fov_deg=(30, -30))
    with pytest.raises(InputError, match="T_robot_sensor: not rigid: the 3x3 block must be a rotation"):
        _sensor(T_robot_sensor=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InputError, match="topic must start with '/'"):
        _sensor(topic="x")
    with pytest.raises(InputError, match="sigma must be a number > 0"):
        _sensor(sigma=0.0)
    with pytest.raises(InputError, match="must not contain whitespace"):
        _sensor(name="a b")


@pytest.mark.parametrize("kw, message", [
    (dict(seed=-1), "seed must be an integer >= 0, got -1"),
    (dict(seed=1.5), "seed must be an integer >= 0"),
    (dict(holds=0), r"holds must be an integer in 1..100 per sensor, got 0"),
    (dict(holds=(2, 2)), r"holds must give one integer in 1..100 per sensor \(3 sensors\)"),
    (dict(sensors=two_sensor_rig()[:1]), r"exactly one lidar and at least one camera, got lidar1 \(lidar\)"),
    (dict(sensors=(*two_sensor_rig(), _sensor())), "exactly one lidar"),
    (dict(sensors=(two_sensor_rig()[0], two_sensor_rig()[1], two_sensor_rig()[1])), r"share the name \['camera1'\]"),
    (dict(target=cylinder_target(0.05, 0.5)), "target must be a checkerboard diamond"),
    (dict(timing=SceneTiming(gap_hold=20)), "gap_hold 20 but the session has only 12 holds"),
    (dict(perturbation=(0.03,)), r"perturbation must be \(metres, degrees\)"),
    (dict(initial_sigma=(0.0, 3.0)), "initial_sigma"),
    (dict(pixel_noise_sigma=-1.0), "pixel_noise_sigma must be >= 0"),
    (dict(exclusive="yes"), "exclusive must be true or false"),
])
def test_bad_requests_are_refused_before_anything_is_written(tmp_path, kw, message):
    with pytest.raises(InputError, match=message):
        write_mocap_scene(tmp_path / "s", **kw)
    assert not (tmp_path / "s").exists()


def test_bad_clock_and_path_values_are_refused():
    with pytest.raises(InputError, match="SceneTiming.hold_s: expected a duration > 0"):
        SceneTiming(hold_s=0.0)
    with pytest.raises(InputError, match=r"SceneTiming.sensor_hz: expected an integer rate in 1..1000"):
        SceneTiming(sensor_hz=2.5)
    with pytest.raises(InputError, match=r"SceneTiming.gap_s: expected 0 <= start < end <= hold_s"):
        SceneTiming(gap_s=(0.5, 2.0))
    with pytest.raises(InputError, match="RobotPath.velocity_mps: expected three finite numbers"):
        RobotPath(velocity_mps=(0.01, 0.0))
