"""Kernels of the Pharr light sampler (:mod:`rgbd_envmap.lights.pharr`), called from that module only.

The flat CDF of a 2000 × 1000 map would be 16 MB written and read back per frame; instead one pass
over the map writes only the rows' totals of luminance × pixel solid angle (the marginal) and checks
the values, and a second kernel computes the running sum of just the rows that samples fell in (the
conditional), once per row, to place each sample in its row (at the fraction of that running sum's
total: the two sums differ only by rounding). What they compute, in plain numpy:
:func:`rgbd_envmap.reference.lights.pharr` (the same pixels; offsets equal to float64 rounding).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["row_totals", "pick_in_rows"]


#: reassociation lets LLVM vectorise the row sums; no 'nnan' / 'ninf': NaN and inf must reach the
#: sums, the finiteness check relies on it.
FASTMATH = {"reassoc", "contract"}


@numba.njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def row_totals(radiance, valid, use_valid, row_omega, wr, wg, wb, out):  # pragma: no cover - compiled
    """``out`` (H,) float64: (wr ΣR + wg ΣG + wb ΣB) · Ω over each row's valid pixels. Returns
    (smallest value, finite) over the valid pixels (finite: every row's sums are finite)."""
    H = radiance.shape[0]
    W = radiance.shape[1]
    lo = np.inf
    finite = True
    for v in range(H):
        sr = 0.0
        sg = 0.0
        sb = 0.0
        m = np.float32(np.inf)  # the minimum in the map's own dtype: float64 minima kept LLVM scalar
        if use_valid:
            for u in range(W):
                if valid[v, u]:
                    r = radiance[v, u, 0]
                    g = radiance[v, u, 1]
                    b = radiance[v, u, 2]
                    sr += np.float64(r)
                    sg += np.float64(g)
                    sb += np.float64(b)
                    m = min(m, min(r, min(g, b)))
        else:
            for u in range(W):
                r = radiance[v, u, 0]
                g = radiance[v, u, 1]
                b = radiance[v, u, 2]
                sr += np.float64(r)
                sg += np.float64(g)
                sb += np.float64(b)
                m = min(m, min(r, min(g, b)))
        if not np.isfinite(sr + sg + sb):
            finite = False
        lo = min(lo, m)
        out[v] = (wr * sr + wg * sg + wb * sb) * row_omega[v]
    return lo, finite


@numba.njit(cache=True, error_model="numpy")
def pick_in_rows(radiance, valid, use_valid, row_omega, wr, wg, wb, order, rows, u2, cols, fracs):  # pragma: no cover - compiled
    """For sample i (visited in ``order``, sorted by row): the column of ``rows[i]`` whose step of the
    row's running sum of Y · Ω (left to right) holds the fraction ``u2[i]`` of the row's total, and
    the sample's continuous offset in it, into ``cols``, ``fracs``."""
    W = radiance.shape[1]
    buf = np.empty(W)
    prev = -1
    for k in range(order.shape[0]):
        i = order[k]
        v = rows[i]
        if v != prev:
            acc = 0.0
            om = row_omega[v]
            for u in range(W):
                if not use_valid or valid[v, u]:
                    acc += wr * np.float64(radiance[v, u, 0]) + wg * np.float64(radiance[v, u, 1]) \
                        + wb * np.float64(radiance[v, u, 2])
                buf[u] = acc * om
            prev = v
        x = u2[i] * buf[W - 1]
        lo = 0
        hi = W - 1
        while lo < hi:
            mid = (lo + hi) // 2
            if buf[mid] > x:
                hi = mid
            else:
                lo = mid + 1
        if buf[lo] <= x:  # x rounded onto the row's total: the last pixel of positive weight
            lo = W - 1
            while lo > 0 and buf[lo] == buf[lo - 1]:
                lo -= 1
            cols[i] = lo
            fracs[i] = 1.0 - 1e-12
            continue
        base = buf[lo - 1] if lo > 0 else 0.0
        cols[i] = lo
        fracs[i] = min(max((x - base) / (buf[lo] - base), 0.0), 1.0 - 1e-12)
