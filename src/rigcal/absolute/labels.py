"""Body reference points in an external scan: labels files, wheel centres, markers, ground plane.

All coordinates here are in the **external** frame (the scanner's, e.g. a Leica P40 point
cloud), in metres. The paper (section III-E, IV-B) finds the body frame from reference points
on the vehicle picked in that scan, in one of three ways:

* **single-point labels** - a person clicks one point per wheel: the wheel centre (hub);
* **rim labels** - a person clicks N >= 3 points on each wheel's rim; a robust 3D circle fit
  (:func:`fit_circle_3d`) gives the rim's centre, radius and axis;
* **markers** - targets the scanner detects, placed on the ground next to the wheels below the
  axles (``marker_rear_left`` ... ``marker_front_right``).

The ground plane comes from a RANSAC plane fit on the lower part of the scan
(:func:`fit_ground_plane`), its normal pointing up.

Labels files
------------
YAML: a mapping from label name to one point ``[x, y, z]`` or a list of points::

    rear_left:  [[0.12, 3.41, -1.18], [0.31, 3.40, -1.02], ...]   # rim points
    rear_right: [2.95, 1.12, -1.17]                                # one click: the hub
    marker_rear_left: [0.20, 3.80, -1.49]

CSV: one point per row, ``label,x,y,z``; an optional header row ``label,x,y,z``; blank lines
and lines starting with ``#`` are skipped; a label may repeat (one row per rim point).

Label names: the wheels ``rear_left``, ``rear_right``, ``front_left``, ``front_right``, and
markers ``marker_<name>`` (the body frame from markers uses ``marker_rear_left`` ...
``marker_front_right``). Any other name is refused, so that a typo does not silently drop a
wheel.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
from scipy.optimize import least_squares

from rigcal.errors import ConfigError, GeometryError, InputError
from rigcal.geometry.fitting import (
    fit_circle_2d,
    fit_plane_lstsq,
    plane_basis,
    ransac_circle_2d,
    ransac_plane,
    to_plane_2d,
)
from rigcal.geometry.so3 import so3_exp
from rigcal.io._text import is_number, load_yaml, type_name
from rigcal.io.limits import MAX_ABS

__all__ = [
    "Circle3D",
    "GroundPlane",
    "LabelSet",
    "MARKER_PREFIX",
    "WHEEL_NAMES",
    "WheelCentre",
    "fit_circle_3d",
    "fit_ground_plane",
    "format_labels_csv",
    "format_labels_yaml",
    "parse_labels_csv",
    "parse_labels_yaml",
    "wheel_centre",
    "wheel_centres",
]

#: The four wheels, in the order every result uses.
WHEEL_NAMES: tuple[str, ...] = ("rear_left", "rear_right", "front_left", "front_right")
#: Label names starting with this are markers.
MARKER_PREFIX = "marker_"
_MARKER_RE = re.compile(r"^marker_[A-Za-z0-9_]+$")
_METHODS = ("auto", "single", "circle")


# ----------------------------------------------------------------------------- labels


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class LabelSet:
    """Labelled points of an external scan: ``points[label]`` is a read-only (N, 3) array [m]
    in the external frame (N = 1 for a single click or a marker). ``source`` names the file."""

    points: Mapping[str, np.ndarray]
    source: str = "labels"

    def __post_init__(self) -> None:
        checked: dict[str, np.ndarray] = {}
        for name, pts in dict(self.points).items():
            _check_label_name(name, self.source)
            p = np.asarray(pts, dtype=float)
            if p.ndim == 1:
                p = p[None, :]
            if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
                raise InputError(
                    f"{self.source}: label '{name}': expected (N, 3) points, got shape {p.shape}"
                )
            if not np.all(np.isfinite(p)):
                raise InputError(f"{self.source}: label '{name}' has non-finite coordinates")
            checked[name] = _readonly(p)
        object.__setattr__(self, "points", MappingProxyType(checked))

    @property
    def wheels(self) -> tuple[str, ...]:
        """The wheel labels present, in :data:`WHEEL_NAMES` order."""
        return tuple(w for w in WHEEL_NAMES if w in self.points)

    @property
    def markers(self) -> Mapping[str, np.ndarray]:
        """Marker positions (3,) by label name (the mean of a marker's points)."""
        return MappingProxyType(
            {
                k: _readonly(v.mean(axis=0))
                for k, v in self.points.items()
                if k.startswith(MARKER_PREFIX)
            }
        )

    def require(self, names: Sequence[str], what: str = "wheel") -> None:
        """Raise InputError naming the first missing label and listing what is present."""
        missing = [n for n in names if n not in self.points]
        if missing:
            present = ", ".join(sorted(self.points)) or "no labels"
            raise InputError(
                f"{self.source}: missing {what} '{missing[0]}'"
                + (f" (and {', '.join(missing[1:])})" if len(missing) > 1 else "")
                + f"; present: {present}"
            )


def _check_label_name(name: Any, source: str) -> None:
    if not isinstance(name, str):
        raise InputError(f"{source}: label names must be strings, got {type_name(name)} {name!r}")
    if name in WHEEL_NAMES or _MARKER_RE.match(name):
        return
    raise InputError(
        f"{source}: unknown label '{name}': expected one of {', '.join(WHEEL_NAMES)} "
        f"or '{MARKER_PREFIX}<name>'"
    )


def _point(value: Any, where: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        n = len(value) if isinstance(value, (list, tuple)) else None
        raise InputError(
            f"{where}: expected a point [x, y, z]"
            + (f", got {n} values" if n is not None else f", got {type_name(value)}")
        )
    out = []
    for axis, v in zip("xyz", value):
        if not is_number(v) or not abs(float(v)) <= MAX_ABS["m"]:
            raise InputError(
                f"{where}: {axis} must be a finite number, got {v!r} (within ±{MAX_ABS['m']:g} m)"
            )
        out.append(float(v))
    return out


def parse_labels_yaml(
    text: str, source: str = "labels.yaml", required: Sequence[str] = ()
) -> LabelSet:
    """Labels from YAML text (see the module docstring); errors name ``source`` and the label.

    ``required``: label names that must be present (e.g. :data:`WHEEL_NAMES`); a missing one
    raises InputError naming it and listing the labels present.
    """
    data = load_yaml(text, source)
    if not isinstance(data, dict) or not data:
        raise InputError(
            f"{source}: expected a mapping of label name to points, got {type_name(data)}"
        )
    points: dict[str, np.ndarray] = {}
    for name, value in data.items():
        _check_label_name(name, source)
        where = f"{source}: label '{name}'"
        if isinstance(value, (list, tuple)) and value and all(
            isinstance(v, (list, tuple)) for v in value
        ):
            pts = [_point(v, f"{where}, point {i + 1}") for i, v in enumerate(value)]
        else:
            pts = [_point(value, where)]
        points[name] = np.array(pts)
    labels = LabelSet(points, source)
    labels.require(required)
    return labels


def parse_labels_csv(
    text: str, source: str = "labels.csv", required: Sequence[str] = ()
) -> LabelSet:
    """Labels from CSV text, rows ``label,x,y,z`` (see the module docstring).

    Errors name ``source``, the line and the column; ``required`` as in :func:`parse_labels_yaml`.
    """
    rows: dict[str, list[list[float]]] = {}
    reader = csv.reader(io.StringIO(text, newline=None))  # LF, CRLF or CR line ends
    try:
        table = [(reader.line_num, row) for row in reader]
    except csv.Error as exc:
        raise InputError(f"{source}: line {reader.line_num}: malformed CSV: {exc}") from None
    for line, row in table:
        cells = [c.strip() for c in row]
        if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
            continue
        if [c.lower() for c in cells] == ["label", "x", "y", "z"]:
            continue
        if len(cells) != 4:
            raise InputError(
                f"{source}: line {line}: expected 4 columns (label, x, y, z), got {len(cells)}"
            )
        name = cells[0]
        _check_label_name(name, f"{source}: line {line}")
        xyz = []
        for axis, cell in zip("xyz", cells[1:]):
            try:
                v = float(cell)
            except ValueError:
                raise InputError(
                    f"{source}: line {line}: column {axis} of label '{name}' "
                    f"is not a number: {cell!r}"
                ) from None
            if not abs(v) <= MAX_ABS["m"]:
                raise InputError(
                    f"{source}: line {line}: column {axis} of label '{name}' is {cell}, "
                    f"expected a finite number within ±{MAX_ABS['m']:g} m"
                )
            xyz.append(v)
        rows.setdefault(name, []).append(xyz)
    if not rows:
        raise InputError(f"{source}: no label rows (expected rows 'label,x,y,z')")
    labels = LabelSet({k: np.array(v) for k, v in rows.items()}, source)
    labels.require(required)
    return labels


def _order(labels: LabelSet) -> list[str]:
    wheels = [w for w in WHEEL_NAMES if w in labels.points]
    return wheels + sorted(k for k in labels.points if k not in WHEEL_NAMES)


def format_labels_yaml(labels: LabelSet) -> str:
    """YAML text of ``labels`` that :func:`parse_labels_yaml` reads back exactly (``repr``
    floats); wheels first, then markers by name."""
    lines = []
    for name in _order(labels):
        pts = labels.points[name]
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in p) + "]" for p in pts)
        lines.append(f"{name}: [{rows}]")
    return "\n".join(lines) + "\n"


