"""Optional parts of rigcal and the pip extra that installs each.

The base install calibrates from detections, reads bags and point clouds, writes every result
file and report.html. What a user can do without is an extra (``pip install "rigcal[NAME]"``,
``rigcal[all]`` for all of them):

=========  ==============================  =================================================
extra      packages                        what needs it
=========  ==============================  =================================================
images     opencv-python-headless          camera images: detection in a recording, the raw
                                           demo, lidar-on-image overlays, mocap camera targets
plots      matplotlib                      PNG plots: ``calibrate --plot``, mocap lidar
                                           overlays, the study's figures
fleet      dask[distributed], bokeh        ``calibrate --batch`` and ``study`` on a Dask
                                           cluster (bokeh: Dask's dashboard)
mcap       foxglove-sdk                    ``export --format mcap`` (a Foxglove scene)
=========  ==============================  =================================================

:func:`require` imports an optional module or raises :class:`MissingExtraError`, one line that
names the extra; the command line turns a :class:`ModuleNotFoundError` of one of these modules
into the same line (:func:`missing_extra_message`), wherever it is raised.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import NamedTuple

from rigcal.errors import RigcalError


class Extra(NamedTuple):
    """An optional module: the pip package that provides it, the extra that installs it."""

    package: str
    extra: str


#: top-level module name -> where it comes from
EXTRAS: dict[str, Extra] = {
    "cv2": Extra("opencv-python-headless", "images"),
    "matplotlib": Extra("matplotlib", "plots"),
    "dask": Extra("dask[distributed]", "fleet"),
    "distributed": Extra("dask[distributed]", "fleet"),
    "bokeh": Extra("bokeh", "fleet"),
    "foxglove": Extra("foxglove-sdk", "mcap"),
}


class MissingExtraError(RigcalError):
    """An optional package is not installed; the message names the extra that installs it."""


def missing_extra_message(module: str, purpose: str | None = None) -> str | None:
    """The one line for a missing optional ``module`` (dotted names are reduced to their top
    level), or None when ``module`` is not an optional one of rigcal's."""
    top = (module or "").split(".")[0]
    extra = EXTRAS.get(top)
    if extra is None:
        return None
    what = f"{purpose} needs" if purpose else "this needs"
    return (f"{what} {extra.package}, which is not installed: "
            f"pip install \"rigcal[{extra.extra}]\" (or \"rigcal[all]\")")


def require(module: str, purpose: str) -> ModuleType:
    """Import the optional ``module`` (a key of :data:`EXTRAS`, or a submodule of one);
    MissingExtraError naming the extra when it is not installed. ``purpose`` starts the message
    (``"detecting the board in camera images"``)."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = exc.name or module
        message = missing_extra_message(missing, purpose) if missing.split(".")[0] == module.split(".")[0] else None
        if message is None:
            raise
        raise MissingExtraError(message) from None


def available(module: str) -> bool:
    """True when the optional ``module`` can be imported."""
    try:
        importlib.import_module(module)
    except ModuleNotFoundError:
        return False
    return True


__all__ = ["EXTRAS", "Extra", "MissingExtraError", "available", "missing_extra_message", "require"]
