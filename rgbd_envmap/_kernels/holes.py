"""Kernels of hole filling (:mod:`rgbd_envmap.depth.holes`), called from that module only.

What :func:`monroy2018_kernel` computes, eq. (1) of paper 003, is written plainly in
:mod:`rgbd_envmap.reference.holes`; the tests compare the two bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["ray", "three_rays", "monroy2018_kernel", "count_known"]


@numba.njit(cache=True, error_model="numpy")
def ray(y, x, ys, dx, flat, w, wf, inv_w, scale):  # pragma: no cover - compiled
    """Weight and depth of one ray's source for the hole (y, x): the nearest known pixel on the ray
    lies in row ``ys``, k = |y − ys| steps away, in column x + dx·k. Weight max(0, (w − k·scale) / w);
    beyond w steps (or with no source, ``ys`` far away) it is 0 by the formula itself, and the depth
    read is the hole's own pixel, replaced by 0 (so the term w·d is +0 exactly). Branch-free."""
    k = abs(y - ys)
    near = k < w
    weight = max(0.0, (wf - float(k) * scale) * inv_w)
    at = (ys * w + x + dx * k) if near else (y * w + x)
    d = np.float64(flat[np.uint64(at)])
    return weight, d if near else 0.0


@numba.njit(cache=True, error_model="numpy")
def three_rays(y, x, src_v, src_l, src_r, flat, w, wf, inv_w, sqrt2):  # pragma: no cover - compiled
    """(Σ w_n d_n, Σ w_n, min d_n, max d_n) over the vertical ray and the diagonal rays towards
    columns x − 1 and x + 1 of one sweep, the extremes over the sources of non-zero weight (inf / 0
    when there is none); ``src_*`` hold the row of each ray's nearest known pixel (the diagonal ones
    as views indexed by x for this row)."""
    # The directions as int64, not literals: numba compiled ray once per literal value.
    wv, dv = ray(y, x, src_v[x], np.int64(0), flat, w, wf, inv_w, 1.0)
    wl, dl = ray(y, x, src_l[x], np.int64(-1), flat, w, wf, inv_w, sqrt2)
    wr, dr = ray(y, x, src_r[x], np.int64(1), flat, w, wf, inv_w, sqrt2)
    lo = min(dv if wv > 0.0 else np.inf, min(dl if wl > 0.0 else np.inf, dr if wr > 0.0 else np.inf))
    hi = max(dv if wv > 0.0 else 0.0, max(dl if wl > 0.0 else 0.0, dr if wr > 0.0 else 0.0))
    return wv * dv + wl * dl + wr * dr, wv + wl + wr, lo, hi


