"""Undetermined is not a result: is every sensor's pose determined to a useful level?

Each sensor kind has a bound (:data:`DETERMINED_BOUND`, default 50 mm / 1 deg; configurable
per kind): a sensor whose reported std exceeds it in some direction is **undetermined**. The
check names the sensor, its weak directions and the placements that would fix them (from where
its boards are in its own view).

Which directions are judged:

* a lidar, camera or 3D radar: x, y, z along and roll, pitch, yaw about its own axes (the
  reported covariance of its right perturbation - no Euler-angle singularity);
* a 2D radar: its in-plane pose - x, y along its own axes and yaw about its own z. Its z, roll
  and pitch are *bounded* by the elevation field of view by design (reported as intervals, see
  ``bounded``), or *held*: they are never undetermined. What those bounded directions still
  allow the in-plane pose to do (a tilt the field of view permits moves x, y and yaw: the
  reported covariance includes it) counts, so a 2D radar's bound is wider;
* MCPE with a 2D radar as reference: every other sensor's x, y and yaw in the radar's frame,
  with the radar's z, roll and pitch held (the height, roll and pitch relative to the radar,
  and what a tilt of the radar does to the others' positions over their lever arm, are bounded
  by its field of view);
* held directions (``--hold-radar-plane``) are not judged.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.problem.consistency import PASS, UNDETERMINED, Check, Evidence

#: largest std [m, deg] of a determined pose per sensor kind: (translation, rotation)
DETERMINED_BOUND: dict[str, tuple[float, float]] = {
    "lidar": (0.05, 1.0),
    "camera": (0.05, 1.0),
    "radar": (0.10, 2.0),
    "radar3d": (0.05, 1.0),
}
#: tangent index (rotation first) of a 2D radar's in-plane directions in its own frame
_IN_PLANE = {"yaw": 2, "x": 3, "y": 4}


def _judged(kind: SensorKind, std: Mapping[str, float], covariance: np.ndarray, radar_reference: bool,
            held: tuple[str, ...]) -> dict[str, float]:
    """The judged directions' std (m; deg) of one sensor: along and about its own axes (the
    right perturbation's covariance: no Euler-angle singularity), or with a 2D radar as
    reference x, y and yaw of ``T_reference_sensor`` in the radar's frame."""
    if radar_reference:
        return {k.split("_")[0]: float(std[k]) for k in ("x_m", "y_m", "yaw_deg") if k.split("_")[0] not in held}
    d = np.sqrt(np.maximum(np.diag(np.asarray(covariance, dtype=float)), 0.0))
    out = {"x": d[3], "y": d[4], "z": d[5], "roll": math.degrees(d[0]), "pitch": math.degrees(d[1]),
           "yaw": math.degrees(d[2])}
    if kind is SensorKind.RADAR:  # z, roll, pitch: bounded by the field of view, not judged here
        out = {k: out[k] for k in _IN_PLANE}
    return {k: float(v) for k, v in out.items() if k not in held}


def _board_points(dataset: Dataset, name: str) -> np.ndarray:
    s = dataset.sensor(name)
    p = s.points[s.valid]
    if s.kind.is_point_cloud:
        p = p.mean(axis=1)
    if p.shape[-1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    return p


def placement_advice(dataset: Dataset, name: str, weak: list[str]) -> str:
    """What board placements would determine the weak directions of ``name``, from where its
    boards are in its own view."""
    s = dataset.sensor(name)
    p = _board_points(dataset, name)
    n = len(p)
    planar = s.kind is SensorKind.RADAR
    where = "in its field of view" + (" at its height (within its elevation field of view)" if planar else "")
    if n < 4:
        return f"{name} saw only {n} board{'s' if n != 1 else ''}: place more boards {where}, left-right and near-far"
    centred = p - p.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False) / math.sqrt(n)
    if sv[0] < 0.1:
        return (f"all {n} boards {name} saw are at one spot in its view (within {sv[0] * 1000:.0f} mm): move the "
                f"board between placements - left-right and near-far {where}")
    if sv[1] < 0.1:
        rng = np.linalg.norm(p, axis=1)
        along = "one ray from it" if np.ptp(rng) > 2 * sv[1] * math.sqrt(n) else "one line"
        return (f"the {n} boards {name} saw lie on {along} (within {sv[1] * 1000:.0f} mm): spread them "
                f"left-right across {where}")
    rot = any(w.split(" ")[0] in ("roll", "pitch", "yaw") for w in weak)
    return (f"{name}'s {n} boards span {2 * sv[0]:.1f} x {2 * sv[1]:.1f} m in its view: "
            + ("spread them wider (both sides of its view, near and far)" if rot else
               "more boards, spread near-far and left-right") + f" {where}")


