"""TargetSurface: closest points and normals, analytic and from a template cloud."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.surface import TargetSurface, surface_distance_m
from rigcal.targets.templates import circle_board_target, cylinder_target, diamond_target

TARGETS = {
    "diamond": lambda: diamond_target(),
    "cylinder": lambda: cylinder_target(0.0564, 0.4953, resolution_m=0.003),
    "circle_board": lambda: circle_board_target(resolution_m=0.004),
}


def _near(target: Target, rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Points within a few cm of the target's template."""
    base = target.template[rng.integers(0, len(target.template), n)]
    return base + rng.normal(0.0, 0.03, (n, 3))


@pytest.mark.parametrize("which", sorted(TARGETS))
def test_closest_points_are_on_the_surface_and_no_template_point_is_closer(which):
    target = TARGETS[which]()
    surface = TargetSurface.of(target)
    assert surface.analytic
    rng = np.random.default_rng(3)
    p = _near(target, rng)
    q, n = surface.closest(p)
    assert surface.distance(q).max() < 1e-12
    d = np.linalg.norm(p - q, axis=1)
    d_template = np.min(np.linalg.norm(p[:, None, :] - target.template[None, :, :], axis=2), axis=1)
    # the template samples the surface: the true closest point is never farther
    assert np.all(d <= d_template + 1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # the point-to-plane distance at the closest point is the distance itself
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", n, p - q)), d, atol=1e-9)


def test_face_normals_on_the_surface():
    dia = TargetSurface.of(diamond_target())
    centre = np.array([[0.116, 0.1015, 0.0]])
    q, n = dia.closest(centre + [0.0, 0.0, 0.01])
    np.testing.assert_allclose(q, centre, atol=1e-12)
    np.testing.assert_allclose(np.abs(n), [[0, 0, 1]], atol=1e-12)
    cyl = TargetSurface.of(cylinder_target(0.05, 0.5))
    q, n = cyl.closest([[0.0, 0.06, -0.2], [0.0, 0.05, -0.2]])
    np.testing.assert_allclose(q, [[0.0, 0.05, -0.2], [0.0, 0.05, -0.2]], atol=1e-12)
    np.testing.assert_allclose(n, [[0, 1, 0], [0, 1, 0]], atol=1e-12)  # on the surface too


def test_beyond_an_edge_the_normal_points_away_from_the_edge():
    dia = TargetSurface.of(diamond_target(side_m=0.5))
    centre = np.array([0.116, 0.1015, 0.0])
    far = centre + [0.5, 0.0, 0.0]  # beyond the +x corner, in the plane
    q, n = dia.closest(far[None])
    np.testing.assert_allclose(q[0], centre + [0.5 / np.sqrt(2), 0, 0], atol=1e-12)
    np.testing.assert_allclose(n[0], [1, 0, 0], atol=1e-12)


def test_a_point_in_a_hole_goes_to_the_rim():
    target = circle_board_target()
    surface = TargetSurface.of(target)
    hole = target.lidar_keypoints[0]
    q, n = surface.closest((hole + [0.01, 0.0, 0.0])[None])
    r = target.dims["hole_diameter_m"] / 2
    np.testing.assert_allclose(q[0], hole + [r, 0, 0], atol=1e-12)
    np.testing.assert_allclose(n[0], [-1, 0, 0], atol=1e-12)


def test_template_surface_fits_local_planes():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.5, 0.5, (2000, 2))
    plane = np.column_stack([xy, np.zeros(len(xy))])
    surface = TargetSurface.of_template(plane)
    assert not surface.analytic
    q, n = surface.closest([[0.1, 0.2, 0.05], [0.0, 0.0, -0.02]])
    np.testing.assert_allclose(np.abs(n[:, 2]), 1.0, atol=1e-9)
    assert np.all(np.abs(q[:, 2]) < 1e-12)


def test_custom_target_uses_its_template_and_has_no_analytic_distance():
    t = diamond_target()
    custom = Target("blob", TargetKind.CUSTOM, t.template, lidar_keypoints=t.lidar_keypoints)
    assert not TargetSurface.of(custom).analytic
    with pytest.raises(InputError, match="custom"):
        surface_distance_m(custom, [[0, 0, 0]])


def test_surface_is_immutable_and_checks_its_template():
    s = TargetSurface.of(diamond_target())
    with pytest.raises(AttributeError):
        s.template = None
    with pytest.raises(ValueError):
        s.template[0, 0] = 1.0
    with pytest.raises(InputError, match="template"):
        TargetSurface("x", np.zeros((0, 3)))


@pytest.mark.parametrize("which", ["diamond", "circle_board"])
def test_a_plates_boundary_is_the_signed_distance_to_its_outline(which):
    """Positive inside, zero on the outline, negative outside; its gradient is the inward
    normal of the nearest side (checked by central differences); the cylinder has none."""
    target = TARGETS[which]()
    surface = TargetSurface.of(target)
    assert surface.planar
    rng = np.random.default_rng(4)
    xy = _near(target, rng)[:, :2]
    f, g = surface.boundary(xy)
    # inside the plate's template (away from the holes' rims) the distance is positive
    on = surface.boundary(target.template[:, :2])[0]
    assert np.all(on >= -1e-9)
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0)
    h = 1e-7
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        fd = (surface.boundary(xy + e)[0] - surface.boundary(xy - e)[0]) / (2 * h)
        np.testing.assert_allclose(g[:, k], fd, atol=1e-5)
    # a point moved out of the plate by d along the gradient's opposite has distance f - d
    f2, _ = surface.boundary(xy - 0.001 * g)
    np.testing.assert_allclose(f2, f - 0.001, atol=1e-9)
    assert (f < 0).any() and (f > 0).any()
    assert not TargetSurface.of(TARGETS["cylinder"]()).planar
    with pytest.raises(ValueError, match="not a flat plate"):
        TargetSurface.of(TARGETS["cylinder"]()).boundary(xy)
