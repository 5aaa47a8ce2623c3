"""Image bytes <-> pixels, shared by folder recordings and bags."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.recordings.images import decode_image_bytes, encode_png


def test_image_errors():
    import cv2

    with pytest.raises(InputError, match="img: empty image data"):
        decode_image_bytes(b"", "img")
    with pytest.raises(InputError, match=r"img: cannot decode image \(not a PNG or JPEG\?\)"):
        decode_image_bytes(b"\x89PNG garbage", "img")
    ok, buf = cv2.imencode(".png", np.zeros((3, 3), np.uint16))
    with pytest.raises(InputError, match="img: image has uint16 pixels, expected 8-bit"):
        decode_image_bytes(buf.tobytes(), "img")


@pytest.mark.parametrize("shape", [(4, 5), (4, 5, 3)])
def test_png_round_trip(shape):
    img = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    np.testing.assert_array_equal(decode_image_bytes(encode_png(img, "img"), "img"), img)
