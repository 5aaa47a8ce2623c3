"""Calibration as data: pose parameter blocks, residual batches bound to them, a solver.

* :mod:`rigcal.problem.residuals` - pure, batched residual functions with analytic Jacobians;
* :mod:`rigcal.problem.solver` - the problem value and a Levenberg-Marquardt solver on SE(3);
* :mod:`rigcal.problem.configurations` - MCPE / FCPE / PSE as choices of blocks;
* :mod:`rigcal.problem.calibrate` - the end-to-end entry point returning a result value;
* :mod:`rigcal.problem.check` / :mod:`rigcal.problem.diff` - is a stored calibration still right
  for new detections, and how two calibrations differ (:mod:`rigcal.problem.stored`,
  :mod:`rigcal.problem.movement`).
"""
