"""Motion-capture pose streams: a tracked body's pose ``T_M_body`` over time, interpolated.

A motion capture system (MCS) reports, at a high rate, the pose of every tracked rigid body
(the robot's marker body ``R``, each target ``T``) in its stationary map frame ``M`` (Charron et
al., section III-A: ``T_M_R`` and ``T_M_T``). :class:`PoseStream` holds one body's samples;
:func:`interpolate` gives the pose at sensor time stamps, refusing times outside the stream and
inside gaps longer than ``max_gap_s`` (an occluded body must not be guessed across seconds).

Interpolation between two samples ``i`` and ``i + 1`` at fraction ``a`` in [0, 1]:
translation linear, rotation along the shortest geodesic (slerp)
``R = R_i @ exp(a * log(R_i^T @ R_{i+1}))``. A query exactly on a sample returns that sample,
whatever the gaps around it.

Readers:

* :func:`parse_pose_csv` / :func:`read_pose_csv`: ``t, x, y, z, qx, qy, qz, qw`` with a header
  (columns found by name, extra columns ignored); ``t`` in seconds or nanoseconds (see
  :func:`parse_pose_csv` for the rule), x, y, z in metres, the quaternion (x, y, z, w) as in ROS.
* :func:`read_tf_streams`: ``tf2_msgs/TFMessage`` on ``/tf`` and ``/tf_static``; transforms are
  picked by child frame id and parent chains are composed up to the mocap frame.
* :func:`read_pose_topics`: ``geometry_msgs/TransformStamped`` (the Vicon bridge),
  ``geometry_msgs/PoseStamped``, ``geometry_msgs/PoseWithCovarianceStamped`` and
  ``nav_msgs/Odometry`` topics, one stream per topic.

Bag messages are stamped with their header stamp (the bag's receive time when the stamp is
zero). Samples with a NaN or a zero quaternion (what bridges publish for an occluded body) are
mocap dropouts: dropped, counted and mentioned in a warning; the gap they leave is refused by
:func:`interpolate`. Samples that are neither a pose nor a dropout - an infinite number, a
position beyond :data:`MAX_POSITION_M` (1e4 m), a quaternion whose norm is off 1 by more than
1e-3 (it is not silently normalised) - are refused with an InputError naming the bag, the
topic, the message and the field. In a CSV an occlusion is a row with all seven pose fields
empty or nan; a row with only some of them missing is refused (see :func:`parse_pose_csv`).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np

from rigcal.errors import GeometryError, InputError
from rigcal.io.limits import MAX_ABS
from rigcal.geometry.se3 import from_rt
from rigcal.geometry.so3 import so3_exp, so3_log

__all__ = [
    "DEFAULT_MAX_GAP_S",
    "DROPOUT_SAMPLES",
    "MocapNoise",
    "POSE_MSGTYPES",
    "TF_MSGTYPE",
    "PoseSources",
    "PoseStream",
    "interpolate",
    "list_pose_sources",
    "matrix_to_quat_xyzw",
    "mcs_noise",
    "parse_pose_csv",
    "pose_csv_text",
    "quat_xyzw_to_matrix",
    "read_pose_csv",
    "read_pose_topics",
    "read_tf_streams",
    "interpolation_weight",
    "relative_velocity",
    "write_pose_csv",
]

log = logging.getLogger(__name__)

DEFAULT_MAX_GAP_S = 0.05
"""Largest gap between two samples [s] that :func:`interpolate` bridges (20 Hz)."""

DROPOUT_SAMPLES = 25
"""A gap left by dropped samples (mocap dropouts) is bridged up to this many sample periods by
default (0.25 s at 100 Hz): a burst of occluded samples is not a hole in the data."""

_NS = 1_000_000_000
_RIGID_TOL = 1e-6
_QUAT_NORM_TOL = 1e-3
#: largest |x|, |y|, |z| [m] of a mocap position: a motion-capture volume is metres to tens of
#: metres across, so anything beyond is a unit mistake (millimetres?) or a corrupt sample
MAX_POSITION_M = 1e4
_FIELDS = ("x", "y", "z", "qx", "qy", "qz", "qw")

TF_MSGTYPE = "tf2_msgs/msg/TFMessage"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_MSGTYPES = (TRANSFORM_STAMPED, POSE_STAMPED, POSE_COV_STAMPED, ODOMETRY)
"""Message types :func:`read_pose_topics` reads (one pose per message)."""


# --------------------------------------------------------------------------------------------
# quaternions, (x, y, z, w) as in ROS


def quat_xyzw_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) ordered (x, y, z, w).

    Quaternions are normalised first; a zero or non-finite quaternion raises GeometryError."""
    q = np.asarray(q_xyzw, dtype=float)
    if q.shape[-1:] != (4,):
        raise GeometryError(f"quaternions must have shape (..., 4) (x, y, z, w), got {q.shape}")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
        raise GeometryError("cannot make a rotation from a zero or non-finite quaternion")
    x, y, z, w = np.moveaxis(q / norm, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) ordered (x, y, z, w) with ``w >= 0`` from rotations (..., 3, 3).

    Uses the largest of the four candidate pivots, so it is accurate for every rotation."""
    R = np.asarray(R, dtype=float)
    batch = R.shape[:-2]
    m = R.reshape(-1, 3, 3)
    r00, r11, r22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    tr = r00 + r11 + r22
    k = np.argmax(np.stack([r00, r11, r22, tr], axis=1), axis=1)
    # the four candidates, each scaled by 4 * (its pivot component)
    cands = np.stack([
        np.stack([1 + r00 - r11 - r22, m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0],
                  m[:, 2, 1] - m[:, 1, 2]], axis=1),
        np.stack([m[:, 0, 1] + m[:, 1, 0], 1 + r11 - r00 - r22, m[:, 1, 2] + m[:, 2, 1],
                  m[:, 0, 2] - m[:, 2, 0]], axis=1),
        np.stack([m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1], 1 + r22 - r00 - r11,
                  m[:, 1, 0] - m[:, 0, 1]], axis=1),
        np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1],
                  1 + tr], axis=1),
    ], axis=1)
    q = cands[np.arange(m.shape[0]), k]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(batch + (4,))


# --------------------------------------------------------------------------------------------
# the stream value


def _check_max_gap(max_gap_s: float) -> int:
    ok = isinstance(max_gap_s, (int, float, np.integer, np.floating)) and not isinstance(
        max_gap_s, bool)
    if not ok or not math.isfinite(float(max_gap_s)) or float(max_gap_s) <= 0:
        raise InputError(f"max_gap_s must be a finite number > 0 [s], got {max_gap_s!r}")
    return int(round(float(max_gap_s) * _NS))


def _fmt_s(t_ns: int) -> str:
    return f"{t_ns / _NS:.9f} s"


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class PoseStream:
    """Poses of one tracked body over time.

    ``t_ns`` (N,) int64 strictly increasing time stamps [ns]; ``T`` (N, 4, 4) the body's pose in
    the mocap frame, ``T_M_body`` (maps a point given in the body frame into the mocap frame
    ``M``). ``frame_id`` names ``M`` when known (e.g. the TF parent ``world``); ``source`` says
    where the samples came from (for messages). Arrays are read-only copies."""

    name: str
    t_ns: np.ndarray
    T: np.ndarray
    frame_id: str = ""
    source: str = ""
    #: stamps [ns] of the samples dropped as mocap dropouts (an occluded body: NaN values):
    #: a gap that holds one is bridged up to ``max_dropout_s`` (:func:`interpolate`)
    dropout_t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        what = f"{self.source + ': ' if self.source else ''}pose stream '{self.name}'"
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"{what}: name must be a non-empty string, got {self.name!r}")
        t_in = np.asarray(self.t_ns)
        if t_in.ndim != 1 or t_in.size == 0:
            raise InputError(f"{what}: t_ns must be a non-empty 1-D array, got shape {t_in.shape}")
        if not np.issubdtype(t_in.dtype, np.integer):
            raise InputError(f"{what}: t_ns must be integer nanoseconds, got dtype {t_in.dtype}")
        t = np.array(t_in, dtype=np.int64)
        steps = np.diff(t)
        if np.any(steps <= 0):
            i = int(np.flatnonzero(steps <= 0)[0])
            kind = "duplicate" if steps[i] == 0 else "out-of-order"
            raise InputError(
                f"{what}: t_ns must be strictly increasing: {kind} sample {i + 1} at {t[i + 1]} ns "
                f"after sample {i} at {t[i]} ns"
            )
        T = np.array(self.T, dtype=float)
        if T.shape != (t.size, 4, 4):
            raise InputError(f"{what}: T must have shape ({t.size}, 4, 4), got {T.shape}")
        if not np.all(np.isfinite(T)):
            i = int(np.flatnonzero(~np.all(np.isfinite(T.reshape(t.size, -1)), axis=1))[0])
            raise InputError(f"{what}: pose {i} (t = {t[i]} ns) has non-finite entries")
        bottom = np.abs(T[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
        R = T[:, :3, :3]
        ortho = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
        bad = (bottom > 1e-9) | (ortho > _RIGID_TOL) | (np.linalg.det(R) <= 0)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"{what}: pose {i} (t = {t[i]} ns) is not rigid: expected a proper rotation "
                f"(|R^T R - I| = {ortho[i]:.3g}, det = {np.linalg.det(R[i]):.6g}) and last row "
                "[0, 0, 0, 1]"
            )
        t.setflags(write=False)
        T.setflags(write=False)
        object.__setattr__(self, "t_ns", t)
        object.__setattr__(self, "T", T)
        d = np.unique(np.asarray(self.dropout_t_ns, dtype=np.int64).reshape(-1))
        d.setflags(write=False)
        object.__setattr__(self, "dropout_t_ns", d)

    @classmethod
    def from_positions_quaternions(cls, name: str, t_ns: Any, positions_xyz: Any,
                                   quaternions_xyzw: Any, frame_id: str = "",
                                   source: str = "", dropout_t_ns: Any = ()) -> "PoseStream":
        """A stream from positions (N, 3) [m] and quaternions (N, 4) (x, y, z, w), normalised."""
        p = np.asarray(positions_xyz, dtype=float)
        q = np.asarray(quaternions_xyzw, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4):
            raise InputError(
                f"pose stream '{name}': expected positions (N, 3) and quaternions (N, 4), got "
                f"{p.shape} and {q.shape}"
            )
        try:
            R = quat_xyzw_to_matrix(q)
        except GeometryError as exc:
            raise InputError(f"pose stream '{name}': {exc}") from None
        return cls(name, t_ns, from_rt(R, p), frame_id, source, np.asarray(dropout_t_ns, dtype=np.int64))

    def __len__(self) -> int:
        return int(self.t_ns.size)

    @property
    def start_ns(self) -> int:
        return int(self.t_ns[0])

    @property
    def end_ns(self) -> int:
        return int(self.t_ns[-1])

    @property
    def positions_xyz(self) -> np.ndarray:
        """(N, 3) body origin in the mocap frame [m] (a new array)."""
        return self.T[:, :3, 3].copy()

    @property
    def quaternions_xyzw(self) -> np.ndarray:
        """(N, 4) body orientation in the mocap frame, (x, y, z, w) with w >= 0."""
        return matrix_to_quat_xyzw(self.T[:, :3, :3])

    def interpolate(self, t_ns: Any, max_gap_s: float = DEFAULT_MAX_GAP_S,
                    max_dropout_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Same as :func:`interpolate` (``self`` is the stream)."""
        return interpolate(self, t_ns, max_gap_s, max_dropout_s)

    @property
    def period_ns(self) -> int:
        """The median step between samples [ns] (0 for a single sample)."""
        return int(np.median(np.diff(self.t_ns))) if len(self) > 1 else 0

    def at(self, t_ns: int, max_gap_s: float = DEFAULT_MAX_GAP_S,
           max_dropout_s: float | None = None) -> np.ndarray:
        """The pose (4, 4) ``T_M_body`` at ``t_ns``; InputError naming the stream and the reason
        (before the start, after the end, or inside a gap longer than ``max_gap_s`` - or, for a
        gap left by dropped samples, than ``max_dropout_s``)."""
        T, valid = interpolate(self, np.array([t_ns]), max_gap_s, max_dropout_s)
        if valid[0]:
            return T[0]
        t = int(t_ns)
        what = f"pose stream '{self.name}'{' (' + self.source + ')' if self.source else ''}"
        if t < self.start_ns or t > self.end_ns:
            side = "before the start" if t < self.start_ns else "after the end"
            raise InputError(
                f"{what}: no pose at t = {t} ns ({_fmt_s(t)}): {side} of the stream, which covers "
                f"[{self.start_ns}, {self.end_ns}] ns ({len(self)} samples)"
            )
        i = int(np.searchsorted(self.t_ns, t, side="right")) - 1
        a, b = int(self.t_ns[i]), int(self.t_ns[i + 1])
        dropped = int(np.sum((self.dropout_t_ns > a) & (self.dropout_t_ns < b)))
        if dropped:
            limit = _max_dropout(self, max_gap_s, max_dropout_s) / _NS
            raise InputError(
                f"{what}: no pose at t = {t} ns: it falls in a dropout of {dropped} samples, a gap "
                f"of {(b - a) / _NS:.3f} s between samples at {a} and {b} ns, longer than "
                f"max_dropout_s = {limit:g} s"
            )
        raise InputError(
            f"{what}: no pose at t = {t} ns: it falls in a gap of {(b - a) / _NS:.3f} s between "
            f"samples at {a} and {b} ns, longer than max_gap_s = {max_gap_s} s"
        )

    def window(self, start_ns: int | None = None, end_ns: int | None = None) -> "PoseStream":
        """The samples with ``start_ns <= t < end_ns`` (a new stream; InputError if none)."""
        keep = np.ones(len(self), dtype=bool)
        if start_ns is not None:
            keep &= self.t_ns >= int(start_ns)
        if end_ns is not None:
            keep &= self.t_ns < int(end_ns)
        if not np.any(keep):
            raise InputError(
                f"pose stream '{self.name}': no samples in [{start_ns}, {end_ns}) ns; the stream "
                f"covers [{self.start_ns}, {self.end_ns}] ns"
            )
        d = self.dropout_t_ns
        dk = np.ones(d.size, dtype=bool)
        if start_ns is not None:
            dk &= d >= int(start_ns)
        if end_ns is not None:
            dk &= d < int(end_ns)
        return PoseStream(self.name, self.t_ns[keep], self.T[keep], self.frame_id, self.source, d[dk])


