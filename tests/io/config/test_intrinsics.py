"""ROS camera calibration files (INI and CameraInfo YAML) -> RadtanCamera."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.config.intrinsics import (
    parse_camera_info_yaml_text,
    parse_intrinsics_ini_text,
    read_intrinsics,
)
from rigcal.sensors.camera import RadtanCamera

MONO = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "tudelft_prius" / "mono"

K = [[1419.435287, 0.0, 948.748187], [0.0, 1442.298159, 621.179140], [0.0, 0.0, 1.0]]
D = [-0.175243, 0.158967, 0.003024, -0.002257, -0.062404]

INI = """# oST version 5.0 parameters


[image]

width
1936

height
1216

[narrow_stereo/left]

camera matrix
1419.435287 0.000000 948.748187
0.000000 1442.298159 621.179140
0.000000 0.000000 1.000000

distortion
-0.175243 0.158967 0.003024 -0.002257 -0.062404

rectification
0.999822 -0.002368 -0.018702
0.002425 0.999992 0.003022
0.018694 -0.003067 0.999821

projection
1495.468642 0.000000 961.272442 0.000000
0.000000 1495.468642 624.895920 0.000000
0.000000 0.000000 1.000000 0.000000
"""

YAML = """image_width: 1936
image_height: 1216
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [1419.435287, 0.0, 948.748187, 0.0, 1442.298159, 621.179140, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.175243, 0.158967, 0.003024, -0.002257, -0.062404]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [1495.47, 0, 961.27, 0, 0, 1495.47, 624.90, 0, 0, 0, 1, 0]
"""


def check_prius(cam: RadtanCamera) -> None:
    assert isinstance(cam, RadtanCamera)
    assert cam.size_wh == (1936, 1216)
    np.testing.assert_array_equal(cam.camera_matrix, K)
    np.testing.assert_array_equal(cam.dist_coeffs, D)


def test_parse_ini():
    check_prius(parse_intrinsics_ini_text(INI, "mem.ini"))


def test_parse_yaml():
    check_prius(parse_camera_info_yaml_text(YAML, "mem.yaml"))


def test_ini_and_yaml_agree_and_four_coefficients_mean_k3_zero():
    ini = INI.replace(" -0.062404", "")
    yaml_text = YAML.replace("cols: 5", "cols: 4").replace(", -0.062404]", "]")
    a = parse_intrinsics_ini_text(ini, "mem.ini")
    b = parse_camera_info_yaml_text(yaml_text, "mem.yaml")
    assert a == b and a.param("k3") == 0.0


def test_real_ini():
    path = MONO / "intrinsics.ini"
    if not path.is_file():
        pytest.skip(f"real data not present: {path}")
    check_prius(read_intrinsics(path))


@pytest.mark.parametrize(
    "suffix, text",
    [(".ini", INI), (".yaml", YAML), (".yml", YAML), (".txt", INI), (".cal", YAML)],
)
def test_read_intrinsics_by_extension_or_content(tmp_path, suffix, text):
    p = tmp_path / f"cam{suffix}"
    p.write_text(text)
    check_prius(read_intrinsics(p))


def test_read_missing_file(tmp_path):
    with pytest.raises(InputError, match="nope.ini: camera intrinsics file not found"):
        read_intrinsics(tmp_path / "nope.ini")


def test_several_camera_sections_need_a_name():
    right = "[narrow_stereo/right]\ncamera matrix\n1 0 1\n0 1 1\n0 0 1\ndistortion\n0 0 0 0 0\n"
    two = INI + "\n" + right
    with pytest.raises(InputError, match="several camera sections"):
        parse_intrinsics_ini_text(two, "s.ini")
    check_prius(parse_intrinsics_ini_text(two, "s.ini", camera_name="narrow_stereo/left"))
    cam_right = parse_intrinsics_ini_text(two, "s.ini", camera_name="narrow_stereo/right")
    assert cam_right.param("fx") == 1.0
    with pytest.raises(InputError, match=r"no camera section \[front\]"):
        parse_intrinsics_ini_text(two, "s.ini", camera_name="front")


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("[image]", "[picture]", r"bad.ini: line 6: \[picture\] unknown key 'width'"),
        ("[image]\n\nwidth\n1936\n\nheight\n1216", "", r"bad.ini: missing section \[image\]"),
        ("width\n1936", "", r"bad.ini: \[image\]: missing 'width'"),
        ("1216", "1216.5", r"bad.ini: line 9: \[image\] height: expected one integer"),
        ("1936", "abc", r"bad.ini: line 7: \[image\] width: expected a number, got 'abc'"),
        (
            "-0.062404",
            "-0.062404 0.1",
            r"line 19: \[narrow_stereo/left\] distortion: "
            r"expected 5 plumb-bob coefficients .* got 6",
        ),
        (
            "0.003024 -0.002257 -0.062404",
            "0.003024",
            r"distortion: expected 5 plumb-bob coefficients .*got 3",
        ),
        (
            "1442.298159 621.179140",
            "1442.298159",
            r"line 14: \[narrow_stereo/left\] camera matrix: expected 3 rows of 3 numbers, "
            r"got 3 rows \(3 \+ 2 \+ 3 numbers\)",
        ),
        (
            "621.179140",
            "six21",
            r"line 16: \[narrow_stereo/left\] camera matrix: expected a number, got 'six21'",
        ),
        ("0.999992", "nan", r"rectification: expected a finite number, got 'nan'"),
        (
            "1495.468642 0.000000 961.272442 0.000000",
            "1495.468642 0.000000 961.272442",
            r"projection: expected 3 rows of 4 numbers",
        ),
        (
            "camera matrix\n",
            "",
            r"line 14: \[narrow_stereo/left\] numbers before any key",
        ),
        (
            "distortion\n-0.175243 0.158967 0.003024 -0.002257 -0.062404\n",
            "",
            r"\[narrow_stereo/left\] \(line 12\): missing 'distortion'",
        ),
        ("[narrow_stereo/left]", "[narrow_stereo/left", "line 12: malformed section header"),
        (
            "rectification",
            "rectifikation",
            r"unknown key 'rectifikation' \(expected one of: camera matrix, distortion",
        ),
        (
            "0.000000 1442.298159",
            "1.0 1442.298159",
            r"camera matrix: expected \[\[fx, 0, cx\], \[0, fy, cy\], \[0, 0, 1\]\]",
        ),
        ("1419.435287 0.000000", "-1419.435287 0.000000", r"camera matrix: fx and fy must be > 0"),
    ],
)
def test_ini_errors_name_file_line_and_field(old, new, match):
    assert old in INI
    with pytest.raises(InputError, match=match):
        parse_intrinsics_ini_text(INI.replace(old, new, 1), "bad.ini")


def test_ini_without_camera_section():
    text = "[image]\nwidth\n10\nheight\n10\n"
    with pytest.raises(InputError, match="bad.ini: missing the camera section"):
        parse_intrinsics_ini_text(text, "bad.ini")


def test_ini_text_before_any_section():
    with pytest.raises(InputError, match=r"bad.ini: line 1: 'width' before the first \[section\]"):
        parse_intrinsics_ini_text("width\n" + INI, "bad.ini")


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("image_width: 1936\n", "", "bad.yaml: missing field 'image_width'"),
        (
            "image_height: 1216",
            "image_height: -3",
            "bad.yaml: image_height: expected a positive integer",
        ),
        (
            "image_width: 1936",
            "image_width: wide",
            "bad.yaml: image_width: expected a positive integer",
        ),
        (
            "plumb_bob",
            "equidistant",
            "bad.yaml: distortion_model: only plumb_bob is supported, got 'equidistant'",
        ),
        (
            "cols: 5",
            "cols: 6",
            r"bad.yaml: distortion_coefficients: rows x cols = 1 x 6 but data has 5 numbers",
        ),
        (
            "cols: 5\n  data: [-0.175243, 0.158967, 0.003024, -0.002257, -0.062404]",
            "cols: 3\n  data: [-0.175243, 0.158967, 0.003024]",
            r"distortion_coefficients: expected 5 plumb-bob coefficients .*got 3",
        ),
        (
            "0.0, 1442.298159",
            "0.0, x1442",
            r"bad.yaml: camera_matrix.data\[4\]: expected a finite number, got 'x1442'",
        ),
        (
            "rows: 3\n  cols: 3\n  data: [1419",
            "rows: 1\n  cols: 9\n  data: [1419",
            r"camera_matrix: expected 3 x 3, got 1 x 9",
        ),
        ("  cols: 4\n", "  cols: 3\n", r"projection_matrix: rows x cols = 3 x 3 but data has 12"),
        ("camera_matrix:\n  rows: 3\n", "camera_matrix:\n", r"camera_matrix: missing 'rows'"),
        (
            "image_width: 1936",
            "image_width: 1936\nimage_width: 1936",
            r"duplicate key 'image_width'",
        ),
    ],
)
def test_yaml_errors_name_file_and_field(old, new, match):
    assert old in YAML
    with pytest.raises(InputError, match=match):
        parse_camera_info_yaml_text(YAML.replace(old, new, 1), "bad.yaml")


def test_yaml_not_a_mapping():
    with pytest.raises(InputError, match="bad.yaml: expected a CameraInfo mapping"):
        parse_camera_info_yaml_text("- 1\n- 2\n", "bad.yaml")
    with pytest.raises(InputError, match=r"bad.yaml: line \d+, column \d+: invalid YAML"):
        parse_camera_info_yaml_text("a: [1, 2\n", "bad.yaml")
