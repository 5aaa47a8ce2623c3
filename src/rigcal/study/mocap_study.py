"""Charron et al.'s simulation study (section IV-A, Tables I-III) on rigcal's own raw simulation.

For every trial (seeded by ``(seed, trial)``):

1. the true extrinsic of the studied sensor (:func:`rigcal.sim.mocap.paper_rig`) is perturbed
   by a uniform draw in +-3 cm per axis and +-5 deg per roll/pitch/yaw: the initial
   calibration ``T_robot_sensor_initial``;
2. captures of the target held in the sensor's view are simulated
   (:func:`rigcal.sim.mocap.simulate_mocap`: ray-cast VLP-16 scans or rendered 2048 x 1536
   images, MCS poses exact or noisy) until ``max(measurements)`` of them yield a measurement;
3. each capture is measured by rigcal's mocap-guided extractors (:mod:`rigcal.extract`), guided
   by the target pose the MCS and the *initial* calibration predict: the lidar cloud is cropped,
   clustered and the template fitted by ICP (diamond: its four corners; cylinder: the scan
   points on the fitted template), the image is searched for the checkerboard corners or the
   green silhouette's contour. Captures that give no measurement (target predicted outside
   the view, corners not found, ICP refused, ...) are skipped and counted;
4. the first ``N`` measurements, for each ``N`` in ``measurements``, are calibrated with
   :func:`rigcal.problem.mocap.calibrate_mocap` from the initial calibration.

Recorded per (trial, N):

* translation error [mm]: ``|t_est - t_true|``, and the paper's definition "the absolute
  difference in the translation norms" ``| |t_est| - |t_true| |`` (much smaller: only the error
  along ``t_true`` shows);
* rotation error [deg]: the angle of ``R_true^T R_est``, and the paper's "absolute difference in
  the [angle-axis] angle" ``| angle(R_est) - angle(R_true) |``;
* lidar: the RMS Euclidean distance [mm] between the measured keypoints and the ground-truth
  keypoints (target keypoints put into the lidar frame by the MCS and the *estimated*
  calibration); for the cylinder, the RMS distance of the measured points to the cylinder's
  surface so placed. Camera: the RMS reprojection error [px] of the measured pixels.

:class:`StudyTable` holds every trial and the mean / standard deviation per ``N``;
:meth:`StudyTable.format` prints them next to the paper's numbers (:data:`PAPER_TABLES`).
`rigcal study mocap` runs :func:`run` (its options and parser: :mod:`rigcal.cli.study`).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import ConvergenceError, GeometryError, InputError, RigcalError
from rigcal.geometry.se3 import from_rt, invert, transform_points
from rigcal.geometry.so3 import matrix_from_rpy, so3_log
from rigcal.problem.mocap import CORRESPONDENCES, MocapOptions, MocapSensor, TargetObservation, calibrate_mocap
from rigcal.sim.mocap import (
    CAMERA,
    LIDAR,
    MocapCapture,
    MocapRig,
    MocapSimulation,
    PaperTargets,
    Placement,
    paper_rig,
    paper_targets,
    simulate_mocap,
)
from rigcal.targets.definition import Target, TargetKind
from rigcal.targets.surface import TargetSurface, surface_distance_m

log = logging.getLogger(__name__)

__all__ = [
    "PAPER_TABLES",
    "StudyRow",
    "StudyTable",
    "TrialResult",
    "extract_observation",
    "perturb_calibration",
    "run",
    "run_mocap_study",
]

TARGETS = ("diamond", "cylinder")
SENSORS = (LIDAR, CAMERA)

#: The paper's simulation tables: (target, sensor) -> N -> ((trans mu, sd) [mm],
#: (rot mu, sd) [deg], (Euclidean [mm] or reprojection [px] mu, sd)). Table I: diamond / lidar,
#: Table II: cylinder / lidar, Table III: diamond / camera (the paper has no cylinder / camera
#: table).
PAPER_TABLES: Mapping[tuple[str, str], Mapping[int, tuple[tuple[float, float], ...]]] = {
    ("diamond", LIDAR): {
        30: ((0.1, 1.7e-6), (1.8e-3, 5.1e-8), (0.5, 0.1)),
        15: ((0.1, 2.0e-6), (2.4e-3, 3.6e-7), (0.4, 0.6)),
        5: ((0.3, 4.3e-6), (3.8e-3, 3.5e-8), (2.2, 9.0)),
    },
    ("cylinder", LIDAR): {
        30: ((4.6, 2.4), (4.7e-2, 3.4e-2), (4.5, 0.3)),
        15: ((7.4, 4.6), (0.1, 6.8e-2), (5.0, 0.3)),
        5: ((88.0, 64.2), (1.6, 2.0), (7.8, 0.7)),
    },
    ("diamond", CAMERA): {
        30: ((0.111, 1.3e-6), (0.035, 9.2e-8), (0.158, 1.4e-8)),
        15: ((0.066, 3.6e-6), (0.035, 3.6e-6), (0.167, 6.2e-8)),
        5: ((0.136, 1.9e-6), (0.034, 1.3e-8), (0.131, 3.9e-7)),
    },
}
PAPER_TABLE_NAMES = {("diamond", LIDAR): "Table I", ("cylinder", LIDAR): "Table II", ("diamond", CAMERA): "Table III"}


# --------------------------------------------------------------------------------------------
# values


@dataclass(frozen=True)
class TrialResult:
    """One calibration: trial ``trial`` with its first ``measurements`` measurements.

    Errors of the estimate against the truth: ``translation_error_mm`` (norm of the difference),
    ``rotation_error_deg`` (geodesic angle), and the paper's definitions
    ``translation_norm_diff_mm`` / ``rotation_angle_diff_deg`` (see the module docstring).
    ``residual``: RMS Euclidean error [mm] (lidar) or RMS reprojection error [px] (camera);
    ``initial_*``: the errors of the initial calibration. ``error`` is "" or why the calibration
    failed (then the errors are NaN).
    """

    trial: int
    measurements: int
    translation_error_mm: float
    rotation_error_deg: float
    translation_norm_diff_mm: float
    rotation_angle_diff_deg: float
    residual: float
    initial_translation_error_mm: float
    initial_rotation_error_deg: float
    solve_time_s: float
    error: str = ""

    @property
    def ok(self) -> bool:
        return not self.error


@dataclass(frozen=True)
class Stat:
    """Mean and standard deviation (ddof 1; 0 for one value) of ``n`` values."""

    mean: float
    std: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> "Stat":
        v = np.asarray([x for x in values if math.isfinite(x)], dtype=float)
        if v.size == 0:
            return cls(math.nan, math.nan, 0)
        return cls(float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0, int(v.size))


@dataclass(frozen=True)
class StudyRow:
    """The statistics over the successful trials with ``measurements`` measurements."""

    measurements: int
    trials: int
    failed: int
    translation_mm: Stat
    rotation_deg: Stat
    translation_norm_diff_mm: Stat
    rotation_angle_diff_deg: Stat
    residual: Stat


@dataclass(frozen=True)
class StudyTable:
    """The result of :func:`run_mocap_study`: one row per number of measurements, every trial,
    and how the time was spent. ``residual_name`` is ``"Euc. [mm]"`` (lidar) or
    ``"Proj. [px]"`` (camera). ``skipped_captures`` counts the captures the extractors turned
    down, by reason."""

    target: str
    sensor: str
    mcs_noise_m: float
    trials: int
    seed: int
    rows: tuple[StudyRow, ...]
    results: tuple[TrialResult, ...]
    residual_name: str
    skipped_captures: Mapping[str, int]
    captures_simulated: int
    time_per_trial_s: float
    simulate_time_s: float
    extract_time_s: float
    calibrate_time_s: float
    target_source: str = ""
    method: str = ""
    notes: tuple[str, ...] = ()

    def row(self, measurements: int) -> StudyRow:
        for r in self.rows:
            if r.measurements == measurements:
                return r
        raise InputError(f"study: no row for {measurements} measurements (rows: {[r.measurements for r in self.rows]})")

    def paper(self) -> Mapping[int, tuple[tuple[float, float], ...]]:
        """The paper's numbers for this target and sensor ({} when the paper has none)."""
        return PAPER_TABLES.get((self.target, self.sensor), {})

    def format(self) -> str:
        """A text table like the paper's, the paper's values beside ours."""
        paper = self.paper()
        name = PAPER_TABLE_NAMES.get((self.target, self.sensor), "no table in the paper")
        sensor = "VLP-16 lidar" if self.sensor == LIDAR else "2048x1536 pinhole camera"
        noise = "exact MCS poses" if self.mcs_noise_m == 0 else f"MCS noise {self.mcs_noise_m * 1e3:.3g} mm"
        lines = [
            f"Mocap calibration study: {self.target} target, {sensor}, {noise}; "
            f"{self.trials} trials (seed {self.seed}); initial calibration perturbed uniformly "
            f"+-3 cm / +-5 deg per axis",
            f"paper: Charron et al., {name}. err = norm of the difference (|dt|, rotation angle of "
            f"R_true^T R_est); paper-def = |norm(t_est) - norm(t_true)|, |angle(R_est) - angle(R_true)| "
            f"(the paper's definitions); mu +- sigma over successful trials",
        ]
        if self.method:
            lines.append(f"method: {self.method}")
        lines.append("")
        res = self.residual_name
        head = (f"{'N':>3} {'ok':>5} | {'trans err [mm]':>17} {'paper-def [mm]':>17} | "
                f"{'rot err [deg]':>19} {'paper-def [deg]':>19} | {res:>15} || "
                f"{'paper trans [mm]':>17} {'paper rot [deg]':>18} {'paper ' + res:>18}")
        lines.append(head)
        lines.append("-" * len(head))

        def pm(s: Stat, fmt: str) -> str:
            return "n/a" if s.n == 0 else f"{s.mean:{fmt}} +- {s.std:{fmt}}".replace("+- ", "+-")

        def pp(v: tuple[float, float]) -> str:
            return f"{v[0]:.3g} +-{v[1]:.2g}"

        for r in sorted(self.rows, key=lambda r: -r.measurements):
            p = paper.get(r.measurements)
            ours = (f"{r.measurements:>3} {r.trials:>2}/{r.trials + r.failed:<2} | {pm(r.translation_mm, '.3g'):>17} "
                    f"{pm(r.translation_norm_diff_mm, '.3g'):>17} | {pm(r.rotation_deg, '.2e'):>19} "
                    f"{pm(r.rotation_angle_diff_deg, '.2e'):>19} | {pm(r.residual, '.3g'):>15} || ")
            theirs = (f"{pp(p[0]):>17} {pp(p[1]):>18} {pp(p[2]):>18}" if p else f"{'-':>17} {'-':>18} {'-':>18}")
            lines.append(ours + theirs)
        lines.append("")
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped_captures.items())) or "none"
        lines.append(
            f"{self.captures_simulated} captures simulated, skipped by the extractors: {skipped}. "
            f"Time per trial {self.time_per_trial_s:.2f} s (simulate {self.simulate_time_s:.2f}, "
            f"extract {self.extract_time_s:.2f}, calibrate {self.calibrate_time_s:.2f})."
        )
        if self.target_source:
            lines.append(f"target: {self.target_source}")
        lines += list(self.notes)
        return "\n".join(lines)

    METRICS = (("translation_mm", "translation error [mm]", 0), ("rotation_deg", "rotation error [deg]", 1),
               ("translation_norm_diff_mm", "translation, paper's definition [mm]", 0),
               ("rotation_angle_diff_deg", "rotation, paper's definition [deg]", 1),
               ("residual", "residual", 2))

    def json_rows(self) -> list[dict]:
        """One row per (N, metric): mean, std and count over the successful trials, the paper's
        mean and std (its tables report translation and rotation in its own definitions - they
        sit beside both of ours - and the residual), trials and failures."""
        paper = self.paper()
        table = PAPER_TABLE_NAMES.get((self.target, self.sensor))
        out = []
        for r in sorted(self.rows, key=lambda r: r.measurements):
            p = paper.get(r.measurements)
            for key, label, col in self.METRICS:
                st = getattr(r, key)
                unit = self.residual_name if key == "residual" else label
                out.append({
                    "table": f"mocap {table}" if table else "mocap", "target": self.target, "sensor": self.sensor,
                    "mcs_noise_m": self.mcs_noise_m, "measurements": r.measurements, "metric": key,
                    "unit": unit, "mean": _finite(st.mean), "std": _finite(st.std), "n": st.n,
                    "paper_mean": p[col][0] if p else None, "paper_std": p[col][1] if p else None,
                    "trials": r.trials + r.failed, "failures": r.failed,
                })
        return out

    def markdown(self) -> str:
        """The table as Markdown, the paper's values beside ours (``format`` is the plain-text
        version)."""
        paper = self.paper()
        name = PAPER_TABLE_NAMES.get((self.target, self.sensor), "no table in the paper")
        head = self.format().splitlines()
        lines = [f"### Motion-capture study: {self.target} target, {self.sensor} (paper: Charron et al., {name})",
                 "", head[0], "", head[1], ""]
        if self.method:
            lines += [f"Method: {self.method}", ""]
        res = self.residual_name
        lines += [f"| N | ok | translation err [mm] | paper-def [mm] | rotation err [deg] | paper-def [deg] | {res} "
                  f"| paper trans [mm] | paper rot [deg] | paper {res} |",
                  "| --- |" + " --- |" * 9]

        def pm(st: Stat, fmt: str) -> str:
            return "n/a" if st.n == 0 else f"{st.mean:{fmt}} +- {st.std:{fmt}}"

        for r in sorted(self.rows, key=lambda r: -r.measurements):
            p = paper.get(r.measurements)
            theirs = ([f"{v[0]:.3g} +- {v[1]:.2g}" for v in p] if p else ["-", "-", "-"])
            lines.append(f"| {r.measurements} | {r.trials}/{r.trials + r.failed} | {pm(r.translation_mm, '.3g')} | "
                         f"{pm(r.translation_norm_diff_mm, '.3g')} | {pm(r.rotation_deg, '.2e')} | "
                         f"{pm(r.rotation_angle_diff_deg, '.2e')} | {pm(r.residual, '.3g')} | " + " | ".join(theirs) + " |")
        lines += [""] + [ln for ln in head if ln.startswith(("target:", "failed:"))]
        tail = [ln for ln in head if "captures simulated" in ln]
        return "\n".join(lines + tail) + "\n"

    def plot(self, path) -> None:
        """Write a PNG: translation error, rotation error (ours and the paper's definitions) and
        the residual against N, mean +- std over the trials; the paper's values as black marks."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        paper = self.paper()
        rows = sorted(self.rows, key=lambda r: r.measurements)
        n = np.array([r.measurements for r in rows], dtype=float)
        fig, axes = plt.subplots(1, 3, figsize=(12.6, 3.6))
        panels = (("translation [mm]", ("translation_mm", "translation_norm_diff_mm"), 0),
                  ("rotation [deg]", ("rotation_deg", "rotation_angle_diff_deg"), 1),
                  (self.residual_name, ("residual",), 2))
        for ax, (title, keys, col) in zip(axes, panels):
            for key in keys:
                m = np.array([getattr(r, key).mean for r in rows])
                sd = np.array([getattr(r, key).std for r in rows])
                label = "ours, paper's definition" if key.endswith("diff_mm") or key.endswith("diff_deg") else "ours"
                ax.errorbar(n, m, yerr=sd, marker="o", capsize=3, label=label)
            pts = [(r.measurements, paper[r.measurements][col]) for r in rows if r.measurements in paper]
            if pts:
                ax.errorbar([p[0] for p in pts], [p[1][0] for p in pts], yerr=[p[1][1] for p in pts], fmt="kx",
                            markersize=8, capsize=3, label="paper")
            ax.set_title(title)
            ax.set_xlabel("measurements N")
            ax.set_yscale("log")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(f"Mocap study: {self.target} / {self.sensor}, {self.trials} trials (mean +- std)")
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)

    def as_dict(self) -> dict:
        """Plain values (for JSON)."""

        def st(s: Stat) -> dict:
            return {"mean": s.mean, "std": s.std, "n": s.n}

        return {
            "target": self.target, "sensor": self.sensor, "mcs_noise_m": self.mcs_noise_m,
            "trials": self.trials, "seed": self.seed, "residual_name": self.residual_name,
            "rows": [
                {"measurements": r.measurements, "trials": r.trials, "failed": r.failed,
                 "translation_mm": st(r.translation_mm), "rotation_deg": st(r.rotation_deg),
                 "translation_norm_diff_mm": st(r.translation_norm_diff_mm),
                 "rotation_angle_diff_deg": st(r.rotation_angle_diff_deg), "residual": st(r.residual)}
                for r in self.rows
            ],
            "results": [
                {"trial": r.trial, "measurements": r.measurements,
                 "translation_error_mm": r.translation_error_mm, "rotation_error_deg": r.rotation_error_deg,
                 "translation_norm_diff_mm": r.translation_norm_diff_mm,
                 "rotation_angle_diff_deg": r.rotation_angle_diff_deg, "residual": r.residual,
                 "initial_translation_error_mm": r.initial_translation_error_mm,
                 "initial_rotation_error_deg": r.initial_rotation_error_deg, "error": r.error}
                for r in self.results
            ],
            "time_per_trial_s": self.time_per_trial_s,
            "skipped_captures": dict(self.skipped_captures),
            "captures_simulated": self.captures_simulated,
        }


# --------------------------------------------------------------------------------------------
# steps


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def perturb_calibration(T_robot_sensor: np.ndarray, rng: np.random.Generator, translation_m: float = 0.03,
                        rotation_deg: float = 5.0) -> np.ndarray:
    """The paper's initial calibration: ``T_robot_sensor`` with every translation axis moved by
    U(-translation_m, translation_m) and the rotation turned by roll, pitch, yaw each
    U(-rotation_deg, rotation_deg) (applied in the sensor frame, on the right)."""
    dR = matrix_from_rpy(np.radians(rng.uniform(-rotation_deg, rotation_deg, 3)))
    T = np.array(T_robot_sensor, dtype=float)
    return from_rt(T[:3, :3] @ dR, T[:3, 3] + rng.uniform(-translation_m, translation_m, 3))


def _uncertainty(translation_m: float = 0.03, rotation_deg: float = 5.0):
    """The initial calibration's 1-sigma (uniform +-a has sigma a / sqrt 3), 3 sigma margins."""
    from rigcal.extract.guidance import PoseUncertainty

    return PoseUncertainty(translation_m / math.sqrt(3), math.radians(rotation_deg) / math.sqrt(3), 3.0)


