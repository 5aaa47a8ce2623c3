"""URDF: parsing, conventions pinned against forward kinematics, in-place origin updates,
the shared TU Delft example, refusals (missing/non-fixed/conflicting/hostile), file writing."""

from __future__ import annotations

import difflib
import math
import os
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import rigcal.io.results.urdf as urdf_module
from rigcal.errors import InputError
from rigcal.geometry import from_rt, invert, matrix_from_rpy, rpy_from_matrix, so3_exp
from rigcal.io.results.urdf import (
    format_float,
    forward_kinematics,
    matrix_from_origin,
    origin_from_matrix,
    parse_urdf,
    read_original_calibration_yaml,
    rpy_from_rotation,
    set_joint_origins,
    solve_joint_origins,
    update_urdf_text,
    write_urdf,
)

DATA = Path(__file__).resolve().parents[4] / "shared" / "data" / "tudelft_prius" / "urdf"
if not DATA.exists():  # pragma: no cover - alternative checkout layouts
    DATA = Path("/work/shared/data/tudelft_prius/urdf")


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=float)


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=float)


def random_pose(rng, scale=2.0) -> np.ndarray:
    return from_rt(so3_exp(rng.normal(size=3)), rng.normal(scale=scale, size=3))


def changed_lines(old: str, new: str) -> tuple[list[str], list[str]]:
    diff = list(difflib.unified_diff(old.splitlines(True), new.splitlines(True), n=0))
    removed = [d for d in diff[2:] if d.startswith("-")]
    added = [d for d in diff[2:] if d.startswith("+")]
    return removed, added


CHAIN = """<?xml version="1.0"?>
<!-- a comment -->
<robot name="r">
  <link name="base"/>
  <link name="mid"/>
  <link name="sensor"/>
  <joint name="j1" type="fixed">
    <parent link="base"/>
    <child link="mid"/>
    <origin xyz="0.5 0 1" rpy="0 0 1.5707963267948966"/>
  </joint>
  <joint name="j2" type="fixed">
    <parent link="mid"/>
    <child link="sensor"/>
    <origin xyz="1 0 0" rpy="0 0 0"/>
  </joint>
</robot>
"""


# ------------------------------------------------------------------------------ conventions


def test_urdf_rpy_is_fixed_axis_roll_pitch_yaw():
    r, p, y = 0.3, -0.4, 1.1
    text = CHAIN.replace('rpy="0 0 1.5707963267948966"', f'rpy="{r} {p} {y}"')
    T = forward_kinematics(parse_urdf(text), "base", "mid")
    # fixed axes: roll about x, then pitch about the fixed y, then yaw about the fixed z
    np.testing.assert_allclose(T[:3, :3], Rz(y) @ Ry(p) @ Rx(r), atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [0.5, 0, 1], atol=0)
    # the classic mistake, x-y-z applied intrinsically (Rx Ry Rz), is a different rotation
    assert np.max(np.abs(T[:3, :3] - Rx(r) @ Ry(p) @ Rz(y))) > 0.1


def test_hand_computed_origins():
    # yaw 90 deg: the child's x axis is the parent's y axis
    T = matrix_from_origin((0, 0, 0), (0, 0, math.pi / 2))
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # roll 90 then yaw 90 (fixed axes): z -> -y (roll) -> +x (yaw)
    T = matrix_from_origin((0, 0, 0), (math.pi / 2, 0, math.pi / 2))
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    # origin = T_parent_child: the child's origin sits at xyz in the parent frame
    T = matrix_from_origin((1, 2, 3), (0.1, 0.2, 0.3))
    np.testing.assert_allclose(T @ [0, 0, 0, 1], [1, 2, 3, 1], atol=0)


