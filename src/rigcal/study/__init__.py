"""Studies that reproduce a paper's experiments on simulated raw data and print its tables.

* :mod:`~rigcal.study.mocap_study` - Charron et al.'s simulated motion-capture calibration
  (Tables I-III): diamond and cylinder targets, VLP-16 lidar and pinhole camera.
* :mod:`~rigcal.study.coverage` - how often the motion-capture calibration's reported 95 %
  region holds the truth (:func:`~rigcal.study.coverage.mocap_coverage`).
"""

from rigcal.study.mocap_study import (
    PAPER_TABLES,
    StudyRow,
    StudyTable,
    TrialResult,
    run_mocap_study,
)

__all__ = ["PAPER_TABLES", "StudyRow", "StudyTable", "TrialResult", "run_mocap_study"]
