"""Absolute calibration end to end: every rig sensor's pose in the vehicle body frame.

Paper, III-E and Fig. 5. The external scanner (a dense terrestrial lidar) is one more sensor of
the dataset: it detects the calibration boards like the rig's sensors do, and its scan of the
parked vehicle gives the body frame.

1. **relative calibration** with the external scanner as the reference
   (:func:`rigcal.problem.calibrate.calibrate`, ``mode`` FCPE by default): ``T_external_sensor``
   for every rig sensor - directly from the boards it shares with the scanner, or through the
   jointly calibrated rig when it shares boards only with other rig sensors;
2. **body frame** from the labels in the external scan (:mod:`rigcal.absolute.body_frame`):
   ground plane of ``scan_points``, wheel centres (rim circles or hub clicks) or markers,
   ``T_external_body``;
3. ``T_body_sensor = T_body_external @ T_external_sensor``.

Uncertainty. A calibration covariance is over the right perturbation ``T @ exp(xi)`` in the
sensor frame; a left factor does not change it, so the relative part carries over to
``T_body_sensor`` as it is. The body frame adds, independently (the labels and the scan are not
the board detections), ``Ad(T_sensor_body) C_body Ad(T_sensor_body)^T``, where ``C_body`` is
the covariance of ``T_external_body``'s right perturbation, propagated to first order (numeric
Jacobian of the frame construction) from

* each rim circle's centre: ``s^2 (J^T J)^-1`` of its geometric fit, ``s`` the fit's residual
  scale (or ``label_sigma_m`` when given);
* hub clicks and markers: ``label_sigma_m^2 / n`` per axis (no residuals to learn it from;
  without ``label_sigma_m`` the body frame is taken as exact and a warning says so);
* the ground plane: ``s^2 (J^T J)^-1`` of the plane fit over its inliers (tiny with 10^5
  points; floor unevenness is not modelled).

Bad input raises InputError before anything is solved, with nothing returned: an external
sensor not in the dataset (or a 2D radar), boards seen by the scanner but by no rig sensor
(they tie nothing to the rig; the message lists them - remove them or mark them ignored), a
sensor sharing no boards with any other, labels missing a wheel or marker, fewer than 3 rim
points, a scan without ground. Errors of the body-frame step (including its GeometryErrors -
collinear rim clicks, swapped wheels, no ground) are re-raised as InputError naming the labels'
source, since at this level they are faults of the labels or the scan.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from rigcal.absolute.body_frame import (
    ORIGINS,
    BodyFrame,
    body_frame_from_markers,
    body_frame_from_wheels,
)
from rigcal.absolute.labels import (
    MARKER_PREFIX,
    WHEEL_NAMES,
    GroundPlane,
    LabelSet,
    WheelCentre,
    fit_ground_plane,
    wheel_centres,
)
from rigcal.absolute.result import (
    DEFAULT_BODY_FRAME,
    AbsoluteResult,
    BodySensorEstimate,
)
from rigcal.dataset import Dataset, SensorKind
from rigcal.errors import ConfigError, InputError, RigcalError
from rigcal.geometry.fitting import plane_basis
from rigcal.geometry.se3 import invert, se3_log
from rigcal.geometry.so3 import hat, so3_exp
from rigcal.problem.calibrate import CalibrationOptions, calibrate
from rigcal.problem.result import CalibrationResult
from rigcal.problem.uncertainty import pose_std

__all__ = [
    "METHODS",
    "absolute_calibration",
    "adjoint",
    "body_frame_covariance",
    "compose_body",
]

log = logging.getLogger(__name__)

#: Reference-point methods: rim-circle fits, one hub click per wheel, markers by the wheels.
METHODS = ("circle", "single", "markers")


# ----------------------------------------------------------------------------- SE(3) helpers


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of a rigid (4, 4) ``T`` for twists ``(omega, v)``:
    ``T @ exp(xi) @ inv(T) = exp(adjoint(T) @ xi)``."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    A[3:, :3] = hat(t) @ R
    return A


def compose_body(
    T_external_body: np.ndarray,
    T_external_sensor: np.ndarray,
    relative_covariance: np.ndarray,
    body_covariance: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``T_body_sensor`` (4, 4) with its covariance (6, 6) and the body frame's share of it.

    ``relative_covariance``: of ``T_external_sensor``'s right perturbation (sensor frame);
    ``body_covariance``: of ``T_external_body``'s right perturbation (body frame), None = exact.
    With ``T_external_body <- T_external_body @ exp(e)``, ``T_body_sensor`` becomes
    ``T_body_sensor @ exp(-Ad(T_sensor_body) e)``.
    """
    T_bs = invert(T_external_body) @ np.asarray(T_external_sensor, dtype=float)
    rel = np.asarray(relative_covariance, dtype=float)
    if body_covariance is None:
        share = np.zeros((6, 6))
    else:
        A = adjoint(invert(T_bs))
        share = A @ np.asarray(body_covariance, dtype=float) @ A.T
        share = (share + share.T) / 2
    return T_bs, rel + share, share


