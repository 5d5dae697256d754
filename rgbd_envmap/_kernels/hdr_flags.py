"""Kernel of HDR capture's clip flags (:mod:`rgbd_envmap.colour.hdr`), called from that module only.

What it computes is written plainly in :func:`rgbd_envmap.reference.colour.low_confidence_reference`;
the tests compare the two exactly. One pass over the pixels: numpy's ``(rgb > level).any(axis=-1)``
(and the bracket's dark test beside it) reduced a length-3 axis with a generic loop, about 0.6 ms
for a 224 × 172 frame, each of the two times a depth frame asks.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["low_confidence_kernel"]


@numba.njit(cache=True, nogil=True)
def low_confidence_kernel(rgb, level, dark, use_dark, out):  # pragma: no cover - compiled
    """``out[r, c]`` = any channel of ``rgb[r, c]`` > ``level`` or, when ``use_dark``, no channel ≥
    ``dark`` (NaN compares false: a NaN channel neither clips nor is bright, as numpy's comparisons).
    ``rgb`` (H, W, 3) float32 or float64, ``level`` and ``dark`` of its dtype."""
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            a, b, d = rgb[r, c, 0], rgb[r, c, 1], rgb[r, c, 2]
            flag = (a > level) | (b > level) | (d > level)
            if use_dark:
                flag |= not ((a >= dark) | (b >= dark) | (d >= dark))
            out[r, c] = flag
