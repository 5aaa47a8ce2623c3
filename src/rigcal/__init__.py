"""rigcal: joint extrinsic calibration of lidar, camera and radar rigs.

Transforms are 4x4 numpy arrays named ``T_to_from``: ``T_to_from @ p_from = p_to``.
See ``docs/conventions.md``; the Python API is in ``docs/api.md``::

    import rigcal

    dataset = rigcal.load_dataset("detections/rig.yaml")
    result = rigcal.calibrate(dataset, mode="fcpe")
    result.sensors["camera1"].T_reference_sensor, result.verdict.status

The functions and types below are imported on first use (module ``__getattr__``), so that
``import rigcal`` and ``rigcal --version`` load none of numpy, scipy or OpenCV.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module that defines it (imported when the name is first used)
_EXPORTS = {
    # functions (rigcal.api)
    "load_dataset": "rigcal.api",
    "detect_board": "rigcal.api",
    "calibrate": "rigcal.api",
    "write_results": "rigcal.api",
    "write_urdf": "rigcal.api",
    "check": "rigcal.api",
    "diff": "rigcal.api",
    # values
    "Dataset": "rigcal.dataset",
    "SensorDetections": "rigcal.dataset",
    "SensorKind": "rigcal.dataset",
    "BoardGeometry": "rigcal.dataset",
    "CalibrationOptions": "rigcal.problem.calibrate",
    "CalibrationResult": "rigcal.problem.result",
    "SensorEstimate": "rigcal.problem.result",
    "CheckOptions": "rigcal.problem.check",
    "CheckResult": "rigcal.problem.check",
    "DiffResult": "rigcal.problem.diff",
    # errors
    "RigcalError": "rigcal.errors",
    "InputError": "rigcal.errors",
}

__all__ = ["__version__", *sorted(_EXPORTS)]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ imports them
    from rigcal.api import calibrate, check, detect_board, diff, load_dataset, write_results, write_urdf
    from rigcal.problem.check import CheckOptions, CheckResult
    from rigcal.problem.diff import DiffResult
    from rigcal.dataset import BoardGeometry, Dataset, SensorDetections, SensorKind
    from rigcal.errors import InputError, RigcalError
    from rigcal.problem.calibrate import CalibrationOptions
    from rigcal.problem.result import CalibrationResult, SensorEstimate


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'rigcal' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