# ----------------------------------------------------------------------------- body covariance


def _circle_centre_cov(points: np.ndarray, wc: WheelCentre, sigma_m: float | None) -> np.ndarray:
    """(3, 3) covariance of a rim circle's centre: ``s^2 (J^T J)^-1`` of the geometric fit
    (per point: the distance out of the circle's plane and in the plane from the circle;
    parameters centre, axis tilt (2), radius), centre block."""
    p = np.asarray(points, dtype=float)
    c0, n0, r0 = np.asarray(wc.centre), np.asarray(wc.normal), float(wc.radius_m)
    basis = plane_basis(n0)
    R0 = np.column_stack([basis[0], basis[1], n0])

    def res(x: np.ndarray) -> np.ndarray:
        n = R0 @ so3_exp(np.array([x[3], x[4], 0.0]))[:, 2]
        q = p - x[:3]
        h = q @ n
        rho = np.linalg.norm(q - h[:, None] * n, axis=1)
        return np.concatenate([h, rho - x[5]])

    x0 = np.array([*c0, 0.0, 0.0, r0])
    # keep the points the fit used: those near the fitted circle (a tyre click is dropped)
    r = res(x0).reshape(2, -1)
    dist = np.hypot(r[0], r[1])
    keep = dist < max(0.01, 5 * float(np.median(dist)) + 1e-6)
    p = p[keep]
    J = np.zeros((2 * p.shape[0], 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = 1e-7
        J[:, i] = (res(x0 + d) - res(x0 - d)) / 2e-7
    dof = J.shape[0] - 6
    if sigma_m is None:
        if dof <= 0:
            raise _NoResiduals(wc.name)
        s2 = float(np.sum(res(x0) ** 2) / dof)
    else:
        s2 = float(sigma_m) ** 2
    try:
        C = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        raise _NoResiduals(wc.name) from None
    return C[:3, :3]


class _NoResiduals(Exception):
    """A wheel's fit leaves no redundancy to estimate its noise from."""


def _ground_cov(points: np.ndarray, ground: GroundPlane) -> np.ndarray:
    """(3, 3) covariance of the ground's (tilt about e1, tilt about e2, offset) from its
    inliers: ``rms^2 (J^T J)^-1`` with per point ``[e1 . p, e2 . p, 1]``."""
    p = np.asarray(points, dtype=float)
    mask = np.asarray(ground.inliers, dtype=bool)
    if mask.shape != (p.shape[0],):  # a plane fitted to other points: its inliers are unknown
        return np.zeros((3, 3))
    p = p[mask]
    if p.shape[0] < 4:
        return np.zeros((3, 3))
    e = plane_basis(np.asarray(ground.normal))
    J = np.column_stack([p @ e[0], p @ e[1], np.ones(p.shape[0])])
    dist = p @ np.asarray(ground.normal) + ground.offset_m
    s2 = float(np.sum(dist**2) / max(p.shape[0] - 3, 1))
    try:
        return s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.zeros((3, 3))


def _ground_with(ground: GroundPlane, g: np.ndarray) -> GroundPlane:
    n0 = np.asarray(ground.normal)
    e = plane_basis(n0)
    n = n0 + g[0] * e[0] + g[1] * e[1]
    n = n / np.linalg.norm(n)
    return ground._replace(normal=n, offset_m=float(ground.offset_m + g[2]))


def body_frame_covariance(
    body: BodyFrame,
    centres_external: Mapping[str, np.ndarray],
    centre_covariances: Mapping[str, np.ndarray],
    ground_covariance: np.ndarray,
    *,
    markers: bool = False,
) -> np.ndarray:
    """(6, 6) covariance of ``body.T_external_body``'s right perturbation (body axes).

    First-order propagation through the frame construction (central differences of
    ``body_frame_from_wheels`` / ``_markers``) of independent reference-point covariances
    ``centre_covariances[wheel]`` (3, 3) at ``centres_external[wheel]`` (3,) and the ground's
    (tilt, tilt, offset) covariance (3, 3).
    """
    ground = body.ground
    T0_inv = invert(body.T_external_body)
    x0 = np.concatenate([np.asarray(centres_external[w], float) for w in WHEEL_NAMES])
    x0 = np.concatenate([x0, np.zeros(3)])

    def frame(x: np.ndarray) -> np.ndarray:
        pts = {w: x[3 * i : 3 * i + 3] for i, w in enumerate(WHEEL_NAMES)}
        g = _ground_with(ground, x[12:15])
        if markers:
            bf = body_frame_from_markers(pts, g, body.origin)
        else:
            bf = body_frame_from_wheels(pts, g, body.origin)
        return se3_log(T0_inv @ bf.T_external_body)

    steps = np.concatenate([np.full(12, 1e-6), np.full(3, 1e-7)])
    J = np.zeros((6, 15))
    for i in range(15):
        d = np.zeros(15)
        d[i] = steps[i]
        J[:, i] = (frame(x0 + d) - frame(x0 - d)) / (2 * steps[i])
    C_in = np.zeros((15, 15))
    for i, w in enumerate(WHEEL_NAMES):
        C_in[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = centre_covariances[w]
    C_in[12:, 12:] = ground_covariance
    C = J @ C_in @ J.T
    return (C + C.T) / 2


# ----------------------------------------------------------------------------- checks


def _check_dataset(dataset: Dataset, external: str) -> None:
    if not isinstance(dataset, Dataset):
        raise InputError(f"absolute calibration: expected a Dataset, got {type(dataset).__name__}")
    if not isinstance(external, str) or external not in dataset.names:
        raise InputError(
            f"absolute calibration: external scanner {external!r} is not a sensor of the "
            f"dataset (sensors: {', '.join(dataset.names)})"
        )
    ext = dataset.sensor(external)
    if ext.kind is SensorKind.RADAR:
        raise ConfigError(
            f"absolute calibration: external scanner '{external}' is a 2D radar; it must "
            "measure the boards in 3D (a lidar / terrestrial scanner)"
        )
    rig = [s for s in dataset.sensors if s.name != external]
    seen_by_rig = np.zeros(dataset.num_boards, dtype=bool)
    for s in rig:
        seen_by_rig |= s.valid
    lonely = np.flatnonzero(ext.valid & ~seen_by_rig)
    if lonely.size:
        raise InputError(
            f"absolute calibration: board(s) {lonely.tolist()} are seen by the external scanner "
            f"'{external}' but by no rig sensor ({', '.join(s.name for s in rig)}): such "
            "placements tie nothing to the rig; remove them or mark them ignored for "
            f"'{external}'"
        )
    if not np.any(ext.valid & seen_by_rig):
        raise InputError(
            f"absolute calibration: the external scanner '{external}' shares no boards with "
            f"the rig ({', '.join(s.name for s in rig)}): it detects "
            f"{int(ext.valid.sum())} board(s), none of them seen by a rig sensor"
        )
    for s in rig:
        others = np.zeros(dataset.num_boards, dtype=bool)
        for o in dataset.sensors:
            if o.name != s.name:
                others |= o.valid
        if not np.any(s.valid & others):
            raise InputError(
                f"absolute calibration: rig sensor '{s.name}' shares no boards with the "
                f"external scanner '{external}' or any other rig sensor (it detects "
                f"{int(s.valid.sum())} board(s): {np.flatnonzero(s.valid).tolist()}); it cannot "
                "be placed in the body frame - record boards it sees together with the others"
            )


def _check_args(method: str, origin: str, body_frame: str, label_sigma_m: float | None) -> None:
    if method not in METHODS:
        raise ConfigError(
            f"absolute calibration: method must be one of {', '.join(METHODS)}, got {method!r}"
        )
    if origin not in ORIGINS:
        raise ConfigError(
            f"absolute calibration: origin must be one of {', '.join(ORIGINS)}, got {origin!r}"
        )
    if not isinstance(body_frame, str) or not body_frame or any(c.isspace() for c in body_frame):
        raise ConfigError(
            "absolute calibration: body_frame must be a non-empty name without whitespace, "
            f"got {body_frame!r}"
        )
    if label_sigma_m is not None:
        ok = isinstance(label_sigma_m, (int, float)) and not isinstance(label_sigma_m, bool)
        if not (ok and np.isfinite(label_sigma_m) and label_sigma_m > 0):
            raise ConfigError(
                f"absolute calibration: label_sigma_m must be a positive number, got "
                f"{label_sigma_m!r}"
            )


# ----------------------------------------------------------------------------- body frame


def _body(
    labels: LabelSet,
    scan_points: np.ndarray | None,
    method: str,
    origin: str,
    ground_plane: GroundPlane | None,
    up_hint: Sequence[float],
    label_sigma_m: float | None,
    rng: np.random.Generator,
) -> tuple[BodyFrame, np.ndarray, str, list[str]]:
    """The body frame, its covariance, where that came from, and warnings."""
    if not isinstance(labels, LabelSet):
        raise InputError(
            f"absolute calibration: labels must be a LabelSet, got {type(labels).__name__}"
        )
    src = labels.source
    if ground_plane is None:
        if scan_points is None:
            raise InputError(
                f"absolute calibration: give the external scan's points (for the ground plane) "
                f"with the labels from {src}"
            )
        pts = np.asarray(scan_points, dtype=float)
        ground = fit_ground_plane(pts, up_hint=up_hint, rng=rng, source=f"{src}: external scan")
    else:
        pts = None if scan_points is None else np.asarray(scan_points, dtype=float)
        ground = ground_plane
    warnings: list[str] = []
    if method == "markers":
        markers = {k: v for k, v in labels.markers.items()}
        body = body_frame_from_markers(markers, ground, origin)
        centres = {w: np.asarray(markers[MARKER_PREFIX + w]) for w in WHEEL_NAMES}
        counts = {w: labels.points[MARKER_PREFIX + w].shape[0] for w in WHEEL_NAMES}
    else:
        wc = wheel_centres(labels, method, rng=rng)
        body = body_frame_from_wheels(wc, ground, origin)
        centres = {w: np.asarray(wc[w].centre) for w in WHEEL_NAMES}
        counts = {w: labels.points[w].shape[0] for w in WHEEL_NAMES}
    # the body frame's uncertainty
    cov_pts: dict[str, np.ndarray] = {}
    source = "label sigma" if label_sigma_m is not None else "fit residuals"
    if method == "circle":
        try:
            for w in WHEEL_NAMES:
                cov_pts[w] = _circle_centre_cov(labels.points[w], wc[w], label_sigma_m)
        except _NoResiduals as exc:
            warnings.append(
                f"body frame uncertainty not estimated: wheel '{exc}' has too few rim points to "
                "estimate the click noise from; pass label_sigma_m (the body frame is taken as "
                "exact)"
            )
            cov_pts = {}
    elif label_sigma_m is not None:
        cov_pts = {w: np.eye(3) * label_sigma_m**2 / counts[w] for w in WHEEL_NAMES}
    else:
        what = "hub clicks" if method == "single" else "markers"
        warnings.append(
            f"body frame uncertainty not included: {what} carry no residuals to estimate their "
            "noise from; pass label_sigma_m (the body frame is taken as exact)"
        )
    if not cov_pts:
        return body, np.zeros((6, 6)), "none", warnings
    g_cov = _ground_cov(pts, ground) if pts is not None else np.zeros((3, 3))
    cov = body_frame_covariance(body, centres, cov_pts, g_cov, markers=method == "markers")
    return body, cov, source, warnings


# ----------------------------------------------------------------------------- pipeline


def absolute_calibration(
    dataset: Dataset,
    external: str,
    labels: LabelSet,
    scan_points: np.ndarray | None,
    method: str = "circle",
    origin: str = "rear_axle",
    mode: str = "fcpe",
    *,
    body_frame: str = DEFAULT_BODY_FRAME,
    ground_plane: GroundPlane | None = None,
    up_hint: Sequence[float] = (0.0, 0.0, 1.0),
    label_sigma_m: float | None = None,
    options: CalibrationOptions | None = None,
    rng: np.random.Generator | int = 0,
) -> AbsoluteResult:
    """Every rig sensor's ``T_body_sensor`` with its covariance (see the module docstring).

    * ``dataset``: board detections of the rig's sensors **and** of the external scanner
      ``external`` (a sensor of the dataset, its frame = the external frame of ``labels`` and
      ``scan_points``);
    * ``labels``: wheel labels (rim clicks for ``method='circle'``, one hub click for
      ``'single'``) or markers ``marker_rear_left`` ... (``'markers'``), external frame [m];
    * ``scan_points`` (N, 3): the external scan of the vehicle and the floor around it
      (external frame [m]) for the ground plane; may be None when ``ground_plane`` is given;
    * ``origin``: ``rear_axle``, ``front_axle`` or ``wheelbase_centre``;
    * ``mode``: the relative calibration's configuration (``fcpe``, ``mcpe``, ``pse``),
      with the scanner as its reference; ``options`` sets the rest of
      :class:`~rigcal.problem.calibrate.CalibrationOptions` (its mode and reference are
      replaced by ``mode`` and ``external``);
    * ``body_frame``: the body frame's name in files and TF trees;
    * ``label_sigma_m``: the labels' noise per axis [m] if known (else rim-circle residuals
      give it; hub clicks and markers without it leave the body frame exact);
    * ``up_hint``: "up" in the external frame (a levelled scanner: its z).

    Raises InputError / ConfigError for bad input (nothing is returned), ConvergenceError when
    the relative calibration does not converge.
    """
    _check_args(method, origin, body_frame, label_sigma_m)
    _check_dataset(dataset, external)
    if options is not None and options.reference not in (None, external):
        raise ConfigError(
            f"absolute calibration: options.reference is '{options.reference}', but the "
            f"reference must be the external scanner '{external}'"
        )
    gen = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    try:
        body, body_cov, body_src, warnings = _body(
            labels, scan_points, method, origin, ground_plane, up_hint, label_sigma_m, gen
        )
    except RigcalError as exc:
        if isinstance(exc, InputError) and str(exc).startswith("absolute calibration:"):
            raise
        src = labels.source if isinstance(labels, LabelSet) else "labels"
        detail = str(exc) if src in str(exc) else f"{src}: {exc}"
        cls = type(exc) if isinstance(exc, InputError) else InputError
        raise cls(
            f"absolute calibration: body frame ({method} labels, external scan of "
            f"'{external}'): {detail}"
        ) from exc
    opts = replace(options or CalibrationOptions(), mode=mode, reference=external)
    try:
        relative = calibrate(dataset, opts)
    except InputError as exc:
        raise type(exc)(
            f"absolute calibration with external scanner '{external}' as the reference: {exc}"
        ) from exc
    return _assemble(dataset, external, method, body_frame, body, body_cov, body_src,
                     warnings, relative)


def _assemble(
    dataset: Dataset,
    external: str,
    method: str,
    body_frame: str,
    body: BodyFrame,
    body_cov: np.ndarray,
    body_src: str,
    warnings: list[str],
    relative: CalibrationResult,
) -> AbsoluteResult:
    sensors = {}
    exact = body_src == "none"
    for s in dataset.sensors:
        if s.name == external:
            continue
        est = relative.sensors[s.name]
        T_bs, cov, share = compose_body(
            body.T_external_body, est.T_reference_sensor, est.covariance,
            None if exact else body_cov,
        )
        sensors[s.name] = BodySensorEstimate(
            name=s.name,
            kind=s.kind,
            frame_id=est.frame_id,
            T_body_sensor=T_bs,
            covariance=cov,
            std=pose_std(T_bs, cov),
            relative_covariance=est.covariance,
            body_covariance=share,
            held=est.held,
            bounded=est.bounded,
            bounded_set=est.bounded_set,
        )
    log.info(
        "absolute calibration: body frame wheelbase %.3f m, tracks %.3f / %.3f m, ground rms "
        "%.1f mm; %d sensors", body.wheelbase_m, body.track_rear_m, body.track_front_m,
        1000 * body.ground.rms_m, len(sensors),
    )
    return AbsoluteResult(
        body_frame=body_frame,
        external=external,
        external_frame=relative.sensors[external].frame_id,
        method=method,
        body=body,
        body_covariance=body_cov,
        body_uncertainty=body_src,
        sensors=sensors,
        relative=relative,
        warnings=tuple(relative.warnings) + tuple(warnings),
    )
