"""The circle board in one image of a calibrated camera -> the four hole centres in 3D.

Pipeline (paper section III-B: "the four circles are detected based on edges in the 2D image
plane; using the known geometry of the calibration board, PnP extracts the 3D locations"):

1. **Hole candidates.** The holes show the scene behind the plate, usually darker than the
   white plate (``hole_polarity="any"`` then also tries brighter). The grey image (optionally
   an ROI, by default all of it) is halved and thresholded at several levels; the outer
   contours at each level that are well fitted by an ellipse, of a plausible size and
   surrounded by a brighter ring (the plate) are candidates. Candidates found at several levels
   are merged, keeping the level closest to half-way between hole and plate grey.
2. **The square pattern.** Among the candidates, the four whose centres form a projected square
   (an affine image of the board's square up to a small perspective residual) and whose ellipses
   are the images of the board's circles under that affine map (size and shape) are chosen, and
   ordered top-left, top-right, bottom-left, bottom-right as seen in the image (clockwise from
   the corner nearest the top-left direction).
3. **PnP.** Sub-pixel rim edges are found at full resolution on rays of each ellipse and the
   ellipses refitted to them. Their centres, undistorted through the camera model (so any
   :class:`CameraModel` works), go to ``cv2.solvePnPGeneric`` (IPPE, planar), which returns
   both planar pose hypotheses ``T_camera_board``.
4. **Rim refinement (bias correction).** The centre of a projected circle is not the projection
   of its centre, so ellipse centres bias the pose, most for close, tilted boards. The pose is
   refined (robust Gauss-Newton) so that the projected rims of the four 3D circles pass through
   the rim edge points, measured along the projected rim's normal [px]. The rims' common radius
   is fitted too (``fit_hole_radius``): the distance then rests on the hole spacing, not on
   the apparent hole size, which sub-pixel edge biases and the plate's lit inner wall distort.
   Both IPPE hypotheses are refined and the one with the lower cost wins; the edges are then
   re-sampled along the normals of the projected rims and the fit repeated.

The result holds the four hole centres ``T_camera_board @ c_board`` in the camera optical frame
(4, 3) [m], ordered TL, TR, BL, BR (see :mod:`rigcal.targets.circle_board`). ``quality``:

* ``reprojection_rms_px`` - RMS distance of all rim edge points (outliers included) to the
  projected 3D rims;
* ``square_side_error_m`` - largest deviation from ``spacing_m`` of the four sides between
  hole centres fitted independently (a circle per hole in the fitted board plane): a
  consistency check, since the returned centres form the exact square by construction;
* ``hole_diameter_error_m`` - largest deviation of those independent circles' diameters;
* ``distance_m`` (camera to board centre), ``tilt_deg`` (board normal vs line of sight),
  ``centre_bias_px`` (largest ellipse-centre vs projected-centre offset: the corrected bias),
  ``pnp_rms_px`` (PnP on the ellipse centres), ``hole_diameter_m`` (the fitted rims'
  diameter), ``rim_points``, ``candidates``, ``bright_holes`` (1.0 when the holes are brighter
  than the plate);
* ``flip_cost_ratio`` / ``flip_angle_deg`` - the planar pose ambiguity: the other IPPE
  hypothesis, refined the same way, has this many times the cost and a board normal this far
  from the chosen one (``inf`` / 0 when there is no other; without rim refinement the ratio
  is that of the PnP RMS). A ratio near 1 with a large angle
  means the board's tilt is uncertain (far, nearly frontal boards); the centres' mean is not.

Failures (:class:`DetectionFailure` ``reason``): ``wrong_image_size``, ``too_few_holes``,
``no_square_pattern``, ``pnp_failed``, ``poor_fit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from rigcal.dataset import BoardGeometry
from rigcal.detect.result import BoardDetection, DetectionFailure
from rigcal.errors import ConfigError
from rigcal.geometry.se3 import from_rt, se3_exp
from rigcal.recording import ImageFrame
from rigcal.sensors.camera.base import CameraModel
from rigcal.targets.circle_board import board_centres

WRONG_IMAGE_SIZE = "wrong_image_size"
TOO_FEW_HOLES = "too_few_holes"
NO_SQUARE_PATTERN = "no_square_pattern"
PNP_FAILED = "pnp_failed"
POOR_FIT = "poor_fit"

# canonical image angles atan2(dv, du) of TL, TR, BR, BL around the pattern centre (v down)
_CORNER_ANGLES = np.radians([-135.0, -45.0, 45.0, 135.0])
# cyclic order TL, TR, BR, BL -> detection order TL, TR, BL, BR
_CYCLIC_TO_DETECTION = (0, 1, 3, 2)


@dataclass(frozen=True)
class MonoDetectorConfig:
    """Settings of :func:`detect_board_mono`.

    Defaults follow the original tool's ``image_processing.yaml`` where it applies (Gaussian
    blur sigma 2 px before edge work; holes of radius 20-38 px at its ROI's distances), widened
    to search the whole image and boards from ~1.5 m to ~12 m with a 1400 px focal length.
    """

    roi: tuple[int, int, int, int] | None = None
    """Optional search region ``(x, y, width, height)`` [px]; ``None`` searches the whole image."""
    hole_polarity: str = "any"
    """``"dark"``: the holes show a darker background than the plate; ``"bright"``: brighter;
    ``"any"``: look for dark holes first, then for bright ones."""
    blur_sigma_px: float = 2.0
    """Gaussian blur before thresholding (full-resolution pixels)."""
    edge_sigma_px: float = 1.0
    """Gaussian blur of the full-resolution image the rim edges are located in."""
    min_hole_radius_px: float = 6.0
    max_hole_radius_px: float = 200.0
    threshold_step: int = 16
    """Grey-level step between the thresholds that segment dark holes."""
    min_contrast: float = 25.0
    """Least grey-level difference between the plate around a hole and the hole."""
    max_ellipse_residual: float = 0.06
    """Largest RMS radial deviation of a hole contour from its ellipse, relative to its radius."""
    pattern_tolerance: float = 0.3
    """Relative tolerance of the square pattern test (ellipse sizes, perspective residual)."""
    max_candidates: int = 40
    refine_rim: bool = True
    """Correct the ellipse-centre bias by fitting the projected 3D rims (recommended)."""
    fit_hole_radius: bool = True
    """Fit the rims' radius too (one for the four holes) instead of fixing it to
    ``hole_diameter_m / 2``: the distance then follows from the hole spacing alone, so a
    sub-pixel bias of the edges (blur on a curved rim, the plate's lit inner wall) or a hole cut
    a little too wide does not scale the distance (recommended)."""
    rim_points_per_hole: int = 96
    max_reprojection_rms_px: float = 2.0
    """Detections whose rim fit RMS exceeds this fail with ``poor_fit``."""

    def __post_init__(self) -> None:
        positive = (
            "blur_sigma_px",
            "edge_sigma_px",
            "min_hole_radius_px",
            "max_hole_radius_px",
            "threshold_step",
            "min_contrast",
            "max_ellipse_residual",
            "pattern_tolerance",
            "max_candidates",
            "rim_points_per_hole",
            "max_reprojection_rms_px",
        )
        for name in positive:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ConfigError(f"mono detector: {name} must be a positive number, got {v!r}")
        if self.min_hole_radius_px >= self.max_hole_radius_px:
            raise ConfigError(
                f"mono detector: min_hole_radius_px ({self.min_hole_radius_px}) must be below "
                f"max_hole_radius_px ({self.max_hole_radius_px})"
            )
        if self.hole_polarity not in ("dark", "bright", "any"):
            raise ConfigError(
                f"mono detector: hole_polarity must be 'dark', 'bright' or 'any', got "
                f"{self.hole_polarity!r}"
            )
        if self.rim_points_per_hole < 8:
            raise ConfigError(
                f"mono detector: rim_points_per_hole must be >= 8, got {self.rim_points_per_hole}"
            )
        if self.roi is not None:
            roi = tuple(self.roi)
            if len(roi) != 4 or any(isinstance(v, bool) or not isinstance(v, int) for v in roi):
                raise ConfigError(
                    "mono detector: roi must be four integers (x, y, width, height), got "
                    f"{self.roi!r}"
                )
            if roi[0] < 0 or roi[1] < 0 or roi[2] <= 0 or roi[3] <= 0:
                raise ConfigError(
                    f"mono detector: roi needs x, y >= 0 and width, height > 0, got {roi}"
                )
            object.__setattr__(self, "roi", roi)


class HoleEllipse(NamedTuple):
    """A hole candidate in the image: centre (u, v) [px], semi-axes ``a >= b`` [px], ``angle``
    [rad] of the major axis from the u axis; ``plate`` / ``hole`` grey levels around / inside."""

    u: float
    v: float
    a: float
    b: float
    angle: float
    plate: float
    hole: float
    threshold: float

    @property
    def centre(self) -> np.ndarray:
        return np.array([self.u, self.v])

    def shape_matrix(self) -> np.ndarray:
        """(2, 2) M with the ellipse ``{c + M^(1/2) x : |x| = 1}``, i.e. R diag(a^2, b^2) R^T."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        R = np.array([[c, -s], [s, c]])
        return R @ np.diag([self.a**2, self.b**2]) @ R.T

    def points(self, angles: np.ndarray, scale: float | np.ndarray = 1.0) -> np.ndarray:
        """(N, 2) points at parameter ``angles`` on the ellipse scaled by ``scale``."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        x = self.a * np.cos(angles) * scale
        y = self.b * np.sin(angles) * scale
        return np.stack([self.u + c * x - s * y, self.v + s * x + c * y], axis=-1)


@dataclass(frozen=True, eq=False)
class MonoBoardFit:
    """Everything :func:`fit_board_mono` found: the detection plus the pose and image evidence.

    ``T_camera_board`` (4, 4) maps board-frame points into the camera optical frame;
    ``ellipses`` are the four chosen holes in detection order (TL, TR, BL, BR);
    ``rim_points_px`` (M, 2) the rim edge points used in the final fit and ``rim_hole`` (M,)
    which hole each belongs to; ``projected_centres_px`` (4, 2) the projections of the 3D hole
    centres.
    """

    detection: BoardDetection
    T_camera_board: np.ndarray
    ellipses: tuple[HoleEllipse, ...]
    rim_points_px: np.ndarray
    rim_hole: np.ndarray
    projected_centres_px: np.ndarray

    def __post_init__(self) -> None:
        for name in ("T_camera_board", "rim_points_px", "rim_hole", "projected_centres_px"):
            arr = np.array(getattr(self, name))
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


def detect_board_mono(
    frame: ImageFrame,
    camera: CameraModel,
    board: BoardGeometry = BoardGeometry(),
    config: MonoDetectorConfig = MonoDetectorConfig(),
) -> BoardDetection | DetectionFailure:
    """The board's four hole centres (4, 3) in the camera optical frame [m] (TL, TR, BL, BR),
    or a :class:`DetectionFailure` with its reason. See the module docstring."""
    out = fit_board_mono(frame, camera, board, config)
    return out.detection if isinstance(out, MonoBoardFit) else out


def fit_board_mono(
    frame: ImageFrame,
    camera: CameraModel,
    board: BoardGeometry = BoardGeometry(),
    config: MonoDetectorConfig = MonoDetectorConfig(),
) -> MonoBoardFit | DetectionFailure:
    """Like :func:`detect_board_mono`, returning the pose and image evidence too."""

    def fail(reason: str, detail: str) -> DetectionFailure:
        return DetectionFailure(frame.sensor, frame.t_ns, reason, detail)

    if frame.size_wh != camera.size_wh:
        return fail(
            WRONG_IMAGE_SIZE,
            f"image is {frame.size_wh[0]}x{frame.size_wh[1]} px but the {camera.name} camera "
            f"intrinsics are for {camera.width}x{camera.height} px",
        )
    grey = frame.image if frame.image.ndim == 2 else cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY)
    polarities = ("dark", "bright") if config.hole_polarity == "any" else (config.hole_polarity,)
    counts: dict[str, int] = {}
    pattern = None
    for polarity in polarities:
        # the pipeline looks for dark holes in a bright plate: invert for bright holes
        work = grey if polarity == "dark" else cv2.bitwise_not(grey)
        candidates = find_hole_candidates(work, config)
        counts[polarity] = len(candidates)
        if len(candidates) >= 4:
            pattern = find_square_pattern(candidates, board, config)
            if pattern is not None:
                break
    seen = ", ".join(f"{n} {p}" for p, n in counts.items())
    if pattern is None and max(counts.values()) < 4:
        return fail(
            TOO_FEW_HOLES,
            f"found {seen} hole candidate(s), need 4 (radius {config.min_hole_radius_px:g}-"
            f"{config.max_hole_radius_px:g} px, contrast >= {config.min_contrast:g} grey levels)",
        )
    if pattern is None:
        return fail(
            NO_SQUARE_PATTERN,
            f"no 4 of the hole candidates ({seen}) form the board's square "
            f"(spacing {board.spacing_m:g} m, hole diameter {board.hole_diameter_m:g} m)",
        )
    obj = board_centres(board)
    # sub-pixel rim edges at full resolution, and the ellipses refitted to them
    chosen = tuple(candidates[i] for i in pattern)
    edge = _edge_image(work, chosen, config)
    rim_px, rim_hole = _rim_points_radial(edge, chosen, config)
    ellipses = _refit_ellipses(chosen, rim_px, rim_hole)
    centres_px = np.array([e.centre for e in ellipses])

    poses = _pnp(obj, centres_px, camera)
    if not poses:
        return fail(
            PNP_FAILED, f"cv2.solvePnPGeneric (IPPE) found no pose for {centres_px.tolist()}"
        )
    pnp_rms = min(rms for _, rms in poses)
    radius_m = board.hole_diameter_m / 2.0

    flip = (math.inf, 0.0)  # (cost ratio, normal angle [deg]) of the other IPPE hypothesis
    if config.refine_rim:
        if rim_px.shape[0] < 12:
            return fail(PNP_FAILED, f"only {rim_px.shape[0]} rim edge points found on the holes")
        free = config.fit_hole_radius
        # both IPPE hypotheses, on every second rim point (the winner is refined further below)
        fits = [
            _fit_rims(T0, radius_m, rim_px[::2], rim_hole[::2], obj, camera, free, 12)
            for T0, _ in poses
        ]
        fits = sorted((f for f in fits if f is not None), key=lambda f: f.cost)
        if not fits:
            return fail(PNP_FAILED, "the rim fit diverged for both IPPE pose hypotheses")
        best = fits[0]
        if len(fits) > 1:  # how clearly the rims tell the planar pose ambiguity apart
            cos = float(np.clip(fits[0].T[:3, 2] @ fits[1].T[:3, 2], -1.0, 1.0))
            flip = (fits[1].cost / max(fits[0].cost, 1e-12), math.degrees(math.acos(cos)))
        rim_px, rim_hole = _rim_points_along_model(
            edge, best.T, obj, best.radius_m, camera, ellipses, config
        )
        if rim_px.shape[0] < 12:
            return fail(PNP_FAILED, f"only {rim_px.shape[0]} rim edge points found on the holes")
        fit = _fit_rims(best.T, best.radius_m, rim_px, rim_hole, obj, camera, free)
        if fit is None:
            return fail(PNP_FAILED, "the rim fit diverged")
        T, radius_m = fit.T, fit.radius_m
        resid = _rim_residuals_px(
            T, radius_m, camera.unproject(rim_px), rim_px, rim_hole, obj, camera
        )
        keep = np.isfinite(resid)
        rms = float(np.sqrt(np.mean(resid[keep] ** 2))) if np.any(keep) else math.inf
    else:
        ranked = sorted(poses, key=lambda p: p[1])
        T = ranked[0][0]
        rim_px, rim_hole = np.zeros((0, 2)), np.zeros(0, dtype=int)
        rms = pnp_rms
        if len(ranked) > 1:
            cos = float(np.clip(ranked[0][0][:3, 2] @ ranked[1][0][:3, 2], -1.0, 1.0))
            flip = (ranked[1][1] / max(ranked[0][1], 1e-12), math.degrees(math.acos(cos)))

    centres_cam = obj @ T[:3, :3].T + T[:3, 3]
    if not np.all(centres_cam[:, 2] > 0):
        return fail(
            PNP_FAILED, f"the pose puts the board behind the camera: {centres_cam.tolist()}"
        )
    if not rms <= config.max_reprojection_rms_px:
        return fail(
            POOR_FIT,
            f"rim reprojection RMS {rms:.2f} px exceeds {config.max_reprojection_rms_px:g} px",
        )
    proj, _ = camera.project(centres_cam)
    quality: dict[str, float] = {
        "reprojection_rms_px": rms,
        "pnp_rms_px": pnp_rms,
        "distance_m": float(np.linalg.norm(T[:3, 3])),
        "tilt_deg": float(
            np.degrees(np.arccos(abs(T[:3, 2] @ T[:3, 3]) / np.linalg.norm(T[:3, 3])))
        ),
        "centre_bias_px": float(np.max(np.linalg.norm(proj - centres_px, axis=1))),
        "rim_points": float(rim_px.shape[0]),
        "hole_diameter_m": 2.0 * radius_m,
        "candidates": float(len(candidates)),
        "bright_holes": float(polarity == "bright"),
        "flip_cost_ratio": flip[0],
        "flip_angle_deg": flip[1],
    }
    if rim_px.shape[0]:
        side_err, diam_err = _independent_hole_check(T, rim_px, rim_hole, board, camera)
        quality["square_side_error_m"] = side_err
        quality["hole_diameter_error_m"] = diam_err
    else:
        quality["square_side_error_m"] = _side_error(centres_cam, board)
    detection = BoardDetection(frame.sensor, frame.t_ns, centres_cam, quality)
    return MonoBoardFit(detection, T, ellipses, rim_px, rim_hole, proj)


# ---------------------------------------------------------------------------- candidates
def _roi(config: MonoDetectorConfig, width: int, height: int) -> tuple[int, int, int, int]:
    if config.roi is None:
        return 0, 0, width, height
    x, y, w, h = config.roi
    x0, y0 = min(x, width), min(y, height)
    return x0, y0, min(x + w, width) - x0, min(y + h, height) - y0


def find_hole_candidates(grey: np.ndarray, config: MonoDetectorConfig) -> list[HoleEllipse]:
    """Dark elliptical blobs inside a brighter surround in a uint8 grey image (H, W), in
    full-resolution pixel coordinates, best first."""
    x0, y0, w, h = _roi(config, grey.shape[1], grey.shape[0])
    if w < 8 or h < 8:
        return []
    crop = grey[y0 : y0 + h, x0 : x0 + w]
    scale = 2 if config.min_hole_radius_px >= 5 else 1  # find holes of >= 2.5 px at half size
    small = crop if scale == 1 else cv2.resize(crop, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    sigma = config.blur_sigma_px / scale
    small = cv2.GaussianBlur(small, (0, 0), sigma) if sigma > 0.3 else small
    sh, sw = small.shape
    rmin, rmax = config.min_hole_radius_px / scale, config.max_hole_radius_px / scale
    lo, hi = int(small.min()), int(small.max())
    found: list[HoleEllipse] = []
    step = int(config.threshold_step)
    for t in range(lo + step, hi, step):
        _, binary = cv2.threshold(small, t - 1, 1, cv2.THRESH_BINARY_INV)
        contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        for c in contours:
            n = c.shape[0]
            if n < 4 * rmin or n > 4 * math.pi * rmax:
                continue
            pts = c.reshape(-1, 2)
            if pts[:, 0].min() <= 0 or pts[:, 1].min() <= 0:
                continue  # touches the image or ROI border: not a whole hole
            if pts[:, 0].max() >= sw - 1 or pts[:, 1].max() >= sh - 1:
                continue
            ell = _ellipse_from_contour(pts.astype(np.float64), rmin, rmax, config)
            if ell is None:
                continue
            cu, cv_, a, b, ang = ell
            plate, hole, ok = _surround(small, cu, cv_, a, b, ang, t, config)
            if not ok:
                continue
            found.append(
                HoleEllipse(
                    (cu + 0.5) * scale - 0.5 + x0,
                    (cv_ + 0.5) * scale - 0.5 + y0,
                    a * scale,
                    b * scale,
                    ang,
                    plate,
                    hole,
                    float(t),
                )
            )
    return _merge_candidates(found)[: int(config.max_candidates)]


def _ellipse_from_contour(
    pts: np.ndarray, rmin: float, rmax: float, config: MonoDetectorConfig
) -> tuple[float, float, float, float, float] | None:
    (cu, cv_), (d1, d2), ang_deg = cv2.fitEllipse(pts.astype(np.float32))
    a, b = d1 / 2.0, d2 / 2.0
    ang = math.radians(ang_deg)
    if b > a:
        a, b = b, a
        ang += math.pi / 2
    if not (b >= rmin * 0.5 and a >= rmin and a <= rmax) or b < 0.25 * a:
        return None
    # radial residual of the contour (pixel centres lie ~0.5 px inside the true boundary)
    c, s = math.cos(ang), math.sin(ang)
    d = pts - (cu, cv_)
    x = (c * d[:, 0] + s * d[:, 1]) / (a + 0.5)
    y = (-s * d[:, 0] + c * d[:, 1]) / (b + 0.5)
    rho = np.sqrt(x * x + y * y)
    if float(np.sqrt(np.mean((rho - 1.0) ** 2))) > config.max_ellipse_residual + 0.5 / b:
        return None
    return cu, cv_, a, b, ang


def _sample_nearest(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    ij = np.rint(pts).astype(int)
    h, w = img.shape
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    out = np.full(pts.shape[0], np.nan)
    out[ok] = img[ij[ok, 1], ij[ok, 0]]
    return out


def _surround(
    img: np.ndarray, cu: float, cv_: float, a: float, b: float, ang: float, t: float,
    config: MonoDetectorConfig,
) -> tuple[float, float, bool]:
    """Plate grey (ring 1.3-1.6 radii), hole grey (inner 0.5 radii), and whether the ring is a
    bright surround: >= 90 % of it above the threshold and contrast >= min_contrast."""
    e = HoleEllipse(cu, cv_, a, b, ang, 0, 0, t)
    th = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.concatenate([_sample_nearest(img, e.points(th, s)) for s in (1.3, 1.45, 1.6)])
    inner = np.concatenate([_sample_nearest(img, e.points(th[::3], s)) for s in (0.0, 0.25, 0.5)])
    if np.isnan(ring).any() or np.isnan(inner).any():
        return 0.0, 0.0, False
    plate, hole = float(np.median(ring)), float(np.median(inner))
    ok = np.mean(ring >= t) >= 0.9 and plate - hole >= config.min_contrast
    return plate, hole, bool(ok)


def _merge_candidates(found: list[HoleEllipse]) -> list[HoleEllipse]:
    """One candidate per hole: the level closest to half-way between hole and plate grey."""
    def level_error(e: HoleEllipse) -> float:
        return abs(e.threshold - 0.5 * (e.plate + e.hole)) / max(e.plate - e.hole, 1.0)

    order = sorted(found, key=level_error)
    kept: list[HoleEllipse] = []
    for e in order:
        same = any(
            math.hypot(e.u - k.u, e.v - k.v) < 0.6 * min(e.b, k.b)
            and 0.6 < e.a / k.a < 1.0 / 0.6
            for k in kept
        )
        if not same:
            kept.append(e)
    # holes seen at more levels are more trustworthy: rank by support, then contrast
    support = [
        sum(math.hypot(e.u - f.u, e.v - f.v) < 0.6 * e.b for f in found) for e in kept
    ]
    ranked = sorted(zip(kept, support), key=lambda es: (-es[1], -(es[0].plate - es[0].hole)))
    return [e for e, _ in ranked]


# ---------------------------------------------------------------------------- the square
def order_corners(centres_px: np.ndarray) -> np.ndarray | None:
    """Indices (4,) ordering four image points TL, TR, BL, BR, or None if they are not the
    corners of a convex quadrilateral."""
    p = np.asarray(centres_px, dtype=float)
    d = p - p.mean(axis=0)
    cyc = np.argsort(np.arctan2(d[:, 1], d[:, 0]))  # clockwise on screen (v down)
    q = p[cyc]
    e = np.roll(q, -1, axis=0) - q
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not np.all(cross > 0):
        return None
    ang = np.arctan2(d[cyc, 1], d[cyc, 0])
    best, best_cost = 0, math.inf
    for k in range(4):
        diff = np.angle(np.exp(1j * (np.roll(ang, -k) - _CORNER_ANGLES)))
        cost = float(np.sum(diff**2))
        if cost < best_cost:
            best, best_cost = k, cost
    cyc = np.roll(cyc, -best)
    return cyc[list(_CYCLIC_TO_DETECTION)]


def find_square_pattern(
    candidates: list[HoleEllipse], board: BoardGeometry, config: MonoDetectorConfig
) -> tuple[int, int, int, int] | None:
    """Indices of the four candidates forming the board's square, ordered TL, TR, BL, BR."""
    n = len(candidates)
    if n < 4:
        return None
    c = np.array([e.centre for e in candidates])
    a = np.array([e.a for e in candidates])
    tol = config.pattern_tolerance
    ratio = board.spacing_m / (board.hole_diameter_m / 2.0)  # centre distance / radius (3.2)
    dist = np.linalg.norm(c[:, None] - c[None], axis=-1)
    amean = 0.5 * (a[:, None] + a[None])
    size_ok = np.maximum(a[:, None], a[None]) <= (1 + tol) ** 2 * np.minimum(a[:, None], a[None])
    near = (dist > 0.2 * ratio * amean) & (dist < math.sqrt(2) * ratio * (1 + tol) * amean)
    adj = size_ok & near
    np.fill_diagonal(adj, False)
    obj = board_centres(board)[:, :2] * np.array([1.0, -1.0])  # board y up -> image v down
    r_board = board.hole_diameter_m / 2.0
    best, best_score = None, math.inf
    for combo in _four_cliques(adj):
        idx = np.array(combo)
        order = order_corners(c[idx])
        if order is None:
            continue
        idx = idx[order]
        score = _pattern_score(c[idx], [candidates[i] for i in idx], obj, r_board, tol)
        if score is not None and score < best_score:
            best, best_score = tuple(int(i) for i in idx), score
    return best


def _four_cliques(adj: np.ndarray):
    """Every i < j < k < l with all six pairs adjacent (pruned as the set grows)."""
    n = adj.shape[0]
    nbrs = [set(np.flatnonzero(adj[i]).tolist()) for i in range(n)]
    for i in range(n):
        if len(nbrs[i]) < 3:
            continue
        for j in sorted(x for x in nbrs[i] if x > i):
            common_ij = nbrs[i] & nbrs[j]
            for k in sorted(x for x in common_ij if x > j):
                for l in sorted(x for x in common_ij & nbrs[k] if x > k):
                    yield i, j, k, l


def _pattern_score(
    img: np.ndarray, ells: list[HoleEllipse], obj: np.ndarray, r_board: float, tol: float
) -> float | None:
    """How well four ordered ellipses match an affine image of the board (lower is better)."""
    X = np.column_stack([obj, np.ones(4)])
    sol, *_ = np.linalg.lstsq(X, img, rcond=None)
    A = sol[:2].T  # image = A @ board_xy(v down) + t
    if np.linalg.det(A) <= 0:
        return None
    side = math.sqrt(abs(np.linalg.det(A))) * abs(obj[0, 0]) * 2
    resid = float(np.max(np.linalg.norm(X @ sol - img, axis=1))) / side
    if resid > 0.25 * tol:
        return None
    # each ellipse should be the affine image of a circle of the board's hole radius
    Mp = (A @ A.T) * r_board**2
    shape_err = 0.0
    for e in ells:
        Mm = e.shape_matrix()
        w, V = np.linalg.eigh(Mm)
        Wi = V @ np.diag(1.0 / np.sqrt(w)) @ V.T
        s = np.sqrt(np.linalg.eigvalsh(Wi @ Mp @ Wi))
        # measured holes are blurred by ~1 px; allow that on top of the relative tolerance
        slack = 1.0 / max(e.b, 1.0)
        if s.min() < 1 / (1 + tol) - slack or s.max() > 1 + tol + slack:
            return None
        shape_err = max(shape_err, float(np.max(np.abs(np.log(s)))))
    return resid + shape_err


# ---------------------------------------------------------------------------- PnP
def _pnp(obj: np.ndarray, img: np.ndarray, camera: CameraModel) -> list[tuple[np.ndarray, float]]:
    """Pose hypotheses (T_camera_board, RMS px) of IPPE on undistorted ellipse centres."""
    rays = camera.unproject(img)
    if not np.all(np.isfinite(rays)) or np.any(rays[:, 2] <= 0):
        return []
    xn = rays[:, :2] / rays[:, 2:3]
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            obj.astype(np.float64),
            xn.reshape(-1, 1, 2).astype(np.float64),
            np.eye(3),
            None,
            flags=cv2.SOLVEPNP_IPPE,
        )
    except cv2.error:
        return []
    out = []
    for rvec, tvec in zip(rvecs[:n], tvecs[:n]):
        R, _ = cv2.Rodrigues(rvec)
        T = from_rt(R, tvec.reshape(3))
        pts = obj @ R.T + tvec.reshape(3)
        if np.any(pts[:, 2] <= 0) or not np.all(np.isfinite(T)):
            continue
        uv, valid = camera.project(pts)
        if not valid.all():
            continue
        out.append((T, float(np.sqrt(np.mean(np.sum((uv - img) ** 2, axis=1))))))
    return out


