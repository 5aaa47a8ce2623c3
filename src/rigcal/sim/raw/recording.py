"""A time series of raw frames while a board is held at K placements in turn.

Timeline (:class:`BoardTimeline`): the board dwells at placement 0 for ``dwell_s``, is carried to
placement 1 in ``transition_s``, dwells there, ... and ends with the dwell at placement K-1.
During a dwell the board sways slightly about its placement (a smooth random motion of at most
about ``jitter_m`` / ``jitter_deg``, zero at the start and end of the window); during a
transition its position follows a smoothstep from one placement to the next and its
orientation the matching rotation interpolation. The vehicle is parked, so the world frame of
the :class:`~rigcal.sim.raw.scene.Scene` is the rig frame (x forward, y left, z up, on the
ground) and the back wall stays fixed for the whole recording.

Sensors (:class:`RawSensor`) fire at their own rates from their own time offsets (lidar and
cameras 10 Hz, radars 13 Hz by default: unsynchronised). Every frame is produced from the board
pose at its timestamp. Frames come out sorted by time (ties by sensor order).

Randomness: ``rng`` (a Generator or an int seed) first draws the dwell jitter, then one seed per
sensor (in the given order); each sensor draws its noise from its own stream. The same seed gives
the same recording.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping, Sequence, Union

import numpy as np

from rigcal.dataset import BoardGeometry, SensorKind
from rigcal.errors import InputError
from rigcal.geometry.se3 import from_rt, invert
from rigcal.geometry.so3 import so3_exp, so3_log
from rigcal.recording import Frame
from rigcal.sim.raw.camera import PinholeRadtanCamera, StereoCamera, render, render_stereo
from rigcal.sim.raw.lidar import LidarModel, hdl64e, scan, vlp16
from rigcal.sim.raw.radar import RadarModel, automotive_2d, detections
from rigcal.geometry.se3 import as_rigid
from rigcal.sim.raw.scene import Scene
from rigcal.sim.rig import (
    RIG_FRAME,
    SimSensor,
    _as_rng,
    make_rig_placements,
    prius_like_rig,
    visible,
)

SensorModel = Union[LidarModel, PinholeRadtanCamera, StereoCamera, RadarModel]

DEFAULT_RATE_HZ = {"lidar": 10.0, "camera": 10.0, "stereo": 10.0, "radar": 13.0, "radar3d": 13.0}


# --------------------------------------------------------------------------- sensors


@dataclass(frozen=True, eq=False)
class RawSensor:
    """A raw-data sensor on the rig: a model, its pose ``T_rig_sensor`` (sensor frame -> rig;
    a camera's sensor frame is its optical frame, a stereo pair's that of the left camera),
    frame rate [Hz] (default by kind, see :data:`DEFAULT_RATE_HZ`) and the time of its first
    frame ``offset_s`` after the recording starts. Cameras: ``image_noise_sigma`` grey levels,
    ``supersample`` rays per pixel side."""

    name: str
    model: object
    T_rig_sensor: np.ndarray
    rate_hz: float | None = None
    offset_s: float = 0.0
    image_noise_sigma: float = 2.0
    supersample: int = 2

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InputError(f"raw sensor name must be a non-empty string, got {self.name!r}")
        T = as_rigid(self.T_rig_sensor, f"raw sensor '{self.name}'.T_rig_sensor")
        object.__setattr__(self, "T_rig_sensor", T)
        kind = self.kind  # validates the model
        rate = DEFAULT_RATE_HZ[kind] if self.rate_hz is None else self.rate_hz
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            raise InputError(f"raw sensor '{self.name}'.rate_hz must be > 0, got {self.rate_hz!r}")
        object.__setattr__(self, "rate_hz", float(rate))
        if not (math.isfinite(self.offset_s) and self.offset_s >= 0):
            raise InputError(
                f"raw sensor '{self.name}'.offset_s must be >= 0, got {self.offset_s!r}"
            )
        object.__setattr__(self, "offset_s", float(self.offset_s))

    @property
    def kind(self) -> str:
        """'lidar', 'camera', 'stereo', 'radar' (2D) or 'radar3d'."""
        m = self.model
        if isinstance(m, LidarModel):
            return "lidar"
        if isinstance(m, StereoCamera):
            return "stereo"
        if isinstance(m, RadarModel):
            return "radar" if m.dims == 2 else "radar3d"
        if hasattr(m, "unproject") and hasattr(m, "width") and hasattr(m, "height"):
            return "camera"
        raise InputError(
            f"raw sensor '{self.name}': model must be a LidarModel, a camera (width, height, "
            f"unproject), a StereoCamera or a RadarModel, got {type(m).__name__}"
        )

    @property
    def sensor_kind(self) -> SensorKind:
        """The detection-level kind (:class:`rigcal.dataset.SensorKind`)."""
        return {
            "lidar": SensorKind.LIDAR,
            "camera": SensorKind.CAMERA,
            "stereo": SensorKind.CAMERA,
            "radar": SensorKind.RADAR,
            "radar3d": SensorKind.RADAR3D,
        }[self.kind]

    def to_sim_sensor(self) -> SimSensor:
        """The matching detection-level :class:`~rigcal.sim.rig.SimSensor` (pose, field of view,
        range limits) - for :func:`rigcal.sim.rig.make_rig_placements` and ``visible``."""
        m = self.model
        kind = self.kind
        if kind == "lidar":
            return SimSensor(
                self.name, SensorKind.LIDAR, self.T_rig_sensor,
                sigma_m=m.range_sigma_m, max_azimuth_deg=180.0,
                max_elevation_deg=m.vertical_angles_deg[-1],
                min_elevation_deg=m.vertical_angles_deg[0],
                min_range_m=max(m.min_range_m, 0.5), max_range_m=m.max_range_m,
            )
        if kind in ("camera", "stereo"):
            cam = m.camera if kind == "stereo" else m
            az, el = _camera_half_fov_deg(cam)
            return SimSensor(
                self.name, SensorKind.CAMERA, self.T_rig_sensor,
                max_azimuth_deg=az, max_elevation_deg=el,
            )
        return SimSensor(
            self.name, self.sensor_kind, self.T_rig_sensor,
            range_sigma_m=m.range_sigma_m, azimuth_sigma_deg=m.azimuth_sigma_deg,
            elevation_sigma_deg=m.elevation_sigma_deg if m.dims == 3 else None,
            max_azimuth_deg=m.azimuth_fov_deg, max_elevation_deg=m.elevation_fov_deg,
            min_range_m=max(m.min_range_m, 0.5), max_range_m=m.max_range_m,
            max_incidence_deg=m.max_incidence_deg,
        )


def _camera_half_fov_deg(camera) -> tuple[float, float]:
    """Smallest half field of view (azimuth, elevation) [deg] over the image's edge midpoints."""
    w, h = int(camera.width), int(camera.height)
    cx = getattr(camera, "cx", (w - 1) / 2.0)
    cy = getattr(camera, "cy", (h - 1) / 2.0)
    uv = np.array([[-0.5, cy], [w - 0.5, cy], [cx, -0.5], [cx, h - 0.5]], dtype=float)
    out = camera.unproject(uv)
    rays = np.asarray(out[0] if isinstance(out, tuple) else out, dtype=float)
    if rays.shape[-1] == 2:
        rays = np.concatenate([rays, np.ones((4, 1))], axis=1)
    az = np.degrees(np.abs(np.arctan2(rays[:2, 0], rays[:2, 2])))
    el = np.degrees(np.abs(np.arctan2(rays[2:, 1], rays[2:, 2])))
    return float(np.min(az)), float(np.min(el))


