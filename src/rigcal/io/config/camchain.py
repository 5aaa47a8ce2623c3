"""Camera files of Kalibr and of the original tool -> :class:`CameraModel` values.

* **Kalibr camchain YAML** (``camchain.yaml`` / ``camchain-imucam.yaml``), one mapping per
  camera ``cam0``, ``cam1``, ...::

    cam0:
      camera_model: pinhole            # pinhole | ds   (omni, eucm: not supported)
      intrinsics: [fu, fv, pu, pv]     # ds: [xi, alpha, fu, fv, pu, pv]
      distortion_model: radtan         # radtan | equidistant | none   (fov: not supported)
      distortion_coeffs: [k1, k2, r1, r2]
      resolution: [752, 480]           # [width, height] px
      rostopic: /cam0/image_raw        # optional
      T_cam_imu: [[...] x 4]           # optional (imu-cam chains)
    cam1:
      T_cn_cnm1: [[...] x 4]           # optional: cam0 -> cam1
      ...

  ``pinhole`` + ``radtan`` is :class:`RadtanCamera` (``k3 = 0``), ``pinhole`` + ``equidistant``
  is :class:`KannalaBrandtCamera`, ``pinhole`` + ``none`` is :class:`PinholeCamera` and ``ds`` +
  ``none`` is :class:`DoubleSphereCamera` (its intrinsics reordered to ``fx fy cx cy xi alpha``).

  Transforms follow rigcal's ``T_to_from`` convention (a (4, 4) matrix mapping a point in
  ``from`` into ``to``) and are returned keyed by ``(to, from)``: Kalibr's ``T_cn_cnm1`` of
  ``camN`` maps points in ``cam(N-1)`` into ``camN``, so it is stored as
  ``T_to_from[("camN", "cam(N-1)")]``; ``T_cam_imu`` of ``camN`` maps points in the chain's
  reference IMU into ``camN`` and is stored as ``T_to_from[("camN", "imu0")]``.

* **The original tool's intrinsics JSON** (``F1_sim.json``, ``intrinsics_EXAMPLE.json``)::

    {"date": "2018_12_20", "method": "matlab", "camera_type": "RADTAN",
     "image_width": 2048, "image_height": 1536, "frame_id": "F1_link",
     "intrinsics": [fx, fy, cx, cy, k1, k2, p1, p2]}

  ``camera_type`` ``RADTAN`` (fx fy cx cy k1 k2 p1 p2), ``KANNALABRANDT`` (fx fy cx cy k1 k2 k3
  k4) or ``DOUBLESPHERE`` (fx fy cx cy eps alpha; ``eps`` is ``xi``), or any other name
  :func:`~rigcal.sensors.camera.registry.camera_from_params` knows. ``LADYBUG`` has no
  intrinsics in the file and is not supported.

:func:`read_camera_file` reads either of them - or a ROS CameraInfo YAML / calibrator INI
(:mod:`rigcal.io.config.intrinsics`) - choosing by content. Every malformed input raises
:class:`InputError` naming the file and the key.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from rigcal.errors import InputError
from rigcal.io.limits import check_finite
from rigcal.io._text import is_number, load_yaml, read_text, type_name
from rigcal.io.config.intrinsics import parse_camera_info_yaml_text, parse_intrinsics_ini_text
from rigcal.sensors.camera.base import CameraModel
from rigcal.sensors.camera.double_sphere import DoubleSphereCamera
from rigcal.sensors.camera.kannala_brandt import KannalaBrandtCamera
from rigcal.sensors.camera.pinhole import PinholeCamera
from rigcal.sensors.camera.radtan import RadtanCamera
from rigcal.sensors.camera.registry import camera_from_params

_CAM_KEY = re.compile(r"cam(0|[1-9][0-9]*)")
# YAML 1.1 (PyYAML) reads "1e-5" as a string; Kalibr writes "1.0e-05", people write "1e-5"
_EXPONENT_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+")
_ROTATION_TOL = 1e-6

# Kalibr camera_model -> (intrinsics names, accepted distortion models)
_KALIBR_CAMERAS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "pinhole": (("fu", "fv", "pu", "pv"), ("none", "radtan", "equidistant")),
    "ds": (("xi", "alpha", "fu", "fv", "pu", "pv"), ("none",)),
}
_KALIBR_DISTORTIONS: dict[str, tuple[str, ...]] = {
    "none": (),
    "radtan": ("k1", "k2", "r1", "r2"),
    "equidistant": ("k1", "k2", "k3", "k4"),
}
_KALIBR_KEYS = (
    "camera_model",
    "intrinsics",
    "distortion_model",
    "distortion_coeffs",
    "resolution",
    "rostopic",
    "T_cn_cnm1",
    "T_cam_imu",
    "cam_overlaps",
    "timeshift_cam_imu",
    "line_delay",
)


class Camchain(NamedTuple):
    """Cameras of one file and the transforms between them.

    ``cameras``: name -> model, in file order (``cam0``, ``cam1``, ... for Kalibr; the
    ``frame_id`` - else the file stem - for single-camera files). ``T_to_from``: ``(to, from)``
    -> read-only (4, 4) matrix mapping points in ``from`` into ``to`` [m]. ``topics``: camera
    name -> ROS image topic where the file gives one.
    """

    cameras: dict[str, CameraModel]
    T_to_from: dict[tuple[str, str], np.ndarray]
    topics: dict[str, str]


# ---------------------------------------------------------------------------- value checks
def _number(value: Any, source: str, where: str) -> float:
    if isinstance(value, str) and _EXPONENT_NUMBER.fullmatch(value.strip()):
        value = float(value)
    if not is_number(value) or not math.isfinite(value):
        raise InputError(
            f"{source}: {where}: expected a finite number, got {value!r} ({type_name(value)})"
        )
    return float(value)


def _numbers(value: Any, source: str, where: str) -> np.ndarray:
    if not isinstance(value, list):
        raise InputError(f"{source}: {where}: expected a list of numbers, got {type_name(value)}")
    return np.array([_number(v, source, f"{where}[{i}]") for i, v in enumerate(value)])


def _size(value: Any, source: str, where: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise InputError(f"{source}: {where}: expected a positive integer [px], got {value!r}")
    return value


def _transform(value: Any, source: str, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 4 or any(
        not isinstance(row, list) or len(row) != 4 for row in value
    ):
        raise InputError(f"{source}: {where}: expected a 4x4 matrix (4 rows of 4 numbers)")
    T = np.array(
        [[_number(v, source, f"{where}[{i}][{j}]") for j, v in enumerate(row)]
         for i, row in enumerate(value)]
    )
    check_finite(T, f"{source}: {where}", "entry", "m")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-12):
        raise InputError(f"{source}: {where}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > _ROTATION_TOL or np.linalg.det(R) <= 0:
        raise InputError(
            f"{source}: {where}: the upper-left 3x3 block is not a rotation "
            f"(|R^T R - I| = {err:.2g}, det = {np.linalg.det(R):.6g})"
        )
    T.setflags(write=False)
    return T


def _build(
    source: str, where: str, model: str, width: int, height: int, params: Any
) -> CameraModel:
    try:
        return camera_from_params(model, width, height, params)
    except InputError as exc:
        raise InputError(f"{source}: {where}: {exc}") from None


# ---------------------------------------------------------------------------- Kalibr
def _kalibr_camera(node: Any, name: str, source: str) -> CameraModel:
    if not isinstance(node, dict):
        raise InputError(
            f"{source}: {name}: expected a mapping (camera_model, intrinsics, ...), got "
            f"{type_name(node)}"
        )
    for key in node:
        if key not in _KALIBR_KEYS:
            raise InputError(
                f"{source}: {name}: unknown key {key!r} (expected: {', '.join(_KALIBR_KEYS)})"
            )
    for key in ("camera_model", "intrinsics"):
        if key not in node:
            raise InputError(f"{source}: {name}: missing '{key}'")
    if "resolution" not in node:
        raise InputError(f"{source}: {name}: missing 'resolution' ([width, height] in px)")

    model = node["camera_model"]
    if not isinstance(model, str) or model.strip().lower() not in _KALIBR_CAMERAS:
        raise InputError(
            f"{source}: {name}.camera_model: unknown camera model {model!r} "
            f"(supported: {', '.join(_KALIBR_CAMERAS)})"
        )
    model = model.strip().lower()
    intrinsic_names, distortions = _KALIBR_CAMERAS[model]

    coeffs_given = node.get("distortion_coeffs") not in (None, [])
    distortion = node.get("distortion_model", None if coeffs_given else "none")
    if distortion is None:
        raise InputError(
            f"{source}: {name}: missing 'distortion_model' (distortion_coeffs are given)"
        )
    if not isinstance(distortion, str) or distortion.strip().lower() not in distortions:
        known = distortions if isinstance(distortion, str) else tuple(_KALIBR_DISTORTIONS)
        raise InputError(
            f"{source}: {name}.distortion_model: {distortion!r} is not supported with "
            f"camera_model '{model}' (supported: {', '.join(known)})"
        )
    distortion = distortion.strip().lower()
    coeff_names = _KALIBR_DISTORTIONS[distortion]

    intrinsics = _numbers(node["intrinsics"], source, f"{name}.intrinsics")
    if intrinsics.size != len(intrinsic_names):
        raise InputError(
            f"{source}: {name}.intrinsics: camera_model '{model}' expects "
            f"{len(intrinsic_names)} values ({' '.join(intrinsic_names)}), got {intrinsics.size}"
        )
    coeffs = _numbers(node.get("distortion_coeffs") or [], source, f"{name}.distortion_coeffs")
    if coeffs.size != len(coeff_names):
        expected = f"{len(coeff_names)} values ({' '.join(coeff_names)})" if coeff_names else "none"
        raise InputError(
            f"{source}: {name}.distortion_coeffs: distortion_model '{distortion}' expects "
            f"{expected}, got {coeffs.size}"
        )

    resolution = node["resolution"]
    if not isinstance(resolution, list) or len(resolution) != 2:
        raise InputError(
            f"{source}: {name}.resolution: expected [width, height] in px, got {resolution!r}"
        )
    width = _size(resolution[0], source, f"{name}.resolution[0] (width)")
    height = _size(resolution[1], source, f"{name}.resolution[1] (height)")

    if model == "ds":
        xi, alpha, fu, fv, pu, pv = intrinsics
        return _build(
            source, f"{name}.intrinsics", "double_sphere", width, height,
            [fu, fv, pu, pv, xi, alpha],
        )
    rigcal_model = {"none": "pinhole", "radtan": "radtan", "equidistant": "kannala_brandt"}
    return _build(
        source, f"{name}.intrinsics", rigcal_model[distortion], width, height,
        np.concatenate([intrinsics, coeffs]),
    )


def _camchain_from_doc(doc: dict, source: str) -> Camchain:
    indices: dict[int, str] = {}
    for key in doc:
        match = _CAM_KEY.fullmatch(key) if isinstance(key, str) else None
        if match is None:
            raise InputError(
                f"{source}: unexpected top-level key {key!r} "
                f"(a Kalibr camchain has cam0, cam1, ...)"
            )
        indices[int(match.group(1))] = key
    if not indices:
        raise InputError(f"{source}: no cameras (expected cam0, cam1, ...)")
    missing = [f"cam{i}" for i in range(max(indices) + 1) if i not in indices]
    if missing:
        raise InputError(
            f"{source}: cameras must be numbered from cam0 without gaps; missing {missing}"
        )

    cameras: dict[str, CameraModel] = {}
    transforms: dict[tuple[str, str], np.ndarray] = {}
    topics: dict[str, str] = {}
    for i in sorted(indices):
        name = indices[i]
        node = doc[name]
        cameras[name] = _kalibr_camera(node, name, source)
        if node.get("T_cn_cnm1") is not None:
            if i == 0:
                raise InputError(
                    f"{source}: cam0.T_cn_cnm1: cam0 is the first camera of the chain and has no "
                    f"previous camera"
                )
            transforms[(name, f"cam{i - 1}")] = _transform(
                node["T_cn_cnm1"], source, f"{name}.T_cn_cnm1"
            )
        if node.get("T_cam_imu") is not None:
            transforms[(name, "imu0")] = _transform(node["T_cam_imu"], source, f"{name}.T_cam_imu")
        topic = node.get("rostopic")
        if topic is not None:
            if not isinstance(topic, str) or not topic.strip():
                raise InputError(
                    f"{source}: {name}.rostopic: expected a topic name, got {topic!r}"
                )
            topics[name] = topic.strip()
    return Camchain(cameras, transforms, topics)


def parse_camchain_text(text: str, source: str) -> Camchain:
    """The cameras and transforms of a Kalibr camchain YAML ``text``; ``source`` names the file."""
    doc = load_yaml(text, source)
    if not isinstance(doc, dict):
        raise InputError(
            f"{source}: expected a Kalibr camchain mapping (cam0, cam1, ...), got {type_name(doc)}"
        )
    return _camchain_from_doc(doc, source)


def read_camchain(path: str | os.PathLike[str]) -> Camchain:
    """The cameras and transforms of a Kalibr camchain YAML file."""
    p = Path(path)
    return parse_camchain_text(read_text(p, "Kalibr camchain file"), str(p))


# ---------------------------------------------------------------------------- original tool
def _tool_camera_from_doc(doc: dict, source: str) -> tuple[str | None, CameraModel]:
    if "calibration" in doc and "intrinsics" not in doc:
        raise InputError(
            f"{source}: the older layout with a 'calibration' list is not supported; expected "
            f"camera_type, image_width, image_height and intrinsics at the top level"
        )
    for key in ("camera_type", "intrinsics"):
        if key not in doc:
            raise InputError(f"{source}: missing '{key}'")
    for key in ("image_width", "image_height"):
        if key not in doc:
            raise InputError(f"{source}: missing '{key}' (the image resolution in px)")
    camera_type = doc["camera_type"]
    if not isinstance(camera_type, str):
        raise InputError(
            f"{source}: camera_type: expected a model name such as 'RADTAN', got "
            f"{type_name(camera_type)}"
        )
    width = _size(doc["image_width"], source, "image_width")
    height = _size(doc["image_height"], source, "image_height")
    intrinsics = _numbers(doc["intrinsics"], source, "intrinsics")
    try:
        model = camera_from_params(camera_type, width, height, intrinsics)
    except InputError as exc:
        key = "camera_type" if str(exc).startswith("unknown camera model") else "intrinsics"
        raise InputError(f"{source}: {key}: {exc}") from None
    frame_id = doc.get("frame_id")
    if frame_id is not None and (not isinstance(frame_id, str) or not frame_id.strip()):
        raise InputError(f"{source}: frame_id: expected a frame name, got {frame_id!r}")
    return (frame_id.strip() if frame_id else None), model


def _load_json(text: str, source: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{source}: line {exc.lineno}, column {exc.colno}: invalid JSON: {exc.msg}"
        ) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise InputError(f"{source}: not a usable JSON document ({exc})") from None
    except RecursionError:
        raise InputError(f"{source}: JSON nested too deeply") from None


def parse_intrinsics_json_text(text: str, source: str) -> CameraModel:
    """The camera of the original tool's intrinsics JSON ``text``; ``source`` names the file."""
    doc = _load_json(text, source)
    if not isinstance(doc, dict):
        raise InputError(
            f"{source}: expected an intrinsics object (camera_type, intrinsics, ...), got "
            f"{type_name(doc)}"
        )
    return _tool_camera_from_doc(doc, source)[1]


