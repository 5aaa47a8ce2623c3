"""URDF: parse text into values, forward kinematics over fixed joints, rewrite joint origins.

Conventions (``docs/urdf.md``):

* a joint's ``<origin xyz="x y z" rpy="r p y"/>`` is ``T_parent_child``, the child link's pose
  in the parent link's frame: ``p_parent = R @ p_child + (x, y, z)`` with
  ``R = Rz(y) @ Ry(p) @ Rx(r)`` (roll about the parent's fixed x axis first, then pitch about
  its fixed y, then yaw about its fixed z; the same matrix as intrinsic Z-Y'-X''). A missing
  ``xyz`` or ``rpy`` (or a missing ``<origin>``) means zeros;
* ``forward_kinematics(urdf, a, b)`` is ``T_a_b`` (``p_a = T_a_b @ p_b``), the product of the
  joint origins along the tree path; only fixed joints are allowed on the path;
* a calibration update ``{sensor_link: T_body_sensor}`` is the sensor link's pose in the body
  link's frame; :func:`update_urdf_text` rewrites one joint origin per sensor so that the
  written file's forward kinematics reproduce it;
* the original tool's calibration YAML means ``p_target = transform @ p_source``, i.e.
  ``transform = T_target_source``.

Rewriting is textual: the parser records the character span of every joint's ``<origin>`` tag
and of its ``xyz``/``rpy`` values, and only those values are replaced (numbers in shortest
round-trip ``repr`` form), so comments, attribute order, quoting, indentation and line endings
stay byte-identical. XML with a DOCTYPE or ENTITY declaration is refused before parsing
(entity expansion, external entities); parsing also runs through ``defusedxml`` when installed.
"""

from __future__ import annotations

import bisect
import itertools
import math
import os
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple
from xml.parsers import expat

import numpy as np

from rigcal.errors import GeometryError, InputError
from rigcal.io.limits import read_limited
from rigcal.geometry.se3 import as_rigid, from_rt, invert
from rigcal.geometry.so3 import matrix_from_rpy, rpy_from_matrix
from rigcal.io._text import is_finite_number, load_yaml, type_name
from rigcal.io.atomic import atomic_write_bytes

try:  # defence in depth; our own guard below refuses DTDs and entities either way
    import defusedxml.ElementTree as _defused_et
except ImportError:  # pragma: no cover - depends on the environment
    _defused_et = None

JOINT_TYPES = ("fixed", "revolute", "continuous", "prismatic", "floating", "planar")
"""Joint types a URDF may declare; only ``fixed`` joints have a pose without joint positions."""

FK_TOLERANCE = 1e-9
"""Largest difference between a requested ``T_body_sensor`` and the written file's FK."""

_BOM = b"\xef\xbb\xbf"
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\Z")
_COMMENT = re.compile(r"<!--.*?-->", re.S)
_DECLARATION = re.compile(r"<!(DOCTYPE|ENTITY)\b")
_TAG_NAME = re.compile(r"<([^\s/>]+)")
_TAG_ATTR = re.compile(r"\s+([^\s=/>]+)\s*=\s*(?:\"([^\"]*)\"|'([^']*)')")
_TAG_CLOSE = re.compile(r"\s*(/?)>")


# --------------------------------------------------------------------------------------------
# values


class Span(NamedTuple):
    """Characters ``text[start:end]`` of the parsed text."""

    start: int
    end: int


class Origin(NamedTuple):
    """A joint's ``<origin>``: values, and where they are in the text (for rewriting).

    ``xyz`` [m] and ``rpy`` [rad] (``R = Rz(y) Ry(p) Rx(r)``) are zeros when absent. ``tag`` is
    the ``<origin .../>`` start tag (None if the joint has no origin); ``xyz_value`` and
    ``rpy_value`` are the characters between the quotes (None if the attribute is absent);
    ``name_end`` is just after ``<origin``, ``attrs_end`` just after its last attribute.
    """

    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    tag: Span | None = None
    xyz_value: Span | None = None
    rpy_value: Span | None = None
    name_end: int = -1
    attrs_end: int = -1
    quote: str = '"'

    @property
    def matrix(self) -> np.ndarray:
        """``T_parent_child`` (4, 4)."""
        return matrix_from_origin(self.xyz, self.rpy)


class Link(NamedTuple):
    name: str
    line: int


class Joint(NamedTuple):
    """A joint: ``origin`` is ``T_parent_child``; ``line`` is 1-based; ``element`` spans the
    whole ``<joint>`` element and ``child_element`` its ``<child>`` element."""

    name: str
    type: str
    parent: str
    child: str
    origin: Origin
    line: int
    element: Span
    child_element: Span


@dataclass(frozen=True)
class Urdf:
    """A parsed URDF: its links and joints in file order, and the text they came from."""

    source: str
    text: str
    robot_name: str
    links: Mapping[str, Link]
    joints: Mapping[str, Joint]
    parent_joint: Mapping[str, str]
    """child link -> the joint that carries it (the root link has none)."""

    def link(self, name: str) -> Link:
        try:
            return self.links[name]
        except KeyError:
            raise InputError(
                f"{self.source}: no link named '{name}' (links: {_names(self.links)})"
            ) from None

    def joint(self, name: str) -> Joint:
        try:
            return self.joints[name]
        except KeyError:
            raise InputError(
                f"{self.source}: no joint named '{name}' (joints: {_names(self.joints)})"
            ) from None

    def joint_to(self, link: str) -> Joint | None:
        """The joint whose child is ``link`` (None for a root link)."""
        self.link(link)
        name = self.parent_joint.get(link)
        return None if name is None else self.joints[name]


class JointUpdate(NamedTuple):
    """One planned origin change: ``joint`` gets ``xyz``/``rpy`` so that FK from the body link
    to ``sensor_link`` equals the requested ``T_body_sensor`` (requested under ``key``)."""

    key: str
    joint: str
    sensor_link: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    T_body_sensor: np.ndarray
    """The request as used (its rotation block projected onto SO(3) if it was not exact)."""


