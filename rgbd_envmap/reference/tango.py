"""Reference of the Tango ingest (:mod:`rgbd_envmap.ingest.tango`): the point cloud → RGB-D frame as one
plain per-point loop.

:func:`rgbd_frame_reference` does, point by point, what the kernels do in SIMD passes:

1. a point with confidence ≥ the threshold (in float64), finite and in front of the depth sensor goes
   through the sensor's Brown distortion and intrinsics to its nearest pixel (``floor(u + 0.5)``);
   the closest z wins a pixel, the earlier point a tie;
2. each winning point goes to the colour camera (``rot``, ``trans``: T_colour_from_depth), through its
   distortion and intrinsics, and takes the bilinear interpolation of the four surrounding texels
   *after* sRGB decoding (:func:`rgbd_envmap.colour.srgb8_to_linear_lut`, widened to float64); the 2×2
   starts at min(⌊u⌋, width − 2), so it stays inside the image; a point outside [0, width − 1] ×
   [0, height − 1] gets no colour and its pixel is not known.

The arithmetic is written with numpy scalars in the kernels' precision (float32 where they keep
float32, float64 where they widen), so the kernels' results equal these bit for bit.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.colour import srgb8_to_linear_lut
from rgbd_envmap.types import Intrinsics

__all__ = ["distort_point", "rgbd_frame_reference"]

_F64 = np.float64


def distort_point(x, y, dist) -> tuple[np.float64, np.float64]:
    """Brown distortion of one normalised point (x, y) with the kernels' widening: x² + y² in the
    input's precision, the rest in float64. ``dist``: (k1, k2, p1, p2, k3)."""
    k1, k2, p1, p2, k3 = (_F64(c) for c in dist)
    r2 = _F64(x * x + y * y)
    x, y = _F64(x), _F64(y)
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def rgbd_frame_reference(points: np.ndarray, conf: np.ndarray, threshold: float, dintr: Intrinsics, rot: np.ndarray,
                         trans: np.ndarray, cintr: Intrinsics, srgb8: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-point loop: nearest depth pixel, closest z wins (first on a tie), bilinear linear colour.

    Args:
        points: (N, 3) float32 depth-frame points; conf: (N,) confidences; threshold: the confidence
            threshold; dintr / cintr: the depth and colour cameras; rot, trans: T_colour_from_depth's
            (3, 3) rotation and (3,) translation (float64); srgb8: (H_c, W_c, 3) uint8 colour image.

    Returns:
        (depth (H, W) float32, 0 where no point won; index of the winning point (H, W) int32, −1 where
        none; rgb (H, W, 3) float32 linear colour; known (H, W) bool, the pixels that got a colour).
    """
    lut = srgb8_to_linear_lut().astype(np.float64)
    h, w = dintr.height, dintr.width
    depth = np.zeros((h, w), np.float32)
    index = np.full((h, w), -1, np.int32)
    for i, (x, y, z) in enumerate(points):
        if not _F64(conf[i]) >= threshold or not (z > 0 and np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        xd, yd = distort_point(x / z, y / z, dintr.distortion.coefficients)
        col, row = np.floor(dintr.fx * xd + dintr.cx + 0.5), np.floor(dintr.fy * yd + dintr.cy + 0.5)
        if not (0 <= col < w and 0 <= row < h):
            continue
        col, row = int(col), int(row)
        if index[row, col] < 0 or z < depth[row, col]:
            depth[row, col], index[row, col] = z, i
    ch, cw = cintr.height, cintr.width
    rgb = np.zeros((h, w, 3), np.float32)
    known = np.zeros((h, w), bool)
    for row, col in zip(*np.nonzero(index >= 0)):
        px, py, pz = (_F64(v) for v in points[index[row, col]])
        x, y, z = (rot[j, 0] * px + rot[j, 1] * py + rot[j, 2] * pz + trans[j] for j in range(3))
        if not (z > 0 and np.isfinite(x) and np.isfinite(y)):
            continue
        xd, yd = distort_point(x / z, y / z, cintr.distortion.coefficients)
        u, v = cintr.fx * xd + cintr.cx, cintr.fy * yd + cintr.cy
        if not (0 <= u <= cw - 1 and 0 <= v <= ch - 1):
            continue
        u0, v0 = min(int(u), max(cw - 2, 0)), min(int(v), max(ch - 2, 0))
        u1, v1 = min(u0 + 1, cw - 1), min(v0 + 1, ch - 1)
        au, av = u - u0, v - v0
        for c in range(3):
            top = (1.0 - au) * lut[srgb8[v0, u0, c]] + au * lut[srgb8[v0, u1, c]]
            bottom = (1.0 - au) * lut[srgb8[v1, u0, c]] + au * lut[srgb8[v1, u1, c]]
            rgb[row, col, c] = np.float32((1.0 - av) * top + av * bottom)
        known[row, col] = True
    return depth, index, rgb, known
