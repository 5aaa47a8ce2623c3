"""Camera models by the names other tools use for them.

:func:`camera_from_params` builds a model from a model name as written by the original tool,
Kalibr, ROS or OpenCV, an image size and a parameter vector **in rigcal's order** (the model's
``param_names``; readers of formats with another order, e.g. Kalibr's ``ds`` intrinsics
``[xi, alpha, fu, fv, pu, pv]``, reorder before calling it). Names are matched case-insensitively:

==================  ================================================  ============================
model               names                                             params
==================  ================================================  ============================
``pinhole``         pinhole                                           fx fy cx cy
``radtan``          radtan, plumb_bob, pinhole-radtan,                fx fy cx cy k1 k2 p1 p2 [k3]
                    radial-tangential
``kannala_brandt``  kannala_brandt, kannalabrandt, equidistant,       fx fy cx cy k1 k2 k3 k4
                    pinhole-equi
``double_sphere``   double_sphere, doublesphere, ds                   fx fy cx cy xi alpha
==================  ================================================  ============================

(``kannalabrandt`` and ``doublesphere`` are the original tool's ``camera_type`` names in lower
case; its ``RADTAN`` has 8 parameters, so ``radtan`` accepts 8 or 9 with ``k3 = 0`` by default.)
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any, Mapping, NamedTuple

import numpy as np

from rigcal.errors import InputError
from rigcal.sensors.camera.base import CameraModel
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.kannala_brandt import KannalaBrandtCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera


class ModelSpec(NamedTuple):
    """How a model is built from a parameter vector: its class, the accepted vector lengths
    (the shorter ones are padded with zeros) and the parameter names for messages."""

    cls: type[CameraModel]
    sizes: tuple[int, ...]
    names: str


MODELS: Mapping[str, ModelSpec] = MappingProxyType(
    {
        PinholeCamera.name: ModelSpec(PinholeCamera, (4,), "fx fy cx cy"),
        RadtanCamera.name: ModelSpec(RadtanCamera, (8, 9), "fx fy cx cy k1 k2 p1 p2 [k3]"),
        KannalaBrandtCamera.name: ModelSpec(
            KannalaBrandtCamera, (8,), "fx fy cx cy k1 k2 k3 k4"
        ),
        DoubleSphereCamera.name: ModelSpec(DoubleSphereCamera, (6,), "fx fy cx cy xi alpha"),
    }
)
"""rigcal's model name -> how to build it."""

MODEL_ALIASES: Mapping[str, str] = MappingProxyType(
    {
        "pinhole": "pinhole",
        "radtan": "radtan",
        "plumb_bob": "radtan",
        "pinhole-radtan": "radtan",
        "radial-tangential": "radtan",
        "kannala_brandt": "kannala_brandt",
        "kannalabrandt": "kannala_brandt",
        "equidistant": "kannala_brandt",
        "pinhole-equi": "kannala_brandt",
        "double_sphere": "double_sphere",
        "doublesphere": "double_sphere",
        "ds": "double_sphere",
    }
)
"""Accepted model names (lower case) -> rigcal's model name."""


def canonical_model_name(model_name: Any) -> str:
    """rigcal's name of the model called ``model_name`` by some tool (case-insensitive).

    Raises InputError listing the known names for an unknown one.
    """
    key = model_name.strip().lower() if isinstance(model_name, str) else None
    if key not in MODEL_ALIASES:
        raise InputError(
            f"unknown camera model {model_name!r} (known: {', '.join(MODEL_ALIASES)})"
        )
    return MODEL_ALIASES[key]


def camera_from_params(
    model_name: str, width: int, height: int, params: Any
) -> CameraModel:
    """A camera model from its name (any of :data:`MODEL_ALIASES`), image size [px] and
    parameter vector (P,) in rigcal's order.

    Raises InputError for an unknown model, a wrong number of parameters (``"radtan expects 8
    or 9 parameters (fx fy cx cy k1 k2 p1 p2 [k3]), got 7"``), non-numeric or non-finite values
    and whatever the model itself refuses (image size, fx <= 0, alpha outside [0, 1], ...).
    """
    name = canonical_model_name(model_name)
    spec = MODELS[name]
    try:
        raw = np.array(params)
    except (TypeError, ValueError):  # ragged nesting
        raw = np.array(None)
    if raw.dtype.kind not in "iuf":
        raise InputError(f"{name} expects numeric parameters ({spec.names}), got {params!r}")
    p = raw.astype(float)
    if p.ndim != 1 or p.size not in spec.sizes:
        count = p.size if p.ndim == 1 else f"an array of shape {p.shape}"
        sizes = " or ".join(str(n) for n in spec.sizes)
        raise InputError(f"{name} expects {sizes} parameters ({spec.names}), got {count}")
    full = len(spec.cls.param_names)
    if p.size < full:
        p = np.concatenate([p, np.zeros(full - p.size)])
    return spec.cls(width, height, p)


__all__ = ["MODELS", "MODEL_ALIASES", "ModelSpec", "camera_from_params", "canonical_model_name"]
