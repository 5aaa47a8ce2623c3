"""How far apart are two calibrations of the same rig, and is the difference more than their
uncertainty? ``rigcal diff old.yaml new.yaml``.

Per sensor both calibrations give ``T_reference_sensor`` with a covariance; the change
``delta = log(T_old^-1 T_new)`` (right perturbation, rotation first) is tested with a chi-square
test under ``C_old + C_new`` (two calibrations from different boards are independent), over the
directions both measure: a 2D radar's z, roll and pitch are never tested (only its field of view
bounds them). The tests are Bonferroni-corrected over the sensors compared. When the two files
have different reference sensors, the new calibration is expressed in the old one's reference
frame through its relative poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import invert, se3_exp, se3_log
from rigcal.problem.check import CANNOT_TELL, MOVED, STATUS_ORDER, UNCHANGED
from rigcal.problem.movement import (
    MoveTest,
    change_std,
    change_summary,
    format_deg,
    format_mm,
    format_p,
    format_vector,
    move_test_fields,
    move_test,
)
from rigcal.problem.stored import TANGENT, StoredCalibration, untestable_directions

if TYPE_CHECKING:
    from rigcal.problem.result import CalibrationResult


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class SensorDiff:
    """One sensor's difference between two calibrations: ``status`` (``unchanged``, ``moved`` or
    ``cannot tell``), the ``test`` of its change, both poses (``T_reference_sensor`` in the old
    calibration's reference frame) and the directions not tested."""

    name: str
    kind: str
    status: str
    reason: str
    test: MoveTest | None
    T_old: np.ndarray
    T_new: np.ndarray
    untested: tuple[str, ...] = ()

    @property
    def change(self) -> dict[str, Any]:
        """:func:`rigcal.problem.movement.change_summary` of the change in the directions
        compared (a 2D radar's in-plane pose; every direction of the others)."""
        delta = se3_log(invert(self.T_old) @ self.T_new)
        for i, d in enumerate(TANGENT):
            if d in self.untested:
                delta[i] = 0.0
        return change_summary(self.T_old, self.T_old @ se3_exp(delta))

    @property
    def headline(self) -> str:
        c, t = self.change, self.test
        size = f"{format_mm(c['distance_m'])} mm, {c['rotation_deg']:.2f} deg"
        if t is not None and self.status == MOVED:
            sd_t, sd_r = change_std(t.delta, t.covariance)
            size = (f"{format_mm(c['distance_m'])} +- {format_mm(sd_t)} mm, {c['rotation_deg']:.2f} +- "
                    f"{sd_r:.2f} deg")
        if self.status == CANNOT_TELL or t is None:
            return f"cannot tell: {self.reason} ({size})"
        text = f"{self.status}: {size} ({format_p(t.p_value)})"
        if self.untested:
            text += f"; {', '.join(self.untested)} not compared (only bounded)"
        return text

    @property
    def direction(self) -> str:
        c = self.change
        return (f"origin {format_vector(c['translation_m'], 1000.0)} mm (reference frame), "
                f"{c['rotation_deg']:.2f} deg about {format_vector(c['axis_sensor'], decimals=2)} ({self.name}'s axes)")

    def to_dict(self) -> dict[str, Any]:
        c, t = self.change, self.test
        return {
            "status": self.status,
            "headline": self.headline,
            "reason": self.reason,
            "untested": list(self.untested),
            **move_test_fields(t),
            "delta": [float(x) for x in se3_log(invert(self.T_old) @ self.T_new)],
            "translation_m": [float(x) for x in c["translation_m"]],
            "distance_m": float(c["distance_m"]),
            "rotation_deg": float(c["rotation_deg"]),
            "axis_sensor": [float(x) for x in c["axis_sensor"]],
            "T_old": [[float(x) for x in row] for row in self.T_old],
            "T_new": [[float(x) for x in row] for row in self.T_new],
        }


@dataclass(frozen=True, eq=False)
class DiffResult:
    """Per sensor (worst first) the difference of two calibrations; ``only_old`` / ``only_new``:
    sensors in one file only (not compared); ``status`` as :class:`rigcal.problem.check.CheckResult`."""

    reference: str
    sensors: Mapping[str, SensorDiff]
    only_old: tuple[str, ...]
    only_new: tuple[str, ...]
    alpha: float
    old: str = ""
    new: str = ""

    @property
    def status(self) -> str:
        found = {s.status for s in self.sensors.values()}
        return next((s for s in STATUS_ORDER if s in found), UNCHANGED)

    @property
    def moved(self) -> tuple[str, ...]:
        return tuple(n for n, s in self.sensors.items() if s.status == MOVED)

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "reference": self.reference,
            "old": self.old,
            "new": self.new,
            "alpha": float(self.alpha),
            "moved": list(self.moved),
            "only_old": list(self.only_old),
            "only_new": list(self.only_new),
            "sensors": {n: s.to_dict() for n, s in self.sensors.items()},
        }