# --------------------------------------------------------------------------- timeline


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True, eq=False)
class BoardTimeline:
    """Board placements over time: nominal poses ``T_rig_board`` (K, 4, 4), dwell windows
    ``windows_ns`` (K, 2) [start, end] in ns, and the sway of each dwell (``jitter`` (K, C, 3, 6):
    per component amplitude (rotation [rad], translation [m]), frequency [Hz], phase [rad])."""

    T_rig_board: np.ndarray
    windows_ns: np.ndarray
    jitter: np.ndarray

    def __post_init__(self) -> None:
        T = np.array(self.T_rig_board, dtype=float)
        W = np.array(self.windows_ns, dtype=np.int64)
        J = np.array(self.jitter, dtype=float)
        K = T.shape[0]
        bad_jitter = J.ndim != 4 or J.shape[0] != K or J.shape[2:] != (3, 6)
        if T.shape != (K, 4, 4) or W.shape != (K, 2) or bad_jitter:
            raise InputError(
                f"board timeline: expected T_rig_board (K, 4, 4), windows_ns (K, 2), jitter "
                f"(K, C, 3, 6); got {T.shape}, {W.shape}, {J.shape}"
            )
        if K < 1:
            raise InputError("board timeline needs at least one placement")
        if np.any(W[:, 1] < W[:, 0]) or np.any(W[1:, 0] < W[:-1, 1]):
            raise InputError("board timeline: dwell windows must be ordered and not overlap")
        for a in (T, W, J):
            a.setflags(write=False)
        object.__setattr__(self, "T_rig_board", T)
        object.__setattr__(self, "windows_ns", W)
        object.__setattr__(self, "jitter", J)

    @property
    def num_placements(self) -> int:
        return int(self.T_rig_board.shape[0])

    @property
    def start_ns(self) -> int:
        return int(self.windows_ns[0, 0])

    @property
    def end_ns(self) -> int:
        return int(self.windows_ns[-1, 1])

    def placement_at(self, t_ns: int) -> int:
        """Index of the placement whose dwell window holds ``t_ns`` ([start, end]), -1 otherwise."""
        t = int(t_ns)
        k = int(np.searchsorted(self.windows_ns[:, 0], t, side="right")) - 1
        if k >= 0 and t <= self.windows_ns[k, 1]:
            return k
        return -1

    def pose_at(self, t_ns: int) -> np.ndarray:
        """(4, 4) ``T_rig_board`` at time ``t_ns`` (held at the first / last placement outside
        the timeline)."""
        t = int(t_ns)
        W = self.windows_ns
        k = int(np.searchsorted(W[:, 0], t, side="right")) - 1
        if k < 0:
            return self.T_rig_board[0].copy()
        if t <= W[k, 1]:
            return self._dwell_pose(k, (t - W[k, 0]) * 1e-9, (W[k, 1] - W[k, 0]) * 1e-9)
        if k == self.num_placements - 1:
            return self.T_rig_board[-1].copy()
        s = _smoothstep((t - W[k, 1]) / max(W[k + 1, 0] - W[k, 1], 1))
        Ta, Tb = self.T_rig_board[k], self.T_rig_board[k + 1]
        R = Ta[:3, :3] @ so3_exp(s * so3_log(Ta[:3, :3].T @ Tb[:3, :3]))
        return from_rt(R, (1.0 - s) * Ta[:3, 3] + s * Tb[:3, 3])

    def _dwell_pose(self, k: int, tau_s: float, dwell_s: float) -> np.ndarray:
        J = self.jitter[k]  # (C, 3, 6): amplitude, frequency, phase
        envelope = math.sin(math.pi * tau_s / dwell_s) if dwell_s > 0 else 0.0
        xi = envelope * np.sum(J[:, 0] * np.sin(2.0 * np.pi * J[:, 1] * tau_s + J[:, 2]), axis=0)
        return self.T_rig_board[k] @ from_rt(so3_exp(xi[:3]), xi[3:])


