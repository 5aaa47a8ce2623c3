"""camera_from_params: the names of the original tool, Kalibr, ROS and OpenCV -> models."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.kannala_brandt import KannalaBrandtCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera
from rigcal.sensors.camera.registry import (
    MODEL_ALIASES,
    MODELS,
    camera_from_params,
    canonical_model_name,
)

PINHOLE = [500.0, 510.0, 320.0, 240.0]
RADTAN8 = PINHOLE + [-0.2, 0.05, 0.001, -0.002]
KB = PINHOLE + [0.01, -0.002, 0.0003, -0.00004]
DS = PINHOLE + [-0.2, 0.6]


@pytest.mark.parametrize(
    "name, params, cls",
    [
        ("pinhole", PINHOLE, PinholeCamera),
        ("PINHOLE", PINHOLE, PinholeCamera),
        ("radtan", RADTAN8, RadtanCamera),
        ("RADTAN", RADTAN8, RadtanCamera),  # the original tool's camera_type
        ("plumb_bob", RADTAN8 + [0.01], RadtanCamera),  # ROS CameraInfo
        ("pinhole-radtan", RADTAN8, RadtanCamera),
        ("equidistant", KB, KannalaBrandtCamera),  # Kalibr / ROS
        ("kannala_brandt", KB, KannalaBrandtCamera),
        ("KANNALABRANDT", KB, KannalaBrandtCamera),  # the original tool
        ("pinhole-equi", KB, KannalaBrandtCamera),
        ("double_sphere", DS, DoubleSphereCamera),
        ("ds", DS, DoubleSphereCamera),  # Kalibr
        ("DS", DS, DoubleSphereCamera),
        ("DOUBLESPHERE", DS, DoubleSphereCamera),  # the original tool
        (" Pinhole-Equi ", KB, KannalaBrandtCamera),
    ],
)
def test_known_names(name, params, cls):
    cam = camera_from_params(name, 640, 480, params)
    assert type(cam) is cls and cam.size_wh == (640, 480)
    np.testing.assert_array_equal(cam.params[: len(params)], params)


def test_radtan_k3_defaults_to_zero():
    cam = camera_from_params("radtan", 640, 480, RADTAN8)
    assert cam.param("k3") == 0.0 and cam.num_params == 9
    cam9 = camera_from_params("radtan", 640, 480, np.array(RADTAN8 + [0.02]))
    assert cam9.param("k3") == 0.02


def test_every_model_is_reachable_by_its_own_name():
    assert set(MODEL_ALIASES.values()) == set(MODELS)
    for name, spec in MODELS.items():
        assert spec.cls.name == name and MODEL_ALIASES[name] == name
        assert max(spec.sizes) == len(spec.cls.param_names)
    assert canonical_model_name("Plumb_Bob") == "radtan"


def test_inputs_are_not_mutated():
    params = np.array(KB)
    cam = camera_from_params("equidistant", 640, 480, params)
    params[0] = 1.0
    assert cam.param("fx") == 500.0


def test_unknown_model_lists_the_known_ones():
    with pytest.raises(InputError, match=r"unknown camera model 'omni' \(known: pinhole, radtan, ") as info:
        camera_from_params("omni", 640, 480, PINHOLE)
    for alias in MODEL_ALIASES:
        assert alias in str(info.value)
    with pytest.raises(InputError, match="unknown camera model None"):
        camera_from_params(None, 640, 480, PINHOLE)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "name, count, message",
    [
        ("radtan", 7, r"radtan expects 8 or 9 parameters \(fx fy cx cy k1 k2 p1 p2 \[k3\]\), got 7"),
        ("plumb_bob", 10, r"radtan expects 8 or 9 parameters .*, got 10"),
        ("pinhole", 5, r"pinhole expects 4 parameters \(fx fy cx cy\), got 5"),
        ("equidistant", 9, r"kannala_brandt expects 8 parameters \(fx fy cx cy k1 k2 k3 k4\), got 9"),
        ("ds", 4, r"double_sphere expects 6 parameters \(fx fy cx cy xi alpha\), got 4"),
    ],
)
def test_wrong_number_of_parameters(name, count, message):
    with pytest.raises(InputError, match=message):
        camera_from_params(name, 640, 480, np.ones(count))


def test_non_numeric_or_badly_shaped_parameters():
    with pytest.raises(InputError, match=r"pinhole expects numeric parameters \(fx fy cx cy\), got \['a'"):
        camera_from_params("pinhole", 640, 480, ["a", 1, 2, 3])
    with pytest.raises(InputError, match="pinhole expects numeric parameters"):
        camera_from_params("pinhole", 640, 480, [1.0, None, 2.0, 3.0])
    with pytest.raises(InputError, match="pinhole expects numeric parameters"):
        camera_from_params("pinhole", 640, 480, [True, True, True, True])
    with pytest.raises(InputError, match=r"expects 4 parameters .*got an array of shape \(2, 2\)"):
        camera_from_params("pinhole", 640, 480, [[1.0, 2.0], [3.0, 4.0]])


def test_model_checks_still_apply():
    with pytest.raises(InputError, match="alpha must be in"):
        camera_from_params("ds", 640, 480, PINHOLE + [0.0, 1.5])
    with pytest.raises(InputError, match="must be a positive integer"):
        camera_from_params("pinhole", 0, 480, PINHOLE)
    with pytest.raises(InputError, match="must be finite"):
        camera_from_params("pinhole", 640, 480, [np.nan, 1.0, 1.0, 1.0])
