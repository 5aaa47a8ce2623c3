"""rigcal.io.results.bounded: the rule that keeps a URDF's values for the directions a
calibration only bounds (a 2D radar's z, roll, pitch), on exact synthetic poses."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, matrix_from_rpy
from rigcal.geometry.se3 import se3_exp
from rigcal.io.results.bounded import keep_nominal
from rigcal.io.results.urdf import add_fixed_links, parse_urdf


def pose(xyz, rpy_deg):
    return from_rt(matrix_from_rpy(np.radians(rpy_deg)), np.asarray(xyz, dtype=float))


N = pose((3.7, -0.05, 0.5), (2.0, -3.0, 10.0))  # the URDF's nominal mounting, tilted on purpose


@pytest.mark.parametrize("keep", [("roll", "pitch", "z"), ("z",), ("roll", "pitch"), ()])
def test_keep_nominal_replaces_only_the_measured_directions(keep):
    # the calibrated pose in the nominal frame: every direction off by a known amount
    D = pose((0.05, -0.02, 0.3), (4.0, -6.0, 1.5))
    W = keep_nominal(N, N @ D, keep)
    D_new = invert(N) @ W
    rpy = np.degrees([np.arctan2(D_new[2, 1], D_new[2, 2]), -np.arcsin(D_new[2, 0]),
                      np.arctan2(D_new[1, 0], D_new[0, 0])])
    expect = pose((0.05, -0.02, 0.0 if "z" in keep else 0.3),
                  (0.0 if "roll" in keep else 4.0, 0.0 if "pitch" in keep else -6.0, 1.5))
    np.testing.assert_allclose(D_new, expect, atol=1e-12)
    assert rpy[2] == pytest.approx(1.5)
    if set(keep) == {"roll", "pitch", "z"}:
        # the sensor keeps the URDF's plane: its z axis and its height along it exactly
        np.testing.assert_allclose(W[:3, 2], N[:3, 2], atol=1e-12)
        assert float(N[:3, 2] @ (W[:3, 3] - N[:3, 3])) == pytest.approx(0.0, abs=1e-12)


def test_keep_nominal_recovers_the_truth_of_a_synthetic_rig():
    """A radar whose estimate sits at a vertex of its bounded set (tilted 8 deg, 0.2 m high) with
    the true in-plane pose: kept into a URDF holding the true mounting, the truth comes back."""
    truth = pose((3.7, -0.05, 0.5), (0.3, 0.5, -1.2))
    estimate = truth @ se3_exp(np.array([np.radians(3.0), np.radians(8.0), 0.0, 0.0, 0.0, 0.2]))
    # the in-plane pose of the estimate is the truth's: the rule must not move it
    W = keep_nominal(truth, estimate, ("roll", "pitch", "z"))
    np.testing.assert_allclose(W[:3, 2], truth[:3, 2], atol=1e-12)
    D = invert(truth) @ W
    # the calibrated origin projected onto the nominal plane; heading from the projected x axis
    np.testing.assert_allclose(D[:2, 3], (invert(truth) @ estimate)[:2, 3], atol=1e-12)
    assert abs(D[2, 3]) < 1e-12


def test_keep_nominal_refuses_unknown_directions():
    with pytest.raises(InputError, match=r"cannot keep \['yaw'\] from the URDF"):
        keep_nominal(N, N, ("yaw",))


def test_frame_plan_keeps_writes_or_says_why():
    from rigcal.io.results.bounded import bounded_lines
    from rigcal.io.results.calibration_files import CalibrationTransforms
    from rigcal.io.results.frames import frames_block, plan_frames

    text = '<robot name="r"><link name="base_link"/></robot>'
    text = add_fixed_links(text, "r.urdf", {"lidar": np.eye(4), "radar": N}, "base_link")
    urdf = parse_urdf(text, "r.urdf")
    C = N @ pose((0.1, 0.0, 0.4), (5.0, 5.0, 2.0))  # the estimate, relative to the lidar
    values = {"radar": {"z": (0.1, 0.9, 0.5), "roll": (-10.0, 10.0, 5.0), "x": (3.6, 3.9, 3.8)}}
    cal = CalibrationTransforms("relative", "lidar", {"radar": C, "cam": np.eye(4)}, "c.yaml",
                                bounded={"radar": ("roll", "pitch", "z")}, bounded_values=values)
    plan = plan_frames(cal, urdf)
    np.testing.assert_allclose(plan.T_root("radar"), keep_nominal(N, C, ("roll", "pitch", "z")), atol=1e-12)
    np.testing.assert_array_equal(plan.T_root("cam"), np.eye(4))
    assert dict(plan.kept) == {"radar": ("roll", "pitch", "z")}
    assert bounded_lines(cal, plan, "r.urdf") == [
        "radar: roll, pitch, z kept from r.urdf, the rest calibrated (--write-bounded writes the estimate); "
        "the calibration only bounds them: z +0.100 .. +0.900 m (estimate +0.500), roll -10.00 .. +10.00 deg "
        "(estimate +5.00)"
    ]
    # recorded in calibration.yaml's frames block: a later plan without the URDF publishes the same
    block = frames_block(plan)
    assert block["sensors"]["radar"]["kept_from_urdf"]["directions"] == ["roll", "pitch", "z"]
    again = CalibrationTransforms("relative", "lidar", cal.transforms, "c.yaml", bounded=cal.bounded,
                                  kept={"radar": np.array(block["sensors"]["radar"]["kept_from_urdf"]["T_reference_measured"])})
    np.testing.assert_allclose(plan_frames(again).T_root("radar"), plan.T_root("radar"), atol=1e-12)
    # --write-bounded: the estimate, said so
    est = plan_frames(cal, urdf, write_bounded=True)
    np.testing.assert_allclose(est.T_root("radar"), C, atol=1e-12)
    assert bounded_lines(cal, est, "r.urdf", True)[0].startswith("radar: roll, pitch, z written from the estimate (--write-bounded)")
    # a URDF without the sensor's link: nothing to keep from
    bare = parse_urdf(add_fixed_links('<robot name="r"><link name="base_link"/></robot>', "b.urdf",
                                      {"lidar": np.eye(4)}, "base_link"), "b.urdf")
    plain = plan_frames(cal, bare)
    np.testing.assert_allclose(plain.T_root("radar"), C, atol=1e-12)
    assert bounded_lines(cal, plain, "b.urdf") == [
        "radar: roll, pitch, z written from the estimate (b.urdf has no link 'radar' to keep them from), "
        "although the calibration only bounds them: z +0.100 .. +0.900 m (estimate +0.500), roll -10.00 .. "
        "+10.00 deg (estimate +5.00)"
    ]