def determined_check(
    dataset: Dataset,
    stds: Mapping[str, Mapping[str, float]],
    covariances: Mapping[str, np.ndarray],
    reference: str,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    radar_reference: bool = False,
    held: Mapping[str, tuple[str, ...]] | None = None,
) -> Check:
    """The ``determined`` check over every sensor but the reference: ``stds`` (as
    :func:`rigcal.problem.uncertainty.pose_std`) and ``covariances`` (right perturbation, 6x6)
    per sensor; ``bounds`` per kind (default :data:`DETERMINED_BOUND`)."""
    limits = {**DETERMINED_BOUND, **(bounds or {})}
    held = held or {}
    bad, evidence = [], []
    for s in dataset.sensors:
        if s.name == reference or s.name not in stds:
            continue
        t_max, r_max = limits[s.kind.value]
        judged = _judged(s.kind, stds[s.name], covariances[s.name], radar_reference, tuple(held.get(s.name, ())))
        weak = []
        for d, v in judged.items():
            rotation = d in ("roll", "pitch", "yaw")
            limit = r_max if rotation else t_max
            evidence.append(Evidence(f"{s.name} {d}", v, limit, "std [deg]" if rotation else "std [m]"))
            if not np.isfinite(v) or v > limit:
                weak.append(f"{d} (std {v:.2f} deg)" if rotation else f"{d} (std {v * 1000:.0f} mm)")
        if weak:
            bound = f"{t_max * 1000:g} mm / {r_max:g} deg"
            frame = " in the reference radar's frame" if radar_reference else " (along / about its own axes)"
            bad.append(f"{s.name}: {', '.join(weak)}{frame} not determined to {bound} - "
                       + placement_advice(dataset, s.name, weak))
    if bad:
        return Check("determined", UNDETERMINED, "; ".join(bad) + " (the other sensors' results are determined; "
                     "--force writes them all)", tuple(evidence))
    return Check("determined", PASS, "every sensor's pose determined to its bound", tuple(evidence))


def parse_bound(text: str) -> tuple[str | None, tuple[float, float]]:
    """``[KIND:]MM/DEG`` (e.g. ``radar:100/2``) -> (kind or None for all, (m, deg))."""
    from rigcal.errors import InputError

    kind, _, value = text.rpartition(":")
    kind = kind.strip().lower() or None
    if kind is not None and kind not in DETERMINED_BOUND:
        raise InputError(f"--max-std {text!r}: unknown sensor kind '{kind}' (expected one of: "
                         f"{', '.join(DETERMINED_BOUND)})")
    try:
        mm, deg = (float(v) for v in value.split("/"))
    except ValueError:
        raise InputError(f"--max-std {text!r}: expected [KIND:]MM/DEG, e.g. 50/1 or radar:100/2") from None
    if not (mm > 0 and deg > 0 and math.isfinite(mm) and math.isfinite(deg)):
        raise InputError(f"--max-std {text!r}: both bounds must be positive numbers")
    return kind, (mm / 1000.0, deg)


__all__ = ["DETERMINED_BOUND", "determined_check", "parse_bound", "placement_advice"]