@dataclass
class _Extractor:
    """Extraction settings for one target and sensor, with the prepared template."""

    target: Target
    kind: str
    rig: MocapRig
    uncertainty: object
    template: object = None

    def __post_init__(self) -> None:
        if self.kind == LIDAR:
            from rigcal.extract.icp import prepare_template

            self.template = prepare_template(self.target.template)


def extract_observation(
    capture: MocapCapture,
    sim: MocapSimulation,
    kind: str,
    T_robot_sensor_initial: np.ndarray,
    extractor: _Extractor | None = None,
    lidar_measurement: str = "keypoints",
):
    """Measure ``capture``'s ``kind`` data with the mocap-guided extractors.

    The expected target pose is ``inv(T_robot_sensor_initial) @ T_robot_target`` with the MCS's
    (possibly noisy) poses. Returns a :class:`~rigcal.problem.mocap.TargetObservation` (with
    keypoint correspondences for the diamond, without for the cylinder) or the extractor's
    :class:`~rigcal.extract.result.ExtractionFailure`.
    """
    from rigcal.extract.result import ExtractionFailure

    if kind not in SENSORS:
        raise InputError(f"extract_observation: kind must be one of {SENSORS}, got {kind!r}")
    if lidar_measurement not in ("keypoints", "points"):
        raise InputError(f"extract_observation: lidar_measurement must be 'keypoints' or 'points', got {lidar_measurement!r}")
    ex = extractor or _Extractor(sim.target, kind, sim.rig, _uncertainty())
    target = sim.target
    name = sim.rig.name_of(kind)
    T_rt = capture.T_robot_target_mcs
    T_exp = invert(np.asarray(T_robot_sensor_initial, float)) @ T_rt
    diamond = target.kind is TargetKind.CHECKERBOARD_DIAMOND
    if kind == LIDAR:
        diamond = diamond and lidar_measurement == "keypoints"
        from rigcal.extract.lidar import extract_lidar_target

        if capture.cloud is None:
            return ExtractionFailure(name, capture.t_ns, "target_not_in_view", "no scan of the target")
        m = extract_lidar_target(
            capture.cloud, T_exp, ex.template,
            keypoints_target=target.lidar_keypoints if diamond else None,
            uncertainty=ex.uncertainty, sensor=name, t_ns=capture.t_ns, target=target.name,
        )
        if not m.ok:
            return m
        kp = target.lidar_keypoints[m.keypoint_index] if diamond else None
    else:
        from rigcal.extract.camera import extract_checkerboard, extract_cylinder

        if capture.image is None:
            return ExtractionFailure(name, capture.t_ns, "target_not_in_view", "no image of the target")
        camera = sim.rig.camera
        if diamond:
            pattern = (int(target.dims["cols"]), int(target.dims["rows"]))
            m = extract_checkerboard(
                capture.image, camera, pattern, target.camera_keypoints, T_exp,
                uncertainty=ex.uncertainty, estimate_pose=False, sensor=name, t_ns=capture.t_ns,
                target=target.name,
            )
        else:
            m = extract_cylinder(
                capture.image, camera, T_exp, target.template, uncertainty=ex.uncertainty,
                sensor=name, t_ns=capture.t_ns, target=target.name,
            )
        if not m.ok:
            return m
        kp = target.camera_keypoints[m.keypoint_index] if diamond else None
    if len(m.keypoints) == 0:
        return ExtractionFailure(name, capture.t_ns, "no_cluster" if kind == LIDAR else "no_contour",
                                 "the extractor returned no points")
    return TargetObservation(name, target.name, capture.t_ns, T_rt, m.keypoints, kp)