def make_timeline(
    placements: np.ndarray,
    rng: np.random.Generator | int,
    *,
    dwell_s: float = 3.0,
    transition_s: float = 1.5,
    jitter_m: float = 0.002,
    jitter_deg: float = 0.1,
    start_ns: int = 0,
    components: int = 2,
) -> BoardTimeline:
    """A :class:`BoardTimeline` through ``placements`` (K, 4, 4) ``T_rig_board``: dwell
    windows ``[start_ns + k (dwell + transition), ... + dwell]``; sway amplitudes drawn from
    ``rng`` (each component up to ``jitter / components`` per axis, 0.2 - 1.0 Hz)."""
    gen = _as_rng(rng)
    P = np.array(placements, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] < 1:
        raise InputError(f"placements must have shape (K, 4, 4) with K >= 1, got {P.shape}")
    for k in range(P.shape[0]):
        as_rigid(P[k], f"placements[{k}]")
    for name, v in (("dwell_s", dwell_s), ("transition_s", transition_s), ("jitter_m", jitter_m),
                    ("jitter_deg", jitter_deg)):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"make_timeline: {name} must be >= 0, got {v!r}")
    if dwell_s <= 0:
        raise InputError(f"make_timeline: dwell_s must be > 0, got {dwell_s!r}")
    K = P.shape[0]
    C = int(components)
    period_ns = (dwell_s + transition_s) * 1e9
    starts = int(start_ns) + np.round(np.arange(K) * period_ns).astype(np.int64)
    windows = np.stack([starts, starts + int(round(dwell_s * 1e9))], axis=1)
    amp = gen.uniform(-1.0, 1.0, (K, C, 6)) / max(C, 1)
    amp[..., :3] *= math.radians(jitter_deg)
    amp[..., 3:] *= jitter_m
    freq = gen.uniform(0.2, 1.0, (K, C, 6))
    phase = gen.uniform(0.0, 2.0 * math.pi, (K, C, 6))
    return BoardTimeline(P, windows, np.stack([amp, freq, phase], axis=2))