def read_intrinsics_json(path: str | os.PathLike[str]) -> CameraModel:
    """The camera of one of the original tool's intrinsics JSON files."""
    p = Path(path)
    return parse_intrinsics_json_text(read_text(p, "camera intrinsics file"), str(p))


# ---------------------------------------------------------------------------- any camera file
def _first_content_line(text: str) -> str:
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if line:
            return line
    return ""


def _looks_like_camchain(doc: dict) -> bool:
    return any(isinstance(k, str) and _CAM_KEY.fullmatch(k) for k in doc)


def parse_camera_file_text(text: str, source: str) -> Camchain:
    """The cameras of any camera file rigcal reads, chosen by content:

    * a mapping with ``cam0``, ``cam1``, ... keys - a Kalibr camchain;
    * a mapping with ``camera_type`` / ``intrinsics`` - the original tool's intrinsics (JSON);
    * a mapping with ``camera_matrix`` - a ROS CameraInfo YAML (named by ``camera_name``);
    * a leading ``[section]`` line - the ROS calibrator's INI.

    Single-camera files give one camera named by ``frame_id`` / ``camera_name``, else
    ``Path(source).stem``.
    """
    text = text.lstrip("\ufeff")
    first = _first_content_line(text)
    stem = Path(source).stem or "camera"
    if first.startswith("[") and first.endswith("]") and len(first) > 2 and "," not in first:
        camera = parse_intrinsics_ini_text(text, source)
        return Camchain({stem: camera}, {}, {})
    doc = _load_json(text, source) if text.lstrip().startswith("{") else load_yaml(text, source)
    if isinstance(doc, dict):
        if _looks_like_camchain(doc):
            return _camchain_from_doc(doc, source)
        if "camera_type" in doc or "intrinsics" in doc or "calibration" in doc:
            frame_id, camera = _tool_camera_from_doc(doc, source)
            return Camchain({frame_id or stem: camera}, {}, {})
        if "camera_matrix" in doc:
            camera = parse_camera_info_yaml_text(text, source)
            name = doc.get("camera_name")
            name = name.strip() if isinstance(name, str) and name.strip() else stem
            return Camchain({name: camera}, {}, {})
    raise InputError(
        f"{source}: not a camera file rigcal knows; expected a Kalibr camchain (cam0, cam1, ...), "
        f"the original tool's intrinsics JSON (camera_type, intrinsics, image_width, "
        f"image_height), a ROS CameraInfo YAML (camera_matrix, ...) or a ROS calibrator INI"
    )


