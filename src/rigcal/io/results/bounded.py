"""What a URDF update does with the directions a calibration only bounds.

A 2D radar measures range and azimuth: its height, roll and pitch (along / about its own z, x,
y axes) are only bounded by its elevation field of view, and the estimate is some point of that
bounded set (often a vertex of it). Written into a URDF as if measured, they would replace the
robot's nominal mounting by a guess. ``rigcal urdf`` therefore keeps the URDF's values for those
directions and takes only the measured ones from the calibration.

Every writer does so alike, through the frame plan (rule 5 of :mod:`rigcal.io.results.frames`):
``rigcal urdf``, ``rigcal export --urdf``, and the files ``rigcal calibrate --initial robot.urdf``
writes; :func:`bounded_lines` says what was done, one line per sensor.

**The rule** (:func:`keep_nominal`). ``N = T_body_sensor`` is the sensor link's pose in the URDF
now (forward kinematics from the body link), ``C`` the calibrated pose in the same frame. In
``N``'s own frame the calibrated pose is ``D = N^-1 C``; write ``D`` as translation ``(dx, dy,
dz)`` and rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (the URDF's rpy convention). The bounded
directions of ``D`` are set to zero - ``dz`` for z, ``roll`` and ``pitch`` for the tilt - and
``N @ D'`` is written. With all three bounded the sensor keeps the URDF's plane (its z axis and
its height along it exactly) and takes from the calibration its position in that plane (the
calibrated origin projected onto it) and its heading in it (the calibrated x axis projected
onto it). The in-plane pose is the one calibrated at the estimated tilt; when the nominal tilt
differs much from it, calibrate again with the nominal mounting as a prior (``--initial``,
``--prior``) to get the in-plane pose that goes with the nominal tilt.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy, rpy_from_matrix

#: the directions a bounded calibration can leave to the URDF (about / along the sensor's axes)
KEEPABLE = ("roll", "pitch", "z")


def keep_nominal(T_nominal: np.ndarray, T_calibrated: np.ndarray, directions) -> np.ndarray:
    """``T_body_sensor`` with the ``directions`` (of roll, pitch, z) of ``T_nominal`` and the
    others of ``T_calibrated`` (module docstring); a new (4, 4) array."""
    unknown = set(directions) - set(KEEPABLE)
    if unknown:
        raise InputError(f"cannot keep {sorted(unknown)} from the URDF (only {', '.join(KEEPABLE)})")
    N = np.asarray(T_nominal, dtype=float)
    D = invert(N) @ np.asarray(T_calibrated, dtype=float)
    roll, pitch, yaw = rpy_from_matrix(D[:3, :3])
    t = D[:3, 3].copy()
    if "roll" in directions:
        roll = 0.0
    if "pitch" in directions:
        pitch = 0.0
    if "z" in directions:
        t[2] = 0.0
    return N @ from_rt(matrix_from_rpy(np.array([roll, pitch, yaw])), t)


def bounded_text(values: Mapping[str, tuple[float, float, float]]) -> str:
    from rigcal.problem.uncertainty import format_bounded

    return ", ".join(format_bounded(k, *v) for k, v in values.items())


def bounded_lines(cal, plan, urdf_source: str | None, write_bounded: bool = False) -> list[str]:
    """One line per sensor of ``cal`` (a :class:`~rigcal.io.results.calibration_files.CalibrationTransforms`)
    with bounded directions: kept from the URDF ``urdf_source`` in the frame ``plan``
    (:func:`rigcal.io.results.frames.plan_frames`), or written from the estimate and why."""
    lines = []
    for frame, dirs in (getattr(cal, "bounded", None) or {}).items():
        if frame not in cal.transforms or not dirs:
            continue
        what = ", ".join(dirs)
        values = (getattr(cal, "bounded_values", None) or {}).get(frame, {})
        detail = bounded_text({k: v for k, v in values.items() if k in dirs})
        detail = f": {detail}" if detail else ""
        if frame in plan.kept:
            source = urdf_source or plan.urdf or "the URDF"
            lines.append(f"{frame}: {what} kept from {source}, the rest calibrated (--write-bounded writes "
                         f"the estimate); the calibration only bounds them{detail}")
        elif write_bounded:
            lines.append(f"{frame}: {what} written from the estimate (--write-bounded), although the "
                         f"calibration only bounds them{detail}")
        else:
            where = f"{urdf_source} has no link '{frame}'" if urdf_source else "no URDF"
            lines.append(f"{frame}: {what} written from the estimate ({where} to keep them from), "
                         f"although the calibration only bounds them{detail}")
    return lines


__all__ = ["KEEPABLE", "bounded_lines", "bounded_text", "keep_nominal"]