# --------------------------------------------------------------------------- scene


def scene_for_placements(
    placements: np.ndarray,
    board: BoardGeometry = BoardGeometry(),
    wall_distance_m: float = 2.5,
    **scene_options,
) -> Scene:
    """A :class:`Scene` with the board at ``placements[0]`` and one fixed back wall
    ``wall_distance_m`` behind the furthest plate corner of all placements (vertical, facing
    the mean direction the boards face). ``scene_options`` go to :class:`Scene`."""
    P = np.array(placements, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] < 1:
        raise InputError(f"placements must have shape (K, 4, 4) with K >= 1, got {P.shape}")
    z = P[:, :3, 2].copy()
    z[:, 2] = 0.0
    n = z.sum(axis=0)
    if np.linalg.norm(n) < 1e-6:
        raise InputError("scene_for_placements: the boards face no common horizontal direction")
    n /= np.linalg.norm(n)
    probe = Scene(P[0], board=board, **scene_options)
    corners = np.concatenate([probe.with_board(T).plate_corners_world() for T in P])
    c = float(np.min(corners @ n)) - float(wall_distance_m)
    centre = P[:, :3, 3].mean(axis=0)
    point = centre + (c - float(centre @ n)) * n
    return Scene(
        P[0], board=board, wall_point_world=point, wall_normal_world=n,
        wall_distance_m=wall_distance_m, **scene_options,
    )


# --------------------------------------------------------------------------- recording


