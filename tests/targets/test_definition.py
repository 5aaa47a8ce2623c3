"""The Target value and its crop box: validation at the boundary, immutability, derived views."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.targets.definition import CropBox, Target, TargetKind

PLATE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def test_kind_parse():
    assert TargetKind.parse("Cylinder") is TargetKind.CYLINDER
    assert TargetKind.parse(TargetKind.CUSTOM) is TargetKind.CUSTOM
    assert TargetKind("checkerboard_diamond") is TargetKind.CHECKERBOARD_DIAMOND
    with pytest.raises(InputError, match=r"t\.json: unknown target kind 'sphere' \(expected one "
                                         r"of checkerboard_diamond, cylinder, circle_board, "
                                         r"custom\)"):
        TargetKind.parse("sphere", "t.json")


def test_crop_box_bounds_and_contains():
    box = CropBox.from_bounds([-0.5, 0.75, -0.4, 0.6, -0.15, 0.15])
    assert box.bounds() == (-0.5, 0.75, -0.4, 0.6, -0.15, 0.15)
    np.testing.assert_array_equal(box.min_xyz, [-0.5, -0.4, -0.15])
    pts = np.array([[0, 0, 0], [0.75, 0.6, 0.15], [0.8, 0, 0], [0, 0, -0.2]])
    assert box.contains(pts).tolist() == [True, True, False, False]
    around = CropBox.around(PLATE, 0.1)
    np.testing.assert_allclose(around.bounds(), (-0.1, 1.1, -0.1, 1.1, -0.1, 0.1))
    with pytest.raises(ValueError):
        box.min_xyz[0] = 0.0


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: CropBox.from_bounds([0, 1, 0, 1]), r"expected 6 bounds \(x_min, x_max, y_min"),
        (lambda: CropBox.from_bounds([0, 1, 1, 0, 0, 1]), r"crop box: y min must be below max"),
        (lambda: CropBox([0, 0, 0], [1, 1, np.inf]), r"bounds must be finite"),
        (lambda: CropBox([0, 0], [1, 1]), r"min and max need 3 values each, got 2 and 2"),
        (lambda: CropBox.around(PLATE, 0.0), r"margin_m must be > 0"),
    ],
)
def test_crop_box_errors(call, match):
    with pytest.raises(InputError, match=match):
        call()


def test_target_copies_and_freezes():
    tpl = PLATE.copy()
    kp = PLATE[:2].copy()
    t = Target("plate", "custom", tpl, lidar_keypoints=kp, camera_keypoints=None,
               dims={"rows": 3, "side_m": 0.5}, planar=True)
    tpl[0, 0] = 9.0
    kp[0, 0] = 9.0
    assert t.template[0, 0] == 0.0 and t.lidar_keypoints[0, 0] == 0.0
    assert t.kind is TargetKind.CUSTOM
    assert dict(t.dims) == {"rows": 3, "side_m": 0.5} and isinstance(t.dims["rows"], int)
    with pytest.raises(ValueError):
        t.template[0, 0] = 1.0
    with pytest.raises(TypeError):
        t.dims["rows"] = 4  # type: ignore[index]
    with pytest.raises(AttributeError):
        t.name = "x"  # type: ignore[misc]
    # lidar matched to keypoints, camera (no keypoints) to the template
    assert t.lidar_points is t.lidar_keypoints
    assert t.camera_points is t.template
    t2 = t.with_params(use_lidar_keypoints=False)
    assert t2.lidar_points is t2.template and t.use_lidar_keypoints
    t3 = t.with_template(PLATE * 2)
    np.testing.assert_array_equal(t3.template, PLATE * 2)
    np.testing.assert_array_equal(t.template, PLATE)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"template": np.zeros((0, 3))}, r"target 'b': template: expected a non-empty \(N, 3\) "
                                          r"array, got shape \(0, 3\)"),
        ({"template": np.zeros((4, 2))}, r"template: expected a non-empty \(N, 3\)"),
        ({"template": [[0, 0, np.nan]]}, r"template: points must be finite"),
        ({"template": None}, r"template: expected an \(N, 3\) array of points, got None"),
        ({"lidar_keypoints": [[0, 0]]}, r"lidar_keypoints: expected a non-empty \(N, 3\)"),
        ({"camera_keypoints": "abc"}, r"camera_keypoints: expected an \(N, 3\) array of numbers"),
        ({"kind": "sphere"}, r"target 'b': unknown target kind 'sphere'"),
        ({"dims": {"radius_m": np.nan}}, r"dims\['radius_m'\] must be a finite number"),
        ({"dims": {"closed": True}}, r"dims\['closed'\] must be a finite number"),
        ({"use_lidar_keypoints": True, "lidar_keypoints": None},
         r"use_lidar_keypoints is set but there are no lidar keypoints"),
        ({"crop_box": (0, 1)}, r"crop_box must be a CropBox or None"),
        ({"crop_image_px": (20, -1)}, r"crop_image_px must be two numbers >= 0"),
    ],
)
def test_target_validation(kwargs, match):
    base = dict(name="b", kind="custom", template=PLATE, lidar_keypoints=PLATE[:1],
                camera_keypoints=None)
    base.update(kwargs)
    with pytest.raises(InputError, match=match):
        Target(**base)


def test_target_needs_a_name():
    with pytest.raises(InputError, match="target: name must be a non-empty string"):
        Target(" ", "custom", PLATE, use_lidar_keypoints=False)


def test_crop_image_px_is_a_tuple():
    t = Target("b", "cylinder", PLATE, use_lidar_keypoints=False, crop_image_px=[20, 30])
    assert t.crop_image_px == (20.0, 30.0)
