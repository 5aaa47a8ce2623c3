"""Camera measurement extractors guided by the expected target pose (Charron et al., III-C).

* :func:`extract_checkerboard` - checkerboard corners (OpenCV) in a crop around the projected
  target, ordered like the target's camera keypoints (the grid's 180-degree ambiguity is
  resolved with the expected pose), then optionally the target pose by PnP. When the target's
  planar outline is given (the diamond's four corners), its edges are located to sub-pixel
  accuracy and its corners join the PnP: a 0.2 m checkerboard at 2 m leaves the tilt uncertain
  by about 0.25 deg (1 sigma), the 0.7 m outline brings it to a few hundredths.
* :func:`extract_cylinder` - colour threshold (HSV, green by default) in the crop, the largest
  contour: its pixels are the keypoints, its filled region the silhouette.
* :func:`extract_target_camera` - either of them for a :class:`rigcal.targets.definition.Target`;
* :func:`solve_pnp`, :func:`fit_outline`, :func:`order_grid` - the steps, usable alone.

Works with any :class:`rigcal.sensors.camera.CameraModel` (``project``, ``project_jacobian``,
``unproject``): PnP runs on unprojected (normalised) rays and is refined on pixels.
Images are uint8 (H, W) mono or (H, W, 3) BGR arrays, or :class:`rigcal.recording.ImageFrame`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from rigcal.errors import InputError
from rigcal.extract.guidance import (
    PixelBox,
    PoseUncertainty,
    camera_view,
    check_points,
    check_pose,
    expected_image_box,
)
from rigcal.extract.result import (
    BLACK_IMAGE,
    CROP_OUTSIDE_IMAGE,
    NO_CONTOUR,
    NO_CORNERS,
    NO_OUTLINE,
    PATTERN_SIZE_MISMATCH,
    PNP_FAILED,
    ExtractionFailure,
    ExtractionResult,
    Measurement,
)
from rigcal.geometry.se3 import from_rt, se3_exp, transform_points
from rigcal.geometry.so3 import hat, so3_log
from rigcal.recording import ImageFrame

__all__ = [
    "OutlineFit",
    "PnpFit",
    "extract_checkerboard",
    "extract_cylinder",
    "extract_target_camera",
    "fit_outline",
    "order_grid",
    "solve_pnp",
]

MIN_CROP_PX = 16
"""A crop narrower or lower than this (after clipping to the image) is outside the image."""


# ---------------------------------------------------------------------------- inputs
def _image(image, sensor: str, t_ns: int | None) -> tuple[np.ndarray, str, int]:
    if isinstance(image, ImageFrame):
        return image.image, sensor or image.sensor, image.t_ns if t_ns is None else t_ns
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise InputError(
            f"sensor '{sensor}': expected a uint8 image (H, W) or (H, W, 3) BGR, got "
            f"{img.dtype} {img.shape}"
        )
    return img, sensor, 0 if t_ns is None else t_ns


def _gray(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def _check_camera(camera, img: np.ndarray, sensor: str) -> None:
    h, w = img.shape[:2]
    if (camera.width, camera.height) != (w, h):
        raise InputError(
            f"sensor '{sensor}': image is {w}x{h} but the camera model is "
            f"{camera.width}x{camera.height}"
        )


def _crop_box(
    camera,
    img: np.ndarray,
    crop: PixelBox | None,
    T_expected: np.ndarray | None,
    points_target: np.ndarray,
    uncertainty: PoseUncertainty | None,
    margin_px: float,
) -> PixelBox | None:
    """The search region clipped to the image (None if it has no usable overlap)."""
    h, w = img.shape[:2]
    if crop is None and T_expected is not None:
        crop = expected_image_box(camera, T_expected, points_target, uncertainty, margin_px)
        if crop is None:
            return None
    elif crop is None:
        crop = PixelBox(0, 0, w, h)
    else:
        crop = PixelBox(*(int(x) for x in crop))
    clipped = crop.clip(w, h)
    if clipped.width < MIN_CROP_PX or clipped.height < MIN_CROP_PX:
        return None
    return clipped


def _is_black(gray: np.ndarray, black_level: int) -> tuple[bool, float]:
    level = float(np.percentile(gray, 99.0))
    return level < black_level, level


# ---------------------------------------------------------------------------- ordering
def _grid_candidates(grid: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The orderings of a (rows, cols, 2) corner grid that keep its shape (4, or 8 if square)."""
    out = [
        ("identity", grid),
        ("rotate180", grid[::-1, ::-1]),
        ("flip_rows", grid[::-1, :]),
        ("flip_cols", grid[:, ::-1]),
    ]
    if grid.shape[0] == grid.shape[1]:
        tr = np.swapaxes(grid, 0, 1)
        out += [
            ("transpose", tr),
            ("rotate90", tr[::-1, :]),
            ("rotate270", tr[:, ::-1]),
            ("antitranspose", tr[::-1, ::-1]),
        ]
    return out


