"""The original mocap calibration tool's JSON files: target definitions and optimizer settings.

Target definition (``CheckerboardTargetSim.json``, ``CheckerboardTarget_EXAMPLE.json``,
``CylinderTarget.json``), all coordinates metres in the target frame (the frame the mocap
system tracks, the frame of the template cloud)::

    {
      "crop_scan": [x_min, x_max, y_min, y_max, z_min, z_max],   # box in the target frame [m]
      "crop_image": [w, h],                 # image margins around the projected target [px]
      "template_cloud": "name.pcd",         # relative to the JSON file; "" = none
      "is_target_2d": true,                 # a plate
      "use_lidar_keypoints": true,          # optional; lidar matched to keypoints or template
      "keypoints_lidar": [{"x": .., "y": .., "z": ..}, ...],
      "keypoints_camera": [{"x": .., "y": .., "z": ..}, ...]
    }

The crop box layout (min, max pairs per axis, applied after mapping scan points into the
target frame) follows the tool's scan cropping. Note that the shared files' boxes are rough:
``CheckerboardTargetSim.json``'s +-5 cm box holds none of its own keypoints, and
``CylinderTarget.json``'s z range +-0.3 m holds only the top 0.3 m of the 0.5 m cylinder in
``cylinder_target_rotated.pcd`` (whose axis is z) - it seems written for a cylinder lying
along x. They are read as given.

:func:`parse_vicon_target` returns a :class:`rigcal.targets.definition.Target`. Its kind is
inferred unless given: a plate whose camera keypoints are a full checkerboard grid of inner
corners at ``((c + 1) s, (r + 1) s, 0)`` and whose lidar keypoints (if any) are the corners of a
diamond centred on that grid is a ``checkerboard_diamond`` (dims rows, cols, square_m and, from
the corners, side_m); a solid without keypoints is a ``cylinder``; anything else ``custom``.
The template is, in this order: the ``template`` argument, the referenced PCD (when it exists),
or the analytic template of the kind (:func:`rigcal.targets.templates.analytic_target`, which
needs the dims; missing ones can be passed in ``dims``).

Optimizer settings (``OptimizerConfig.json``) become an :class:`OptimizerConfig`; see its
docstring for every field and its unit.
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from rigcal.errors import InputError
from rigcal.targets.definition import CropBox, Target, TargetKind

__all__ = [
    "OptimizerConfig",
    "load_json",
    "optimizer_config_json_text",
    "parse_optimizer_config",
    "parse_vicon_target",
    "read_optimizer_config",
    "read_vicon_target",
    "vicon_target_json_text",
    "write_vicon_target",
]

log = logging.getLogger(__name__)

DIAMOND_TOL_M = 1e-4
"""Largest deviation [m] of lidar keypoints from an exact diamond for the kind to be inferred."""


def load_json(text: str, source: str) -> Any:
    """Parse JSON ``text``; syntax errors and duplicate keys raise InputError naming ``source``
    and the line."""

    def no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in pairs:
            if k in out:
                raise InputError(f"{source}: duplicate key '{k}'")
            out[k] = v
        return out

    try:
        return json.loads(text, object_pairs_hook=no_duplicates)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{source}: line {exc.lineno}, column {exc.colno}: invalid JSON: {exc.msg}"
        ) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise InputError(f"{source}: not a usable JSON document ({exc})") from None
    except RecursionError:
        raise InputError(f"{source}: JSON nested too deeply") from None


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(doc: Mapping[str, Any], key: str, n: int | None, source: str) -> list[float]:
    if key not in doc:
        raise InputError(f"{source}: missing key '{key}'")
    v = doc[key]
    if not isinstance(v, list) or not all(_is_number(x) for x in v):
        raise InputError(f"{source}: '{key}' must be a list of numbers, got {v!r}")
    if n is not None and len(v) != n:
        raise InputError(f"{source}: '{key}' must have {n} numbers, got {len(v)}")
    return [float(x) for x in v]


def _bool(doc: Mapping[str, Any], key: str, source: str, default: bool | None = None) -> bool:
    if key not in doc:
        if default is not None:
            return default
        raise InputError(f"{source}: missing key '{key}'")
    v = doc[key]
    if not isinstance(v, bool):
        raise InputError(f"{source}: '{key}' must be true or false, got {v!r}")
    return v


def _keypoints(doc: Mapping[str, Any], key: str, source: str) -> np.ndarray | None:
    if key not in doc:
        raise InputError(f"{source}: missing key '{key}'")
    v = doc[key]
    if not isinstance(v, list):
        raise InputError(f"{source}: '{key}' must be a list of {{x, y, z}}, got {v!r}")
    pts = []
    for i, p in enumerate(v):
        if not isinstance(p, dict):
            raise InputError(f"{source}: {key}[{i}] must be an object {{x, y, z}}, got {p!r}")
        row = []
        for axis in "xyz":
            if axis not in p:
                raise InputError(f"{source}: {key}[{i}]: missing key '{axis}'")
            if not _is_number(p[axis]):
                raise InputError(f"{source}: {key}[{i}].{axis} must be a number, got "
                                 f"{p[axis]!r}")
            row.append(float(p[axis]))
        pts.append(row)
    return np.array(pts) if pts else None


# --------------------------------------------------------------------------------------------
# target definitions


def _checkerboard_grid(points: np.ndarray | None) -> tuple[int, int, float] | None:
    """(rows, cols, square_m) if ``points`` are exactly the inner corners of a checkerboard in
    rigcal's diamond convention (see :mod:`rigcal.targets.templates`), else None."""
    from rigcal.targets.templates import checkerboard_inner_corners

    if points is None or len(points) < 2:
        return None
    xs = np.unique(np.round(points[:, 0], 9))
    ys = np.unique(np.round(points[:, 1], 9))
    rows, cols = len(ys), len(xs)
    if rows * cols != len(points):
        return None
    sq = float(xs[0]) if cols else 0.0
    if sq <= 0:
        return None
    expected = checkerboard_inner_corners(rows, cols, sq)
    if not np.allclose(points, expected, atol=1e-6, rtol=0.0):
        return None
    return rows, cols, sq


