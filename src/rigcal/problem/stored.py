"""A calibration as stored in ``calibration.yaml``, as one value: what ``rigcal check`` and
``rigcal diff`` compare against.

Per sensor: ``T_reference_sensor``, the (6, 6) covariance of its right perturbation (rotation
[rad] first, then translation [m], both in the sensor frame), the directions only bounded by a
2D radar's field of view and the directions held; per sensor pair the covariance of the
relative pose (``relative`` in ``calibration.yaml``, cross-correlations included); and the
noise model of the detections (:mod:`rigcal.problem.noise`). Read by
:func:`rigcal.io.results.stored.read_stored_calibration`, or taken from a
:class:`~rigcal.problem.result.CalibrationResult` in memory with :meth:`StoredCalibration.from_result`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from rigcal.dataset import SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import adjoint, invert

#: tangent order of a right perturbation (rotation first), as in the solver
TANGENT = ("roll", "pitch", "yaw", "x", "y", "z")


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class StoredSensor:
    """One sensor of a stored calibration (see the module docstring)."""

    name: str
    kind: SensorKind
    frame_id: str
    T_reference_sensor: np.ndarray
    covariance: np.ndarray
    bounded: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    held: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name, shape in (("T_reference_sensor", (4, 4)), ("covariance", (6, 6))):
            a = np.array(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise InputError(f"sensor '{self.name}': {name} must have shape {shape}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "bounded", dict(self.bounded))
        object.__setattr__(self, "held", tuple(self.held))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class StoredCalibration:
    """A relative calibration: every sensor's pose in the ``reference`` sensor's frame.

    ``relative[(a, b)]``: the (6, 6) covariance of the right perturbation of ``T_a_b`` (in b's
    frame), for the pairs the file lists (either order is enough, see
    :meth:`relative_covariance`). ``noise_model[sensor][component]``: the detections' noise std
    (m; camera depth: m at 1 m; radar angles: deg), :func:`rigcal.problem.noise.theta_by_sensor`.
    """

    reference: str
    sensors: Mapping[str, StoredSensor]
    relative: Mapping[tuple[str, str], np.ndarray] = field(default_factory=dict)
    noise_model: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    mode: str = ""
    num_boards: int = 0
    source: str = "calibration"
    #: the (6N, 6N) joint covariance of every sensor's right perturbation (``joint_covariance``
    #: in calibration.yaml), None when the file has none; its sensors in ``joint_sensors`` order
    #: (default: ``sensors``'); kept as the block of ``sensors`` (a calibration narrowed to some
    #: sensors keeps their part)
    joint: np.ndarray | None = None
    joint_sensors: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "sensors", dict(self.sensors))
        object.__setattr__(self, "relative", dict(self.relative))
        if self.reference not in self.sensors:
            raise InputError(f"{self.source}: reference '{self.reference}' is not one of the sensors "
                             f"{list(self.sensors)}")
        if self.joint is not None:
            J = np.array(self.joint, dtype=float)
            order = list(self.joint_sensors or self.sensors)
            if J.shape != (6 * len(order), 6 * len(order)) or not set(self.sensors) <= set(order):
                raise InputError(f"{self.source}: joint_covariance must be (6N, 6N) for the sensors "
                                 f"{list(self.sensors)}, got {J.shape} for {order}")
            idx = np.concatenate([np.arange(6) + 6 * order.index(n) for n in self.sensors])
            J = J[np.ix_(idx, idx)]
            J.setflags(write=False)
            object.__setattr__(self, "joint", J)
            object.__setattr__(self, "joint_sensors", tuple(self.sensors))

    def joint_block(self, a: str, b: str) -> np.ndarray | None:
        """The (6, 6) cross-covariance of sensors ``a`` and ``b``'s right perturbations from
        :attr:`joint`; None without one."""
        if self.joint is None:
            return None
        order = list(self.sensors)
        i, j = 6 * order.index(a), 6 * order.index(b)
        return np.array(self.joint[i:i + 6, j:j + 6])

    @property
    def relative_is_joint(self) -> bool:
        """True when ``relative`` agrees with the sensors' own covariances (the reference's pairs
        are the sensors' poses themselves): the joint covariance's relative poses. Files whose
        ``relative`` came from another covariance than the sensors' (the solver's, before the
        noise model's sandwich) are not used for it."""
        cached = self.__dict__.get("_joint")
        if cached is None:
            pairs = [(self.reference, n) for n in self.sensors if n != self.reference]
            cached = bool(self.relative) and all(
                (a, b) in self.relative
                and np.allclose(self.relative[(a, b)], self.sensors[b].covariance, rtol=1e-6, atol=1e-14)
                for a, b in pairs)
            object.__setattr__(self, "_joint", cached)
        return cached

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.sensors)

    def T(self, to: str, frm: str) -> np.ndarray:
        """``T_to_from`` between two sensors of the calibration."""
        return invert(self.sensors[to].T_reference_sensor) @ self.sensors[frm].T_reference_sensor

    def relative_covariance(self, to: str, frm: str) -> np.ndarray:
        """(6, 6) covariance of the right perturbation of ``T_to_from`` (in ``frm``'s frame).

        From ``relative`` (the pair in either order: ``(T e^xi)^-1 = T^-1 e^(-Ad(T) xi)``) when it
        holds the joint covariance (:attr:`relative_is_joint`); otherwise from the two sensors'
        own covariances as if they were independent."""
        if to == frm:
            return np.zeros((6, 6))
        if self.relative_is_joint:
            if (to, frm) in self.relative:
                return np.array(self.relative[(to, frm)])
            if (frm, to) in self.relative:
                # (T e^xi)^-1 = T^-1 e^(-Ad(T) xi) for T = T_from_to
                Ad = adjoint(self.T(frm, to))
                C = Ad @ self.relative[(frm, to)] @ Ad.T
                return 0.5 * (C + C.T)
        # T_to_from = T_ref_to^-1 T_ref_from: (T_a e^xa)^-1 T_b e^xb = T_a_b e^(xb - Ad(T_b_a) xa)
        Ad = adjoint(self.T(frm, to))
        C = self.sensors[frm].covariance + Ad @ self.sensors[to].covariance @ Ad.T
        return 0.5 * (C + C.T)

    @classmethod
    def from_result(cls, result, source: str = "calibration") -> "StoredCalibration":
        """The stored form of a :class:`~rigcal.problem.result.CalibrationResult` (what its
        ``calibration.yaml`` holds)."""
        sensors = {
            name: StoredSensor(name, est.kind, est.frame_id, est.T_reference_sensor, est.covariance,
                               est.bounded, est.held)
            for name, est in result.sensors.items()
        }
        relative = {(rel.to, rel.frm): rel.covariance for rel in result.relative.values()}
        return cls(result.reference, sensors, relative, result.noise_model, result.mode,
                   int(result.num_boards), source, getattr(result, "joint_covariance", None))


#: the directions of a 2D radar's pose it does not measure (it sees no elevation): bounded by its
#: field of view or held, never tested as if measured
RADAR_UNMEASURED = ("roll", "pitch", "z")


def untestable_directions(kind: SensorKind) -> tuple[str, ...]:
    """The tangent directions of a sensor of ``kind`` that board detections do not measure: a
    2D radar's z, roll and pitch (:data:`RADAR_UNMEASURED`); none for the others."""
    return RADAR_UNMEASURED if kind == SensorKind.RADAR else ()


__all__ = ["TANGENT", "StoredCalibration", "RADAR_UNMEASURED", "StoredSensor", "untestable_directions"]