def order_grid(
    corners_px: np.ndarray, pattern_size: tuple[int, int], expected_px: np.ndarray
) -> tuple[np.ndarray, str, float, float]:
    """Reorder detected grid corners to match the expected keypoint pixels.

    ``corners_px`` (N, 2) in OpenCV's order (``pattern_size = (cols, rows)``, row-major),
    ``expected_px`` (N, 2) the target's keypoints projected at the expected pose, in keypoint
    order. The grid symmetries (180-degree turn, flips, and quarter turns for a square grid)
    are compared after removing the mean offset (a translation error of the prediction moves
    every corner alike) and the closest wins.

    Returns ``(ordered (N, 2), symmetry name, mean residual [px], runner-up residual [px])``.
    """
    cols, rows = pattern_size
    grid = np.asarray(corners_px, dtype=float).reshape(rows, cols, 2)
    exp = np.asarray(expected_px, dtype=float).reshape(-1, 2)
    exp_c = exp - exp.mean(axis=0)
    scored = []
    for name, cand in _grid_candidates(grid):
        c = cand.reshape(-1, 2)
        err = float(np.mean(np.linalg.norm((c - c.mean(axis=0)) - exp_c, axis=1)))
        scored.append((err, name, c))
    scored.sort(key=lambda s: s[0])
    return scored[0][2].copy(), scored[0][1], scored[0][0], scored[1][0]


# ---------------------------------------------------------------------------- PnP
class PnpFit(NamedTuple):
    """A target pose from 2D-3D correspondences: ``T_camera_target`` (4, 4), the pixel
    residuals (N, 2), their RMS [px] and 1-sigma errors from the Gauss-Newton covariance scaled
    by the residual variance: rotation [rad] and target-origin position [m], each along its
    worst direction."""

    T_camera_target: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    sigma_rotation_rad: float
    sigma_translation_m: float


def _residuals(camera, X: np.ndarray, uv: np.ndarray, T: np.ndarray):
    pc = transform_points(T, X)
    proj, _ = camera.project(pc)
    return pc, proj - uv


def _refine_pnp(camera, X: np.ndarray, uv: np.ndarray, T0: np.ndarray, iterations: int = 30):
    """Levenberg-Marquardt on pixel residuals; left perturbation ``T <- exp(xi) T``."""
    T = T0.copy()
    pc, r = _residuals(camera, X, uv, T)
    if not np.all(np.isfinite(r)):
        return None
    cost = float(np.sum(r * r))
    lam = 1e-3
    H = None
    for _ in range(iterations):
        Jp = camera.project_jacobian(pc)  # (N, 2, 3)
        dP = np.concatenate([-hat(pc), np.broadcast_to(np.eye(3), pc.shape + (3,))], axis=2)
        J = (Jp @ dP).reshape(-1, 6)
        H = J.T @ J
        g = J.T @ r.reshape(-1)
        improved = False
        for _ in range(10):
            step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
            T_new = se3_exp(step) @ T
            pc_new, r_new = _residuals(camera, X, uv, T_new)
            c_new = float(np.sum(r_new * r_new)) if np.all(np.isfinite(r_new)) else math.inf
            if c_new <= cost:
                T, pc, r, lam, improved = T_new, pc_new, r_new, max(lam / 10.0, 1e-9), True
                converged = cost - c_new < 1e-12 * max(cost, 1e-12) or np.linalg.norm(step) < 1e-12
                cost = c_new
                break
            lam *= 10.0
        if not improved or converged:
            break
    Jp = camera.project_jacobian(pc)
    dP = np.concatenate([-hat(pc), np.broadcast_to(np.eye(3), pc.shape + (3,))], axis=2)
    J = (Jp @ dP).reshape(-1, 6)
    return T, r, J.T @ J