def _rotation_angle(R: np.ndarray) -> float:
    return float(np.linalg.norm(so3_log(R)))


def _residual(obs: Sequence[TargetObservation], kind: str, target: Target, T_est: np.ndarray, camera, result) -> float:
    """RMS Euclidean error [mm] (lidar) or reprojection error [px] (camera) at ``T_est``."""
    T_se = invert(T_est)
    if kind == LIDAR:
        if obs[0].keypoints_target is not None:
            d = [np.linalg.norm(o.measured - transform_points(T_se @ o.T_robot_target, o.keypoints_target), axis=1) for o in obs]
        else:
            d = [surface_distance_m(target, transform_points(invert(T_se @ o.T_robot_target), o.measured)) for o in obs]
        e = np.concatenate(d)
        return float(np.sqrt(np.mean(e**2)) * 1e3)
    if target.kind is TargetKind.CHECKERBOARD_DIAMOND:
        d = []
        for o in obs:
            uv, _ = camera.project(transform_points(T_se @ o.T_robot_target, o.keypoints_target))
            d.append(np.linalg.norm(o.measured - uv, axis=1))
        e = np.concatenate(d)
        return float(np.sqrt(np.mean(e**2)))
    return float(next(iter(result.reprojection_px.values())))


#: the lidar std [m] the calibration assumes for exact scans: the diamond's ICP corners scatter
#: by a few mm (ring quantisation); points on a surface are exact up to this floor
CORNER_SIGMA_M = 0.003
POINT_SIGMA_FLOOR_M = 0.0005


