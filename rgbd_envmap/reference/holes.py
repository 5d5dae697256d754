"""References of hole filling (:mod:`rgbd_envmap.depth.holes`): eq. (1) of paper 003, one pixel and one
direction at a time.

- :func:`eq1_reference`: eq. (1) as the paper states it, marching outward from every unknown pixel;
- :func:`eq1_kernel_order_reference`: the same march with the kernel's float64 order of operations,
  which the kernel matches bit for bit;
- :func:`source_range_reference`: the smallest and largest depth among each pixel's sources of
  non-zero weight, what ``max_source_ratio`` tests.

Eq. (1): for an unknown pixel, walk the 8 rays of pixels (4 axis-aligned, 4 diagonal) to the nearest
*originally* known pixel in each direction (filled pixels never serve as sources); x_r is its
Euclidean pixel distance (k steps → k on an axis, k·√2 on a diagonal); its weight is
w_n = max(0, (w − x_r) / w) with w the frame **width** in pixels; the depth is
d = Σ w_n d_n / Σ w_n, and the pixel stays unknown when every weight is 0.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DIRECTIONS", "eq1_reference", "eq1_kernel_order_reference", "source_range_reference"]

#: The 8 ray directions (dy, dx).
DIRECTIONS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def eq1_reference(depth: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1) of paper 003, one pixel and one direction at a time, in float64.

    Args:
        depth: (H, W) z-depth; read only where ``known``.
        known: (H, W) bool.

    Returns:
        (filled depth (H, W) float64, 0 where still unknown; known_after (H, W) bool).
    """
    h, w = depth.shape
    out = np.zeros((h, w), np.float64)
    after = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            if known[y, x]:
                out[y, x] = depth[y, x]
                after[y, x] = True
                continue
            num = den = 0.0
            for dy, dx in DIRECTIONS:
                k = 1
                while 0 <= y + k * dy < h and 0 <= x + k * dx < w:
                    if known[y + k * dy, x + k * dx]:
                        x_r = math.hypot(k * dy, k * dx)  # Euclidean distance in pixels
                        w_n = max(0.0, (w - x_r) / w)
                        num += w_n * float(depth[y + k * dy, x + k * dx])
                        den += w_n
                        break  # only the nearest known pixel of this direction
                    k += 1
            if den > 0.0:
                out[y, x] = num / den
                after[y, x] = True
    return out, after


def eq1_kernel_order_reference(depth: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Eq. (1) once more, marching as :func:`eq1_reference` does, but with the kernel's float64
    arithmetic in the kernel's order: weights max(0, (w − k·s) · (1/w)) from the step count k (capped
    at w) with s = 1 or √2; sums up, up-left, up-right, then down, down-left, down-right, left,
    right; the quotient rounded once to float32. :func:`rgbd_envmap.depth.fill_holes` ("monroy2018")
    equals this bit for bit.

    Returns:
        (H, W) float32 filled depth, 0 where still unknown.
    """
    h, w = depth.shape
    wf, inv_w, s2 = float(w), 1.0 / float(w), math.sqrt(2.0)
    out = np.zeros((h, w), np.float32)

    def ray(y, x, dy, dx, scale):
        k = 1
        while 0 <= y + k * dy < h and 0 <= x + k * dx < w:
            if known[y + k * dy, x + k * dx]:
                kk = min(k, w)
                return max(0.0, (wf - kk * scale) * inv_w), float(depth[y + k * dy, x + k * dx])
            k += 1
        return max(0.0, (wf - wf * scale) * inv_w), 0.0  # no source: weight 0

    for y in range(h):
        for x in range(w):
            if known[y, x]:
                out[y, x] = depth[y, x]
                continue
            (wa, da), (wb, db), (wc, dc) = ray(y, x, -1, 0, 1.0), ray(y, x, -1, -1, s2), ray(y, x, -1, 1, s2)
            num_up, den_up = wa * da + wb * db + wc * dc, wa + wb + wc
            (wa, da), (wb, db), (wc, dc) = ray(y, x, 1, 0, 1.0), ray(y, x, 1, -1, s2), ray(y, x, 1, 1, s2)
            num, den = wa * da + wb * db + wc * dc, wa + wb + wc
            for dx in (-1, 1):
                wt, d = ray(y, x, 0, dx, 1.0)
                num += wt * d
                den += wt
            if den + den_up > 0.0:
                out[y, x] = np.float32((num + num_up) / (den + den_up))
    return out


def source_range_reference(depth: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the smallest and largest depth among the eq. (1) sources of non-zero weight
    (inf / 0 where there is none), marching each of the 8 rays as :func:`eq1_reference` does. A hole
    whose range has max / min above ``max_source_ratio`` is one that option leaves unknown (and
    :func:`rgbd_envmap.depth.fill_holes_flagged` flags)."""
    h, w = depth.shape
    lo, hi = np.full((h, w), np.inf), np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            for dy, dx in DIRECTIONS:
                k = 1
                while 0 <= y + k * dy < h and 0 <= x + k * dx < w:
                    if known[y + k * dy, x + k * dx]:
                        if math.hypot(k * dy, k * dx) < w:
                            d = float(depth[y + k * dy, x + k * dx])
                            lo[y, x], hi[y, x] = min(lo[y, x], d), max(hi[y, x], d)
                        break
                    k += 1
    return lo, hi