# ---------------------------------------------------------------------------- rim edges
class _EdgeImage(NamedTuple):
    img: np.ndarray  # float32 blurred grey crop
    x0: int
    y0: int
    min_peak: float  # least edge gradient [grey / px] that counts as a rim edge


def _edge_image(
    grey: np.ndarray, ellipses: tuple[HoleEllipse, ...], config: MonoDetectorConfig
) -> _EdgeImage:
    """The blurred float crop of ``grey`` around the four holes that rim edges are found in."""
    centres = np.array([e.centre for e in ellipses])
    amax = max(e.a for e in ellipses)
    margin = int(2.0 * amax + 8)
    x0 = max(int(centres[:, 0].min()) - margin, 0)
    y0 = max(int(centres[:, 1].min()) - margin, 0)
    x1 = min(int(centres[:, 0].max()) + margin, grey.shape[1])
    y1 = min(int(centres[:, 1].max()) + margin, grey.shape[0])
    crop = grey[y0:y1, x0:x1].astype(np.float32)
    if config.edge_sigma_px > 0.3:
        crop = cv2.GaussianBlur(crop, (0, 0), config.edge_sigma_px)
    # a blurred step of height H peaks at H / (sqrt(2 pi) sigma) grey/px; accept a quarter of
    # the weakest hole's contrast at that
    contrast = min(e.plate - e.hole for e in ellipses)
    sigma = math.hypot(config.edge_sigma_px, 1.0)
    return _EdgeImage(crop, x0, y0, 0.25 * contrast / (math.sqrt(2 * math.pi) * sigma))