def format_labels_csv(labels: LabelSet) -> str:
    """CSV text (header ``label,x,y,z``, one row per point) that :func:`parse_labels_csv`
    reads back exactly."""
    lines = ["label,x,y,z"]
    for name in _order(labels):
        for p in labels.points[name]:
            lines.append(",".join([name, *(repr(float(v)) for v in p)]))
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- 3D circle


class Circle3D(NamedTuple):
    """A circle in space: ``centre`` (3,) [m], unit ``normal`` (3,) of its plane (pointing to the
    side the external sensor - the origin - is on), ``radius_m``, ``rms_m`` the RMS distance of
    the inlier points to the circle, ``inliers`` (N,) bool mask of the points used."""

    centre: np.ndarray
    normal: np.ndarray
    radius_m: float
    rms_m: float
    inliers: np.ndarray


def _circle_residuals(x: np.ndarray, p: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """Two residuals per point: the distance out of the circle's plane and in the plane from
    the circle. ``x = (centre (3), tilt (2), radius)``; normal = R0 exp([tilt, 0]) e_z."""
    n = R0 @ so3_exp(np.array([x[3], x[4], 0.0]))[:, 2]
    q = p - x[:3]
    h = q @ n
    rho = np.linalg.norm(q - h[:, None] * n, axis=1)
    return np.concatenate([h, rho - x[5]])


def fit_circle_3d(
    points: np.ndarray,
    *,
    outlier_tolerance_m: float | None = 0.01,
    rng: np.random.Generator | int = 0,
) -> Circle3D:
    """A circle through (N, 3) points, N >= 3 (e.g. clicks on a wheel rim).

    1. the plane: least squares, or RANSAC with inlier tolerance ``outlier_tolerance_m`` when
       N >= 6 (a mis-click on the tyre or the body is dropped);
    2. the circle in that plane: algebraic start then geometric fit (RANSAC for N >= 6);
    3. a geometric refinement of centre, axis and radius on the inliers, minimising the
       distances of the points to the 3D circle (out of plane and in plane).

    ``outlier_tolerance_m=None`` trusts every point. Raises GeometryError for collinear or
    coincident points, or when fewer than 3 points agree on one circle.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"3D circle fit: expected (N, 3) points, got shape {p.shape}")
    if p.shape[0] < 3:
        raise GeometryError(f"3D circle fit: needs at least 3 points, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise GeometryError("3D circle fit: got non-finite points")
    robust = outlier_tolerance_m is not None and p.shape[0] >= 6
    if robust:
        tol = float(outlier_tolerance_m)
        if not (math.isfinite(tol) and tol > 0):
            raise InputError(
                f"outlier_tolerance_m must be a positive number, got {outlier_tolerance_m!r}"
            )
        plane = ransac_plane(p, tol, rng, max_iterations=100, min_inliers=3)
    else:
        plane = fit_plane_lstsq(p)
    mask = plane.inliers.copy()
    centroid = p[mask].mean(axis=0)
    basis = plane_basis(plane.normal)
    uv = to_plane_2d(p, centroid, basis)
    if robust and mask.sum() >= 4:
        span = float(np.max(np.ptp(uv[mask], axis=0)))
        circ = ransac_circle_2d(
            uv[mask], 0.05 * span, 50.0 * span + 1e-9, tol, rng, max_iterations=200
        )
        idx = np.flatnonzero(mask)
        mask = np.zeros_like(mask)
        mask[idx[circ.inliers]] = True
        c2, r = circ.centre, circ.radius
    else:
        circ = fit_circle_2d(uv[mask])
        c2, r = circ.centre, circ.radius
    if mask.sum() < 3:
        raise GeometryError(
            f"3D circle fit: only {int(mask.sum())} of {p.shape[0]} points on one circle"
        )
    centre0 = centroid + c2 @ basis
    R0 = np.column_stack([basis[0], basis[1], plane.normal])
    q = p[mask]
    sol = least_squares(
        _circle_residuals, np.array([*centre0, 0.0, 0.0, r]), args=(q, R0), method="lm",
        x_scale=np.array([r, r, r, 1.0, 1.0, r]),
    )
    x = sol.x
    if not (np.all(np.isfinite(x)) and x[5] > 0):
        raise GeometryError("3D circle fit: the geometric refinement diverged")
    normal = R0 @ so3_exp(np.array([x[3], x[4], 0.0]))[:, 2]
    centre = x[:3]
    if normal @ centre > 0:  # point toward the origin (the external sensor)
        normal = -normal
    res = _circle_residuals(x, q, R0).reshape(2, -1)
    rms = float(np.sqrt(np.mean(np.sum(res * res, axis=0))))
    return Circle3D(centre.copy(), normal, float(x[5]), rms, mask)


# ----------------------------------------------------------------------------- wheel centres


class WheelCentre(NamedTuple):
    """One wheel's centre in the external frame: ``centre`` (3,) [m]; ``method`` 'single' or
    'circle'; ``n_points`` labels used; for 'circle' also ``radius_m``, the rim ``normal`` (3,)
    and ``rms_m``, else NaN / None."""

    name: str
    centre: np.ndarray
    method: str
    n_points: int
    radius_m: float = float("nan")
    normal: np.ndarray | None = None
    rms_m: float = float("nan")


def wheel_centre(
    name: str,
    points: np.ndarray,
    method: str = "auto",
    *,
    outlier_tolerance_m: float | None = 0.01,
    rng: np.random.Generator | int = 0,
) -> WheelCentre:
    """The centre of wheel ``name`` from its labelled (N, 3) points.

    ``method``: 'single' - one click on the hub is the centre (more clicks are averaged);
    'circle' - N >= 3 rim clicks, :func:`fit_circle_3d`; 'auto' - 'single' for one point,
    'circle' otherwise. Fewer than 3 rim points raise InputError naming the wheel.
    """
    if method not in _METHODS:
        raise ConfigError(
            f"wheel '{name}': method must be one of {', '.join(_METHODS)}, got {method!r}"
        )
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    n = p.shape[0]
    if method == "auto":
        method = "single" if n == 1 else "circle"
    if method == "single":
        if n == 0:
            raise InputError(f"wheel '{name}': no labelled point")
        return WheelCentre(name, _readonly(p.mean(axis=0)), "single", n)
    if n < 3:
        raise InputError(
            f"wheel '{name}': a rim circle needs at least 3 labelled rim points, got {n}"
        )
    try:
        c = fit_circle_3d(p, outlier_tolerance_m=outlier_tolerance_m, rng=rng)
    except GeometryError as exc:
        raise GeometryError(f"wheel '{name}': {exc}") from exc
    return WheelCentre(
        name,
        _readonly(c.centre),
        "circle",
        int(c.inliers.sum()),
        c.radius_m,
        _readonly(c.normal),
        c.rms_m,
    )


def wheel_centres(
    labels: LabelSet,
    method: str = "auto",
    *,
    outlier_tolerance_m: float | None = 0.01,
    rng: np.random.Generator | int = 0,
) -> dict[str, WheelCentre]:
    """The four wheel centres of a :class:`LabelSet`, keyed by :data:`WHEEL_NAMES`.

    A missing wheel raises InputError naming it and listing the labels present.
    """
    labels.require(WHEEL_NAMES)
    gen = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    return {
        w: wheel_centre(
            w, labels.points[w], method, outlier_tolerance_m=outlier_tolerance_m, rng=gen
        )
        for w in WHEEL_NAMES
    }


# ----------------------------------------------------------------------------- ground plane


class GroundPlane(NamedTuple):
    """The ground ``normal . p + offset_m = 0`` with a unit ``normal`` (3,) pointing **up**, so
    ``normal . p + offset_m`` is a point's height above the ground [m]. ``inliers`` (N,) bool
    over the points given to the fit, ``rms_m`` their RMS distance, ``threshold_m`` the RANSAC
    inlier tolerance used."""

    normal: np.ndarray
    offset_m: float
    inliers: np.ndarray
    rms_m: float
    threshold_m: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) heights [m] of (N, 3) points above the ground."""
        return np.asarray(points, dtype=float) @ self.normal + self.offset_m

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) orthogonal projections of (N, 3) points onto the ground."""
        p = np.asarray(points, dtype=float)
        return p - self.height(p)[..., None] * self.normal


def fit_ground_plane(
    points: np.ndarray,
    *,
    threshold_m: float = 0.02,
    up_hint: Sequence[float] = (0.0, 0.0, 1.0),
    lower_band_m: float | None = 0.5,
    max_tilt_deg: float = 20.0,
    min_inliers: int = 100,
    min_fraction: float = 0.3,
    rng: np.random.Generator | int = 0,
    source: str = "scan",
) -> GroundPlane:
    """RANSAC ground plane of an (N, 3) point cloud [m] (e.g. the external scan).

    Only the lower part is searched: points less than ``lower_band_m`` above the 1st-percentile
    height along ``up_hint`` (None: all points). The plane's normal must be within
    ``max_tilt_deg`` of ``up_hint``; points within ``threshold_m`` are inliers. A plane with
    fewer than ``min_inliers`` inliers, or fewer than ``min_fraction`` of the searched points,
    is not ground: GeometryError naming ``source`` ("no ground"). The final inlier mask covers
    all given points; the normal is oriented along ``up_hint``.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{source}: expected an (N, 3) point cloud, got shape {p.shape}")
    p = p[np.all(np.isfinite(p), axis=1)]
    up = np.asarray(up_hint, dtype=float).reshape(3)
    if not np.linalg.norm(up) > 0:
        raise InputError(f"{source}: up_hint must be a non-zero 3-vector, got {list(up_hint)}")
    up = up / np.linalg.norm(up)
    thr = float(threshold_m)
    if not (math.isfinite(thr) and thr > 0):
        raise InputError(f"{source}: threshold_m must be a positive number, got {threshold_m!r}")
    if p.shape[0] < max(3, min_inliers):
        raise GeometryError(
            f"{source}: no ground: the scan has {p.shape[0]} points, "
            f"need at least {max(3, min_inliers)}"
        )
    h = p @ up
    if lower_band_m is not None:
        lower = h < np.percentile(h, 1.0) + float(lower_band_m)
    else:
        lower = np.ones(p.shape[0], dtype=bool)
    cand = p[lower]
    where = f"the lowest {lower_band_m} m of " if lower_band_m is not None else ""
    try:
        fit = ransac_plane(
            cand, thr, rng, max_iterations=300, normal_hint=up, max_angle_deg=max_tilt_deg,
            min_inliers=3,
        )
    except GeometryError as exc:
        raise GeometryError(
            f"{source}: no ground: no plane within {max_tilt_deg} deg of up {up.round(3).tolist()} "
            f"in {where}the scan ({exc})"
        ) from exc
    count = int(fit.inliers.sum())
    fraction = count / max(cand.shape[0], 1)
    if count < min_inliers or fraction < min_fraction:
        raise GeometryError(
            f"{source}: no ground: the best near-horizontal plane in {where}the scan holds "
            f"{count} of {cand.shape[0]} points ({100 * fraction:.0f}%) within {thr} m; "
            f"need {min_inliers} points and {100 * min_fraction:.0f}%"
        )
    n, d = fit.normal, fit.d
    if n @ up < 0:
        n, d = -n, -d
    dist = p @ n + d
    mask = np.abs(dist) < thr
    # map back to the caller's rows (non-finite rows are never inliers)
    full = np.zeros(np.asarray(points).shape[0], dtype=bool)
    finite = np.all(np.isfinite(np.asarray(points, dtype=float)), axis=1)
    full[np.flatnonzero(finite)[mask]] = True
    rms = float(np.sqrt(np.mean(dist[mask] ** 2)))
    return GroundPlane(_readonly(n), float(d), full, rms, thr)