def _diamond_side(lidar: np.ndarray | None, rows: int, cols: int, sq: float) -> float | None:
    """The diamond's side if ``lidar`` are its 4 corners around the checkerboard centre."""
    from rigcal.targets.templates import diamond_corners

    if lidar is None or len(lidar) != 4:
        return None
    centre = np.array([(cols + 1) * sq / 2.0, (rows + 1) * sq / 2.0])
    h = float(np.median(np.linalg.norm(lidar[:, :2] - centre, axis=1)))
    if h <= 0:
        return None
    side = h * math.sqrt(2.0)
    # 0.1 mm: the shared CheckerboardTargetSim.json has its +x corner 20 um off the square
    if not np.allclose(lidar, diamond_corners(side, centre), atol=DIAMOND_TOL_M, rtol=0.0):
        return None
    return side


def _template_points(template: Any, source: str) -> np.ndarray:
    from rigcal.io.clouds import read_point_cloud
    from rigcal.recording import PointCloudFrame

    if isinstance(template, PointCloudFrame):
        return template.points_xyz
    if isinstance(template, (str, os.PathLike)):
        return read_point_cloud(template, "template").points_xyz
    try:
        pts = np.asarray(template, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{source}: template must be points (K, 3), a point cloud or a path"
                         ) from None
    return pts