def _edges_along(
    edge: _EdgeImage, start: np.ndarray, direction: np.ndarray, length: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray]:
    """Strongest dark-to-bright edge along segments ``start + s * direction``, s in [0, length]:
    returns the edge points (K, 2) [px] and a mask (K,) of segments with a clear edge."""
    m = int(np.ceil(length.max() / step)) + 1
    s = np.arange(m) * step
    pts = start[:, None, :] + s[None, :, None] * direction[:, None, :]
    map_x = (pts[..., 0] - edge.x0).astype(np.float32)
    map_y = (pts[..., 1] - edge.y0).astype(np.float32)
    prof = cv2.remap(edge.img, map_x, map_y, cv2.INTER_LINEAR, borderValue=np.nan)
    inside = s[None, :] <= length[:, None]
    deriv = np.gradient(prof.astype(np.float64), step, axis=1)
    deriv[~inside | ~np.isfinite(deriv)] = -np.inf
    k = np.argmax(deriv, axis=1)
    rows = np.arange(len(k))
    peak = deriv[rows, k]
    interior = (k > 0) & (k < m - 1) & (s[np.minimum(k + 1, m - 1)] <= length)
    km, kp = np.maximum(k - 1, 0), np.minimum(k + 1, m - 1)
    ym, y0, yp = deriv[rows, km], peak, deriv[rows, kp]
    with np.errstate(invalid="ignore", divide="ignore"):
        den = ym - 2 * y0 + yp
        off = np.where(interior & (den < 0), 0.5 * (ym - yp) / den, 0.0)
    off = np.clip(np.nan_to_num(off), -0.5, 0.5)
    ok = interior & np.isfinite(peak) & (peak >= edge.min_peak)
    pos = (k + off) * step
    return start + pos[:, None] * direction, ok


