"""Motion-capture calibration on a non-overlapping rig with known truth (keypoint level)."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.dataset import SensorKind
from rigcal.errors import ConfigError, ConvergenceError, InputError
from rigcal.geometry.se3 import from_rt, invert, se3_exp, transform_points
from rigcal.geometry.so3 import matrix_from_rpy, so3_log
from rigcal.problem.mocap import MocapOptions, MocapSensor, TargetObservation, calibrate_mocap
from rigcal.sensors.camera.radtan import RadtanCamera
from rigcal.targets.surface import TargetSurface
from rigcal.targets.templates import cylinder_target

R_OPT = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # columns: optical x, y, z in a body x-fwd frame


def _pose(xyz, rpy_deg, optical=False):
    R = matrix_from_rpy(np.radians(rpy_deg))
    return from_rt(R @ R_OPT if optical else R, xyz)


def _diamond():
    h = 0.5
    corners = np.array([[0, h, 0], [h, 0, 0], [0, -h, 0], [-h, 0, 0]], float)  # lidar keypoints
    g = np.arange(-3, 4) * 0.06
    inner = np.array([[x, y, 0.0] for y in g[:6] for x in g[:5]])  # checkerboard corners
    return corners, inner


def _cylinder(rng, n=4000, r=0.15, h=1.0):
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(-h / 2, h / 2, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), z])


def _camera():
    return RadtanCamera(1280, 960, np.array([900.0, 900.0, 639.5, 479.5, -0.05, 0.01, 0.0, 0.0, 0.0]))


TRUTH = {
    "lidar1": _pose([0.3, 0.0, 0.5], [0.5, -1.0, 2.0]),  # looks forward
    "camera1": _pose([0.0, 0.25, 0.4], [0.0, 0.0, 90.0], optical=True),  # looks left
    "camera2": _pose([0.0, -0.25, 0.4], [0.0, 5.0, -90.0], optical=True),  # looks right
}


def _observations(rng, n_each, noise_px=0.2, noise_m=0.002, cylinder_for=()):
    cam = _camera()
    corners, inner = _diamond()
    cyl = _cylinder(rng)
    obs = []
    for name, T_R_S in TRUTH.items():
        fwd = T_R_S[:3, 2] if name.startswith("camera") else T_R_S[:3, 0]
        for k in range(n_each):
            d = rng.uniform(2.0, 4.0)
            centre = T_R_S[:3, 3] + d * fwd + rng.uniform(-0.4, 0.4, 3) * [1, 1, 0.5]
            # target z axis toward the sensor, with tilt; make its frame
            z = -fwd + rng.normal(0, 0.25, 3)
            z /= np.linalg.norm(z)
            x = np.cross([0, 0, 1], z)
            x /= np.linalg.norm(x)
            R = np.column_stack([x, np.cross(z, x), z]) @ matrix_from_rpy(np.radians([0, 0, rng.uniform(-30, 30)]))
            T_R_T = from_rt(R, centre)
            T_S_T = invert(T_R_S) @ T_R_T
            t = int(k * 1e8)
            if name in cylinder_for:
                pts = cyl[rng.choice(len(cyl), 300, replace=False)]
                P = pts @ T_S_T[:3, :3].T + T_S_T[:3, 3]
                if name.startswith("camera"):
                    uv, ok = cam.project(P)
                    obs.append(TargetObservation(name, "cylinder", t, T_R_T, uv[ok] + rng.normal(0, noise_px, (ok.sum(), 2))))
                else:
                    obs.append(TargetObservation(name, "cylinder", t, T_R_T, P + rng.normal(0, noise_m, P.shape)))
            elif name.startswith("camera"):
                uv, ok = cam.project(inner @ T_S_T[:3, :3].T + T_S_T[:3, 3])
                assert ok.all()
                obs.append(TargetObservation(name, "diamond", t, T_R_T, uv + rng.normal(0, noise_px, uv.shape), inner))
            else:
                P = corners @ T_S_T[:3, :3].T + T_S_T[:3, 3]
                obs.append(TargetObservation(name, "diamond", t, T_R_T, P + rng.normal(0, noise_m, P.shape), corners))
    return obs


def _sensors(cam_sigma=0.2, lidar_sigma=0.002):
    return [
        MocapSensor("lidar1", SensorKind.LIDAR, sigma=lidar_sigma),
        MocapSensor("camera1", SensorKind.CAMERA, _camera(), sigma=cam_sigma),
        MocapSensor("camera2", SensorKind.CAMERA, _camera(), sigma=cam_sigma),
    ]


def _perturbed(rng):
    out = {}
    for k, T in TRUTH.items():
        xi = np.concatenate([np.radians(rng.uniform(-5, 5, 3)), rng.uniform(-0.03, 0.03, 3)])
        out[k] = T @ se3_exp(xi)
    return out


def _errors(result):
    out = {}
    for k, T in TRUTH.items():
        E = result.sensors[k].T_reference_sensor
        out[k] = (np.linalg.norm(E[:3, 3] - T[:3, 3]), np.degrees(np.linalg.norm(so3_log(T[:3, :3].T @ E[:3, :3]))))
    return out


def _errors_of(result, name):
    T, E = TRUTH[name], result.sensors[name].T_reference_sensor
    return np.linalg.norm(E[:3, 3] - T[:3, 3]), np.degrees(np.linalg.norm(so3_log(T[:3, :3].T @ E[:3, :3])))


def test_non_overlapping_rig_with_diamond_targets_noise_free():
    rng = np.random.default_rng(0)
    obs = _observations(rng, 5, noise_px=0.0, noise_m=0.0)
    r = calibrate_mocap(_sensors(), obs, _perturbed(rng))
    for name, (t, a) in _errors(r).items():
        assert t < 1e-6 and a < 1e-5, (name, t, a)
    assert r.reference == "robot" and set(r.reprojection_px) == {"robot-camera1", "robot-camera2"}


def test_non_overlapping_rig_with_noise_within_reported_uncertainty():
    rng = np.random.default_rng(1)
    obs = _observations(rng, 15)
    r = calibrate_mocap(_sensors(), obs, _perturbed(rng))
    for name, (t, a) in _errors(r).items():
        s = r.sensors[name].std
        t_std = np.linalg.norm([s["x_m"], s["y_m"], s["z_m"]])
        assert t < 4 * t_std + 1e-4, (name, t, t_std)
        assert t < 0.005 and a < 0.1, (name, t, a)
    assert r.reprojection_px["robot-camera1"] == pytest.approx(0.2 * np.sqrt(2), rel=0.3)
    # every sensor-to-sensor transform, with its propagated uncertainty
    assert list(r.relative) == ["lidar1-camera1", "lidar1-camera2", "camera1-camera2"]
    for key, rel in r.relative.items():
        T_true = invert(TRUTH[rel.to]) @ TRUTH[rel.frm]
        err = np.linalg.norm(rel.T_to_from[:3, 3] - T_true[:3, 3])
        std_t = np.linalg.norm([rel.std[k] for k in ("x_m", "y_m", "z_m")])
        assert 0 < std_t and err < 4 * std_t + 1e-4, (key, err, std_t)


@pytest.mark.slow
def test_cylinder_targets_need_correspondence_iterations_and_converge():
    rng = np.random.default_rng(2)
    obs = _observations(rng, 30, noise_m=0.001, noise_px=0.2, cylinder_for=("lidar1",))
    cyl = _cylinder(np.random.default_rng(99), n=20000)
    r = calibrate_mocap(_sensors(), obs, _perturbed(rng), templates={"cylinder": cyl})
    t, a = _errors(r)["lidar1"]
    assert r.noise_iterations > 1  # correspondences were re-estimated
    assert t < 0.01 and a < 0.2, (t, a)


def _near_half_cylinder_observations(rng, n_obs, noise_m=0.0):
    """Lidar1 sees only the half of a cylinder (rigcal.targets, top at z = 0) that faces it."""
    target = cylinder_target(0.1, 0.8)
    T_R_S = TRUTH["lidar1"]
    obs = []
    for k in range(n_obs):
        d = rng.uniform(2.0, 4.0)
        centre = T_R_S[:3, 3] + d * T_R_S[:3, 0] + rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.4]
        R = matrix_from_rpy(np.radians(rng.uniform([-30, -30, -180], [30, 30, 180])))
        T_R_T = from_rt(R, centre - R @ [0.0, 0.0, -0.4])
        T_T_S = invert(T_R_T) @ T_R_S
        a = rng.uniform(0, 2 * np.pi, 4000)
        p = np.column_stack([0.1 * np.cos(a), 0.1 * np.sin(a), rng.uniform(-0.8, 0.0, 4000)])
        facing = np.einsum("ni,ni->n", np.column_stack([np.cos(a), np.sin(a), 0 * a]), T_T_S[:3, 3] - p) > 0
        P = transform_points(invert(T_T_S), p[facing][:200])
        obs.append(TargetObservation("lidar1", "cylinder", int(k * 1e8), T_R_T, P + rng.normal(0, noise_m, P.shape)
                                     if noise_m else P))
    return target, obs


def test_surface_correspondences_remove_the_centroid_bias_of_a_half_seen_cylinder():
    rng = np.random.default_rng(7)
    target, obs = _near_half_cylinder_observations(rng, 15)
    sensor = [MocapSensor("lidar1", SensorKind.LIDAR, sigma=0.002)]
    start = {"lidar1": _perturbed(rng)["lidar1"]}
    surfaces = {"cylinder": TargetSurface.of(target)}
    exact = calibrate_mocap(sensor, obs, start, surfaces)
    t, a = _errors_of(exact, "lidar1")
    assert t < 1e-5 and a < 1e-4, (t, a)
    assert exact.rmse_m["robot-lidar1"] < 1e-6
    paper = calibrate_mocap(sensor, obs, start, surfaces, MocapOptions(correspondences="centroid"))
    t_paper, _ = _errors_of(paper, "lidar1")
    assert t_paper > 0.005  # the scan's centroid is not the template's: centimetre-level bias
    # a template cloud instead of the analytic surface: local planes, sub-millimetre (least
    # squares, the default: the cloud's discretisation errors, symmetric about the surface,
    # cancel in it)
    cloud = calibrate_mocap(sensor, obs, start, {"cylinder": target.template})
    t_cloud, a_cloud = _errors_of(cloud, "lidar1")
    assert t_cloud < 2e-4 and a_cloud < 0.005, (t_cloud, a_cloud)
    # the noise model takes them for per-hold errors (every observation its own hold): weighted
    # by it (estimator "gls") the estimate moves within its uncertainty (0.76 mm here, std
    # about 1 mm), still sub-millimetre and inside its region
    from rigcal.study.coverage import CHI2_95_6, nees

    weighted = calibrate_mocap(sensor, obs, start, {"cylinder": target.template}, MocapOptions(estimator="gls"))
    est = weighted.sensors["lidar1"]
    assert _errors_of(weighted, "lidar1")[0] < 1e-3
    assert nees(est.T_reference_sensor, TRUTH["lidar1"], est.covariance)[0] < CHI2_95_6


def test_surface_correspondences_with_range_noise_stay_within_the_reported_uncertainty():
    rng = np.random.default_rng(8)
    target, obs = _near_half_cylinder_observations(rng, 30, noise_m=0.005)
    sensor = [MocapSensor("lidar1", SensorKind.LIDAR, sigma=0.005)]
    r = calibrate_mocap(sensor, obs, {"lidar1": _perturbed(rng)["lidar1"]}, {"cylinder": TargetSurface.of(target)})
    t, a = _errors_of(r, "lidar1")
    s = r.sensors["lidar1"].std
    assert t < 4 * np.linalg.norm([s["x_m"], s["y_m"], s["z_m"]]) + 1e-4, (t, s)
    assert t < 0.003 and a < 0.1, (t, a)
    assert r.rmse_m["robot-lidar1"] == pytest.approx(0.005, rel=0.15)  # the point-to-surface distance


def _ray_cast_cylinder_session(seed, range_noise_m, holds=4, frames=5):
    """A VLP-16 (rigcal.sim's paper rig) scanning the paper's thin cylinder (56.4 mm tube) held
    still ``holds`` times at 1.6-3 m, with range noise along every ray; exact MCS. (observations,
    truth, start 2 cm / 2 deg off, surfaces)."""
    import math

    from rigcal.sim.mocap import (CYLINDER_HEIGHT_M, CYLINDER_RADIUS_M, LIDAR, SURFACE_TARGET, Placement,
                                  cast_lidar, paper_rig, sample_target_pose)
    from rigcal.sim.raw.lidar import vlp16

    rng = np.random.default_rng([seed, 1])
    rig = paper_rig(lidar=vlp16(range_sigma_m=range_noise_m))
    target = cylinder_target(CYLINDER_RADIUS_M, CYLINDER_HEIGHT_M, name="cylinder")
    obs = []
    for h in range(holds):
        T_mr = from_rt(matrix_from_rpy([0.0, 0.0, rng.uniform(-math.pi, math.pi)]), [*rng.uniform(-2, 2, 2), 0.0])
        T_mt = sample_target_pose(rig, LIDAR, target, T_mr, rng, Placement(distance_range_m=(1.6, 3.0),
                                                                             clutter_boxes=0))
        for k in range(frames):
            cloud = cast_lidar(rig.lidar, T_mr @ rig.T_robot_lidar, target, T_mt, (), rng, range_sigma_m=range_noise_m)
            pts = cloud.points_xyz[cloud.fields["surface"] == SURFACE_TARGET]
            obs.append(TargetObservation("lidar1", "cylinder", int((10 * h + k) * 2.5e8), invert(T_mr) @ T_mt, pts,
                                         hold=str(h)))
    d = rng.normal(size=6)
    d[:3] *= math.radians(2.0) / np.linalg.norm(d[:3])
    d[3:] *= 0.02 / np.linalg.norm(d[3:])
    return obs, rig.T_robot_lidar, rig.T_robot_lidar @ se3_exp(d), {"cylinder": TargetSurface.of(target)}


def test_a_thin_cylinder_under_range_noise_is_tied_by_each_points_range_along_its_ray():
    """A VLP-16's 15 mm of range noise across a 56 mm tube makes its points' closest surface
    points biased (the tube looks fatter, its axis nearer): the point-to-surface distance was
    centimetres off outside its region; the range along each ray (the default) holds the truth
    in its region about as often as it says."""
    from rigcal.geometry.se3 import se3_log
    from rigcal.problem.consistency import mocap_verdict
    from rigcal.problem.mocap import calibrate_mocap_fit

    sensor = [MocapSensor("lidar1", SensorKind.LIDAR, sigma=0.01)]
    out = {True: [], False: []}
    for seed in range(6):
        obs, truth, start, surfaces = _ray_cast_cylinder_session(seed, 0.015)
        for ranges in out:
            fit = calibrate_mocap_fit(sensor, obs, {"lidar1": start}, surfaces, MocapOptions(curved_ranges=ranges))
            est = fit.result.sensors["lidar1"]
            e = se3_log(invert(est.T_reference_sensor) @ truth)
            out[ranges].append((np.linalg.norm(e[3:]), float(e @ np.linalg.solve(est.covariance, e))))
            f = fit.sensors["lidar1"]
            if ranges:  # the tube it ranged, for the verdict's thin-tube note (15 mm on 56.4 mm)
                assert f.curved_target == "cylinder" and f.curved_radius_m == pytest.approx(0.0564)
                assert "thin" in {c.name for c in mocap_verdict(fit).checks}
            else:
                assert f.curved_target == "" and np.isnan(f.curved_radius_m)
    ray, surf = np.array(out[True]), np.array(out[False])
    inside_ray, inside_surf = np.mean(ray[:, 1] <= 12.59), np.mean(surf[:, 1] <= 12.59)
    assert inside_ray >= 4 / 6, ray
    assert inside_surf <= 3 / 6, surf  # the biased model: confidently wrong
    assert np.median(ray[:, 0]) < 0.7 * np.median(surf[:, 0]), (ray, surf)


def test_correspondence_scheme_is_checked():
    with pytest.raises(ConfigError, match="correspondences must be one of"):
        MocapOptions(correspondences="magic")
    with pytest.raises(ConfigError, match="curved_ranges must be true or false"):
        MocapOptions(curved_ranges="yes")


def test_bad_input_is_refused():
    rng = np.random.default_rng(3)
    obs = _observations(rng, 2)
    with pytest.raises(InputError, match="never saw a target"):
        calibrate_mocap(_sensors() + [MocapSensor("lidar2", SensorKind.LIDAR)], obs, {**_perturbed(rng), "lidar2": np.eye(4)})
    with pytest.raises(InputError, match="no initial calibration"):
        calibrate_mocap(_sensors(), obs, {"lidar1": np.eye(4)})
    with pytest.raises(InputError, match="no keypoint correspondences and no template"):
        bad = obs + [TargetObservation("lidar1", "cylinder", 0, np.eye(4), np.ones((5, 3)))]
        calibrate_mocap(_sensors(), bad, _perturbed(rng))
    with pytest.raises(InputError, match="measures pixels"):
        bad = obs + [TargetObservation("camera1", "diamond", 0, np.eye(4), np.ones((4, 3)), np.ones((4, 3)))]
        calibrate_mocap(_sensors(), bad, _perturbed(rng))
    with pytest.raises(ConfigError, match="needs a camera model"):
        MocapSensor("c", SensorKind.CAMERA)
    ok = TargetObservation("lidar1", "diamond", 0, np.eye(4), np.ones((5, 3)), edge_rays=[])
    assert ok.edge_rays.shape == (0, 6) and not ok.edge_rays.flags.writeable
    for rays in (np.zeros((2, 5)), np.zeros(6), [[np.nan] * 6]):
        with pytest.raises(InputError, match=r"edge_rays must be finite numbers of shape \(E, 6\)"):
            TargetObservation("lidar1", "diamond", 0, np.eye(4), np.ones((5, 3)), edge_rays=rays)


# --------------------------------------------------------------------------- overlap and mixed

OVERLAP_TRUTH = {
    "lidar1": _pose([0.3, 0.0, 0.5], [0.5, -1.0, 2.0]),
    "camera1": _pose([0.25, 0.1, 0.45], [0.0, 2.0, -3.0], optical=True),  # also looks forward
}


def _overlap_observations(rng, n, mcs_noise_m=0.00015, mcs_noise_rad=0.0005):
    cam = _camera()
    corners, inner = _diamond()
    obs = []
    for k in range(n):
        centre = np.array([3.0 + rng.uniform(0, 1.5), rng.uniform(-0.5, 0.5), 0.5 + rng.uniform(-0.3, 0.3)])
        z = np.array([-1.0, 0, 0]) + rng.normal(0, 0.2, 3)
        z /= np.linalg.norm(z)
        x = np.cross([0, 0, 1], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z]) @ matrix_from_rpy(np.radians([0, 0, rng.uniform(-30, 30)]))
        T_true = from_rt(R, centre)
        T_mcs = T_true @ se3_exp(np.concatenate([rng.normal(0, mcs_noise_rad, 3), rng.normal(0, mcs_noise_m, 3)]))
        t = int(k * 1e8)
        for name, T_R_S in OVERLAP_TRUTH.items():
            T_S_T = invert(T_R_S) @ T_true
            if name == "camera1":
                uv, ok = cam.project(inner @ T_S_T[:3, :3].T + T_S_T[:3, 3])
                obs.append(TargetObservation(name, "diamond", t, T_mcs, uv + rng.normal(0, 0.2, uv.shape), inner))
            else:
                P = corners @ T_S_T[:3, :3].T + T_S_T[:3, 3]
                obs.append(TargetObservation(name, "diamond", t + 1000, T_mcs, P + rng.normal(0, 0.002, P.shape), corners))
    return obs


def _relative_error(result):
    T_lc = invert(result.sensors["lidar1"].T_reference_sensor) @ result.sensors["camera1"].T_reference_sensor
    T_true = invert(OVERLAP_TRUTH["lidar1"]) @ OVERLAP_TRUTH["camera1"]
    return float(np.linalg.norm(T_lc[:3, 3] - T_true[:3, 3]))


def _overlap_sensors():
    return [MocapSensor("lidar1", SensorKind.LIDAR, sigma=0.002), MocapSensor("camera1", SensorKind.CAMERA, _camera(), sigma=0.2)]


def test_overlapping_views_share_target_poses_under_mcs_priors():
    errs_fixed, errs_gls, errs_joint = [], [], []
    for seed in range(3):
        rng = np.random.default_rng(10 + seed)
        obs = _overlap_observations(rng, 15, mcs_noise_m=0.002, mcs_noise_rad=0.002)  # a poor MCS
        init = {k: T @ se3_exp(np.r_[np.radians(rng.uniform(-3, 3, 3)), rng.uniform(-0.02, 0.02, 3)]) for k, T in OVERLAP_TRUTH.items()}
        fixed = calibrate_mocap(_overlap_sensors(), obs, init, options=MocapOptions(estimator="ls"))
        gls = calibrate_mocap(_overlap_sensors(), obs, init, options=MocapOptions(estimator="gls"))
        joint = calibrate_mocap(_overlap_sensors(), obs, init, options=MocapOptions(target_pose_sigma=(0.002, 0.002)))
        errs_fixed.append(_relative_error(fixed))
        errs_gls.append(_relative_error(gls))
        errs_joint.append(_relative_error(joint))
    # sharing the target pose between the two sensors' simultaneous views removes the MCS error
    # from their relative pose; each sensor on its own keeps it, weighted by its noise model
    # (estimator "gls") less of it (here 3.1 mm in the mean, least squares 7.1, weighted 5.1)
    assert np.mean(errs_joint) < 0.5 * np.mean(errs_fixed), (errs_joint, errs_fixed)
    assert np.mean(errs_joint) < np.mean(errs_gls) < np.mean(errs_fixed), (errs_joint, errs_gls, errs_fixed)


def test_the_gls_estimator_weighs_each_sensor_unless_the_sensors_are_coupled_by_estimated_target_poses():
    rng = np.random.default_rng(14)
    obs = _overlap_observations(rng, 15, mcs_noise_m=0.002, mcs_noise_rad=0.002)
    init = {k: T @ se3_exp(np.r_[np.radians(rng.uniform(-3, 3, 3)), rng.uniform(-0.02, 0.02, 3)])
            for k, T in OVERLAP_TRUTH.items()}
    from rigcal.problem.mocap import calibrate_mocap_fit

    g = calibrate_mocap_fit(_overlap_sensors(), obs, init, options=MocapOptions(estimator="gls"))
    ls = calibrate_mocap(_overlap_sensors(), obs, init)  # the default: least squares
    for name, est in g.result.sensors.items():
        other = ls.sensors[name]
        d = np.linalg.norm(est.T_reference_sensor[:3, 3] - other.T_reference_sensor[:3, 3])
        f = g.sensors[name]
        if f.estimator == "gls":
            # one weighted step apart: not the same estimate, within the uncertainty of either
            assert f.weighting_test <= 1.0 and 1e-7 < d < 3.0 * np.sqrt(np.trace(other.covariance[3:, 3:]))
        else:  # the residuals reject the model's weights: least squares stands
            assert f.estimator == "ls" and f.weighting_test > 1.0 and d == 0.0
    assert "gls" in {f.estimator for f in g.sensors.values()}
    # coupled through the target poses: the joint least-squares solution stands either way
    opts = dict(target_pose_sigma=(0.002, 0.002))  # the estimator asked for: gls, then ls
    a = calibrate_mocap(_overlap_sensors(), obs, init, options=MocapOptions(estimator="gls", **opts))
    b = calibrate_mocap(_overlap_sensors(), obs, init, options=MocapOptions(estimator="ls", **opts))
    for name in a.sensors:
        np.testing.assert_array_equal(a.sensors[name].T_reference_sensor, b.sensors[name].T_reference_sensor)
        np.testing.assert_array_equal(a.sensors[name].covariance, b.sensors[name].covariance)
    with pytest.raises(ConfigError, match="estimator must be one of gls, ls"):
        MocapOptions(estimator="wls")


@pytest.mark.slow  # twelve sessions of eight holds: about a minute
def test_under_mcs_noise_per_capture_gls_puts_the_cameras_closer_than_least_squares():
    """Issue 23: with 0.15 mm / 0.3 mrad per capture the cameras came out mm off. Least squares
    weighs every frame alike; the estimate under the estimated noise model (per-capture and
    per-hold MCS errors) weighs a view by how much it tells (estimator "gls"). Measured on 40
    sessions per error model (seed 1; camera 1.50 -> 0.58 mm under this model): docs/mocap.md."""
    from rigcal.study.coverage import mocap_coverage

    g = mocap_coverage(6, seed=3, holds=8, error_model="mcs_capture", estimator="gls")
    ls = mocap_coverage(6, seed=3, holds=8, error_model="mcs_capture")
    assert g["estimator"] == "gls" and ls["estimator"] == "ls" and g["failed"] == ls["failed"] == 0
    cam_g, cam_l = (np.asarray(x["per_sensor"]["camera"]["errors_m"]) for x in (g, ls))
    assert np.median(cam_g) < 0.7 * np.median(cam_l), (cam_g, cam_l)
    assert g["per_sensor"]["camera"]["inside_6dof"] >= 5 / 6


def test_mocap_and_board_placements_in_one_problem():
    from rigcal.problem.calibrate import CalibrationOptions, calibrate
    from rigcal.sim import SimSensor, make_rig_placements, simulate

    sims = [
        SimSensor("lidar1", SensorKind.LIDAR, OVERLAP_TRUTH["lidar1"], sigma_m=0.01),
        SimSensor("camera1", SensorKind.CAMERA, OVERLAP_TRUTH["camera1"]),
    ]
    res = {"mocap": [], "boards": [], "mixed": []}
    for seed in range(4):
        rng = np.random.default_rng(40 + seed)
        obs = _overlap_observations(rng, 5, mcs_noise_m=0.0015, mcs_noise_rad=0.0015)
        init = {k: T @ se3_exp(np.r_[np.radians(rng.uniform(-3, 3, 3)), rng.uniform(-0.02, 0.02, 3)]) for k, T in OVERLAP_TRUTH.items()}
        boards = simulate(sims, make_rig_placements(rng, sims, 10), rng=rng, reference="lidar1").dataset
        res["mocap"].append(_relative_error(calibrate_mocap(_overlap_sensors(), obs, init)))
        b = calibrate(boards, CalibrationOptions(mode="fcpe"))
        T_lc = b.sensors["camera1"].T_reference_sensor
        T_true = invert(OVERLAP_TRUTH["lidar1"]) @ OVERLAP_TRUTH["camera1"]
        res["boards"].append(float(np.linalg.norm(T_lc[:3, 3] - T_true[:3, 3])))
        res["mixed"].append(_relative_error(calibrate_mocap(_overlap_sensors(), obs, init, boards=boards)))
    mean = {k: float(np.mean(v)) for k, v in res.items()}
    assert mean["mixed"] <= min(mean["mocap"], mean["boards"]) * 1.05, mean


# ---------------------------------------------------------------- honest uncertainty, bad starts


def _camera_holds(rng, holds=4, frames=5, mcs_rad=0.002, mcs_m=0.001, pixel_sigma=0.5):
    """A camera's corner observations of a diamond held still ``holds`` times (``frames``
    frames each, one MCS error per hold) and the true T_robot_camera."""
    from rigcal.geometry.se3 import se3_exp
    from rigcal.sim.mocap import CAMERA, Placement, paper_rig, sample_target_pose
    from rigcal.targets.templates import diamond_target

    rig = paper_rig()
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    kp = target.camera_keypoints
    obs, t = [], 0
    for h in range(holds):
        T_mr = np.eye(4)
        T_mr[:2, 3] = rng.uniform(-1, 1, 2)
        T_rt = sample_target_pose(rig, CAMERA, target, T_mr, rng, Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0))
        T_rt = invert(T_mr) @ T_rt
        T_st = invert(rig.T_robot_camera) @ T_rt
        uv, _ = rig.camera.project(kp @ T_st[:3, :3].T + T_st[:3, 3])
        xi = np.concatenate([rng.normal(0, mcs_rad, 3), rng.normal(0, mcs_m, 3)])
        for _ in range(frames):
            t += 250_000_000
            obs.append(TargetObservation("camera", "diamond", t, T_rt @ se3_exp(xi),
                                         uv + rng.normal(0, pixel_sigma, uv.shape), kp))
    return rig, obs


def test_a_start_behind_the_camera_is_recovered_by_pnp():
    from rigcal.problem.mocap import calibrate_mocap_fit

    rig, obs = _camera_holds(np.random.default_rng(3))
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # turned half round: every corner behind the camera
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    fit = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera @ flip})
    est = fit.result.sensors["camera"]
    assert fit.sensors["camera"].start == "pnp"
    good = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera})
    assert good.sensors["camera"].start == "initial"
    dt, dr = _err(est.T_reference_sensor, good.result.sensors["camera"].T_reference_sensor)
    assert dt < 1e-6 and dr < 1e-5  # the same answer as from a good start
    assert _err(est.T_reference_sensor, rig.T_robot_camera)[0] < 0.03
    assert min(est.std.values()) > 0


def test_a_camera_nothing_can_place_is_refused_not_converged():
    rig, obs = _camera_holds(np.random.default_rng(4), holds=3, frames=1)
    few = [TargetObservation(o.sensor, o.target, o.t_ns, o.T_robot_target, o.measured[:3],
                             o.keypoints_target[:3]) for o in obs]  # 3 corners: no PnP
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    with pytest.raises(ConvergenceError, match="project into the image"):
        calibrate_mocap([sensor], few, {"camera": rig.T_robot_camera @ flip})


def test_hold_correlated_errors_widen_the_covariance():
    from rigcal.problem.mocap import calibrate_mocap_fit

    rig, obs = _camera_holds(np.random.default_rng(5), holds=5, frames=5)
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    fit = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera})
    f = fit.sensors["camera"]
    cov = fit.result.sensors["camera"].covariance
    assert f.holds == 5 and f.observations == 25
    assert f.hold_inflation > 3.0
    assert np.trace(cov) > 3.0 * np.trace(f.covariance_naive)
    assert 0.4 < f.noise_sigma < 0.6  # the camera's own noise (0.5 px), told 1 px
    # the MCS's 2 mrad / 1 mm per hold, from 5 holds: for a small grid a turn of the target
    # looks much like its shift and like an affine distortion of its image, so the likelihood
    # may put part of it in the other shapes (here the rotation in view_affine, 0.085 px, and
    # 1.3 mm in translation; seeds 7-12 give 1.1-2.1 mrad and 0.4-1.2 mm)
    assert 0.25 < max(f.hold_sigma[0] / 0.002, f.hold_sigma[1] / 0.001) < 2.5


@pytest.mark.slow  # 20 sessions of eight holds: about 2 minutes (CI runs it)
def test_reported_95_percent_regions_hold_the_truth():
    """Issue 23, item 2: sessions with a per-hold MCS error (1 mm / 2 mrad) and per-corner
    biases, eight holds per sensor: the regions hold the truth as often as they say and are not
    too wide (median NEES per DOF within 0.5-2 per sensor kind; measured on 20 sessions: lidar
    0.95 inside, 0.80, camera 1.00, 0.84; docs/mocap.md has 180 per model). The old covariance
    (one noise scale, frames independent) held 0.23."""
    from rigcal.study.coverage import mocap_coverage

    r = mocap_coverage(20, seed=1, holds=8)
    assert r["failed"] == 0 and r["checks"] == 40
    assert r["inside_6dof"] >= 0.9 and r["inside_3dof_translation"] >= 0.9
    assert r["naive_inside_6dof"] < r["inside_6dof"] - 0.3  # the old covariance did not
    for s in ("lidar", "camera"):
        k = r["per_sensor"][s]
        assert k["inside_6dof"] >= 0.85, (s, k)
        assert 0.5 <= k["nees_median"] <= 2.0, (s, k)
        assert 0.8 < k["noise_ratio_median"] < 1.25


def _spied_coverage(monkeypatch, *args, **kwargs):
    """``mocap_coverage(*args, **kwargs)`` and every fit it made."""
    from rigcal.problem import mocap as mocap_module
    from rigcal.study.coverage import mocap_coverage

    fits = []
    real = mocap_module.calibrate_mocap_fit

    def spy(*a, **k):
        fits.append(real(*a, **k))
        return fits[-1]

    monkeypatch.setattr(mocap_module, "calibrate_mocap_fit", spy)
    return mocap_coverage(*args, **kwargs), fits


def test_the_mcs_per_hold_error_is_pooled_over_the_sensors_holds(monkeypatch):
    """Four holds per sensor cannot show a 1 mm / 2 mrad per-hold MCS error on their own (2-3
    degrees of freedom; the lidar's region held 0.85 of 40 sessions under ``hold_bias``, the
    camera's 0.78 under ``mixed``); the same MCS's error in the lidar's and the camera's holds
    together can (0.93 and 0.93 after, docs/mocap.md). A sensor whose own estimate is below the
    pooled value takes it, as a least value."""
    from rigcal.problem.consistency import mocap_verdict

    r, fits = _spied_coverage(monkeypatch, 6, seed=0, holds=4, error_model="hold_bias")
    assert r["failed"] == 0 and len(fits) == 6
    pooled = [(fit, name, f) for fit in fits for name, f in fit.sensors.items() if f.hold_pooled]
    assert len(pooled) >= 3  # a sensor whose own estimate is below the pooled one takes it
    for kind in ("lidar", "camera"):  # the benchmark's split by it: the fits' own flags
        k = r["per_sensor"][kind]
        flags = [fit.sensors[kind].hold_pooled for fit in fits]
        assert k["pooled_6dof"] == flags and k["pooled"] == sum(flags)
        assert k["pooled_inside_6dof"] == sum(p and n <= 12.5916 for p, n in zip(flags, k["nees_6dof"]))
    for fit, name, f in pooled:
        # an estimate of the MCS's 1 mm / 2 mrad, its degrees of freedom from the holds of all
        assert 0.3 < max(f.components["hold_m"] / 1e-3, f.components["hold_rad"] / 2e-3) < 3.0, f.components
        text = next(c.detail for c in mocap_verdict(fit).checks if c.name == "errors")
        assert f"{name} " in text and "the MCS's, pooled over the sensors' holds" in text


def _noise_inputs(rng, holds, hold, extra=0.0, frames=3, points=10):
    """One sensor's residuals with a per-hold error in rotation and translation (variance
    ``hold`` each, plus ``extra`` of its own) and unit point noise."""
    from rigcal.problem.mocap import _NoiseInputs

    n = holds * frames * points * 2
    X = rng.normal(size=(n, 6))
    hold_of = np.repeat(np.arange(holds), frames * points * 2)
    loads = {}
    for c in ("hold_rot", "hold"):
        base = rng.normal(size=(holds, frames * points * 2, 3))
        U = np.zeros((n, 3 * holds))
        for g in range(holds):
            U[hold_of == g, 3 * g: 3 * g + 3] = base[g]
        loads[c] = U
    r = X @ rng.normal(size=6) + rng.normal(size=n)
    for U in loads.values():
        r = r + U @ rng.normal(0, np.sqrt(hold + extra), U.shape[1])
    return _NoiseInputs(r, X, loads, {}, np.full(n, -1), np.zeros(n, dtype=bool), False)


def test_the_pooled_per_hold_error_is_a_least_value_and_a_sensor_that_rejects_it_is_left_out():
    from rigcal.problem.mocap import _components

    rng = np.random.default_rng(33)
    inputs = {f"s{k}": _noise_inputs(rng, 4, hold=0.5) for k in range(3)}
    own = {n: i.fit() for n, i in inputs.items()}
    comps = _components(inputs)
    for n, c in comps.items():
        for comp in ("hold_rot", "hold"):
            # the pooled value where the sensor's own is below it (with the pooled degrees of
            # freedom: all three sensors' holds), its own where above
            if comp in c.fixed:
                assert c.get(comp) > own[n].get(comp)
                assert c.dof[comp] > 1.5 * own[n].dof[comp] and 0.2 < c.get(comp) < 1.0
            else:
                assert c.get(comp) == pytest.approx(own[n].get(comp), rel=0.05)  # re-estimated beside it
    assert sum(len(c.fixed) for c in comps.values()) >= 2
    # a fourth sensor with a far larger per-hold error of its own would drag the pooled value
    # up until the others reject it: it is left out (keeps its own), the others pool as before
    inputs["big"] = _noise_inputs(rng, 4, hold=0.5, extra=50.0)
    with_big = _components(inputs)
    assert not with_big["big"].fixed and with_big["big"].get("hold") > 5.0
    for n in comps:
        assert with_big[n].fixed == comps[n].fixed and with_big[n].values == comps[n].values
    # one sensor alone: nothing to pool with
    assert not _components({"s0": inputs["s0"]})["s0"].fixed


def test_without_a_per_hold_error_nothing_is_pooled(monkeypatch):
    r, fits = _spied_coverage(monkeypatch, 4, seed=0, holds=4, error_model="pixel")
    assert r["failed"] == 0
    assert sum(f.hold_pooled for fit in fits for f in fit.sensors.values()) <= 2


@pytest.mark.slow
def test_four_holds_per_sensor_hold_the_truth_under_every_per_hold_error():
    """Issue 23, item 2 with four holds: the MCS's per-hold error pooled over the sensors
    (measured on 40 ``mixed`` sessions: lidar 0.97 inside, median NEES per DOF 0.46, camera
    0.93, 0.33 - wide where a sensor keeps its own per-hold estimate from four holds; before the
    pooling 0.90 / 0.45 and 0.78 / 0.36)."""
    from rigcal.study.coverage import mocap_coverage

    r = mocap_coverage(20, seed=0, holds=4, error_model="mixed")
    assert r["failed"] == 0 and r["checks"] == 40
    for s in ("lidar", "camera"):
        k = r["per_sensor"][s]
        assert k["inside_6dof"] >= 0.85, (s, k)
        assert k["nees_median"] >= 0.2, (s, k)  # wide, not absurdly


def _err(T, T_true):
    dt = float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))
    dr = float(np.degrees(np.linalg.norm(so3_log(T_true[:3, :3].T @ T[:3, :3]))))
    return dt, dr


def test_the_coverage_sessions_take_the_mcs_per_hold_accuracy_as_the_calibrations_floor(monkeypatch):
    """``hold_sigma_floor``: the MCS's per-hold accuracy as a user states it - four holds cannot
    tell a 1 mm / 2 mrad per-hold error from none at the test's level, the floor keeps it
    (measured over 40 hold_bias sessions: lidar 0.97 inside, camera 0.97; docs/mocap.md)."""
    from rigcal.problem import mocap as mocap_module
    from rigcal.study.coverage import mocap_coverage

    fits = []
    real = mocap_module.calibrate_mocap_fit

    def spy(*args, **kwargs):
        fit = real(*args, **kwargs)
        fits.append((args[4].hold_sigma_floor, fit))
        return fit

    monkeypatch.setattr(mocap_module, "calibrate_mocap_fit", spy)
    r = mocap_coverage(1, seed=0, error_model="hold_bias", hold_sigma_floor=(0.002, 0.001))
    assert r["hold_sigma_floor"] == (0.002, 0.001) and r["failed"] == 0 and r["checks"] == 2
    (floor, fit), = fits
    assert floor == (0.002, 0.001)
    for f in fit.sensors.values():  # no sensor's per-hold error below what it was told
        assert f.hold_sigma[0] >= 0.002 * (1 - 1e-9) and f.hold_sigma[1] >= 0.001 * (1 - 1e-9)
    for bad in ((0.002,), (-1.0, 0.0), (np.nan, 0.0), "x"):
        with pytest.raises(InputError, match="hold_sigma_floor must be"):
            mocap_coverage(1, hold_sigma_floor=bad)


def test_a_lidar_that_saw_one_plate_is_refused_not_converged():
    # every point on one flat plate: its in-plane position and the turn about its normal are
    # not determined - refused with the reason, never a result with a made-up std
    from rigcal.sim.mocap import paper_rig
    from rigcal.targets.templates import diamond_target

    rig = paper_rig()
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    T_rt = from_rt(matrix_from_rpy(np.radians([90.0, 0.0, -90.0])), [2.5, 0.0, 0.7])
    rng = np.random.default_rng(6)
    uv = rng.uniform(-0.15, 0.15, (300, 2))
    pts_t = np.column_stack([uv, np.zeros(len(uv))]) + target.template.mean(axis=0)
    T_lt = invert(rig.T_robot_lidar) @ T_rt
    obs = [TargetObservation("lidar", "diamond", k, T_rt, transform_points(T_lt, pts_t)) for k in range(3)]
    lidar = MocapSensor("lidar", SensorKind.LIDAR, sigma=0.01)
    with pytest.raises(ConvergenceError, match="do not determine its pose"):
        calibrate_mocap([lidar], obs, {"lidar": rig.T_robot_lidar},
                        {"diamond": TargetSurface.of(target)})


def test_an_undetermined_sensor_is_named_in_the_error():
    # the one-plate lidar next to a well-seen camera: the error names the lidar (sensor=), so
    # rigcal mocap can calibrate the camera without it
    from rigcal.targets.templates import diamond_target

    rig, cam_obs = _camera_holds(np.random.default_rng(5), holds=4, frames=2)
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    T_rt = from_rt(matrix_from_rpy(np.radians([90.0, 0.0, -90.0])), [2.5, 0.0, 0.7])
    rng = np.random.default_rng(6)
    uv = rng.uniform(-0.15, 0.15, (300, 2))
    pts_t = np.column_stack([uv, np.zeros(len(uv))]) + target.template.mean(axis=0)
    T_lt = invert(rig.T_robot_lidar) @ T_rt
    obs = [TargetObservation("lidar", "diamond", 1000 + k, T_rt, transform_points(T_lt, pts_t))
           for k in range(3)]
    sensors = [MocapSensor("lidar", SensorKind.LIDAR, sigma=0.01),
               MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)]
    with pytest.raises(ConvergenceError, match="sensor 'lidar': its measurements do not determine") as exc:
        calibrate_mocap(sensors, obs + list(cam_obs),
                        {"lidar": rig.T_robot_lidar, "camera": rig.T_robot_camera},
                        {"diamond": TargetSurface.of(target)})
    assert exc.value.sensor == "lidar"


# --------------------------------------------------------------------------- issue 23


def test_non_finite_mcs_poses_and_measurements_are_input_errors():
    with pytest.raises(InputError, match=r"observation of 'd' by 'c' at t = 5 ns: T_robot_target has "
                                         r"non-finite entries"):
        TargetObservation("c", "d", 5, np.full((4, 4), np.nan), np.ones((4, 2)))
    bad = np.ones((4, 2))
    bad[1, 0] = np.inf
    with pytest.raises(InputError, match="measured has non-finite entries"):
        TargetObservation("c", "d", 5, np.eye(4), bad)
    with pytest.raises(InputError, match=r"velocity must be finite numbers of shape \(6,\)"):
        TargetObservation("c", "d", 5, np.eye(4), np.ones((4, 2)), velocity=np.ones(3))


def test_a_camera_seen_in_one_hold_is_refused_naming_how_many_more_it_needs():
    from rigcal.problem.mocap import calibrate_mocap_fit

    rig, obs = _camera_holds(np.random.default_rng(7), holds=4, frames=4)
    one = [o for o in obs if o.t_ns <= 4 * 250_000_000]  # the first hold's frames only
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    with pytest.raises(ConvergenceError, match=r"sensor 'camera': its measurements do not determine its "
                                               r"pose: its targets were seen in 1 distinct hold, .* hold "
                                               r"the target 2 more times in its image") as exc:
        calibrate_mocap_fit([sensor], one, {"camera": rig.T_robot_camera})
    assert exc.value.sensor == "camera"
    # two holds at the same place count once
    again = [TargetObservation(o.sensor, o.target, o.t_ns + 10**10, o.T_robot_target, o.measured,
                               o.keypoints_target, hold="again") for o in one]
    with pytest.raises(ConvergenceError, match=r"seen in 1 distinct hold \(2 holds, but at nearly the same"):
        calibrate_mocap_fit([sensor], one + again, {"camera": rig.T_robot_camera})
    fit = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera})  # four holds: fine
    assert fit.sensors["camera"].views == 4


def test_target_poses_are_shared_by_time_and_pose_not_by_stamps_alone():
    # every observation stamped 1 ns apart (a broken clock): with estimated target poses, each
    # observation keeps its own (its MCS pose differs), so the result is the same as without
    rng = np.random.default_rng(11)
    obs = _overlap_observations(rng, 12)
    squeezed = [TargetObservation(o.sensor, o.target, k, o.T_robot_target, o.measured, o.keypoints_target)
                for k, o in enumerate(obs)]
    init = {k: T @ se3_exp(np.r_[np.radians(rng.uniform(-2, 2, 3)), rng.uniform(-0.02, 0.02, 3)])
            for k, T in OVERLAP_TRUTH.items()}
    r = calibrate_mocap(_overlap_sensors(), squeezed, init, options=MocapOptions(target_pose_sigma=(0.001, 0.001)))
    for name, T in OVERLAP_TRUTH.items():
        E = r.sensors[name].T_reference_sensor
        assert np.linalg.norm(E[:3, 3] - T[:3, 3]) < 0.01, name  # was 8.3 m off


def _moving_camera_holds(rng, offset_s, holds=6, frames=5, speed=0.05):
    """Camera observations while the robot drives at ``speed`` in a new direction every hold;
    the camera stamps its frames ``offset_s`` after their capture."""
    import math

    from rigcal.geometry.se3 import se3_log
    from rigcal.sim.mocap import CAMERA, Placement, paper_rig, sample_target_pose
    from rigcal.targets.templates import diamond_target

    rig = paper_rig()
    kp = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond").camera_keypoints
    target = diamond_target(0.5, 0.029, rows=6, cols=7, name="diamond")
    obs, t0 = [], 0.0
    for h in range(holds):
        T_mr0 = from_rt(matrix_from_rpy(np.array([0, 0, rng.uniform(-3, 3)])), [*rng.uniform(-2, 2, 2), 0])
        T_mt = sample_target_pose(rig, CAMERA, target, T_mr0, rng, Placement(distance_range_m=(1.6, 3.0), clutter_boxes=0))
        a = rng.uniform(-math.pi, math.pi)
        v = speed * np.array([math.cos(a), math.sin(a), 0.0])

        def T_mr(t, T_mr0=T_mr0, v=v, t0=t0):
            return T_mr0 @ from_rt(np.eye(3), v * (t - t0))

        for k in range(frames):
            tc = t0 + 0.25 * k
            st = tc + offset_s
            T_st = invert(rig.T_robot_camera) @ invert(T_mr(tc)) @ T_mt
            uv, _ = rig.camera.project(kp @ T_st[:3, :3].T + T_st[:3, 3])
            T_a = invert(T_mr(st)) @ T_mt
            vel = se3_log(invert(T_a) @ invert(T_mr(st + 1e-3)) @ T_mt) / 1e-3
            obs.append(TargetObservation("camera", "diamond", int(st * 1e9), T_a,
                                         uv + rng.normal(0, 0.05, uv.shape), kp, hold=str(h), velocity=vel))
        t0 += 5.0
    return rig, obs


def test_a_clock_offset_is_estimated_with_its_std_when_the_robot_moves():
    from rigcal.problem.mocap import calibrate_mocap_fit

    rig, obs = _moving_camera_holds(np.random.default_rng(1), 0.05)
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    fit = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera})
    f = fit.sensors["camera"]
    assert f.time_offset_status == "determined"
    assert abs(f.time_offset_s - 0.05) < 0.002 and f.time_offset_std_s < 0.001
    E = fit.result.sensors["camera"].T_reference_sensor
    assert np.linalg.norm(E[:3, 3] - rig.T_robot_camera[:3, 3]) < 0.001  # 2.5 mm off without it
    assert fit.result.noise_model["camera"]["time_offset_s"] == f.time_offset_s
    # with the clocks declared synchronised the offset is not estimated: least squares (the
    # default) errs, 1.7 mm; weighted, the noise model takes the offset's shifts for errors per
    # capture and weighs those frames down (0.2 mm) - either way the truth is inside the region
    from rigcal.study.coverage import CHI2_95_6, nees

    for estimator, off_by in (("ls", (0.0005, 0.005)), ("gls", (0.0, 0.001))):
        off = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera},
                                  options=MocapOptions(time_offset_sigma_s=0.0, estimator=estimator))
        assert off.sensors["camera"].time_offset_status == "none"
        assert off.sensors["camera"].estimator == estimator
        E = off.result.sensors["camera"]
        assert off_by[0] < np.linalg.norm(E.T_reference_sensor[:3, 3] - rig.T_robot_camera[:3, 3]) < off_by[1]
        assert nees(E.T_reference_sensor, rig.T_robot_camera, E.covariance)[0] < CHI2_95_6


def test_an_offset_the_pose_absorbs_is_undetermined_and_widens_the_covariance():
    # the robot drives the same way in every hold: the offset is a translation of the camera
    from rigcal.problem.mocap import calibrate_mocap_fit

    rng = np.random.default_rng(2)
    rig, obs = _moving_camera_holds(rng, 0.0)  # no offset: both models are right about the data
    same = []
    for o in obs:  # every hold the same motion in the robot frame: 5 cm/s straight ahead
        T = o.T_robot_target
        same.append(TargetObservation(o.sensor, o.target, o.t_ns, T, o.measured, o.keypoints_target,
                                      hold=o.hold, velocity=np.r_[0, 0, 0, T[:3, :3].T @ np.array([-0.05, 0, 0])]))
    sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
    fit = calibrate_mocap_fit([sensor], same, {"camera": rig.T_robot_camera})
    f = fit.sensors["camera"]
    assert f.time_offset_status == "undetermined" and f.time_offset_effect > 1.5
    assert f.time_offset_std_s > 0.02  # the prior's 50 ms, barely narrowed
    still = calibrate_mocap_fit([sensor], [TargetObservation(o.sensor, o.target, o.t_ns, o.T_robot_target,
                                                             o.measured, o.keypoints_target, hold=o.hold)
                                           for o in same], {"camera": rig.T_robot_camera})
    assert still.sensors["camera"].time_offset_status == "none"
    assert np.trace(fit.result.sensors["camera"].covariance[3:, 3:]) > \
        2 * np.trace(still.result.sensors["camera"].covariance[3:, 3:])


def _affine_view_holds(rng, holds=4, frames=5, affine_px=0.03, pixel_sigma=0.01):
    """A camera's corner grids of a diamond held still ``holds`` times under an exact MCS,
    each view's grid distorted in the image by its own affine error (a shift and a linear
    part of ``affine_px`` std each at the grid's edge, the same in every frame of the hold:
    what OpenCV's detector makes of a small grid, measured in the simulated session) plus
    ``pixel_sigma`` of noise per corner and frame; and the true T_robot_camera."""
    rig, clean = _camera_holds(rng, holds=holds, frames=frames, mcs_rad=0.0, mcs_m=0.0, pixel_sigma=0.0)
    obs = []
    for h in range(holds):
        uv = clean[h * frames].measured
        c = uv.mean(axis=0)
        x, y = ((uv - c) / np.abs(uv - c).max()).T
        a = rng.normal(0, affine_px, 6)
        bias = np.column_stack([a[0] + a[2] * x + a[3] * y, a[1] + a[4] * x + a[5] * y])
        for o in clean[h * frames:(h + 1) * frames]:
            obs.append(TargetObservation(o.sensor, o.target, o.t_ns, o.T_robot_target,
                                         o.measured + bias + rng.normal(0, pixel_sigma, uv.shape),
                                         o.keypoints_target))
    return rig, obs


@pytest.mark.slow
def test_a_detectors_affine_error_per_view_is_neither_hidden_nor_blown_up():
    """Issue 23: a corner detector errs on one view mostly by an affine distortion of the
    small grid (0.02-0.04 px, the same in every frame; 97 % or more of each view's pose error
    in the simulated session), and for a small grid those directions are nearly the pose's.
    The view component has them taken out and the isotropic per-hold one over-claimed them:
    with nothing but such errors (exact MCS) the 8 sessions' NEES6 were 0.01-0.06, median
    0.017 (chi2(6): 5.35), before the per-hold affine component (``view_affine``). With it,
    measured: NEES6 1.25-13.8 over 16 sessions, median 3.56, 14 of 16 inside (the first 8
    alone: median 2.49 - a median of 8 draws is too noisy a measure, hence 16). The estimated
    affine error is 0.023-0.032 px; a little wide still (the widening for its ~18 degrees of
    freedom, 1.27, and a spurious capture component in 2 of 16)."""
    from scipy.stats import chi2

    from rigcal.geometry.se3 import se3_log
    from rigcal.problem.mocap import calibrate_mocap_fit

    nees, affine = [], []
    for seed in range(16):
        rig, obs = _affine_view_holds(np.random.default_rng(100 + seed))
        sensor = MocapSensor("camera", SensorKind.CAMERA, camera=rig.camera, sigma=1.0)
        fit = calibrate_mocap_fit([sensor], obs, {"camera": rig.T_robot_camera})
        est = fit.result.sensors["camera"]
        e = se3_log(invert(est.T_reference_sensor) @ rig.T_robot_camera)
        nees.append(float(e @ np.linalg.solve(est.covariance, e)))
        affine.append(fit.sensors["camera"].components.get("view_affine_px", 0.0))
    inside = np.mean(np.array(nees) < chi2.ppf(0.95, 6))
    assert inside >= 0.75, nees
    assert 0.5 * 5.35 < np.median(nees) < 2.0 * 5.35, nees  # chi2(6) median 5.35
    assert all(0.01 < a < 0.06 for a in affine), affine  # 0.03 px drawn