def parse_vicon_target(text: str, source: str = "target JSON", *, name: str | None = None,
                       kind: TargetKind | str | None = None, template: Any = None,
                       template_dir: str | os.PathLike[str] | None = None,
                       dims: Mapping[str, float] | None = None,
                       resolution_m: float | None = None) -> Target:
    """A :class:`Target` from the original tool's target JSON text (see the module docstring).

    ``template``: points (K, 3) in the target frame, a PointCloudFrame or a point cloud path;
    it takes precedence over the file's ``template_cloud``, which is looked up in
    ``template_dir`` (None: not looked up). ``dims`` adds or confirms dimensions (a value that
    contradicts one inferred from the keypoints by more than 1e-6 is refused).
    ``resolution_m`` is the analytic template's sampling step."""
    doc = load_json(text, source)
    if not isinstance(doc, dict):
        raise InputError(f"{source}: expected a JSON object, got {type(doc).__name__}")
    bounds = _numbers(doc, "crop_scan", 6, source)
    try:
        crop = CropBox.from_bounds(bounds)
    except InputError as exc:
        raise InputError(f"{source}: 'crop_scan' [x_min, x_max, y_min, y_max, z_min, z_max]: "
                         f"{exc}") from None
    crop_image = _numbers(doc, "crop_image", 2, source)
    if "template_cloud" not in doc:
        raise InputError(f"{source}: missing key 'template_cloud'")
    cloud_name = doc["template_cloud"]
    if not isinstance(cloud_name, str):
        raise InputError(f"{source}: 'template_cloud' must be a file name or \"\", got "
                         f"{cloud_name!r}")
    is_2d = _bool(doc, "is_target_2d", source)
    lidar = _keypoints(doc, "keypoints_lidar", source)
    camera = _keypoints(doc, "keypoints_camera", source)
    use_lidar = _bool(doc, "use_lidar_keypoints", source, default=lidar is not None)
    if use_lidar and lidar is None:
        log.warning("%s: use_lidar_keypoints is true but keypoints_lidar is empty; lidar "
                    "measurements will be matched to the template", source)
        use_lidar = False
    known = {"crop_scan", "crop_image", "template_cloud", "is_target_2d", "use_lidar_keypoints",
             "keypoints_lidar", "keypoints_camera"}
    unknown = sorted(set(doc) - known)
    if unknown:
        log.warning("%s: ignoring unknown keys %s", source, unknown)

    inferred: dict[str, float] = {}
    grid = _checkerboard_grid(camera)
    inferred_kind = TargetKind.CUSTOM
    if grid is not None and is_2d:
        rows, cols, sq = grid
        side = _diamond_side(lidar, rows, cols, sq)
        if lidar is None or side is not None:
            inferred_kind = TargetKind.CHECKERBOARD_DIAMOND
            inferred.update(rows=rows, cols=cols, square_m=sq)
            if side is not None:
                inferred["side_m"] = side
    elif not is_2d and lidar is None and camera is None:
        inferred_kind = TargetKind.CYLINDER
    target_kind = TargetKind.parse(kind, source) if kind is not None else inferred_kind
    all_dims = dict(inferred)
    for k, v in dict(dims or {}).items():
        if k in inferred and abs(float(v) - float(inferred[k])) > 1e-6:
            raise InputError(
                f"{source}: dims['{k}'] = {v} contradicts {inferred[k]:.9g} inferred from the "
                "keypoints"
            )
        all_dims[k] = v

    if template is not None:
        points = _template_points(template, source)
    else:
        points = None
        if cloud_name and template_dir is not None:
            path = Path(template_dir) / cloud_name
            if path.is_file():
                from rigcal.io.clouds import read_point_cloud

                points = read_point_cloud(path, "template").points_xyz
            else:
                log.warning("%s: template_cloud %s not found; using the analytic template",
                            source, path)
        if points is None:
            from rigcal.targets.templates import analytic_target

            why = (f"template_cloud '{cloud_name}' not found" if cloud_name and template_dir
                   else f"template_cloud '{cloud_name}' not looked up" if cloud_name
                   else "template_cloud is empty")
            try:
                points = analytic_target(target_kind, all_dims,
                                         resolution_m=resolution_m).template
            except InputError as exc:
                raise InputError(
                    f"{source}: no template: {why} and {exc}; pass template= or dims="
                ) from None
    stem = Path(source).stem if source else "target"
    try:
        return Target(
            name=name or stem, kind=target_kind, template=points, lidar_keypoints=lidar,
            camera_keypoints=camera, dims=all_dims, crop_box=crop, planar=is_2d,
            use_lidar_keypoints=use_lidar, crop_image_px=tuple(crop_image),
        )
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def read_vicon_target(path: str | os.PathLike[str], *, name: str | None = None,
                      kind: TargetKind | str | None = None, template: Any = None,
                      dims: Mapping[str, float] | None = None,
                      resolution_m: float | None = None) -> Target:
    """Read a target JSON file (:func:`parse_vicon_target`); ``template_cloud`` is looked up
    next to the file and the target is named after the file's stem unless ``name`` is given."""
    from rigcal.io._text import read_text

    p = Path(path)
    return parse_vicon_target(read_text(p, "target JSON"), str(p), name=name, kind=kind,
                              template=template, template_dir=p.parent, dims=dims,
                              resolution_m=resolution_m)


