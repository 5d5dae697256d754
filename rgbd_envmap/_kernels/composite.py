"""Kernels of compositing: the exact 8-bit sRGB encoder and the per-pixel composite.

Called from :mod:`rgbd_envmap.render.composite` only; what they compute, in plain numpy:
:mod:`rgbd_envmap.reference.render_composite`.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["ENCODE_BINS", "encode8", "composite"]

#: Bins of the sRGB encoder's lookup table over [0, 1]; fine enough that no bin holds two code steps.
ENCODE_BINS = 4096


@numba.njit(cache=True, inline="always")
def encode8(x, thresholds, base):  # pragma: no cover - compiled
    """Linear value → 8-bit sRGB code, clipping to [0, 1] (NaN → 0)."""
    if not x > 0.0:
        return 0
    if x >= 1.0:
        return 255
    k = np.int64(base[np.int64(x * ENCODE_BINS)])
    if x >= thresholds[k]:
        k += 1
    return k


@numba.njit(cache=True)
def composite(out, colour, mask, alpha, r0, r1, c0, c1, m, use_m, grey, lut, thresholds, base):  # pragma: no cover
    """In place on ``out`` (H, W, 3) uint8 within the bbox: object pixels ← encode(M · colour); plane
    pixels ← encode((1 − α) · decode(out) + α · grey), in linear light."""
    for r in range(r0, r1):
        orow = out[r]
        mrow = mask[r]
        arow = alpha[r]
        crow = colour[r]
        for c in range(c0, c1):
            if mrow[c]:
                cr = np.float64(crow[c, 0])
                cg = np.float64(crow[c, 1])
                cb = np.float64(crow[c, 2])
                if use_m:
                    for k in range(3):
                        orow[c, k] = encode8(m[k, 0] * cr + m[k, 1] * cg + m[k, 2] * cb, thresholds, base)
                else:
                    orow[c, 0] = encode8(cr, thresholds, base)
                    orow[c, 1] = encode8(cg, thresholds, base)
                    orow[c, 2] = encode8(cb, thresholds, base)
            else:
                a = np.float64(arow[c])
                if a > 0.0:
                    b = 1.0 - a
                    for k in range(3):
                        orow[c, k] = encode8(b * lut[orow[c, k]] + a * grey[k], thresholds, base)

