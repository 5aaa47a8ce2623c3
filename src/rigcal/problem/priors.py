"""Soft priors around a sensor's nominal mounting: how far the calibration may move it.

A **mounting prior** gives 1-sigma tolerances of some directions of a sensor's nominal pose
(``T_reference_sensor`` from ``--initial``): ``x_m``, ``y_m``, ``z_m`` along and ``roll_deg``,
``pitch_deg``, ``yaw_deg`` about **the sensor's own axes** - the directions of the right
perturbation ``T = T_nominal exp(xi)``, the same directions as the reported covariance and a
2D radar's bounded directions (its z along, roll and pitch about its own axes). A camera's own
axes are its optical frame (z along the optical axis).

In the problem (:mod:`rigcal.problem.solver`) a prior is a whitened residual block
``log(T_nominal^-1 T) / sigma`` bound to the sensor's pose block; a direction without a
tolerance has ``sigma = inf`` (no residual), and a tolerance of **0** holds the direction at
the nominal value exactly (the pose block's degree of freedom is not free): ``--hold-radar-plane``
is the prior ``{z_m: 0, roll_deg: 0, pitch_deg: 0}`` on every 2D radar, the limit of a tiny
tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from rigcal.errors import ConfigError, InputError

#: prior keys in the tangent order of a right perturbation (rotation first)
PRIOR_KEYS = ("roll_deg", "pitch_deg", "yaw_deg", "x_m", "y_m", "z_m")
#: a 2D radar's z, roll and pitch held (``--hold-radar-plane``)
HOLD_RADAR_PLANE = {"roll_deg": 0.0, "pitch_deg": 0.0, "z_m": 0.0}


def check_prior(value: Any, where: str) -> dict[str, float]:
    """A prior mapping ``{key: tolerance}`` with keys from :data:`PRIOR_KEYS` and finite
    tolerances >= 0 (m, deg), in :data:`PRIOR_KEYS` order; InputError naming ``where`` else."""
    if not isinstance(value, Mapping) or not value:
        raise InputError(
            f"{where}: expected a mapping of tolerances, e.g. {{z_m: 0.01, roll_deg: 0.5}} "
            f"(keys: {', '.join(PRIOR_KEYS)}), got {value!r}"
        )
    out = {}
    for key, tol in value.items():
        if key not in PRIOR_KEYS:
            raise InputError(f"{where}: unknown direction {key!r} (expected one of: {', '.join(PRIOR_KEYS)})")
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not math.isfinite(tol) or tol < 0:
            unit = "m" if key.endswith("_m") else "deg"
            raise InputError(f"{where}.{key}: expected a tolerance in {unit} >= 0 (0 holds it), got {tol!r}")
        out[key] = float(tol)
    return {k: out[k] for k in PRIOR_KEYS if k in out}


def parse_prior_text(text: str, where: str = "--prior") -> tuple[str | None, dict[str, float]]:
    """``[SENSOR:]key=value,key=value`` (the command line's ``--prior``) as (sensor or None,
    prior mapping)."""
    sensor = None
    body = text.strip()
    head, sep, rest = body.partition(":")
    if sep and "=" not in head:
        sensor, body = head.strip(), rest
        if not sensor:
            raise InputError(f"{where} {text!r}: empty sensor name before ':'")
    items: dict[str, Any] = {}
    for part in body.split(","):
        key, eq, val = part.partition("=")
        if not eq:
            raise InputError(f"{where} {text!r}: expected [SENSOR:]key=value,... e.g. z_m=0.01,roll_deg=0.5")
        try:
            items[key.strip()] = float(val)
        except ValueError:
            raise InputError(f"{where} {text!r}: {key.strip()}: expected a number, got {val.strip()!r}") from None
    return sensor, check_prior(items, f"{where} {text!r}")


def prior_sigma(prior: Mapping[str, float]) -> np.ndarray:
    """(6,) tangent-order sigma [rad, rad, rad, m, m, m] of a prior mapping: inf where the
    prior says nothing, 0 where it holds the direction."""
    out = np.full(6, np.inf)
    for i, key in enumerate(PRIOR_KEYS):
        if key in prior:
            v = float(prior[key])
            out[i] = math.radians(v) if key.endswith("_deg") else v
    return out


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class SensorPrior:
    """A sensor's nominal pose ``T_nominal`` (``T_reference_sensor``, (4, 4)) and its tolerances
    ``tolerance`` (:data:`PRIOR_KEYS` subset, m / deg; 0 holds the direction)."""

    sensor: str
    T_nominal: np.ndarray
    tolerance: Mapping[str, float]

    def __post_init__(self) -> None:
        T = np.array(self.T_nominal, dtype=float)
        T.setflags(write=False)
        object.__setattr__(self, "T_nominal", T)
        object.__setattr__(self, "tolerance", dict(self.tolerance))

    @property
    def sigma(self) -> np.ndarray:
        """(6,) tangent-order sigma [rad, m]; inf: no prior; 0: held."""
        return prior_sigma(self.tolerance)

    @property
    def held(self) -> np.ndarray:
        """(6,) bool: directions held exactly (tolerance 0)."""
        return self.sigma == 0.0

    @property
    def soft(self) -> bool:
        """True when some direction has a finite, positive tolerance (a residual block)."""
        s = self.sigma
        return bool(np.any(np.isfinite(s) & (s > 0)))


def merge_priors(
    names: tuple[str, ...],
    reference: str,
    manifest: Mapping[str, Mapping[str, float]],
    default: Mapping[str, float] | None,
    per_sensor: Mapping[str, Mapping[str, float]] | None,
    held: Mapping[str, Mapping[str, float]] | None = None,
) -> dict[str, dict[str, float]]:
    """Each non-reference sensor's tolerances: the command line's per-sensor prior, else the
    manifest's, else the command line's default; ``held`` (e.g. :data:`HOLD_RADAR_PLANE` for a
    2D radar) overrides its keys. Sensors with no tolerance are left out. ConfigError for a
    per-sensor prior on an unknown sensor or on the reference (its pose is fixed)."""
    per_sensor = dict(per_sensor or {})
    for name in per_sensor:
        if name not in names:
            raise ConfigError(f"--prior {name}:...: unknown sensor '{name}' (sensors: {', '.join(names)})")
        if name == reference:
            raise ConfigError(f"--prior {name}:...: '{name}' is the reference sensor; its pose is fixed")
    out = {}
    for name in names:
        if name == reference:
            continue
        tol = dict(per_sensor.get(name) or manifest.get(name) or default or {})
        tol.update((held or {}).get(name, {}))
        if tol:
            out[name] = {k: tol[k] for k in PRIOR_KEYS if k in tol}
    return out


__all__ = [
    "HOLD_RADAR_PLANE",
    "PRIOR_KEYS",
    "SensorPrior",
    "check_prior",
    "merge_priors",
    "parse_prior_text",
    "prior_sigma",
]
