"""Camera images of a :class:`~rigcal.sim.raw.scene.Scene` by per-pixel ray casting.

Camera frame: the optical frame (z forward along the optical axis, x right, y down);
``T_world_camera`` maps optical-frame points into the world (rig) frame. Pixel convention as in
OpenCV: the centre of pixel (col, row) is at (u, v) = (col, row).

Rendering casts ``supersample x supersample`` rays per pixel (default 2 x 2, so hole edges are
anti-aliased), shades every hit and box-filters down:

``grey = material.grey * (1 + contrast * texture) * (0.75 + 0.25 |cos(incidence)|)``

with the scene's seeded speckle texture (see :mod:`rigcal.sim.raw.scene`), ``scene.sky_grey``
where nothing is hit, then adds Gaussian noise (``noise_sigma`` grey levels, drawn from the
caller's generator) and rounds to uint8.

Camera model: anything with ``width``, ``height`` and ``unproject(uv (N, 2)) -> rays (N, 3)``
(or ``(rays, valid)``) works. :class:`PinholeRadtanCamera` is a minimal pinhole + plumb-bob
(radtan: k1, k2, p1, p2, k3) model for the simulator.
TODO: switch to ``rigcal.sensors.camera.RadtanCamera`` once that package exists.
Undistorted pinhole cameras take a fast path (rays from fx, fy, cx, cy, no unprojection);
distorted cameras unproject every sub-pixel once and keep the rays in a small cache.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from rigcal.errors import InputError
from rigcal.recording import ImageFrame, StereoFrame
from rigcal.geometry.se3 import from_rt, invert
from rigcal.sim.raw.scene import (
    SURFACE_GROUND,
    SURFACE_NONE,
    SURFACE_PLATE,
    SURFACE_WALL,
    Scene,
    texture_tile,
    trace_planes,
)
from rigcal.geometry.se3 import as_rigid

_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
_BAND_SAMPLES = 1 << 17  # rays per block while rendering (keeps temporaries in cache)


@dataclass(frozen=True)
class PinholeRadtanCamera:
    """Pinhole + plumb-bob (radtan) intrinsics: ``width`` x ``height`` [px], focal lengths and
    principal point [px], radial k1, k2, k3 and tangential p1, p2 (OpenCV's order
    k1, k2, p1, p2, k3)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0):
                raise InputError(f"camera.{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"camera.{name} must be a positive number [px], got {v!r}")
        for name in ("cx", "cy") + _DIST_NAMES:
            v = getattr(self, name)
            if not math.isfinite(v):
                raise InputError(f"camera.{name} must be finite, got {v!r}")
        for name in ("fx", "fy", "cx", "cy") + _DIST_NAMES:
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distortion(self) -> np.ndarray:
        """(5,) k1, k2, p1, p2, k3 (OpenCV's order)."""
        return np.array([getattr(self, n) for n in _DIST_NAMES])

    @property
    def is_distorted(self) -> bool:
        return any(getattr(self, n) != 0.0 for n in _DIST_NAMES)

    def undistorted(self) -> "PinholeRadtanCamera":
        """The same intrinsics without distortion."""
        return replace(self, **{n: 0.0 for n in _DIST_NAMES})

    def _distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def project(self, points_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of points (N, 3) in the optical frame [m] and a validity mask (N,):
        in front of the camera and inside the image (pixel centres 0 .. width-1 +- 0.5)."""
        p = np.asarray(points_camera, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"camera.project: points must be (N, 3), got {p.shape}")
        z = p[:, 2]
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        xd, yd = self._distort(p[:, 0] / zs, p[:, 1] / zs)
        uv = np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=1)
        inside = (
            (uv[:, 0] >= -0.5)
            & (uv[:, 0] <= self.width - 0.5)
            & (uv[:, 1] >= -0.5)
            & (uv[:, 1] <= self.height - 0.5)
        )
        uv[~front] = np.nan
        return uv, front & inside

    def unproject(self, uv: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Unit rays (N, 3) in the optical frame through pixels ``uv`` (N, 2) (distortion is
        inverted by Newton iterations, exact to ~1e-13 for moderate distortion)."""
        q = np.asarray(uv, dtype=float)
        if q.ndim != 2 or q.shape[1] != 2:
            raise InputError(f"camera.unproject: pixels must be (N, 2), got {q.shape}")
        xd = (q[:, 0] - self.cx) / self.fx
        yd = (q[:, 1] - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        if self.is_distorted:
            k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
            for _ in range(int(iterations)):  # Newton on distort(x, y) = (xd, yd)
                r2 = x * x + y * y
                radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
                fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
                fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
                jxx = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
                jxy = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
                jyy = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
                det = jxx * jyy - jxy * jxy
                det = np.where(np.abs(det) > 1e-12, det, 1e-12)
                step_x = (jyy * fx - jxy * fy) / det
                step_y = (jxx * fy - jxy * fx) / det
                x = x - step_x
                y = y - step_y
                change = max(
                    np.max(np.abs(step_x), initial=0.0), np.max(np.abs(step_y), initial=0.0)
                )
                if change < 1e-13:
                    break
        rays = np.stack([x, y, np.ones_like(x)], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair: both cameras share ``camera`` (no distortion); the right camera
    sits ``baseline_m`` along the left camera's +x axis with the same orientation."""

    camera: PinholeRadtanCamera
    baseline_m: float

    def __post_init__(self) -> None:
        if not isinstance(self.camera, PinholeRadtanCamera):
            raise InputError(
                f"stereo.camera must be a PinholeRadtanCamera, got {type(self.camera).__name__}"
            )
        if self.camera.is_distorted:
            raise InputError(
                "stereo.camera: a rectified pair has no distortion, got "
                f"k1, k2, p1, p2, k3 = {self.camera.distortion.tolist()}"
            )
        if not (math.isfinite(self.baseline_m) and self.baseline_m > 0):
            raise InputError(f"stereo.baseline_m must be > 0, got {self.baseline_m!r}")
        object.__setattr__(self, "baseline_m", float(self.baseline_m))

    @property
    def T_left_right(self) -> np.ndarray:
        """(4, 4) pose of the right camera in the left camera's optical frame."""
        return from_rt(np.eye(3), np.array([self.baseline_m, 0.0, 0.0]))

    def stereo_rig(self):
        """The pair as a :class:`rigcal.sensors.stereo.StereoRig` (for the stereo detector)."""
        from rigcal.sensors.stereo import StereoRig

        c = self.camera
        return StereoRig(c.fx, c.fy, c.cx, c.cy, self.baseline_m, c.width, c.height)

    def disparity_px(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """Disparity [px] of a point at optical-axis depth ``depth_m``: fx * baseline / z."""
        return self.camera.fx * self.baseline_m / np.asarray(depth_m, dtype=float)


# --------------------------------------------------------------------------- rays


def _pinhole_params(camera) -> tuple[float, float, float, float] | None:
    """(fx, fy, cx, cy) if ``camera`` is an undistorted pinhole we can cast rays for directly."""
    if isinstance(camera, PinholeRadtanCamera) and not camera.is_distorted:
        return camera.fx, camera.fy, camera.cx, camera.cy
    return None


def _subpixel_coords(n: int, s: int) -> np.ndarray:
    """Sub-pixel sample centres along one image axis: s per pixel, pixel centres at integers."""
    return ((np.arange(n * s, dtype=np.float64) + 0.5) / s - 0.5)


_RAY_CACHE: "OrderedDict[tuple, tuple[object, np.ndarray, np.ndarray]]" = OrderedDict()
_RAY_CACHE_SIZE = 3


def _camera_size(camera) -> tuple[int, int]:
    try:
        w, h = int(camera.width), int(camera.height)
    except (AttributeError, TypeError, ValueError) as exc:
        raise InputError(
            f"camera model {type(camera).__name__} needs integer width and height"
        ) from exc
    if w <= 0 or h <= 0:
        raise InputError(f"camera model {type(camera).__name__}: size {w}x{h} is not positive")
    return w, h


def _unprojected_grid(camera, s: int) -> tuple[np.ndarray, np.ndarray]:
    """(x/z, y/z) float32 arrays (H*s, W*s) of the rays through every sub-pixel; NaN where the
    model gives no ray in front of the camera. Cached per camera object."""
    try:
        key = (camera, s)
        hash(key)
    except TypeError:  # unhashable model (e.g. holds arrays): cache by identity
        key = (id(camera), s)
    hit = _RAY_CACHE.get(key)
    if hit is not None and (hit[0] is camera or hit[0] == camera):
        _RAY_CACHE.move_to_end(key)
        return hit[1], hit[2]
    w, h = _camera_size(camera)
    us = _subpixel_coords(w, s)
    vs = _subpixel_coords(h, s)
    xn = np.empty((h * s, w * s), dtype=np.float32)
    yn = np.empty_like(xn)
    rows_per_chunk = max(1, 400_000 // (w * s))
    for r0 in range(0, h * s, rows_per_chunk):
        r1 = min(h * s, r0 + rows_per_chunk)
        uu, vv = np.meshgrid(us, vs[r0:r1])
        out = camera.unproject(np.stack([uu.ravel(), vv.ravel()], axis=1))
        rays = np.asarray(out[0] if isinstance(out, tuple) else out, dtype=float)
        if rays.shape[-1] == 2:
            rays = np.concatenate([rays, np.ones(rays.shape[:-1] + (1,))], axis=-1)
        z = rays[:, 2]
        ok = np.isfinite(rays).all(axis=1) & (z > 1e-9)
        zs = np.where(ok, z, 1.0)
        xn[r0:r1] = np.where(ok, rays[:, 0] / zs, np.nan).reshape(r1 - r0, w * s)
        yn[r0:r1] = np.where(ok, rays[:, 1] / zs, np.nan).reshape(r1 - r0, w * s)
    xn.setflags(write=False)
    yn.setflags(write=False)
    _RAY_CACHE[key] = (camera, xn, yn)
    while len(_RAY_CACHE) > _RAY_CACHE_SIZE:
        _RAY_CACHE.popitem(last=False)
    return xn, yn


# --------------------------------------------------------------------------- rendering


@lru_cache(maxsize=4)
def _texture_atlas(seed: int) -> np.ndarray:
    """(3 * 1025, 1024) float32: the plate, wall and ground tiles stacked by surface id, each
    followed by a copy of its first row so bilinear lookups wrap within the tile."""
    tiles = [texture_tile(seed, sid) for sid in (SURFACE_PLATE, SURFACE_WALL, SURFACE_GROUND)]
    atlas = np.concatenate([np.concatenate([t, t[:1]]) for t in tiles])
    atlas.setflags(write=False)
    return atlas


def _shade(scene: Scene, tr, norm_d: np.ndarray | float) -> np.ndarray:
    """Grey levels (float32) of traced sub-pixels."""
    import cv2

    sid = tr.sid
    idx = sid.astype(np.intp) + 1  # 0 = sky, 1 = plate, 2 = wall, 3 = ground
    mats = [scene.plate_material, scene.wall_material, scene.ground_material]
    inv_cell = np.array([0.0] + [1.0 / m.texture_cell_m for m in mats], dtype=np.float32)
    grey = np.array([scene.sky_grey] + [m.grey for m in mats], dtype=np.float32)
    contrast = np.array([0.0] + [m.texture_contrast for m in mats], dtype=np.float32)
    tile = texture_tile(scene.texture_seed, SURFACE_PLATE).shape[0]
    k = np.take(inv_cell, idx)
    size, inv_size = np.float32(tile), np.float32(1.0 / tile)
    mx = tr.a * k
    mx -= np.floor(mx * inv_size) * size  # wrap into [0, tile] (np.mod is ~30x slower)
    my = tr.b * k
    my -= np.floor(my * inv_size) * size
    my += np.take(np.array([0, 0, tile + 1, 2 * (tile + 1)], dtype=np.float32), idx)
    atlas = _texture_atlas(scene.texture_seed)
    tex = cv2.remap(atlas, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    cos = np.abs(tr.ndotd) / norm_d
    out = np.take(grey, idx) * (1.0 + np.take(contrast, idx) * tex)
    out *= np.float32(0.75) + np.float32(0.25) * cos
    np.copyto(out, np.float32(scene.sky_grey), where=sid == SURFACE_NONE)
    return out


def _render_grey(camera, T_world_camera: np.ndarray, scene: Scene, supersample: int) -> np.ndarray:
    """Noise-free float32 (H, W) grey image."""
    import cv2

    w, h = _camera_size(camera)
    s = int(supersample)
    planes = scene.planes_in(invert(T_world_camera))
    pin = _pinhole_params(camera)
    if pin is not None:
        fx, fy, cx, cy = pin
        xn = ((_subpixel_coords(w, s) - cx) / fx).astype(np.float32)[None, :]
        yn = ((_subpixel_coords(h, s) - cy) / fy).astype(np.float32)[:, None]
    else:
        xn, yn = _unprojected_grid(camera, s)
    one = np.float32(1.0)
    grey = np.empty((h * s, w * s), dtype=np.float32)
    band = max(s, (_BAND_SAMPLES // (w * s)) // s * s)  # rows per band: cache-sized blocks
    for r0 in range(0, h * s, band):
        r1 = min(h * s, r0 + band)
        xb = xn if xn.shape[0] == 1 else xn[r0:r1]
        yb = yn[r0:r1]
        tr = trace_planes(
            planes, scene.plate_bounds_board, scene.board, (0.0, 0.0, 0.0), xb, yb, one
        )
        out = _shade(scene, tr, np.sqrt(xb * xb + yb * yb + one))
        if pin is None:  # sub-pixels the model cannot unproject stay black
            np.copyto(out, np.float32(0.0), where=~np.isfinite(xb))
        grey[r0:r1] = out
    if s > 1:
        grey = cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA)
    return grey


def _finish(
    grey: np.ndarray, rng: np.random.Generator, noise_sigma: float, bgr: bool
) -> np.ndarray:
    import cv2

    noise = rng.standard_normal(grey.shape, dtype=np.float32)
    img = grey + np.float32(noise_sigma) * noise
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if bgr else img


def _check_render_args(scene: Scene, rng, supersample: int, noise_sigma: float) -> None:
    if not isinstance(scene, Scene):
        raise InputError(f"render: scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"render: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if not (isinstance(supersample, (int, np.integer)) and 1 <= supersample <= 8):
        raise InputError(f"render: supersample must be an integer in 1..8, got {supersample!r}")
    if not (math.isfinite(noise_sigma) and noise_sigma >= 0):
        raise InputError(f"render: noise_sigma must be >= 0, got {noise_sigma!r}")


def render(
    camera,
    T_world_camera: np.ndarray,
    scene: Scene,
    rng: np.random.Generator,
    t_ns: int = 0,
    sensor: str = "camera",
    *,
    noise_sigma: float = 2.0,
    supersample: int = 2,
    bgr: bool = False,
    frame_id: str = "",
) -> ImageFrame:
    """An :class:`~rigcal.recording.ImageFrame` (uint8, (H, W) or BGR (H, W, 3)) of ``scene``
    seen by ``camera`` at ``T_world_camera`` (optical frame -> world). Draws H * W normals from
    ``rng`` (image noise, ``noise_sigma`` grey levels)."""
    _check_render_args(scene, rng, supersample, noise_sigma)
    T = as_rigid(T_world_camera, f"render '{sensor}': T_world_camera")
    grey = _render_grey(camera, T, scene, supersample)
    img = _finish(grey, rng, noise_sigma, bgr)
    return ImageFrame(sensor=sensor, t_ns=t_ns, image=img, frame_id=frame_id or sensor)


def render_stereo(
    stereo: StereoCamera,
    T_world_left: np.ndarray,
    scene: Scene,
    rng: np.random.Generator,
    t_ns: int = 0,
    sensor: str = "stereo",
    *,
    noise_sigma: float = 2.0,
    supersample: int = 2,
    bgr: bool = False,
    frame_id: str = "",
) -> StereoFrame:
    """A rectified :class:`~rigcal.recording.StereoFrame`: the left camera at ``T_world_left``
    (optical frame -> world), the right one ``stereo.baseline_m`` along the left +x axis. A point
    at depth z appears ``fx * baseline / z`` pixels further left in the right image. Noise: the
    left image's normals are drawn first, then the right's."""
    if not isinstance(stereo, StereoCamera):
        raise InputError(f"render_stereo: expected a StereoCamera, got {type(stereo).__name__}")
    _check_render_args(scene, rng, supersample, noise_sigma)
    T_left = as_rigid(T_world_left, f"render_stereo '{sensor}': T_world_left")
    T_right = T_left @ stereo.T_left_right
    grey_l = _render_grey(stereo.camera, T_left, scene, supersample)
    grey_r = _render_grey(stereo.camera, T_right, scene, supersample)
    left = _finish(grey_l, rng, noise_sigma, bgr)
    right = _finish(grey_r, rng, noise_sigma, bgr)
    return StereoFrame(
        sensor=sensor, t_ns=t_ns, left=left, right=right, frame_id=frame_id or sensor
    )