@numba.njit(cache=True, error_model="numpy")
def monroy2018_kernel(depth, known, max_ratio, drop):  # pragma: no cover - compiled
    """(H, W) float32 depth, (H, W) bool known → (H, W) float32 filled, (H, W) bool known_after,
    (H, W) bool across: the holes whose sources of non-zero weight span depths with max / min >
    ``max_ratio`` (``np.inf``: none). With ``drop`` those stay unknown (0.0, not known_after), else
    they are filled like any other hole and only flagged.

    Only the unknown pixels need eq. (1); the known ones only serve as sources. So the image is swept
    twice, top to bottom (sources above: up, up-left, up-right) and bottom to top (sources below),
    keeping per ray the **row of its nearest known pixel** so far: one int32 per column for the
    vertical rays and one per diagonal (x − y or x + y) for the diagonal ones, so a diagonal's state
    sits at one index for the whole sweep. After each row, its known pixels become the sources of
    their column and diagonals (a branch-free select over the row, SIMD). An unknown pixel reads its
    three sources from those states (:func:`three_rays`) and their depths straight from the image.
    Left and right sources come from the row's list of unknown pixels: the left source of a hole is
    x − 1, or, when x − 1 is a hole too, that hole's left source. Cost: O(H·W) selects plus eq. (1)
    per *unknown* pixel, so it does not grow with the size of the holes.

    Weights are max(0, (w − k·s) / w), s = 1 or √2, from the step count k, and the sums of w_n·d_n
    and w_n run in float64 in a fixed order (up, up-left, up-right; down, down-left, down-right,
    left, right: :func:`rgbd_envmap.reference.holes.eq1_kernel_order_reference` pins it bit for bit);
    a ray without a source within w steps adds +0. k·√2 never equals w for integers, so the cut-off
    is exact.
    """
    h, w = depth.shape
    wf = float(w)
    inv_w = 1.0 / wf
    sqrt2 = np.sqrt(2.0)
    out = np.empty((h, w), np.float32)
    after = np.empty((h, w), np.bool_)
    across = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            k = known[y, x]
            out[y, x] = depth[y, x] if k else np.float32(0.0)
            after[y, x] = k
    # The unknown pixels, row by row: holes[start[y]:start[y + 1]] are row y's, by increasing x.
    holes = np.empty(h * w, np.uint32)  # unsigned: no negative-index checks where x indexes
    start = np.empty(h + 1, np.int64)
    n = 0
    for y in range(h):
        start[y] = n
        for x in range(w):
            holes[n] = x  # branch-free compaction: always written, kept only for a hole
            n += 0 if known[y, x] else 1
    start[h] = n
    if n == 0:
        return out, after, across
    flat = depth.reshape(-1)
    num_down = np.empty(n)  # Σ w_n d_n and Σ w_n of the top-to-bottom sweep, per hole
    den_down = np.empty(n)
    lo_down = np.empty(n)  # and the extremes of its sources' depths
    hi_down = np.empty(n)
    right = np.empty(n, np.int64)  # each hole's right source (column), −1: none
    src_v = np.empty(w, np.int32)  # row of the nearest known pixel on each ray
    src_a = np.empty(w + h, np.int32)  # diagonals x − y, at index x − y + h − 1
    src_b = np.empty(w + h, np.int32)  # anti-diagonals x + y
    for sweep in range(2):
        down = sweep == 1
        # "No source": a row at least w steps from every row of the image (weight 0 on every ray).
        none = np.int32(h + w) if down else np.int32(-w)
        src_v[:] = none
        src_a[:] = none
        src_b[:] = none
        for i in range(h):
            y = h - 1 - i if down else i
            first, last = start[y], start[y + 1]
            sa = src_a[h - 1 - y:h - 1 - y + w]  # this row's diagonals, indexed by x
            sb = src_b[y:y + w]
            if not down:  # up-left: diagonal x − y; up-right: x + y
                for j in range(first, last):
                    num_down[j], den_down[j], lo_down[j], hi_down[j] = three_rays(y, holes[j], src_v, sa, sb, flat, w,
                                                                                  wf, inv_w, sqrt2)
            else:  # down-left: anti-diagonal x + y; down-right: x − y; then left and right
                for j in range(last - 1, first - 1, -1):
                    x = holes[j]
                    if x == w - 1:
                        right[j] = -1
                    elif j + 1 < last and holes[j + 1] == x + 1:
                        right[j] = right[j + 1]
                    else:
                        right[j] = x + 1
                row = y * w
                left = -1
                for j in range(first, last):
                    x = holes[j]
                    num, den, lo, hi = three_rays(y, x, src_v, sb, sa, flat, w, wf, inv_w, sqrt2)
                    lo, hi = min(lo, lo_down[j]), max(hi, hi_down[j])
                    if x == 0:
                        left = -1
                    elif j == first or holes[j - 1] != x - 1:
                        left = x - 1
                    has = left >= 0
                    wt = max(0.0, (wf - float(x - left)) * inv_w) if has else 0.0
                    v = np.float64(flat[np.uint64(row + (left if has else x))])
                    num += wt * (v if has else 0.0)
                    den += wt
                    lo = min(lo, v if wt > 0.0 else np.inf)
                    hi = max(hi, v if wt > 0.0 else 0.0)
                    r = right[j]
                    has = r >= 0
                    wt = max(0.0, (wf - float(r - x)) * inv_w) if has else 0.0
                    v = np.float64(flat[np.uint64(row + (r if has else x))])
                    num += wt * (v if has else 0.0)
                    den += wt
                    lo = min(lo, v if wt > 0.0 else np.inf)
                    hi = max(hi, v if wt > 0.0 else 0.0)
                    total = den + den_down[j]
                    spans_edge = hi > lo * max_ratio
                    if total > 0.0:
                        across[y, x] = spans_edge
                        if not (drop and spans_edge):
                            out[y, x] = np.float32((num + num_down[j]) / total)
                            after[y, x] = True
            # The row's known pixels become the nearest sources of their column and diagonals.
            # (Views, not offset indices: numba's negative-index check on an offset kept these scalar.)
            yy = np.int32(y)
            kn = known[y]
            for x in range(w):
                src_v[x] = yy if kn[x] else src_v[x]
            for x in range(w):
                sa[x] = yy if kn[x] else sa[x]
            for x in range(w):
                sb[x] = yy if kn[x] else sb[x]
    return out, after, across


@numba.njit(cache=True)
def count_known(depth, known):  # pragma: no cover - compiled
    """(known pixels, of which non-finite, of which ≤ 0) in one branch-free pass: the input check of
    every fill, cheaper than numpy's boolean indexing and ``isfinite``."""
    n = 0
    bad = 0
    nonpositive = 0
    for y in range(depth.shape[0]):
        for x in range(depth.shape[1]):
            v = depth[y, x]
            k = np.int64(known[y, x])
            finite = np.int64(np.isfinite(v))
            n += k
            bad += k * (1 - finite)
            nonpositive += k * finite * np.int64(v <= 0.0)
    return n, bad, nonpositive
