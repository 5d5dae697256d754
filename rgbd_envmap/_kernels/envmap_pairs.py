"""Kernels of the colour pairs and frame samples (:mod:`rgbd_envmap.envmap.pairs`), called from that module only.

What the pairs are is written plainly in :func:`rgbd_envmap.reference.envmap.pairs_reference`; the
tests compare the kernels with it, and the fused frame passes with the separate calls, bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from rgbd_envmap._kernels.envmap_common import _BLOCK, _mn, _mx, _u, block_coords
from rgbd_envmap._kernels.intrinsics import PRANGE_ONLY, prefetch

__all__ = ["pairs_kernel", "frame_pairs_kernel", "frame_pair_sums_kernel", "world_points", "frame_samples_kernel"]


@numba.njit(cache=True, inline="always")
def _pairs_block(points, start, m, colours, cstart, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                 bx, by, bz, bv, bu, br, bi):  # pragma: no cover - compiled
    """The pairs of points[start : start + m] (colours from row cstart on) appended to src / dst
    from row k on; returns the new count."""
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    hw = height * width
    pf, df, vf = planes.reshape(3, hw), depth.reshape(hw), valid.reshape(hw)
    # int64 start and count: _pairs_block is inlined where they are literal zeros, and numba compiled
    # block_coords once more per literal.
    block_coords(points, np.int64(start), np.int64(m), origin[0], origin[1], origin[2], row_px, col_px,
                  bx, by, bz, bv, bu, br)
    # In stages over the block: the map pixels of the whole block are requested before any is
    # read, and the colours of the block's pairs before any is used: the frame's region of the
    # 34 MB map is rarely still cached when the next depth frame arrives, and one miss at a time
    # would be half of the pass.
    pix, hits = bi[0], bi[1]
    for j in range(m):
        i = start + j
        # abs(x) < inf: finite, as a compare; an unusable point is marked -1 (looks up pixel 0, dropped).
        usable = ((abs(points[i, 0]) < np.inf) & (abs(points[i, 1]) < np.inf) & (abs(points[i, 2]) < np.inf)
                  & (br[j] > 0.0))
        row = _mn(int(bv[j]), height - 1)
        col = int(bu[j])
        q = row * width + (col - width if col >= width else col)
        q = q if usable else -1
        pix[j] = q
        prefetch(df, q)
        prefetch(vf, q)
    # The pair test without branches (whether a point pairs is as good as random), its hits compacted.
    n_hit = 0
    for j in range(m):
        q = pix[j]
        p = _u(_mx(q, 0))  # row, col ≥ 0 (v, u ≥ 0)
        hit = (q >= 0) & vf[p] & (abs(df[p] - br[j]) <= max_diff)
        hits[n_hit] = j
        n_hit += hit
    for h in range(n_hit):
        p = _u(pix[hits[h]])
        prefetch(pf[0], p)
        prefetch(pf[1], p)
        prefetch(pf[2], p)
    for h in range(n_hit):
        j = hits[h]
        p = _u(pix[j])
        for c in range(3):
            src[_u(k), c] = colours[_u(cstart + j), c]
            dst[_u(k), c] = pf[c, p]
        k += 1
    return k


@numba.njit(cache=True, inline="always")
def _accumulate_pair(colours, i, pf, p, sums, counts, saturation):  # pragma: no cover - compiled
    """Pair (colours[i], map colour p) into the colour fit's normal-equation sums, as
    :func:`rgbd_envmap.colour.ccm_sums` accumulates (src, dst): ``sums`` gets AᵀA (6 upper
    entries), AᵀB (9, row-major) and tr(BᵀB) in float64, ``counts`` the pairs kept, the ones dropped
    as non-finite and as saturated (any src channel ≥ ``saturation``)."""
    a0, a1, a2 = np.float64(colours[i, 0]), np.float64(colours[i, 1]), np.float64(colours[i, 2])
    b0, b1, b2 = np.float64(pf[0, p]), np.float64(pf[1, p]), np.float64(pf[2, p])
    if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
            and math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)):
        counts[1] += 1
    elif a0 >= saturation or a1 >= saturation or a2 >= saturation:
        counts[2] += 1
    else:
        counts[0] += 1
        sums[0] += a0 * a0
        sums[1] += a0 * a1
        sums[2] += a0 * a2
        sums[3] += a1 * a1
        sums[4] += a1 * a2
        sums[5] += a2 * a2
        sums[6] += a0 * b0
        sums[7] += a0 * b1
        sums[8] += a0 * b2
        sums[9] += a1 * b0
        sums[10] += a1 * b1
        sums[11] += a1 * b2
        sums[12] += a2 * b0
        sums[13] += a2 * b1
        sums[14] += a2 * b2
        sums[15] += b0 * b0 + b1 * b1 + b2 * b2


@numba.njit(cache=True)
def pairs_kernel(points, colours, origin, height, width, depth, valid, planes, max_diff, src, dst):  # pragma: no cover - compiled
    """The pairs of :func:`collect_pairs`, written compacted into src / dst; returns their count.
    Map coordinates are computed a block at a time (:func:`block_coords`), so no per-point
    temporaries outlive a block."""
    n = points.shape[0]
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bi = np.empty((2, _BLOCK), np.int64)
    k = 0
    for start in range(0, n, _BLOCK):
        k = _pairs_block(points, start, _mn(_BLOCK, n - start), colours, start, origin, height, width, depth, valid,
                         planes, max_diff, src, dst, k, bx, by, bz, bv, bu, br, bi)
    return k


@numba.njit(cache=True)
def frame_pairs_kernel(depth_img, mask, rays, rot, trans, rgb, origin, height, width, depth, valid, planes,
                       max_diff):  # pragma: no cover - compiled
    """:func:`collect_pairs` of :func:`frame_points` of the ``mask`` pixels with colours
    ``rgb[mask]``, without either array: the points are unprojected a block at a time into a
    buffer that :func:`_pairs_block` reads as it reads an (N, 3) array, so the pairs are the same.
    Returns (src, dst)."""
    n = np.count_nonzero(mask)
    src, dst = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    k = _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, 0, depth_img.shape[0], origin, height, width, depth,
                          valid, planes, max_diff, src, dst)
    return src[:k], dst[:k]


@numba.njit(cache=True)
def _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, r0, r1, origin, height, width, depth, valid, planes,
                      max_diff, src, dst):  # pragma: no cover - compiled
    """:func:`frame_pairs_kernel`'s pass over frame rows ``r0`` to ``r1`` − 1: the pairs stored
    into ``src`` / ``dst``. Returns their count."""
    w = depth_img.shape[1]
    pts, col = np.empty((_BLOCK, 3)), np.empty((_BLOCK, 3), np.float32)
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bi = np.empty((2, _BLOCK), np.int64)
    k, m = 0, 0
    for r in range(r0, r1):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth_img, rays, rot, trans, r, c, pts, m)
                col[m, 0], col[m, 1], col[m, 2] = rgb[r, c, 0], rgb[r, c, 1], rgb[r, c, 2]
                m += 1
                if m == _BLOCK:
                    k = _pairs_block(pts, 0, m, col, 0, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                                     bx, by, bz, bv, bu, br, bi)
                    m = 0
    return _pairs_block(pts, 0, m, col, 0, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                        bx, by, bz, bv, bu, br, bi)


@numba.njit(cache=True, parallel=PRANGE_ONLY)
def frame_pair_sums_kernel(depth_img, mask, rays, rot, trans, rgb, origin, height, width, depth, valid, planes,
                        max_diff, sums, counts, saturation):  # pragma: no cover - compiled
    """The pairs of :func:`frame_pairs_kernel` reduced to the colour fit's normal-equation sums
    (:func:`_accumulate_pair`), on up to two threads with the same sums bit for bit: the frame's
    rows split where about half the ``mask`` pixels lie above, each part's pairs found and stored
    at the same time, then accumulated in pair order (the first part's, then the second's).
    Returns the count of pairs."""
    h = depth_img.shape[0]
    per_row = np.zeros(h + 1, np.int64)
    for r in range(h):
        per_row[r + 1] = per_row[r] + np.count_nonzero(mask[r])
    split = 0
    while split < h and 2 * per_row[split + 1] <= per_row[h]:
        split += 1
    src = np.empty((per_row[h], 3), np.float32)
    dst = np.empty((per_row[h], 3), np.float32)
    found = np.zeros(2, np.int64)
    for t in numba.prange(2):
        lo, hi = (0, split) if t == 0 else (split, h)
        at = per_row[lo]  # the part's pairs from its first mask pixel's slot on
        found[t] = _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, lo, hi, origin, height, width, depth,
                                     valid, planes, max_diff, src[at:per_row[hi]], dst[at:per_row[hi]])
    pf = dst.T
    for t in range(2):
        at = 0 if t == 0 else per_row[split]
        for j in range(at, at + found[t]):
            _accumulate_pair(src, j, pf, j, sums, counts, saturation)
    return found[0] + found[1]



@numba.njit(cache=True, inline="always")
def _world_point(depth, rays, rot, trans, r, c, out, k):  # pragma: no cover - compiled
    """out[k] = the world point of pixel (r, c) of a z-depth image (callers are not fastmath, so
    every caller computes the same bits)."""
    z = depth[r, c]
    x, y = rays[r, c, 0] * z, rays[r, c, 1] * z
    for j in range(3):
        out[k, j] = rot[j, 0] * x + rot[j, 1] * y + rot[j, 2] * z + trans[j]


@numba.njit(cache=True)
def world_points(depth, mask, rays, rot, trans):  # pragma: no cover - compiled
    h, w = depth.shape
    out = np.empty((np.count_nonzero(mask), 3))
    k = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth, rays, rot, trans, r, c, out, k)
                k += 1
    return out


@numba.njit(cache=True)
def frame_samples_kernel(depth, mask, rays, rot, trans, rgb, flag, matrix, correct):  # pragma: no cover - compiled
    """:func:`frame_points` of the ``mask`` pixels with their (M, 3) float32 colours (times the
    float32 ``matrix``ᵀ when ``correct``) and (M,) bool ``flag`` (uint8 image) in one pass, instead
    of numpy's boolean gathers."""
    h, w = depth.shape
    n = np.count_nonzero(mask)
    pts, col, out_flag = np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty(n, np.bool_)
    k = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth, rays, rot, trans, r, c, pts, k)
                x, y, z = rgb[r, c, 0], rgb[r, c, 1], rgb[r, c, 2]
                if correct:
                    for j in range(3):
                        col[k, j] = matrix[j, 0] * x + matrix[j, 1] * y + matrix[j, 2] * z
                else:
                    col[k, 0], col[k, 1], col[k, 2] = x, y, z
                out_flag[k] = flag[r, c] != 0
                k += 1
    return pts, col, out_flag

