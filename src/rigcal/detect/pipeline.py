"""Detection over a recording: every sensor's frames through its detector, then board
placements (stable periods matched across sensors), then a :class:`Dataset` for calibration.

The library never prints: progress goes to an optional callback ``progress(done, total)``.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, Protocol

import numpy as np

from rigcal.dataset import Dataset, SensorKind
from rigcal.detect.placements import (
    NS,
    Placement,
    SensorSpec,
    dataset_from_placements,
    match_placements,
    placements_from_windows,
    stable_periods,
)
from rigcal.detect.result import BoardDetection, DetectionFailure, DetectionResult
from rigcal.errors import InputError
from rigcal.io.limits import check_scalar
from rigcal.io.config.rig_config import DetectionRig, SensorSetup
from rigcal.recording import Frame, ImageFrame, StereoFrame


class RecordingLike(Protocol):
    """What detection needs from a recording (a bag or a folder)."""

    def topics(self) -> Mapping[str, str]: ...

    def count(self, topic: str) -> int: ...

    def frames(self, sensor_topics: Mapping[str, tuple[str, str]]) -> Iterator[Frame]: ...


Detector = Callable[[Frame], DetectionResult]


def _config(cls: type, overrides: Mapping[str, Any], where: str):
    allowed = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in overrides if k not in allowed]
    if unknown:
        raise InputError(f"{where}: unknown detector setting(s) {unknown} (allowed: {', '.join(allowed)})")
    converted = {}
    for k, v in overrides.items():
        for j, x in enumerate(v if isinstance(v, list) else [v]):
            if isinstance(x, float) or (isinstance(x, int) and not isinstance(x, bool)):
                check_scalar(x, f"{where}: detector", k + (f"[{j}]" if isinstance(v, list) else ""),
                             "1")
        converted[k] = tuple(v) if isinstance(v, list) else v
    try:
        return cls(**converted)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {exc}") from None
    except InputError as exc:  # the config's own checks name the keys, not the file
        raise InputError(f"{where}: {exc}") from None


def build_detector(setup: SensorSetup, rig: DetectionRig, recording: RecordingLike | None = None) -> Detector:
    """The detector function for one sensor of the rig (heavy imports happen here)."""
    where = f"{rig.source}: sensor '{setup.name}'"
    board = rig.board
    if setup.kind in (SensorKind.RADAR, SensorKind.RADAR3D):
        from rigcal.detect.radar import RadarDetectorConfig, detect_board_radar

        cfg = _config(RadarDetectorConfig, setup.detector, where)
        return lambda f: detect_board_radar(f, cfg)
    if setup.kind == SensorKind.LIDAR:
        from rigcal.detect.lidar import LidarDetectorConfig, detect_board_lidar

        cfg = _config(LidarDetectorConfig, setup.detector, where)
        return lambda f: detect_board_lidar(f, board, cfg)
    from rigcal.extras import require

    require("cv2", f"detecting the board in camera images (sensor '{setup.name}')")
    if setup.input == "mono":
        from rigcal.detect.mono import MonoDetectorConfig, detect_board_mono

        camera = camera_model(setup, rig, recording)
        cfg = _config(MonoDetectorConfig, setup.detector, where)
        return lambda f: detect_board_mono(f, camera, board, cfg)
    from rigcal.detect.stereo import StereoDetectorConfig, detect_board_stereo

    cfg = _config(StereoDetectorConfig, setup.detector, where)
    if setup.input == "stereo_cloud":
        return lambda f: detect_board_stereo(f, board, cfg)
    from rigcal.detect.stereo import detect_board_stereo_pair
    from rigcal.sensors.stereo import StereoRig

    st = setup.stereo
    stereo_rig = None

    def detect_pair(f: Frame) -> DetectionResult:
        nonlocal stereo_rig
        assert isinstance(f, StereoFrame)
        if stereo_rig is None:
            h, w = f.left.shape[:2]
            stereo_rig = StereoRig(
                fx=st["fx"], fy=st["fy"], cx=st["cx"], cy=st["cy"], baseline_m=st["baseline_m"],
                width=w, height=h,
            )
        # SGBM at full resolution only around the board (a coarse pass finds it)
        return detect_board_stereo_pair(f, stereo_rig, board, cfg)

    return detect_pair


def camera_model(setup: SensorSetup, rig: DetectionRig, recording: RecordingLike | None):
    """The camera model of a detection rig's camera: from its intrinsics file, else from the
    recording's CameraInfo (the detector and the report's raw overlays use the same one)."""
    if setup.intrinsics is not None:
        from rigcal.io.config.camchain import read_camera_file, select_camera

        where = f"{rig.source}: sensor '{setup.name}': intrinsics"
        try:
            return select_camera(read_camera_file(setup.intrinsics), str(setup.intrinsics),
                                 camera=setup.camera, names=(setup.name, setup.frame_id),
                                 topic=setup.topic)[1]
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
    if recording is None or not hasattr(recording, "camera_info"):
        raise InputError(
            f"{rig.source}: sensor '{setup.name}': camera_info_topic needs a bag recording "
            "(a folder recording has no CameraInfo); give intrinsics (a file) instead"
        )
    from rigcal.io.config.intrinsics import camera_from_info

    where = f"{rig.source}: sensor '{setup.name}': camera_info_topic {setup.camera_info_topic}"
    try:
        info = recording.camera_info(setup.camera_info_topic)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    return camera_from_info(info, f"{where} in {getattr(recording, 'path', 'the recording')}")


@dataclass(frozen=True)
class SensorStats:
    frames: int = 0
    detections: int = 0
    failures: Mapping[str, int] = field(default_factory=dict)
    stable_periods: int = 0
    placements: int = 0


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class DetectionRun:
    """Everything detection produced: per-sensor results, placements, the dataset, statistics;
    ``frame_ids``: per sensor the ``header.frame_id`` its messages carried (absent when empty);
    ``notes``: where the rig's frame_id and the messages' disagree."""

    results: Mapping[str, tuple[DetectionResult, ...]]
    placements: tuple[Placement, ...]
    dataset: Dataset
    stats: Mapping[str, SensorStats]
    frame_ids: Mapping[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def sensor_frame_ids(rig: DetectionRig, seen: Mapping[str, Counter]) -> tuple[dict[str, str], list[str]]:
    """Each sensor's frame_id: the rig's when given, else the (most common) ``header.frame_id``
    of its messages, else its name; and a note per sensor whose rig frame_id differs from its
    messages' or whose messages carry several."""
    out: dict[str, str] = {}
    notes: list[str] = []
    for s in rig.sensors:
        counts = seen.get(s.name, Counter())
        message = counts.most_common(1)[0][0] if counts else ""
        if len(counts) > 1:
            notes.append(f"sensor '{s.name}': its messages carry several frame_ids "
                         f"({', '.join(sorted(counts))}); using '{s.frame_id if s.frame_id_given else message}'")
        if s.frame_id_given:
            out[s.name] = s.frame_id
            if message and message != s.frame_id:
                notes.append(f"sensor '{s.name}': frame_id '{s.frame_id}' (rig) differs from its "
                             f"messages' frame_id '{message}'; the rig's is used")
        else:
            out[s.name] = message.lstrip("/") or s.frame_id
    return out, notes


