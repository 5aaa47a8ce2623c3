"""The vehicle body frame in the external frame, from wheel centres or markers and the ground.

Body frame (paper, section IV-B): origin at the centre of the rear axle projected onto the
ground, X forward (toward the front axle), Y toward the left rear wheel, Z up, perpendicular
to the ground. Construction, all in the external frame:

1. the axle centres: the mean of the two wheel centres (or of the two markers) of each axle,
   projected onto the ground plane;
2. ``Z`` = the ground normal (pointing up);
3. ``X`` = the direction from the rear to the front axle centre (it lies in the ground plane
   because both points do);
4. ``Y = Z x X``; the left wheels must lie on +Y and the right wheels on -Y, else the labels
   are swapped (left/right or rear/front) and GeometryError says which wheel is off;
5. the origin: the rear axle centre (``origin='rear_axle'``, default), the front axle centre
   (``'front_axle'``) or their midpoint (``'wheelbase_centre'``).

The result's ``T_external_body`` maps body-frame points into the external frame; with a
sensor's pose in the external frame (from a relative calibration that includes the external
scanner), :func:`sensor_in_body` gives ``T_body_sensor = T_body_external @ T_external_sensor``.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from rigcal.absolute.labels import (
    MARKER_PREFIX,
    WHEEL_NAMES,
    GroundPlane,
    LabelSet,
    WheelCentre,
    fit_ground_plane,
    wheel_centres,
)
from rigcal.errors import ConfigError, GeometryError, InputError
from rigcal.geometry.align import kabsch
from rigcal.geometry.fitting import fit_plane_lstsq
from rigcal.geometry.frames import Transform
from rigcal.geometry.se3 import from_rt, invert

__all__ = [
    "BODY_FRAME",
    "BodyFrame",
    "ORIGINS",
    "body_frame_from_labels",
    "body_frame_from_markers",
    "body_frame_from_reference_points",
    "body_frame_from_wheels",
    "sensor_in_body",
    "sensors_in_body",
]

BODY_FRAME = "body"
#: Allowed body-frame origins.
ORIGINS = ("rear_axle", "front_axle", "wheelbase_centre")
_MIN_WHEELBASE_M = 0.3
_MIN_HALF_TRACK_M = 0.1


class BodyFrame(NamedTuple):
    """The body frame found in the external frame.

    * ``T_external_body`` (4, 4): maps body-frame points into the external frame;
    * ``origin``: one of :data:`ORIGINS`;
    * ``wheelbase_m``: distance between the axle centres on the ground;
    * ``track_rear_m``, ``track_front_m``: lateral (Y) distance between the left and right
      wheel centres (or markers) of each axle;
    * ``points_body``: the reference points used (wheel centres or markers), (3,) each in the
      body frame, keyed by wheel name; their Z is the height above the ground;
    * ``ground``: the ground plane used, in the external frame.
    """

    T_external_body: np.ndarray
    origin: str
    wheelbase_m: float
    track_rear_m: float
    track_front_m: float
    points_body: Mapping[str, np.ndarray]
    ground: GroundPlane

    @property
    def T_body_external(self) -> np.ndarray:
        """(4, 4) inverse of ``T_external_body``."""
        return invert(self.T_external_body)

    def transform(self, external_frame: str = "external") -> Transform:
        """``T_external_body`` as a frame-checked :class:`~rigcal.geometry.Transform`."""
        return Transform(self.T_external_body, external_frame, BODY_FRAME)


def _vec3(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected a finite (3,) point, got shape {np.asarray(v).shape}")
    return a


def _centres(points: Mapping[str, object], what: str) -> dict[str, np.ndarray]:
    out = {}
    for w in WHEEL_NAMES:
        if w not in points:
            present = ", ".join(sorted(points)) or "none"
            raise InputError(f"{what}: missing '{w}'; present: {present}")
        v = points[w]
        if isinstance(v, WheelCentre):
            v = v.centre
        out[w] = _vec3(v, f"{what} '{w}'")
    return out


def _check_ground(ground: GroundPlane) -> tuple[np.ndarray, float]:
    if not isinstance(ground, GroundPlane):
        raise InputError(f"ground_plane: expected a GroundPlane, got {type(ground).__name__}")
    n = _vec3(ground.normal, "ground_plane.normal")
    norm = float(np.linalg.norm(n))
    if abs(norm - 1.0) > 1e-6:
        raise InputError(f"ground_plane.normal must be a unit vector, got norm {norm:.6g}")
    return n, float(ground.offset_m)


def _frame(
    c: dict[str, np.ndarray], n: np.ndarray, d: float, origin: str, what: str, ground: GroundPlane
) -> BodyFrame:
    if origin not in ORIGINS:
        raise ConfigError(f"origin must be one of {', '.join(ORIGINS)}, got {origin!r}")

    def proj(p: np.ndarray) -> np.ndarray:
        return p - (p @ n + d) * n

    rear = proj((c["rear_left"] + c["rear_right"]) / 2)
    front = proj((c["front_left"] + c["front_right"]) / 2)
    x = front - rear
    wheelbase = float(np.linalg.norm(x))
    if wheelbase < _MIN_WHEELBASE_M:
        raise GeometryError(
            f"{what}: the rear and front axle centres coincide on the ground "
            f"({1000 * wheelbase:.0f} mm apart, need {1000 * _MIN_WHEELBASE_M:.0f} mm): "
            "check the rear_* and front_* labels"
        )
    X = x / wheelbase
    Z = n
    Y = np.cross(Z, X)
    axle = {"rear_left": rear, "rear_right": rear, "front_left": front, "front_right": front}
    for w in WHEEL_NAMES:
        side = float((c[w] - axle[w]) @ Y)
        want_left = w.endswith("left")
        if (side > _MIN_HALF_TRACK_M) != want_left or abs(side) < _MIN_HALF_TRACK_M:
            raise GeometryError(
                f"{what}: '{w}' lies {abs(side):.3f} m to the "
                f"{'left' if side > 0 else 'right'} of the "
                f"rear->front axis (seen from above the ground); the left wheels must be on "
                f"the left and the right wheels on the right, at least {_MIN_HALF_TRACK_M} m "
                "from it: are left/right or rear/front swapped, or is the ground normal "
                "pointing down?"
            )
    o = {"rear_axle": rear, "front_axle": front, "wheelbase_centre": (rear + front) / 2}[origin]
    T = from_rt(np.column_stack([X, Y, Z]), o)
    T.setflags(write=False)
    T_be = invert(T)
    pts = {}
    for w in WHEEL_NAMES:
        p = T_be[:3, :3] @ c[w] + T_be[:3, 3]
        p.setflags(write=False)
        pts[w] = p
    return BodyFrame(
        T,
        origin,
        wheelbase,
        float(pts["rear_left"][1] - pts["rear_right"][1]),
        float(pts["front_left"][1] - pts["front_right"][1]),
        MappingProxyType(pts),
        ground,
    )


def body_frame_from_wheels(
    wheel_centres: Mapping[str, object],
    ground_plane: GroundPlane,
    origin: str = "rear_axle",
) -> BodyFrame:
    """The body frame from the four wheel centres (external frame; (3,) arrays or
    :class:`~rigcal.absolute.labels.WheelCentre`, keyed by :data:`WHEEL_NAMES`) and the ground.

    Raises InputError for a missing wheel, GeometryError for coincident axles or wheels on the
    wrong side of the rear->front axis, ConfigError for an unknown ``origin``.
    """
    c = _centres(wheel_centres, "wheel centres")
    n, d = _check_ground(ground_plane)
    return _frame(c, n, d, origin, "body frame from wheels", ground_plane)


def body_frame_from_markers(
    markers: Mapping[str, object],
    ground_plane: GroundPlane | None = None,
    origin: str = "rear_axle",
    *,
    up_hint: Sequence[float] = (0.0, 0.0, 1.0),
) -> BodyFrame:
    """The body frame from four markers on the ground next to the wheels, below the axles.

    ``markers``: (3,) positions in the external frame keyed by wheel name, with or without the
    ``marker_`` prefix (``marker_rear_left`` or ``rear_left``). The axle centres are the
    midpoints of each axle's two markers, projected onto ``ground_plane``; without a ground
    plane the least-squares plane through the four markers is used (its normal along
    ``up_hint``) - then marker height errors tilt Z too.
    """
    named = {}
    for k, v in markers.items():
        key = k[len(MARKER_PREFIX):] if k.startswith(MARKER_PREFIX) else k
        named[key] = v
    try:
        c = _centres(named, "markers")
    except InputError as exc:
        raise InputError(str(exc).replace("missing '", f"missing '{MARKER_PREFIX}")) from exc
    if ground_plane is None:
        pts = np.stack([c[w] for w in WHEEL_NAMES])
        try:
            fit = fit_plane_lstsq(pts)
        except GeometryError as exc:
            raise GeometryError(
                f"markers: no ground plane through the four markers: {exc}"
            ) from exc
        up = _vec3(up_hint, "up_hint")
        nrm, d = fit.normal, fit.d
        if nrm @ up < 0:
            nrm, d = -nrm, -d
        ground_plane = GroundPlane(nrm, float(d), np.ones(4, dtype=bool), fit.rms, float("nan"))
    n, d = _check_ground(ground_plane)
    return _frame(c, n, d, origin, "body frame from markers", ground_plane)


def body_frame_from_labels(
    labels: LabelSet,
    scan_points: np.ndarray | None = None,
    *,
    method: str = "auto",
    origin: str = "rear_axle",
    ground_plane: GroundPlane | None = None,
    ground_threshold_m: float = 0.02,
    up_hint: Sequence[float] = (0.0, 0.0, 1.0),
    rng: np.random.Generator | int = 0,
) -> BodyFrame:
    """The whole pipeline: ground plane of ``scan_points`` (N, 3) (unless ``ground_plane`` is
    given), then the body frame from the wheel labels, or, when ``labels`` has no wheels, from
    the markers ``marker_rear_left`` ... ``marker_front_right``.

    ``method`` is the wheel-centre method ('auto', 'single', 'circle', see
    :func:`~rigcal.absolute.labels.wheel_centre`).
    """
    gen = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    if ground_plane is None:
        if scan_points is None:
            raise InputError(f"{labels.source}: give the scan points or a ground plane")
        ground_plane = fit_ground_plane(
            scan_points, threshold_m=ground_threshold_m, up_hint=up_hint, rng=gen,
            source=f"{labels.source}: scan",
        )
    if not labels.wheels and labels.markers:
        return body_frame_from_markers(labels.markers, ground_plane, origin)
    centres = wheel_centres(labels, method, rng=gen)
    return body_frame_from_wheels(centres, ground_plane, origin)


def body_frame_from_reference_points(
    points_external: Mapping[str, object], points_body: Mapping[str, object]
) -> np.ndarray:
    """``T_external_body`` from >= 3 named reference points known in both frames (e.g. from a
    CAD model of the body), by Kabsch; names present in only one mapping are ignored.
    """
    names = [k for k in points_body if k in points_external]
    if len(names) < 3:
        raise InputError(
            f"reference points: need at least 3 names known in both frames, got {len(names)} "
            f"({', '.join(names) or 'none'})"
        )
    a = np.stack([_vec3(points_body[k], f"reference point '{k}' (body)") for k in names])
    b = np.stack([_vec3(points_external[k], f"reference point '{k}' (external)") for k in names])
    try:
        return kabsch(a, b)
    except GeometryError as exc:
        raise GeometryError(f"reference points {', '.join(names)}: {exc}") from exc


def sensor_in_body(T_external_body: np.ndarray, T_external_sensor: np.ndarray) -> np.ndarray:
    """``T_body_sensor = T_body_external @ T_external_sensor`` (both (4, 4))."""
    Teb = np.asarray(T_external_body, dtype=float)
    Tes = np.asarray(T_external_sensor, dtype=float)
    if Teb.shape != (4, 4) or Tes.shape != (4, 4):
        raise InputError(
            f"sensor_in_body: expected two (4, 4) transforms, got {Teb.shape} and {Tes.shape}"
        )
    return invert(Teb) @ Tes


def sensors_in_body(
    T_external_body: np.ndarray,
    T_external_reference: np.ndarray,
    T_reference_sensors: Mapping[str, np.ndarray],
) -> dict[str, np.ndarray]:
    """``T_body_sensor`` for every sensor of a relative calibration.

    ``T_external_reference``: the reference sensor's pose in the external frame (e.g. from
    boards seen by both the scanner and the reference sensor); ``T_reference_sensors[name]``:
    each sensor's pose in the reference frame.
    """
    T_body_ref = sensor_in_body(T_external_body, T_external_reference)
    out = {}
    for name, T in T_reference_sensors.items():
        m = np.asarray(T, dtype=float)
        if m.shape != (4, 4):
            raise InputError(f"sensor '{name}': expected a (4, 4) transform, got {m.shape}")
        out[name] = T_body_ref @ m
    return out