def _rim_points_radial(
    edge: _EdgeImage, ellipses: tuple[HoleEllipse, ...], config: MonoDetectorConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Edge points on rays from each ellipse's centre, scanning 0.6 to 1.4 of its radius."""
    n = int(config.rim_points_per_hole)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts, holes = [], []
    for i, e in enumerate(ellipses):
        inner = e.points(th, 0.6)
        outer = e.points(th, 1.4)
        d = outer - inner
        length = np.linalg.norm(d, axis=1)
        p, ok = _edges_along(edge, inner, d / length[:, None], length, 0.25)
        pts.append(p[ok])
        holes.append(np.full(int(ok.sum()), i))
    return np.concatenate(pts), np.concatenate(holes)


def _refit_ellipses(
    ellipses: tuple[HoleEllipse, ...], rim_px: np.ndarray, rim_hole: np.ndarray
) -> tuple[HoleEllipse, ...]:
    """Each hole's ellipse fitted to its sub-pixel rim points (points off the first fit by more
    than 3 robust sigmas dropped once); a hole keeps its old ellipse if the refit is implausible."""
    out = []
    for i, e in enumerate(ellipses):
        pts = rim_px[rim_hole == i]
        new = e
        for _ in range(2):
            if pts.shape[0] < 8:
                break
            (cu, cv_), (d1, d2), ang_deg = cv2.fitEllipse(pts.astype(np.float32))
            a, b, ang = d1 / 2.0, d2 / 2.0, math.radians(ang_deg)
            if b > a:
                a, b, ang = b, a, ang + math.pi / 2
            plausible = (
                b > 0
                and math.hypot(cu - e.u, cv_ - e.v) < 0.5 * e.b
                and 0.7 < a / e.a < 1.0 / 0.7
                and 0.7 < b / e.b < 1.0 / 0.7
            )
            if not plausible:
                break
            new = HoleEllipse(cu, cv_, a, b, ang, e.plate, e.hole, e.threshold)
            c, s = math.cos(ang), math.sin(ang)
            d = pts - (cu, cv_)
            rho = np.hypot((c * d[:, 0] + s * d[:, 1]) / a, (-s * d[:, 0] + c * d[:, 1]) / b)
            dev = np.abs(rho - 1.0) * b
            keep = dev <= max(3.0 * 1.4826 * float(np.median(dev)), 0.3)
            if keep.all():
                break
            pts = pts[keep]
        out.append(new)
    return tuple(out)


def _rim_points_along_model(
    edge: _EdgeImage, T: np.ndarray, obj: np.ndarray, radius_m: float, camera: CameraModel,
    ellipses: tuple[HoleEllipse, ...], config: MonoDetectorConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Edge points along the normals of the projected 3D rims under pose ``T``."""
    n = int(config.rim_points_per_hole)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    R, t = T[:3, :3], T[:3, 3]
    pts, holes = [], []
    for i, e in enumerate(ellipses):
        rim_b = obj[i] + radius_m * np.stack([np.cos(th), np.sin(th), np.zeros(n)], axis=1)
        tan_b = np.stack([-np.sin(th), np.cos(th), np.zeros(n)], axis=1)
        rim_c = rim_b @ R.T + t
        uv, valid = camera.project(rim_c)
        J = camera.project_jacobian(rim_c)
        tan = np.einsum("nij,nj->ni", J, tan_b @ R.T)
        # outward normal in the image: perpendicular to the tangent, away from the centre
        nrm = np.stack([tan[:, 1], -tan[:, 0]], axis=1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        flip = np.sum(nrm * (uv - uv.mean(axis=0)), axis=1) < 0
        nrm[flip] *= -1
        half = max(3.0, 0.25 * e.b)
        start = uv - half * nrm
        length = np.full(n, 2 * half)
        good = valid & np.all(np.isfinite(nrm), axis=1)
        p, ok = _edges_along(edge, start[good], nrm[good], length[good], 0.25)
        pts.append(p[ok])
        holes.append(np.full(int(ok.sum()), i))
    return np.concatenate(pts), np.concatenate(holes)


# ---------------------------------------------------------------------------- rim fit
def _rim_residuals_px(
    T: np.ndarray, radius_m: float | np.ndarray, rays: np.ndarray, uv: np.ndarray,
    hole: np.ndarray, obj: np.ndarray, camera: CameraModel,
) -> np.ndarray:
    """Signed distances [px] of rim points ``uv`` (M, 2) to the projected rims of circles of
    ``radius_m`` around ``obj[hole]`` under the pose(s) ``T`` (4, 4) or (K, 4, 4) (radius
    scalar or (K,)), along the rim's image normal (first order): (M,) or (K, M). NaN where the
    ray (unit rays (M, 3) of ``uv``) misses the board plane."""
    Ts = np.asarray(T)[None] if np.ndim(T) == 2 else np.asarray(T)
    r, _ = _rim_geometry(Ts, radius_m, rays, uv, hole, obj, camera)
    return r[0] if np.ndim(T) == 2 else r


def _rim_geometry(
    Ts: np.ndarray, radius_m: float | np.ndarray, rays: np.ndarray, uv: np.ndarray,
    hole: np.ndarray, obj: np.ndarray, camera: CameraModel, normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (K, M) of :func:`_rim_residuals_px` for poses ``Ts`` (K, 4, 4) and the unit
    image normals (K, M, 2) they are measured along. Given ``normals`` (M, 2), those are used
    for every pose instead (finite differences, where the normals hardly change)."""
    K, M = Ts.shape[0], len(hole)
    rad = np.broadcast_to(np.asarray(radius_m, dtype=float), (K,))[:, None, None]
    R, t = Ts[:, :3, :3], Ts[:, :3, 3]
    nrm = R[:, :, 2]  # (K, 3) board normals in the camera frame
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sum(nrm * t, axis=1)[:, None] / (nrm @ rays.T)  # (K, M) ray-plane distances
    P_b = np.matmul(rays[None] * s[..., None] - t[:, None], R)  # R^T (P - t), row-wise
    d = P_b[..., :2] - obj[hole, :2][None]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = d / np.linalg.norm(d, axis=-1, keepdims=True)  # in-plane direction from the centre
    zeros = np.zeros((K, M, 1))
    Rt = np.swapaxes(R, 1, 2)
    rim_c = np.matmul(np.concatenate([obj[hole, :2][None] + rad * u, zeros], axis=-1), Rt)
    rim_c = (rim_c + t[:, None]).reshape(-1, 3)  # the nearest rim point, camera frame
    proj, _ = camera.project(rim_c)
    if normals is None:
        tan_c = np.matmul(np.concatenate([-u[..., 1:], u[..., :1], zeros], axis=-1), Rt)
        tan = np.sum(camera.project_jacobian(rim_c) * tan_c.reshape(-1, 1, 3), axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            n_img = np.column_stack([tan[:, 1], -tan[:, 0]])
            n_img /= np.linalg.norm(tan, axis=1)[:, None]
    else:
        n_img = np.tile(normals, (K, 1))
    r = np.sum(n_img * (np.tile(uv, (K, 1)) - proj), axis=1).reshape(K, M)
    r[~(s > 0)] = np.nan
    return r, n_img.reshape(K, M, 2)


_FD_STEP = 1e-7
_ROBUST_SCALE_PX = 1.0


def _robust_cost(r: np.ndarray) -> float:
    """Soft-L1 cost of residuals [px] with scale ``_ROBUST_SCALE_PX`` (as scipy's "soft_l1")."""
    z = (r / _ROBUST_SCALE_PX) ** 2
    return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0))) * _ROBUST_SCALE_PX**2


