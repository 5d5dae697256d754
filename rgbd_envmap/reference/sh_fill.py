"""Reference of the SH stage's missing-pixel fill (:func:`rgbd_envmap.sh.fill_missing`,
:func:`rgbd_envmap.sh.fill_plan`): the rule written out, one pixel at a time.

The rule (paper 003 §7.1; docs/design/overview.md, stage 8): a pixel without data (``valid`` False)
takes the radiance of the closest data pixel along the four directions up, down, left and right,
at most ``radius_px`` pixels away. Longitude wraps across the seam (column W − 1 is next to column
0); rows do not wrap across the poles. At equal distance the directions rank up, down, left, right.
A pixel with no data pixel within the radius in any of the four directions is not filled (it
contributes nothing to the projection).

Each source is ranked by the key 4 · distance + direction (0 up, 1 down, 2 left, 3 right): the
smaller key wins, which is "closest, then up, down, left, right". The fill plan stores these keys,
and :class:`~rgbd_envmap.sh.IncrementalProjection` keeps one per pixel.

- :func:`fill_source`: the source and key of one pixel;
- :func:`fill_sources`: both for every pixel, as the fill plan states them;
- :func:`fill_missing`: the filled map, pixel by pixel;
- :func:`fill_missing_by_distance`: the same map, vectorised one distance at a time (fast enough
  for full-size maps).
"""

from __future__ import annotations

import numpy as np

__all__ = ["DIRECTIONS", "NO_SOURCE", "fill_missing", "fill_missing_by_distance", "fill_source", "fill_sources"]

#: The four directions (row step, column step) in the order that breaks ties: up, down, left, right.
DIRECTIONS = ((-1, 0), (1, 0), (0, -1), (0, 1))

#: The key of a missing pixel without a source (larger than every key 4 · distance + direction).
NO_SOURCE = np.iinfo(np.int32).max


def fill_source(valid: np.ndarray, v: int, u: int, radius_px: int) -> tuple[tuple[int, int] | None, int]:
    """The data pixel (row, column) that missing pixel (v, u) copies, and its key 4 · distance +
    direction; ``(None, NO_SOURCE)`` when no data pixel lies within ``radius_px`` along the four
    directions."""
    H, W = valid.shape
    best, best_key = None, NO_SOURCE
    for direction, (dv, du) in enumerate(DIRECTIONS):
        for distance in range(1, radius_px + 1):
            vv, uu = v + dv * distance, (u + du * distance) % W  # columns wrap, rows do not
            if not 0 <= vv < H:
                break
            if valid[vv, uu]:
                key = 4 * distance + direction
                if key < best_key:
                    best, best_key = (vv, uu), key
                break  # the closest data pixel along this direction
    return best, best_key


def fill_sources(valid: np.ndarray, radius_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel (row-major, (H W,) int64): the flat index v' W + u' of the source (−2 for a data
    pixel, −1 for a missing pixel without a source) and the key (0 for a data pixel,
    :data:`NO_SOURCE` without a source)."""
    H, W = valid.shape
    src = np.full(H * W, -2, np.int64)
    key = np.zeros(H * W, np.int64)
    for v in range(H):
        for u in range(W):
            if valid[v, u]:
                continue
            best, k = fill_source(valid, v, u, radius_px)
            src[v * W + u] = -1 if best is None else best[0] * W + best[1]
            key[v * W + u] = k
    return src, key


def fill_missing(radiance: np.ndarray, valid: np.ndarray, radius_px: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """The filled map, pixel by pixel: (filled (H, W, 3) float64, used (H, W) bool). A data pixel
    keeps its radiance; a missing pixel copies its source's; one without a source is 0 and not
    ``used``. Values under ``valid = False`` are never read."""
    H, W, _ = radiance.shape
    out = np.zeros_like(radiance, dtype=np.float64)
    used = np.ones((H, W), bool)
    for v in range(H):
        for u in range(W):
            if valid[v, u]:
                out[v, u] = radiance[v, u]
                continue
            best, _ = fill_source(valid, v, u, radius_px)
            if best is None:
                used[v, u] = False
            else:
                out[v, u] = radiance[best]
    return out, used


def fill_missing_by_distance(radiance: np.ndarray, valid: np.ndarray, radius_px: int = 50
                             ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fill_missing` vectorised: for distance 1, 2, …, and within one distance up, down,
    left, right, every pixel not yet filled takes the data pixel found there (rows clipped at the
    poles, columns wrap). Returns (filled (H, W, 3) float32, used (H, W) bool); the filled values
    equal :func:`fill_missing`'s rounded to float32."""
    H, W = valid.shape
    out = np.where(valid[..., None], radiance, 0.0).astype(np.float32)
    found = valid.copy()
    for distance in range(1, radius_px + 1):
        for dv, du in DIRECTIONS:
            src_ok = np.zeros((H, W), bool)
            src_val = np.zeros((H, W, 3), np.float32)
            if dv:
                lo, hi = max(0, -dv * distance), min(H, H - dv * distance)  # rows whose source is on the map
                if lo >= hi:
                    continue
                src_ok[lo:hi] = valid[lo + dv * distance:hi + dv * distance]
                src_val[lo:hi] = radiance[lo + dv * distance:hi + dv * distance]
            else:
                src_ok = np.roll(valid, -du * distance, axis=1)
                src_val = np.roll(radiance, -du * distance, axis=1)
            take = ~found & src_ok
            out[take] = src_val[take]
            found |= take
    return out, found
