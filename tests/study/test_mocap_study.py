"""Charron et al.'s simulation study on rigcal's raw simulation: small seeded runs with the
paper's accuracy claims (noise-free MCS unless stated). The full tables come from
``rigcal study mocap`` with more trials."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.sim.mocap import paper_rig, paper_targets, simulate_mocap
from rigcal.study import PAPER_TABLES, StudyTable, run_mocap_study
from rigcal.cli.study import mocap_main as main
from rigcal.study.mocap_study import extract_observation, perturb_calibration


def _row(table: StudyTable, n: int):
    r = table.row(n)
    assert r.failed == 0, table.format()
    return r


@pytest.mark.slow
def test_camera_with_the_diamond_reaches_the_papers_accuracy():
    # paper, Table III: 0.066-0.136 mm and 0.035 deg (its own error definitions)
    t = run_mocap_study("diamond", "camera", measurements=(5, 15), trials=1, seed=1)
    r15, r5 = _row(t, 15), _row(t, 5)
    assert r15.translation_mm.mean <= 0.14 and r15.rotation_deg.mean <= 0.035, t.format()
    assert r5.translation_norm_diff_mm.mean <= 0.14 and r5.rotation_angle_diff_deg.mean <= 0.035, t.format()
    assert r5.rotation_deg.mean <= 0.035, t.format()
    assert r15.residual.mean < 0.16  # reprojection [px]; paper 0.13-0.17 px


def test_lidar_with_the_diamond_points_recovers_the_calibration_from_five_measurements():
    # The default: every scan point on the plate, tied to the plate's surface. Exact scans and
    # MCS (paper, Table I: 0.3 mm / 0.004 deg with 5): the points lie exactly on the plate, so
    # its planes (and the points' containment in its outline) recover the extrinsic.
    t = run_mocap_study("diamond", "lidar", measurements=(5,), trials=3, seed=2)
    assert "every scan point" in t.method and "surface" in t.method
    for r in t.results:
        assert r.ok and r.translation_error_mm <= 0.3 and r.rotation_error_deg <= 0.004, t.format()
        assert r.initial_translation_error_mm > 1000 * r.translation_error_mm
    assert _row(t, 5).residual.mean < 0.01  # RMS distance of the points to the plate [mm]


def test_lidar_with_the_diamond_corners_is_limited_by_the_icp_corners():
    # The paper's simulation method: the 4 corners placed by ICP of the template on the scan.
    # On VLP-16 rings the plate's in-plane pose is seen only through the ring ends near its
    # edges; rigcal's ICP places the corners unbiased but with ~2-3 mm scatter, so the result
    # stays at millimetres (30-trial study: ~1 mm / 0.03 deg with 30, ~3 mm / 0.07 deg with
    # 5) instead of the paper's 0.1-0.3 mm.
    t = run_mocap_study("diamond", "lidar", measurements=(5, 30), trials=2, seed=3, lidar_measurement="keypoints")
    r5, r30 = _row(t, 5), _row(t, 30)
    assert r5.translation_mm.mean < 8.0 and r5.rotation_deg.mean < 0.2, t.format()
    assert r30.translation_mm.mean < 3.0 and r30.rotation_deg.mean < 0.07, t.format()
    assert 1.0 < r30.residual.mean < 10.0  # Euclidean corner error [mm]
    for r in (r for r in t.results if r.measurements == 30):
        assert r.initial_translation_error_mm > 5 * r.translation_error_mm
        assert r.initial_rotation_error_deg > 25 * r.rotation_error_deg


def test_cylinder_converges_with_15_to_30_measurements():
    # paper, Table II: 4.6 mm / 0.047 deg with 30, 7.4 mm / 0.1 deg with 15, 88 mm with 5
    t = run_mocap_study("cylinder", "lidar", measurements=(15, 30), trials=1, seed=4,
                        correspondences="surface")
    for n in (15, 30):
        r = _row(t, n)
        assert r.translation_mm.mean <= 4.6 and r.rotation_deg.mean <= 0.047, t.format()


def test_cylinder_with_the_papers_centroid_aligned_matching_stays_biased():
    # calibrate_mocap matches points to the template after aligning centroids (paper III-D);
    # a VLP-16 sees only the near half of a 56 mm cylinder, whose centroid is not the
    # template's, so the translation keeps a centimetre-level bias (30-trial study: ~37 mm
    # with 30) while the rotation improves from ~5 deg to a few tenths.
    t = run_mocap_study("cylinder", "lidar", measurements=(30,), trials=1, seed=4, correspondences="centroid")
    r = t.results[0]
    assert r.ok and r.rotation_error_deg < 0.2 * r.initial_rotation_error_deg
    assert 5.0 < r.translation_error_mm < 80.0
    assert r.residual > 5.0  # RMS distance of the points to the surface so placed [mm]


def test_mcs_noise_costs_accuracy_but_not_convergence():
    t = run_mocap_study("diamond", "lidar", measurements=(15,), trials=1, seed=5, mcs_noise_m=0.00015,
                        lidar_measurement="points", correspondences="surface")
    r = _row(t, 15)
    assert 0.001 < r.translation_mm.mean < 3.0 and r.rotation_deg.mean < 0.1, t.format()
    assert "MCS noise 0.15 mm" in t.format()


# -- the table and the command line -------------------------------------------------------------


@pytest.fixture(scope="module")
def small_table() -> StudyTable:
    return run_mocap_study("cylinder", "lidar", measurements=(3, 5), trials=2, seed=0)


def test_table_holds_every_trial_and_prints_the_paper_beside_it(small_table):
    t = small_table
    assert [r.measurements for r in t.rows] == [3, 5] and len(t.results) == 4
    assert t.paper() is PAPER_TABLES[("cylinder", "lidar")]
    text = t.format()
    assert "Table II" in text and "88 +-64" in text and "4.6 +-2.4" not in text  # only rows we ran
    assert "paper-def" in text and "Euc. [mm]" in text and "2 trials" in text
    assert "Time per trial" in text
    d = t.as_dict()
    json.dumps(d)
    assert d["rows"][0]["measurements"] == 3 and d["rows"][0]["trials"] == 2
    with pytest.raises(InputError, match="no row for 30 measurements"):
        t.row(30)
    assert PAPER_TABLES[("diamond", "lidar")][5][0] == (0.3, 4.3e-6)
    assert PAPER_TABLES[("diamond", "camera")][30][2] == (0.158, 1.4e-8)


def test_command_line_shell_returns_text_and_exit_code():
    text, code = main(["--target", "cylinder", "--trials", "1", "--measurements", "3", "--seed", "1"])
    assert code == 0 and "cylinder target" in text and "Table II" in text
    text, code = main(["--target", "cylinder", "--trials", "1", "--measurements", "3", "--json"])
    assert code == 0 and json.loads(text)["target"] == "cylinder"
    text, code = main(["--trials", "0"])  # a usage error naming the option (issue #22: options have ranges)
    assert code == 2 and "argument --trials: expected 1 to 10000, got 0" in text
    text, code = main(["--help"])
    assert code == 0 and "examples:" in text and "rigcal study mocap --trials 20" in text
    text, code = main(["--target", "sphere"])
    assert code == 2 and "invalid choice" in text


def test_bad_study_requests_are_refused():
    with pytest.raises(InputError, match="target must be one of"):
        run_mocap_study("sphere")
    with pytest.raises(InputError, match="sensor must be one of"):
        run_mocap_study(sensor="radar")
    with pytest.raises(InputError, match="measurements must be >= 1"):
        run_mocap_study(measurements=(0, 5))
    with pytest.raises(InputError, match="mcs_noise_m must be >= 0"):
        run_mocap_study(mcs_noise_m=-1.0)
    with pytest.raises(InputError, match="correspondences must be one of"):
        run_mocap_study(correspondences="magic")
    with pytest.raises(InputError, match="lidar_measurement must be"):
        run_mocap_study(lidar_measurement="edges")


def test_same_data_trials_differ_only_in_the_initial_calibration():
    t = run_mocap_study("cylinder", "lidar", measurements=(3,), trials=2, seed=0, same_data=True)
    assert t.captures_simulated <= 5  # one pool of captures for both trials
    a, b = t.results
    assert a.initial_translation_error_mm != b.initial_translation_error_mm
    assert "same captures in every trial" in t.format()


# -- the steps ----------------------------------------------------------------------------------


def test_initial_calibration_is_perturbed_uniformly_within_3cm_and_5deg():
    T = paper_rig().T_robot_lidar
    rng = np.random.default_rng(0)
    dt, drpy = [], []
    for _ in range(300):
        P = perturb_calibration(T, rng)
        dt.append(P[:3, 3] - T[:3, 3])
        drpy.append(np.degrees(rpy_from_matrix(T[:3, :3].T @ P[:3, :3])))
    dt, drpy = np.array(dt), np.array(drpy)
    assert np.abs(dt).max() <= 0.03 and np.abs(dt).max() > 0.028
    assert np.abs(drpy).max() <= 5.0 + 1e-9 and np.abs(drpy).max() > 4.8
    assert np.std(dt) == pytest.approx(0.03 / math.sqrt(3), rel=0.1)


def test_extraction_of_a_capture_without_data_is_an_explicit_failure():
    tg = paper_targets()
    sim = simulate_mocap(paper_rig(), tg.diamond, 1, 0, sensors=("lidar",))
    c = sim.captures[0]
    f = extract_observation(c, sim, "camera", paper_rig().T_robot_camera)
    assert not f.ok and f.reason == "target_not_in_view" and "no image" in f.detail
    o = extract_observation(c, sim, "lidar", paper_rig().T_robot_lidar)
    assert o.measured.shape == (4, 3) and o.keypoints_target.shape == (4, 3)
    with pytest.raises(InputError, match="kind must be one of"):
        extract_observation(c, sim, "radar", np.eye(4))