class OriginalCalibration(NamedTuple):
    """The original tool's calibration YAML: ``p_target = T_target_source @ p_source``."""

    source: str
    target: str
    T_target_source: np.ndarray


class WrittenUrdf(NamedTuple):
    path: Path
    backup: Path | None
    skipped: tuple[str, ...] = ()  # calibrated frames the URDF has no link for (left out)
    added: tuple[str, ...] = ()  # links appended with a fixed joint to the body link
    notes: tuple[str, ...] = ()  # how each calibrated frame was mapped (optical frames)


def _names(mapping: Mapping[str, Any], limit: int = 12) -> str:
    names = list(mapping)
    shown = ", ".join(names[:limit])
    if len(names) > limit:
        shown += f", ... ({len(names)} in all)"
    return shown or "none"


# --------------------------------------------------------------------------------------------
# numbers and rotations


def format_float(value: float) -> str:
    """Shortest text that reads back as exactly ``value`` (``repr``); ``-0``/``0`` as ``0`` and
    integral values without ``.0`` (``3.0`` -> ``3``)."""
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"cannot write a non-finite number ({v}) into a URDF")
    if v == 0.0:
        return "0"
    text = repr(v)
    return text[:-2] if text.endswith(".0") else text


def rpy_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) [rad] with ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` as plain floats
    (see :func:`rigcal.geometry.so3.rpy_from_matrix`)."""
    r, p, y = (float(v) for v in rpy_from_matrix(np.asarray(R, dtype=float)))
    return r, p, y


def matrix_from_origin(xyz: Any, rpy: Any) -> np.ndarray:
    """``T_parent_child`` (4, 4) of a URDF origin: translation ``xyz`` [m], rotation
    ``Rz(y) @ Ry(p) @ Rx(r)`` from ``rpy = (r, p, y)`` [rad]."""
    return from_rt(matrix_from_rpy(np.asarray(rpy, dtype=float)), np.asarray(xyz, dtype=float))


def origin_from_matrix(
    T_parent_child: np.ndarray,
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(xyz, rpy) of a rigid (4, 4) transform, the inverse of :func:`matrix_from_origin`."""
    T = np.asarray(T_parent_child, dtype=float)
    xyz = tuple(float(v) for v in T[:3, 3])
    return xyz, rpy_from_rotation(T[:3, :3])  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# parsing


class _Refused(Exception):
    """Raised from expat handlers to stop at a DTD or entity."""


def _line_column(text: str, index: int) -> tuple[int, int]:
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


def _refuse_declarations(text: str, source: str) -> None:
    """Refuse DOCTYPE/ENTITY declarations anywhere outside comments, before any parser runs."""
    blanked = _COMMENT.sub(lambda m: re.sub(r"[^\n]", " ", m.group()), text)
    match = _DECLARATION.search(blanked)
    if match is not None:
        line, column = _line_column(text, match.start())
        raise InputError(
            f"{source}: line {line}, column {column}: refusing XML with a <!{match.group(1)} "
            "...> declaration (a URDF needs no DTD; DTDs allow entity expansion and external "
            "entity attacks)"
        )


def _defused_check(text: str, source: str) -> None:
    """Parse once with defusedxml (when installed), DTDs forbidden; wrap its errors."""
    if _defused_et is None:
        return
    try:
        _defused_et.fromstring(text, forbid_dtd=True)
    except SyntaxError as exc:  # xml.etree.ElementTree.ParseError
        position = getattr(exc, "position", None)
        where = f"line {position[0]}, column {position[1] + 1}: " if position else ""
        detail = re.sub(r":? line \d+, column \d+$", "", str(exc))
        raise InputError(f"{source}: {where}malformed XML: {detail}") from exc
    except ValueError as exc:  # defusedxml.DefusedXmlException and subclasses
        raise InputError(
            f"{source}: refusing hostile XML ({type(exc).__name__}: {exc})"
        ) from exc


def _scan_tag(text: str, start: int) -> tuple[dict[str, tuple[Span, str]], int, int, int, bool]:
    """Attributes of the start tag at ``text[start] == '<'``: {name: (value span, quote)},
    the end of the tag name, the end of the last attribute, the tag end, self-closing."""
    m = _TAG_NAME.match(text, start)
    if m is None:
        raise ValueError("no tag at this position")
    name_end = pos = attrs_end = m.end()
    attrs: dict[str, tuple[Span, str]] = {}
    while True:
        a = _TAG_ATTR.match(text, pos)
        if a is None:
            break
        group = 2 if a.group(2) is not None else 3
        attrs[a.group(1)] = (Span(a.start(group), a.end(group)), '"' if group == 2 else "'")
        pos = attrs_end = a.end()
    c = _TAG_CLOSE.match(text, pos)
    if c is None:
        raise ValueError("unterminated start tag")
    return attrs, name_end, attrs_end, c.end(), c.group(1) == "/"


class _Element:
    __slots__ = ("name", "attrs", "raw", "start", "line", "column", "tag_end", "end",
                 "self_closing", "name_end", "attrs_end", "children")

    def __init__(self, name: str, attrs: dict[str, str], start: int, line: int, column: int):
        self.name = name
        self.attrs = attrs
        self.start = start
        self.line = line
        self.column = column
        self.children: list[_Element] = []
        self.raw: dict[str, tuple[Span, str]] = {}
        self.tag_end = self.end = self.name_end = self.attrs_end = -1
        self.self_closing = False


def _parse_elements(text: str, source: str) -> _Element:
    """The element tree (root, depth <= 3) with character positions, via expat."""
    try:
        data = text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise InputError(f"{source}: text cannot be encoded as UTF-8: {exc.reason}") from exc
    if text.isascii():
        def char_index(byte_index: int) -> int:
            return byte_index
    else:
        offsets = list(itertools.accumulate((len(ch.encode("utf-8")) for ch in text), initial=0))

        def char_index(byte_index: int) -> int:
            return bisect.bisect_left(offsets, byte_index)

    parser = expat.ParserCreate(encoding="utf-8")
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    stack: list[_Element] = []
    roots: list[_Element] = []

    def refuse(*_: Any) -> None:
        raise _Refused("DTD or entity declaration")

    def start(name: str, attrs: dict[str, str]) -> None:
        index = char_index(parser.CurrentByteIndex)
        element = _Element(name, attrs, index, parser.CurrentLineNumber,
                           parser.CurrentColumnNumber + 1)
        if len(stack) <= 2:  # robot / joint / origin: positions needed
            raw, name_end, attrs_end, tag_end, closing = _scan_tag(text, index)
            element.raw, element.name_end, element.attrs_end = raw, name_end, attrs_end
            element.tag_end, element.self_closing = tag_end, closing
            (stack[-1].children if stack else roots).append(element)
        stack.append(element)

    def end(name: str) -> None:
        element = stack.pop()
        if element.tag_end < 0:
            return
        if element.self_closing:
            element.end = element.tag_end
        else:
            close = char_index(parser.CurrentByteIndex)
            element.end = text.index(">", close) + 1

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.UnparsedEntityDeclHandler = refuse
    parser.NotationDeclHandler = refuse
    parser.ExternalEntityRefHandler = refuse
    try:
        parser.Parse(data, True)
    except _Refused:
        raise InputError(
            f"{source}: line {parser.CurrentLineNumber}: refusing XML with a DTD or entity "
            "declaration (entity expansion and external entities are not allowed)"
        ) from None
    except expat.ExpatError as exc:
        raise InputError(
            f"{source}: line {exc.lineno}, column {exc.offset + 1}: malformed XML: "
            f"{expat.ErrorString(exc.code)}"
        ) from exc
    except ValueError as exc:  # our tag scanner disagreed with expat: should not happen
        raise InputError(f"{source}: cannot locate a tag in the text: {exc}") from exc
    return roots[0]


def _numbers(value: str, what: str) -> tuple[float, float, float]:
    parts = value.split()
    if len(parts) != 3 or not all(_NUMBER.match(p) for p in parts):
        hint = " (a xacro file? run xacro first)" if "$" in value else ""
        raise InputError(f"{what}: expected three numbers, got {value!r}{hint}")
    x, y, z = (float(p) for p in parts)
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise InputError(f"{what}: expected finite numbers, got {value!r}")
    return x, y, z


def _origin(element: _Element | None, what: str) -> Origin:
    if element is None:
        return Origin((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    xyz = _numbers(element.attrs.get("xyz", "0 0 0"), f"{what} origin xyz")
    rpy = _numbers(element.attrs.get("rpy", "0 0 0"), f"{what} origin rpy")
    quotes = [q for _, q in element.raw.values()]
    return Origin(
        xyz=xyz,
        rpy=rpy,
        tag=Span(element.start, element.tag_end),
        xyz_value=element.raw["xyz"][0] if "xyz" in element.raw else None,
        rpy_value=element.raw["rpy"][0] if "rpy" in element.raw else None,
        name_end=element.name_end,
        attrs_end=element.attrs_end,
        quote=quotes[0] if quotes else '"',
    )


def _single_child(element: _Element, tag: str, what: str) -> _Element | None:
    found = [c for c in element.children if c.name == tag]
    if len(found) > 1:
        raise InputError(
            f"{what} has {len(found)} <{tag}> elements (lines "
            f"{', '.join(str(c.line) for c in found)}); expected one"
        )
    return found[0] if found else None


def parse_urdf(text: str, source: str = "<urdf>") -> Urdf:
    """Parse URDF ``text`` into an immutable :class:`Urdf`; ``source`` names it in messages.

    Only ``<link>`` and ``<joint>`` elements directly under ``<robot>`` are read (a
    ``<transmission>``'s ``<joint>`` is not a joint). Refuses (InputError, naming ``source``
    and the line): DOCTYPE/ENTITY declarations, malformed XML, a root other than ``<robot>``,
    nameless or duplicate links/joints, a joint without one ``<parent link>`` and one
    ``<child link>``, an unknown joint type, origins that are not three finite numbers, a
    link carried by two joints.
    """
    if not isinstance(text, str):
        raise TypeError(f"parse_urdf: text must be str, got {type(text).__name__}")
    _refuse_declarations(text, source)
    _defused_check(text, source)
    root = _parse_elements(text, source)
    if root.name != "robot":
        raise InputError(f"{source}: expected the root element <robot>, got <{root.name}>")
    links: dict[str, Link] = {}
    joints: dict[str, Joint] = {}
    parent_joint: dict[str, str] = {}
    for element in root.children:
        where = f"{source}: line {element.line}"
        if element.name not in ("link", "joint"):
            continue
        name = element.attrs.get("name", "")
        if not name:
            raise InputError(f"{where}: <{element.name}> without a name attribute")
        if element.name == "link":
            if name in links:
                raise InputError(
                    f"{where}: link '{name}' is defined twice (first on line {links[name].line})"
                )
            links[name] = Link(name, element.line)
            continue
        what = f"{where}: joint '{name}'"
        if name in joints:
            raise InputError(f"{what} is defined twice (first on line {joints[name].line})")
        kind = element.attrs.get("type", "")
        if kind not in JOINT_TYPES:
            raise InputError(
                f"{what}: type must be one of {', '.join(JOINT_TYPES)}, got {kind!r}"
            )
        ends = {}
        for tag in ("parent", "child"):
            child = _single_child(element, tag, what)
            if child is None or not child.attrs.get("link"):
                raise InputError(f"{what}: expected one <{tag} link=\"...\"/> element")
            ends[tag] = child
        parent, child_link = ends["parent"].attrs["link"], ends["child"].attrs["link"]
        if parent == child_link:
            raise InputError(f"{what}: parent and child are the same link '{parent}'")
        if child_link in parent_joint:
            raise InputError(
                f"{what}: link '{child_link}' is already the child of joint "
                f"'{parent_joint[child_link]}'; a URDF is a tree"
            )
        origin = _origin(_single_child(element, "origin", what), what)
        joints[name] = Joint(
            name=name,
            type=kind,
            parent=parent,
            child=child_link,
            origin=origin,
            line=element.line,
            element=Span(element.start, element.end),
            child_element=Span(ends["child"].start, ends["child"].end),
        )
        parent_joint[child_link] = name
    _refuse_cycles(joints, parent_joint, source)
    return Urdf(
        source=source,
        text=text,
        robot_name=root.attrs.get("name", ""),
        links=MappingProxyType(links),
        joints=MappingProxyType(joints),
        parent_joint=MappingProxyType(parent_joint),
    )


def _refuse_cycles(joints: Mapping[str, Joint], parent_joint: Mapping[str, str], source: str) -> None:
    """InputError naming the joints of a cycle, anywhere in the file (a URDF is a tree: a cycle
    away from the sensors' chains would be copied into the output as it is)."""
    done: set[str] = set()
    for start in parent_joint:
        path: list[str] = []
        on_path: set[str] = set()
        link = start
        while link in parent_joint and link not in done:
            if link in on_path:
                cycle = sorted((joints[parent_joint[c]] for c in path[path.index(link):]), key=lambda j: j.line)
                names = ", ".join(f"'{j.name}'" for j in cycle)
                links = ", ".join(sorted(j.child for j in cycle))
                raise InputError(f"{source}: line {cycle[0].line}: joints {names} form a cycle (links {links}); "
                                 "a URDF is a tree")
            on_path.add(link)
            path.append(link)
            link = joints[parent_joint[link]].parent
        done.update(path)


# --------------------------------------------------------------------------------------------
# forward kinematics


def _joints_up(urdf: Urdf, link: str) -> list[Joint]:
    """Joints from ``link`` up to its root, nearest first."""
    urdf.link(link)
    chain: list[Joint] = []
    seen = {link}
    current = link
    while current in urdf.parent_joint:
        joint = urdf.joints[urdf.parent_joint[current]]
        chain.append(joint)
        current = joint.parent
        if current in seen:
            raise InputError(
                f"{urdf.source}: joints form a cycle through link '{current}' "
                f"({', '.join(j.name for j in chain)})"
            )
        seen.add(current)
    if current not in urdf.links:
        raise InputError(
            f"{urdf.source}: joint '{chain[-1].name}' names parent link '{current}', "
            "which is not defined"
        )
    return chain


def _path(urdf: Urdf, a: str, b: str) -> tuple[list[Joint], list[Joint]]:
    """The tree path from link ``a`` to link ``b``: (joints from ``a`` up to the common
    ancestor, nearest to ``a`` first; joints from the common ancestor down to ``b``, top first)."""
    up_a = _joints_up(urdf, a)
    up_b = _joints_up(urdf, b)
    links_a = [a] + [j.parent for j in up_a]
    links_b = [b] + [j.parent for j in up_b]
    common = next((link for link in links_b if link in set(links_a)), None)
    if common is None:
        raise InputError(
            f"{urdf.source}: links '{a}' and '{b}' are not connected by joints "
            f"(roots '{links_a[-1]}' and '{links_b[-1]}')"
        )
    up = up_a[: links_a.index(common)]
    down = list(reversed(up_b[: links_b.index(common)]))
    return up, down


def _check_fixed(urdf: Urdf, joints: list[Joint], a: str, b: str) -> None:
    moving = [j for j in joints if j.type != "fixed"]
    if moving:
        listed = ", ".join(f"'{j.name}' ({j.type}, line {j.line})" for j in moving)
        raise InputError(
            f"{urdf.source}: the chain from link '{a}' to link '{b}' has non-fixed joint(s) "
            f"{listed}; only fixed joints have a pose without joint positions"
        )


def _fk(urdf: Urdf, a: str, b: str, origins: Mapping[str, np.ndarray]) -> np.ndarray:
    up, down = _path(urdf, a, b)
    _check_fixed(urdf, up + down, a, b)

    def matrix(joint: Joint) -> np.ndarray:
        return origins[joint.name] if joint.name in origins else joint.origin.matrix

    T_common_a = np.eye(4)
    for joint in reversed(up):
        T_common_a = T_common_a @ matrix(joint)
    T_common_b = np.eye(4)
    for joint in down:
        T_common_b = T_common_b @ matrix(joint)
    return invert(T_common_a) @ T_common_b


def forward_kinematics(urdf: Urdf, root_link: str, link: str) -> np.ndarray:
    """``T_root_link`` (4, 4): ``link``'s pose in ``root_link``'s frame, a new array.

    ``root_link`` is usually an ancestor of ``link`` but need not be: the path goes through
    their common ancestor (``T_a_b = inv(T_c_a) @ T_c_b``). Every joint on the path must be
    fixed (InputError naming the others), both links must exist and be connected.
    """
    return _fk(urdf, root_link, link, {})


# --------------------------------------------------------------------------------------------
# planning and rewriting


def _resolve_target(
    urdf: Urdf, key: str, joint_for: Mapping[str, str]
) -> tuple[str, Joint]:
    """(sensor link, joint to change) for an update key (a link name, else a joint name)."""
    if key in urdf.links:
        named = joint_for.get(key)
        if named is not None:
            return key, urdf.joint(named)
        joint = urdf.joint_to(key)
        if joint is None:
            raise InputError(
                f"{urdf.source}: link '{key}' is a root link: no joint carries it, so there is "
                "no origin to update"
            )
        return key, joint
    if key in urdf.joints:
        joint = urdf.joints[key]
        named = joint_for.get(key)
        if named is not None and named != key:
            raise InputError(
                f"{urdf.source}: '{key}' is a joint; joint_for cannot name another joint "
                f"('{named}') for it"
            )
        return joint.child, joint
    raise InputError(
        f"{urdf.source}: no link or joint named '{key}' to update (links: {_names(urdf.links)})"
    )


def solve_joint_origins(
    urdf: Urdf,
    updates: Mapping[str, Any],
    body_link: str,
    joint_for: Mapping[str, str] | None = None,
) -> tuple[JointUpdate, ...]:
    """The joint origins that make FK from ``body_link`` reproduce every ``T_body_sensor``.

    ``updates`` maps a sensor link (or a joint, meaning its child link) to ``T_body_sensor``
    (4, 4), the sensor link's pose in ``body_link``'s frame. By default the joint changed is
    the one carrying the sensor link; ``joint_for`` may name a joint higher up the chain (the
    fixed joints between it and the sensor link are kept and accounted for). ``body_link``
    need not be the root: the joint must lie below the common ancestor of body and sensor.

    Several sensors are solved top-down (a joint nearer the root first), so a sensor whose
    chain passes through another sensor's joint sees that joint's new origin, and every
    request is met at once. Refused (InputError): unknown links/joints, a non-fixed joint on a
    chain, a joint not on its sensor's chain (or on the body link's side), two sensors
    changing one joint, and a joint changed for one sensor lying between another sensor's
    joint and that sensor's link (the two requests would fight).
    """
    urdf.link(body_link)
    joint_for = dict(joint_for or {})
    if not isinstance(updates, Mapping) or not updates:
        raise InputError(
            f"{urdf.source}: expected a non-empty mapping sensor link -> T_body_sensor, "
            f"got {type_name(updates) if not isinstance(updates, Mapping) else 'an empty one'}"
        )
    for key in joint_for:
        if key not in updates:
            raise InputError(
                f"{urdf.source}: joint_for names '{key}', which has no calibrated pose "
                f"(updates: {', '.join(map(str, updates))})"
            )
    planned: list[tuple[str, str, Joint, np.ndarray, list[Joint]]] = []
    owner: dict[str, str] = {}
    for key, T in updates.items():
        if not isinstance(key, str):
            raise InputError(f"{urdf.source}: update keys must be link names, got {key!r}")
        T_body_sensor = as_rigid(T, f"{urdf.source}: T_{body_link}_{key}")
        T_body_sensor.setflags(write=False)
        sensor, joint = _resolve_target(urdf, key, joint_for)
        if sensor == body_link:
            raise InputError(
                f"{urdf.source}: '{key}' is the body link '{body_link}' itself; its pose in its "
                "own frame is the identity"
            )
        up, down = _path(urdf, body_link, sensor)
        chain = ", ".join(j.name for j in up + down)
        if joint in up:
            raise InputError(
                f"{urdf.source}: joint '{joint.name}' (for '{key}') lies on the body link's "
                f"side of the chain from '{body_link}' to '{sensor}' ({chain}); changing it "
                f"would move the body link"
            )
        common = up[-1].parent if up else body_link
        if joint not in down and joint in _joints_up(urdf, common):
            raise InputError(
                f"{urdf.source}: joint '{joint.name}' (for '{key}') lies above link '{common}', "
                f"where the chains to body link '{body_link}' and link '{sensor}' meet; "
                "changing it moves both together"
            )
        if joint not in down:
            raise InputError(
                f"{urdf.source}: joint '{joint.name}' (for '{key}') is not on the chain from "
                f"body link '{body_link}' to link '{sensor}' ({chain})"
            )
        _check_fixed(urdf, up + down, body_link, sensor)
        if joint.name in owner:
            raise InputError(
                f"{urdf.source}: sensors '{owner[joint.name]}' and '{key}' would both change "
                f"joint '{joint.name}'; give one of them another joint (joint_for)"
            )
        owner[joint.name] = key
        below = down[down.index(joint) + 1 :]
        planned.append((key, sensor, joint, T_body_sensor, below))
    for key, sensor, joint, _, below in planned:
        for other in below:
            if other.name in owner:
                raise InputError(
                    f"{urdf.source}: joint '{other.name}' (changed for '{owner[other.name]}') "
                    f"lies between joint '{joint.name}' (changed for '{key}') and link "
                    f"'{sensor}'; both poses cannot be met: change a joint below "
                    f"'{other.name}' for '{key}', or update only one"
                )
    depth = {j.name: len(_joints_up(urdf, j.parent)) for _, _, j, _, _ in planned}
    planned.sort(key=lambda item: depth[item[2].name])
    working: dict[str, np.ndarray] = {}
    result = []
    for key, sensor, joint, T_body_sensor, _ in planned:
        T_body_parent = _fk(urdf, body_link, joint.parent, working)
        T_child_sensor = _fk(urdf, joint.child, sensor, working)
        T_parent_child = invert(T_body_parent) @ T_body_sensor @ invert(T_child_sensor)
        xyz, rpy = origin_from_matrix(T_parent_child)
        working[joint.name] = matrix_from_origin(xyz, rpy)
        result.append(JointUpdate(key, joint.name, sensor, xyz, rpy, T_body_sensor))
    return tuple(result)


def _triple(values: tuple[float, float, float]) -> str:
    return " ".join(format_float(v) for v in values)


def set_joint_origins(urdf: Urdf, origins: Mapping[str, tuple[Any, Any]]) -> str:
    """``urdf.text`` with the named joints' origins set to ``{joint: (xyz, rpy)}``.

    Only the values of ``xyz``/``rpy`` that change numerically are replaced (a missing
    attribute is added after the others, a missing ``<origin>`` goes after ``<child>`` with the
    same indentation, quoting and tag style); every other character is kept.
    """
    text = urdf.text
    edits: list[tuple[int, int, str]] = []
    for name, (xyz_in, rpy_in) in origins.items():
        joint = urdf.joint(name)
        xyz = tuple(float(v) for v in xyz_in)
        rpy = tuple(float(v) for v in rpy_in)
        if len(xyz) != 3 or len(rpy) != 3 or not all(map(math.isfinite, xyz + rpy)):
            raise InputError(
                f"{urdf.source}: joint '{name}': origin needs three finite xyz and three "
                f"finite rpy values, got {xyz_in!r}, {rpy_in!r}"
            )
        origin = joint.origin
        if origin.tag is None:
            edits.append(_new_origin_edit(text, joint, xyz, rpy))  # type: ignore[arg-type]
            continue
        inserts: list[tuple[int, str]] = []
        for attr, new, old, span in (
            ("xyz", xyz, origin.xyz, origin.xyz_value),
            ("rpy", rpy, origin.rpy, origin.rpy_value),
        ):
            if tuple(new) == tuple(old):
                continue  # numerically unchanged (a missing attribute already means zeros)
            value = _triple(new)  # type: ignore[arg-type]
            if span is not None:
                edits.append((span.start, span.end, value))
            else:
                at = origin.name_end if attr == "xyz" else origin.attrs_end
                inserts.append((at, f" {attr}={origin.quote}{value}{origin.quote}"))
        if len(inserts) == 2 and inserts[0][0] == inserts[1][0]:
            inserts = [(inserts[0][0], inserts[0][1] + inserts[1][1])]
        edits.extend((at, at, new_text) for at, new_text in inserts)
    edits.sort()
    for (s1, e1, _), (s2, _, _) in zip(edits, edits[1:]):
        if s2 < e1:  # pragma: no cover - spans of distinct joints never overlap
            raise InputError(f"{urdf.source}: overlapping origin edits at characters {s1}, {s2}")
    pieces = []
    last = 0
    for start, end, new_text in edits:
        pieces.append(text[last:start])
        pieces.append(new_text)
        last = end
    pieces.append(text[last:])
    return "".join(pieces)


def _new_origin_edit(
    text: str, joint: Joint, xyz: tuple[float, float, float], rpy: tuple[float, float, float]
) -> tuple[int, int, str]:
    child = joint.child_element
    tag = text[child.start : child.end]
    quote = "'" if re.search(r"=\s*'", tag) and not re.search(r'=\s*"', tag) else '"'
    tail = " />" if re.search(r"\s/>\Z", tag) else "/>"
    element = f"<origin xyz={quote}{_triple(xyz)}{quote} rpy={quote}{_triple(rpy)}{quote}{tail}"
    line_start = text.rfind("\n", 0, child.start) + 1
    indent = text[line_start : child.start]
    if line_start > 0 and indent.strip() == "":
        newline = "\r\n" if text[line_start - 2 : line_start] == "\r\n" else "\n"
        return child.end, child.end, f"{newline}{indent}{element}"
    return child.end, child.end, f" {element}"


def update_urdf_text(
    text: str,
    source: str,
    updates: Mapping[str, Any],
    body_link: str,
    joint_for: Mapping[str, str] | None = None,
) -> str:
    """New URDF text whose forward kinematics give ``T_body_sensor`` for every update.

    See :func:`solve_joint_origins` for the meaning of ``updates``/``joint_for`` and the
    refusals, :func:`set_joint_origins` for what changes in the text. The result is parsed
    again and checked against every request (to :data:`FK_TOLERANCE`) before it is returned.
    """
    urdf = parse_urdf(text, source)
    plan = solve_joint_origins(urdf, updates, body_link, joint_for)
    new_text = set_joint_origins(urdf, {u.joint: (u.xyz, u.rpy) for u in plan})
    written = parse_urdf(new_text, source)
    for update in plan:
        wanted = update.T_body_sensor
        got = forward_kinematics(written, body_link, update.sensor_link)
        scale = max(1.0, float(np.max(np.abs(wanted[:3, 3]))))
        error = float(np.max(np.abs(got - wanted)))
        if error > FK_TOLERANCE * scale:  # pragma: no cover - a bug, not a user error
            raise GeometryError(
                f"{source}: after updating joint '{update.joint}', FK from '{body_link}' to "
                f"'{update.sensor_link}' is off by {error:.3g}"
            )
    return new_text


# --------------------------------------------------------------------------------------------
# calibrated frames -> URDF links (missing links, camera optical frames)

#: REP 103: the optical frame's fixed rotation in its body-convention camera link (decided in
#: :mod:`rigcal.io.results.frames`, the one place for the frame contract).
from rigcal.io.results.frames import OPTICAL_RPY  # noqa: E402, F401  (re-exported)


@dataclass(frozen=True)
class SensorLinks:
    """How calibrated frames map onto a URDF: ``updates`` (link -> ``T_body_link``) and
    ``joint_for`` for :func:`update_urdf_text`, frames to ``add`` as new links, frames
    ``skipped`` because the URDF lacks them, and a note per optical-frame mapping; ``body_link``
    is the link every pose is relative to (a camera reference's body-convention link)."""

    updates: Mapping[str, np.ndarray]
    joint_for: Mapping[str, str]
    add: Mapping[str, np.ndarray]
    skipped: tuple[str, ...]
    notes: tuple[str, ...]
    body_link: str = ""


def link_names(urdf: Urdf) -> str:
    """The URDF's link names for a message (the first 12, then how many in all)."""
    return _names(urdf.links)


def sensor_links(urdf: Urdf, plan: Any, add_missing: bool = False) -> SensorLinks:
    """The URDF updates of a frame plan (:func:`rigcal.io.results.frames.plan_frames` made with
    this ``urdf``): each calibrated transform ``(root, link, T_root_link)`` whose link the URDF
    has updates the joint carrying that link (a camera's optical joint is kept: the optical
    child follows); a link the URDF lacks is skipped, or with ``add_missing`` added on a fixed
    joint from the root. If nothing at all matches, InputError naming both sides."""
    body_link = plan.root
    if body_link not in urdf.links:
        raise InputError(
            f"{urdf.source}: no link named '{body_link}', the frame the calibration is relative "
            f"to (links: {_names(urdf.links)}); set the reference sensor's frame_id in the "
            "manifest to its URDF link, or give --body-link"
        )
    updates: dict[str, np.ndarray] = {}
    add: dict[str, np.ndarray] = {}
    skipped: list[str] = []
    for edge in plan.transforms:
        if not edge.calibrated:
            continue
        if edge.child in urdf.links:
            updates[edge.child] = edge.T_parent_child
        elif add_missing:
            add[edge.child] = edge.T_parent_child
        else:
            skipped.append(edge.child)
    if not updates and not add:
        frames = [s.frame_id for s in plan.sensors]
        raise InputError(
            f"{urdf.source}: none of the calibrated frames ({', '.join(frames)}) "
            f"is a link of the URDF (links: {_names(urdf.links)}); set each sensor's frame_id "
            "in the manifest to its URDF link, or add the links (--add-missing)"
        )
    return SensorLinks(updates, {}, add, tuple(skipped), plan.notes, body_link)


def plan_sensor_links(
    urdf: Urdf,
    transforms: Mapping[str, Any],
    body_link: str,
    kinds: Mapping[str, str] | None = None,
    add_missing: bool = False,
) -> SensorLinks:
    """Map calibrated frames (``{frame_id: T_body_frame}``; a camera's frame is its optical
    frame, z forward) onto ``urdf``'s links by the frame contract
    (:mod:`rigcal.io.results.frames`): a frame that is a link is updated there; a camera
    (``kinds[frame] == "camera"``) whose link follows REP 103's body convention and has an
    optical child gets the calibrated pose on that optical child (the camera link's joint
    moves, the optical joint is kept), and a frame that *is* an optical child (joint rpy =
    (-pi/2, 0, -pi/2)) keeps its optical joint and moves the joint above; a frame the URDF
    lacks is skipped, or added (``add_missing``) on a fixed joint from ``body_link``."""
    from rigcal.io.results.calibration_files import CalibrationTransforms
    from rigcal.io.results.frames import plan_frames

    if body_link not in urdf.links:  # named before any frame is resolved
        raise InputError(
            f"{urdf.source}: no link named '{body_link}', the frame the calibration is relative "
            f"to (links: {_names(urdf.links)}); set the reference sensor's frame_id in the "
            "manifest to its URDF link, or give --body-link"
        )
    cal = CalibrationTransforms("relative", body_link, dict(transforms), urdf.source,
                                dict(kinds or {}))
    return sensor_links(urdf, plan_frames(cal, urdf), add_missing)


def add_fixed_links(text: str, source: str, links: Mapping[str, Any], body_link: str) -> str:
    """``text`` with a ``<link name=...>`` and a fixed ``<joint>`` from ``body_link`` per entry of
    ``links`` (``{name: T_body_link}``), inserted before ``</robot>``."""
    if not links:
        return text
    urdf = parse_urdf(text, source)
    end = text.rfind("</robot>")
    if end < 0:  # pragma: no cover - parse_urdf has checked the root element
        raise InputError(f"{source}: no </robot> closing tag to add links before")
    line_start = text.rfind("\n", 0, end) + 1
    own_line = text[line_start:end].strip() == ""
    m = re.search(r"\n([ \t]*)<(?:link|joint)\b", text)
    indent = (m.group(1) if m else "  ") if own_line else ""
    step = indent if indent.strip() == "" and indent else "  "
    taken = set(urdf.joints)
    pieces = []
    for name, T in links.items():
        if not re.fullmatch(r"[A-Za-z0-9_./-]+", name):
            raise InputError(f"{source}: cannot add a link named {name!r} (letters, digits, _ . / -)")
        joint = f"{name}_joint"
        k = 1
        while joint in taken:
            joint, k = f"{name}_joint_{k}", k + 1
        taken.add(joint)
        xyz, rpy = origin_from_matrix(as_rigid(T, f"{source}: T_{body_link}_{name}"))
        pieces.append(
            f'{indent}<link name="{name}"/>\n'
            f'{indent}<joint name="{joint}" type="fixed">\n'
            f'{indent}{step}<parent link="{body_link}"/>\n'
            f'{indent}{step}<child link="{name}"/>\n'
            f'{indent}{step}<origin xyz="{_triple(xyz)}" rpy="{_triple(rpy)}"/>\n'
            f"{indent}</joint>\n"
        )
    insert_at = line_start if own_line else end
    new_text = text[:insert_at] + "".join(pieces) + text[insert_at:]
    parse_urdf(new_text, source)  # still a valid tree
    return new_text


# --------------------------------------------------------------------------------------------
# the original tool's calibration YAML


def read_original_calibration_yaml(
    text: str, source: str = "<calibration>"
) -> OriginalCalibration:
    """The original tool's ``{source, target, transform}`` YAML.

    ``transform`` is a 4x4 row-major nested list with ``p_target = transform @ p_source``, so
    the value returned is ``T_target_source``. To place ``target`` in a URDF keeping
    ``source`` where it is: ``update_urdf_text(text, src, {target: invert(T_target_source)},
    body_link=source)``.
    """
    data = load_yaml(text, source)
    if not isinstance(data, dict):
        raise InputError(
            f"{source}: expected a mapping with source, target and transform, got "
            f"{type_name(data)}"
        )
    expected = ("source", "target", "transform")
    unknown = [k for k in data if k not in expected]
    if unknown:
        raise InputError(
            f"{source}: unknown key(s) {', '.join(map(repr, unknown))} "
            f"(expected: {', '.join(expected)})"
        )
    missing = [k for k in expected if k not in data]
    if missing:
        raise InputError(f"{source}: missing key(s) {', '.join(missing)}")
    frames = []
    for key in ("source", "target"):
        value = data[key]
        if not isinstance(value, str) or not value.strip():
            raise InputError(f"{source}: {key}: expected a frame name, got {type_name(value)}")
        frames.append(value)
    rows = data["transform"]
    if not (
        isinstance(rows, list)
        and len(rows) == 4
        and all(isinstance(r, list) and len(r) == 4 for r in rows)
    ):
        if isinstance(rows, list):
            lengths = [len(r) if isinstance(r, list) else type_name(r) for r in rows]
            shape = f"{len(rows)} rows of lengths {lengths}"
        else:
            shape = type_name(rows)
        raise InputError(f"{source}: transform: expected 4 rows of 4 numbers, got {shape}")
    for i, row in enumerate(rows):
        for j, value in enumerate(row):
            if not is_finite_number(value):
                raise InputError(
                    f"{source}: transform[{i}][{j}]: expected a finite number, got "
                    f"{type_name(value)} {value!r}"
                )
    T = as_rigid(rows, f"{source}: transform")
    return OriginalCalibration(frames[0], frames[1], T)


# --------------------------------------------------------------------------------------------
# files


def _read_urdf_file(path: Path) -> tuple[bytes, str]:
    data = read_limited(path, "URDF file", "text")
    body = data[len(_BOM) :] if data.startswith(_BOM) else data
    try:
        return data, body.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: URDF file is not UTF-8 (byte {exc.start}: {exc.reason})"
        ) from exc


def read_urdf(path: str | os.PathLike[str]) -> Urdf:
    """:func:`parse_urdf` of a file (UTF-8, a byte-order mark allowed; size limited)."""
    p = Path(path)
    return parse_urdf(_read_urdf_file(p)[1], str(p))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _backup_path(path: Path) -> Path:
    candidate = path.with_name(path.name + ".bak")
    n = 1
    while candidate.exists():
        candidate = path.with_name(f"{path.name}.bak.{n}")
        n += 1
    return candidate


def write_urdf(
    in_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str] | None,
    updates: Mapping[str, Any],
    body_link: str,
    in_place: bool = False,
    joint_for: Mapping[str, str] | None = None,
    *,
    kinds: Mapping[str, str] | None = None,
    missing: str = "error",
    frame_plan: Any = None,
) -> WrittenUrdf:
    """Update ``in_path`` (see :func:`update_urdf_text`) and write the result atomically.

    Without ``in_place`` the result goes to ``out_path``, which must not be the input file.
    With ``in_place`` (``out_path`` None or the input) the input's exact bytes are first
    copied to ``<name>.bak`` (``.bak.1``, ``.bak.2``... if taken), then the input is replaced.
    A symlinked input is updated where it points. A UTF-8 byte-order mark is kept. Nothing is
    written if the update is refused. Returns the written path and the backup (or None).

    ``missing`` says what happens to an update key the URDF has no link or joint for:
    ``"error"`` (refused), ``"skip"`` (left out, listed in ``skipped``) or ``"add"`` (a new link
    on a fixed joint from ``body_link``, listed in ``added``); with ``"skip"``/``"add"``,
    ``kinds`` (frame -> sensor kind) maps camera optical frames as :func:`plan_sensor_links`
    describes. ``frame_plan`` (a :class:`~rigcal.io.results.frames.FramePlan` resolved in this
    URDF) replaces ``updates``/``body_link``/``kinds``: what every other writer publishes is
    what the URDF gets (:func:`sensor_links`).
    """
    if missing not in ("error", "skip", "add"):
        raise InputError(f"missing must be 'error', 'skip' or 'add', got {missing!r}")
    source = Path(in_path)
    original, text = _read_urdf_file(source)
    if in_place:
        other = None if out_path is None else Path(out_path)
        if other is not None and other != source and not _same_file(source, other):
            raise InputError(
                f"{source}: in_place rewrites the input; do not also give an output path "
                f"({out_path})"
            )
        target = source
    else:
        if out_path is None:
            raise InputError(
                f"{source}: give an output path, or in_place=True to rewrite the input"
            )
        target = Path(out_path)
        if target.resolve() == source.resolve() or _same_file(source, target):
            raise InputError(
                f"{target}: is the input file; refusing to overwrite it without in_place=True "
                "(which keeps a backup)"
            )
    skipped: tuple[str, ...] = ()
    added: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    if missing == "error" and frame_plan is None:
        new_text = update_urdf_text(text, str(source), updates, body_link, joint_for)
    else:
        if frame_plan is not None:
            plan = sensor_links(parse_urdf(text, str(source)), frame_plan, missing == "add")
            if missing == "error" and plan.skipped:
                raise InputError(
                    f"{source}: no link named {', '.join(repr(f) for f in plan.skipped)} (links: "
                    f"{_names(parse_urdf(text, str(source)).links)})"
                )
        else:
            plan = plan_sensor_links(parse_urdf(text, str(source)), updates, body_link, kinds,
                                     add_missing=missing == "add")
        body_link = plan.body_link or body_link
        new_text = add_fixed_links(text, str(source), plan.add, body_link)
        if plan.updates:
            new_text = update_urdf_text(new_text, str(source), plan.updates, body_link,
                                        {**plan.joint_for, **dict(joint_for or {})})
        skipped, added, notes = plan.skipped, tuple(plan.add), plan.notes
    bom = _BOM if original.startswith(_BOM) else b""
    backup = None
    if in_place:
        backup = atomic_write_bytes(_backup_path(source), original)
        try:
            shutil.copymode(source, backup)
        except OSError:  # pragma: no cover - best effort
            pass
        target = source.resolve()  # through a symlink: update the file it points to
    atomic_write_bytes(target, bom + new_text.encode("utf-8"))
    return WrittenUrdf(target, backup, skipped, added, notes)
