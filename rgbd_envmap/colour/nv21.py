"""Colour at the sensor boundary: NV21 decoding and encoding, and the sRGB transfer functions.

Inside the pipeline colour is linear RGB float32; sRGB-encoded 8-bit only at the sensor (NV21 / PNG).
:func:`srgb8_to_linear_lut` decodes 8-bit images by table lookup, exactly.

References:
    IEC 61966-2-1:1999, Multimedia systems – Colour measurement – Default RGB colour space – sRGB.
    Android ``ImageFormat.NV21``: Y plane followed by interleaved V/U at half resolution (ITU-R BT.601,
    decoded here with OpenCV's ``COLOR_YUV2RGB_NV21``; :mod:`rgbd_envmap.reference.colour` writes out
    the BT.601 formula it approximates).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from rgbd_envmap.checks import check_array, check_positive_int
from rgbd_envmap.errors import InvalidInputError, ShapeError

__all__ = ["decode_nv21", "encode_nv21", "srgb_to_linear", "linear_to_srgb", "srgb8_to_linear_lut"]


def decode_nv21(nv21: np.ndarray, height: int, width: int) -> np.ndarray:
    """Decode an NV21 buffer of shape (H * 3 // 2, W) uint8 (or the same bytes flat) into (H, W, 3)
    uint8 sRGB-encoded RGB."""
    height = check_positive_int(height, "height")
    width = check_positive_int(width, "width")
    if height % 2 or width % 2:
        raise InvalidInputError(f"decode_nv21: height and width must be even, got {height}×{width}")
    buf = check_array(nv21, "nv21", dtype=np.uint8)
    expected = height * 3 // 2 * width
    if buf.shape not in ((expected,), (height * 3 // 2, width)):
        raise ShapeError(
            f"nv21: expected shape ({height * 3 // 2}, {width}) or ({expected},) for {height}×{width}, got {buf.shape}"
        )
    return cv2.cvtColor(np.ascontiguousarray(buf.reshape(height * 3 // 2, width)), cv2.COLOR_YUV2RGB_NV21)


def encode_nv21(rgb: np.ndarray) -> np.ndarray:
    """Encode (H, W, 3) uint8 sRGB into an NV21 buffer (H * 3 // 2, W) uint8, the inverse of
    :func:`decode_nv21` up to 4:2:0 chroma subsampling and rounding. OpenCV has no RGB→NV21 encoder,
    so this encodes I420 and interleaves V and U."""
    rgb = check_array(rgb, "rgb", shape=("H", "W", 3), dtype=np.uint8)
    h, w = rgb.shape[:2]
    if h % 2 or w % 2 or h == 0 or w == 0:
        raise InvalidInputError(f"encode_nv21: height and width must be even and > 0, got {h}×{w}")
    i420 = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YUV_I420).reshape(-1)
    y_size, c_size = h * w, (h // 2) * (w // 2)
    out = np.empty(h * 3 // 2 * w, dtype=np.uint8)
    out[:y_size] = i420[:y_size]
    out[y_size::2] = i420[y_size + c_size:]  # V
    out[y_size + 1::2] = i420[y_size:y_size + c_size]  # U
    return out.reshape(h * 3 // 2, w)


@lru_cache(maxsize=1)
def _srgb8_lut() -> np.ndarray:
    lut = srgb_to_linear(np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)
    lut.setflags(write=False)
    return lut


def srgb8_to_linear_lut() -> np.ndarray:
    """(256,) float32 linear value of each 8-bit sRGB code (read-only, cached); ``lut[img]`` decodes
    an image exactly and several times faster than evaluating the transfer function."""
    return _srgb8_lut()


def srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    """sRGB EOTF (IEC 61966-2-1): encoded values in [0, 1] → linear, float32 (float64 stays float64).

    Values outside [0, 1] are clipped first; NaN stays NaN. Integer and bool input is taken as float32;
    complex input and anything not numeric raise :class:`~rgbd_envmap.errors.DTypeError`.
    """
    x = check_array(rgb, "rgb", dtype=("float", "int", "bool"))
    x = np.clip(x.astype(np.float32) if x.dtype.kind != "f" else x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(x.dtype, copy=False)


def linear_to_srgb(rgb: np.ndarray) -> np.ndarray:
    """Inverse sRGB EOTF: linear values (clipped to [0, 1]) → encoded values in [0, 1], float32
    (float64 stays float64). NaN stays NaN; the dtype policy is :func:`srgb_to_linear`'s."""
    x = check_array(rgb, "rgb", dtype=("float", "int", "bool"))
    x = np.clip(x.astype(np.float32) if x.dtype.kind != "f" else x, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(x.dtype, copy=False)
