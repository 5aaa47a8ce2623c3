"""The frame contract: which static transforms every writer emits for a calibration.

One module decides, for a calibration (and optionally the robot's URDF), the list of
``(parent, child, T_parent_child)`` static transforms; the URDF writer, the ROS 1 / ROS 2 launch
files, the ``ros2 run`` lines, the YAML/JSON exports, ``calibration.launch``,
``absolute.launch`` and the ``frames`` block of ``calibration.yaml`` all take it from
:func:`plan_frames`, so they agree on every frame (``docs/conventions.md``, "Frames in
outputs").

Rules:

1. A calibrated transform is between *measured frames*: a lidar's or radar's own frame
   (x forward, y left, z up) and a camera's **optical frame** (x right, y down, z forward,
   REP 103). ``T_reference_sensor`` is the sensor's measured frame in the reference's.
2. Without a URDF a sensor's ``frame_id`` names its measured frame: a camera's ``frame_id``
   is its optical frame. Writers publish ``T_<reference frame_id>_<frame_id>``.
3. With a URDF each ``frame_id`` is looked up among its links (REP 103/105):

   * a camera whose ``frame_id`` names a body-convention link ``B`` with one optical child
     ``O`` (a fixed joint with ``rpy = (-pi/2, 0, -pi/2)``), or names ``O`` itself: the
     calibrated pose is ``O``'s; writers publish ``(parent, B)`` and ``(B, O)`` with the
     URDF's optical joint, and the URDF writer moves the joint carrying ``B``;
   * any other ``frame_id`` that is a link: the calibrated pose is that link's;
   * a ``frame_id`` the URDF lacks: as without a URDF.

4. Every calibrated transform hangs from one root: the reference sensor's frame (resolved like
   any sensor: a camera reference with a separate optical link gives the root ``B`` and the
   edge ``(B, O)``), or the body frame of an absolute (``body_frame``) or motion-capture
   (``robot_frame``) calibration; ``body_link`` renames it.
5. Directions a calibration only bounds (a 2D radar's z, roll, pitch without a prior,
   ``bounded`` of :class:`~rigcal.io.results.calibration_files.CalibrationTransforms`) keep the
   URDF's values where the URDF has the sensor's frame (relative to the reference's):
   :func:`rigcal.io.results.bounded.keep_nominal`; without a URDF, the pose recorded as kept
   (``kept_from_urdf`` in the ``frames`` block), else the estimate. ``write_bounded`` writes
   the estimate anyway.

``calibration.yaml`` records the outcome (``frames``: the reference frame, the URDF used, each
sensor's link and measured frame, and the transforms), so that a later export without the URDF
publishes the same frames (:func:`recorded_frames`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rigcal.errors import InputError
from rigcal.geometry.se3 import as_rigid, from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy

__all__ = [
    "CONVENTION",
    "OPTICAL_RPY",
    "T_BODY_OPTICAL",
    "FramePlan",
    "SensorFrame",
    "StaticTransform",
    "camera_frames_without_urdf",
    "edges_of",
    "frames_block",
    "plan_frames",
    "plan_with_checks",
    "quaternion_xyzw",
    "recorded_frames",
    "resolve_in_urdf",
    "transform_entry",
]

#: REP 103: a camera's optical frame (x right, y down, z forward) in its body-convention link
#: (x forward, y left, z up) is the fixed rotation rpy = (-pi/2, 0, -pi/2).
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)


def _optical() -> np.ndarray:
    T = from_rt(matrix_from_rpy(np.asarray(OPTICAL_RPY)), np.zeros(3))
    T.setflags(write=False)
    return T


T_BODY_OPTICAL = _optical()
"""``T_body_optical`` (4, 4): the optical frame's pose in its body-convention camera link."""