def _as_stored(calibration: Any, what: str) -> StoredCalibration:
    if isinstance(calibration, StoredCalibration):
        return calibration
    return StoredCalibration.from_result(calibration, what)


def diff(
    old: StoredCalibration | CalibrationResult,
    new: StoredCalibration | CalibrationResult,
    alpha: float = 0.05,
    power: float = 0.8,
) -> DiffResult:
    """The difference of two calibrations of one rig (each a
    :class:`~rigcal.problem.stored.StoredCalibration` or a
    :class:`~rigcal.problem.result.CalibrationResult`); see the module docstring.

    Raises InputError when the two share no sensor besides the reference, or when the new one
    lacks the old one's reference sensor."""
    if not 0.0 < alpha < 0.5:
        raise InputError(f"diff: alpha must be in (0, 0.5), got {alpha!r}")
    a, b = _as_stored(old, "old calibration"), _as_stored(new, "new calibration")
    ref = a.reference
    if ref not in b.sensors:
        raise InputError(f"{b.source}: has no sensor '{ref}', the reference of {a.source}: the two calibrations "
                         "cannot be put in one frame")
    common = [n for n in a.names if n in b.sensors and n != ref]
    if not common:
        raise InputError(f"{a.source} and {b.source} share no sensor besides the reference '{ref}' "
                         f"({', '.join(a.names)} vs {', '.join(b.names)})")
    for n in common:
        if a.sensors[n].kind != b.sensors[n].kind:
            raise InputError(f"sensor '{n}' is a {a.sensors[n].kind.value} in {a.source} but a "
                             f"{b.sensors[n].kind.value} in {b.source}")
    level = alpha / len(common)
    out = {}
    for n in common:
        T_old = a.sensors[n].T_reference_sensor
        T_new = b.T(ref, n)
        C = a.relative_covariance(ref, n) + b.relative_covariance(ref, n)
        fixed = untestable_directions(a.sensors[n].kind)
        idx = [i for i, d in enumerate(TANGENT) if d not in fixed]
        U = np.zeros((6, len(idx)))
        U[idx, np.arange(len(idx))] = 1.0
        delta = U @ (U.T @ se3_log(invert(T_old) @ T_new))  # the directions compared
        if not np.all(np.isfinite(C)):
            out[n] = SensorDiff(n, a.sensors[n].kind.value, CANNOT_TELL, "a covariance is not finite", None,
                                T_old, T_new, fixed)
            continue
        test = move_test(delta, C, U, level, power)
        status = MOVED if test.significant else UNCHANGED
        out[n] = SensorDiff(n, a.sensors[n].kind.value, status, "", test, T_old, T_new, fixed)
    ordered = dict(sorted(out.items(), key=lambda kv: (STATUS_ORDER.index(kv[1].status),
                                                       -(kv[1].test.z if kv[1].test else -math.inf))))
    return DiffResult(ref, ordered, tuple(n for n in a.names if n not in b.sensors),
                      tuple(n for n in b.names if n not in a.sensors), alpha, a.source, b.source)


__all__ = ["DiffResult", "SensorDiff", "diff"]