class _RimFit(NamedTuple):
    T: np.ndarray  # T_camera_board (4, 4)
    radius_m: float  # the rims' radius (fitted, or the board's when fixed)
    cost: float  # robust cost at the solution


def _fit_rims(
    T0: np.ndarray, radius0_m: float, uv: np.ndarray, hole: np.ndarray, obj: np.ndarray,
    camera: CameraModel, free_radius: bool, max_iterations: int = 30,
) -> _RimFit | None:
    """Refine T_camera_board (and, if ``free_radius``, the common rim radius) so the projected
    rims pass through ``uv``: robust (soft-L1) Gauss-Newton on a right perturbation
    ``T <- T @ exp(xi)`` and ``radius <- radius * exp(rho)`` with a batched forward-difference
    Jacobian and step halving. Returns None if it fails."""
    rays = camera.unproject(uv)
    ok = np.all(np.isfinite(rays), axis=1)
    rays, uv, hole = rays[ok], uv[ok], hole[ok]
    if len(hole) < 12:
        return None
    n = 7 if free_radius else 6
    steps = np.vstack([np.zeros(n), _FD_STEP * np.eye(n)])
    if not free_radius:
        steps = np.column_stack([steps, np.zeros(n + 1)])

    def evaluate(T: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        # residuals at T, then forward differences of all coordinates in one batched call that
        # keeps the image normals of T (a Gauss-Newton approximation of the Jacobian)
        r0, normals = _rim_geometry(T[None], radius, rays, uv, hole, obj, camera)
        Ts = T @ se3_exp(steps[1:, :6])
        radii = radius * np.exp(steps[1:, 6])
        r, _ = _rim_geometry(Ts, radii, rays, uv, hole, obj, camera, normals=normals[0])
        r0 = np.where(np.isfinite(r0[0]), r0[0], 1e3)
        r = np.where(np.isfinite(r), r, 1e3)
        return r0, ((r - r0) / _FD_STEP).T

    T, radius = np.array(T0, dtype=float), float(radius0_m)
    r, J = evaluate(T, radius)
    cost = _robust_cost(r)
    for _ in range(max_iterations):
        w = 1.0 / np.sqrt(1.0 + (r / _ROBUST_SCALE_PX) ** 2)  # IRLS weights of soft-L1
        H = J.T @ (J * w[:, None])
        g = J.T @ (w * r)
        try:
            dx = -np.linalg.solve(H + 1e-9 * np.trace(H) * np.eye(n), g)
        except np.linalg.LinAlgError:
            return None
        for _halving in range(10):
            T_new = T @ se3_exp(dx[:6])
            radius_new = radius * math.exp(dx[6]) if free_radius else radius
            r_new, J_new = evaluate(T_new, radius_new)
            cost_new = _robust_cost(r_new)
            if cost_new <= cost:
                break
            dx = dx / 2.0
        else:
            break  # no descent: converged as far as the data allow
        improvement = cost - cost_new
        T, radius, r, J, cost = T_new, radius_new, r_new, J_new, cost_new
        if np.linalg.norm(dx) < 1e-8 or improvement <= 1e-6 * max(cost, 1e-12):
            break
    if not np.all(np.isfinite(T)) or np.any((obj @ T[:3, :3].T + T[:3, 3])[:, 2] <= 0):
        return None
    return _RimFit(T, radius, cost)


def _independent_hole_check(
    T: np.ndarray, uv: np.ndarray, hole: np.ndarray, board: BoardGeometry, camera: CameraModel
) -> tuple[float, float]:
    """(largest side error, largest diameter error) [m] of circles fitted to each hole's rim
    points in the board plane of ``T`` independently of the board's layout."""
    R, t = T[:3, :3], T[:3, 3]
    rays = camera.unproject(uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (R[:, 2] @ t) / (rays @ R[:, 2])
    P_b = (rays * s[:, None] - t) @ R
    centres, diam = [], []
    for i in range(4):
        q = P_b[(hole == i) & np.isfinite(s) & (s > 0), :2]
        if q.shape[0] < 5:
            return math.nan, math.nan
        c, r = _fit_circle(q)
        centres.append(c)
        diam.append(2 * r)
    c3 = np.column_stack([np.array(centres), np.zeros(4)])
    side_err = _side_error(c3, board)
    diam_err = float(np.max(np.abs(np.array(diam) - board.hole_diameter_m)))
    return side_err, diam_err


def _fit_circle(q: np.ndarray) -> tuple[np.ndarray, float]:
    """Circle (centre (2,), radius) through 2D points (algebraic fit, refitted once without
    points farther than 3 robust sigmas from the first circle)."""
    keep = np.ones(len(q), dtype=bool)
    for _ in range(2):
        A = np.column_stack([2 * q[keep], np.ones(int(keep.sum()))])
        sol, *_ = np.linalg.lstsq(A, np.sum(q[keep] ** 2, axis=1), rcond=None)
        c = sol[:2]
        r = math.sqrt(max(sol[2] + c @ c, 1e-12))
        d = np.abs(np.linalg.norm(q - c, axis=1) - r)
        mad = float(np.median(d[keep])) * 1.4826
        new_keep = d <= max(3.0 * mad, 1e-9)
        if new_keep.sum() < 5:
            break
        keep = new_keep
    return c, r


def _side_error(centres: np.ndarray, board: BoardGeometry) -> float:
    """Largest deviation [m] of the four sides TL-TR, BL-BR, TL-BL, TR-BR from spacing_m."""
    sides = [(0, 1), (2, 3), (0, 2), (1, 3)]
    return float(
        max(abs(np.linalg.norm(centres[i] - centres[j]) - board.spacing_m) for i, j in sides)
    )