@dataclass(frozen=True, eq=False)
class SimRecording:
    """A simulated recording and its truth.

    * ``frames``: chronologically sorted raw frames of every sensor;
    * ``sensors``: the :class:`RawSensor` specs (truth poses: ``truth``);
    * ``timeline``: placements, dwell windows (``windows_ns``), board pose at any time;
    * ``frame_T_rig_board`` (F, 4, 4): the board pose at each frame's timestamp;
    * ``frame_placement`` (F,): placement index of each frame, -1 while the board moves;
    * ``scene``: the scene (wall, materials) with the board at placement 0.
    """

    frames: tuple
    sensors: tuple[RawSensor, ...]
    timeline: BoardTimeline
    frame_T_rig_board: np.ndarray
    frame_placement: np.ndarray
    scene: Scene
    board: BoardGeometry = field(default_factory=BoardGeometry)

    @property
    def truth(self) -> Mapping[str, np.ndarray]:
        """``T_rig_sensor`` of every sensor."""
        return {s.name: s.T_rig_sensor for s in self.sensors}

    @property
    def T_rig_board(self) -> np.ndarray:
        """(K, 4, 4) nominal board placements."""
        return self.timeline.T_rig_board

    @property
    def windows_ns(self) -> np.ndarray:
        """(K, 2) dwell windows [start, end] [ns]."""
        return self.timeline.windows_ns

    def truth_T(self, to: str, frm: str) -> np.ndarray:
        """True ``T_to_from`` between two sensors; ``"rig"`` stands for the rig frame."""
        return invert(self._T_rig(to)) @ self._T_rig(frm)

    def _T_rig(self, name: str) -> np.ndarray:
        if name == RIG_FRAME:
            return np.eye(4)
        for s in self.sensors:
            if s.name == name:
                return s.T_rig_sensor
        raise InputError(
            f"unknown sensor '{name}' (simulated sensors: {[s.name for s in self.sensors]}, "
            f"or '{RIG_FRAME}')"
        )

    def frames_of(self, sensor: str) -> tuple:
        """The frames of one sensor, in time order."""
        self._T_rig(sensor)
        return tuple(f for f in self.frames if f.sensor == sensor)

    def dwell_frames(self, k: int, sensor: str | None = None) -> tuple:
        """Frames taken while the board dwelt at placement ``k`` (optionally of one sensor)."""
        if not 0 <= int(k) < self.timeline.num_placements:
            raise InputError(
                f"placement {k} out of range 0..{self.timeline.num_placements - 1}"
            )
        return tuple(
            f for f, p in zip(self.frames, self.frame_placement)
            if p == k and (sensor is None or f.sensor == sensor)
        )


def _check_sensors(sensors: Sequence[RawSensor]) -> tuple[RawSensor, ...]:
    sensors = tuple(sensors)
    if not sensors:
        raise InputError("a recording needs at least one sensor")
    for s in sensors:
        if not isinstance(s, RawSensor):
            raise InputError(f"expected RawSensor values, got {type(s).__name__}")
    names = [s.name for s in sensors]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise InputError(f"duplicate raw sensor names: {dupes}")
    return sensors


def frame_times_ns(sensor: RawSensor, start_ns: int, end_ns: int) -> np.ndarray:
    """(M,) int64 timestamps of ``sensor`` within [start_ns, end_ns]."""
    first = start_ns + int(round(sensor.offset_s * 1e9))
    if first > end_ns:
        return np.zeros(0, dtype=np.int64)
    n = int(math.floor((end_ns - first) * 1e-9 * sensor.rate_hz + 1e-9)) + 1
    return first + np.round(np.arange(n) * (1e9 / sensor.rate_hz)).astype(np.int64)


def _make_frame(sensor: RawSensor, scene: Scene, gen: np.random.Generator, t_ns: int) -> Frame:
    T = sensor.T_rig_sensor
    kind = sensor.kind
    if kind == "lidar":
        return scan(sensor.model, T, scene, gen, t_ns, sensor.name)
    if kind == "stereo":
        return render_stereo(
            sensor.model, T, scene, gen, t_ns, sensor.name,
            noise_sigma=sensor.image_noise_sigma, supersample=sensor.supersample,
        )
    if kind == "camera":
        return render(
            sensor.model, T, scene, gen, t_ns, sensor.name,
            noise_sigma=sensor.image_noise_sigma, supersample=sensor.supersample,
        )
    return detections(sensor.model, T, scene, gen, t_ns, sensor.name)


