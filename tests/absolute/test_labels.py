"""Labels files, the robust 3D circle fit, wheel centres and the ground plane of a scan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rigcal.absolute.labels import (
    WHEEL_NAMES,
    LabelSet,
    fit_circle_3d,
    fit_ground_plane,
    format_labels_csv,
    format_labels_yaml,
    parse_labels_csv,
    parse_labels_yaml,
    wheel_centre,
    wheel_centres,
)
from rigcal.errors import ConfigError, GeometryError, InputError
from rigcal.geometry.so3 import matrix_from_rpy
from rigcal.sim.vehicle import (
    SURFACE_GROUND,
    SimVehicle,
    simulate_external_scan,
    simulate_hub_labels,
    simulate_markers,
    simulate_rim_labels,
)

YAML = """\
rear_left: [[0.1, 3.4, -1.2], [0.3, 3.4, -1.0], [0.5, 3.4, -1.2]]
rear_right: [2.9, 1.1, -1.17]
front_left: [[-2.6, 3.4, -1.2], [-2.4, 3.4, -1.0], [-2.2, 3.4, -1.2]]
front_right: [-2.5, 1.1, -1.17]
marker_rear_left: [0.2, 3.8, -1.49]
"""


def _circle(centre, normal_rpy_deg, radius, n, sigma, seed):
    rng = np.random.default_rng(seed)
    R = matrix_from_rpy(np.radians(normal_rpy_deg))
    ang = np.linspace(0, 2 * math.pi, n, endpoint=False) + 0.3
    local = radius * np.column_stack([np.cos(ang), np.sin(ang), np.zeros(n)])
    return np.asarray(centre) + local @ R.T + sigma * rng.standard_normal((n, 3)), R[:, 2]


# ----------------------------------------------------------------------------- files


def test_yaml_labels_single_points_and_rims():
    labels = parse_labels_yaml(YAML, "labels.yaml", required=WHEEL_NAMES)
    assert labels.wheels == WHEEL_NAMES
    assert labels.points["rear_left"].shape == (3, 3)
    assert labels.points["rear_right"].shape == (1, 3)
    np.testing.assert_allclose(labels.markers["marker_rear_left"], [0.2, 3.8, -1.49])
    with pytest.raises(ValueError):
        labels.points["rear_left"][0, 0] = 1.0  # read-only


@pytest.mark.parametrize("fmt, parse", [(format_labels_yaml, parse_labels_yaml), (format_labels_csv, parse_labels_csv)])
def test_labels_round_trip(fmt, parse):
    labels = simulate_rim_labels(SimVehicle(), np.eye(4), 4, n_points=5)
    markers = simulate_markers(SimVehicle(), np.eye(4), 4)
    both = LabelSet({**labels.points, **markers.points}, "both")
    back = parse(fmt(both), "round trip", required=WHEEL_NAMES)
    assert set(back.points) == set(both.points)
    for k, v in both.points.items():
        np.testing.assert_array_equal(back.points[k], v)


def test_csv_header_comments_and_repeated_labels():
    text = "# rim clicks\nlabel,x,y,z\nrear_left,1,2,3\n\nrear_left, 1.5 ,2,3\nmarker_a,0,0,0\n"
    labels = parse_labels_csv(text, "l.csv")
    assert labels.points["rear_left"].shape == (2, 3)
    assert list(labels.markers) == ["marker_a"]


def test_missing_wheel_is_named_with_what_is_present():
    text = "rear_left: [1, 2, 3]\nrear_right: [1, 2, 3]\nfront_left: [1, 2, 3]\n"
    with pytest.raises(InputError, match=r"l\.yaml: missing wheel 'front_right'; present: front_left, rear_left, rear_right"):
        parse_labels_yaml(text, "l.yaml", required=WHEEL_NAMES)
    with pytest.raises(InputError, match=r"l\.csv: missing wheel 'rear_right' \(and front_left, front_right\); present: rear_left"):
        parse_labels_csv("rear_left,1,2,3\n", "l.csv", required=WHEEL_NAMES)
    with pytest.raises(InputError, match=r"missing wheel 'front_right'"):
        wheel_centres(parse_labels_yaml(text, "l.yaml"))


@pytest.mark.parametrize(
    "text, match",
    [
        ("rear_lft: [1, 2, 3]", r"l\.yaml: unknown label 'rear_lft': expected one of rear_left"),
        ("rear_left: [[1, 2], [1, 2, 3]]", r"label 'rear_left', point 1: expected a point \[x, y, z\], got 2 values"),
        ("rear_left: [1, x, 3]", r"label 'rear_left': y must be a finite number, got 'x'"),
        ("rear_left: [1, .nan, 3]", r"label 'rear_left': y must be a finite number"),
        ("- [1, 2, 3]", r"expected a mapping of label name to points, got a list"),
        ("rear_left: [1, 2, 3]\nrear_left: [1, 2, 3]", r"duplicate key 'rear_left'"),
    ],
)
def test_yaml_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_labels_yaml(text, "l.yaml")


@pytest.mark.parametrize(
    "text, match",
    [
        ("rear_left,1,2\n", r"l\.csv: line 1: expected 4 columns \(label, x, y, z\), got 3"),
        ("rear_left,1,2,3,4\n", r"line 1: expected 4 columns .* got 5"),
        ("label,x,y,z\nrear_left,1,abc,3\n", r"line 2: column y of label 'rear_left' is not a number: 'abc'"),
        ("rear_left,1,2,inf\n", r"line 1: column z of label 'rear_left' is inf"),
        ("wheel9,1,2,3\n", r"line 1: unknown label 'wheel9'"),
        ("# nothing\n", r"l\.csv: no label rows"),
    ],
)
def test_csv_errors(text, match):
    with pytest.raises(InputError, match=match):
        parse_labels_csv(text, "l.csv")


# ----------------------------------------------------------------------------- circle fit


def test_circle_fit_exact_on_noise_free_points():
    p, n = _circle([1.0, -2.0, 0.3], (10, -20, 35), 0.2, 8, 0.0, 0)
    c = fit_circle_3d(p)
    np.testing.assert_allclose(c.centre, [1.0, -2.0, 0.3], atol=1e-9)
    assert c.radius_m == pytest.approx(0.2, abs=1e-9)
    assert abs(abs(c.normal @ n) - 1) < 1e-12
    assert c.normal @ c.centre < 0  # toward the sensor at the origin


def test_circle_fit_three_points_is_the_circumcircle():
    p, _ = _circle([0.5, 0.5, 0.5], (0, 0, 0), 0.3, 3, 0.0, 0)
    c = fit_circle_3d(p)
    np.testing.assert_allclose(c.centre, [0.5, 0.5, 0.5], atol=1e-9)
    assert c.rms_m < 1e-9


def test_circle_fit_drops_a_misclick():
    p, _ = _circle([3.0, 1.0, 0.32], (90, 0, 30), 0.2, 10, 0.002, 1)
    p[4] += [0.0, 0.05, 0.03]  # a click on the tyre
    robust = fit_circle_3d(p, rng=0)
    assert not robust.inliers[4] and robust.inliers.sum() == 9
    assert np.linalg.norm(robust.centre - [3.0, 1.0, 0.32]) < 0.002
    naive = fit_circle_3d(p, outlier_tolerance_m=None)
    assert np.linalg.norm(naive.centre - [3.0, 1.0, 0.32]) > 2 * np.linalg.norm(robust.centre - [3.0, 1.0, 0.32])


def test_circle_fit_refuses_degenerate_points():
    with pytest.raises(GeometryError, match="needs at least 3 points, got 2"):
        fit_circle_3d(np.zeros((2, 3)))
    with pytest.raises(GeometryError, match="collinear"):
        fit_circle_3d(np.column_stack([np.linspace(0, 1, 5)] * 3))
    with pytest.raises(InputError, match=r"expected \(N, 3\) points, got shape \(4, 2\)"):
        fit_circle_3d(np.zeros((4, 2)))


# ----------------------------------------------------------------------------- wheel centres


def test_wheel_centre_methods():
    v = SimVehicle()
    hubs = v.hub_centres_body()
    rim = simulate_rim_labels(v, np.eye(4), 0, sigma_m=0.0)
    for w in WHEEL_NAMES:
        c = wheel_centre(w, rim.points[w])
        assert c.method == "circle" and c.n_points == 10
        np.testing.assert_allclose(c.centre, hubs[w], atol=1e-9)
        assert c.radius_m == pytest.approx(v.rim_radius_m, abs=1e-9)
        assert abs(c.normal[1]) == pytest.approx(1.0)
    hub = simulate_hub_labels(v, np.eye(4), 0, sigma_m=0.0)
    c = wheel_centre("rear_left", hub.points["rear_left"])
    assert c.method == "single" and math.isnan(c.radius_m)
    np.testing.assert_allclose(c.centre, hubs["rear_left"])


def test_fewer_than_three_rim_points_names_the_wheel():
    labels = parse_labels_yaml(
        "rear_left: [[0, 0, 0], [0, 0.1, 0]]\nrear_right: [1, 1, 1]\n"
        "front_left: [2, 2, 2]\nfront_right: [3, 3, 3]\n", "l.yaml",
    )
    with pytest.raises(InputError, match=r"wheel 'rear_left': a rim circle needs at least 3 labelled rim points, got 2"):
        wheel_centres(labels)
    with pytest.raises(InputError, match=r"wheel 'front_right': a rim circle needs at least 3 .* got 1"):
        wheel_centre("front_right", labels.points["front_right"], "circle")
    with pytest.raises(ConfigError, match=r"wheel 'rear_left': method must be one of auto, single, circle"):
        wheel_centre("rear_left", labels.points["rear_left"], "hub")


def test_collinear_rim_points_name_the_wheel():
    with pytest.raises(GeometryError, match=r"wheel 'rear_right': .*collinear"):
        wheel_centre("rear_right", np.column_stack([np.linspace(0, 1, 4)] * 3))


# ----------------------------------------------------------------------------- ground plane


@pytest.fixture(scope="module")
def scan():
    return simulate_external_scan(SimVehicle(), rng=1)


def test_ground_plane_of_the_external_scan(scan):
    g = fit_ground_plane(scan.points_external, rng=0)
    true_up = scan.T_external_body[:3, 2]
    assert math.degrees(math.acos(min(1.0, g.normal @ true_up))) < 0.005
    # the body origin is on the ground
    assert abs(g.height(scan.T_external_body[:3, 3][None])[0]) < 0.0005
    assert g.rms_m < 0.003 and g.threshold_m == 0.02
    is_ground = scan.surface == SURFACE_GROUND
    assert g.inliers[is_ground].mean() > 0.99
    np.testing.assert_allclose(g.height(g.project(scan.points_external[:10])), 0, atol=1e-12)


def test_ground_normal_points_up_along_the_hint(scan):
    flipped = scan.points_external * [1, 1, -1]  # a scanner mounted upside down
    g = fit_ground_plane(flipped, up_hint=(0, 0, -1), rng=0)
    assert g.normal[2] < -0.99


def test_scan_without_ground_is_refused():
    no_ground = simulate_external_scan(SimVehicle(), rng=1, ground=False)
    with pytest.raises(GeometryError, match=r"leica: no ground: the best near-horizontal plane .* need 100 points and 30%"):
        fit_ground_plane(no_ground.points_external, rng=0, source="leica")
    with pytest.raises(GeometryError, match=r"leica: no ground: the scan has 5 points"):
        fit_ground_plane(np.zeros((5, 3)), source="leica")
    with pytest.raises(InputError, match=r"leica: expected an \(N, 3\) point cloud"):
        fit_ground_plane(np.zeros((5, 2)), source="leica")