def vicon_target_json_text(target: Target, template_cloud: str = "") -> str:
    """The original tool's target JSON for ``target`` (``template_cloud`` names the PCD the
    caller writes next to it; rigcal's ``kind`` and ``dims`` are not part of the format). A
    target without a crop box gets its template's bounding box grown by 0.1 m."""
    crop = target.crop_box or CropBox.around(target.template, 0.1)

    def pts(a: np.ndarray | None) -> list[dict[str, float]]:
        return [] if a is None else [{"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}
                                     for p in a]

    doc = {
        "crop_scan": list(crop.bounds()),
        "crop_image": list(target.crop_image_px or (0.0, 0.0)),
        "template_cloud": template_cloud,
        "is_target_2d": target.planar,
        "use_lidar_keypoints": target.use_lidar_keypoints,
        "keypoints_lidar": pts(target.lidar_keypoints),
        "keypoints_camera": pts(target.camera_keypoints),
    }
    return json.dumps(doc, indent=2) + "\n"


def write_vicon_target(path: str | os.PathLike[str], target: Target,
                       template_cloud: str = "") -> Path:
    """Write :func:`vicon_target_json_text` atomically; when ``template_cloud`` is given the
    template is written there too (binary PCD, relative to the JSON file)."""
    from rigcal.io.atomic import atomic_write_text
    from rigcal.io.clouds import write_pcd
    from rigcal.recording import PointCloudFrame

    p = Path(path)
    if template_cloud:
        write_pcd(p.parent / template_cloud, PointCloudFrame("template", 0, target.template),
                  xyz_dtype=np.float64)
    return atomic_write_text(p, vicon_target_json_text(target, template_cloud))


# --------------------------------------------------------------------------------------------
# optimizer settings


@dataclass(frozen=True)
class OptimizerConfig:
    """The original tool's ``OptimizerConfig.json`` (defaults: the shared file's values).

    Field (JSON key) - meaning:

    * ``max_correspondence_iterations`` (same) - outer iterations of correspondence search +
      least squares before giving up;
    * ``max_pixel_cor_dist_px`` (``max_pixel_cor_dist``) - largest image distance [px] of a
      camera correspondence;
    * ``max_point_cor_dist_m`` (``max_point_cor_dist``) - largest distance [m] of a lidar
      correspondence (100: unlimited);
    * ``match_centroids`` - shift the predicted keypoints onto the measured centroid before the
      nearest-neighbour search (paper, section III-D); ``match_centroids_on_first_iter_only``
      - only in the first iteration;
    * ``extract_image_target_perimeter`` - for targets without camera keypoints, match image
      measurements to the outline (concave hull, ``concave_hull_alpha`` [px]) of the projected
      template;
    * ``estimate_target_lidar_corrections`` / ``estimate_target_camera_corrections`` - also
      estimate a correction of each target's pose;
    * ``error_tol_rot_deg`` (``error_tol[0:3]``) and ``error_tol_trans_m`` (``error_tol[3:6]``)
      - convergence: stop when every calibration changes less than these per axis (roll, pitch,
      yaw [deg]; x, y, z [m]);
    * ``template_downsample_size_m`` (``template_downsample_size``) - voxel size (x, y, z) [m]
      the template clouds are thinned to;
    * ``image_noise_px`` (``image_noise``, optional, 2) and ``lidar_noise_m`` (``lidar_noise``,
      optional, 3) - measurement sigmas, None when absent (the shared file has neither);
    * ``viz_point_size``, ``viz_corr_line_width``, ``show_camera_measurements``,
      ``show_lidar_measurements``, ``show_loop_closure_correspondences``, ``output_errors``,
      ``print_results_to_terminal`` - display and logging switches of the original tool.

    ``extra`` keeps keys this reader does not know (read-only)."""

    max_correspondence_iterations: int = 10
    max_pixel_cor_dist_px: float = 1000.0
    max_point_cor_dist_m: float = 100.0
    match_centroids: bool = True
    match_centroids_on_first_iter_only: bool = False
    extract_image_target_perimeter: bool = True
    concave_hull_alpha: float = 10.0
    estimate_target_lidar_corrections: bool = True
    estimate_target_camera_corrections: bool = True
    error_tol_rot_deg: tuple[float, float, float] = (0.001, 0.001, 0.001)
    error_tol_trans_m: tuple[float, float, float] = (0.0001, 0.0001, 0.0001)
    template_downsample_size_m: tuple[float, float, float] = (0.003, 0.003, 0.003)
    image_noise_px: tuple[float, float] | None = None
    lidar_noise_m: tuple[float, float, float] | None = None
    viz_point_size: int = 5
    viz_corr_line_width: int = 2
    show_camera_measurements: bool = False
    show_lidar_measurements: bool = False
    show_loop_closure_correspondences: bool = False
    output_errors: bool = False
    print_results_to_terminal: bool = False
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "extra", MappingProxyType(dict(self.extra)))