def solve_pnp(
    camera,
    points_target: np.ndarray,
    uv: np.ndarray,
    T_camera_target_init: np.ndarray | None = None,
    *,
    sensor: str = "",
    t_ns: int = 0,
) -> PnpFit | ExtractionFailure:
    """The target pose from points ``points_target`` (N, 3) [m] seen at pixels ``uv`` (N, 2).

    An initial pose comes from OpenCV on the unprojected rays (IPPE when the points are
    coplanar - of its two solutions the one nearer ``T_camera_target_init`` in rotation, or
    with the lower error - SQPnP otherwise); it is refined by Levenberg-Marquardt on the pixel
    residuals with the full camera model. Fails with ``pnp_failed``.
    """
    X = check_points(points_target, "points_target", minimum=4)
    p = check_points(uv, "uv", dim=2, minimum=4)
    if X.shape[0] != p.shape[0]:
        raise InputError(f"solve_pnp: {X.shape[0]} target points but {p.shape[0]} pixels")
    rays = camera.unproject(p)
    with np.errstate(invalid="ignore", divide="ignore"):
        xn = rays[:, :2] / rays[:, 2:3]
    ok = np.all(np.isfinite(xn), axis=1) & (rays[:, 2] > 0)
    if np.sum(ok) < 4:
        return ExtractionFailure(
            sensor, t_ns, PNP_FAILED, f"only {int(np.sum(ok))} of {len(p)} pixels unproject"
        )
    Xo, xo = X[ok], xn[ok]
    centred = Xo - Xo.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    planar = sv[2] < 1e-6 * max(sv[0], 1e-12)
    K = np.eye(3)
    candidates: list[np.ndarray] = []
    try:
        flags = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            Xo.astype(np.float64), xo.astype(np.float64), K, None, flags=flags
        )
        for rv, tv in zip(rvecs, tvecs):
            candidates.append(from_rt(cv2.Rodrigues(rv)[0], np.asarray(tv, float).reshape(3)))
    except cv2.error as exc:
        return ExtractionFailure(sensor, t_ns, PNP_FAILED, f"OpenCV PnP failed: {exc}")
    if T_camera_target_init is not None:
        T_init = check_pose(T_camera_target_init, "T_camera_target_init")
        candidates.append(T_init)
    best = None
    for T0 in candidates:
        if not np.all(np.isfinite(T0)):
            continue
        out = _refine_pnp(camera, X, p, T0)
        if out is None:
            continue
        T, r, H = out
        cost = float(np.sum(r * r))
        if not np.all(np.isfinite(r)) or np.any(transform_points(T, X)[:, 2] <= 0):
            continue
        if best is None or cost < best[0] - 1e-9:
            best = (cost, T, r, H)
    if best is None:
        return ExtractionFailure(
            sensor, t_ns, PNP_FAILED, "no PnP solution places the points in front"
        )
    cost, T, r, H = best
    dof = max(r.size - 6, 1)
    s2 = cost / dof
    try:
        cov = np.linalg.inv(H) * s2
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    # left perturbation in the camera frame: the target origin t moves by -hat(t) omega + v
    A = np.concatenate([-hat(T[:3, 3]), np.eye(3)], axis=1)
    cov_t = A @ cov @ A.T if np.all(np.isfinite(cov)) else np.full((3, 3), np.inf)
    sig_r = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0))) if np.all(
        np.isfinite(cov)) else math.inf
    sig_t = float(np.sqrt(max(np.linalg.eigvalsh(cov_t).max(), 0.0))) if np.all(
        np.isfinite(cov_t)) else math.inf
    return PnpFit(T, r, float(np.sqrt(np.mean(np.sum(r * r, axis=1)))), sig_r, sig_t)


# ---------------------------------------------------------------------------- outline
class OutlineFit(NamedTuple):
    """A planar polygon located in the image: ``corners_px`` (K, 2) intersections of the fitted
    edge lines (in the order of the target polygon's corners), ``edge_rms_px`` (K,) line-fit
    RMS per edge, ``edge_points`` (K,) how many sub-pixel edge points each line kept."""

    corners_px: np.ndarray
    edge_rms_px: np.ndarray
    edge_points: np.ndarray