def _max_dropout(stream: PoseStream, max_gap_s: float, max_dropout_s: float | None) -> int:
    """The longest gap [ns] left by dropped samples that is bridged: ``max_dropout_s``, or by
    default :data:`DROPOUT_SAMPLES` sample periods of the stream (at least ``max_gap_s``)."""
    gap = _check_max_gap(max_gap_s)
    if max_dropout_s is not None:
        return max(gap, _check_max_gap(max_dropout_s))
    return max(gap, DROPOUT_SAMPLES * stream.period_ns)


def interpolate(stream: PoseStream, t_ns: Any, max_gap_s: float = DEFAULT_MAX_GAP_S,
                max_dropout_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Poses of ``stream`` at times ``t_ns`` (integer ns, any shape S).

    Returns ``(T, valid)``: ``T`` of shape S + (4, 4) (``T_M_body``; NaN where not valid) and
    ``valid`` of shape S. A time is valid when it equals a sample's time, or lies strictly
    between two consecutive samples at most ``max_gap_s`` apart - or, when samples between
    them were dropped as mocap dropouts (``stream.dropout_t_ns``), at most ``max_dropout_s``
    apart (default: :data:`DROPOUT_SAMPLES` sample periods, a burst of occluded samples is
    interpolated over, not a gap). Times before the first or after the last sample are never
    valid. Translation is interpolated linearly, rotation by slerp (constant angular velocity
    along the shortest arc)."""
    max_gap_ns = _check_max_gap(max_gap_s)
    max_drop_ns = _max_dropout(stream, max_gap_s, max_dropout_s)
    t_in = np.asarray(t_ns)
    if t_in.size and not np.issubdtype(t_in.dtype, np.integer):
        if not np.all(np.isfinite(t_in)) or np.any(t_in != np.round(t_in)):
            raise InputError(
                f"pose stream '{stream.name}': query times must be integer nanoseconds"
            )
    t = t_in.astype(np.int64).reshape(-1)
    ts = stream.t_ns
    n = ts.size
    i = np.searchsorted(ts, t, side="right") - 1  # ts[i] <= t < ts[i + 1]
    inside = i >= 0
    exact = inside & (ts[np.clip(i, 0, n - 1)] == t)
    between = inside & (i < n - 1) & ~exact
    lo = np.clip(i, 0, n - 1)
    hi = np.clip(i + 1, 0, n - 1)
    gap = ts[hi] - ts[lo]
    ok_gap = gap <= max_gap_ns
    if stream.dropout_t_ns.size and max_drop_ns > max_gap_ns:
        d = stream.dropout_t_ns
        dropped = np.searchsorted(d, ts[hi], side="left") - np.searchsorted(d, ts[lo], side="right")
        ok_gap |= (dropped > 0) & (gap <= max_drop_ns)
    between &= ok_gap
    valid = exact | between

    out = np.full((t.size, 4, 4), np.nan)
    if np.any(exact):
        out[exact] = stream.T[lo[exact]]
    if np.any(between):
        a = lo[between]
        b = hi[between]
        alpha = ((t[between] - ts[a]) / (ts[b] - ts[a]).astype(float))[:, None]
        Ra = stream.T[a, :3, :3]
        Rb = stream.T[b, :3, :3]
        w = so3_log(np.swapaxes(Ra, 1, 2) @ Rb)
        R = Ra @ so3_exp(alpha * w)
        p = stream.T[a, :3, 3] + alpha * (stream.T[b, :3, 3] - stream.T[a, :3, 3])
        out[between] = from_rt(R, p)
    return out.reshape(t_in.shape + (4, 4)), valid.reshape(t_in.shape)


# --------------------------------------------------------------------------------------------
# what the streams tell about the MCS's own noise, and relative motion


class MocapNoise(NamedTuple):
    """The per-sample noise of one body's MCS poses: std per axis of the rotation [rad] and the
    translation [m] (right perturbation, body frame), from ``samples`` second differences."""

    rotation_rad: float
    translation_m: float
    samples: int

    def covariance(self) -> np.ndarray:
        """(6, 6) diagonal covariance of one sample's right perturbation (rotation first)."""
        return np.diag([self.rotation_rad ** 2] * 3 + [self.translation_m ** 2] * 3)


#: second differences are used only where the body moves slower than this [m/s]: a still
#: target (a hold), a creeping robot - not the target being carried
NOISE_MAX_SPEED_MPS = 0.1


def mcs_noise(stream: PoseStream, max_speed_mps: float = NOISE_MAX_SPEED_MPS) -> MocapNoise:
    """The per-sample noise of ``stream`` estimated from the stream itself, over its still or
    steady stretches (a held target, a creeping robot: grouped by motion, never by stamps
    alone): for independent noise ``x[i-1] - 2 x[i] + x[i+1]`` has variance ``6 sigma^2``
    while the motion is smooth. Only consecutive, evenly spaced samples (no dropout between
    them) moving slower than ``max_speed_mps`` count; the spread is a median absolute
    deviation, so the rare jerk does not count. Zero for exact poses; ``samples`` 0 when no
    stretch qualifies (then the noise is unknown: zeros)."""
    t = stream.t_ns
    if len(stream) < 3:
        return MocapNoise(0.0, 0.0, 0)
    dt = np.diff(t).astype(float)
    step = float(np.median(dt))
    even = np.abs(dt - step) <= 0.1 * step
    ok = even[:-1] & even[1:]
    p = stream.T[:, :3, 3]
    R = stream.T[:, :3, :3]
    speed = np.linalg.norm(p[2:] - p[:-2], axis=1) / (2 * step / _NS)
    ok &= speed <= max_speed_mps
    if not np.any(ok):
        return MocapNoise(0.0, 0.0, 0)
    d2p = (p[:-2] - 2 * p[1:-1] + p[2:])[ok]
    w = so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:])  # (N-1, 3) rotation steps, body frame
    d2r = (w[1:] - w[:-1])[ok]

    def spread(x: np.ndarray) -> float:
        mad = np.median(np.abs(x - np.median(x, axis=0)), axis=0) * 1.4826
        return float(np.sqrt(np.mean(mad ** 2) / 6.0))

    return MocapNoise(spread(d2r), spread(d2p), int(np.sum(ok)))


