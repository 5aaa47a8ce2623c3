"""How often does ``rigcal check`` raise a false alarm, and how often does it find a moved sensor?

A simulated fleet from the rig population of the coverage benchmark
(:mod:`rigcal.study.board_coverage`: random rigs of 2 lidars, 2 cameras and 2 2D radars with
the issue's unequal noise, calibrated with FCPE on 15 boards): each vehicle is calibrated once
(the stored calibration), then checked on new boards twice - as it is (every false alarm is one)
and with one sensor moved (2-30 mm and 0.1-2 deg, a random direction and axis; for half of the
2D radars chosen, only in the directions it does not measure: along its own z axis and about an
axis in its plane, which no check can detect). A fleet with a share of moved vehicles takes the
moved check for those and the clean one for the others.

A move is *detectable* when it is not a 2D radar's unmeasured move; its size in standard
deviations of the stored calibration is the Mahalanobis length of the move (right
perturbation, the tested directions) under the stored covariance of the sensor's pose relative
to its best-known partner (``calibration.yaml``'s ``relative``).

Every random draw comes from ``numpy.random.default_rng([seed, vehicle, ...])``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from rigcal.errors import RigcalError
from rigcal.geometry.se3 import se3_exp

#: what each check on the fleet records, per vehicle and board count
__all__ = ["MOVE_ROTATION_DEG", "MOVE_TRANSLATION_M", "Vehicle", "check_vehicle", "fleet_dataset", "fleet_rates",
           "moved_sensor", "moved_vehicles", "roc", "simulate_vehicle"]

MOVE_TRANSLATION_M = (0.002, 0.030)
MOVE_ROTATION_DEG = (0.1, 2.0)
CALIBRATION_BOARDS = 15


@dataclass(frozen=True, eq=False)
class Vehicle:
    """A simulated vehicle: its sensors (the truth) and the calibration stored for it."""

    index: int
    sensors: tuple
    result: Any  # rigcal.problem.result.CalibrationResult
    calibrate_time_s: float

    @property
    def stored(self):
        """The calibration as ``calibration.yaml`` stores it."""
        from rigcal.problem.stored import StoredCalibration

        return StoredCalibration.from_result(self.result, f"vehicle {self.index}")


def simulate_vehicle(seed: int, index: int, boards: int = CALIBRATION_BOARDS) -> Vehicle:
    """Vehicle ``index`` of the fleet: a coverage-population rig calibrated with FCPE on
    ``boards`` boards (raises RigcalError when the calibration fails)."""
    from rigcal.problem.calibrate import CalibrationOptions, calibrate
    from rigcal.sim.rig import make_rig_placements, random_rig, simulate
    from rigcal.study.board_coverage import NoiseSpec, _with_noise

    rng = np.random.default_rng([seed, index])
    sensors = _with_noise(random_rig(rng, 2, 2, 2), NoiseSpec())
    sim = simulate(sensors, make_rig_placements(rng, sensors, boards), rng=rng)
    t0 = time.perf_counter()
    result = calibrate(sim.dataset, CalibrationOptions(mode="fcpe", cross_validation_folds=0))
    return Vehicle(index, sensors, result, time.perf_counter() - t0)


def _unit(rng: np.random.Generator, n: int = 3) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def moved_sensor(vehicle: Vehicle, rng: np.random.Generator) -> tuple[str, np.ndarray, bool]:
    """(sensor, move, detectable): one sensor of the vehicle picked at random and a move
    ``T_rig_sensor -> T_rig_sensor exp(move)`` (right perturbation (6,), rotation first) of
    2-30 mm and 0.1-2 deg; for half of the 2D radars picked, only along its own z axis and about
    an axis in its x-y plane (not detectable)."""
    from rigcal.dataset import SensorKind

    s = vehicle.sensors[int(rng.integers(len(vehicle.sensors)))]
    t = rng.uniform(*MOVE_TRANSLATION_M)
    a = math.radians(rng.uniform(*MOVE_ROTATION_DEG))
    unmeasured = s.kind == SensorKind.RADAR and rng.random() < 0.5
    if unmeasured:
        axis = np.r_[_unit(rng, 2), 0.0]
        direction = np.array([0.0, 0.0, 1.0 if rng.random() < 0.5 else -1.0])
    else:
        axis, direction = _unit(rng), _unit(rng)
    return s.name, np.r_[a * axis, t * direction], not unmeasured


def _sigma_multiple(stored, name: str, move: np.ndarray, tested: Sequence[int]) -> float:
    """The move's Mahalanobis length under the stored relative covariance to the sensor's
    best-known partner (the largest over partners), over the ``tested`` tangent directions."""
    idx = list(tested)
    best = 0.0
    for o in stored.names:
        if o == name:
            continue
        C = stored.relative_covariance(o, name)[np.ix_(idx, idx)]
        m = move[idx]
        d2 = float(m @ np.linalg.pinv(C, rcond=1e-12, hermitian=True) @ m)
        best = max(best, math.sqrt(max(d2, 0.0)))
    return best


def check_vehicle(vehicle: Vehicle, seed: int, boards: Sequence[int] = (10, 4)) -> list[dict]:
    """The vehicle checked on new boards, clean and with one sensor moved, for every count of
    ``boards``: one record per (boards, clean|moved) with the rig's status, the sensors named
    moved, the Bonferroni-adjusted smallest p-value of the first round, and the compute time."""
    from rigcal.dataset import SensorKind
    from rigcal.problem.check import CheckOptions, check
    from rigcal.sim.rig import make_rig_placements, simulate

    rng = np.random.default_rng([seed, vehicle.index, 1])
    name, move, detectable = moved_sensor(vehicle, rng)
    moved = tuple(s.with_pose(s.T_rig_sensor @ se3_exp(move)) if s.name == name else s for s in vehicle.sensors)
    kind = next(s.kind for s in vehicle.sensors if s.name == name)
    tested = [2, 3, 4] if kind == SensorKind.RADAR else list(range(6))
    stored = vehicle.stored
    sigma = _sigma_multiple(stored, name, move, tested)
    out = []
    for K in boards:
        T_rig_board = make_rig_placements(rng, vehicle.sensors, K)
        for case, sensors in (("clean", vehicle.sensors), ("moved", moved)):
            data = simulate(sensors, T_rig_board, rng=rng)
            row = {"vehicle": vehicle.index, "boards": K, "case": case, "sensor": name if case == "moved" else None,
                   "detectable": detectable if case == "moved" else None,
                   "translation_mm": float(np.linalg.norm(move[3:]) * 1000) if case == "moved" else None,
                   "rotation_deg": float(math.degrees(np.linalg.norm(move[:3]))) if case == "moved" else None,
                   "sigma_stored": sigma if case == "moved" else None}
            try:
                cpu = time.process_time()
                res = check(stored, data.dataset, CheckOptions())
                cpu = time.process_time() - cpu
            except RigcalError as exc:
                out.append({**row, "status": "error", "error": str(exc)})
                continue
            named = [n for n, v in res.sensors.items() if v.status == "moved"]
            first = [v for v in res.sensors.values() if v.status == "moved" and v.step == 1]
            tested_sensors = [v for v in res.sensors.values() if v.test is not None and v.test.dof > 0]
            ps = [v.test.p_value for v in tested_sensors]
            true = res.sensors.get(name) if case == "moved" else None
            out.append({
                **row, "status": res.status, "named": named,
                "first": first[0].name if first else None,
                "alternatives": list(first[0].alternatives) if first else [],
                "cannot_tell": [n for n, v in res.sensors.items() if v.status == "cannot tell"],
                "p_min_adjusted": min(1.0, min(ps) * len(tested_sensors)) if ps else 1.0,
                "true_status": true.status if true is not None else None,
                "true_detectable_mm": (true.test.detectable_translation_m * 1000
                                       if true is not None and true.test is not None else None),
                "compute_s": res.compute_time_s,
                "cpu_s": cpu,
            })
    return out


def moved_vehicles(indices: Sequence[int], moved_fraction: float, seed: int) -> set[int]:
    """The vehicles of a fleet that get one sensor moved: ``moved_fraction`` of ``indices``,
    drawn once from the seed."""
    rng = np.random.default_rng([seed, 99])
    n = int(round(moved_fraction * len(indices)))
    return set(int(i) for i in rng.permutation(sorted(indices))[:n])


def fleet_dataset(vehicle: Vehicle, seed: int, boards: int, moved: bool):
    """(new detections, moved sensor or None): what a fleet check of ``vehicle`` is given - its
    rig as it is, or with :func:`moved_sensor`'s move (the same move :func:`check_vehicle` makes)."""
    from rigcal.sim.rig import make_rig_placements, simulate

    name, move, _ = moved_sensor(vehicle, np.random.default_rng([seed, vehicle.index, 1]))
    sensors = tuple(s.with_pose(s.T_rig_sensor @ se3_exp(move)) if moved and s.name == name else s
                    for s in vehicle.sensors)
    rng = np.random.default_rng([seed, vehicle.index, 2])
    data = simulate(sensors, make_rig_placements(rng, vehicle.sensors, boards), rng=rng).dataset
    return data, (name if moved else None)


