"""Reference of compositing (:func:`rgbd_envmap.render.composite`): the layer drawn over the frame,
written out with whole-image numpy operations.

Per pixel of the frame (8-bit sRGB) and of the rendered :class:`~rgbd_envmap.render.Layer`:

- where the object is (``layer.mask``): its colour c (reference colour space, linear) is mapped
  into the frame's colour space by the inverse correction matrix M (``M @ c``; none: c itself),
  then encoded to 8-bit sRGB;
- elsewhere, where the shadow plane has alpha a > 0: the frame is decoded to linear light and
  blended towards the plane's grey, ``(1 − a) · frame + a · (M @ (g, g, g))``, then encoded again;
- everywhere else the frame is unchanged.

Encoding clips to [0, 1] and rounds half up: code = ⌊255 · srgb(x) + ½⌋ in float64, NaN → 0
(IEC 61966-2-1). Decoding is the library's 8-bit lookup table
(:func:`rgbd_envmap.colour.srgb8_to_linear_lut`). The library's composite gives the same codes bit
for bit.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.colour import srgb8_to_linear_lut
from rgbd_envmap.render.layer import Layer

__all__ = ["composite", "decode_srgb8", "encode_srgb8"]


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear values → 8-bit sRGB codes (uint8): clipped to [0, 1] (NaN → 0), then
    ⌊255 · srgb(x) + ½⌋ with the sRGB transfer function evaluated in float64."""
    x = np.asarray(linear, np.float64)
    x = np.clip(np.where(np.isnan(x), 0.0, x), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.floor(255.0 * s + 0.5).astype(np.uint8)


def decode_srgb8(codes: np.ndarray) -> np.ndarray:
    """8-bit sRGB codes → linear values (float64), the sRGB transfer function in float64 (the
    library's lookup table holds these values rounded to float32)."""
    s = np.asarray(codes, np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def composite(frame_srgb: np.ndarray, layer: Layer, *, ccm_inverse: np.ndarray | None = None,
              shadow_grey: float = 0.15) -> np.ndarray:
    """The (H, W, 3) uint8 frame with the layer drawn over it (see the module docstring)."""
    out = np.array(frame_srgb, np.uint8, copy=True)
    m = np.eye(3) if ccm_inverse is None else np.asarray(ccm_inverse, np.float64)
    grey = m @ np.full(3, float(shadow_grey))
    obj = layer.mask
    c = layer.colour[obj].astype(np.float64)  # (n, 3)
    if ccm_inverse is None:
        out[obj] = encode_srgb8(c)
    else:
        mapped = [m[k, 0] * c[:, 0] + m[k, 1] * c[:, 1] + m[k, 2] * c[:, 2] for k in range(3)]
        out[obj] = encode_srgb8(np.stack(mapped, axis=1))
    plane = ~obj & (layer.plane_alpha > 0)
    a = layer.plane_alpha[plane].astype(np.float64)[:, None]
    frame_linear = srgb8_to_linear_lut()[out[plane]].astype(np.float64)  # (n, 3)
    out[plane] = encode_srgb8((1.0 - a) * frame_linear + a * grey)
    return out
