"""The one interface every camera model implements.

A camera model maps points in the camera optical frame (z forward, x right, y down) [m] to
pixel coordinates (u right, v down) [px]. Pixel centres are at integer coordinates (OpenCV's
convention), so the image covers ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``.

Models are immutable values: ``params`` is a read-only (P,) array, :meth:`CameraModel.with_params`
returns a new model. Projection never raises for points it cannot image: it returns a validity
mask instead (behind the camera, outside the model's domain, outside the image).

A model subclass is a frozen dataclass that sets the class attributes ``name`` and
``param_names`` (every model's parameters start with ``fx, fy, cx, cy``) and implements the private hooks ``_project``, ``_project_jacobian``,
``_params_jacobian`` and ``_unproject`` on already-validated float arrays; it may override
``_in_domain`` (where the projection is defined and one-to-one, by default ``z > eps``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from rigcal.errors import InputError

MIN_DEPTH_M = 1e-6
"""Points with ``z <= MIN_DEPTH_M`` are behind (or on) the camera plane and never valid."""


def as_points(points: np.ndarray, what: str = "points_cam") -> np.ndarray:
    """A new float (N, 3) array from ``points``; a single (3,) point becomes (1, 3)."""
    p = np.array(points, dtype=float)  # a copy: callers' arrays are never touched
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{what}: expected an (N, 3) array of points, got shape {p.shape}")
    return p


def as_pixels(uv: np.ndarray, what: str = "uv") -> np.ndarray:
    """A new float (N, 2) array from ``uv``; a single (2,) pixel becomes (1, 2)."""
    p = np.array(uv, dtype=float)
    if p.ndim == 1 and p.shape[0] == 2:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 2:
        raise InputError(f"{what}: expected an (N, 2) array of pixels, got shape {p.shape}")
    return p


def intrinsics_from_camera_matrix(camera_matrix: np.ndarray, model: str) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of an OpenCV camera matrix K (3, 3) without skew; InputError naming
    ``model`` otherwise."""
    K = np.asarray(camera_matrix, dtype=float)
    if K.shape != (3, 3):
        raise InputError(f"{model} camera: camera matrix must be 3x3, got {K.shape}")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0) or K[1, 0] != 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise InputError(
            f"{model} camera: camera matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}"
        )
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