CONVENTION = (
    "T_parent_child: p_parent = T_parent_child @ p_child (the child frame's pose in the parent "
    "frame); a calibrated transform is between measured frames: a lidar's or radar's own frame "
    "(x forward, y left, z up), a camera's optical frame (x right, y down, z forward, REP 103); "
    "a camera's frame_id names its optical frame unless a URDF gives it a separate optical "
    "child link; xyz in m; rpy = (roll, pitch, yaw) in rad with R = Rz(yaw) @ Ry(pitch) @ "
    "Rx(roll); quaternion_xyzw = (x, y, z, w)"
)

_IDENTITY = np.eye(4)
_IDENTITY.setflags(write=False)


class SensorFrame(NamedTuple):
    """How one calibrated frame is named in the outputs.

    ``frame_id``: the name the calibration gives it; ``link``: the frame published under the
    parent (a camera's body-convention link, else the measured frame itself); ``measured``:
    the frame whose pose the calibration gives (a camera's optical frame); ``T_link_measured``
    (4, 4): identity unless ``link != measured`` (then the URDF's optical joint). ``in_urdf``:
    whether the URDF has ``link`` (None without a URDF)."""

    sensor: str
    kind: str | None
    frame_id: str
    link: str
    measured: str
    T_link_measured: np.ndarray
    in_urdf: bool | None = None


class StaticTransform(NamedTuple):
    """One published transform: ``T_parent_child`` (4, 4); ``sensor`` it belongs to;
    ``calibrated`` False for a fixed optical joint copied from the URDF (or the record)."""

    parent: str
    child: str
    T_parent_child: np.ndarray
    sensor: str = ""
    calibrated: bool = True


@dataclass(frozen=True, eq=False)
class FramePlan:
    """What every writer emits for one calibration (see the module docstring).

    ``root``: the parent of every calibrated transform; ``reference``: how the reference (or
    the body frame) is named; ``sensors``: every other calibrated frame, in calibration order;
    ``transforms``: the static transforms, a tree under ``root`` (parents before children);
    ``urdf``: the URDF the links were resolved in (its name), if any; ``notes``: one line per
    frame whose name was resolved through the URDF."""

    root: str
    reference: SensorFrame
    sensors: tuple[SensorFrame, ...]
    transforms: tuple[StaticTransform, ...]
    urdf: str | None = None
    notes: tuple[str, ...] = ()
    body: bool = False  # the root is a body frame (absolute, motion capture), not a sensor
    #: frame_id -> the bounded directions whose values are the URDF's (rule 5)
    kept: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    def T_root(self, frame: str) -> np.ndarray:
        """``T_root_frame`` (4, 4) by composing the published transforms (a new array)."""
        by_child = {t.child: t for t in self.transforms}
        T = np.eye(4)
        current = frame
        seen = set()
        while current != self.root:
            if current not in by_child or current in seen:
                raise InputError(f"frame '{frame}' is not published under '{self.root}'")
            seen.add(current)
            edge = by_child[current]
            T = np.asarray(edge.T_parent_child) @ T
            current = edge.parent
        return T

    def sensor_frame(self, frame_id: str) -> SensorFrame:
        for s in (self.reference, *self.sensors):
            if s.frame_id == frame_id:
                return s
        raise InputError(f"no calibrated frame '{frame_id}'")

    def differs_from(self, other: "FramePlan") -> list[str]:
        """Frames (``frame_id``) whose published names differ between two plans."""
        mine = {s.frame_id: (s.link, s.measured) for s in (self.reference, *self.sensors)}
        theirs = {s.frame_id: (s.link, s.measured) for s in (other.reference, *other.sensors)}
        return [f for f in mine if f in theirs and mine[f] != theirs[f]]


# --------------------------------------------------------------------------------------------
# resolving one frame


def _is_optical_joint(joint: Any) -> bool:
    if joint is None or joint.type != "fixed":
        return False
    return bool(np.allclose(joint.origin.matrix, T_BODY_OPTICAL, atol=1e-6))


def _plain(sensor: str, kind: str | None, frame_id: str, in_urdf: bool | None) -> SensorFrame:
    return SensorFrame(sensor, kind, frame_id, frame_id, frame_id, _IDENTITY, in_urdf)


