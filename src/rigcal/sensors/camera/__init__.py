"""Camera models behind one interface (:class:`CameraModel`): one module per model.

* :mod:`~rigcal.sensors.camera.pinhole` - ``pinhole`` (fx, fy, cx, cy);
* :mod:`~rigcal.sensors.camera.radtan` - ``radtan``: pinhole + plumb bob (k1, k2, p1, p2, k3),
  OpenCV's default model;
* :mod:`~rigcal.sensors.camera.kannala_brandt` - ``kannala_brandt`` (equidistant fisheye,
  k1..k4, as OpenCV's fisheye model);
* :mod:`~rigcal.sensors.camera.double_sphere` - ``double_sphere`` (xi, alpha; Usenko et al.).

``CAMERA_MODELS`` maps each model's ``name`` to its class; :func:`make_camera` builds one by
name (how files and configurations refer to models).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.sensors.camera.base import CameraModel
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.kannala_brandt import KannalaBrandtCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera

CAMERA_MODELS: Mapping[str, type[CameraModel]] = {
    PinholeCamera.name: PinholeCamera,
    RadtanCamera.name: RadtanCamera,
    KannalaBrandtCamera.name: KannalaBrandtCamera,
    DoubleSphereCamera.name: DoubleSphereCamera,
}


def make_camera(name: str, width: int, height: int, params: np.ndarray) -> CameraModel:
    """A camera model by ``name`` (one of ``CAMERA_MODELS``)."""
    try:
        cls = CAMERA_MODELS[str(name).strip().lower()]
    except KeyError:
        raise InputError(
            f"unknown camera model '{name}' (expected one of: {', '.join(CAMERA_MODELS)})"
        ) from None
    return cls(width, height, params)


__all__ = [
    "CAMERA_MODELS",
    "CameraModel",
    "DoubleSphereCamera",
    "KannalaBrandtCamera",
    "PinholeCamera",
    "RadtanCamera",
    "make_camera",
]