def test_forward_kinematics_composes_parent_to_child():
    u = parse_urdf(CHAIN, "chain.urdf")
    T = forward_kinematics(u, "base", "sensor")
    # j2 moves 1 m along mid's x, which j1's yaw turns into base's +y
    np.testing.assert_allclose(T[:3, 3], [0.5, 1.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(forward_kinematics(u, "sensor", "base"), invert(T), atol=1e-15)
    np.testing.assert_allclose(forward_kinematics(u, "mid", "mid"), np.eye(4))


def test_rpy_from_rotation_matches_geometry_and_survives_gimbal_lock():
    rng = np.random.default_rng(1)
    for _ in range(200):
        R = so3_exp(rng.normal(size=3))
        rpy = rpy_from_rotation(R)
        np.testing.assert_allclose(matrix_from_rpy(np.array(rpy)), R, atol=2e-15)
        np.testing.assert_allclose(rpy, rpy_from_matrix(R), atol=1e-9)
    for sign in (1.0, -1.0):
        for eps in (0.0, 1e-14, 1e-11, 1e-8, 1e-5):
            R = Rz(0.7) @ Ry(sign * (math.pi / 2 - eps)) @ Rx(-0.4)
            rpy = rpy_from_rotation(R)
            np.testing.assert_allclose(matrix_from_rpy(np.array(rpy)), R, atol=4e-15)
            assert abs(rpy[1]) <= math.pi / 2


def test_format_float_is_exact():
    rng = np.random.default_rng(2)
    for v in rng.normal(scale=10.0, size=500):
        assert float(format_float(v)) == v
    assert format_float(-0.0) == "0"
    assert format_float(3.0) == "3"
    assert format_float(1e22) == "1e+22"


def test_origin_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(100):
        T = random_pose(rng)
        xyz, rpy = origin_from_matrix(T)
        np.testing.assert_allclose(matrix_from_origin(xyz, rpy), T, atol=1e-14)


# ------------------------------------------------------------------------------ parsing


def test_parse_records_values_and_exact_spans():
    u = parse_urdf(CHAIN, "chain.urdf")
    assert list(u.links) == ["base", "mid", "sensor"]
    j1 = u.joints["j1"]
    assert (j1.type, j1.parent, j1.child, j1.line) == ("fixed", "base", "mid", 7)
    assert j1.origin.rpy == (0.0, 0.0, 1.5707963267948966)
    assert CHAIN[slice(*j1.origin.xyz_value)] == "0.5 0 1"
    assert CHAIN[slice(*j1.origin.rpy_value)] == "0 0 1.5707963267948966"
    assert CHAIN[slice(*j1.origin.tag)].startswith("<origin ")
    assert CHAIN[slice(*j1.element)].startswith('<joint name="j1"')
    assert CHAIN[slice(*j1.element)].endswith("</joint>")
    assert u.joint_to("sensor").name == "j2"
    assert u.joint_to("base") is None


def test_parse_is_immutable():
    u = parse_urdf(CHAIN)
    with pytest.raises(TypeError):
        u.links["x"] = None  # type: ignore[index]
    with pytest.raises(Exception):
        u.text = ""  # type: ignore[misc]


def test_parse_spans_with_non_ascii_text():
    text = CHAIN.replace("<!-- a comment -->", "<!-- Kalibrierung für Fahrzeug ✓ -->")
    u = parse_urdf(text)
    assert text[slice(*u.joints["j2"].origin.xyz_value)] == "1 0 0"


def test_transmission_joints_are_not_joints():
    text = CHAIN.replace(
        "</robot>",
        '  <transmission name="t"><joint name="j1"><hardwareInterface>x</hardwareInterface>'
        "</joint></transmission>\n</robot>",
    )
    assert list(parse_urdf(text).joints) == ["j1", "j2"]


def test_missing_origin_and_attributes_mean_zero():
    text = CHAIN.replace('<origin xyz="1 0 0" rpy="0 0 0"/>', "").replace(
        'rpy="0 0 1.5707963267948966"', ""
    )
    u = parse_urdf(text)
    assert u.joints["j2"].origin.tag is None
    assert u.joints["j2"].origin.xyz == (0.0, 0.0, 0.0)
    assert u.joints["j1"].origin.rpy == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("<robot", "<rob", r"malformed XML"),
        ('<link name="mid"/>', '<link name="mid">', r"line \d+, column \d+: malformed XML"),
        ('<link name="mid"/>', '<link name="base"/>', r"link 'base' is defined twice"),
        ('<link name="mid"/>', "<link/>", r"<link> without a name"),
        ('type="fixed">\n    <parent link="mid"', 'type="hinge">\n    <parent link="mid"',
         r"joint 'j2': type must be one of"),
        ('<parent link="mid"/>', "", r"joint 'j2': expected one <parent"),
        ('xyz="1 0 0"', 'xyz="1 0"', r"joint 'j2' origin xyz: expected three numbers"),
        ('xyz="1 0 0"', 'xyz="${x} 0 0"', r"xacro"),
        ('xyz="1 0 0"', 'xyz="nan 0 0"', r"expected three numbers"),
        ('<child link="sensor"/>', '<child link="mid"/>', r"parent and child are the same link"),
        ('<parent link="mid"/>\n    <child link="sensor"/>',
         '<parent link="base"/>\n    <child link="mid"/>', r"already the child of joint 'j1'"),
    ],
)
def test_parse_refusals(old, new, match):
    text = CHAIN.replace(old, new, 1)
    assert text != CHAIN
    with pytest.raises(InputError, match=r"^bad\.urdf: .*" + match):
        parse_urdf(text, "bad.urdf")


def test_root_must_be_robot():
    with pytest.raises(InputError, match=r"x\.urdf: expected the root element <robot>, got <sdf>"):
        parse_urdf("<sdf/>", "x.urdf")