# field name -> (JSON key, kind); kind: bool, int, float, or a tuple length
_OPT_KEYS: dict[str, tuple[str, Any]] = {
    "max_correspondence_iterations": ("max_correspondence_iterations", int),
    "max_pixel_cor_dist_px": ("max_pixel_cor_dist", float),
    "max_point_cor_dist_m": ("max_point_cor_dist", float),
    "match_centroids": ("match_centroids", bool),
    "match_centroids_on_first_iter_only": ("match_centroids_on_first_iter_only", bool),
    "extract_image_target_perimeter": ("extract_image_target_perimeter", bool),
    "concave_hull_alpha": ("concave_hull_alpha", float),
    "estimate_target_lidar_corrections": ("estimate_target_lidar_corrections", bool),
    "estimate_target_camera_corrections": ("estimate_target_camera_corrections", bool),
    "template_downsample_size_m": ("template_downsample_size", 3),
    "image_noise_px": ("image_noise", 2),
    "lidar_noise_m": ("lidar_noise", 3),
    "viz_point_size": ("viz_point_size", int),
    "viz_corr_line_width": ("viz_corr_line_width", int),
    "show_camera_measurements": ("show_camera_measurements", bool),
    "show_lidar_measurements": ("show_lidar_measurements", bool),
    "show_loop_closure_correspondences": ("show_loop_closure_correspondences", bool),
    "output_errors": ("output_errors", bool),
    "print_results_to_terminal": ("print_results_to_terminal", bool),
}
_OPT_OPTIONAL = {"image_noise", "lidar_noise"}


def parse_optimizer_config(text: str, source: str = "optimizer config") -> OptimizerConfig:
    """An :class:`OptimizerConfig` from ``OptimizerConfig.json`` text. Every key of the shared
    file is required (as in the original tool); ``image_noise`` and ``lidar_noise`` are
    optional; unknown keys go to ``extra``. InputError names the file and the key."""
    doc = load_json(text, source)
    if not isinstance(doc, dict):
        raise InputError(f"{source}: expected a JSON object, got {type(doc).__name__}")
    values: dict[str, Any] = {}
    for fname, (key, kind) in _OPT_KEYS.items():
        if key not in doc:
            if key in _OPT_OPTIONAL:
                continue
            raise InputError(f"{source}: missing key '{key}'")
        v = doc[key]
        if kind is bool:
            values[fname] = _bool(doc, key, source)
        elif kind is int:
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise InputError(f"{source}: '{key}' must be a whole number >= 0, got {v!r}")
            values[fname] = v
        elif kind is float:
            if not _is_number(v) or v < 0:
                raise InputError(f"{source}: '{key}' must be a number >= 0, got {v!r}")
            values[fname] = float(v)
        else:
            nums = _numbers(doc, key, kind, source)
            if any(x < 0 for x in nums):
                raise InputError(f"{source}: '{key}' must not be negative, got {nums}")
            values[fname] = tuple(nums)
    tol = _numbers(doc, "error_tol", 6, source)
    if any(x <= 0 for x in tol):
        raise InputError(f"{source}: 'error_tol' must be 6 numbers > 0, got {tol}")
    values["error_tol_rot_deg"] = tuple(tol[:3])
    values["error_tol_trans_m"] = tuple(tol[3:])
    known = {k for k, _ in _OPT_KEYS.values()} | {"error_tol"}
    extra = {k: v for k, v in doc.items() if k not in known}
    if extra:
        log.debug("%s: keeping unknown keys %s", source, sorted(extra))
    return OptimizerConfig(**values, extra=extra)


def read_optimizer_config(path: str | os.PathLike[str]) -> OptimizerConfig:
    """Read ``OptimizerConfig.json`` (:func:`parse_optimizer_config`)."""
    from rigcal.io._text import read_text

    p = Path(path)
    return parse_optimizer_config(read_text(p, "optimizer config"), str(p))


def optimizer_config_json_text(config: OptimizerConfig) -> str:
    """JSON text in the original layout that :func:`parse_optimizer_config` reads back."""
    doc: dict[str, Any] = {}
    for f in fields(config):
        if f.name in ("extra", "error_tol_rot_deg", "error_tol_trans_m"):
            continue
        key, kind = _OPT_KEYS[f.name]
        v = getattr(config, f.name)
        if v is None:
            continue
        doc[key] = list(v) if isinstance(v, tuple) else v
    doc["error_tol"] = [*config.error_tol_rot_deg, *config.error_tol_trans_m]
    doc.update(config.extra)
    return json.dumps(doc, indent=2) + "\n"