def iter_recording(
    sensors: Sequence[RawSensor],
    timeline: BoardTimeline,
    scene: Scene,
    rng: np.random.Generator | int,
    progress: Callable[[int, int], None] | None = None,
) -> Iterator[tuple[Frame, np.ndarray, int]]:
    """Yield ``(frame, T_rig_board, placement)`` in time order, one frame at a time (for
    recordings too large to hold in memory). ``scene`` gives the wall and materials; its board
    pose is replaced by the timeline's. Draws one seed per sensor from ``rng`` first.
    ``progress(done, total)`` is called before the first frame and after each."""
    sensors = _check_sensors(sensors)
    gen = _as_rng(rng)
    streams = [np.random.default_rng(int(s)) for s in gen.integers(0, 2**63 - 1, len(sensors))]
    times = [frame_times_ns(s, timeline.start_ns, timeline.end_ns) for s in sensors]
    total = sum(len(ts) for ts in times)
    merged = heapq.merge(*[[(int(t), i) for t in ts] for i, ts in enumerate(times)])
    if progress:
        progress(0, total)
    for done, (t_ns, i) in enumerate(merged, start=1):
        T_board = timeline.pose_at(t_ns)
        frame = _make_frame(sensors[i], scene.with_board(T_board), streams[i], t_ns)
        yield frame, T_board, timeline.placement_at(t_ns)
        if progress:
            progress(done, total)


def simulate_recording(
    sensors: Sequence[RawSensor],
    placements: np.ndarray,
    rng: np.random.Generator | int = 0,
    *,
    dwell_s: float = 3.0,
    transition_s: float = 1.5,
    jitter_m: float = 0.002,
    jitter_deg: float = 0.1,
    start_ns: int = 0,
    scene: Scene | None = None,
    board: BoardGeometry = BoardGeometry(),
    progress: Callable[[int, int], None] | None = None,
) -> SimRecording:
    """Simulate every sensor while the board dwells at each of ``placements`` (K, 4, 4)
    ``T_rig_board`` in turn (see the module docstring). ``scene``: wall and materials (default
    :func:`scene_for_placements`); ``progress(frames done, frames in all)`` after each frame.
    Returns a :class:`SimRecording` holding all frames - for the full-size preset prefer
    :func:`iter_recording`."""
    sensors = _check_sensors(sensors)
    gen = _as_rng(rng)
    timeline = make_timeline(
        placements, gen, dwell_s=dwell_s, transition_s=transition_s, jitter_m=jitter_m,
        jitter_deg=jitter_deg, start_ns=start_ns,
    )
    if scene is None:
        scene = scene_for_placements(timeline.T_rig_board, board=board)
    elif not isinstance(scene, Scene):
        raise InputError(f"simulate_recording: scene must be a Scene, got {type(scene).__name__}")
    frames, poses, placement = [], [], []
    for frame, T_board, k in iter_recording(sensors, timeline, scene, gen, progress):
        frames.append(frame)
        poses.append(T_board)
        placement.append(k)
    P = np.array(poses, dtype=float).reshape(-1, 4, 4)
    idx = np.array(placement, dtype=np.int64)
    P.setflags(write=False)
    idx.setflags(write=False)
    return SimRecording(
        frames=tuple(frames), sensors=sensors, timeline=timeline, frame_T_rig_board=P,
        frame_placement=idx, scene=scene.with_board(timeline.T_rig_board[0]), board=scene.board,
    )


# --------------------------------------------------------------------------- placements