def read_camera_file(path: str | os.PathLike[str]) -> Camchain:
    """The cameras (and transforms) of any camera file rigcal reads; see
    :func:`parse_camera_file_text`."""
    p = Path(path)
    return parse_camera_file_text(read_text(p, "camera file"), str(p))


# ---------------------------------------------------------------------------- choosing one camera
def select_camera(
    chain: Camchain,
    source: str,
    *,
    camera: str | None = None,
    names: tuple[str, ...] = (),
    topic: str | None = None,
) -> tuple[str, CameraModel]:
    """(name, model) of one camera of a camera file: ``camera`` if given (InputError if the file
    lacks it), else the only one, else the one whose ``rostopic`` is ``topic``, else the first
    named like one of ``names`` (a sensor's name, its frame_id); InputError listing the
    cameras otherwise."""
    cams = chain.cameras
    if camera is not None:
        if camera not in cams:
            raise InputError(f"{source}: no camera '{camera}' (cameras: {', '.join(cams)})")
        return camera, cams[camera]
    if len(cams) == 1:
        name = next(iter(cams))
        return name, cams[name]
    if topic is not None:
        hits = [n for n, t in chain.topics.items() if t == topic]
        if len(hits) == 1:
            return hits[0], cams[hits[0]]
    for key in names:
        if key in cams:
            return key, cams[key]
    raise InputError(
        f"{source} holds cameras {', '.join(cams)} and none has the topic {topic or '-'} or the "
        f"name {' / '.join(names) or '-'}; say which with 'camera' (e.g. camera: cam1)"
    )