def _topics(setup: SensorSetup) -> dict[str, tuple[str, str]]:
    kind = setup.kind.value  # readers convert by kind: clouds, images (camera), radar lists
    if setup.input == "stereo_pair":
        return {f"{setup.name}#left": (setup.topic, kind), f"{setup.name}#right": (setup.right_topic, kind)}
    return {setup.name: (setup.topic, kind)}


def _pair_stereo(name: str, pending: dict, frame: ImageFrame, tol_ns: int = 5_000_000):
    """Pair left/right images of one stereo sensor by timestamp; returns a StereoFrame or None."""
    side = "left" if frame.sensor.endswith("#left") else "right"
    other = "right" if side == "left" else "left"
    for t, img in list(pending[other].items()):
        if abs(t - frame.t_ns) <= tol_ns:
            del pending[other][t]
            left, right = (frame.image, img) if side == "left" else (img, frame.image)
            if left.ndim == 3:
                import cv2

                left = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
                right = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
            return StereoFrame(name, min(t, frame.t_ns), left, right)
    pending[side][frame.t_ns] = frame.image
    # forget unmatched images that are far behind
    for s in ("left", "right"):
        for t in [t for t in pending[s] if frame.t_ns - t > 10 * tol_ns]:
            del pending[s][t]
    return None


_CLOUD = "sensor_msgs/msg/PointCloud2"
_IMAGES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
#: sensor input -> (bag message types, folder-recording contents) it can read
_ACCEPTS = {
    "cloud": ((_CLOUD,), ("points",)),
    "stereo_cloud": ((_CLOUD,), ("points",)),
    "mono": (_IMAGES, ("image",)),
    "stereo_pair": (_IMAGES, ("image",)),
    "radar": ((_CLOUD,), ("points", "radar_csv")),
}


def _check_topic_types(setup: SensorSetup, rig: DetectionRig, recording: RecordingLike,
                       available: Mapping[str, str]) -> None:
    """Refuse a topic whose message type (bag) or file kind (folder) the sensor cannot read,
    before any frame is read."""
    msg_types, contents = _ACCEPTS[setup.input]
    topics = [setup.topic] + ([setup.right_topic] if setup.input == "stereo_pair" else [])
    for topic in topics:
        found = str(available.get(topic, ""))
        if "/" in found:  # a bag: pkg/msg/Type
            ok, expected = found in msg_types, msg_types
        else:  # a folder recording: points, image, radar_csv (several joined by +)
            ok, expected = all(part in contents for part in found.split("+")), contents
        if not ok:
            what = f"a {setup.kind.value}" + (f" with input {setup.input}"
                                              if setup.kind is SensorKind.CAMERA else "")
            raise InputError(
                f"{rig.source}: sensor '{setup.name}': topic {topic} in "
                f"{getattr(recording, 'path', 'the recording')} has type {found or '?'}; "
                f"{what} expects {' or '.join(expected)}"
            )