def raw_rig_placements(
    rng: np.random.Generator | int,
    sensors: Sequence[RawSensor],
    num_boards: int,
    *,
    min_ground_clearance_m: float = 0.02,
    scene: Scene | None = None,
    max_candidates: int = 20000,
    **placement,
) -> np.ndarray:
    """(K, 4, 4) ``T_rig_board`` every sensor sees, with the whole plate above the ground.

    Candidates come from :func:`rigcal.sim.rig.make_rig_placements` with the sensors'
    :meth:`RawSensor.to_sim_sensor` (``placement`` keyword arguments are passed on; defaults
    here: ``tilt_deg=10``, ``elevation_spread_deg=2``); a board whose plate would reach below
    ``min_ground_clearance_m`` is lifted until it clears the ground and kept only if every
    sensor still sees it. ``scene`` gives the plate layout (default :class:`Scene`).
    """
    sensors = _check_sensors(sensors)
    gen = _as_rng(rng)
    K = int(num_boards)
    if K < 1:
        raise InputError(f"num_boards must be >= 1, got {num_boards}")
    sims = [s.to_sim_sensor() for s in sensors]
    template = scene if scene is not None else Scene(np.eye(4))
    placement.setdefault("tilt_deg", 10.0)
    placement.setdefault("elevation_spread_deg", 2.0)
    kept: list[np.ndarray] = []
    tried = 0
    while len(kept) < K and tried < max_candidates:
        batch = max(2 * K, 8)
        cand = make_rig_placements(
            gen, sims, batch, min_fraction=0.0, partial_probability=0.0, board=template.board,
            max_candidates=max_candidates, **placement,
        )
        tried += batch
        for T in cand:
            low = float(np.min(template.with_board(T).plate_corners_world()[:, 2]))
            lift = max(0.0, min_ground_clearance_m + template.ground_height_m - low)
            T = T.copy()
            T[2, 3] += lift
            if all(visible(s, T[None], template.board)[0] for s in sims):
                kept.append(T)
            if len(kept) == K:
                break
    if len(kept) < K:
        raise InputError(
            f"raw_rig_placements: found only {len(kept)} of {K} boards above the ground seen "
            f"by every sensor in {tried} candidates"
        )
    return np.array(kept)


# --------------------------------------------------------------------------- presets


def prius_like_raw_rig() -> tuple[RawSensor, ...]:
    """The sensors of :func:`rigcal.sim.rig.prius_like_rig` (same names and poses) as raw
    sensors: ``lidar1`` an HDL-64E-like lidar (10 Hz), ``camera1`` the left camera of a
    rectified 1936 x 1216 stereo pair (fx = fy = 1400 px, 0.12 m baseline, 10 Hz, 40 ms after
    the lidar), ``radar1`` a 2D automotive radar (13 Hz, from 20 ms)."""
    poses = {s.name: s.T_rig_sensor for s in prius_like_rig()}
    cam = PinholeRadtanCamera(1936, 1216, 1400.0, 1400.0, 967.5, 607.5)
    return (
        RawSensor("lidar1", hdl64e(), poses["lidar1"], rate_hz=10.0, offset_s=0.0),
        RawSensor(
            "camera1", StereoCamera(cam, 0.12), poses["camera1"], rate_hz=10.0, offset_s=0.04
        ),
        RawSensor("radar1", automotive_2d(), poses["radar1"], rate_hz=13.0, offset_s=0.02),
    )


def small_raw_rig() -> tuple[RawSensor, ...]:
    """A fast preset for tests: the Prius rig's camera and radar poses with a VLP-16-like lidar
    on a front mount (1.1 m high, so its +-15 deg beams reach the boards) and a 640 x 480
    stereo pair (fx = fy = 600 px, 0.12 m baseline); rates and offsets as
    :func:`prius_like_raw_rig`."""
    poses = {s.name: s.T_rig_sensor for s in prius_like_rig()}
    T_lidar = poses["lidar1"].copy()
    T_lidar[:3, 3] = [1.2, 0.0, 1.1]
    cam = PinholeRadtanCamera(640, 480, 600.0, 600.0, 319.5, 239.5)
    return (
        RawSensor("lidar1", vlp16(), T_lidar, rate_hz=10.0, offset_s=0.0),
        RawSensor(
            "camera1", StereoCamera(cam, 0.12), poses["camera1"], rate_hz=10.0, offset_s=0.04
        ),
        RawSensor("radar1", automotive_2d(), poses["radar1"], rate_hz=13.0, offset_s=0.02),
    )