def _sensor_sigma(kind: str, target: Target, lidar_range_sigma_m: float = 0.0, corners: bool = False) -> float:
    """The measurement std the calibration assumes (it weighs the residuals and sets the robust
    loss's scale), as a user would set it for the sensor: the range noise for points on a
    surface, the corner scatter for the diamond's corners (whichever is larger)."""
    if kind == LIDAR:
        return max(CORNER_SIGMA_M if corners else POINT_SIGMA_FLOOR_M, lidar_range_sigma_m)
    return 0.1 if target.kind is TargetKind.CHECKERBOARD_DIAMOND else 0.7


def _calibrate(obs, kind, rig: MocapRig, target: Target, T_init, T_true, trial, n, options,
               lidar_range_sigma_m: float = 0.0) -> TrialResult:
    name = rig.name_of(kind)
    sk = SensorKind.LIDAR if kind == LIDAR else SensorKind.CAMERA
    corners = obs[0].keypoints_target is not None
    sensor = MocapSensor(name, sk, camera=rig.camera if kind == CAMERA else None,
                         sigma=_sensor_sigma(kind, target, lidar_range_sigma_m, corners))
    templates = {} if obs[0].keypoints_target is not None else {target.name: TargetSurface.of(target)}
    init_t = float(np.linalg.norm(T_init[:3, 3] - T_true[:3, 3]) * 1e3)
    init_r = math.degrees(_rotation_angle(T_true[:3, :3].T @ T_init[:3, :3]))
    t0 = time.perf_counter()
    try:
        res = calibrate_mocap([sensor], obs, {name: T_init}, templates, options)
        T = res.sensors[name].T_reference_sensor
    except (ConvergenceError, GeometryError) as exc:
        nan = math.nan
        return TrialResult(trial, n, nan, nan, nan, nan, nan, init_t, init_r, time.perf_counter() - t0, str(exc))
    dt = time.perf_counter() - t0
    return TrialResult(
        trial=trial,
        measurements=n,
        translation_error_mm=float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1e3),
        rotation_error_deg=math.degrees(_rotation_angle(T_true[:3, :3].T @ T[:3, :3])),
        translation_norm_diff_mm=abs(float(np.linalg.norm(T[:3, 3]) - np.linalg.norm(T_true[:3, 3]))) * 1e3,
        rotation_angle_diff_deg=math.degrees(abs(_rotation_angle(T[:3, :3]) - _rotation_angle(T_true[:3, :3]))),
        residual=_residual(obs, kind, target, T, rig.camera, res),
        initial_translation_error_mm=init_t,
        initial_rotation_error_deg=init_r,
        solve_time_s=dt,
    )


