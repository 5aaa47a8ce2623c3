"""The value a calibration returns, and its plain-data form for YAML/JSON."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.geometry.so3 import rpy_from_matrix

STD_KEYS = ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg")


def bounded_dict(bounded: dict[str, tuple[float, float, float]]) -> dict[str, dict[str, float]]:
    """Bounded quantities as written to calibration.yaml / JSON: ``{key: {low, high,
    estimate}}`` - absolute values (m for x, y, z; deg for roll, pitch, yaw)."""
    return {k: {"low": float(lo), "high": float(hi), "estimate": float(e)} for k, (lo, hi, e) in bounded.items()}


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class BoundedSet:
    """The offsets of a sensor's bounded ``directions`` (of roll, pitch, z about / along its own
    axes) that its constraints allow, to first order: ``A @ beta <= b`` and ``|beta| <= limit``
    (``beta`` in ``directions`` order, rad / m; the estimate, ``beta = 0``, inside), and how the
    whole pose follows them: ``move_map`` (6, k), the right perturbation per unit offset (its
    in-plane pose re-solved at the set's extremes)."""

    directions: tuple[str, ...]
    A: np.ndarray
    b: np.ndarray
    limit: np.ndarray
    move_map: np.ndarray

    def __post_init__(self) -> None:
        k = len(self.directions)
        for name, shape in (("A", (-1, k)), ("b", (-1,)), ("limit", (k,)), ("move_map", (6, k))):
            a = np.array(getattr(self, name), dtype=float).reshape(shape)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "directions", tuple(self.directions))

    @cached_property
    def vertices(self) -> np.ndarray:
        """(n, k) the set's vertices (:func:`rigcal.problem.numerics.polytope_vertices`)."""
        from rigcal.problem.numerics import polytope_vertices

        if not self.directions:
            return np.zeros((1, 0))
        return polytope_vertices(self.A, np.maximum(self.b, 0.0), self.limit)

    def extremes(self, g: np.ndarray) -> tuple[float, float]:
        """(min, max) of ``g @ beta`` over the set (over its vertices); ``g`` (k,)."""
        g = np.asarray(g, dtype=float).ravel()
        if not np.any(g):
            return 0.0, 0.0
        vals = self.vertices @ g
        return min(float(vals.min()), 0.0), max(float(vals.max()), 0.0)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class SensorEstimate:
    """One sensor's pose in the reference frame with its uncertainty.

    ``covariance`` (6, 6) is over the right perturbation (omega, v) of ``T_reference_sensor``
    (rotation [rad] first, then translation [m], both in the sensor frame); ``std`` gives the
    standard deviations of x, y, z [m] and roll, pitch, yaw [deg] of ``T_reference_sensor``.
    ``held`` lists degrees of freedom held at their prior (e.g. z, roll, pitch of a 2D radar).
    """

    name: str
    kind: SensorKind
    frame_id: str
    T_reference_sensor: np.ndarray
    covariance: np.ndarray
    std: dict[str, float]
    held: tuple[str, ...] = ()
    #: directions set by an inequality constraint rather than by measurements (a 2D radar's
    #: z, roll, pitch without a prior): local direction -> (low, high) offset from the estimate
    #: that the constraints allow (m for x/y/z along the sensor's own axes, deg for
    #: roll/pitch/yaw about them); their std is not meaningful. As absolute values of the pose
    #: table: :attr:`bounded_absolute`
    bounded: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: the mounting prior's tolerances (:mod:`rigcal.problem.priors`; m / deg, 0: held)
    prior: dict[str, float] = field(default_factory=dict)
    #: the set of ``bounded`` offsets the constraints allow, and how the pose follows them
    #: (None: the box of the ``bounded`` intervals, the directions alone)
    bounded_set: BoundedSet | None = None

    @property
    def bounded_values(self) -> dict[str, tuple[float, float, float]]:
        """What the bounded directions leave open, as absolute values of the pose table of
        ``T_reference_sensor``: ``{key: (low, high, estimate)}`` for its z [m], roll, pitch
        [deg] and any other quantity they move by more than its std
        (:func:`rigcal.problem.uncertainty.sensor_bounded_values`)."""
        from rigcal.problem.uncertainty import sensor_bounded_values

        return sensor_bounded_values(self.T_reference_sensor, self.std, self.bounded, self.bounded_set)

    @property
    def xyz_m(self) -> np.ndarray:
        return self.T_reference_sensor[:3, 3].copy()

    @property
    def rpy_deg(self) -> np.ndarray:
        return np.degrees(rpy_from_matrix(self.T_reference_sensor[:3, :3]))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class RelativeEstimate:
    """One sensor's pose in another's frame, ``T_to_from`` (``frm`` seen from ``to``), with its
    uncertainty: ``covariance`` (6, 6) over the right perturbation (omega, v) of ``T_to_from``,
    propagated from both sensors' joint covariance (their correlation included); ``std`` as for
    :class:`SensorEstimate`."""

    to: str
    frm: str
    T_to_from: np.ndarray
    covariance: np.ndarray
    std: dict[str, float]
    #: pose-table quantities (x, y, z, roll, pitch, yaw) that a bounded direction of either
    #: sensor moves by more than their std: ``{key: (low, high, estimate)}`` (m / deg)
    bounded: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    @property
    def rotation_std_deg(self) -> np.ndarray:
        """(3,) std [deg] of the rotation vector of ``T_to_from``'s right perturbation: small
        rotations about the ``frm`` sensor's own x, y, z axes (well defined at any attitude,
        unlike Euler angles near gimbal lock)."""
        return np.degrees(np.sqrt(np.maximum(np.diag(self.covariance)[:3], 0.0)))

    @property
    def gimbal_lock(self) -> bool:
        """True when the Euler pitch is within 15 deg of +-90 deg: roll and yaw (and their std)
        are then ill defined; read :attr:`rotation_std_deg`."""
        from rigcal.problem.uncertainty import near_gimbal_lock

        return near_gimbal_lock(self.T_to_from)

    @property
    def xyz_m(self) -> np.ndarray:
        return self.T_to_from[:3, 3].copy()

    @property
    def rpy_deg(self) -> np.ndarray:
        return np.degrees(rpy_from_matrix(self.T_to_from[:3, :3]))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class CalibrationResult:
    """Everything a calibration run estimated and measured.

    ``rmse_m`` keys are ``"a-b"`` sensor pairs (in dataset order); values are the root mean
    squared distance over common detections as the original tool defines it (3D pairs over the
    circle centres, radar pairs in 2D after projection). ``per_board_m[pair][k]`` is the error
    of board k for that pair (RMS over its points). ``outliers[sensor]`` are the board indices
    excluded for that sensor (found automatically or from an ignore file). ``relative["a-b"]``
    is sensor b's pose in sensor a's frame (``T_a_b``) with its covariance, for every pair of
    calibrated sensors (a before b in sensor order).
    """

    mode: str
    reference: str
    converged: bool
    sensors: dict[str, SensorEstimate]
    rmse_m: dict[str, float]
    per_board_m: dict[str, dict[int, float]]
    outliers: dict[str, tuple[int, ...]]
    ignored: dict[str, tuple[int, ...]] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    iterations: int = 0
    cost: float = 0.0
    num_boards: int = 0
    noise_sigma_m: dict[str, tuple[float, ...]] = field(default_factory=dict)
    noise_iterations: int = 0
    board_poses: dict[int, np.ndarray] = field(default_factory=dict)
    cross_validation_rmse_m: dict[str, float] = field(default_factory=dict)
    solve_time_s: float = 0.0
    #: camera pairs' reprojection RMS [px] (motion-capture calibration: "robot-camera1")
    reprojection_px: dict[str, float] = field(default_factory=dict)
    relative: dict[str, RelativeEstimate] = field(default_factory=dict)
    #: noise std per sensor and component estimated from the residuals (see
    #: :mod:`rigcal.problem.noise`): m; camera depth: m at 1 m range; radar angles: deg
    noise_model: dict[str, dict[str, float]] = field(default_factory=dict)
    #: the consistency check (:mod:`rigcal.problem.consistency`); None: not checked
    verdict: Any = None
    #: sensors left out of the result, each with the reason (motion-capture calibration: a
    #: sensor that never saw a target, or whose measurements leave its pose undetermined,
    #: while the others were calibrated)
    not_calibrated: dict[str, str] = field(default_factory=dict)
    #: (6N, 6N) joint covariance of the N sensors' right perturbations (in ``sensors`` order; the
    #: reference's rows zero), cross terms included: what ``rigcal check`` needs to combine the
    #: errors of several stored relative poses exactly. None when the result has none (motion
    #: capture; MCPE with a 2D radar reference, whose relative poses add their own pair fits).
    joint_covariance: np.ndarray | None = None
    #: the frame the poses are relative to when the reference is not a sensor (motion capture:
    #: mocap.yaml's ``robot_frame``); empty: the reference sensor's ``frame_id``
    reference_frame: str = ""

    @property
    def flagged(self) -> bool:
        """True when a consistency check failed: the result contradicts its noise model."""
        return self.verdict is not None and self.verdict.status == "flagged"

    def T(self, to: str, frm: str) -> np.ndarray:
        """``T_to_from`` between two calibrated sensors (or the reference)."""
        T_ref_to = self.sensors[to].T_reference_sensor
        T_ref_from = self.sensors[frm].T_reference_sensor
        return np.linalg.inv(T_ref_to) @ T_ref_from

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-safe data (lists and floats)."""

        def f(x: float) -> float:
            return float(x)

        return {
            "reference": self.reference,
            "mode": self.mode,
            "converged": bool(self.converged),
            "verdict": self.verdict.to_dict() if self.verdict is not None else None,
            "num_boards": int(self.num_boards),
            "sensors": {
                name: {
                    "kind": est.kind.value,
                    "frame_id": est.frame_id,
                    "T_reference_sensor": [[f(v) for v in row] for row in est.T_reference_sensor],
                    "xyz_m": [f(v) for v in est.xyz_m],
                    "rpy_deg": [f(v) for v in est.rpy_deg],
                    "std": {k: f(est.std[k]) for k in STD_KEYS},
                    "covariance": [[f(v) for v in row] for row in est.covariance],
                    "held": list(est.held),
                    "bounded": bounded_dict(est.bounded_values),
                    "bounded_offsets": {d: [f(lo), f(hi)] for d, (lo, hi) in est.bounded.items()},
                    "prior": {k: f(v) for k, v in est.prior.items()},
                }
                for name, est in self.sensors.items()
            },
            "not_calibrated": {k: str(v) for k, v in self.not_calibrated.items()},
            **({} if self.joint_covariance is None else {"joint_covariance": {
                "sensors": list(self.sensors),
                "matrix": [[f(v) for v in row] for row in np.asarray(self.joint_covariance)],
            }}),
            "relative": {
                key: {
                    "to": rel.to,
                    "from": rel.frm,
                    "T_to_from": [[f(v) for v in row] for row in rel.T_to_from],
                    "xyz_m": [f(v) for v in rel.xyz_m],
                    "rpy_deg": [f(v) for v in rel.rpy_deg],
                    "std": {k: f(rel.std[k]) for k in STD_KEYS},
                    "rotation_std_deg": [f(v) for v in rel.rotation_std_deg],
                    "gimbal_lock": bool(rel.gimbal_lock),
                    "bounded": bounded_dict(rel.bounded),
                    "covariance": [[f(v) for v in row] for row in rel.covariance],
                }
                for key, rel in self.relative.items()
            },
            "rmse_m": {k: f(v) for k, v in self.rmse_m.items()},
            "reprojection_px": {k: f(v) for k, v in self.reprojection_px.items()},
            "cross_validation_rmse_m": {k: f(v) for k, v in self.cross_validation_rmse_m.items()},
            "per_board_m": {
                pair: {int(k): f(v) for k, v in errs.items()} for pair, errs in self.per_board_m.items()
            },
            "outliers": {k: [int(b) for b in v] for k, v in self.outliers.items()},
            "ignored": {k: [int(b) for b in v] for k, v in self.ignored.items()},
            "noise_sigma_m": {k: [f(s) for s in v] for k, v in self.noise_sigma_m.items()},
            "noise_iterations": int(self.noise_iterations),
            "noise_model": {k: {c: f(v) for c, v in comps.items()} for k, comps in self.noise_model.items()},
            "warnings": list(self.warnings),
            "iterations": int(self.iterations),
            "cost": f(self.cost),
            "solve_time_s": f(self.solve_time_s),
        }