def _sample(gray_f: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float image at (..., 2) pixel coordinates (u, v)."""
    flat = xy.reshape(-1, 2).astype(np.float32)
    vals = cv2.remap(
        gray_f, flat[:, 0:1], flat[:, 1:2], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    )
    return vals.reshape(xy.shape[:-1])


def _fit_line(xn: np.ndarray, rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line ``n . x = d`` with MAD trimming; returns (line (3,), kept mask)."""
    keep = np.ones(len(xn), dtype=bool)
    for _ in range(rounds):
        c = xn[keep].mean(axis=0)
        _, _, vt = np.linalg.svd(xn[keep] - c)
        n = vt[1]
        res = (xn - c) @ n
        mad = 1.4826 * np.median(np.abs(res[keep])) + 1e-12
        new = np.abs(res) < 3.0 * mad
        if new.sum() < 2 or np.array_equal(new, keep):
            break
        keep = new
    return np.array([n[0], n[1], -float(n @ c)]), keep


def fit_outline(
    image: np.ndarray,
    camera,
    T_camera_target: np.ndarray,
    polygon_target: np.ndarray,
    *,
    search_px: float = 10.0,
    samples_per_edge: int = 60,
    edge_span: tuple[float, float] = (0.12, 0.88),
    min_contrast: float = 20.0,
    min_points_per_edge: int = 10,
    sensor: str = "",
    t_ns: int = 0,
) -> OutlineFit | ExtractionFailure:
    """Locate the edges of a planar polygonal target near its predicted outline.

    ``polygon_target`` (K, 3) [m]: the polygon's corners in the target frame, in order around
    it (e.g. the diamond's four lidar keypoints). Along each edge (between ``edge_span`` of its
    length, away from the corners) the image is sampled across the predicted edge within
    ``+-search_px``; the strongest intensity step (sub-pixel by a parabola through the gradient
    peak, at least ``min_contrast`` grey levels) is an edge point. Edge points are unprojected,
    a line is fitted per edge in the normalised image plane (so lens distortion is handled) and
    consecutive lines are intersected. Fails with ``no_outline``.
    """
    img, sensor, t_ns = _image(image, sensor, t_ns)
    gray = _gray(img).astype(np.float32)
    T = check_pose(T_camera_target, "T_camera_target")
    poly = check_points(polygon_target, "polygon_target", minimum=3)
    K = len(poly)
    s = np.linspace(edge_span[0], edge_span[1], int(samples_per_edge))
    offsets = np.arange(-search_px, search_px + 1e-9, 0.25)
    lines, rms, counts = [], [], []
    for k in range(K):
        P0, P1 = poly[k], poly[(k + 1) % K]
        X = P0[None, :] + s[:, None] * (P1 - P0)[None, :]
        uv, _ = camera.project(transform_points(T, X))
        if not np.all(np.isfinite(uv)):
            return ExtractionFailure(sensor, t_ns, NO_OUTLINE, f"edge {k} does not project")
        tangent = np.gradient(uv, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        pts = uv[:, None, :] + offsets[None, :, None] * normal[:, None, :]
        prof = _sample(gray, pts)  # (S, O)
        grad = np.gradient(prof, axis=1)
        contrast = prof.max(axis=1) - prof.min(axis=1)
        idx = np.argmax(np.abs(grad), axis=1)
        inner = (idx > 0) & (idx < len(offsets) - 1) & (contrast >= min_contrast)
        if np.sum(inner) < min_points_per_edge:
            return ExtractionFailure(
                sensor, t_ns, NO_OUTLINE,
                f"edge {k}: {int(np.sum(inner))} edge samples with contrast >= {min_contrast}, "
                f"need {min_points_per_edge}",
            )
        rows = np.flatnonzero(inner)
        sign = np.sign(grad[rows, idx[rows]])
        polarity = np.sign(np.sum(sign)) or 1.0
        rows = rows[sign == polarity]
        i = idx[rows]
        g0 = np.abs(grad[rows, i - 1])
        g1 = np.abs(grad[rows, i])
        g2 = np.abs(grad[rows, i + 1])
        den = g0 - 2.0 * g1 + g2
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(np.abs(den) > 1e-9, 0.5 * (g0 - g2) / den, 0.0)
        frac = np.clip(frac, -0.5, 0.5)
        o = offsets[i] + frac * (offsets[1] - offsets[0])
        edge_uv = uv[rows] + o[:, None] * normal[rows]
        rays = camera.unproject(edge_uv)
        with np.errstate(invalid="ignore", divide="ignore"):
            xn = rays[:, :2] / rays[:, 2:3]
        good = np.all(np.isfinite(xn), axis=1)
        if np.sum(good) < min_points_per_edge:
            return ExtractionFailure(
                sensor, t_ns, NO_OUTLINE,
                f"edge {k}: only {int(np.sum(good))} edge points unproject",
            )
        line, kept = _fit_line(xn[good])
        if kept.sum() < min_points_per_edge:
            return ExtractionFailure(
                sensor, t_ns, NO_OUTLINE, f"edge {k}: {int(kept.sum())} edge points fit a line"
            )
        res_n = xn[good][kept] @ line[:2] + line[2]
        # residuals to pixels with the local image scale
        Jp = camera.project_jacobian(np.concatenate([xn[good][kept], np.ones((kept.sum(), 1))], 1))
        scale = np.linalg.norm(Jp[:, :, :2], ord=2, axis=(1, 2))
        lines.append(line)
        rms.append(float(np.sqrt(np.mean((res_n * scale) ** 2))))
        counts.append(int(kept.sum()))
    corners_n = []
    for k in range(K):
        x = np.cross(lines[k - 1], lines[k])
        if abs(x[2]) < 1e-12:
            return ExtractionFailure(
                sensor, t_ns, NO_OUTLINE, f"edges {k - 1} and {k} are parallel"
            )
        corners_n.append(x[:2] / x[2])
    pts = np.concatenate([np.array(corners_n), np.ones((K, 1))], axis=1)
    corners_px, _ = camera.project(pts)
    if not np.all(np.isfinite(corners_px)):
        return ExtractionFailure(sensor, t_ns, NO_OUTLINE, "an outline corner does not project")
    return OutlineFit(corners_px, np.array(rms), np.array(counts))


# ---------------------------------------------------------------------------- checkerboard
#: below this square size [px] the grid's corners are refined with cv2.cornerSubPix (window
#: SUBPIX_WINDOW_SQUARES): on the rendered sessions' 9-20 px squares findChessboardCornersSB
#: (CALIB_CB_ACCURACY) pushes a grid's border corners outward (0.034-0.066 px below 13 px) and
#: shifts a whole view's grid by about 0.02 px (RMS; cornerSubPix 0.007) - errors that look
#: like a pose error and do not average out over holds; refined, the cameras come out 2-4x
#: closer to the truth with regions that hold it. On the paper's image (31 px squares, JPEG)
#: SB's corners are the better ones (PnP residual 0.07 px against 0.13-0.14 refined) - so the
#: threshold lies between (benchmarks/corner_bias.py, benchmarks/mocap_sessions.py, docs/mocap.md)
SMALL_SQUARE_PX = 20.0
SUBPIX_WINDOW_SQUARES = 0.4


def grid_square_px(corners: np.ndarray, pattern_size: tuple[int, int]) -> float:
    """The median distance [px] between neighbouring corners of a grid (N, 2) in OpenCV's
    row-major order (``pattern_size = (cols, rows)``)."""
    cols, rows = pattern_size
    g = np.asarray(corners, dtype=float).reshape(rows, cols, 2)
    d = np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(),
                        np.linalg.norm(np.diff(g, axis=0), axis=2).ravel()])
    return float(np.median(d))