def roc(rows: Sequence[dict], boards: int, thresholds: Sequence[float], sigma_min: float = 3.0) -> list[dict]:
    """False-alarm and detection rates when a vehicle is called moved as soon as its smallest
    Bonferroni-adjusted p-value (first round of the search) is below each threshold."""
    rows = [r for r in rows if r["boards"] == boards and r["status"] != "error"]
    clean = [r for r in rows if r["case"] == "clean"]
    big = [r for r in rows if r["case"] == "moved" and r["detectable"] and r["sigma_stored"] > sigma_min]
    return [{"threshold": t,
             "false_alarm": float(np.mean([r["p_min_adjusted"] < t for r in clean])) if clean else math.nan,
             "detection": float(np.mean([r["p_min_adjusted"] < t for r in big])) if big else math.nan}
            for t in thresholds]


def fleet_rates(rows: Sequence[dict], boards: int, moved_fraction: float = 0.1, seed: int = 0,
                sigma_min: float = 3.0) -> dict:
    """The fleet figures for one board count from :func:`check_vehicle`'s records."""
    rows = [r for r in rows if r["boards"] == boards]
    vehicles = sorted({r["vehicle"] for r in rows})
    moved_set = moved_vehicles(vehicles, moved_fraction, seed)
    clean = [r for r in rows if r["case"] == "clean"]
    moved = [r for r in rows if r["case"] == "moved"]
    fleet = [r for r in rows if (r["case"] == "moved") == (r["vehicle"] in moved_set)]
    big = [r for r in moved if r["detectable"] and r["status"] != "error" and r["sigma_stored"] > sigma_min]
    found = [r for r in big if r["status"] == "moved"]
    right = [r for r in found if r["first"] == r["sensor"] and not r["alternatives"]]
    either = [r for r in found if r["first"] == r["sensor"] or r["sensor"] in r["alternatives"]]
    unmeasured = [r for r in moved if r["detectable"] is False and r["status"] != "error"]

    def rate(part, total):
        return len(part) / len(total) if total else math.nan

    return {
        "boards": boards,
        "vehicles": len(vehicles),
        "false_alarm": rate([r for r in clean if r["status"] == "moved"], clean),
        "clean_cannot_tell": rate([r for r in clean if r["status"] == "cannot tell"], clean),
        "clean_errors": sum(r["status"] == "error" for r in clean),
        "detection": rate(found, big),
        "detectable_moves": len(big),
        "named_right": rate(right, found),
        "named_right_or_alternative": rate(either, found),
        "unmeasured_moves": len(unmeasured),
        "unmeasured_flagged": rate([r for r in unmeasured if r["status"] == "moved"], unmeasured),
        "fleet_moved_vehicles": len(moved_set),
        "fleet_false_alarm": rate([r for r in fleet if r["case"] == "clean" and r["status"] == "moved"],
                                  [r for r in fleet if r["case"] == "clean"]),
        "fleet_detection": rate([r for r in fleet if r in big and r["status"] == "moved"],
                                [r for r in fleet if r in big]),
        "detection_by_sigma": {
            label: rate([r for r in part if r["status"] == "moved"], part)
            for label, part in (
                (f"{lo:g}-{hi:g}", [r for r in moved if r["detectable"] and r["status"] != "error"
                                    and lo < r["sigma_stored"] <= hi])
                for lo, hi in ((0, 3), (3, 5), (5, 10), (10, math.inf)))},
        "detection_beyond_quoted": rate(
            [r for r in moved if r["detectable"] and r["status"] == "moved" and r["true_detectable_mm"]
             and r["translation_mm"] > r["true_detectable_mm"]],
            [r for r in moved if r["detectable"] and r["status"] != "error" and r["true_detectable_mm"]
             and r["translation_mm"] > r["true_detectable_mm"]]),
        "compute_s_median": float(np.median([r["compute_s"] for r in rows if "compute_s" in r])),
        "compute_s_max": float(np.max([r["compute_s"] for r in rows if "compute_s" in r])),
        "cpu_s_median": float(np.median([r["cpu_s"] for r in rows if "cpu_s" in r])),
        "cpu_s_max": float(np.max([r["cpu_s"] for r in rows if "cpu_s" in r])),
    }
