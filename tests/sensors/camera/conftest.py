"""Shared fixtures for the camera tests: the contract cases of every model and two helpers.

The cases live here rather than in a test module so that every test module in this directory
can use them. Under ``--import-mode=importlib`` a test module cannot import this file or
another test module, so everything is handed out as a fixture:

- ``camera``: one camera model per case in ``CASES``, the contract cases of all models.
  ``test_contract.py`` runs its tests on it.
- ``kb_camera`` and ``ds_camera``: the Kannala-Brandt and double sphere cases only, for the
  model-specific tests in ``test_kannala_brandt.py`` and ``test_double_sphere.py``.
- ``camera_cases``: the list ``CASES`` itself, as (id, factory) pairs.
- ``pixels_in_image`` and ``points_in_view``: the helper functions of the same names.

A new model adds its cases to ``CASES`` (through a list of its own if its module needs them).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pytest

from rigcal.sensors.camera import (
    CameraModel,
    DoubleSphereCamera,
    KannalaBrandtCamera,
    PinholeCamera,
    RadtanCamera,
)

Case = tuple[str, Callable[[], CameraModel]]

PRIUS = dict(width=1936, height=1216, fx=1419.435287, fy=1442.298159, cx=948.748187, cy=621.179140)
PRIUS_DIST = dict(k1=-0.175243, k2=0.158967, p1=0.003024, p2=-0.002257, k3=-0.062404)

# TUM-VI's published equidistant calibration of cam0, cropped to 400 x 400 so that the image
# corners stay in front of the camera (rigcal models image the front half-space only).
TUMVI_K = dict(fx=190.97847715128717, fy=190.9733070521226, cx=199.5, cy=201.3)
TUMVI_D = dict(
    k1=0.0034823894022493434,
    k2=0.0007150348452162257,
    k3=-0.0020532361418706202,
    k4=0.00020293673591811182,
)

PINHOLE_CASES: list[Case] = [
    ("pinhole-prius", lambda: PinholeCamera.from_intrinsics(**PRIUS)),
    (
        "pinhole-vga-anisotropic",
        lambda: PinholeCamera.from_intrinsics(640, 480, 500, 520, 330, 235),
    ),
]

RADTAN_CASES: list[Case] = [
    ("radtan-prius", lambda: RadtanCamera.from_intrinsics(**PRIUS, **PRIUS_DIST)),
    (
        "radtan-strong-barrel",
        lambda: RadtanCamera.from_intrinsics(
            640, 480, 380, 385, 322, 241, k1=-0.32, k2=0.11, p1=0.0012, p2=-0.0007, k3=-0.015
        ),
    ),
    (
        "radtan-pincushion-no-k3",
        lambda: RadtanCamera.from_intrinsics(800, 600, 900, 900, 400, 300, k1=0.08, k2=0.01),
    ),
]

KB_CASES: list[Case] = [
    (
        "kb-wide",
        lambda: KannalaBrandtCamera.from_intrinsics(
            1280, 960, 600, 602, 640.5, 480.2, k1=-0.02, k2=0.01, k3=-0.003, k4=0.0005
        ),
    ),
    ("kb-tumvi-cropped", lambda: KannalaBrandtCamera.from_intrinsics(400, 400, **TUMVI_K, **TUMVI_D)),
    (
        # theta_d folds back at 60 deg; the image stays inside the image circle
        "kb-fold-at-60deg",
        lambda: KannalaBrandtCamera.from_intrinsics(400, 300, 400, 405, 200.5, 149.5, k1=-0.3),
    ),
    ("kb-no-distortion", lambda: KannalaBrandtCamera.from_intrinsics(640, 480, 300, 310, 322, 241)),
]

DS_CASES: list[Case] = [
    (
        # the paper's TUM-VI-like fisheye (xi < 0, alpha > 0.5), cropped to keep the image
        # corners in front of the camera (rigcal models image the front half-space only)
        "ds-fisheye-cropped",
        lambda: DoubleSphereCamera.from_intrinsics(360, 360, 158.28, 158.27, 179.5, 180.9, -0.17, 0.59),
    ),
    (
        "ds-low-alpha-positive-xi",
        lambda: DoubleSphereCamera.from_intrinsics(640, 480, 420, 415, 318, 243, xi=0.3, alpha=0.3),
    ),
    (
        # nearly a pinhole (alpha = xi = 0 is one; see test_zero_xi_and_alpha_is_a_pinhole - the
        # contract's finite differences need room on both sides of every parameter)
        "ds-near-pinhole",
        lambda: DoubleSphereCamera.from_intrinsics(640, 480, 500, 520, 330, 235, xi=0.02, alpha=0.05),
    ),
    (
        # domain bounded by the paper's z > -w2 d1 at 85.4 deg; image circle 252 px
        "ds-negative-xi-bounded",
        lambda: DoubleSphereCamera.from_intrinsics(400, 300, 160, 161, 199.5, 149.7, xi=-0.5, alpha=0.7),
    ),
]

CASES: list[Case] = PINHOLE_CASES + RADTAN_CASES + KB_CASES + DS_CASES


def _ids(cases: list[Case]) -> list[str]:
    return [c[0] for c in cases]


def _factories(cases: list[Case]) -> list[Callable[[], CameraModel]]:
    return [c[1] for c in cases]


@pytest.fixture(params=_factories(CASES), ids=_ids(CASES))
def camera(request) -> CameraModel:
    """Every contract case of every model."""
    return request.param()


@pytest.fixture(params=_factories(KB_CASES), ids=_ids(KB_CASES))
def kb_camera(request) -> KannalaBrandtCamera:
    return request.param()


@pytest.fixture(params=_factories(DS_CASES), ids=_ids(DS_CASES))
def ds_camera(request) -> DoubleSphereCamera:
    return request.param()


@pytest.fixture
def camera_cases() -> list[Case]:
    return list(CASES)


def _pixels_in_image(camera: CameraModel, n: int, seed: int, margin: float = 1.0) -> np.ndarray:
    """``n`` random pixels at least ``margin`` px inside the image."""
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [
            rng.uniform(margin, camera.width - 1 - margin, n),
            rng.uniform(margin, camera.height - 1 - margin, n),
        ]
    )


def _points_in_view(camera: CameraModel, n: int, seed: int) -> np.ndarray:
    """Points in front of the camera that project into the image, at 0.5-30 m."""
    rays = camera.unproject(_pixels_in_image(camera, n, seed))
    depth = np.random.default_rng(seed + 1).uniform(0.5, 30.0, n)
    return rays * depth[:, None]


@pytest.fixture
def pixels_in_image() -> Callable[..., np.ndarray]:
    """The function ``pixels_in_image(camera, n, seed, margin=1.0)``."""
    return _pixels_in_image


@pytest.fixture
def points_in_view() -> Callable[..., np.ndarray]:
    """The function ``points_in_view(camera, n, seed)``."""
    return _points_in_view