def _refine_small_squares(gray: np.ndarray, corners: np.ndarray, pattern_size: tuple[int, int],
                          below_px: float) -> tuple[np.ndarray, float, bool]:
    """``(corners, square_px, refined)``: the corners (N, 2) refined by cv2.cornerSubPix when
    the grid's squares are smaller than ``below_px`` (see SMALL_SQUARE_PX), else as given."""
    square = grid_square_px(corners, pattern_size)
    if not (square < below_px):
        return corners, square, False
    w = max(2, int(round(SUBPIX_WINDOW_SQUARES * square)))
    refined = cv2.cornerSubPix(gray, np.ascontiguousarray(corners, dtype=np.float32).reshape(-1, 1, 2), (w, w),
                               (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
    out = refined.reshape(-1, 2).astype(float)
    if not np.all(np.isfinite(out)) or np.max(np.linalg.norm(out - corners, axis=1)) > 0.5 * square:
        return corners, square, False  # a corner ran off: keep the detector's
    return out, square, True


def _detect_corners(gray: np.ndarray, pattern_size: tuple[int, int], flags: int,
                    square_px: float | None = None):
    """Corners (N, 2) in ``gray`` or None. A large region is searched at half resolution first
    (when the squares are at least ~20 px) and the board then re-detected at full resolution in
    a tight box around it, which is several times faster than a full-resolution search."""
    h, w = gray.shape
    cols, rows = pattern_size
    if max(h, w) > 600 and (square_px is None or square_px >= 20.0):
        small = cv2.resize(gray, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        ok, rough = cv2.findChessboardCornersSB(small, pattern_size, flags=0)
        if ok and rough is not None:
            rough = rough.reshape(-1, 2) * 2.0 + 0.5
            pad = 2.0 * max(np.ptp(rough[:, 0]) / (cols - 1), np.ptp(rough[:, 1]) / (rows - 1))
            u0, v0 = (int(max(math.floor(x - pad), 0)) for x in rough.min(axis=0))
            u1 = int(min(math.ceil(rough[:, 0].max() + pad), w))
            v1 = int(min(math.ceil(rough[:, 1].max() + pad), h))
            ok, corners = cv2.findChessboardCornersSB(gray[v0:v1, u0:u1], pattern_size, flags=flags)
            if ok and corners is not None:
                return corners.reshape(-1, 2).astype(float) + np.array([u0, v0], float)
    ok, corners = cv2.findChessboardCornersSB(gray, pattern_size, flags=flags)
    if not ok or corners is None:
        return None
    return corners.reshape(-1, 2).astype(float)


def _board_size_seen(gray: np.ndarray) -> tuple[int, int] | None:
    """(cols, rows) inner corners of whatever checkerboard OpenCV finds in ``gray``."""
    try:
        ok, corners, meta = cv2.findChessboardCornersSBWithMeta(gray, (3, 3), cv2.CALIB_CB_LARGER)
    except cv2.error:
        return None
    if not ok or meta is None:
        return None
    return int(meta.shape[1]), int(meta.shape[0])


def extract_checkerboard(
    image,
    camera,
    pattern_size: tuple[int, int],
    keypoints_target: np.ndarray,
    T_camera_target_expected: np.ndarray | None = None,
    *,
    uncertainty: PoseUncertainty | None = None,
    crop: PixelBox | None = None,
    crop_margin_px: float = 20.0,
    outline_target: np.ndarray | None = None,
    estimate_pose: bool = True,
    black_level: int = 25,
    sb_flags: int = cv2.CALIB_CB_ACCURACY,
    max_order_residual_squares: float = 0.5,
    refine_below_square_px: float = SMALL_SQUARE_PX,
    sensor: str = "",
    t_ns: int | None = None,
    target: str = "checkerboard",
) -> ExtractionResult:
    """Checkerboard corners, ordered like the target's camera keypoints, and the target pose.

    ``pattern_size`` ``(cols, rows)`` inner corners (OpenCV's convention);
    ``keypoints_target`` (cols*rows, 3) [m] the corners in the target frame, row-major in the
    same grid layout (the ``keypoints_camera`` of a target file). ``T_camera_target_expected``
    (4, 4) the mocap-predicted pose: it decides whether the target is in view, where to crop
    (grown by ``uncertainty`` and ``crop_margin_px``) and which of the grid's symmetric orderings
    is right; a detected grid whose best ordering still differs from the prediction by more
    than ``max_order_residual_squares`` squares on average (after removing the mean offset) is
    refused: OpenCV can return a shifted or transposed sub-grid that takes in T-junctions of the
    board's border. Without it the whole image (or ``crop``) is searched and which corner is
    which cannot be told (a grid looks the same turned half round): the corners come in
    OpenCV's order with ``keypoint_index`` None, no pose, and ``quality["orientation_ambiguous"]``
    1 - order them with :func:`order_grid` against a prediction.
    ``crop`` (a :class:`PixelBox`) overrides the predicted region. A grid whose squares are
    smaller than ``refine_below_square_px`` (default :data:`SMALL_SQUARE_PX`; 0: never) has its
    corners refined with ``cv2.cornerSubPix`` (``quality["corners_subpix"]`` 1, and
    ``quality["square_px"]`` the squares' size).

    With ``estimate_pose`` the pose comes from :func:`solve_pnp`; with ``outline_target``
    (K, 3) [m] (a planar polygon around the board, e.g. the diamond's corners, in order) its
    corners are located by :func:`fit_outline` and join the PnP.

    Returns a :class:`Measurement` (``keypoints`` (N, 2) [px] in keypoint order,
    ``keypoint_index`` 0..N-1, ``T_sensor_target`` or None; extras ``crop_box`` (4,) and, with an
    outline, ``outline_corners_px`` (K, 2)) or an :class:`ExtractionFailure`:
    ``target_not_in_view``, ``crop_outside_image``, ``black_image``, ``no_corners``,
    ``pattern_size_mismatch``, ``pnp_failed``, ``no_outline``.
    """
    img, sensor, t_ns = _image(image, sensor, t_ns)
    _check_camera(camera, img, sensor)
    cols, rows = (int(x) for x in pattern_size)
    if cols < 2 or rows < 2:
        raise InputError(f"sensor '{sensor}': pattern_size must be >= (2, 2), got {pattern_size}")
    kp = check_points(keypoints_target, "keypoints_target")
    if kp.shape[0] != cols * rows:
        raise InputError(
            f"sensor '{sensor}': {kp.shape[0]} camera keypoints in the target but the pattern "
            f"{cols}x{rows} has {cols * rows} corners"
        )
    outline = (
        None if outline_target is None
        else check_points(outline_target, "outline_target", minimum=3)
    )
    T_exp = None if T_camera_target_expected is None else check_pose(
        T_camera_target_expected, "T_camera_target_expected"
    )
    quality: dict[str, float] = {}

    if T_exp is not None:
        view = camera_view(camera, T_exp, kp, margin_px=0.0, min_fraction=1.0)
        quality["fraction_in_view"] = view.fraction
        if not view.visible:
            return ExtractionFailure(
                sensor, t_ns, view.reason, f"checkerboard corners: {view.detail}"
            )
    box = _crop_box(camera, img, crop, T_exp, kp, uncertainty, crop_margin_px)
    if box is None:
        return ExtractionFailure(
            sensor, t_ns, CROP_OUTSIDE_IMAGE,
            f"the search region {tuple(crop) if crop is not None else '(predicted)'} has no "
            f"{MIN_CROP_PX}x{MIN_CROP_PX} px overlap with the {img.shape[1]}x{img.shape[0]} image",
        )
    gray = _gray(img)
    sub = gray[box.v_min:box.v_max, box.u_min:box.u_max]
    black, level = _is_black(sub, black_level)
    if black:
        return ExtractionFailure(
            sensor, t_ns, BLACK_IMAGE,
            f"99th percentile grey level {level:.0f} < {black_level} in the search region",
        )
    square_px = None
    if T_exp is not None:
        exp_uv, _ = camera.project(transform_points(T_exp, kp))
        span = np.linalg.norm(exp_uv[-1] - exp_uv[0])
        square_px = float(span / math.hypot(cols - 1, rows - 1))
    corners = _detect_corners(sub, (cols, rows), sb_flags, square_px)
    if corners is None:
        seen = _board_size_seen(sub)
        if seen is not None and sorted(seen) != sorted((cols, rows)):
            return ExtractionFailure(
                sensor, t_ns, PATTERN_SIZE_MISMATCH,
                f"a checkerboard with {seen[0]}x{seen[1]} inner corners is in view, expected "
                f"{cols}x{rows}",
            )
        return ExtractionFailure(
            sensor, t_ns, NO_CORNERS,
            f"no {cols}x{rows} checkerboard in the {box.width}x{box.height} px region at "
            f"({box.u_min}, {box.v_min})",
        )
    corners = corners + np.array([box.u_min, box.v_min], dtype=float)
    corners, square_seen, refined = _refine_small_squares(gray, corners, (cols, rows), refine_below_square_px)
    quality.update(square_px=square_seen, corners_subpix=float(refined))
    if T_exp is not None:
        expected_px, _ = camera.project(transform_points(T_exp, kp))
        corners, sym, err, runner = order_grid(corners, (cols, rows), expected_px)
        quality.update(order_residual_px=err, order_runner_up_px=runner, orientation_guided=1.0)
        if square_px is not None and err > max_order_residual_squares * square_px:
            return ExtractionFailure(
                sensor, t_ns, PATTERN_SIZE_MISMATCH,
                f"the corner grid differs from the predicted one by {err:.1f} px on average "
                f"(squares are {square_px:.1f} px): a shifted or transposed grid",
            )
    else:
        # nothing tells a corner from its twin across the 180-degree turn: reported, not guessed
        quality.update(orientation_guided=0.0, orientation_ambiguous=1.0)
        return Measurement(sensor=sensor, t_ns=t_ns, target=target, keypoints=corners,
                           keypoint_index=None, T_sensor_target=None,
                           extras={"crop_box": np.array(box, dtype=float)}, quality=quality)
    extras = {"crop_box": np.array(box, dtype=float)}
    T_fit = None
    if estimate_pose:
        fit = solve_pnp(camera, kp, corners, T_exp, sensor=sensor, t_ns=t_ns)
        if isinstance(fit, ExtractionFailure):
            return fit
        quality.update(
            pnp_rms_px=fit.rms_px,
            pnp_sigma_rotation_deg=math.degrees(fit.sigma_rotation_rad),
            pnp_sigma_translation_m=fit.sigma_translation_m,
        )
        T_fit = fit.T_camera_target
        if outline is not None:
            for _ in range(2):  # re-locate the edges once the pose has improved
                of = fit_outline(gray, camera, T_fit, outline, sensor=sensor, t_ns=t_ns)
                if isinstance(of, ExtractionFailure):
                    return of
                joint = solve_pnp(
                    camera, np.vstack([kp, outline]), np.vstack([corners, of.corners_px]), T_fit,
                    sensor=sensor, t_ns=t_ns,
                )
                if isinstance(joint, ExtractionFailure):
                    return joint
                T_fit = joint.T_camera_target
            extras["outline_corners_px"] = of.corners_px
            quality.update(
                outline_edge_rms_px=float(np.max(of.edge_rms_px)),
                joint_pnp_rms_px=joint.rms_px,
                joint_pnp_sigma_rotation_deg=math.degrees(joint.sigma_rotation_rad),
                joint_pnp_sigma_translation_m=joint.sigma_translation_m,
            )
        if T_exp is not None:
            dT = np.linalg.inv(T_exp) @ T_fit
            quality["correction_translation_m"] = float(np.linalg.norm(T_fit[:3, 3] - T_exp[:3, 3]))
            quality["correction_rotation_deg"] = math.degrees(
                float(np.linalg.norm(so3_log(dT[:3, :3])))
            )
    return Measurement(
        sensor=sensor,
        t_ns=t_ns,
        target=target,
        keypoints=corners,
        keypoint_index=np.arange(len(corners)),
        T_sensor_target=T_fit,
        extras=extras,
        quality=quality,
    )


# ---------------------------------------------------------------------------- cylinder
def extract_cylinder(
    image,
    camera=None,
    T_camera_target_expected: np.ndarray | None = None,
    template_target: np.ndarray | None = None,
    *,
    uncertainty: PoseUncertainty | None = None,
    crop: PixelBox | None = None,
    crop_margin_px: float = 20.0,
    hsv_low: tuple[int, int, int] = (35, 80, 30),
    hsv_high: tuple[int, int, int] = (85, 255, 255),
    open_px: int = 3,
    min_area_px: float = 200.0,
    min_fraction_in_view: float = 0.5,
    black_level: int = 25,
    sensor: str = "",
    t_ns: int | None = None,
    target: str = "cylinder",
) -> ExtractionResult:
    """The coloured target's silhouette: threshold in HSV, largest contour (Suzuki's border
    following, ``cv2.findContours``) inside the search region.

    ``hsv_low``/``hsv_high``: inclusive OpenCV HSV bounds (H in 0..180); green by default.
    With ``camera``, ``T_camera_target_expected`` (4, 4) and ``template_target`` (M, 3) [m] the
    search region is the template's predicted box grown by ``uncertainty`` and
    ``crop_margin_px``, and the frame is rejected unless ``min_fraction_in_view`` of the
    template projects into the image; otherwise the whole image (or ``crop``) is searched.
    ``open_px``: side of the morphological opening that removes specks (0: none).

    Returns a :class:`Measurement` with ``keypoints`` the contour's pixels (N, 2) [px] (no
    correspondences), extras ``silhouette`` (h, w) bool over ``crop_box`` (4,) = (u_min, v_min,
    u_max, v_max), quality ``area_px``, ``bbox_*_px``, ``solidity``,
    ``area_ratio_expected`` (with a template); or an :class:`ExtractionFailure`:
    ``target_not_in_view``, ``crop_outside_image``, ``black_image``, ``no_contour``.
    """
    img, sensor, t_ns = _image(image, sensor, t_ns)
    if img.ndim != 3:
        raise InputError(f"sensor '{sensor}': colour thresholding needs a BGR (H, W, 3) image")
    guided = (
        camera is not None
        and T_camera_target_expected is not None
        and template_target is not None
    )
    quality: dict[str, float] = {}
    T_exp = tmpl = None
    if guided:
        _check_camera(camera, img, sensor)
        T_exp = check_pose(T_camera_target_expected, "T_camera_target_expected")
        tmpl = check_points(template_target, "template_target")
        view = camera_view(camera, T_exp, tmpl, 0.0, min_fraction_in_view)
        quality["fraction_in_view"] = view.fraction
        if not view.visible:
            return ExtractionFailure(sensor, t_ns, view.reason, f"cylinder template: {view.detail}")
    region = tmpl if guided else np.zeros((1, 3))
    box = _crop_box(camera, img, crop, T_exp, region, uncertainty, crop_margin_px)
    if box is None:
        return ExtractionFailure(
            sensor, t_ns, CROP_OUTSIDE_IMAGE,
            f"the search region {tuple(crop) if crop is not None else '(predicted)'} has no "
            f"{MIN_CROP_PX}x{MIN_CROP_PX} px overlap with the {img.shape[1]}x{img.shape[0]} image",
        )
    sub = img[box.v_min:box.v_max, box.u_min:box.u_max]
    black, level = _is_black(_gray(sub), black_level)
    if black:
        return ExtractionFailure(
            sensor, t_ns, BLACK_IMAGE,
            f"99th percentile grey level {level:.0f} < {black_level} in the search region",
        )
    hsv = cv2.cvtColor(np.ascontiguousarray(sub), cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, np.array(hsv_low, np.uint8), np.array(hsv_high, np.uint8))
    if open_px > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    areas = [cv2.contourArea(c) for c in contours]
    if not contours or max(areas) < min_area_px:
        return ExtractionFailure(
            sensor, t_ns, NO_CONTOUR,
            f"largest region in HSV {hsv_low}..{hsv_high} has {max(areas) if areas else 0:.0f} px "
            f"area, need {min_area_px:.0f}",
        )
    best = contours[int(np.argmax(areas))]
    area = float(max(areas))
    silhouette = np.zeros(mask.shape, np.uint8)
    cv2.drawContours(silhouette, [best], -1, 255, thickness=cv2.FILLED)
    x, y, w, h = cv2.boundingRect(best)
    hull_area = float(cv2.contourArea(cv2.convexHull(best)))
    pts = best.reshape(-1, 2).astype(float) + np.array([box.u_min, box.v_min], float)
    m = cv2.moments(best)
    quality.update(
        area_px=area,
        bbox_u_px=float(x + box.u_min),
        bbox_v_px=float(y + box.v_min),
        bbox_width_px=float(w),
        bbox_height_px=float(h),
        centroid_u_px=m["m10"] / m["m00"] + box.u_min if m["m00"] > 0 else math.nan,
        centroid_v_px=m["m01"] / m["m00"] + box.v_min if m["m00"] > 0 else math.nan,
        solidity=area / hull_area if hull_area > 0 else math.nan,
        regions=float(len(contours)),
    )
    if guided:
        uv, _ = camera.project(transform_points(T_exp, tmpl))
        uv = uv[np.all(np.isfinite(uv), axis=1)].astype(np.float32)
        if len(uv) >= 3:
            exp_area = float(cv2.contourArea(cv2.convexHull(uv)))
            quality["area_ratio_expected"] = area / exp_area if exp_area > 0 else math.nan
    return Measurement(
        sensor=sensor,
        t_ns=t_ns,
        target=target,
        keypoints=pts,
        keypoint_index=None,
        T_sensor_target=None,
        extras={"silhouette": silhouette > 0, "crop_box": np.array(box, dtype=float)},
        quality=quality,
    )


# ---------------------------------------------------------------------------- by target
def _kind(target) -> str:
    kind = getattr(target, "kind", "")
    return str(getattr(kind, "value", kind))


def extract_target_camera(
    image,
    camera,
    target,
    T_camera_target_expected: np.ndarray | None,
    *,
    use_outline: bool = True,
    **options,
) -> ExtractionResult:
    """The camera extractor for a :class:`rigcal.targets.definition.Target` (read duck-typed:
    ``kind``, ``dims``, ``camera_keypoints``, ``lidar_keypoints``, ``template``,
    ``crop_image_px``).

    ``checkerboard_diamond``: :func:`extract_checkerboard` with pattern ``(dims["cols"],
    dims["rows"])`` and the camera keypoints; with ``use_outline`` the lidar keypoints (the
    diamond's corners) are the outline that refines the pose. ``cylinder``:
    :func:`extract_cylinder` with the template. The target's ``crop_image_px`` (the original
    tool's image margin) is the default ``crop_margin_px``. ``options`` go to the extractor.
    """
    kind = _kind(target)
    crop_image = getattr(target, "crop_image_px", None)
    if crop_image is not None and "crop_margin_px" not in options:
        options["crop_margin_px"] = float(max(crop_image))
    options.setdefault("target", getattr(target, "name", kind) or kind)
    if kind == "checkerboard_diamond":
        dims = getattr(target, "dims", {})
        if "rows" not in dims or "cols" not in dims or target.camera_keypoints is None:
            raise InputError(
                f"target '{getattr(target, 'name', '?')}': a checkerboard needs dims rows and "
                "cols and camera keypoints"
            )
        outline = target.lidar_keypoints if use_outline else None
        return extract_checkerboard(
            image, camera, (int(dims["cols"]), int(dims["rows"])), target.camera_keypoints,
            T_camera_target_expected, outline_target=outline, **options,
        )
    if kind == "cylinder":
        return extract_cylinder(image, camera, T_camera_target_expected, target.template, **options)
    raise InputError(
        f"target '{getattr(target, 'name', '?')}': no camera extractor for kind '{kind}' "
        "(checkerboard_diamond, cylinder)"
    )