@dataclass(frozen=True, eq=False, repr=False)
class CameraModel(ABC):
    """An intrinsic camera model: image size [px] and a parameter vector ``params`` (P,).

    ``params`` layout is named by ``param_names`` (class attribute); ``name`` is a short stable
    identifier of the model (``"pinhole"``, ``"radtan"``, ...).
    """

    width: int
    height: int
    params: np.ndarray

    name: ClassVar[str] = ""
    param_names: ClassVar[tuple[str, ...]] = ()

    # ------------------------------------------------------------------ construction
    def __post_init__(self) -> None:
        for field_name in ("width", "height"):
            v = getattr(self, field_name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) <= 0:
                raise InputError(
                    f"{self.name} camera: {field_name} must be a positive integer [px], got {v!r}"
                )
            object.__setattr__(self, field_name, int(v))
        p = np.array(self.params, dtype=float).reshape(-1)
        if p.shape != (len(self.param_names),):
            raise InputError(
                f"{self.name} camera: expected {len(self.param_names)} parameters "
                f"({', '.join(self.param_names)}), got {p.size}"
            )
        if not np.all(np.isfinite(p)):
            bad = [n for n, x in zip(self.param_names, p) if not math.isfinite(x)]
            raise InputError(f"{self.name} camera: parameters must be finite, got {bad} non-finite")
        # a finite but absurd value (1e308 px) is a unit mistake or an attack: it overflows every
        # projection and stalls the solvers; see rigcal.io.limits.MAX_ABS
        from rigcal.io.limits import MAX_ABS

        for field_name in ("width", "height"):
            if getattr(self, field_name) > MAX_ABS["px"]:
                raise InputError(
                    f"{self.name} camera: {field_name} is {getattr(self, field_name)}, expected at "
                    f"most {MAX_ABS['px']:g} px"
                )
        big = [n for n, x in zip(self.param_names, p) if abs(x) > MAX_ABS["px"]]
        if big:
            raise InputError(
                f"{self.name} camera: parameters {big} are beyond ±{MAX_ABS['px']:g}, expected "
                "pixels (fx fy cx cy) and distortion coefficients of ordinary size"
            )
        p.setflags(write=False)
        object.__setattr__(self, "params", p)
        self._check_params()

    def _check_params(self) -> None:
        """Validation of ``self.params`` (raise InputError): focal lengths > 0 here; models
        with more constraints extend it."""
        fx, fy = self.params[0], self.params[1]
        if fx <= 0 or fy <= 0:
            raise InputError(f"{self.name} camera: fx and fy must be > 0 [px], got {fx}, {fy}")

    @property
    def camera_matrix(self) -> np.ndarray:
        """(3, 3) the linear part ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (OpenCV's K)."""
        fx, fy, cx, cy = self.params[:4]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def with_params(self, params: np.ndarray) -> "CameraModel":
        """A new model of the same kind and size with ``params`` (P,); ``self`` is unchanged."""
        return replace(self, params=np.array(params, dtype=float))

    @property
    def num_params(self) -> int:
        return len(self.param_names)

    @property
    def size_wh(self) -> tuple[int, int]:
        return self.width, self.height

    def param(self, name: str) -> float:
        """One parameter by name (e.g. ``camera.param("fx")``)."""
        try:
            return float(self.params[self.param_names.index(name)])
        except ValueError:
            raise InputError(
                f"{self.name} camera has no parameter '{name}' (has {list(self.param_names)})"
            ) from None

    # ------------------------------------------------------------------ value semantics
    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        assert isinstance(other, CameraModel)
        return self.size_wh == other.size_wh and np.array_equal(self.params, other.params)

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.width, self.height, self.params.tobytes()))

    def __repr__(self) -> str:
        ps = ", ".join(f"{n}={x:.6g}" for n, x in zip(self.param_names, self.params))
        return f"{type(self).__name__}({self.width}x{self.height}, {ps})"

    # ------------------------------------------------------------------ public interface
    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(N,) bool: pixels (N, 2) inside the image (``-0.5 <= u < width - 0.5``, same for v)."""
        p = as_pixels(uv)
        with np.errstate(invalid="ignore"):
            return (
                np.isfinite(p).all(axis=1)
                & (p[:, 0] >= -0.5)
                & (p[:, 0] < self.width - 0.5)
                & (p[:, 1] >= -0.5)
                & (p[:, 1] < self.height - 0.5)
            )

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of points (N, 3) in the camera optical frame [m].

        Returns ``(uv, valid)``: ``uv`` (N, 2) [px] (NaN where the model is undefined) and
        ``valid`` (N,) bool - False behind the camera, outside the model's domain or outside the
        image. Never raises for such points.
        """
        p = as_points(points_cam)
        domain = np.isfinite(p).all(axis=1) & self._in_domain(p)
        uv = np.full((p.shape[0], 2), np.nan)
        if np.any(domain):
            uv[domain] = self._project(p[domain])
        valid = domain & self.in_image(uv)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera optical frame of pixels (N, 2) [px].

        Pixels the model cannot invert (non-finite, outside the model's one-to-one domain, or
        where an iterative inversion does not converge) give NaN rows; pixels outside the image
        are still unprojected when the model allows it.
        """
        p = as_pixels(uv)
        rays = np.full((p.shape[0], 3), np.nan)
        ok = np.isfinite(p).all(axis=1)
        if np.any(ok):
            rays[ok] = self._unproject(p[ok])
        norm = np.linalg.norm(rays, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return rays / norm

    def project_jacobian(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 2, 3) derivative of the pixel (u, v) with respect to the point (x, y, z).

        Rows of points outside the model's domain are NaN.
        """
        p = as_points(points_cam)
        J = np.full((p.shape[0], 2, 3), np.nan)
        ok = np.isfinite(p).all(axis=1) & self._in_domain(p)
        if np.any(ok):
            J[ok] = self._project_jacobian(p[ok])
        return J

    def params_jacobian(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 2, P) derivative of the pixel (u, v) with respect to ``params``.

        Rows of points outside the model's domain are NaN.
        """
        p = as_points(points_cam)
        J = np.full((p.shape[0], 2, self.num_params), np.nan)
        ok = np.isfinite(p).all(axis=1) & self._in_domain(p)
        if np.any(ok):
            J[ok] = self._params_jacobian(p[ok])
        return J

    # ------------------------------------------------------------------ model hooks
    def _in_domain(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: where the projection is defined and one-to-one (default ``z > eps``)."""
        return points[:, 2] > MIN_DEPTH_M

    @abstractmethod
    def _project(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) pixels of finite in-domain points (N, 3)."""

    @abstractmethod
    def _project_jacobian(self, points: np.ndarray) -> np.ndarray:
        """(N, 2, 3) d(uv)/d(point) at finite in-domain points."""

    @abstractmethod
    def _params_jacobian(self, points: np.ndarray) -> np.ndarray:
        """(N, 2, P) d(uv)/d(params) at finite in-domain points."""

    @abstractmethod
    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        """(N, 3) rays (any positive length, NaN where not invertible) of finite pixels (N, 2)."""