def run_detection(
    recording: RecordingLike,
    rig: DetectionRig,
    progress: Callable[[int, int], None] | None = None,
) -> DetectionRun:
    """Detect the board in every frame of every sensor, then find the placements."""
    topics: dict[str, tuple[str, str]] = {}
    for s in rig.sensors:
        topics.update(_topics(s))
    available = recording.topics()
    for pseudo, (topic, _) in topics.items():
        if topic not in available:
            sensor = pseudo.split("#")[0]
            raise InputError(
                f"sensor '{sensor}': topic {topic} is not in the recording "
                f"(topics: {', '.join(sorted(available)) or 'none'})"
            )
    for s in rig.sensors:
        _check_topic_types(s, rig, recording, available)
    detectors = {s.name: build_detector(s, rig, recording) for s in rig.sensors}
    total = sum(recording.count(t) for t, _ in topics.values())
    results: dict[str, list[DetectionResult]] = {s.name: [] for s in rig.sensors}
    frames = Counter()
    pending: dict[str, dict] = {s.name: {"left": {}, "right": {}} for s in rig.sensors if s.input == "stereo_pair"}
    done = 0
    span: list[int] = []  # first and last frame time seen
    seen_frames: dict[str, Counter] = {s.name: Counter() for s in rig.sensors}
    for frame in recording.frames(topics):
        done += 1
        frame_id = getattr(frame, "frame_id", "")
        if frame_id and not frame.sensor.endswith("#right"):  # a stereo pair: the left camera's
            seen_frames[frame.sensor.split("#")[0]][frame_id] += 1
        span = [frame.t_ns, frame.t_ns] if not span else [min(span[0], frame.t_ns),
                                                          max(span[1], frame.t_ns)]
        name = frame.sensor.split("#")[0]
        if frame.sensor.endswith(("#left", "#right")):
            frame = _pair_stereo(name, pending[name], frame)
            if frame is None:
                if progress:
                    progress(done, total)
                continue
        frames[name] += 1
        try:
            res = detectors[name](frame)
        except (ValueError, np.linalg.LinAlgError) as exc:  # a numerical dead end, not a crash
            res = DetectionFailure(name, frame.t_ns, "error", f"{type(exc).__name__}: {exc}")
        results[name].append(res)
        if progress:
            progress(done, total)
    ok = {s: [r for r in rs if isinstance(r, BoardDetection)] for s, rs in results.items()}
    kinds = {s.name: s.kind for s in rig.sensors}
    if rig.windows_ns:
        placements = placements_from_windows(ok, rig.windows_ns, rig.stability, kinds)
        periods = {s: [] for s in ok}
        for pl in placements:  # a window no sensor saw the board in would be an all-NaN board
            if not pl.periods:
                seen = (f"the recording spans {span[0] / NS:.3f} to {span[1] / NS:.3f} s"
                        if span else "the recording has no frames of these sensors")
                raise InputError(
                    f"{rig.source}: placements.windows_s[{pl.index}] [{pl.start_ns / NS:g}, "
                    f"{pl.end_ns / NS:g}] s: no sensor detected the board in this window ({seen}); "
                    "expected a window in which the board stands still"
                )
    else:
        periods = {s: stable_periods(s, d, rig.stability, radar=kinds[s].is_radar) for s, d in ok.items()}
        placements = match_placements(periods, min_sensors=rig.min_sensors)
    frame_ids, notes = sensor_frame_ids(rig, seen_frames)
    specs = [SensorSpec(s.name, s.kind, frame_ids[s.name], s.max_elevation_rad) for s in rig.sensors]
    if not placements:
        parts = []
        for s, d in ok.items():
            fails = Counter(r.reason for r in results[s] if isinstance(r, DetectionFailure))
            why = ", ".join(f"{k}: {v}" for k, v in fails.most_common(2))
            parts.append(f"{s}: {len(d)} detections in {frames[s]} frames" + (f" ({why})" if why else ""))
        example = next(
            (r for rs in results.values() for r in rs if isinstance(r, DetectionFailure) and r.detail), None
        )
        hint = f"; e.g. {example.sensor}: {example.detail}" if example is not None else ""
        raise InputError(
            f"{rig.source}: no board placement found in the recording ({'; '.join(parts)}){hint}"
        )
    dataset = dataset_from_placements(placements, specs, rig.board, rig.reference, rig.source)
    stats = {}
    for s in rig.sensors:
        fails = Counter(r.reason for r in results[s.name] if isinstance(r, DetectionFailure))
        stats[s.name] = SensorStats(
            frames=frames[s.name],
            detections=len(ok[s.name]),
            failures=dict(fails),
            stable_periods=len(periods.get(s.name, [])),
            placements=sum(1 for p in placements if s.name in p.periods),
        )
    return DetectionRun(
        results={k: tuple(v) for k, v in results.items()},
        placements=tuple(placements),
        dataset=dataset,
        stats=stats,
        frame_ids={n: c.most_common(1)[0][0] for n, c in seen_frames.items() if c},
        notes=tuple(notes),
    )