def _check_args(target: str, sensor: str, measurements, trials: int, mcs_noise_m: float, seed: int = 0) -> tuple[int, ...]:
    if target not in TARGETS:
        raise InputError(f"study: target must be one of {TARGETS}, got {target!r}")
    if sensor not in SENSORS:
        raise InputError(f"study: sensor must be one of {SENSORS}, got {sensor!r}")
    try:
        ns = tuple(sorted({int(n) for n in measurements}))
    except (TypeError, ValueError):
        raise InputError(f"study: measurements must be whole numbers, got {measurements!r}") from None
    if not ns or ns[0] < 1:
        raise InputError(f"study: measurements must be >= 1, got {measurements!r}")
    if isinstance(trials, bool) or not isinstance(trials, (int, np.integer)) or trials < 1:
        raise InputError(f"study: trials must be an integer >= 1, got {trials!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"study: seed must be an integer >= 0, got {seed!r}")
    if not (math.isfinite(mcs_noise_m) and mcs_noise_m >= 0):
        raise InputError(f"study: mcs_noise_m must be >= 0, got {mcs_noise_m!r}")
    return ns


@dataclass(frozen=True, eq=False)
class _TrialContext:
    """What every trial of a study shares (sent once to each Dask worker)."""

    sensor: str
    rig: MocapRig
    target: Target
    T_true: np.ndarray
    ns: tuple[int, ...]
    seed: int
    mcs_noise_m: float
    lidar_range_sigma_m: float
    placement: Placement
    options: MocapOptions
    lidar_measurement: str
    extractor: _Extractor
    cap: int


class _TrialOutcome(NamedTuple):
    results: list
    skipped: dict
    simulated: int
    simulate_s: float
    extract_s: float
    calibrate_s: float


def _run_trial(ctx: _TrialContext, trial: int, pool: list | None = None,
               data_rng: np.random.Generator | None = None) -> _TrialOutcome:
    """One trial: perturbed start from ``(seed, trial)``, captures until ``max(ns)``
    measurements, a calibration per N. ``pool``/``data_rng``: the captures shared by every trial
    (``same_data``); otherwise the trial simulates its own from its own generator."""
    rng = np.random.default_rng([ctx.seed, trial])
    T_init = perturb_calibration(ctx.T_true, rng)
    own = pool is None
    pool = [] if own else pool
    sim_rng = rng if own else data_rng
    need = ctx.ns[-1]
    obs: list[TargetObservation] = []
    skipped: dict[str, int] = {}
    results: list[TrialResult] = []
    simulated = 0
    t_sim = t_ext = t_cal = 0.0
    index = 0
    while len(obs) < need and index < ctx.cap:
        if index >= len(pool):
            batch = min(need - len(obs) + 2, ctx.cap - index)
            t0 = time.perf_counter()
            sim = simulate_mocap(ctx.rig, ctx.target, batch, sim_rng, sensors=(ctx.sensor,),
                                 mcs_noise_m=ctx.mcs_noise_m, lidar_range_sigma_m=ctx.lidar_range_sigma_m,
                                 placement=ctx.placement, first_index=len(pool))
            t_sim += time.perf_counter() - t0
            simulated += batch
            pool.extend((sim, c) for c in sim.captures)
        sim, c = pool[index]
        index += 1
        t0 = time.perf_counter()
        o = extract_observation(c, sim, ctx.sensor, T_init, ctx.extractor, ctx.lidar_measurement)
        t_ext += time.perf_counter() - t0
        if isinstance(o, TargetObservation):
            obs.append(o)
        else:
            skipped[o.reason] = skipped.get(o.reason, 0) + 1
    for n in ctx.ns:
        if len(obs) < n:
            nan = math.nan
            results.append(TrialResult(trial, n, nan, nan, nan, nan, nan, nan, nan, 0.0,
                                       f"only {len(obs)} measurements from {index} captures"))
            continue
        t0 = time.perf_counter()
        results.append(_calibrate(obs[:n], ctx.sensor, ctx.rig, ctx.target, T_init, ctx.T_true, trial, n,
                                  ctx.options, ctx.lidar_range_sigma_m))
        t_cal += time.perf_counter() - t0
    log.debug("mocap study trial %d: %d measurements from %d captures", trial, len(obs), index)
    return _TrialOutcome(results, skipped, simulated, t_sim, t_ext, t_cal)


def _trial_task(ctx: _TrialContext, trial: int) -> _TrialOutcome:
    """A trial as a Dask task (its own captures)."""
    return _run_trial(ctx, trial)


def run_mocap_study(
    target: str = "diamond",
    sensor: str = LIDAR,
    measurements: Sequence[int] = (5, 15, 30),
    trials: int = 10,
    mcs_noise_m: float = 0.0,
    seed: int = 0,
    *,
    overlapping: bool = False,
    targets: PaperTargets | None = None,
    placement: Placement = Placement(),
    options: MocapOptions = MocapOptions(),
    correspondences: str = "surface",
    lidar_measurement: str = "points",
    lidar_range_sigma_m: float = 0.0,
    same_data: bool = False,
    max_captures_factor: float = 3.0,
    progress=None,
    runner=None,
) -> StudyTable:
    """Run the paper's simulation study for one target (``"diamond"`` / ``"cylinder"``) and
    one sensor (``"lidar"`` / ``"camera"``); see the module docstring.

    ``measurements``: the numbers of measurements to calibrate with (the first N extracted
    measurements of each trial); ``trials``: how many seeded trials; ``mcs_noise_m``: MCS
    position noise per axis (0 = exact poses, as the paper; 0.00015 = Vicon's 0.15 mm).
    ``targets``: the target definitions (default :func:`rigcal.sim.mocap.paper_targets`).
    ``correspondences`` (measurements without keypoints, :class:`MocapOptions`): ``"centroid"``
    - the paper's centroid-aligned nearest-neighbour matching (III-D) throughout;
    ``"surface"`` - after it, every lidar point tied to the closest point of the target's
    analytic surface (point-to-plane), which removes the bias the centroid alignment leaves
    when only part of the target is seen (cameras keep the paper's matching). ``same_data``: every
    trial sees the same simulated captures and differs only in its initial calibration (what
    the paper's tiny standard deviations suggest it did); otherwise each trial draws new data.
    A trial that cannot gather ``max(measurements)`` measurements within
    ``max_captures_factor`` times as many captures uses what it has for the larger N (those
    rows count it as failed). ``progress(done, total)`` is called after every trial.
    ``runner``: a :class:`rigcal.study.scale.Runner` to run the trials on (e.g. Dask; default
    in this process); every trial is seeded by ``(seed, trial)``, so the numbers do not depend
    on it. With ``same_data`` the trials share one pool of captures and run in this process.
    """
    ns = _check_args(target, sensor, measurements, trials, mcs_noise_m, seed)
    if lidar_measurement not in ("keypoints", "points"):
        raise InputError(f"study: lidar_measurement must be 'keypoints' or 'points', got {lidar_measurement!r}")
    if not (math.isfinite(lidar_range_sigma_m) and lidar_range_sigma_m >= 0):
        raise InputError(f"study: lidar_range_sigma_m must be >= 0, got {lidar_range_sigma_m!r}")
    if correspondences not in CORRESPONDENCES:
        raise InputError(f"study: correspondences must be one of {CORRESPONDENCES}, got {correspondences!r}")
    options = dataclasses.replace(options, correspondences=correspondences)
    tg = targets or paper_targets()
    tdef = tg.diamond if target == "diamond" else tg.cylinder
    source = tg.diamond_source if target == "diamond" else tg.cylinder_source
    rig = paper_rig(overlapping=overlapping)
    T_true = rig.T_robot_sensor(sensor)
    need = ns[-1]
    t_start = time.perf_counter()
    ctx = _TrialContext(
        sensor=sensor, rig=rig, target=tdef, T_true=T_true, ns=ns, seed=int(seed), mcs_noise_m=mcs_noise_m,
        lidar_range_sigma_m=lidar_range_sigma_m, placement=placement, options=options,
        lidar_measurement=lidar_measurement, extractor=_Extractor(tdef, sensor, rig, _uncertainty()),
        cap=int(math.ceil(max_captures_factor * need)) + 5,
    )
    if same_data or runner is None:
        # same_data: every trial draws from one growing pool of captures - one after the other
        data_rng = np.random.default_rng([int(seed), 7919]) if same_data else None
        shared: list[tuple[MocapSimulation, MocapCapture]] = []
        outcomes = []
        for trial in range(int(trials)):
            outcomes.append(_run_trial(ctx, trial, shared if same_data else None, data_rng))
            if progress is not None:
                progress(trial + 1, int(trials))
    else:
        outcomes = runner.map(_trial_task, list(range(int(trials))), shared=ctx, progress=progress,
                              name="mocap-trial")
    results: list[TrialResult] = [r for o in outcomes for r in o.results]
    skipped: dict[str, int] = {}
    for o in outcomes:
        for k, v in o.skipped.items():
            skipped[k] = skipped.get(k, 0) + v
    simulated = sum(o.simulated for o in outcomes)
    t_sim = sum(o.simulate_s for o in outcomes)
    t_ext = sum(o.extract_s for o in outcomes)
    t_cal = sum(o.calibrate_s for o in outcomes)
    total = time.perf_counter() - t_start
    rows = []
    for n in ns:
        rs = [r for r in results if r.measurements == n]
        good = [r for r in rs if r.ok]
        rows.append(StudyRow(
            measurements=n, trials=len(good), failed=len(rs) - len(good),
            translation_mm=Stat.of([r.translation_error_mm for r in good]),
            rotation_deg=Stat.of([r.rotation_error_deg for r in good]),
            translation_norm_diff_mm=Stat.of([r.translation_norm_diff_mm for r in good]),
            rotation_angle_diff_deg=Stat.of([r.rotation_angle_diff_deg for r in good]),
            residual=Stat.of([r.residual for r in good]),
        ))
    failures = sorted({r.error for r in results if not r.ok})
    method = _describe(target, sensor, lidar_measurement, correspondences, lidar_range_sigma_m, same_data)
    notes = tuple(tg.notes) + tuple(f"failed: {f}" for f in failures[:5])
    return StudyTable(
        target=target, sensor=sensor, mcs_noise_m=float(mcs_noise_m), trials=int(trials), seed=int(seed),
        rows=tuple(rows), results=tuple(results),
        residual_name="Euc. [mm]" if sensor == LIDAR else "Proj. [px]",
        skipped_captures=dict(skipped), captures_simulated=simulated,
        time_per_trial_s=total / int(trials), simulate_time_s=t_sim / int(trials),
        extract_time_s=t_ext / int(trials), calibrate_time_s=t_cal / int(trials),
        target_source=source, method=method, notes=notes,
    )


def _describe(target, sensor, lidar_measurement, correspondences, lidar_range_sigma_m, same_data) -> str:
    if sensor == LIDAR:
        keypoints = target == "diamond" and lidar_measurement == "keypoints"
        what = ("the diamond's 4 corners placed by ICP of the template (paper's simulation)" if keypoints
                else "every scan point on the ICP-fitted template")
        if keypoints:
            match = "known correspondences"
        elif correspondences == "centroid":
            match = "centroid-aligned nearest-neighbour correspondences to the template (paper III-D)"
        else:
            match = ("centroid-aligned nearest neighbours (paper III-D), then every point's distance to the "
                     "target's surface" + (", then its range along its ray to the tube" if target == "cylinder"
                                           else ""))
        noise = "exact ranges" if lidar_range_sigma_m == 0 else f"range noise {lidar_range_sigma_m * 1e3:.3g} mm"
        text = f"lidar measured by {what}; {match}; {noise}"
    else:
        text = ("checkerboard corners (OpenCV findChessboardCornersSB) in a crop around the predicted board; "
                "known correspondences" if target == "diamond" else
                "green contour (HSV threshold, largest contour); centroid-aligned nearest-neighbour "
                "correspondences to the projected template (paper III-D)")
        text += "; pixel noise 1.8 grey levels"
    return text + ("; same captures in every trial" if same_data else "; new captures every trial")


# --------------------------------------------------------------------------------------------
# what `rigcal study mocap` runs (its options and parser: rigcal.cli.study)


def run(args: argparse.Namespace, progress=None) -> tuple[str, int]:
    """Run the study for parsed ``args``; returns (text to print, exit code). ``--out DIR``
    writes study.md, study.json (``{"meta", "rows", "trials"}``: every number) and mocap.png
    there; ``--scheduler`` says where the trials run (:mod:`rigcal.study.scale`)."""
    from rigcal.study.scale import SERIAL, task_runner

    scheduler = getattr(args, "scheduler", SERIAL)
    out = getattr(args, "out", None)
    try:
        if out:  # refused before the study, not after it
            from rigcal.io.atomic import check_output_folder

            check_output_folder(out)
        with task_runner(scheduler, tasks=args.trials) as runner:
            table = run_mocap_study(
                target=args.target, sensor=args.sensor, measurements=tuple(args.measurements),
                trials=args.trials, mcs_noise_m=args.mcs_noise_mm * 1e-3, seed=args.seed,
                overlapping=bool(getattr(args, "overlapping", False)),
                lidar_measurement=getattr(args, "lidar_measurement", "points"),
                correspondences=getattr(args, "correspondences", "surface"),
                lidar_range_sigma_m=getattr(args, "lidar_noise_mm", 0.0) * 1e-3,
                same_data=bool(getattr(args, "same_data", False)),
                runner=runner, progress=progress,
            )
            where = runner.description
        out = getattr(args, "out", None)
        if out:
            import json

            from rigcal.io.atomic import staged_folder

            from rigcal.report.study_page import render_study

            document = study_document(table, where)
            with staged_folder(out) as stage:
                table.plot(stage / "mocap.png")
                (stage / "study.md").write_text(table.markdown() + "\n![mocap](mocap.png)\n")
                (stage / "study.json").write_text(json.dumps(document, indent=1) + "\n")
                (stage / "study.html").write_text(render_study(
                    json.loads(json.dumps(document)), "study.json", "Motion-capture calibration study"))
    except RigcalError as exc:
        from rigcal.errors import printable

        return f"rigcal: error: {printable(exc)}", 1
    if getattr(args, "json", False):
        import json

        return json.dumps(table.as_dict(), indent=2), 0
    return table.format(), 0


def study_document(table: StudyTable, scheduler: str = "serial") -> dict:
    """study.json of a mocap study: ``meta`` (settings, method, timings), ``rows`` (one per N and
    metric, :meth:`StudyTable.json_rows`) and ``trials`` (every trial's numbers)."""
    d = table.as_dict()
    meta = {k: d[k] for k in ("target", "sensor", "mcs_noise_m", "trials", "seed", "residual_name",
                              "time_per_trial_s", "skipped_captures", "captures_simulated")}
    meta.update(method=table.method, target_source=table.target_source, notes=list(table.notes),
                scheduler=scheduler, paper="Charron et al., " + PAPER_TABLE_NAMES.get(
                    (table.target, table.sensor), "no table for this target and sensor"))
    trials = [{k: (_finite(v) if isinstance(v, float) else v) for k, v in r.items()} for r in d["results"]]
    return {"meta": meta, "rows": table.json_rows(), "trials": trials}
