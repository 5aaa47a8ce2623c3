"""Rectified stereo camera: disparity by OpenCV's semi-global block matching, then an organised
point cloud in the left camera's optical frame (z forward, x right, y down).

With a rectified pair (identical intrinsics, right camera at ``+baseline_m`` along x):
``Z = fx * baseline_m / disparity``, ``X = (u - cx) * Z / fx``, ``Y = (v - cy) * Z / fy``.

OpenCV is imported only inside the functions that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.errors import ConfigError, InputError
from rigcal.recording import PointCloudFrame, StereoFrame

__all__ = [
    "SgbmParams",
    "StereoRig",
    "disparity_from_pair",
    "downsample_pair",
    "point_cloud_from_pair",
    "point_cloud_in_window",
]


@dataclass(frozen=True)
class StereoRig:
    """Rectified left intrinsics [px], baseline [m] and image size [px] of a stereo camera."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "baseline_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"stereo rig: {name} must be a positive number, got {v!r}")
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise InputError(f"stereo rig: {name} must be a finite number, got {v!r}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise InputError(f"stereo rig: {name} must be a positive integer [px], got {v!r}")
            object.__setattr__(self, name, int(v))

    @property
    def size_wh(self) -> tuple[int, int]:
        return self.width, self.height

    def depth_m(self, disparity_px: np.ndarray) -> np.ndarray:
        """Depth Z [m] of disparities [px] (NaN where the disparity is not positive)."""
        d = np.asarray(disparity_px, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(d > 0, self.fx * self.baseline_m / d, np.nan)


_MODES = {"sgbm": 0, "hh": 1, "sgbm_3way": 2, "hh4": 3}


@dataclass(frozen=True)
class SgbmParams:
    """Settings of OpenCV's StereoSGBM (defaults for 1-2 MP images of a board at 3-7 m).

    * ``num_disparities`` 128 (multiple of 16) with ``min_disparity`` 0 covers depths from
      ``fx * baseline / 128`` (e.g. fx 1000 px, 0.2 m: 1.6 m) to infinity;
    * ``block_size`` 5: small windows keep the hole edges sharp (less foreground fattening);
      ``p1`` / ``p2`` default to OpenCV's recommended ``8 * c * b^2`` and ``32 * c * b^2``
      (c channels, b block size): smooth surfaces, depth jumps allowed at edges;
    * ``disp12_max_diff`` 1: left-right consistency check, so pixels seen by one camera only
      (the wall next to a hole's edge) become invalid instead of taking the plate's depth;
    * ``uniqueness_ratio`` 10, ``speckle_window_size`` 100 px with ``speckle_range`` 2 px:
      drop ambiguous matches and small islands of wrong disparity;
    * ``pre_filter_cap`` 63, ``mode`` ``"sgbm_3way"`` (OpenCV's faster, multi-threaded
      variant of the 5-direction pass; ``"hh"`` runs the full 8-direction pass, slower).
    """

    min_disparity: int = 0
    num_disparities: int = 128
    block_size: int = 5
    p1: int | None = None
    p2: int | None = None
    disp12_max_diff: int = 1
    pre_filter_cap: int = 63
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    mode: str = "sgbm_3way"

    def __post_init__(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ConfigError(
                f"sgbm: num_disparities must be a positive multiple of 16, got "
                f"{self.num_disparities}"
            )
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ConfigError(f"sgbm: block_size must be an odd number >= 1, got {self.block_size}")
        if self.mode not in _MODES:
            raise ConfigError(f"sgbm: mode must be one of {sorted(_MODES)}, got {self.mode!r}")
        if self.p1 is not None and self.p2 is not None and not 0 < self.p1 < self.p2:
            raise ConfigError(f"sgbm: need 0 < p1 < p2, got p1={self.p1}, p2={self.p2}")


def _gray(img: np.ndarray) -> np.ndarray:
    import cv2

    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def disparity_from_pair(frame: StereoFrame, params: SgbmParams = SgbmParams()) -> np.ndarray:
    """(H, W) float32 disparity [px] of the left image, NaN where SGBM found no valid match."""
    import cv2

    left, right = frame.left, frame.right
    channels = 1 if left.ndim == 2 else 3
    b = params.block_size
    p1 = params.p1 if params.p1 is not None else 8 * channels * b * b
    p2 = params.p2 if params.p2 is not None else 32 * channels * b * b
    matcher = cv2.StereoSGBM_create(
        minDisparity=params.min_disparity,
        numDisparities=params.num_disparities,
        blockSize=b,
        P1=p1,
        P2=p2,
        disp12MaxDiff=params.disp12_max_diff,
        preFilterCap=params.pre_filter_cap,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window_size,
        speckleRange=params.speckle_range,
        mode=_MODES[params.mode],
    )
    try:
        raw = matcher.compute(np.ascontiguousarray(left), np.ascontiguousarray(right))
    except cv2.error as exc:
        raise InputError(
            f"sensor '{frame.sensor}': StereoSGBM failed on a {left.shape} pair: {exc}"
        ) from None
    disp = raw.astype(np.float32) / 16.0
    disp[raw < (params.min_disparity * 16)] = np.nan  # OpenCV marks invalid as (min - 1) * 16
    return disp


def _cloud(frame: StereoFrame, rig: StereoRig, disp: np.ndarray, left: np.ndarray, u0: int,
           v0: int) -> PointCloudFrame:
    """The organised cloud of a disparity map whose pixel (0, 0) is the image's (u0, v0)."""
    h, w = disp.shape
    z = rig.depth_m(disp)
    u = np.arange(u0, u0 + w, dtype=float)[None, :]
    v = np.arange(v0, v0 + h, dtype=float)[:, None]
    x = (u - rig.cx) * z / rig.fx
    y = (v - rig.cy) * z / rig.fy
    pts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    gray = _gray(left).reshape(-1).astype(np.float32)
    return PointCloudFrame(
        frame.sensor,
        frame.t_ns,
        pts,
        {"intensity": gray, "disparity_px": disp.reshape(-1)},
        organized_shape=(h, w),
        frame_id=frame.frame_id,
    )


def downsample_pair(frame: StereoFrame, rig: StereoRig, factor: int) -> tuple[StereoFrame, StereoRig]:
    """The pair shrunk ``factor`` times (area averaging) and the rig that goes with it (pixel
    centres kept: ``c' = (c + 0.5) / factor - 0.5``): a cheap, coarse disparity map."""
    import cv2

    if isinstance(factor, bool) or not isinstance(factor, int) or factor < 1:
        raise ConfigError(f"stereo: downsampling factor must be an integer >= 1, got {factor!r}")
    w, h = rig.width // factor, rig.height // factor
    if w < 16 or h < 16:
        raise ConfigError(f"stereo: downsampling {rig.width}x{rig.height} by {factor} leaves "
                          f"{w}x{h} px")
    small = [cv2.resize(img[: h * factor, : w * factor], (w, h), interpolation=cv2.INTER_AREA)
             for img in (frame.left, frame.right)]
    out = StereoFrame(frame.sensor, frame.t_ns, small[0], small[1], frame_id=frame.frame_id)
    return out, StereoRig(
        fx=rig.fx / factor, fy=rig.fy / factor, cx=(rig.cx + 0.5) / factor - 0.5,
        cy=(rig.cy + 0.5) / factor - 0.5, baseline_m=rig.baseline_m, width=w, height=h,
    )


def point_cloud_in_window(
    frame: StereoFrame, rig: StereoRig, window: tuple[int, int, int, int],
    params: SgbmParams = SgbmParams(),
) -> PointCloudFrame:
    """Like :func:`point_cloud_from_pair` for the left image's pixels ``[v0:v1, u0:u1]`` only
    (``window`` = (u0, v0, u1, v1), clipped to the image): SGBM runs on those rows from
    ``min_disparity + num_disparities`` columns left of ``u0`` (the right image's search
    range), so the cost scales with the window. The cloud is organised with the window's shape;
    its pixel (0, 0) is the image's (u0, v0) (a pinhole with ``cx - u0``, ``cy - v0``)."""
    h, w = frame.left.shape[:2]
    if (w, h) != rig.size_wh:
        raise InputError(
            f"sensor '{frame.sensor}': images are {w}x{h} px, the stereo rig expects "
            f"{rig.width}x{rig.height}"
        )
    u0, v0, u1, v1 = (int(a) for a in window)
    u0, u1 = max(0, u0), min(w, u1)
    v0, v1 = max(0, v0), min(h, v1)
    if u1 <= u0 or v1 <= v0:
        raise InputError(f"sensor '{frame.sensor}': empty window {window} in a {w}x{h} image")
    reach = params.min_disparity + params.num_disparities
    ua = max(0, u0 - reach)
    crop = StereoFrame(frame.sensor, frame.t_ns, frame.left[v0:v1, ua:u1],
                       frame.right[v0:v1, ua:u1], frame_id=frame.frame_id)
    disp = disparity_from_pair(crop, params)[:, u0 - ua:]
    return _cloud(frame, rig, disp, frame.left[v0:v1, u0:u1], u0, v0)


def point_cloud_from_pair(
    frame: StereoFrame, rig: StereoRig, params: SgbmParams = SgbmParams()
) -> PointCloudFrame:
    """Organised (H x W) cloud [m] in the left optical frame from a rectified pair; NaN points
    where the disparity is invalid or not positive. Fields: ``intensity`` (left grey value) and
    ``disparity_px``. Raises InputError when the images do not have the rig's size."""
    h, w = frame.left.shape[:2]
    if (w, h) != rig.size_wh:
        raise InputError(
            f"sensor '{frame.sensor}': images are {w}x{h} px, the stereo rig expects "
            f"{rig.width}x{rig.height}"
        )
    return _cloud(frame, rig, disparity_from_pair(frame, params), frame.left, 0, 0)