def interpolation_weight(stream: PoseStream, t_ns: int) -> float:
    """How much of one sample's noise an interpolated pose at ``t_ns`` keeps (its variance
    factor ``a^2 + (1 - a)^2`` for the fraction ``a`` between the two samples; 1 on a sample
    or outside)."""
    ts = stream.t_ns
    i = int(np.searchsorted(ts, int(t_ns), side="right")) - 1
    if i < 0 or i >= len(ts) - 1 or ts[i] == t_ns:
        return 1.0
    a = (int(t_ns) - int(ts[i])) / float(ts[i + 1] - ts[i])
    return a * a + (1 - a) * (1 - a)


def relative_velocity(robot: PoseStream, target: PoseStream, t_ns: int, window_s: float,
                      max_gap_s: float = DEFAULT_MAX_GAP_S,
                      max_dropout_s: float | None = None) -> np.ndarray | None:
    """(6,) how the target's pose in the robot frame ``T_R_T = T_M_R^-1 T_M_T`` changes at
    ``t_ns``: the twist (rad/s, m/s; rotation first) with ``T_R_T(t + h) ~ T_R_T(t) exp(h xi)``,
    the least-squares slope over the samples of both streams within ``+-window_s / 2`` (a
    slope over many samples, not a difference of two: the MCS's noise averages out). None
    when the streams do not cover the window."""
    half = int(round(window_s * 0.5 * _NS))
    lo, hi = int(t_ns) - half, int(t_ns) + half
    times = np.unique(np.concatenate([
        [lo, int(t_ns), hi], robot.t_ns[(robot.t_ns > lo) & (robot.t_ns < hi)],
        target.t_ns[(target.t_ns > lo) & (target.t_ns < hi)]]).astype(np.int64))
    T_mr, ok_r = interpolate(robot, times, max_gap_s, max_dropout_s)
    T_mt, ok_t = interpolate(target, times, max_gap_s, max_dropout_s)
    ok = ok_r & ok_t
    k0 = int(np.flatnonzero(times == int(t_ns))[0])
    if not ok[k0] or np.sum(ok) < 3:
        return None
    from rigcal.geometry.se3 import invert, se3_log

    T_rt = np.einsum("nij,njk->nik", np.linalg.inv(T_mr[ok]), T_mt[ok])
    y = se3_log(np.einsum("ij,njk->nik", invert(T_rt[int(np.sum(ok[:k0]))]), T_rt))
    h = (times[ok] - int(t_ns)) / _NS
    hc = h - h.mean()
    denom = float(hc @ hc)
    if denom <= 0:
        return None
    return (hc @ (y - y.mean(axis=0))) / denom