# ------------------------------------------------------------------------------ hostile XML

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
]>
<robot name="&lol4;"><link name="base"/></robot>
"""

EXTERNAL_ENTITY = """<?xml version="1.0"?>
<!DOCTYPE robot [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>
<robot name="r"><link name="&xxe;"/></robot>
"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, EXTERNAL_ENTITY], ids=["laughs", "xxe"])
def test_hostile_xml_is_refused_before_parsing(text, monkeypatch):
    def explode(*_a, **_k):  # the guard must act before any parser sees the text
        raise AssertionError("parser reached")

    monkeypatch.setattr(urdf_module, "_parse_elements", explode)
    with pytest.raises(InputError, match=r"^evil\.urdf: line 2, column 1: refusing XML with a "
                                         r"<!DOCTYPE"):
        parse_urdf(text, "evil.urdf")


def test_hostile_xml_is_refused_by_update_and_write(tmp_path):
    with pytest.raises(InputError, match="refusing XML"):
        update_urdf_text(EXTERNAL_ENTITY, "evil.urdf", {"x": np.eye(4)}, "base")
    path = tmp_path / "evil.urdf"
    path.write_text(BILLION_LAUGHS)
    with pytest.raises(InputError, match="refusing XML"):
        write_urdf(path, tmp_path / "out.urdf", {"base": np.eye(4)}, "base")
    assert not (tmp_path / "out.urdf").exists()


def test_entity_declaration_without_doctype_text_is_refused():
    with pytest.raises(InputError, match=r"<!ENTITY"):
        parse_urdf('<robot><!ENTITY a "b"></robot>', "e.urdf")


def test_doctype_mentioned_in_a_comment_is_fine():
    text = CHAIN.replace("a comment", "no <!DOCTYPE here, just words")
    assert list(parse_urdf(text).joints) == ["j1", "j2"]


def test_expat_pass_refuses_a_dtd_on_its_own():
    # second line of defence: even if the text guard were bypassed, the parser stops at a DTD
    with pytest.raises(InputError, match=r"refusing XML with a DTD or entity declaration"):
        urdf_module._parse_elements(BILLION_LAUGHS, "evil.urdf")
    with pytest.raises(InputError, match=r"refusing XML with a DTD"):
        urdf_module._parse_elements(EXTERNAL_ENTITY, "evil.urdf")


def test_defusedxml_errors_are_wrapped(monkeypatch):
    class Forbidden(ValueError):
        pass

    def fromstring(text, forbid_dtd=False):
        assert forbid_dtd is True
        raise Forbidden("entities are forbidden")

    monkeypatch.setattr(urdf_module, "_defused_et", types.SimpleNamespace(fromstring=fromstring))
    with pytest.raises(InputError, match=r"^x\.urdf: refusing hostile XML \(Forbidden: entit"):
        parse_urdf(CHAIN, "x.urdf")

    def syntax(text, forbid_dtd=False):
        exc = SyntaxError("mismatched tag: line 3, column 4")
        exc.position = (3, 4)  # type: ignore[attr-defined]
        raise exc

    monkeypatch.setattr(urdf_module, "_defused_et", types.SimpleNamespace(fromstring=syntax))
    with pytest.raises(InputError, match=r"x\.urdf: line 3, column 5: malformed XML: mismatched"):
        parse_urdf(CHAIN, "x.urdf")


# ------------------------------------------------------------------------------ the shared example


def example():
    text = (DATA / "vehicle.urdf").read_text()
    yaml_text = (DATA / "calibration.yaml").read_text()
    cal = read_original_calibration_yaml(yaml_text, "calibration.yaml")
    return text, cal


def test_original_calibration_yaml_direction():
    _, cal = example()
    assert (cal.source, cal.target) == ("camera", "laser_link")
    # p_target = transform @ p_source: the camera's origin is at (2, -2, 0) in the laser frame
    np.testing.assert_allclose(cal.T_target_source @ [0, 0, 0, 1], [2, -2, 0, 1])


def test_shared_example_update_reproduces_the_calibration():
    text, cal = example()
    # keep the reference sensor (camera) where the URDF has it, place the laser from the YAML
    T_camera_laser = invert(cal.T_target_source)  # the laser's pose in the camera frame
    new = update_urdf_text(text, "vehicle.urdf", {cal.target: T_camera_laser}, cal.source)
    written = parse_urdf(new, "out.urdf")
    np.testing.assert_allclose(
        forward_kinematics(written, "camera", "laser_link"), T_camera_laser, atol=1e-9
    )
    # geometry by hand: base->chassis (1,0,0), chassis->camera_mount (0,1,0), ->camera (0,1,0):
    # camera at (1,2,0) in base_link; laser = camera + (-2,2,0) = (-1,4,0); its parent
    # laser_mount_link stays at (1,0,0)+(1,0,0) = (2,0,0), so laser_joint becomes (-3,4,0)
    np.testing.assert_allclose(
        forward_kinematics(written, "base_link", "laser_link")[:3, 3], [-1, 4, 0], atol=1e-12
    )
    assert written.joints["laser_joint"].origin.xyz == (-3.0, 4.0, 0.0)
    removed, added = changed_lines(text, new)
    assert removed == ['-        <origin xyz="1 0 0" rpy="0 0 0" />\n']
    assert added == ['+        <origin xyz="-3 4 0" rpy="0 0 0" />\n']
    # byte-identical around the one changed value
    span = parse_urdf(text).joints["laser_joint"].origin.xyz_value
    assert new[: span.start] == text[: span.start]
    assert new[span.start + len("-3 4 0") :] == text[span.end :]


def test_shared_example_with_body_link_and_named_joint():
    text, cal = example()
    u = parse_urdf(text, "vehicle.urdf")
    T_base_laser = forward_kinematics(u, "base_link", cal.source) @ invert(cal.T_target_source)
    # the same request expressed in base_link gives the same file
    same = update_urdf_text(text, "vehicle.urdf", {"laser_link": T_base_laser}, "base_link")
    assert same == update_urdf_text(
        text, "vehicle.urdf", {"laser_link": invert(cal.T_target_source)}, "camera"
    )
    # the original tool's example updates laser_mount_joint; the fixed laser_joint below it
    # (1,0,0) is kept and accounted for: mount = (-1,4,0) - (1,0,0) - chassis (1,0,0) = (-3,4,0)
    new = update_urdf_text(
        text, "vehicle.urdf", {"laser_link": T_base_laser}, "base_link",
        joint_for={"laser_link": "laser_mount_joint"},
    )
    written = parse_urdf(new)
    assert written.joints["laser_mount_joint"].origin.xyz == (-3.0, 4.0, 0.0)
    assert written.joints["laser_joint"].origin.xyz == (1.0, 0.0, 0.0)
    np.testing.assert_allclose(
        forward_kinematics(written, "base_link", "laser_link"), T_base_laser, atol=1e-9
    )
    removed, added = changed_lines(text, new)
    assert len(removed) == len(added) == 1 and "<origin" in removed[0] and "<origin" in added[0]


def test_output_urdf_of_the_original_assumes_the_inverse_direction():
    """The original's expected output reprints the input (laser_mount_joint 1 0 0): it treats
    ``transform`` as the laser's pose in the camera frame (``T_source_target``), the inverse of
    what its optimizer writes. Our reading gives a different, geometrically derived file."""
    text, cal = example()
    output = parse_urdf((DATA / "output.urdf").read_text(), "output.urdf")
    fk_output = forward_kinematics(output, "camera", "laser_link")
    np.testing.assert_allclose(fk_output, cal.T_target_source, atol=1e-12)  # the inverted reading
    assert np.max(np.abs(fk_output - invert(cal.T_target_source))) > 1.0  # not ours
    # the inverted transform (the classic mistake) reproduces output.urdf's joint values
    mistaken = update_urdf_text(
        text, "vehicle.urdf", {"laser_link": cal.T_target_source}, "camera",
        joint_for={"laser_link": "laser_mount_joint"},
    )
    assert parse_urdf(mistaken).joints["laser_mount_joint"].origin.xyz == (
        output.joints["laser_mount_joint"].origin.xyz
    )


def test_classic_mistakes_give_different_files():
    rng = np.random.default_rng(4)
    T = random_pose(rng)
    u = parse_urdf(CHAIN)
    right = solve_joint_origins(u, {"sensor": T}, "base")[0]
    wrong_inverse = solve_joint_origins(u, {"sensor": invert(T)}, "base")[0]
    assert not np.allclose(right.xyz, wrong_inverse.xyz)
    # reading the written rpy as intrinsic x-y-z (Rx Ry Rz) does not reproduce the pose
    r, p, y = right.rpy
    T_j1 = u.joints["j1"].origin.matrix
    T_wrong = T_j1 @ from_rt(Rx(r) @ Ry(p) @ Rz(y), right.xyz)
    T_right = T_j1 @ from_rt(Rz(y) @ Ry(p) @ Rx(r), right.xyz)
    np.testing.assert_allclose(T_right, T, atol=1e-12)
    assert np.max(np.abs(T_wrong - T)) > 1e-3
    # writing (yaw, pitch, roll) into rpy (order swapped) does not either
    T_swapped = T_j1 @ matrix_from_origin(right.xyz, (y, p, r))
    assert np.max(np.abs(T_swapped - T)) > 1e-3


# ------------------------------------------------------------------------------ updates


def test_update_keeps_everything_else_byte_identical():
    rng = np.random.default_rng(5)
    T = random_pose(rng)
    new = update_urdf_text(CHAIN, "chain.urdf", {"sensor": T}, "base")
    removed, added = changed_lines(CHAIN, new)
    assert removed == ['-    <origin xyz="1 0 0" rpy="0 0 0"/>\n']
    assert len(added) == 1
    assert added[0].startswith('+    <origin xyz="') and added[0].endswith('"/>\n')
    np.testing.assert_allclose(forward_kinematics(parse_urdf(new), "base", "sensor"), T, atol=1e-9)


def test_only_changed_attributes_are_rewritten():
    u = parse_urdf(CHAIN)
    T = u.joints["j1"].origin.matrix @ from_rt(np.eye(3), [5.0, 0.0, 0.0])  # translation only
    new = update_urdf_text(CHAIN, "chain.urdf", {"sensor": T}, "base")
    assert '<origin xyz="5 0 0" rpy="0 0 0"/>' in new  # rpy text untouched


def test_update_by_joint_name_and_unchanged_request():
    u = parse_urdf(CHAIN)
    same = update_urdf_text(CHAIN, "c", {"j2": forward_kinematics(u, "base", "sensor")}, "base")
    assert same == CHAIN


def test_missing_origin_is_inserted_with_the_files_style():
    text = CHAIN.replace('    <origin xyz="1 0 0" rpy="0 0 0"/>\n', "")
    T = random_pose(np.random.default_rng(6))
    new = update_urdf_text(text, "c", {"sensor": T}, "base")
    removed, added = changed_lines(text, new)
    assert removed == [] and len(added) == 1
    assert added[0].startswith('+    <origin xyz="') and added[0].endswith('"/>\n')
    np.testing.assert_allclose(forward_kinematics(parse_urdf(new), "base", "sensor"), T, atol=1e-9)
    # CRLF files, single quotes and " />" tags keep their style
    crlf = text.replace("\n", "\r\n").replace('"', "'").replace("/>", " />")
    new = update_urdf_text(crlf, "c", {"sensor": T}, "base")
    assert "\r\n    <origin xyz='" in new and "' />\r\n  </joint>" in new
    assert "\n" not in new.replace("\r\n", "")


def test_missing_attribute_is_added():
    text = CHAIN.replace('<origin xyz="1 0 0" rpy="0 0 0"/>', '<origin xyz="1 0 0"/>')
    T = random_pose(np.random.default_rng(7))
    new = update_urdf_text(text, "c", {"sensor": T}, "base")
    assert '<origin xyz="' in new and '" rpy="' in new
    np.testing.assert_allclose(forward_kinematics(parse_urdf(new), "base", "sensor"), T, atol=1e-9)
    text = CHAIN.replace('<origin xyz="1 0 0" rpy="0 0 0"/>', "<origin/>")
    new = update_urdf_text(text, "c", {"sensor": T}, "base")
    np.testing.assert_allclose(forward_kinematics(parse_urdf(new), "base", "sensor"), T, atol=1e-9)


def test_inputs_are_not_mutated():
    T = random_pose(np.random.default_rng(8))
    before = T.copy()
    updates = {"sensor": T}
    update_urdf_text(CHAIN, "c", updates, "base")
    assert np.array_equal(T, before) and list(updates) == ["sensor"]


def test_rotation_printed_with_few_digits_is_projected():
    T = random_pose(np.random.default_rng(12))
    rounded = np.round(T, 7)
    plan = solve_joint_origins(parse_urdf(CHAIN), {"sensor": rounded}, "base")
    used = plan[0].T_body_sensor
    np.testing.assert_allclose(used[:3, :3].T @ used[:3, :3], np.eye(3), atol=1e-14)
    np.testing.assert_allclose(used, rounded, atol=1e-6)
    new = update_urdf_text(CHAIN, "c", {"sensor": rounded}, "base")
    fk = forward_kinematics(parse_urdf(new), "base", "sensor")
    np.testing.assert_allclose(fk, used, atol=1e-9)


def test_nested_sensors_are_solved_top_down():
    rng = np.random.default_rng(9)
    T_mid, T_sensor = random_pose(rng), random_pose(rng)
    new = update_urdf_text(CHAIN, "c", {"sensor": T_sensor, "mid": T_mid}, "base")
    u = parse_urdf(new)
    np.testing.assert_allclose(forward_kinematics(u, "base", "mid"), T_mid, atol=1e-9)
    np.testing.assert_allclose(forward_kinematics(u, "base", "sensor"), T_sensor, atol=1e-9)


# ------------------------------------------------------------------------------ refusals


TREE = CHAIN.replace(
    "</robot>",
    """  <link name="arm"/>
  <link name="tool"/>
  <joint name="hinge" type="revolute">
    <parent link="mid"/>
    <child link="arm"/>
    <origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/>
  </joint>
  <joint name="j4" type="fixed">
    <parent link="arm"/>
    <child link="tool"/>
  </joint>
  <link name="other_root"/>
</robot>""",
)


@pytest.mark.parametrize(
    "updates, body, joint_for, match",
    [
        ({"lidar": np.eye(4)}, "base", None, r"no link or joint named 'lidar'"),
        ({"sensor": np.eye(4)}, "chassis", None, r"no link named 'chassis'"),
        ({"tool": np.eye(4)}, "base", None,
         r"chain from link 'base' to link 'tool' has non-fixed joint\(s\) 'hinge' \(revolute"),
        ({"sensor": np.eye(4), "mid": np.eye(4)}, "base", {"sensor": "j1"},
         r"sensors 'sensor' and 'mid' would both change joint 'j1'"),
        ({"sensor": np.eye(4)}, "base", {"sensor": "j4"},
         r"joint 'j4' \(for 'sensor'\) is not on the chain from body link 'base' to link 'sensor'"),
        ({"base": np.eye(4)}, "sensor", None, r"link 'base' is a root link"),
        ({"mid": np.eye(4)}, "sensor", {"mid": "j2"},
         r"joint 'j2' \(for 'mid'\) lies on the body link's side"),
        ({"mid": np.eye(4)}, "sensor", None,
         r"joint 'j1' \(for 'mid'\) lies above link 'mid', where the chains .* meet"),
        ({"sensor": np.eye(4)}, "base", {"sensor": "nope"}, r"no joint named 'nope'"),
        ({"sensor": np.eye(4)}, "base", {"mid": "j1"}, r"joint_for names 'mid'"),
        ({"sensor": np.eye(4)}, "sensor", None, r"is the body link 'sensor' itself"),
        ({"sensor": np.eye(4)}, "other_root", None,
         r"links 'other_root' and 'sensor' are not connected"),
        ({"sensor": np.zeros((3, 3))}, "base", None, r"T_base_sensor: expected a 4x4 matrix"),
        ({"sensor": np.diag([1.0, 1.0, -1.0, 1.0])}, "base", None, r"must be a rotation"),
        ({"sensor": np.full((4, 4), np.nan)}, "base", None, r"expected finite numbers"),
        ({}, "base", None, r"expected a non-empty mapping"),
    ],
)
def test_update_refusals(updates, body, joint_for, match):
    with pytest.raises(InputError, match=r"^tree\.urdf: .*" + match):
        update_urdf_text(TREE, "tree.urdf", updates, body, joint_for)


def test_fighting_requests_are_refused():
    # 'sensor' through j1 keeps j2 fixed, but j2 is changed for 'x' - refuse, do not guess
    with pytest.raises(InputError, match=r"joint 'j2' \(changed for 'j2'\) lies between joint "
                                         r"'j1' \(changed for 'sensor'\) and link 'sensor'"):
        update_urdf_text(
            CHAIN, "c", {"sensor": np.eye(4), "j2": np.eye(4)}, "base", {"sensor": "j1"}
        )


def test_forward_kinematics_refuses_revolute_and_missing():
    u = parse_urdf(TREE, "tree.urdf")
    with pytest.raises(InputError, match=r"tree\.urdf: the chain .* 'hinge' \(revolute, line \d+"):
        forward_kinematics(u, "base", "tool")
    with pytest.raises(InputError, match=r"tree\.urdf: no link named 'wheel'"):
        forward_kinematics(u, "base", "wheel")
    # a non-fixed joint elsewhere in the tree does not matter
    forward_kinematics(u, "base", "sensor")


def test_dangling_parent_link_is_refused():
    text = CHAIN.replace('<parent link="base"/>', '<parent link="ghost"/>')
    with pytest.raises(InputError, match=r"joint 'j1' names parent link 'ghost', which is not"):
        forward_kinematics(parse_urdf(text, "c.urdf"), "mid", "sensor")


# ------------------------------------------------------------------------------ random chains


def random_urdf(rng) -> str:
    """A random tree of fixed joints in varied but legal formatting, with comments."""
    n = int(rng.integers(3, 9))
    lines = ['<?xml version="1.0" encoding="utf-8"?>', '<robot name="random">']
    for i in range(n):
        lines.append(f'  <link name="l{i}"/>')
        if rng.random() < 0.3:
            lines.append(f"  <!-- link l{i}: <joint> in a comment is not a joint -->")
    for i in range(1, n):
        parent = int(rng.integers(0, i))
        xyz = rng.uniform(-3, 3, size=3)
        rpy = rng.uniform([-math.pi, -math.pi / 2, -math.pi], [math.pi, math.pi / 2, math.pi])
        fmt = (lambda v: "%.6f" % v) if rng.random() < 0.5 else repr
        xyz_s, rpy_s = " ".join(fmt(float(v)) for v in xyz), " ".join(fmt(float(v)) for v in rpy)
        style = int(rng.integers(0, 5))
        origin = [
            f'    <origin xyz="{xyz_s}" rpy="{rpy_s}"/>',
            f"    <origin rpy='{rpy_s}'\n            xyz='{xyz_s}' />",
            f'    <origin xyz="{xyz_s}" />',
            None,
            f'    <origin rpy="{rpy_s}"></origin>',
        ][style]
        lines += [f'  <joint name="j{i}" type="fixed">', f'    <parent link="l{parent}"/>',
                  f'    <child link="l{i}"/>']
        if origin is not None:
            lines.append(origin)
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def check_round_trip(rng) -> None:
    text = random_urdf(rng)
    u = parse_urdf(text, "random.urdf")
    links = list(u.links)
    body = "l0" if rng.random() < 0.7 else str(rng.choice(links))
    candidates = [l for l in links if l != body]
    k = int(rng.integers(1, min(4, len(candidates)) + 1))
    sensors = [str(s) for s in rng.choice(candidates, size=k, replace=False)]
    updates = {s: random_pose(rng) for s in sensors}
    joint_for = {}
    for s in sensors:
        if rng.random() < 0.3:  # sometimes a joint higher up the chain
            up, down = urdf_module._path(u, body, s)
            if down:
                joint_for[s] = down[int(rng.integers(0, len(down)))].name
    try:
        new = update_urdf_text(text, "random.urdf", updates, body, joint_for)
    except InputError as exc:  # only the documented conflicts may refuse
        assert any(m in str(exc) for m in ("would both change", "both poses cannot be met",
                                           "body link's side", "is a root link",
                                           "moves both together")), str(exc)
        return
    written = parse_urdf(new, "random.urdf")
    for s, T in updates.items():
        np.testing.assert_allclose(forward_kinematics(written, body, s), T, atol=1e-9)
    changed = {j.joint for j in solve_joint_origins(u, updates, body, joint_for)}
    for name, joint in u.joints.items():
        if name not in changed:
            assert written.joints[name].origin[:2] == joint.origin[:2]
    # only origin lines differ
    for line in difflib.ndiff(text.splitlines(), new.splitlines()):
        if line[:1] in "+-":
            assert "origin" in line or "xyz=" in line, line


def test_random_chains_round_trip_seeded():
    rng = np.random.default_rng(10)
    for _ in range(150):
        check_round_trip(rng)


@settings(max_examples=60, deadline=None)
@given(st.integers(min_value=0, max_value=2**32 - 1))
def test_random_chains_round_trip_hypothesis(seed):
    check_round_trip(np.random.default_rng(seed))


# ------------------------------------------------------------------------------ original YAML


@pytest.mark.parametrize(
    "text, match",
    [
        ("- 1\n", r"expected a mapping"),
        ("source: a\ntarget: b\n", r"missing key\(s\) transform"),
        ("source: a\ntarget: b\ntransform: 3\nextra: 1\n", r"unknown key\(s\) 'extra'"),
        ("source: a\ntarget: b\ntransform: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n",
         r"transform: expected 4 rows of 4 numbers, got 3 rows"),
        ("source: a\ntarget: ''\ntransform: 1\n", r"target: expected a frame name"),
        ("source: a\ntarget: b\ntransform: [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], "
         "[0, 0, 0, 1]]\n", r"transform\[0\]\[3\]: expected a finite number"),
        ("source: a\ntarget: b\ntransform: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
         "[0, 0, 0, 1]]\n", r"must be a rotation"),
        ("source: a\ntarget: b\ntransform: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
         "[0, 0, 1, 1]]\n", r"last row must be \[0, 0, 0, 1\]"),
        ("source: [a\n", r"invalid YAML"),
    ],
)
def test_original_yaml_refusals(text, match):
    with pytest.raises(InputError, match=r"^cal\.yaml: .*" + match):
        read_original_calibration_yaml(text, "cal.yaml")


# ------------------------------------------------------------------------------ files


def test_write_urdf_new_file_leaves_input_alone(tmp_path):
    src = tmp_path / "vehicle.urdf"
    src.write_bytes((DATA / "vehicle.urdf").read_bytes())
    before = src.read_bytes()
    T = invert(example()[1].T_target_source)
    result = write_urdf(src, tmp_path / "out" / "calibrated.urdf", {"laser_link": T}, "camera")
    assert result.path == tmp_path / "out" / "calibrated.urdf" and result.backup is None
    assert src.read_bytes() == before
    written = parse_urdf(result.path.read_text())
    np.testing.assert_allclose(forward_kinematics(written, "camera", "laser_link"), T, atol=1e-9)


def test_write_urdf_refuses_to_overwrite_input_without_in_place(tmp_path):
    src = tmp_path / "v.urdf"
    src.write_text(CHAIN)
    with pytest.raises(InputError, match=r"v\.urdf: is the input file; refusing to overwrite"):
        write_urdf(src, src, {"sensor": np.eye(4)}, "base")
    with pytest.raises(InputError, match=r"in_place=True"):
        write_urdf(src, None, {"sensor": np.eye(4)}, "base")
    if hasattr(os, "link"):
        os.link(src, tmp_path / "hard.urdf")
        with pytest.raises(InputError, match="is the input file"):
            write_urdf(src, tmp_path / "hard.urdf", {"sensor": np.eye(4)}, "base")
    with pytest.raises(InputError, match=r"in_place rewrites the input"):
        write_urdf(src, tmp_path / "other.urdf", {"sensor": np.eye(4)}, "base", in_place=True)
    assert src.read_text() == CHAIN
    assert sorted(p.name for p in tmp_path.iterdir()) in (["hard.urdf", "v.urdf"], ["v.urdf"])


def test_write_urdf_in_place_keeps_backups(tmp_path):
    src = tmp_path / "v.urdf"
    original = b"\xef\xbb\xbf" + CHAIN.replace("\n", "\r\n").encode()
    src.write_bytes(original)
    rng = np.random.default_rng(11)
    T1, T2 = random_pose(rng), random_pose(rng)
    first = write_urdf(src, None, {"sensor": T1}, "base", in_place=True)
    assert first.path == src and first.backup == tmp_path / "v.urdf.bak"
    assert first.backup.read_bytes() == original
    data = src.read_bytes()
    assert data.startswith(b"\xef\xbb\xbf") and b"\r\n" in data and b"\n\n" not in data
    u = parse_urdf(data[3:].decode())
    np.testing.assert_allclose(forward_kinematics(u, "base", "sensor"), T1, atol=1e-9)
    second = write_urdf(src, src, {"sensor": T2}, "base", in_place=True)
    assert second.backup == tmp_path / "v.urdf.bak.1"
    assert second.backup.read_bytes() == data
    assert first.backup.read_bytes() == original


def test_write_urdf_in_place_through_a_symlink(tmp_path):
    real = tmp_path / "real.urdf"
    real.write_text(CHAIN)
    link = tmp_path / "robot.urdf"
    try:
        link.symlink_to(real)
    except OSError:  # pragma: no cover - no symlinks on this system
        pytest.skip("symlinks not available")
    T = random_pose(np.random.default_rng(13))
    result = write_urdf(link, None, {"sensor": T}, "base", in_place=True)
    assert link.is_symlink() and result.backup.read_text() == CHAIN
    np.testing.assert_allclose(
        forward_kinematics(parse_urdf(real.read_text()), "base", "sensor"), T, atol=1e-9
    )


def test_write_urdf_refusal_writes_nothing(tmp_path):
    src = tmp_path / "v.urdf"
    src.write_text(TREE)
    with pytest.raises(InputError, match="non-fixed"):
        write_urdf(src, None, {"tool": np.eye(4)}, "base", in_place=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.urdf"]
    with pytest.raises(InputError, match=r"missing\.urdf: URDF file not found"):
        write_urdf(tmp_path / "missing.urdf", tmp_path / "o.urdf", {"x": np.eye(4)}, "base")


def test_set_joint_origins_refuses_non_finite():
    u = parse_urdf(CHAIN, "c.urdf")
    with pytest.raises(InputError, match=r"c\.urdf: joint 'j2': origin needs three finite"):
        set_joint_origins(u, {"j2": ((0, 0, float("nan")), (0, 0, 0))})


# ---------------------------------------------------------------------------------------------
# a rigcal calibration into a URDF: links by frame_id, missing links, camera optical frames

ROBOT = """<?xml version="1.0"?>
<robot name="car">
  <link name="base_link"/>
  <link name="lidar"/>
  <joint name="lidar_joint" type="fixed">
    <parent link="base_link"/><child link="lidar"/>
    <origin xyz="1 0 1.5" rpy="0 0 0"/>
  </joint>
  <link name="cam_link"/>
  <joint name="cam_joint" type="fixed">
    <parent link="base_link"/><child link="cam_link"/>
    <origin xyz="1.5 0.2 1.2" rpy="0 0 0"/>
  </joint>
  <link name="cam_optical_frame"/>
  <joint name="cam_optical_joint" type="fixed">
    <parent link="cam_link"/><child link="cam_optical_frame"/>
    <origin xyz="0 0 0" rpy="-1.5707963267948966 0 -1.5707963267948966"/>
  </joint>
</robot>
"""


def _rigid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return from_rt(so3_exp(rng.normal(0, 0.5, 3)), rng.normal(0, 1.0, 3))


def _robot(tmp_path) -> Path:
    p = tmp_path / "car.urdf"
    p.write_text(ROBOT)
    return p


def test_missing_links_are_skipped_and_the_rest_reproduced(tmp_path):
    T_lidar, T_radar = _rigid(1), _rigid(2)
    written = write_urdf(_robot(tmp_path), tmp_path / "out.urdf",
                         {"lidar": T_lidar, "front_radar": T_radar}, "base_link", missing="skip")
    assert written.skipped == ("front_radar",) and written.added == ()
    out = parse_urdf((tmp_path / "out.urdf").read_text(), "out")
    assert np.abs(forward_kinematics(out, "base_link", "lidar") - T_lidar).max() < 1e-6
    assert "front_radar" not in out.links


def test_missing_links_are_added_on_request(tmp_path):
    T_lidar, T_radar = _rigid(3), _rigid(4)
    written = write_urdf(_robot(tmp_path), tmp_path / "out.urdf",
                         {"lidar": T_lidar, "front_radar": T_radar}, "base_link", missing="add")
    assert written.added == ("front_radar",) and written.skipped == ()
    out = parse_urdf((tmp_path / "out.urdf").read_text(), "out")
    for link, T in (("lidar", T_lidar), ("front_radar", T_radar)):
        assert np.abs(forward_kinematics(out, "base_link", link) - T).max() < 1e-6
    assert out.joints["front_radar_joint"].type == "fixed"


def test_nothing_in_common_or_a_missing_body_link_says_what_to_set(tmp_path):
    with pytest.raises(InputError, match="none of the calibrated frames .*frame_id"):
        write_urdf(_robot(tmp_path), tmp_path / "o.urdf", {"radar1": _rigid(5)}, "base_link",
                   missing="skip")
    with pytest.raises(InputError, match="no link named 'lidar1'.*frame_id"):
        write_urdf(_robot(tmp_path), tmp_path / "o.urdf", {"camera1": _rigid(5)}, "lidar1",
                   missing="skip")
    assert not (tmp_path / "o.urdf").exists()


@pytest.mark.parametrize("frame", ["cam_link", "cam_optical_frame"])
def test_camera_optical_frame_follows_rep_103(tmp_path, frame):
    """A camera's calibrated pose is its optical frame's (z forward). Whether the manifest names
    the body-convention link or its optical child, the optical child ends up at the calibrated
    pose and the fixed optical rotation is kept; the camera link's joint moves."""
    T_opt = _rigid(6)
    written = write_urdf(_robot(tmp_path), tmp_path / "out.urdf", {frame: T_opt}, "base_link",
                         kinds={frame: "camera"}, missing="skip")
    assert written.notes and "REP 103" in written.notes[0]
    out = parse_urdf((tmp_path / "out.urdf").read_text(), "out")
    assert np.abs(forward_kinematics(out, "base_link", "cam_optical_frame") - T_opt).max() < 1e-6
    before = parse_urdf(ROBOT, "in").joints["cam_optical_joint"].origin
    after = out.joints["cam_optical_joint"].origin
    assert (after.xyz, after.rpy) == (before.xyz, before.rpy)
    # a non-camera frame of the same name is taken literally (no optical mapping)
    literal = write_urdf(_robot(tmp_path), tmp_path / "lit.urdf", {"cam_link": T_opt}, "base_link",
                         missing="skip")
    assert literal.notes == ()
    lit = parse_urdf((tmp_path / "lit.urdf").read_text(), "lit")
    assert np.abs(forward_kinematics(lit, "base_link", "cam_link") - T_opt).max() < 1e-6


def test_prius_calibration_into_the_shared_urdf(tmp_path):
    """The README/guide path: a rigcal calibration of the shared Prius detections (frame ids
    laser_link / camera / front_radar) into the shared vehicle.urdf, which has no radar link."""
    import yaml

    from rigcal.cli.main import run
    from rigcal.io.results.calibration_files import read_calibration_transforms

    manifest = Path(__file__).resolve().parents[3] / "examples" / "prius" / "rig.yaml"
    vehicle = DATA / "vehicle.urdf"
    # the manifest reads ../shared beside the checkout (DATA may come from another layout)
    detections = manifest.parents[3] / "shared" / "data" / "tudelft_prius" / "detections" / "lidar.csv"
    if not vehicle.is_file() or not detections.is_file():
        pytest.skip("../shared/data not present")
    assert run(["calibrate", str(manifest), "--mode", "fcpe", "--out", str(tmp_path / "cal"),
                "--no-plot"]) == 0
    cal = tmp_path / "cal" / "calibration.yaml"
    assert run(["urdf", str(vehicle), str(cal), "--out", str(tmp_path / "skip.urdf")]) == 0
    assert run(["urdf", str(vehicle), str(cal), "--out", str(tmp_path / "add.urdf"),
                "--add-missing"]) == 0
    transforms = read_calibration_transforms(cal).transforms
    assert set(transforms) == {"camera", "front_radar"}
    skip = parse_urdf((tmp_path / "skip.urdf").read_text(), "skip")
    add = parse_urdf((tmp_path / "add.urdf").read_text(), "add")
    assert "front_radar" not in skip.links and "front_radar" in add.links
    for urdf, frames in ((skip, ["camera"]), (add, ["camera", "front_radar"])):
        for frame in frames:
            got = forward_kinematics(urdf, "laser_link", frame)
            assert np.abs(got - transforms[frame]).max() < 1e-6
    assert yaml.safe_load(cal.read_text())["sensors"]["lidar1"]["frame_id"] == "laser_link"