# ---------------------------------------------------------------------------- writing
def _kalibr_node(camera: CameraModel, name: str) -> dict[str, Any]:
    p = [float(v) for v in camera.params]
    if isinstance(camera, DoubleSphereCamera):
        model, intrinsics, distortion, coeffs = "ds", p[4:6] + p[:4], "none", []
    elif isinstance(camera, KannalaBrandtCamera):
        model, intrinsics, distortion, coeffs = "pinhole", p[:4], "equidistant", p[4:8]
    elif isinstance(camera, RadtanCamera):
        if p[8] != 0.0:
            raise InputError(
                f"{name}: Kalibr's radtan has no k3; cannot write k3 = {p[8]} to a camchain"
            )
        model, intrinsics, distortion, coeffs = "pinhole", p[:4], "radtan", p[4:8]
    elif isinstance(camera, PinholeCamera):
        model, intrinsics, distortion, coeffs = "pinhole", p[:4], "none", []
    else:
        raise InputError(f"{name}: Kalibr has no equivalent of the {camera.name} camera model")
    return {
        "camera_model": model,
        "intrinsics": intrinsics,
        "distortion_model": distortion,
        "distortion_coeffs": coeffs,
        "resolution": [camera.width, camera.height],
    }


def format_camchain(chain: Camchain) -> str:
    """A Kalibr camchain YAML text of ``chain`` (cameras named ``cam0``, ``cam1``, ... in order;
    ``T_to_from[("camN", "cam(N-1)")]`` becomes ``T_cn_cnm1``, ``("camN", "imu0")`` ``T_cam_imu``).

    Raises InputError for other camera names or transforms and for models Kalibr lacks.
    """
    names = list(chain.cameras)
    expected = [f"cam{i}" for i in range(len(names))]
    if names != expected:
        raise InputError(f"camchain cameras must be named {expected} in order, got {names}")
    doc: dict[str, Any] = {}
    for name in names:
        doc[name] = _kalibr_node(chain.cameras[name], name)
    for (to, frm), T in chain.T_to_from.items():
        i = names.index(to) if to in names else -1
        if i > 0 and frm == f"cam{i - 1}":
            doc[to]["T_cn_cnm1"] = np.asarray(T, dtype=float).tolist()
        elif i >= 0 and frm == "imu0":
            doc[to]["T_cam_imu"] = np.asarray(T, dtype=float).tolist()
        else:
            raise InputError(
                f"camchain transform T_{to}_{frm}: Kalibr stores only T_camN_cam(N-1) and "
                f"T_camN_imu0"
            )
    for name, topic in chain.topics.items():
        if name not in doc:
            raise InputError(f"camchain topic for unknown camera {name!r}")
        doc[name]["rostopic"] = topic
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def calibration_camchain(cameras: list[tuple[CameraModel, np.ndarray, str | None]]) -> Camchain:
    """A Kalibr camchain of calibrated cameras: per camera (in order ``cam0``, ``cam1``, ...)
    its model, ``T_reference_camera`` (4, 4; the camera's optical frame in the calibration's
    reference frame) and its ROS image topic (None if unknown). ``camN``'s ``T_cn_cnm1`` =
    ``inv(T_reference_camN) @ T_reference_cam(N-1)`` maps points in ``cam(N-1)`` into ``camN``."""
    if not cameras:
        raise InputError("a camchain needs at least one camera")
    names = [f"cam{i}" for i in range(len(cameras))]
    models = {n: c[0] for n, c in zip(names, cameras)}
    T_to_from: dict[tuple[str, str], np.ndarray] = {}
    for i in range(1, len(cameras)):
        T_ref_prev = np.asarray(cameras[i - 1][1], dtype=float)
        T_ref_this = np.asarray(cameras[i][1], dtype=float)
        R = T_ref_this[:3, :3].T
        T = np.eye(4)
        T[:3, :3] = R @ T_ref_prev[:3, :3]
        T[:3, 3] = R @ (T_ref_prev[:3, 3] - T_ref_this[:3, 3])
        T_to_from[(names[i], names[i - 1])] = T
    topics = {n: c[2] for n, c in zip(names, cameras) if c[2]}
    return Camchain(models, T_to_from, topics)


__all__ = [
    "Camchain",
    "calibration_camchain",
    "select_camera",
    "format_camchain",
    "parse_camchain_text",
    "parse_camera_file_text",
    "parse_intrinsics_json_text",
    "read_camchain",
    "read_camera_file",
    "read_intrinsics_json",
]
