"""The value an absolute calibration returns, and its plain-data form for YAML / JSON.

Conventions (``docs/conventions.md``): ``T_body_sensor`` maps sensor-frame points into the body
frame (the sensor's pose in the body frame); ``rpy_deg`` = (roll, pitch, yaw) with
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; covariances are over the right perturbation
``T <- T @ exp(xi)``, ``xi = (omega [rad], v [m])`` in the moving frame (the sensor's for
``T_body_sensor``, the body's for ``T_external_body``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from rigcal.absolute.body_frame import BodyFrame
from rigcal.dataset import SensorKind
from rigcal.geometry.so3 import rpy_from_matrix
from rigcal.problem.result import STD_KEYS, CalibrationResult, bounded_dict

__all__ = [
    "AbsoluteResult",
    "BODY_FRAME_DEFINITIONS",
    "BodySensorEstimate",
    "CONVENTION",
    "DEFAULT_BODY_FRAME",
    "tangent_std",
]

#: Default name of the body frame in files and TF trees (the ROS convention).
DEFAULT_BODY_FRAME = "base_link"

#: What the body frame is, per ``origin`` (see ``docs/absolute.md``).
BODY_FRAME_DEFINITIONS: Mapping[str, str] = {
    "rear_axle": (
        "origin: centre of the rear axle (mean of the two rear wheel centres) projected onto "
        "the ground; x forward toward the front axle centre, in the ground plane; z up, the "
        "ground normal; y = z x x (left)"
    ),
    "front_axle": (
        "origin: centre of the front axle (mean of the two front wheel centres) projected "
        "onto the ground; x forward from the rear toward the front axle centre, in the ground "
        "plane; z up, the ground normal; y = z x x (left)"
    ),
    "wheelbase_centre": (
        "origin: midpoint of the rear and front axle centres projected onto the ground; x "
        "forward from the rear toward the front axle centre, in the ground plane; z up, the "
        "ground normal; y = z x x (left)"
    ),
}

CONVENTION = (
    "T_body_sensor: p_body = T_body_sensor @ p_sensor (the sensor's pose in the body frame); "
    "xyz_m [m]; rpy_deg = (roll, pitch, yaw) [deg] with R = Rz(yaw) @ Ry(pitch) @ Rx(roll); "
    "covariance over the right perturbation T @ exp(omega, v) in the sensor frame (rad, m); "
    "std: of x, y, z [m] and roll, pitch, yaw [deg]"
)


def tangent_std(covariance: np.ndarray) -> dict[str, float]:
    """Standard deviations of a right perturbation ``(omega, v)``'s components, as
    ``{x_m, y_m, z_m, roll_deg, pitch_deg, yaw_deg}`` (translation along, rotation about the
    moving frame's axes; small angles)."""
    d = np.sqrt(np.maximum(np.diag(np.asarray(covariance, dtype=float)), 0.0))
    vals = (d[3], d[4], d[5], np.degrees(d[0]), np.degrees(d[1]), np.degrees(d[2]))
    return dict(zip(STD_KEYS, (float(v) for v in vals)))


def _readonly(a: Any) -> np.ndarray:
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


def _matrix(T: np.ndarray) -> list[list[float]]:
    return [[float(v) + 0.0 for v in row] for row in np.asarray(T, dtype=float)]


def _vector(v: Any) -> list[float]:
    return [float(x) + 0.0 for x in np.asarray(v, dtype=float).reshape(-1)]


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class BodySensorEstimate:
    """One rig sensor's pose in the body frame.

    * ``T_body_sensor`` (4, 4) = ``T_body_external @ T_external_sensor``;
    * ``covariance`` (6, 6): the total, ``relative_covariance + body_covariance`` (both over
      the right perturbation of ``T_body_sensor``, i.e. in the sensor frame);
    * ``relative_covariance``: from the relative calibration (its ``T_external_sensor``
      covariance; a right perturbation is unchanged by the left factor ``T_body_external``);
    * ``body_covariance``: the body frame's uncertainty mapped to the sensor,
      ``Ad(T_sensor_body) @ C_body @ Ad(T_sensor_body).T`` (zero when the body frame is exact);
    * ``std``: of x, y, z [m] and roll, pitch, yaw [deg] of ``T_body_sensor`` (first order);
    * ``held``: degrees of freedom the relative calibration held at their prior;
    * ``bounded``: directions only the field of view bounds (a 2D radar's roll, pitch, z about /
      along its own axes: offsets from the estimate, deg / m), as in the relative calibration,
      with their set ``bounded_set``; :attr:`bounded_values` gives them as absolute values of
      the body-frame pose table.
    """

    name: str
    kind: SensorKind
    frame_id: str
    T_body_sensor: np.ndarray
    covariance: np.ndarray
    std: Mapping[str, float]
    relative_covariance: np.ndarray
    body_covariance: np.ndarray
    held: tuple[str, ...] = ()
    bounded: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    bounded_set: Any = None

    @property
    def bounded_values(self) -> dict[str, tuple[float, float, float]]:
        """The bounded directions as absolute values of ``T_body_sensor``'s pose table:
        ``{key: (low, high, estimate)}`` (:func:`rigcal.problem.uncertainty.sensor_bounded_values`)."""
        from rigcal.problem.uncertainty import sensor_bounded_values

        return sensor_bounded_values(self.T_body_sensor, self.std, self.bounded, self.bounded_set)

    def __post_init__(self) -> None:
        for name in ("T_body_sensor", "covariance", "relative_covariance", "body_covariance"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        object.__setattr__(self, "std", dict(self.std))

    @property
    def xyz_m(self) -> np.ndarray:
        """(3,) the sensor's origin in the body frame [m]."""
        return self.T_body_sensor[:3, 3].copy()

    @property
    def rpy_deg(self) -> np.ndarray:
        """(3,) roll, pitch, yaw [deg] of ``T_body_sensor``."""
        return np.degrees(rpy_from_matrix(self.T_body_sensor[:3, :3]))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class AbsoluteResult:
    """Every rig sensor's pose in the vehicle body frame, and how it was found.

    * ``body_frame``: the body frame's name in files and TF trees (default ``base_link``);
    * ``external`` / ``external_frame``: the external scanner's sensor name and frame id;
    * ``method``: how the reference points were found (``circle``, ``single``, ``markers``);
    * ``body``: the :class:`~rigcal.absolute.body_frame.BodyFrame` in the external frame
      (``T_external_body``, ``origin``, wheelbase, tracks, reference points, ground plane);
    * ``body_covariance`` (6, 6): uncertainty of ``T_external_body`` over its right
      perturbation (body axes; rad, m); zeros when the body frame is taken as exact;
    * ``body_uncertainty``: where it came from: ``"fit residuals"`` (rim-circle fits and the
      ground fit), ``"label sigma"`` (the caller's ``label_sigma_m``) or ``"none"``;
    * ``sensors``: :class:`BodySensorEstimate` per rig sensor (the scanner itself excluded);
    * ``relative``: the relative calibration with the scanner as the reference;
    * ``warnings``: the relative calibration's, plus the body frame's.
    """

    body_frame: str
    external: str
    external_frame: str
    method: str
    body: BodyFrame
    body_covariance: np.ndarray
    body_uncertainty: str
    sensors: Mapping[str, BodySensorEstimate]
    relative: CalibrationResult
    warnings: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "body_covariance", _readonly(self.body_covariance))
        object.__setattr__(self, "sensors", dict(self.sensors))
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def origin(self) -> str:
        """The body frame's origin (one of :data:`rigcal.absolute.ORIGINS`)."""
        return self.body.origin

    @property
    def T_external_body(self) -> np.ndarray:
        """(4, 4) the body frame's pose in the external frame."""
        return np.array(self.body.T_external_body)

    @property
    def body_std(self) -> dict[str, float]:
        """Std of the body frame's origin along and rotation about its own axes (small
        angles): x, y, z [m], roll, pitch, yaw [deg]."""
        return tangent_std(self.body_covariance)

    def T_body_sensor(self, name: str) -> np.ndarray:
        """(4, 4) ``T_body_sensor`` of rig sensor ``name``; KeyError lists the sensors."""
        try:
            return np.array(self.sensors[name].T_body_sensor)
        except KeyError:
            raise KeyError(
                f"unknown sensor '{name}' (in the body frame: {', '.join(self.sensors)})"
            ) from None

    def transforms(self) -> dict[str, np.ndarray]:
        """``{sensor frame_id: T_body_sensor}`` - what a TF export of the body frame needs."""
        return {est.frame_id: np.array(est.T_body_sensor) for est in self.sensors.values()}

    def with_body_frame(self, name: str) -> "AbsoluteResult":
        """A copy whose body frame is called ``name``."""
        return replace(self, body_frame=name)

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-safe data (dicts, lists, floats, strings): the body frame's
        definition and diagnostics, per sensor ``T_body_sensor`` (4x4), ``xyz_m``,
        ``rpy_deg``, ``std`` and ``covariance``, and the relative calibration."""
        b = self.body
        body = {
            "name": self.body_frame,
            "origin": b.origin,
            "definition": BODY_FRAME_DEFINITIONS.get(b.origin, b.origin),
            "method": self.method,
            "external_sensor": self.external,
            "external_frame": self.external_frame,
            "T_external_body": _matrix(b.T_external_body),
            "uncertainty": self.body_uncertainty,
            "std": {k: float(v) for k, v in self.body_std.items()},
            "covariance": _matrix(self.body_covariance),
            "wheelbase_m": float(b.wheelbase_m),
            "track_rear_m": float(b.track_rear_m),
            "track_front_m": float(b.track_front_m),
            "ground_rms_m": float(b.ground.rms_m),
            "ground_inliers": int(np.count_nonzero(b.ground.inliers)),
            "reference_points_body": {k: _vector(v) for k, v in b.points_body.items()},
        }
        sensors = {
            name: {
                "kind": est.kind.value,
                "frame_id": est.frame_id,
                "T_body_sensor": _matrix(est.T_body_sensor),
                "xyz_m": _vector(est.xyz_m),
                "rpy_deg": _vector(est.rpy_deg),
                "std": {k: float(est.std[k]) for k in STD_KEYS},
                "covariance": _matrix(est.covariance),
                "held": list(est.held),
                "bounded": bounded_dict(est.bounded_values),
                "bounded_offsets": {d: [float(lo), float(hi)] for d, (lo, hi) in est.bounded.items()},
            }
            for name, est in self.sensors.items()
        }
        return {
            "convention": CONVENTION,
            "verdict": self.relative.verdict.to_dict() if self.relative.verdict is not None else None,
            "body_frame": body,
            "sensors": sensors,
            "relative": self.relative.to_dict(),
            "warnings": list(self.warnings),
        }
