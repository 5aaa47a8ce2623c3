"""Built-in demonstrations with simulated ground truth (what ``rigcal demo`` runs).

* :func:`detections_demo` - a Prius-like rig simulated at the detection level, calibrated with
  MCPE, FCPE and PSE;
* :func:`raw_demo` - raw sensor data (lidar scans, stereo images, radar detections) simulated
  into a real ROS bag, detected, calibrated, compared with the truth.

Both return values; printing is the CLI's job.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.compare import PoseError, errors_against_truth
from rigcal.problem.result import CalibrationResult


@dataclass(frozen=True)
class ModeOutcome:
    mode: str
    result: CalibrationResult
    errors: Mapping[str, PoseError]


@dataclass(frozen=True)
class DemoReport:
    description: str
    outcomes: tuple[ModeOutcome, ...]
    out_dir: Path
    detection_stats: Mapping[str, object] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def _calibrate_all(dataset, truth, out: Path, modes=("mcpe", "fcpe", "pse")) -> tuple[ModeOutcome, ...]:
    from rigcal.io.results import write_results
    from rigcal.report.plot import plot_calibration

    outcomes = []
    for mode in modes:
        result = calibrate(dataset, CalibrationOptions(mode=mode, cross_validation_folds=5))
        write_results(result, out / mode)
        plot_calibration(dataset, result, out / mode / "calibration.png")
        outcomes.append(ModeOutcome(mode, result, errors_against_truth(result, truth)))
    return tuple(outcomes)


def detections_demo(out_dir: str | os.PathLike[str], seed: int = 7, boards: int = 29) -> DemoReport:
    """Simulate detections of a Prius-like rig, calibrate with every mode, compare with truth."""
    from rigcal.io.manifest import write_dataset
    from rigcal.sim import make_rig_placements, prius_like_rig, simulate

    rng = np.random.default_rng(seed)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, boards), rng=rng, reference=sensors[0].name)
    out = Path(out_dir)
    write_dataset(sim.dataset, out / "dataset")
    return DemoReport(
        description=(
            f"simulated detections of {len(sensors)} sensors ({', '.join(s.name for s in sensors)}), "
            f"{boards} board placements, seed {seed}"
        ),
        outcomes=_calibrate_all(sim.dataset, sim.truth, out),
        out_dir=out,
    )
