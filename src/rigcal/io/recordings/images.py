"""Image files as bytes <-> pixels: the one place recordings decode and encode PNG/JPEG.

Folder recordings (``.png``/``.jpg`` files) and bags (``sensor_msgs/CompressedImage``) both go
through here, so an image reads the same whichever recording it came from. Pixels are uint8,
(H, W) mono or (H, W, 3) BGR, as in :class:`rigcal.recording.ImageFrame`.
"""

from __future__ import annotations

import numpy as np

from rigcal.errors import InputError

__all__ = ["IMAGE_SUFFIXES", "decode_image_bytes", "encode_png"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""File suffixes read as images."""


def decode_image_bytes(data: bytes | bytearray | memoryview, source: str) -> np.ndarray:
    """A PNG/JPEG (any format OpenCV reads) as uint8 (H, W) mono or (H, W, 3) BGR; alpha is
    dropped. 16-bit or undecodable images raise InputError naming ``source``."""
    import cv2

    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size == 0:
        raise InputError(f"{source}: empty image data")
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{source}: cannot decode image (not a PNG or JPEG?)")
    if img.dtype != np.uint8:
        raise InputError(f"{source}: image has {img.dtype} pixels, expected 8-bit")
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] == 4:
            img = img[:, :, :3]
        elif img.shape[2] != 3:
            raise InputError(f"{source}: image has {img.shape[2]} channels, expected 1, 3 or 4")
    return np.ascontiguousarray(img)


def encode_png(image: np.ndarray, source: str) -> bytes:
    """``image`` (uint8 mono or BGR) as PNG bytes; InputError naming ``source`` if OpenCV
    cannot encode it."""
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise InputError(f"{source}: cannot PNG-encode the image")
    return buf.tobytes()