def _matrix(joint: Any) -> np.ndarray:
    T = joint.origin.matrix
    T.setflags(write=False)
    return T


def resolve_in_urdf(urdf: Any, sensor: str, kind: str | None, frame_id: str) -> tuple[SensorFrame, str | None]:
    """How ``frame_id`` of a sensor of ``kind`` (None: unknown) is named with ``urdf`` (rule 3
    of the module docstring), and a note when the URDF changed its meaning (else None)."""
    who = f"{kind} '{sensor}'" if kind and sensor else f"frame '{frame_id}'"
    if frame_id not in urdf.links:
        joint = urdf.joints.get(frame_id)
        if joint is not None:  # a joint's name: its child link
            return SensorFrame(sensor, kind, frame_id, joint.child, joint.child, _IDENTITY, True), None
        return _plain(sensor, kind, frame_id, False), None
    carrier = urdf.joint_to(frame_id)
    if kind in ("camera", None) and _is_optical_joint(carrier):
        body = carrier.parent
        note = (f"{who}: frame '{frame_id}' is the optical child of '{body}' (joint "
                f"'{carrier.name}', REP 103): published as '{body}' with its optical joint kept")
        return SensorFrame(sensor, kind, frame_id, body, frame_id, _matrix(carrier), True), note
    if kind != "camera":
        return _plain(sensor, kind, frame_id, True), None
    children = [j for j in urdf.joints.values() if j.parent == frame_id and _is_optical_joint(j)]
    if len(children) > 1:
        raise InputError(
            f"{urdf.source}: camera '{sensor}': link '{frame_id}' has {len(children)} optical "
            f"children ({', '.join(j.child for j in children)}); set the sensor's frame_id to "
            "the optical frame the camera uses"
        )
    if children:
        joint = children[0]
        note = (f"{who}: link '{frame_id}' follows the body convention (x forward, REP 103) and "
                f"has the optical child '{joint.child}' (joint '{joint.name}'): the calibrated "
                f"optical pose is '{joint.child}''s; '{frame_id}' is published with the optical "
                "joint kept")
        return SensorFrame(sensor, kind, frame_id, frame_id, joint.child, _matrix(joint), True), note
    note = (f"{who}: link '{frame_id}' has no optical child: it is given the camera's optical "
            "pose (x right, y down, z forward)")
    return _plain(sensor, kind, frame_id, True), note


# --------------------------------------------------------------------------------------------
# the plan


def _recorded_frame(recorded: Mapping[str, Any], sensor: str, kind: str | None,
                    frame_id: str) -> SensorFrame:
    entry = recorded.get(frame_id)
    if entry is None:
        return _plain(sensor, kind, frame_id, None)
    link, measured, T = entry
    return SensorFrame(sensor, kind, frame_id, link, measured, T, None)


