"""PoseStream: validation, interpolation accuracy on a smooth trajectory, gap and extent refusal,
quaternion helpers, and the CSV reader/writer with every failure path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.errors import InputError
from rigcal.geometry import from_rt, so3_exp, so3_log
from rigcal.mocap import (
    PoseStream,
    interpolate,
    matrix_to_quat_xyzw,
    parse_pose_csv,
    pose_csv_text,
    quat_xyzw_to_matrix,
    read_pose_csv,
    write_pose_csv,
)

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)
NS = 1_000_000_000
T0 = 1_700_000_000_000_000_000


def rot_err(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    return np.linalg.norm(so3_log(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1)


def sampled(kit, rate_hz: float = 100.0, duration_s: float = 20.0, start_ns: int = T0,
            name: str = "robot") -> PoseStream:
    n = int(duration_s * rate_hz) + 1
    t_ns = start_ns + np.round(np.arange(n) * NS / rate_hz).astype(np.int64)
    return PoseStream(name, t_ns, kit.trajectory((t_ns - start_ns) / NS), frame_id="world")


# -- quaternions -------------------------------------------------------------------------------


@SETTINGS
@given(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_quaternion_round_trip(w):
    R = so3_exp(np.array(w))
    q = matrix_to_quat_xyzw(R)
    assert q[3] >= 0 and np.isclose(np.linalg.norm(q), 1.0)
    np.testing.assert_allclose(quat_xyzw_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(quat_xyzw_to_matrix(-q), R, atol=1e-12)  # q and -q: same rotation


def test_quaternion_order_is_xyzw():
    # 90 deg about z: (x, y, z, w) = (0, 0, sin 45, cos 45)
    s = np.sqrt(0.5)
    np.testing.assert_allclose(quat_xyzw_to_matrix([0, 0, s, s]),
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(matrix_to_quat_xyzw(so3_exp([0, 0, np.pi / 2])), [0, 0, s, s],
                               atol=1e-15)
    # near 180 deg the largest-pivot branch still gives a unit quaternion
    R = so3_exp([np.pi - 1e-9, 0, 0])
    np.testing.assert_allclose(quat_xyzw_to_matrix(matrix_to_quat_xyzw(R)), R, atol=1e-12)


def test_quaternion_zero_refused():
    from rigcal.errors import GeometryError

    with pytest.raises(GeometryError, match="zero or non-finite quaternion"):
        quat_xyzw_to_matrix([0, 0, 0, 0])
    with pytest.raises(GeometryError, match=r"shape \(\.\.\., 4\)"):
        quat_xyzw_to_matrix([0, 0, 1])


# -- the stream value --------------------------------------------------------------------------


def test_stream_is_immutable_and_copies(kit):
    t = np.array([0, 10, 20], dtype=np.int64)
    T = kit.trajectory(np.array([0.0, 0.01, 0.02]))
    s = PoseStream("robot", t, T)
    original = T.copy()
    t[0] = 5
    T[0, 0, 3] = 99.0
    assert s.t_ns[0] == 0 and s.T[0, 0, 3] != 99.0
    with pytest.raises(ValueError):
        s.t_ns[0] = 1
    with pytest.raises(ValueError):
        s.T[0, 0, 0] = 1.0
    with pytest.raises(AttributeError):
        s.name = "x"  # type: ignore[misc]
    assert len(s) == 3 and s.start_ns == 0 and s.end_ns == 20
    np.testing.assert_allclose(quat_xyzw_to_matrix(s.quaternions_xyzw), original[:, :3, :3],
                               atol=1e-12)
    np.testing.assert_allclose(s.positions_xyz, original[:, :3, 3])


@pytest.mark.parametrize(
    "t, T_shape, match",
    [
        ([0, 10, 10], (3, 4, 4), r"strictly increasing: duplicate sample 2 at 10 ns after"),
        ([0, 20, 10], (3, 4, 4), r"strictly increasing: out-of-order sample 2 at 10 ns after"),
        ([0.0, 1.0, 2.0], (3, 4, 4), r"t_ns must be integer nanoseconds"),
        ([], (0, 4, 4), r"t_ns must be a non-empty 1-D array"),
        ([0, 1, 2], (2, 4, 4), r"T must have shape \(3, 4, 4\), got \(2, 4, 4\)"),
    ],
)
def test_stream_validation(t, T_shape, match):
    T = np.broadcast_to(np.eye(4), T_shape)
    with pytest.raises(InputError, match=r"pose stream 'b': (t_ns must be )?" + match):
        PoseStream("b", np.array(t), T)


def test_stream_refuses_non_rigid_and_non_finite():
    T = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    T[1, 0, 0] = 1.1
    with pytest.raises(InputError, match=r"pose 1 \(t = 10 ns\) is not rigid"):
        PoseStream("b", np.array([0, 10, 20]), T)
    T[1, 0, 0] = np.nan
    with pytest.raises(InputError, match=r"pose 1 \(t = 10 ns\) has non-finite entries"):
        PoseStream("b", np.array([0, 10, 20]), T)
    with pytest.raises(InputError, match="name must be a non-empty string"):
        PoseStream("", np.array([0]), np.eye(4)[None])


# -- interpolation -----------------------------------------------------------------------------


def test_interpolation_accuracy_on_smooth_trajectory(kit):
    stream = sampled(kit, rate_hz=100.0, duration_s=20.0)
    rng = np.random.default_rng(7)
    q_ns = T0 + rng.integers(0, 20 * NS, size=5000)
    T, valid = interpolate(stream, q_ns)
    assert valid.all()
    truth = kit.trajectory((q_ns - T0) / NS)
    pos_err = np.linalg.norm(T[:, :3, 3] - truth[:, :3, 3], axis=1)
    ang_err = rot_err(T[:, :3, :3], truth[:, :3, :3])
    assert pos_err.max() < 1e-4, pos_err.max()
    assert ang_err.max() < 1e-4, ang_err.max()
    # results are rigid
    R = T[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-12)


def test_interpolation_hits_samples_exactly_and_is_midway_between(kit):
    stream = sampled(kit, duration_s=1.0)
    T, valid = interpolate(stream, stream.t_ns)
    assert valid.all()
    np.testing.assert_array_equal(T, stream.T)
    # midway: half the relative rotation, the mean position
    a, b = stream.T[10], stream.T[11]
    mid = (stream.t_ns[10] + stream.t_ns[11]) // 2
    Tm = stream.at(int(mid))
    w = so3_log(a[:3, :3].T @ b[:3, :3])
    np.testing.assert_allclose(Tm[:3, :3], a[:3, :3] @ so3_exp(w / 2), atol=1e-12)
    np.testing.assert_allclose(Tm[:3, 3], (a[:3, 3] + b[:3, 3]) / 2, atol=1e-12)


def test_slerp_takes_the_short_way_whatever_the_quaternion_signs():
    q0 = np.array([0.0, 0.0, np.sin(0.05), np.cos(0.05)])  # 0.1 rad about z
    q1 = -np.array([0.0, 0.0, np.sin(0.15), np.cos(0.15)])  # 0.3 rad about z, sign flipped
    s = PoseStream.from_positions_quaternions("b", [0, 10_000_000], np.zeros((2, 3)),
                                              np.stack([q0, q1]))
    T = s.at(5_000_000)
    np.testing.assert_allclose(so3_log(T[:3, :3]), [0, 0, 0.2], atol=1e-12)


@SETTINGS
@given(st.lists(st.floats(-2.0, 2.0), min_size=6, max_size=6), st.floats(0.0, 1.0))
def test_interpolated_rotation_lies_on_the_geodesic(w, a):
    """Slerp contract: R(a) splits the arc R0 -> R1 in the ratio a : 1 - a."""
    R0, R1 = so3_exp(np.array(w[:3])), so3_exp(np.array(w[3:]))
    total = rot_err(R0, R1)
    if total > 3.0:  # near pi the shortest arc is ambiguous
        return
    s = PoseStream("b", [0, 1_000_000], from_rt(np.stack([R0, R1]), np.zeros((2, 3))))
    t = int(round(a * 1_000_000))
    R = s.at(t)[:3, :3]
    frac = t / 1_000_000
    assert rot_err(R0, R) == pytest.approx(frac * total, abs=1e-9)
    assert rot_err(R, R1) == pytest.approx((1 - frac) * total, abs=1e-9)


def test_interpolate_keeps_the_query_shape(kit):
    stream = sampled(kit, duration_s=1.0)
    q = stream.t_ns[:6].reshape(2, 3) + 3
    T, valid = interpolate(stream, q)
    assert T.shape == (2, 3, 4, 4) and valid.shape == (2, 3)
    T1, v1 = stream.interpolate(int(stream.t_ns[5]) + 3)
    assert T1.shape == (4, 4) and v1.shape == () and bool(v1)


def test_outside_the_stream_is_refused(kit):
    stream = sampled(kit, duration_s=1.0)
    q = np.array([stream.start_ns - 1, stream.start_ns, stream.end_ns, stream.end_ns + 1])
    T, valid = interpolate(stream, q)
    assert valid.tolist() == [False, True, True, False]
    assert np.all(np.isnan(T[~valid]))
    with pytest.raises(InputError, match=r"pose stream 'robot': no pose at t = .* before the "
                                         r"start of the stream, which covers \[1700000000000000000"
                                         r", 1700000001000000000\] ns \(101 samples\)"):
        stream.at(stream.start_ns - 1)
    with pytest.raises(InputError, match=r"after the end of the stream"):
        stream.at(stream.end_ns + 1)


def test_gaps_longer_than_max_gap_are_refused(kit):
    full = sampled(kit, duration_s=2.0)
    keep = (full.t_ns < T0 + NS) | (full.t_ns >= T0 + NS + 200_000_000)  # 0.21 s hole at 1 s
    stream = PoseStream("target", full.t_ns[keep], full.T[keep], source="test")
    last_before = int(full.t_ns[full.t_ns < T0 + NS][-1])
    first_after = int(full.t_ns[full.t_ns >= T0 + NS + 200_000_000][0])
    inside = np.array([last_before + 1, (last_before + first_after) // 2, first_after - 1])
    _, valid = interpolate(stream, inside)
    assert not valid.any()
    # the samples bounding the gap are still exact hits
    _, valid = interpolate(stream, np.array([last_before, first_after]))
    assert valid.all()
    with pytest.raises(InputError, match=r"pose stream 'target' \(test\): no pose at t = \d+ ns: "
                                         r"it falls in a gap of 0\.210 s between samples at "
                                         r"\d+ and \d+ ns, longer than max_gap_s = 0\.05 s"):
        stream.at(int(inside[1]))
    # a larger max_gap_s bridges it
    T, valid = interpolate(stream, inside, max_gap_s=0.25)
    assert valid.all()
    with pytest.raises(InputError, match="max_gap_s must be a finite number > 0"):
        interpolate(stream, inside, max_gap_s=0)
    with pytest.raises(InputError, match="query times must be integer nanoseconds"):
        interpolate(stream, np.array([1.5]))


def test_single_sample_stream_only_answers_its_time():
    s = PoseStream("b", np.array([100]), np.eye(4)[None])
    _, valid = interpolate(s, np.array([99, 100, 101]))
    assert valid.tolist() == [False, True, False]


def test_window(kit):
    s = sampled(kit, duration_s=1.0)
    w = s.window(T0 + 100_000_000, T0 + 200_000_000)
    assert len(w) == 10 and w.start_ns == T0 + 100_000_000
    with pytest.raises(InputError, match=r"no samples in \["):
        s.window(0, 10)


# -- CSV -----------------------------------------------------------------------------------------


def _csv(rows, header="t,x,y,z,qx,qy,qz,qw"):
    return header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n"


ID = [0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("unit", ["ns", "s"])
def test_csv_round_trip(kit, tmp_path, unit):
    stream = sampled(kit, duration_s=0.5, name="robot")
    path = write_pose_csv(tmp_path / "robot.csv", stream, time_unit=unit)
    back = read_pose_csv(path)
    assert back.name == "robot" and back.source == str(path)
    np.testing.assert_array_equal(back.t_ns, stream.t_ns)
    np.testing.assert_allclose(back.T, stream.T, atol=1e-14)
    assert path.read_text().splitlines()[0] == "t,x,y,z,qx,qy,qz,qw"
    assert pose_csv_text(back, unit).splitlines()[1].split(",")[0] == (
        "1700000000000000000" if unit == "ns" else "1700000000.000000000")


@pytest.mark.parametrize(
    "times, expected_ns",
    [
        (["1700000000.000000001", "1700000000.010000001"],  # epoch seconds, ns exact
         [1_700_000_000_000_000_001, 1_700_000_000_010_000_001]),
        (["0", "0.01", "0.02"], [0, 10_000_000, 20_000_000]),  # relative seconds
        (["0", "1", "2"], [0, NS, 2 * NS]),  # integral seconds at 1 Hz: median step < 1000
        (["1700000000000000000", "1700000000010000000"],  # epoch ns
         [1_700_000_000_000_000_000, 1_700_000_000_010_000_000]),
        (["0", "10000000", "20000000"], [0, 10_000_000, 20_000_000]),  # relative ns
        (["1.7e18", "1.70000000001e18"], [1_700_000_000_000_000_000, 1_700_000_000_010_000_000]),
    ],
)
def test_csv_time_unit_detection(times, expected_ns):
    s = parse_pose_csv(_csv([[t, 1, 2, 3, *ID] for t in times]), "b")
    assert s.t_ns.tolist() == expected_ns


def test_csv_explicit_time_unit_and_columns_by_name():
    text = ("# exported by a mocap system\n"
            "frame, QW, qx, qy, qz, X, Y, Z, T\n"
            "\n"
            "7, 1, 0, 0, 0, 1.5, 2, 3, 5\n"
            "8, 0, 0, 0, 1, 1.5, 2, 4, 6\n")
    s = parse_pose_csv(text, "b", time_unit="s")
    assert s.t_ns.tolist() == [5 * NS, 6 * NS]
    np.testing.assert_allclose(s.T[1, :3, 3], [1.5, 2, 4])
    np.testing.assert_allclose(s.T[1, :3, :3], np.diag([-1, -1, 1]), atol=1e-15)
    s = parse_pose_csv(text, "b", time_unit="ns")
    assert s.t_ns.tolist() == [5, 6]


def test_csv_drops_occluded_rows(caplog):
    text = _csv([[0, 0, 0, 0, *ID], [0.01, "nan", "nan", "nan", "nan", "nan", "nan", "nan"],
                 [0.02, "", "", "", "", "", "", ""], [0.03, 1, 0, 0, *ID]])
    with caplog.at_level("INFO"):
        s = parse_pose_csv(text, "b", "occl.csv")
    assert s.t_ns.tolist() == [0, 30_000_000]
    assert "dropped 2 of 4 rows" in caplog.text
    _, valid = interpolate(s, np.array([15_000_000]))  # the hole is a 30 ms gap: bridged
    assert valid.all()


@pytest.mark.parametrize(
    "text, match",
    [
        (_csv([[0.0, 0, 0, 0, *ID], [0.02, 0, 0, 0, *ID], [0.01, 0, 0, 0, *ID]]),
         r"f\.csv: line 4: out-of-order time stamp 0\.01 \(s\): not after 0\.02 on line 3"),
        (_csv([[0.0, 0, 0, 0, *ID], [0.0, 0, 0, 0, *ID]]),
         r"f\.csv: line 3: duplicate time stamp 0\.0 \(s\): not after 0\.0 on line 2"),
        (_csv([[5, 0, 0, 0, *ID], [5, 0, 0, 0, *ID]], header="t,x,y,z,qx,qy,qz,qw,extra"),
         r"line 3: duplicate time stamp"),
        (_csv([[0, 0, 0, 0, *ID]], header="time,x,y,z,qx,qy,qz,qw"),
         r"f\.csv: line 1: header must name the columns t, x, y, z, qx, qy, qz, qw; missing t"),
        (_csv([[0, 0, 0, 0, *ID]], header="t,x,y,z,qx,qy,qz,qw,x"),
         r"line 1: duplicate header columns \['x'\]"),
        (_csv([[0, "a", 0, 0, *ID]]), r"f\.csv: line 2: column x: expected a number, got 'a'"),
        (_csv([["now", 0, 0, 0, *ID]]), r"line 2: column t: expected a finite number, got 'now'"),
        (_csv([[0, 0, 0]]), r"line 2: expected at least 8 comma-separated values, got 3"),
        (_csv([[0, 0, 0, 0, 0, 0, 0, 2]]), r"line 2: quaternion \(qx, qy, qz, qw\) has norm 2"),
        (_csv([[0, "inf", 0, 0, *ID]]), r"line 2: infinite pose value"),
        ("", r"f\.csv: no header line"),
        ("t,x,y,z,qx,qy,qz,qw\n", r"f\.csv: no samples after the header \(line 1\)"),
        (_csv([[0, *["nan"] * 7]]), r"every row has missing pose values"),
        (_csv([[0, "nan", 0, 0, *ID]]), r"f\.csv: line 2: column x: expected a finite number, got 'nan'"),
    ],
)
def test_csv_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_pose_csv(text, "b", "f.csv")


def test_csv_ns_must_be_integers_and_unit_must_be_known():
    with pytest.raises(InputError, match=r"line 2: column t: nanosecond stamps must be integers"):
        parse_pose_csv(_csv([[0.5, 0, 0, 0, *ID]]), "b", "f.csv", time_unit="ns")
    with pytest.raises(InputError, match=r"time_unit must be 'auto', 's' or 'ns', got 'ms'"):
        parse_pose_csv(_csv([[0, 0, 0, 0, *ID]]), "b", "f.csv", time_unit="ms")


def test_read_pose_csv_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: pose CSV not found"):
        read_pose_csv(tmp_path / "nope.csv")


def test_from_positions_quaternions_checks_shapes():
    with pytest.raises(InputError, match=r"expected positions \(N, 3\) and quaternions \(N, 4\)"):
        PoseStream.from_positions_quaternions("b", [0], np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError, match=r"pose stream 'b': cannot make a rotation from a zero"):
        PoseStream.from_positions_quaternions("b", [0], np.zeros((1, 3)), np.zeros((1, 4)))


def test_rigid_body_sanity_of_synthetic_trajectory(kit):
    # guards the test fixture itself: poses are rigid and smooth at 100 Hz
    T = kit.trajectory(np.arange(0, 1, 0.01))
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 0.01
    assert from_rt(np.eye(3), np.zeros(3)).shape == (4, 4)


# -- hostile numbers (issue #11) ---------------------------------------------------------------


@pytest.mark.parametrize(
    "row, match",
    [
        # a pose with only its quaternion missing is not an occlusion marker: refused
        ([0.01, 1, 2, 3, "nan", "nan", "nan", "nan"],
         r"f\.csv: line 3: column qx: expected a finite number, got 'nan' \(an occluded sample "
         r"leaves all seven pose columns empty or nan; a row with only qx, qy, qz, qw missing"),
        ([0.01, 1, 2, 3, 0, 0, "", 1], r"f\.csv: line 3: column qz: expected a finite number, got ''"),
        ([0.01, 1, 2, 3, 0, 0, "-inf", 1], r"f\.csv: line 3: infinite pose value in column qz"),
        ([0.01, 1, 2, 3, 0, 0, 0, 0], r"f\.csv: line 3: quaternion \(qx, qy, qz, qw\) has norm 0"),
        ([0.01, 1, 2, 3, 0, 0, 0, 1.01], r"f\.csv: line 3: quaternion .* has norm 1\.01"),
        ([0.01, 1, 12000.0, 3, *ID],
         r"f\.csv: line 3: column y: position 12000 m is beyond 10000 m; expected metres"),
    ],
)
def test_csv_refuses_rows_that_are_neither_a_pose_nor_an_occlusion(row, match):
    with pytest.raises(InputError, match=match):
        parse_pose_csv(_csv([[0, 0, 0, 0, *ID], row, [0.02, 0, 0, 0, *ID]]), "b", "f.csv")


def test_csv_keeps_a_quaternion_within_tolerance_and_warns_about_occlusions(caplog):
    text = _csv([[0, 0, 0, 0, 0, 0, 0, 1.0005], [0.01, *["nan"] * 7], [0.02, 9999.0, 0, 0, *ID]])
    with caplog.at_level("WARNING"):
        s = parse_pose_csv(text, "b", "occl.csv")
    assert s.t_ns.tolist() == [0, 20_000_000]
    np.testing.assert_allclose(s.T[0, :3, :3], np.eye(3), atol=1e-12)  # normalised
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "occl.csv: dropped 1 of 3 rows with missing pose values" in caplog.text


def test_nanosecond_stamps_declared_as_seconds_are_refused_with_a_hint():
    text = "t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{1_700_000_000_000_000_000 + k * 10_000_000},0,0,0,0,0,0,1\n" for k in range(5)
    )
    with pytest.raises(InputError, match=r"robot.csv: line 2: column t: .*set time_unit: ns"):
        parse_pose_csv(text, "robot", "robot.csv", time_unit="s")
    assert parse_pose_csv(text, "robot", "robot.csv", time_unit="ns").t_ns[0] == 1_700_000_000_000_000_000
    with pytest.raises(InputError, match="beyond"):
        parse_pose_csv(text.replace("1700", "9" * 30, 1), "robot", "robot.csv", time_unit="ns")


# -- dropouts, the streams' own noise, relative motion -------------------------------------------


def test_a_burst_of_dropped_csv_rows_is_interpolated_over_up_to_max_dropout_s():
    rows = [[k * 0.01, k * 0.001, 0, 0, *ID] for k in range(40)]
    for k in range(10, 18):  # an 8-sample occlusion: a 90 ms hole between valid samples
        rows[k] = [rows[k][0]] + ["nan"] * 7
    s = parse_pose_csv(_csv(rows), "b", "occl.csv")
    assert len(s.dropout_t_ns) == 8
    T, valid = interpolate(s, np.array([130_000_000]))
    assert valid.all() and T[0, 0, 3] == pytest.approx(0.013)  # the straight path, bridged
    _, valid = interpolate(s, np.array([130_000_000]), max_dropout_s=0.05)
    assert not valid.any()
    with pytest.raises(InputError, match=r"falls in a dropout of 8 samples.*max_dropout_s = 0\.05 s"):
        s.at(130_000_000, max_dropout_s=0.05)
    # a plain gap (no samples at all, not dropped ones) keeps max_gap_s
    plain = parse_pose_csv(_csv([r for k, r in enumerate(rows) if not 10 <= k < 18]), "b", "gap.csv")
    assert not interpolate(plain, np.array([130_000_000]))[1].any()
    # the default scales with the stream's rate: 25 periods
    assert s.window(0, 400_000_000).period_ns == 10_000_000


def test_the_mcs_noise_is_estimated_from_the_stream_over_its_still_and_steady_stretches():
    from rigcal.mocap.streams import mcs_noise

    rng = np.random.default_rng(0)
    n = 3000
    t = np.arange(n, dtype=np.int64) * 10_000_000
    x = np.where(np.arange(n) < 1500, 0.0, 0.01 * (np.arange(n) - 1500) * 0.01)  # still, then 1 cm/s
    x[1000:1010] += np.linspace(0, 0.5, 10)  # a quick carry: too fast to count
    T = np.stack([from_rt(so3_exp(rng.normal(0, 0.0003, 3)), [xi, 1.0, 0.5] + rng.normal(0, 0.00015, 3))
                  for xi in x])
    noise = mcs_noise(PoseStream("b", t, T))
    assert noise.translation_m == pytest.approx(0.00015, rel=0.15)
    assert noise.rotation_rad == pytest.approx(0.0003, rel=0.15)
    assert noise.samples > 2500
    exact = mcs_noise(PoseStream("b", t, np.stack([from_rt(np.eye(3), [xi, 0, 0]) for xi in x])))
    assert exact.translation_m < 1e-12 and exact.rotation_rad < 1e-12
    C = noise.covariance()
    assert C.shape == (6, 6) and C[0, 0] == pytest.approx(noise.rotation_rad ** 2)


def test_relative_velocity_is_the_slope_of_the_target_in_the_robot_frame():
    from rigcal.geometry import se3_log
    from rigcal.mocap.streams import interpolation_weight, relative_velocity

    t = np.arange(200, dtype=np.int64) * 10_000_000
    robot = PoseStream("r", t, np.stack([from_rt(so3_exp([0, 0, 0.02 * k * 0.01]), [0.05 * k * 0.01, 0, 0])
                                         for k in range(200)]))
    target = PoseStream("t", t, np.stack([from_rt(np.eye(3), [3.0, 1.0, 0.5])] * 200))
    v = relative_velocity(robot, target, int(t[100]), 0.5)
    h = 1e-3
    T_rt = [np.linalg.inv(robot.at(int(t[100]) + int(d * 1e9))) @ target.at(int(t[100]))
            for d in (0.0, h)]
    expected = se3_log(np.linalg.inv(T_rt[0]) @ T_rt[1]) / h
    np.testing.assert_allclose(v, expected, rtol=1e-3, atol=1e-6)
    assert relative_velocity(robot, target, int(t[-1]) + 10**9, 0.5) is None  # not covered
    assert interpolation_weight(robot, int(t[3])) == 1.0
    assert interpolation_weight(robot, int(t[3]) + 5_000_000) == pytest.approx(0.5)
