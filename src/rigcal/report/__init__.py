"""Plots and reports of calibrations (matplotlib is imported only when a plot is drawn)."""

from rigcal.report.plot import plot_calibration

__all__ = ["plot_calibration"]