def plan_frames(
    cal: Any,
    urdf: Any = None,
    body_link: str | None = None,
    *,
    use_recorded: bool = True,
    write_bounded: bool = False,
) -> FramePlan:
    """The static transforms every writer emits for ``cal`` (a
    :class:`~rigcal.io.results.calibration_files.CalibrationTransforms`), resolving frame names
    in ``urdf`` (a parsed :class:`~rigcal.io.results.urdf.Urdf`) when given, else in what
    ``cal`` recorded (``use_recorded``), else by rule 2. ``body_link`` renames the frame the
    calibration is relative to (the reference sensor's frame or the body frame). Bounded
    directions as rule 5 (``write_bounded``: the estimate).

    InputError when two frames would be published under one name, or a frame is the root."""
    parent = body_link or cal.parent_frame
    kinds = dict(cal.kinds or {})
    names = dict(getattr(cal, "names", {}) or {})
    recorded = dict(getattr(cal, "recorded", {}) or {}) if use_recorded else {}
    body = cal.kind in ("absolute", "mocap")
    notes: list[str] = []

    def resolve(sensor: str, kind: str | None, frame_id: str) -> SensorFrame:
        if urdf is not None:
            frame, note = resolve_in_urdf(urdf, sensor, kind, frame_id)
            if note:
                notes.append(note)
            return frame
        return _recorded_frame(recorded, sensor, kind, frame_id)

    if body:  # a body frame is taken as it is named
        reference = _plain("", None, parent, None if urdf is None else parent in urdf.links)
    else:
        reference = resolve(names.get(cal.parent_frame, ""), kinds.get(cal.parent_frame), parent)
    root = reference.link
    T_root_ref = np.asarray(reference.T_link_measured, dtype=float)
    transforms: list[StaticTransform] = []
    if reference.link != reference.measured:
        transforms.append(StaticTransform(root, reference.measured, reference.T_link_measured,
                                          reference.sensor, calibrated=False))
    sensors: list[SensorFrame] = []
    ref_who = (f"the reference sensor '{reference.sensor}' (frame '{reference.frame_id}')"
               if reference.sensor else f"the reference frame '{reference.frame_id}'")
    owner: dict[str, str] = {root: ref_who, reference.measured: ref_who}

    def claim(frame: str, who: str) -> None:
        if frame in owner:
            other = owner[frame]
            raise InputError(
                f"{who} and {other} would both publish the frame '{frame}'; a TF tree needs one "
                "frame per sensor (give each sensor its own frame_id)"
            )
        owner[frame] = who

    bounded = dict(getattr(cal, "bounded", {}) or {})
    kept_recorded = dict(getattr(cal, "kept", {}) or {}) if use_recorded else {}
    kept: dict[str, tuple[str, ...]] = {}
    for frame_id, T in cal.transforms.items():
        sensor = names.get(frame_id, "")
        s = resolve(sensor, kinds.get(frame_id), frame_id)
        who = f"sensor '{sensor}' (frame '{frame_id}')" if sensor else f"frame '{frame_id}'"
        claim(s.link, who)
        if s.measured != s.link:
            claim(s.measured, who)
        T_ref_measured = as_rigid(T, f"{cal.source or 'calibration'}: T_{cal.parent_frame}_{frame_id}")
        dirs = tuple(bounded.get(frame_id, ()))
        if dirs and not write_bounded:  # rule 5
            nominal = _nominal(urdf, reference, s) if urdf is not None else None
            if nominal is not None:
                from rigcal.io.results.bounded import keep_nominal

                T_ref_measured, kept[frame_id] = keep_nominal(nominal, T_ref_measured, dirs), dirs
            elif urdf is None and frame_id in kept_recorded:
                T_ref_measured, kept[frame_id] = np.asarray(kept_recorded[frame_id], dtype=float), dirs
        T_root_link = T_root_ref @ T_ref_measured @ invert(s.T_link_measured)
        T_root_link.setflags(write=False)
        transforms.append(StaticTransform(root, s.link, T_root_link, sensor, True))
        if s.measured != s.link:
            transforms.append(StaticTransform(s.link, s.measured, s.T_link_measured, sensor, False))
        sensors.append(s)
    return FramePlan(root, reference, tuple(sensors), tuple(transforms),
                     getattr(urdf, "source", None) if urdf is not None else getattr(cal, "urdf", None),
                     tuple(notes), body, kept)


def _nominal(urdf: Any, reference: SensorFrame, s: SensorFrame) -> np.ndarray | None:
    """The URDF's pose of a sensor's measured frame in the reference's measured frame (forward
    kinematics), or None when the URDF lacks either or the chain is not fixed."""
    from rigcal.io.results.urdf import forward_kinematics

    if reference.measured not in urdf.links or s.measured not in urdf.links:
        return None
    try:
        return forward_kinematics(urdf, reference.measured, s.measured)
    except InputError:
        return None


