"""rigcal's Python API: what the command line does, as functions that return values.

Exported from the package (``rigcal.load_dataset``, ``rigcal.calibrate``, ...) and imported only
when first used, so that ``import rigcal`` stays light. ``docs/api.md`` shows them at work (a
test runs its examples).

* :func:`load_dataset` - a dataset of board detections: a ``rig.yaml`` manifest (or a folder
  holding one), or a recording in which the board is detected first (``rig=``);
* :func:`detect_board` - the board in a recording: the detections, placements and statistics;
* :func:`calibrate` - a :class:`~rigcal.problem.result.CalibrationResult`: every sensor's
  ``T_reference_sensor`` with its 6x6 covariance and std, the errors between sensors, the
  verdict of the consistency check;
* :func:`write_results` - ``calibration.yaml``, ``<sensor>.yaml``, ``calibration.launch`` and
  (with the dataset) ``report.html``, as ``rigcal calibrate --out`` writes them;
* :func:`write_urdf` - a calibration written into a URDF's sensor joints;
* :func:`check` - new board detections judged under a stored calibration: per sensor
  ``unchanged``, ``moved`` (by how much, p-value) or ``cannot tell``, as ``rigcal check``;
* :func:`diff` - two calibrations of one rig compared per sensor, as ``rigcal diff``.

Errors are :class:`rigcal.errors.RigcalError` subclasses whose message names the file, field
or sensor; a result that contradicts its own noise model is returned, not raised: check
``result.flagged`` / ``result.verdict``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rigcal.errors import InputError

if TYPE_CHECKING:
    from rigcal.dataset import Dataset
    from rigcal.problem.check import CheckOptions, CheckResult
    from rigcal.problem.diff import DiffResult
    from rigcal.detect.pipeline import DetectionRun
    from rigcal.io.results.urdf import WrittenUrdf
    from rigcal.problem.calibrate import CalibrationOptions
    from rigcal.problem.result import CalibrationResult

PathLike = str | os.PathLike[str]
MODES = ("mcpe", "fcpe", "pse")


def detect_board(recording: PathLike, rig: PathLike) -> DetectionRun:
    """Detect the board in ``recording`` (a ROS 1 bag, a ROS 2 bag folder or a folder of files)
    with the detection rig ``rig`` (rig.yaml naming each sensor's topic); the run holds
    ``dataset`` (one detection per sensor and placement), ``placements`` (their time windows)
    and ``stats`` (frames, detections and rejections per sensor). Progress is logged."""
    import logging

    from rigcal.detect.pipeline import run_detection
    from rigcal.io.config.rig_config import load_rig_config
    from rigcal.io.recordings.open_any import open_any

    log = logging.getLogger("rigcal.detect")
    config = load_rig_config(rig)
    with open_any(recording) as rec:
        def progress(done: int, total: int) -> None:
            if total and (done == total or done % max(total // 10, 1) == 0):
                log.info("detecting: %d/%d frames", done, total)

        return run_detection(rec, config, progress=progress)


def load_dataset(path: PathLike, *, rig: PathLike | None = None) -> Dataset:
    """The board detections of a rig: ``path`` is a ``rig.yaml`` manifest (or a folder holding
    one, e.g. what ``rigcal detect`` or ``calibrate --keep-detections`` wrote); with ``rig`` (a
    detection rig.yaml), ``path`` is a recording whose board is detected first (:func:`detect_board`)."""
    if rig is not None:
        return detect_board(path, rig).dataset
    from rigcal.io.dataset.manifest import load_manifest

    return load_manifest(path)


def calibrate(dataset: Dataset, mode: str = "fcpe", reference: str | None = None, *,
              options: CalibrationOptions | None = None, **overrides: Any) -> CalibrationResult:
    """Calibrate every sensor of ``dataset`` into the frame of ``reference`` (default: the
    dataset's reference, else the first lidar) with ``mode`` (``"mcpe"``, ``"fcpe"`` or
    ``"pse"``). ``options``: a full :class:`~rigcal.problem.calibrate.CalibrationOptions`;
    ``overrides``: any of its fields by name (``cross_validation_folds=5``,
    ``detect_outliers=False``, ``hold_radar_plane=True``, ``initial={...}``, ``pse_noise=...``).

    The result holds ``sensors[name].T_reference_sensor`` (4x4), ``.covariance`` (6x6, over
    the right perturbation (rotation [rad], translation [m])), ``.std`` (x, y, z [m] and roll,
    pitch, yaw [deg]), ``rmse_m`` and ``per_board_m`` per sensor pair, ``verdict`` and
    ``flagged``; ``result.T(to, frm)`` is ``T_to_from`` between two sensors."""
    import dataclasses

    from rigcal.problem.calibrate import CalibrationOptions
    from rigcal.problem.calibrate import calibrate as _calibrate

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    base = options if options is not None else CalibrationOptions()
    fields = {f.name for f in dataclasses.fields(CalibrationOptions)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise InputError(f"unknown calibration option(s) {unknown}; the options are {sorted(fields - {'mode', 'reference'})}")
    chosen = dataclasses.replace(base, mode=mode, reference=reference if reference is not None else base.reference,
                                 **overrides)
    return _calibrate(dataset, chosen)


def write_results(result: CalibrationResult, out_dir: PathLike, dataset: Dataset | None = None) -> list[Path]:
    """Write ``result`` into ``out_dir`` as ``rigcal calibrate --out`` does: ``calibration.yaml``,
    one ``<sensor>.yaml`` per sensor, ``calibration.launch`` and, with the ``dataset`` it was
    computed from, ``report.json`` and ``report.html``; each file atomically. Returns the paths."""
    if dataset is None:
        from rigcal.io.results.calibration import write_results as _write

        return list(_write(result, out_dir))
    from rigcal.io.results.report import write_calibration_set

    return list(write_calibration_set(result, dataset, out_dir))


def write_urdf(calibration: CalibrationResult | PathLike, urdf_in: PathLike, urdf_out: PathLike | None = None, *,
               body_link: str | None = None, in_place: bool = False, add_missing: bool = False) -> WrittenUrdf:
    """Write a calibration into the sensor joints of the URDF ``urdf_in``, as ``rigcal urdf``
    does: ``calibration`` is a result or a written ``calibration.yaml`` / ``absolute.yaml``;
    every calibrated frame's link is placed relative to ``body_link`` (default: the
    calibration's parent frame, e.g. the reference sensor's link) by updating the fixed joints
    on the way. The result goes to ``urdf_out``, or with ``in_place`` over the input (a backup
    is kept). A frame the URDF has no link for is skipped (``written.skipped``), or with
    ``add_missing`` added on a fixed joint from ``body_link``."""
    from rigcal.io.results.calibration_files import parse_calibration_transforms, read_calibration_transforms
    from rigcal.io.results.urdf import write_urdf as _write_urdf
    from rigcal.problem.result import CalibrationResult

    if isinstance(calibration, CalibrationResult):
        from rigcal.io.results.calibration import result_to_yaml_text

        cal = parse_calibration_transforms(result_to_yaml_text(calibration), "<calibration result>")
    else:
        cal = read_calibration_transforms(calibration)
    return _write_urdf(urdf_in, urdf_in if in_place else urdf_out, dict(cal.transforms),
                       body_link or cal.parent_frame, in_place=in_place, kinds=cal.kinds,
                       missing="add" if add_missing else "skip")


def _stored(calibration: Any, what: str) -> Any:
    """A calibration as :func:`check` and :func:`diff` take it: a result in memory as it is, a
    path (``calibration.yaml`` or its folder) read."""
    from rigcal.problem.result import CalibrationResult
    from rigcal.problem.stored import StoredCalibration

    if isinstance(calibration, (CalibrationResult, StoredCalibration)):
        return calibration
    if isinstance(calibration, (str, os.PathLike)):
        from rigcal.io.results.stored import read_stored_calibration

        return read_stored_calibration(calibration)
    raise InputError(f"{what}: expected a CalibrationResult or the path of a calibration.yaml, "
                     f"got {type(calibration).__name__}")


def check(calibration: CalibrationResult | PathLike, dataset: Dataset | PathLike, *,
          options: CheckOptions | None = None, **overrides: Any) -> CheckResult:
    """Is the rig still calibrated? ``dataset`` (new board detections, or the path of their
    ``rig.yaml``) judged under ``calibration`` (a result, or a ``calibration.yaml``): each
    sensor re-estimated with the others held and compared with its stored pose under both
    covariances. The result's ``status`` is ``"moved"``, ``"cannot tell"`` or ``"unchanged"``;
    ``result.sensors[name]`` says which and by how much (``.status``, ``.headline`` such as
    ``moved: 12 +- 4 mm, 0.40 +- 0.10 deg (p < 0.001)``, ``.change`` with ``distance_m`` and
    ``rotation_deg``, ``.test.p_value``); ``result.detectable`` is the smallest change these
    boards could detect.
    ``options``: a :class:`~rigcal.problem.check.CheckOptions`; ``overrides``: its fields by
    name (``alpha=0.01``, ``min_boards=4``, ...)."""
    import dataclasses

    from rigcal.problem.check import CheckOptions
    from rigcal.problem.check import check as _check

    base = options if options is not None else CheckOptions()
    fields = {f.name for f in dataclasses.fields(CheckOptions)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise InputError(f"unknown check option(s) {unknown}; the options are {sorted(fields)}")
    if not hasattr(dataset, "sensors"):
        dataset = load_dataset(dataset)  # type: ignore[arg-type]
    return _check(_stored(calibration, "check"), dataset,  # type: ignore[arg-type]
                  dataclasses.replace(base, **overrides))


def diff(old: CalibrationResult | PathLike, new: CalibrationResult | PathLike, *,
         alpha: float = 0.05) -> DiffResult:
    """Two calibrations of one rig compared, as ``rigcal diff``: per sensor the change of its
    pose (translation, rotation angle and axis) and whether it is significant at level
    ``alpha`` given both covariances (``status`` as :func:`check`'s)."""
    from rigcal.problem.diff import diff as _diff

    return _diff(_stored(old, "diff: old"), _stored(new, "diff: new"), alpha=alpha)


__all__ = ["calibrate", "check", "detect_board", "diff", "load_dataset", "write_results", "write_urdf"]