# --------------------------------------------------------------------------------------------
# CSV

CSV_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
_NS_MAGNITUDE = Decimal(10) ** 11
_NS_MEDIAN_STEP = Decimal(1000)


def _time_unit(values: list[Decimal], time_unit: str, source: str) -> str:
    if time_unit in ("s", "ns"):
        return time_unit
    if time_unit != "auto":
        raise InputError(f"{source}: time_unit must be 'auto', 's' or 'ns', got {time_unit!r}")
    if any(v != v.to_integral_value() for v in values):
        return "s"  # nanosecond stamps are integers
    if max(abs(v) for v in values) >= _NS_MAGNITUDE:
        return "ns"
    steps = sorted(b - a for a, b in zip(values, values[1:]))
    if steps and steps[len(steps) // 2] >= _NS_MEDIAN_STEP:
        return "ns"
    return "s"


def parse_pose_csv(text: str, name: str, source: str = "CSV", *, time_unit: str = "auto",
                   frame_id: str = "") -> PoseStream:
    """A pose stream from CSV text: a header naming the columns ``t, x, y, z, qx, qy, qz, qw``
    (any order, case-insensitive, extra columns ignored), then one sample per line.

    ``t`` is in seconds or nanoseconds: ``time_unit`` 's' or 'ns', or 'auto' (default), which
    takes nanoseconds when every stamp is an integer and either some stamp is at least 1e11
    (1e11 s would be 3000 years; 1e11 ns is 100 s) or the median step is at least 1000 (1000 s
    between mocap samples is absurd; 1000 ns is 1 MHz), and seconds otherwise. Seconds are
    converted to integer nanoseconds exactly (decimal arithmetic, rounded to the nearest ns).
    x, y, z are metres in the mocap frame; the quaternion is (x, y, z, w), normalised after a
    check that its norm is within 1e-3 of 1.

    Blank lines and lines starting with ``#`` are skipped; a row whose seven pose fields are
    all ``nan`` or empty (an occluded body) is a dropout: dropped, counted and mentioned in a
    warning. A row with only some pose fields missing is corrupt and refused, as are infinite
    values, a position beyond :data:`MAX_POSITION_M` and a quaternion whose norm is off 1 by
    more than 1e-3 (a zero or nan quaternion with a position is not an occlusion marker).
    Out-of-order or duplicate stamps, bad numbers and short rows raise InputError naming
    ``source``, the line number and the column."""
    header: dict[str, int] | None = None
    header_line = 0
    rows: list[tuple[int, Decimal, list[float]]] = []
    dropped = 0
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            names = [c.lower() for c in cells]
            missing = [c for c in CSV_COLUMNS if c not in names]
            if missing:
                raise InputError(
                    f"{source}: line {lineno}: header must name the columns "
                    f"{', '.join(CSV_COLUMNS)}; missing {', '.join(missing)} (got {line!r})"
                )
            dupes = sorted({c for c in names if c and names.count(c) > 1 and c in CSV_COLUMNS})
            if dupes:
                raise InputError(f"{source}: line {lineno}: duplicate header columns {dupes}")
            header = {c: names.index(c) for c in CSV_COLUMNS}
            header_line = lineno
            continue
        need = max(header.values()) + 1
        if len(cells) < need:
            raise InputError(
                f"{source}: line {lineno}: expected at least {need} comma-separated values, got "
                f"{len(cells)}"
            )
        t_text = cells[header["t"]]
        try:
            t_val = Decimal(t_text)
            if not t_val.is_finite():
                raise InvalidOperation
        except InvalidOperation:
            raise InputError(
                f"{source}: line {lineno}: column t: expected a finite number, got {t_text!r}"
            ) from None
        vals: list[float] = []
        for col in CSV_COLUMNS[1:]:
            cell = cells[header[col]]
            try:
                vals.append(float(cell) if cell else math.nan)
            except ValueError:
                raise InputError(
                    f"{source}: line {lineno}: column {col}: expected a number, got {cell!r}"
                ) from None
        missing = [c for c, v in zip(CSV_COLUMNS[1:], vals) if math.isnan(v)]
        if len(missing) == len(vals):  # an occluded body: every pose column empty or nan
            dropped += 1
            rows.append((lineno, t_val, []))
            continue
        for col, v in zip(CSV_COLUMNS[1:], vals):
            if math.isinf(v):
                raise InputError(f"{source}: line {lineno}: infinite pose value in column {col} "
                                 f"({cells[header[col]]!r}); expected a finite number")
        if missing:
            col = missing[0]
            raise InputError(
                f"{source}: line {lineno}: column {col}: expected a finite number, got "
                f"{cells[header[col]]!r} (an occluded sample leaves all seven pose columns empty "
                f"or nan; a row with only {', '.join(missing)} missing is corrupt)"
            )
        for col, v in zip(CSV_COLUMNS[1:4], vals[:3]):
            if abs(v) > MAX_POSITION_M:
                raise InputError(
                    f"{source}: line {lineno}: column {col}: position {v:g} m is beyond "
                    f"{MAX_POSITION_M:g} m; expected metres in the mocap frame (millimetres?)"
                )
        norm = math.sqrt(sum(v * v for v in vals[3:]))
        if abs(norm - 1.0) > _QUAT_NORM_TOL:
            raise InputError(
                f"{source}: line {lineno}: quaternion (qx, qy, qz, qw) has norm {norm:.6g}, "
                f"expected 1 (within {_QUAT_NORM_TOL}); check the column order"
            )
        rows.append((lineno, t_val, vals))
    if header is None:
        raise InputError(f"{source}: no header line (expected {', '.join(CSV_COLUMNS)})")
    if not rows:
        raise InputError(f"{source}: no samples after the header (line {header_line})")

    unit = _time_unit([r[1] for r in rows], time_unit, source)
    scale = Decimal(_NS) if unit == "s" else Decimal(1)
    limit = Decimal(MAX_ABS["s"]) if unit == "s" else Decimal(2**63 - 1)
    for lineno, t_val, _ in rows:
        if abs(t_val) > limit:
            hint = ("; the stamps look like nanoseconds: set time_unit: ns" if unit == "s"
                    and abs(t_val) <= Decimal(2**63 - 1) else "")
            raise InputError(
                f"{source}: line {lineno}: column t: stamp {t_val} is beyond {limit:.3g} "
                f"{unit} (time_unit {unit}){hint}"
            )
    t_all: list[int] = []
    for lineno, t_val, _ in rows:
        t_ns = t_val * scale
        if unit == "ns" and t_ns != t_ns.to_integral_value():
            raise InputError(
                f"{source}: line {lineno}: column t: nanosecond stamps must be integers, got "
                f"{t_val}"
            )
        t_all.append(int(t_ns.to_integral_value(rounding=ROUND_HALF_EVEN)))
    for k in range(1, len(rows)):
        if t_all[k] <= t_all[k - 1]:
            kind = "duplicate" if t_all[k] == t_all[k - 1] else "out-of-order"
            raise InputError(
                f"{source}: line {rows[k][0]}: {kind} time stamp {rows[k][1]} ({unit}): not after "
                f"{rows[k - 1][1]} on line {rows[k - 1][0]}; stamps must strictly increase"
            )
    kept = [k for k, r in enumerate(rows) if r[2]]
    if dropped:
        log.warning("%s: dropped %d of %d rows with missing pose values (occlusions)", source,
                    dropped, len(rows))
    if not kept:
        raise InputError(f"{source}: every row has missing pose values; no samples left")
    data = np.array([rows[k][2] for k in kept], dtype=float)
    t = np.array([t_all[k] for k in kept], dtype=np.int64)
    drops = np.array([t_all[k] for k, r in enumerate(rows) if not r[2]], dtype=np.int64)
    return PoseStream.from_positions_quaternions(name, t, data[:, :3], data[:, 3:], frame_id,
                                                 source, drops)


def read_pose_csv(path: str | os.PathLike[str], name: str | None = None, *,
                  time_unit: str = "auto", frame_id: str = "") -> PoseStream:
    """Read a pose CSV (see :func:`parse_pose_csv`); ``name`` defaults to the file's stem."""
    from rigcal.io._text import read_text

    p = Path(path)
    return parse_pose_csv(read_text(p, "pose CSV"), name or p.stem, str(p), time_unit=time_unit,
                          frame_id=frame_id)


def pose_csv_text(stream: PoseStream, time_unit: str = "ns") -> str:
    """CSV text of ``stream`` that :func:`parse_pose_csv` reads back: header
    ``t,x,y,z,qx,qy,qz,qw``; ``t`` in integer ns or in seconds with 9 decimals (exact);
    numbers in shortest round-trip form."""
    if time_unit not in ("s", "ns"):
        raise InputError(f"time_unit must be 's' or 'ns', got {time_unit!r}")
    lines = [",".join(CSV_COLUMNS)]
    p = stream.T[:, :3, 3]
    q = stream.quaternions_xyzw
    for k, t in enumerate(stream.t_ns.tolist()):
        if time_unit == "ns":
            t_text = str(t)
        else:
            sign = "-" if t < 0 else ""
            t_text = f"{sign}{abs(t) // _NS}.{abs(t) % _NS:09d}"
        nums = [repr(float(v)) for v in (*p[k], *q[k])]
        lines.append(",".join([t_text, *nums]))
    return "\n".join(lines) + "\n"


def write_pose_csv(path: str | os.PathLike[str], stream: PoseStream,
                   time_unit: str = "ns") -> Path:
    """Write ``stream`` as CSV (:func:`pose_csv_text`) atomically; returns the path."""
    from rigcal.io.atomic import atomic_write_text

    return atomic_write_text(path, pose_csv_text(stream, time_unit))


# --------------------------------------------------------------------------------------------
# bags


def _frame_name(name: Any) -> str:
    """TF frame ids without the leading '/' ROS 1 tf sometimes carries."""
    return str(name).lstrip("/")


def _stamp(header: Any, recv_ns: int) -> int:
    stamp = header.stamp
    t = int(stamp.sec) * _NS + int(stamp.nanosec)
    return t or int(recv_ns)


def _pose_numbers(translation: Any, rotation: Any) -> tuple[float, ...]:
    """(x, y, z, qx, qy, qz, qw) of a translation/position and a quaternion message."""
    return (float(translation.x), float(translation.y), float(translation.z),
            float(rotation.x), float(rotation.y), float(rotation.z), float(rotation.w))


def _dropouts(v: np.ndarray) -> np.ndarray:
    """(N,) rows (x, y, z, qx, qy, qz, qw) a mocap bridge publishes for a body it lost: a NaN
    anywhere, or an all-zero quaternion."""
    return np.any(np.isnan(v), axis=1) | np.all(v[:, 3:] == 0.0, axis=1)


def _refuse_bad_numbers(v: np.ndarray, t_ns: Sequence[int], what: str, source: str) -> None:
    """InputError for the first row that is not a dropout (:func:`_dropouts`) yet not a pose:
    an infinite number, a position beyond :data:`MAX_POSITION_M` or a quaternion whose norm
    is off 1 by more than 1e-3. Names the message (its index among ``what``'s messages, 0
    first, and its stamp), the field and what was expected."""
    keep = ~_dropouts(v)
    with np.errstate(invalid="ignore", over="ignore"):
        inf = np.isinf(v) & keep[:, None]
        far = (np.abs(v[:, :3]) > MAX_POSITION_M) & keep[:, None]
        norm = np.linalg.norm(v[:, 3:], axis=1)
        off = keep & ~(np.abs(norm - 1.0) <= _QUAT_NORM_TOL)
    bad = np.any(inf, axis=1) | np.any(far, axis=1) | off
    if not np.any(bad):
        return
    k = int(np.flatnonzero(bad)[0])
    where = f"{source}: {what}: message {k} (stamp {int(t_ns[k])} ns)"
    if np.any(inf[k]):
        j = int(np.flatnonzero(inf[k])[0])
        raise InputError(f"{where}: {_FIELDS[j]} is {v[k, j]}; expected a finite number")
    if np.any(far[k]):
        j = int(np.flatnonzero(far[k])[0])
        raise InputError(f"{where}: position {_FIELDS[j]} = {v[k, j]:g} m is beyond "
                         f"{MAX_POSITION_M:g} m; expected metres in the mocap frame")
    raise InputError(f"{where}: quaternion (qx, qy, qz, qw) = ({', '.join(f'{x:g}' for x in v[k, 3:])}) "
                     f"has norm {norm[k]:.6g}; expected a unit quaternion (norm within "
                     f"{_QUAT_NORM_TOL:g} of 1; all zeros or NaN marks a lost body)")


def _matrices(numbers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T (N, 4, 4), valid (N,)) from rows (x, y, z, qx, qy, qz, qw); dropouts
    (:func:`_dropouts`: an occluded body) are not valid (their T is identity). Check the rows
    with :func:`_refuse_bad_numbers` first."""
    v = np.asarray(numbers, dtype=float).reshape(-1, 7)
    valid = ~_dropouts(v)
    q = np.where(valid[:, None], v[:, 3:], [0.0, 0.0, 0.0, 1.0])
    p = np.where(valid[:, None], v[:, :3], 0.0)
    return from_rt(quat_xyzw_to_matrix(q), p), valid


class _Samples:
    """Pose samples of one body/edge, gathered from messages in any order as raw numbers and
    converted in one batch."""

    def __init__(self, what: str) -> None:
        self.what = what
        self.t: list[int] = []
        self.numbers: list[tuple[float, ...]] = []

    def add(self, t_ns: int, numbers: tuple[float, ...]) -> None:
        self.t.append(int(t_ns))
        self.numbers.append(numbers)

    def valid_samples(self, source: str) -> tuple[np.ndarray, np.ndarray]:
        """(t (N,), T (N, 4, 4)) of the valid samples in message order. Dropouts (a NaN or a
        zero quaternion: a lost body) are skipped (their stamps in ``self.dropped``), counted
        and mentioned in a warning; an infinite number, a position beyond
        :data:`MAX_POSITION_M` or a non-unit quaternion is an InputError naming the message."""
        v = np.array(self.numbers, dtype=float).reshape(-1, 7)
        _refuse_bad_numbers(v, self.t, self.what, source)
        T, valid = _matrices(v)
        dropped = int((~valid).sum())
        if dropped:
            log.warning("%s: %s: dropped %d samples (of %d) as mocap dropouts (NaN values or "
                        "a zero quaternion)", source, self.what, dropped, valid.size)
        if not np.any(valid):
            raise InputError(f"{source}: {self.what}: no valid pose samples "
                             f"({dropped} dropped as invalid)")
        self.dropped = np.array(self.t, dtype=np.int64)[~valid]
        return np.array(self.t, dtype=np.int64)[valid], T[valid]

    def stream(self, name: str, frame_id: str, source: str) -> PoseStream:
        t, T = self.valid_samples(source)
        order = np.argsort(t, kind="stable")
        t, T = t[order], T[order]
        same = np.flatnonzero(np.diff(t) == 0)
        if same.size:
            for i in same:
                if not np.allclose(T[i], T[i + 1], atol=1e-9, rtol=0.0):
                    raise InputError(
                        f"{source}: {self.what}: two different poses stamped {t[i]} ns"
                    )
            keep = np.ones(t.size, dtype=bool)
            keep[same + 1] = False
            log.debug("%s: %s: dropped %d repeated samples", source, self.what, same.size)
            t, T = t[keep], T[keep]
        return PoseStream(name, t, T, frame_id, source, self.dropped)


class _TfEdges(NamedTuple):
    parent: dict[str, str]  # child -> parent
    dynamic: dict[str, _Samples]  # child -> samples of T_parent_child (from /tf)
    static: dict[str, np.ndarray]  # child -> T_parent_child (from /tf_static)


def _tf_topics(rec: Any, topics: Sequence[str], source: str) -> list[str]:
    available = rec.topics()
    present = [t for t in topics if t in available]
    if not present:
        pose_like = sorted(t for t, ty in available.items() if ty in (TF_MSGTYPE, *POSE_MSGTYPES))
        raise InputError(
            f"{source}: none of the TF topics {list(topics)} is in the bag; pose topics found: "
            f"{pose_like or 'none'}"
        )
    for t in present:
        if available[t] != TF_MSGTYPE:
            raise InputError(
                f"{source}: topic {t} has type {available[t]}, expected {TF_MSGTYPE}"
            )
    return present


def _read_tf_edges(rec: Any, topics: Sequence[str], static_topics: Iterable[str],
                   source: str) -> _TfEdges:
    static_set = set(static_topics)
    edges = _TfEdges({}, {}, {})
    for topic, _, recv_ns, msg in rec.messages(topics):
        for tr in msg.transforms:
            parent = _frame_name(tr.header.frame_id)
            child = _frame_name(tr.child_frame_id)
            if not child or not parent:
                raise InputError(f"{source}: topic {topic}: a transform has an empty frame id "
                                 f"(parent {parent!r}, child {child!r})")
            if child == parent:
                raise InputError(f"{source}: topic {topic}: frame '{child}' is its own parent")
            known = edges.parent.get(child)
            if known is not None and known != parent:
                raise InputError(
                    f"{source}: topic {topic}: frame '{child}' has two parents, '{known}' and "
                    f"'{parent}' (a TF tree gives every frame one parent)"
                )
            edges.parent[child] = parent
            numbers = _pose_numbers(tr.transform.translation, tr.transform.rotation)
            if topic in static_set:
                _refuse_bad_numbers(np.array([numbers]), [_stamp(tr.header, recv_ns)],
                                    f"topic {topic}: static transform {parent} -> {child}", source)
                T, ok = _matrices(np.array(numbers))
                if not ok[0]:
                    raise InputError(f"{source}: topic {topic}: static transform "
                                     f"{parent} -> {child} has invalid numbers")
                edges.static[child] = T[0]
            else:
                edges.dynamic.setdefault(
                    child, _Samples(f"TF {parent} -> {child}")
                ).add(_stamp(tr.header, recv_ns), numbers)
    return edges


def _chain(edges: _TfEdges, child: str, mocap_frame: str | None, source: str) -> list[str]:
    """[child, parent, grandparent, ..., top]: up to ``mocap_frame`` or the root."""
    chain = [child]
    while chain[-1] != mocap_frame and chain[-1] in edges.parent:
        nxt = edges.parent[chain[-1]]
        if nxt in chain:
            raise InputError(f"{source}: TF frames form a loop: {' -> '.join(chain + [nxt])}")
        chain.append(nxt)
    if mocap_frame is not None and chain[-1] != mocap_frame:
        raise InputError(
            f"{source}: frame '{child}' does not connect to the mocap frame '{mocap_frame}': its "
            f"parents are {' -> '.join(chain)} (root '{chain[-1]}')"
        )
    return chain


def read_tf_streams(path: str | os.PathLike[str],
                    children: Sequence[str] | Mapping[str, str],
                    mocap_frame: str | None = None, *,
                    topics: Sequence[str] = ("/tf", "/tf_static"),
                    static_topics: Sequence[str] = ("/tf_static",),
                    max_gap_s: float = DEFAULT_MAX_GAP_S) -> dict[str, PoseStream]:
    """Pose streams of TF frames from ``tf2_msgs/TFMessage`` topics of a ROS 1 or ROS 2 bag.

    ``children`` names the tracked frames: a sequence of child frame ids (the streams are named
    after them, as given) or a mapping stream name -> child frame id. Each stream holds
    ``T_<mocap_frame>_<child>``: the frame's parent chain is followed up to ``mocap_frame``
    (default: the root of the chain) and composed. The samples are the stamps of the lowest
    moving (``/tf``) transform in the chain; other moving transforms above it are interpolated
    there (samples where that is refused, see :func:`interpolate`, are dropped) and static
    (``static_topics``) transforms are constant. Leading '/' in frame ids is ignored.

    InputError when a topic is missing or not a TFMessage, a frame is unknown (known child
    frames are listed), has no moving transform in its chain, does not reach ``mocap_frame``,
    or has two parents."""
    from rigcal.io.recordings.bag import open_bag

    _check_max_gap(max_gap_s)
    wanted = dict(children) if isinstance(children, Mapping) else {str(c): c for c in children}
    if not wanted:
        raise InputError(f"{path}: no child frames requested")
    with open_bag(path) as rec:
        source = str(rec.path)
        present = _tf_topics(rec, topics, source)
        edges = _read_tf_edges(rec, present, [t for t in static_topics if t in present], source)
    mocap = _frame_name(mocap_frame) if mocap_frame is not None else None
    edge_streams: dict[str, PoseStream] = {}

    def edge_stream(child: str) -> PoseStream:
        if child not in edge_streams:
            parent = edges.parent[child]
            edge_streams[child] = edges.dynamic[child].stream(
                f"{parent}->{child}", parent, source)
        return edge_streams[child]

    out: dict[str, PoseStream] = {}
    for name, child_id in wanted.items():
        child = _frame_name(child_id)
        if child not in edges.parent:
            raise InputError(
                f"{source}: frame '{child}' (stream '{name}') is not a child frame on "
                f"{', '.join(present)}; known child frames: {sorted(edges.parent)}"
            )
        chain = _chain(edges, child, mocap, source)
        moving = [c for c in chain[:-1] if c in edges.dynamic]
        if not moving:
            raise InputError(
                f"{source}: frame '{child}' (stream '{name}') only has static transforms up to "
                f"'{chain[-1]}'; a pose stream needs moving transforms on /tf"
            )
        base = edge_stream(moving[0])
        t = base.t_ns
        T = np.broadcast_to(np.eye(4), (t.size, 4, 4)).copy()
        valid = np.ones(t.size, dtype=bool)
        # compose from the top: T_top_child = T_top_.. @ ... @ T_parent_child
        for c in reversed(chain[:-1]):
            if c == moving[0]:
                T_edge = base.T
            elif c in edges.dynamic:
                T_edge, ok = interpolate(edge_stream(c), t, max_gap_s)
                valid &= ok
                T_edge = np.where(ok[:, None, None], T_edge, np.eye(4))
            else:
                T_edge = edges.static[c]
            T = T @ T_edge
        if not np.any(valid):
            raise InputError(
                f"{source}: frame '{child}' (stream '{name}'): the moving transforms of its chain "
                f"{' -> '.join(chain)} never overlap in time (max_gap_s = {max_gap_s})"
            )
        if not np.all(valid):
            log.info("%s: stream '%s': dropped %d of %d samples where a parent transform could "
                     "not be interpolated", source, name, int((~valid).sum()), t.size)
        out[name] = PoseStream(name, t[valid], T[valid], chain[-1], source, base.dropout_t_ns)
    return out


def _message_pose(msgtype: str, msg: Any) -> tuple[float, ...]:
    if msgtype == TRANSFORM_STAMPED:
        return _pose_numbers(msg.transform.translation, msg.transform.rotation)
    if msgtype == POSE_STAMPED:
        return _pose_numbers(msg.pose.position, msg.pose.orientation)
    # PoseWithCovarianceStamped and Odometry: pose.pose
    return _pose_numbers(msg.pose.pose.position, msg.pose.pose.orientation)


def read_pose_topics(path: str | os.PathLike[str],
                     topics: Sequence[str] | Mapping[str, str]) -> dict[str, PoseStream]:
    """Pose streams from pose topics of a ROS 1 or ROS 2 bag, one stream per topic.

    ``topics``: a sequence of topics (streams named after the topic without its leading '/',
    e.g. ``/vicon/robot/robot`` -> ``vicon/robot/robot``, the frame name the Vicon bridge uses)
    or a mapping stream name -> topic. Message types: TransformStamped (``transform``),
    PoseStamped (``pose``), PoseWithCovarianceStamped and Odometry (``pose.pose``); each gives
    ``T_<header.frame_id>_<body>``. The stream's ``frame_id`` is the messages' header frame id,
    which must be the same for every message of a topic."""
    from rigcal.io.recordings.bag import open_bag

    wanted = dict(topics) if isinstance(topics, Mapping) else {
        str(t).lstrip("/") or str(t): t for t in topics}
    if not wanted:
        raise InputError(f"{path}: no pose topics requested")
    with open_bag(path) as rec:
        source = str(rec.path)
        available = rec.topics()
        for name, topic in wanted.items():
            if topic not in available:
                pose_like = sorted(t for t, ty in available.items() if ty in POSE_MSGTYPES)
                raise InputError(
                    f"{source}: topic {topic} (stream '{name}') not in bag; pose topics: "
                    f"{pose_like or 'none'}"
                )
            if available[topic] not in POSE_MSGTYPES:
                raise InputError(
                    f"{source}: topic {topic} (stream '{name}') has type {available[topic]}; "
                    f"expected one of {', '.join(POSE_MSGTYPES)}"
                )
        by_topic = {topic: name for name, topic in wanted.items()}
        if len(by_topic) != len(wanted):
            raise InputError(f"{source}: a topic is requested for two streams: {wanted}")
        samples = {t: _Samples(f"topic {t}") for t in by_topic}
        frames: dict[str, str] = {}
        for topic, msgtype, recv_ns, msg in rec.messages(list(by_topic)):
            frame = _frame_name(msg.header.frame_id)
            if frames.setdefault(topic, frame) != frame:
                raise InputError(
                    f"{source}: topic {topic}: header frame id changes from "
                    f"'{frames[topic]}' to '{frame}'"
                )
            samples[topic].add(_stamp(msg.header, recv_ns), _message_pose(msgtype, msg))
    return {by_topic[t]: s.stream(by_topic[t], frames.get(t, ""), source)
            for t, s in samples.items()}


class PoseSources(NamedTuple):
    """What a bag offers for :func:`read_tf_streams` and :func:`read_pose_topics`."""

    tf_parents: dict[str, str]
    """child frame -> parent frame, over every TFMessage topic."""
    moving_frames: tuple[str, ...]
    """child frames with transforms on a non-static TF topic."""
    pose_topics: dict[str, str]
    """topic -> message type, for the pose types :data:`POSE_MSGTYPES`."""


def list_pose_sources(path: str | os.PathLike[str],
                      static_topics: Sequence[str] = ("/tf_static",)) -> PoseSources:
    """The TF frames and pose topics in a bag (reads every TFMessage once)."""
    from rigcal.io.recordings.bag import open_bag

    with open_bag(path) as rec:
        source = str(rec.path)
        available = rec.topics()
        tf_topics = [t for t, ty in available.items() if ty == TF_MSGTYPE]
        edges = _read_tf_edges(rec, tf_topics, [t for t in static_topics if t in tf_topics],
                               source) if tf_topics else _TfEdges({}, {}, {})
    return PoseSources(dict(edges.parent), tuple(sorted(edges.dynamic)),
                       {t: ty for t, ty in available.items() if ty in POSE_MSGTYPES})