def camera_frames_without_urdf(plan: FramePlan) -> list[SensorFrame]:
    """Cameras whose frame_id is published as their optical frame only by rule 2 (no URDF, no
    record) and whose name does not say "optical": if the robot's link of that name follows
    the body convention, the published pose is 120 deg off; the CLI warns about them."""
    if plan.urdf is not None:
        return []
    frames = [plan.reference] + list(plan.sensors)
    return [s for s in frames if s.kind == "camera" and s.link == s.measured
            and "optical" not in s.frame_id.lower()]


# --------------------------------------------------------------------------------------------
# plain data (calibration.yaml's ``frames`` block) and back


def quaternion_xyzw(R: np.ndarray) -> list[float]:
    """The unit quaternion (x, y, z, w) with ``w >= 0`` of a rotation (3, 3), as floats."""
    from rigcal.mocap.streams import matrix_to_quat_xyzw

    return [float(v) + 0.0 for v in matrix_to_quat_xyzw(np.asarray(R, dtype=float)[:3, :3])]


def transform_entry(T: np.ndarray) -> dict[str, Any]:
    """``T_parent_child`` (4x4 rows), ``xyz`` [m], ``rpy`` [rad] and ``quaternion_xyzw``."""
    from rigcal.io.results.urdf import origin_from_matrix

    m = np.asarray(T, dtype=float)
    xyz, rpy = origin_from_matrix(m)
    return {
        "T_parent_child": [[float(v) + 0.0 for v in row] for row in m],
        "xyz": [float(v) + 0.0 for v in xyz],
        "rpy": [float(v) + 0.0 for v in rpy],
        "quaternion_xyzw": quaternion_xyzw(m),
    }


def frames_block(plan: FramePlan) -> dict[str, Any]:
    """The ``frames`` block of ``calibration.yaml``: the convention, the reference frame, the
    URDF used (or None), each sensor's names and the static transforms every writer emits."""

    def entry(s: SensorFrame) -> dict[str, Any]:
        out: dict[str, Any] = {"frame_id": s.frame_id, "link": s.link, "measured_frame": s.measured}
        if s.link != s.measured:
            out["T_link_measured"] = [[float(v) + 0.0 for v in row] for row in s.T_link_measured]
        if s.frame_id in plan.kept:  # rule 5: what is published, for a later plan without the URDF
            T = invert(plan.T_root(plan.reference.measured)) @ plan.T_root(s.measured)
            out["kept_from_urdf"] = {"directions": list(plan.kept[s.frame_id]),
                                     "T_reference_measured": [[float(v) + 0.0 for v in row] for row in T]}
        return out

    return {
        "convention": CONVENTION,
        "reference_frame": plan.reference.frame_id,
        "root": plan.root,
        "urdf": plan.urdf,
        "reference": entry(plan.reference),
        "sensors": {(s.sensor or s.frame_id): entry(s) for s in plan.sensors},
        "static_transforms": [
            {"parent": t.parent, "child": t.child, "sensor": t.sensor,
             "calibrated": bool(t.calibrated), **transform_entry(t.T_parent_child)}
            for t in plan.transforms
        ],
    }


def _name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value or any(c.isspace() for c in value):
        raise InputError(f"{where}: expected a frame name without whitespace, got {value!r}")
    return value


