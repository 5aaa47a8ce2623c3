"""Camera intrinsics files written by the ROS camera calibrator -> :class:`RadtanCamera`.

Two formats:

* the calibrator's INI ("oST" text)::

    [image]
    width
    1936
    height
    1216
    [narrow_stereo/left]          # the camera's name
    camera matrix                 # 3 rows of 3
    fx 0 cx
    0 fy cy
    0 0 1
    distortion                    # k1 k2 p1 p2 [k3] (plumb bob)
    -0.17 0.16 0.003 -0.002 -0.06
    rectification                 # optional, 3x3
    projection                    # optional, 3x4

* the CameraInfo YAML (``image_width``, ``image_height``, ``camera_name``,
  ``camera_matrix: {rows: 3, cols: 3, data: [...]}``, ``distortion_model: plumb_bob``,
  ``distortion_coefficients: {rows: 1, cols: 5, data: [...]}``, optional
  ``rectification_matrix`` 3x3 and ``projection_matrix`` 3x4).

Rectification and projection are checked for shape and numbers but not used: the camera model
describes the raw (distorted) image. Every malformed input raises :class:`InputError` naming the
file, the line (INI) and the field.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.errors import InputError
from rigcal.io._text import is_finite_number, load_yaml, read_text, type_name
from rigcal.sensors.camera.base import CameraModel
from rigcal.sensors.camera.radtan import RadtanCamera

_DIST_NAMES = "k1 k2 p1 p2 [k3]"
_CAMERA_KEYS = {
    "camera matrix": (3, 3),
    "distortion": None,  # 4 or 5 numbers on any number of lines
    "rectification": (3, 3),
    "projection": (3, 4),
}
_IMAGE_KEYS = ("width", "height")
_PLUMB_BOB = ("plumb_bob", "radtan", "radial-tangential")


# ---------------------------------------------------------------------------- shared checks
def _camera(
    source: str,
    width: Any,
    height: Any,
    K: np.ndarray,
    dist: np.ndarray,
    where_size: tuple[str, str],
    where_K: str,
    where_dist: str,
) -> RadtanCamera:
    for value, where in zip((width, height), where_size):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise InputError(f"{source}: {where}: expected a positive integer [px], got {value!r}")
    if dist.size not in (4, 5):
        raise InputError(
            f"{source}: {where_dist}: expected 5 plumb-bob coefficients ({_DIST_NAMES}), "
            f"got {dist.size}"
        )
    fx, fy = K[0, 0], K[1, 1]
    if not (fx > 0 and fy > 0):
        raise InputError(f"{source}: {where_K}: fx and fy must be > 0, got {fx:g} and {fy:g}")
    if K[0, 1] != 0.0 or K[1, 0] != 0.0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise InputError(
            f"{source}: {where_K}: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got "
            f"{K.tolist()}"
        )
    try:
        return RadtanCamera.from_opencv(width, height, K, dist)
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


# ---------------------------------------------------------------------------- CameraInfo message
_INFO_MODELS = {  # distortion_model -> (rigcal model, D sizes accepted)
    "plumb_bob": ("radtan", (0, 4, 5)),
    "rational_polynomial": ("radtan", (8, 12, 14)),
    "equidistant": ("kannala_brandt", (4,)),
}


def camera_from_info(info: Any, source: str) -> CameraModel:
    """The camera model of a ``sensor_msgs/CameraInfo``
    (:class:`rigcal.io.recordings.bag.CameraInfo`): ``K`` (fx, fy, cx, cy; no skew), ``D`` and ``distortion_model``, ``width``/``height``.

    ``plumb_bob`` (k1 k2 p1 p2 [k3]; an empty D is no distortion) -> radtan; ``equidistant``
    (k1 k2 k3 k4) -> kannala_brandt; ``rational_polynomial`` (k1 k2 p1 p2 k3 k4 k5 k6 [...])
    -> radtan when k4.. are all 0 (rigcal has no rational model; other values are refused).
    An uncalibrated camera (K all zeros) is refused. Errors name ``source``."""
    from rigcal.io.limits import check_finite
    from rigcal.sensors.camera.registry import camera_from_params

    model = str(getattr(info, "distortion_model", "")).strip().lower() or "plumb_bob"
    if model not in _INFO_MODELS:
        raise InputError(
            f"{source}: CameraInfo distortion_model '{model}' is not supported (expected "
            f"{', '.join(_INFO_MODELS)})"
        )
    name, sizes = _INFO_MODELS[model]
    K = check_finite(np.asarray(info.K, dtype=float).reshape(-1), source, "CameraInfo K", "px")
    D = check_finite(np.asarray(info.D, dtype=float).reshape(-1), source, "CameraInfo D", "px")
    if K.size != 9:
        raise InputError(f"{source}: CameraInfo K has {K.size} values, expected 9 (3 x 3)")
    K = K.reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(
            f"{source}: CameraInfo K has fx = {K[0, 0]:g}, fy = {K[1, 1]:g}; expected a "
            "calibrated camera (fx, fy > 0)"
        )
    if K[0, 1] != 0.0 or K[1, 0] != 0.0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise InputError(
            f"{source}: CameraInfo K is {K.tolist()}, expected [[fx, 0, cx], [0, fy, cy], "
            "[0, 0, 1]] (no skew)"
        )
    if D.size not in sizes:
        raise InputError(
            f"{source}: CameraInfo D has {D.size} coefficients, expected "
            f"{' or '.join(map(str, sizes))} for distortion_model {model}"
        )
    if model == "rational_polynomial":
        if np.any(D[5:] != 0.0):
            raise InputError(
                f"{source}: CameraInfo distortion_model rational_polynomial with k4..k6 = "
                f"{D[5:8].tolist()} is not supported (rigcal models plumb_bob, equidistant; "
                "k4.. must be 0)"
            )
        D = D[:5]
    if name == "radtan":
        D = np.concatenate([D, np.zeros(5 - D.size)])
    width, height = getattr(info, "width", 0), getattr(info, "height", 0)
    for value, what in ((width, "width"), (height, "height")):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
            raise InputError(f"{source}: CameraInfo {what} is {value!r}, expected a positive "
                             "integer [px]")
    params = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *D]
    try:
        return camera_from_params(name, int(width), int(height), params)
    except InputError as exc:
        raise InputError(f"{source}: CameraInfo: {exc}") from None


# ---------------------------------------------------------------------------- INI
def _parse_number(token: str, source: str, line: int, field: str) -> float:
    try:
        if "_" in token:
            raise ValueError
        value = float(token)
    except ValueError:
        raise InputError(
            f"{source}: line {line}: {field}: expected a number, got {token!r}"
        ) from None
    if not math.isfinite(value):
        raise InputError(f"{source}: line {line}: {field}: expected a finite number, got {token!r}")
    return value


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def parse_intrinsics_ini_text(
    text: str, source: str, camera_name: str | None = None
) -> RadtanCamera:
    """A :class:`RadtanCamera` from the ROS calibrator's INI ``text``; ``source`` names the file.

    A file with several camera sections needs ``camera_name`` (the section name, e.g.
    ``narrow_stereo/left``).
    """
    if text.startswith("\ufeff"):
        text = text[1:]
    # sections -> key -> (first line, rows of numbers)
    sections: dict[str, dict[str, tuple[int, list[list[float]]]]] = {}
    section_lines: dict[str, int] = {}
    section: str | None = None
    key: str | None = None
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("["):
            if not line.endswith("]") or len(line) < 3:
                raise InputError(f"{source}: line {line_no}: malformed section header {line!r}")
            section = line[1:-1].strip()
            if section in sections:
                raise InputError(f"{source}: line {line_no}: duplicate section [{section}]")
            sections[section] = {}
            section_lines[section] = line_no
            key = None
            continue
        if section is None:
            raise InputError(
                f"{source}: line {line_no}: {line!r} before the first [section] header"
            )
        tokens = line.split()
        known = _IMAGE_KEYS if section == "image" else tuple(_CAMERA_KEYS)
        name = " ".join(tokens).lower()
        if not _is_number(tokens[0]) and name in known:
            if name in sections[section]:
                raise InputError(f"{source}: line {line_no}: [{section}] duplicate key '{name}'")
            key = name
            sections[section][key] = (line_no, [])
            continue
        if key is not None and not sections[section][key][1] or _is_number(tokens[0]):
            if key is None:
                raise InputError(
                    f"{source}: line {line_no}: [{section}] numbers before any key "
                    f"(expected one of: {', '.join(known)})"
                )
            field = f"[{section}] {key}"
            sections[section][key][1].append(
                [_parse_number(t, source, line_no, field) for t in tokens]
            )
            continue
        raise InputError(
            f"{source}: line {line_no}: [{section}] unknown key {line!r} "
            f"(expected one of: {', '.join(known)})"
        )

    if "image" not in sections:
        raise InputError(f"{source}: missing section [image] (width, height)")
    image = sections["image"]
    size = []
    for k in _IMAGE_KEYS:
        if k not in image:
            raise InputError(f"{source}: [image]: missing '{k}'")
        line_no, rows = image[k]
        values = [v for row in rows for v in row]
        if len(values) != 1 or not float(values[0]).is_integer():
            raise InputError(
                f"{source}: line {line_no}: [image] {k}: expected one integer [px], got "
                f"{values if values else 'nothing'}"
            )
        size.append(int(values[0]))

    cameras = [s for s in sections if s != "image"]
    if not cameras:
        raise InputError(
            f"{source}: missing the camera section (e.g. [narrow_stereo/left]) with "
            f"'camera matrix' and 'distortion'"
        )
    if camera_name is None:
        if len(cameras) > 1:
            raise InputError(
                f"{source}: several camera sections {cameras}; choose one with camera_name"
            )
        camera_name = cameras[0]
    elif camera_name not in cameras:
        raise InputError(f"{source}: no camera section [{camera_name}] (found {cameras})")
    cam = sections[camera_name]

    matrices: dict[str, np.ndarray] = {}
    for k, shape in _CAMERA_KEYS.items():
        if k not in cam:
            if k in ("camera matrix", "distortion"):
                raise InputError(
                    f"{source}: [{camera_name}] (line {section_lines[camera_name]}): missing "
                    f"'{k}'"
                )
            continue
        line_no, rows = cam[k]
        if shape is None:
            matrices[k] = np.array([v for row in rows for v in row])
            continue
        if len(rows) != shape[0] or any(len(r) != shape[1] for r in rows):
            got = " + ".join(str(len(r)) for r in rows) if rows else "nothing"
            raise InputError(
                f"{source}: line {line_no}: [{camera_name}] {k}: expected {shape[0]} rows of "
                f"{shape[1]} numbers, got {len(rows)} rows ({got} numbers)"
            )
        matrices[k] = np.array(rows)
    dist_line = cam["distortion"][0]
    return _camera(
        source,
        size[0],
        size[1],
        matrices["camera matrix"],
        matrices["distortion"],
        ("[image] width", "[image] height"),
        f"line {cam['camera matrix'][0]}: [{camera_name}] camera matrix",
        f"line {dist_line}: [{camera_name}] distortion",
    )


# ---------------------------------------------------------------------------- YAML
def _yaml_matrix(doc: dict, key: str, shape: tuple[int, int] | None, source: str) -> np.ndarray:
    """``doc[key]`` = {rows, cols, data}; ``shape`` None accepts 1 x n or n x 1."""
    node = doc[key]
    if not isinstance(node, dict):
        raise InputError(
            f"{source}: {key}: expected a mapping with rows, cols, data, got {type_name(node)}"
        )
    for part in ("rows", "cols", "data"):
        if part not in node:
            raise InputError(f"{source}: {key}: missing '{part}'")
    rows, cols, data = node["rows"], node["cols"], node["data"]
    for part, v in (("rows", rows), ("cols", cols)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise InputError(f"{source}: {key}.{part}: expected a non-negative integer, got {v!r}")
    if not isinstance(data, list):
        raise InputError(f"{source}: {key}.data: expected a list of numbers, got {type_name(data)}")
    for i, v in enumerate(data):
        if not is_finite_number(v):
            raise InputError(
                f"{source}: {key}.data[{i}]: expected a finite number, got {v!r} ({type_name(v)})"
            )
    if len(data) != rows * cols:
        raise InputError(
            f"{source}: {key}: rows x cols = {rows} x {cols} but data has {len(data)} numbers"
        )
    if shape is not None and (rows, cols) != shape:
        raise InputError(f"{source}: {key}: expected {shape[0]} x {shape[1]}, got {rows} x {cols}")
    if shape is None and min(rows, cols) > 1:
        raise InputError(f"{source}: {key}: expected a 1 x n vector, got {rows} x {cols}")
    arr = np.array(data, dtype=float)
    return arr if shape is None else arr.reshape(shape)


def parse_camera_info_yaml_text(text: str, source: str) -> RadtanCamera:
    """A :class:`RadtanCamera` from a ROS CameraInfo YAML ``text``; ``source`` names the file."""
    doc = load_yaml(text, source)
    if not isinstance(doc, dict):
        raise InputError(
            f"{source}: expected a CameraInfo mapping (image_width, camera_matrix, ...), got "
            f"{type_name(doc)}"
        )
    for k in ("image_width", "image_height", "camera_matrix", "distortion_coefficients"):
        if k not in doc:
            raise InputError(f"{source}: missing field '{k}'")
    model = doc.get("distortion_model", "plumb_bob")
    if not isinstance(model, str) or model.strip().lower() not in _PLUMB_BOB:
        raise InputError(
            f"{source}: distortion_model: only plumb_bob is supported, got {model!r}"
        )
    K = _yaml_matrix(doc, "camera_matrix", (3, 3), source)
    dist = _yaml_matrix(doc, "distortion_coefficients", None, source)
    for k, shape in (("rectification_matrix", (3, 3)), ("projection_matrix", (3, 4))):
        if k in doc and doc[k] is not None:
            _yaml_matrix(doc, k, shape, source)
    return _camera(
        source,
        doc["image_width"],
        doc["image_height"],
        K,
        dist,
        ("image_width", "image_height"),
        "camera_matrix",
        "distortion_coefficients",
    )


# ---------------------------------------------------------------------------- files
def _looks_like_ini(text: str) -> bool:
    for raw in text.lstrip("\ufeff").splitlines():
        line = raw.split("#", 1)[0].strip()
        if line:
            return line.startswith("[")
    return False


def read_intrinsics(path: str | os.PathLike[str], camera_name: str | None = None) -> RadtanCamera:
    """The camera of an intrinsics file: ``.ini`` -> INI, ``.yaml``/``.yml`` -> CameraInfo YAML,
    anything else by content (a leading ``[section]`` means INI)."""
    p = Path(path)
    text = read_text(p, "camera intrinsics file")
    suffix = p.suffix.lower()
    if suffix == ".ini" or (suffix not in (".yaml", ".yml") and _looks_like_ini(text)):
        return parse_intrinsics_ini_text(text, str(p), camera_name=camera_name)
    return parse_camera_info_yaml_text(text, str(p))
