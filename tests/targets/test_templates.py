"""Analytic targets: one contract every analytic target passes (template on the ideal surface,
keypoints consistent with the template, crop box holding both), plus each shape's geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rigcal.dataset import BoardGeometry
from rigcal.errors import InputError
from rigcal.geometry import from_rt, so3_exp, transform_points
from rigcal.targets.circle_board import board_centres
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.templates import (
    analytic_target,
    checkerboard_inner_corners,
    circle_board_target,
    cylinder_target,
    diamond_corners,
    diamond_target,
)
from rigcal.targets.surface import surface_distance_m

FACTORIES = {
    "diamond_sim": (lambda: diamond_target(), 0.005),
    "diamond_big": (lambda: diamond_target(1.0, 0.05, rows=7, cols=9, resolution_m=0.01), 0.01),
    "cylinder": (lambda: cylinder_target(0.0564, 0.4953), 0.005),
    "cylinder_open": (lambda: cylinder_target(0.1, 0.3, caps=False, resolution_m=0.01), 0.01),
    "circle_board": (lambda: circle_board_target(), 0.01),
    "circle_board_centred": (lambda: circle_board_target(
        BoardGeometry(width_m=0.8, height_m=0.8), holes_above_plate_centre_m=0.0), 0.01),
}


@pytest.fixture(params=sorted(FACTORIES))
def analytic(request):
    make, res = FACTORIES[request.param]
    return make(), res


# -- the contract every analytic target passes -------------------------------------------------


def test_contract_template_lies_on_the_ideal_surface(analytic):
    target, _ = analytic
    assert isinstance(target, Target) and target.kind is not TargetKind.CUSTOM
    assert surface_distance_m(target, target.template).max() < 1e-12


def test_contract_template_is_dense(analytic):
    """Every point of the surface has a template point within the sampling step (checked on
    random points projected to the surface: template points themselves, jittered in-plane)."""
    target, res = analytic
    tree = cKDTree(target.template)
    nn, _ = tree.query(target.template, k=2)
    assert nn[:, 1].max() <= res * 1.01  # no isolated points
    assert len(target.template) > 1000


def test_contract_keypoints_are_consistent_with_the_template(analytic):
    target, res = analytic
    tree = cKDTree(target.template)
    for kp in (target.lidar_keypoints, target.camera_keypoints):
        if kp is None:
            continue
        d, _ = tree.query(kp)
        if target.kind is TargetKind.CIRCLE_BOARD:
            # hole centres: in the plate's plane, a hole radius away from the nearest plate point
            assert np.abs(kp[:, 2]).max() == 0.0
            r = target.dims["hole_diameter_m"] / 2
            np.testing.assert_allclose(d, r, atol=res)
        else:  # on the plate: a template point within half a grid diagonal
            assert surface_distance_m(target, kp).max() < 1e-12
            assert d.max() <= res * math.sqrt(2) / 2 + 1e-12


def test_contract_crop_box_holds_template_and_keypoints(analytic):
    target, _ = analytic
    assert target.crop_box is not None
    assert target.crop_box.contains(target.template).all()
    for kp in (target.lidar_keypoints, target.camera_keypoints):
        if kp is not None:
            assert target.crop_box.contains(kp).all()


def test_contract_analytic_target_rebuilds_from_dims(analytic):
    target, res = analytic
    again = analytic_target(target.kind, target.dims, name=target.name, resolution_m=res)
    if target.lidar_keypoints is not None:
        np.testing.assert_allclose(again.lidar_keypoints, target.lidar_keypoints, atol=1e-15)
    if target.camera_keypoints is not None:
        np.testing.assert_allclose(again.camera_keypoints, target.camera_keypoints, atol=1e-15)
    assert dict(again.dims) == dict(target.dims)


def test_contract_surface_distance_is_a_distance(analytic):
    """Points moved off the surface along the local normal are that far away."""
    target, _ = analytic
    rng = np.random.default_rng(5)
    pts = target.template[rng.choice(len(target.template), 200, replace=False)]
    if target.planar:
        # stay away from the outline so that the plane normal is the closest direction
        inner = surface_distance_m(target, pts + [0.02, 0, 0]) + surface_distance_m(
            target, pts - [0.02, 0, 0]) + surface_distance_m(target, pts + [0, 0.02, 0]) + \
            surface_distance_m(target, pts - [0, 0.02, 0])
        pts = pts[inner < 1e-12]
        off = pts + [0.0, 0.0, 0.003]
    else:
        r = np.hypot(pts[:, 0], pts[:, 1])
        R, H = target.dims["radius_m"], target.dims["height_m"]
        lateral = (np.abs(r - R) < 1e-9) & (pts[:, 2] < -0.01) & (pts[:, 2] > -H + 0.01)
        pts = pts[lateral]
        off = pts.copy()
        off[:, :2] *= (R + 0.003) / R
    assert len(pts) > 10
    np.testing.assert_allclose(surface_distance_m(target, off), 0.003, atol=1e-12)


# -- checkerboard diamond ----------------------------------------------------------------------


def test_diamond_geometry_matches_the_simulated_target():
    t = diamond_target()  # 0.5 m, 6 x 7 inner corners of 29 mm
    assert t.kind is TargetKind.CHECKERBOARD_DIAMOND and t.planar and t.use_lidar_keypoints
    assert dict(t.dims) == {"side_m": 0.5, "square_m": 0.029, "rows": 6, "cols": 7}
    c = t.lidar_keypoints
    # the 4 corners form a square of the documented side: equal sides, equal diagonals
    sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
    np.testing.assert_allclose(sides, 0.5, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c[0] - c[2]), 0.5 * math.sqrt(2), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c[1] - c[3]), 0.5 * math.sqrt(2), atol=1e-12)
    # the diamond is centred on the checkerboard; corners -y, +x, +y, -x
    np.testing.assert_allclose(c.mean(axis=0), [0.116, 0.1015, 0.0], atol=1e-12)
    np.testing.assert_allclose(c[0], [0.116, 0.1015 - 0.5 / math.sqrt(2), 0], atol=1e-12)
    np.testing.assert_allclose(c[1], [0.116 + 0.5 / math.sqrt(2), 0.1015, 0], atol=1e-12)
    # inner corners: rows * cols, row by row, column fastest
    k = t.camera_keypoints
    assert k.shape == (42, 3)
    np.testing.assert_allclose(k[:3], [[0.029, 0.029, 0], [0.058, 0.029, 0], [0.087, 0.029, 0]])
    np.testing.assert_allclose(k[7], [0.029, 0.058, 0])
    np.testing.assert_allclose(k[-1], [0.203, 0.174, 0])


def test_checkerboard_and_diamond_helpers():
    np.testing.assert_allclose(checkerboard_inner_corners(1, 2, 0.1), [[0.1, 0.1, 0],
                                                                       [0.2, 0.1, 0]])
    np.testing.assert_allclose(diamond_corners(math.sqrt(2), (1, 1)),
                               [[1, 0, 0], [2, 1, 0], [1, 2, 0], [0, 1, 0]], atol=1e-15)


def test_diamond_errors():
    with pytest.raises(InputError, match=r"a 8 x 7-square checkerboard of 0\.05 m squares does "
                                         r"not fit on a diamond of side 0\.5 m"):
        diamond_target(0.5, 0.05)
    with pytest.raises(InputError, match=r"checkerboard rows must be a whole number >= 1"):
        diamond_target(rows=0)
    with pytest.raises(InputError, match=r"checkerboard cols must be a whole number >= 1"):
        diamond_target(cols=2.5)
    with pytest.raises(InputError, match=r"diamond side_m must be a finite number > 0"):
        diamond_target(side_m=-1)
    with pytest.raises(InputError, match=r"resolution_m must be a finite number > 0"):
        diamond_target(resolution_m=0)


# -- cylinder ----------------------------------------------------------------------------------


def test_cylinder_geometry():
    t = cylinder_target(0.06, 0.5, resolution_m=0.004)
    assert t.kind is TargetKind.CYLINDER and not t.planar
    assert t.lidar_keypoints is None and t.camera_keypoints is None
    assert t.lidar_points is t.template and t.camera_points is t.template
    p = t.template
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.max() == pytest.approx(0.06)
    assert p[:, 2].min() == pytest.approx(-0.5) and p[:, 2].max() == pytest.approx(0.0)
    lateral = np.isclose(r, 0.06)
    assert lateral.sum() > 0.5 * len(p)
    caps = ~lateral
    assert np.all(np.isclose(p[caps, 2], 0.0) | np.isclose(p[caps, 2], -0.5))
    open_ = cylinder_target(0.06, 0.5, resolution_m=0.004, caps=False)
    np.testing.assert_allclose(np.hypot(open_.template[:, 0], open_.template[:, 1]), 0.06)
    # distances: the axis point at mid-height is min(R, H / 2) from the closed surface
    assert surface_distance_m(t, [[0, 0, -0.25]])[0] == pytest.approx(0.06)
    assert surface_distance_m(t, [[0, 0, -0.01]])[0] == pytest.approx(0.01)
    assert surface_distance_m(t, [[0.06, 0, 0.02]])[0] == pytest.approx(0.02)


# -- circle board ------------------------------------------------------------------------------


def test_circle_board_geometry():
    board = BoardGeometry()
    t = circle_board_target(board)
    assert t.kind is TargetKind.CIRCLE_BOARD and t.planar
    np.testing.assert_array_equal(t.lidar_keypoints, board_centres(board))
    np.testing.assert_array_equal(t.camera_keypoints, board_centres(board))
    p = t.template
    # plate 1.0 x 1.5 m, holes 0.3 m below its centre: y from -0.45 to 1.05
    np.testing.assert_allclose([p[:, 0].min(), p[:, 0].max()], [-0.5, 0.5])
    np.testing.assert_allclose([p[:, 1].min(), p[:, 1].max()], [-0.45, 1.05])
    assert np.all(p[:, 2] == 0.0)
    d = np.linalg.norm(p[:, None, :2] - board_centres(board)[None, :, :2], axis=2)
    assert d.min() >= board.hole_diameter_m / 2 - 1e-12  # nothing inside the holes
    assert surface_distance_m(t, [[0.12, 0.12, 0]])[0] == pytest.approx(0.075)
    assert surface_distance_m(t, [[0.0, 0.0, 0.01]])[0] == pytest.approx(0.01)
    assert surface_distance_m(t, [[0.6, 0.0, 0.0]])[0] == pytest.approx(0.1)
    assert t.dims["reflector_offset_m"] == 0.105


def test_circle_board_holes_must_be_on_the_plate():
    with pytest.raises(InputError, match=r"holes_above_plate_centre_m = 0\.7 puts the holes"):
        circle_board_target(holes_above_plate_centre_m=0.7)


# -- dispatch ----------------------------------------------------------------------------------


def test_analytic_target_errors():
    with pytest.raises(InputError, match=r"analytic cylinder target needs dims radius_m, "
                                         r"height_m; missing height_m"):
        analytic_target("cylinder", {"radius_m": 0.1})
    with pytest.raises(InputError, match=r"a custom target has no analytic template"):
        analytic_target("custom", {})
    custom = Target("c", "custom", [[0, 0, 0]], use_lidar_keypoints=False)
    with pytest.raises(InputError, match=r"target 'c': a custom target has no analytic surface"):
        surface_distance_m(custom, [[0, 0, 0]])
    partial = Target("d", "checkerboard_diamond", [[0, 0, 0]], use_lidar_keypoints=False,
                     dims={"side_m": 0.5})
    with pytest.raises(InputError, match=r"target 'd': surface distance needs dims square_m, "
                                         r"rows, cols"):
        surface_distance_m(partial, [[0, 0, 0]])
    board = analytic_target("circle_board", {"spacing_m": 0.3})
    assert board.dims["spacing_m"] == 0.3 and board.dims["hole_diameter_m"] == 0.15


def test_keypoints_move_with_the_target_frame():
    """What a mocap pose does: T_M_T maps template and keypoints alike (distances preserved)."""
    t = diamond_target()
    T = from_rt(so3_exp([0.3, -0.2, 1.0]), [1.0, 2.0, 0.5])
    kp_m = transform_points(T, t.lidar_keypoints)
    tpl_m = transform_points(T, t.template)
    d0, _ = cKDTree(t.template).query(t.lidar_keypoints)
    d1, _ = cKDTree(tpl_m).query(kp_m)
    np.testing.assert_allclose(d0, d1, atol=1e-12)