def recorded_frames(block: Any, source: str) -> tuple[str | None, dict[str, tuple[str, str, np.ndarray]], str | None]:
    """(reference frame, ``{frame_id: (link, measured, T_link_measured)}``, URDF name) from a
    ``frames`` block of ``calibration.yaml`` (None when absent); InputError naming the key."""
    if block is None:
        return None, {}, None
    if not isinstance(block, dict):
        raise InputError(f"{source}: frames: expected a mapping, got {type(block).__name__}")
    reference = block.get("reference_frame")
    if reference is not None:
        reference = _name(reference, f"{source}: frames.reference_frame")
    out: dict[str, tuple[str, str, np.ndarray]] = {}
    entries = []
    if isinstance(block.get("reference"), dict):
        entries.append(("reference", block["reference"]))
    sensors = block.get("sensors") or {}
    if not isinstance(sensors, dict):
        raise InputError(f"{source}: frames.sensors: expected a mapping")
    entries += [(f"sensors.{k}", v) for k, v in sensors.items()]
    for key, e in entries:
        where = f"{source}: frames.{key}"
        if not isinstance(e, dict):
            raise InputError(f"{where}: expected a mapping with frame_id, link, measured_frame")
        frame_id = _name(e.get("frame_id"), f"{where}.frame_id")
        link = _name(e.get("link", frame_id), f"{where}.link")
        measured = _name(e.get("measured_frame", frame_id), f"{where}.measured_frame")
        if link != measured:
            if "T_link_measured" not in e:
                raise InputError(f"{where}: link '{link}' differs from measured_frame "
                                 f"'{measured}' but T_link_measured is missing")
            T = as_rigid(e["T_link_measured"], f"{where}.T_link_measured")
        else:
            T = _IDENTITY
        out[frame_id] = (link, measured, T)
    urdf = block.get("urdf")
    return reference, out, urdf if isinstance(urdf, str) else None


def edges_of(transforms: Mapping[str, Any] | Sequence[Any], parent_frame: str | None) -> list[StaticTransform]:
    """``StaticTransform`` edges from either ``{child: T_parent_child}`` with one
    ``parent_frame`` (the writers' older form) or a sequence of edges/``(parent, child, T)``."""
    if isinstance(transforms, Mapping):
        if parent_frame is None:
            raise InputError("static transforms: a mapping child -> T needs the parent frame")
        return [StaticTransform(parent_frame, str(c), T) for c, T in transforms.items()]
    out = []
    for item in transforms:
        if isinstance(item, StaticTransform):
            out.append(item)
        else:
            p, c, T = item
            out.append(StaticTransform(p, c, T))
    return out


def plan_with_checks(cal: Any, urdf: Any = None, body_link: str | None = None,
                     write_bounded: bool = False) -> tuple[FramePlan, list[str]]:
    """:func:`plan_frames` and the warnings a user must see where outputs could disagree:

    * with ``urdf``: frames the URDF names differently from what the calibration recorded (or,
      without a record, from rule 2, which files written without the URDF followed, e.g. the
      ``calibration.launch`` of ``rigcal calibrate``): those files publish another frame;
    * without ``urdf`` and without a record: cameras whose frame_id does not say "optical" are
      published as optical frames; a body-convention link of that name would be 120 deg off.
    """
    plan = plan_frames(cal, urdf, body_link, write_bounded=write_bounded)
    warnings: list[str] = []
    if urdf is not None:
        recorded = bool(getattr(cal, "recorded", None))
        other = plan_frames(cal, None, body_link, use_recorded=recorded)
        for frame_id in plan.differs_from(other):
            mine, theirs = plan.sensor_frame(frame_id), other.sensor_frame(frame_id)
            who = f"sensor '{mine.sensor}'" if mine.sensor else f"frame '{frame_id}'"
            what = (f"recorded in {cal.source} ('{theirs.link}' -> '{theirs.measured}')" if recorded
                    else f"files written without this URDF (e.g. calibration.launch) publish its "
                    f"measured pose as '{theirs.measured}'")
            warnings.append(
                f"{who}: {urdf.source} names its measured frame '{mine.measured}' (published "
                f"under '{mine.link}'); {what}, which disagrees: use the outputs written with "
                f"this URDF (rigcal export CALIBRATION --urdf {urdf.source})"
            )
    else:
        for s in camera_frames_without_urdf(plan):
            who = f"camera '{s.sensor}'" if s.sensor else f"camera frame '{s.frame_id}'"
            warnings.append(
                f"{who}: frame '{s.frame_id}' is published as the camera's optical frame (x right, "
                f"y down, z forward); if the robot's '{s.frame_id}' follows the body convention (x "
                "forward) with a separate optical child, give the robot's URDF (rigcal export "
                "--urdf, or calibrate --initial) so the optical child gets this pose"
            )
    return plan, warnings
