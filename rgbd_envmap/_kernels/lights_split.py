"""Kernel of the direct / indirect split (:mod:`rgbd_envmap.lights.split`), called from that module only.

One call finds the luminance threshold above which the valid pixels hold a fraction τ of the map's
energy Y · Ω, marks the direct pixels and sums the direct pixels' own SH coefficients, given either a
table of each pixel's SH basis × solid angle or the real SH basis's separable factors (per row the
Legendre part × solid angle, per column cos / sin(m φ): 2n multiply-adds per pixel and channel
instead of n², from tables that stay in cache), in four passes over the map and no temporary the
size of it but the luminance:

1. luminance, energy total, smallest value and finiteness (what the input checks need);
2. a histogram of energy (and of pixel counts, with each pixel's bin kept) over 4096 bins of the
   luminance's float64 bit pattern between its smallest and largest positive value (the bit
   pattern of a positive double is monotone in its value, so the bins are ordered like the values,
   which is all the search needs; no logarithm per pixel);
3. the pixels of the one bin where the energy summed from the top crosses the target, sorted;
4. the mask, and the SH sums of the direct pixels.

What it computes, as a full sort in plain numpy: :func:`rgbd_envmap.reference.lights.direct_split`
(the same mask and threshold; SH sums equal to float64 rounding).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["direct_split", "clamped_subgrid"]

NBINS = 4096


@numba.njit(cache=True, nogil=True)
def clamped_subgrid(radiance, stride, out):  # pragma: no cover - compiled
    """``out[v, u, c]`` = ``radiance[o + v·stride, o + u·stride, c]`` with o = stride // 2, negative
    values set to 0 (NaN kept, for the split's finiteness check). numpy's strided ``np.maximum``
    over the same view copied three floats at a time through its generic loop, six times slower."""
    H, W = out.shape[0], out.shape[1]
    o = stride // 2
    for v in range(H):
        for u in range(W):
            for c in range(3):
                x = radiance[o + v * stride, o + u * stride, c]
                out[v, u, c] = 0.0 if x < 0 else x  # stored in out's dtype (the map's): exact


@numba.njit(cache=True, error_model="numpy")
def direct_split(radiance, valid, use_valid, row_omega, wr, wg, wb, tau, basis, use_basis, tc, ts, row_w, m_abs,
                 m_sin, y, mask, sh):  # pragma: no cover - compiled
    """Fill ``y`` (H, W) float64 with the luminance (0 at invalid pixels), ``mask`` (H, W) bool with
    the direct pixels and add into ``sh`` (K, 3) float64 (zeroed by the caller) the direct pixels' SH
    sums: with ``use_basis`` 1, Σ radiance × ``basis`` (H·W, K) row; with 2, the separable form of
    the real SH basis, per row Σ_u radiance × cos / sin(m φ_u) (``tc``, ``ts`` (n, W)) weighted by
    ``row_w`` (H, K) (Legendre part × the row's solid angle) at sums[``m_abs[k]``, ``m_sin[k]``];
    with 0, no sums. Returns (threshold, total energy, smallest value, finite); the threshold is inf
    when no pixel is direct, and nothing is marked when a value at a valid pixel is not finite or is
    negative (the caller raises)."""
    H = radiance.shape[0]
    W = radiance.shape[1]
    lowest = np.inf
    finite = True
    total = 0.0
    ymin = np.inf
    ymax = 0.0
    for v in range(H):
        om = row_omega[v]
        for u in range(W):
            if use_valid and not valid[v, u]:
                y[v, u] = 0.0
                continue
            r = np.float64(radiance[v, u, 0])
            g = np.float64(radiance[v, u, 1])
            b = np.float64(radiance[v, u, 2])
            m = min(r, g, b)
            if m < lowest:
                lowest = m
            yy = wr * r + wg * g + wb * b
            if not np.isfinite(yy):
                finite = False
            y[v, u] = yy
            total += yy * om
            if yy > 0.0:
                if yy < ymin:
                    ymin = yy
                if yy > ymax:
                    ymax = yy
    if not finite or lowest < 0.0 or not (tau > 0.0 and total > 0.0):
        mask[:] = False
        return np.inf, total, lowest, finite
    target = tau * total * (1.0 - 1e-12)
    flat = y.reshape(-1)
    bits = flat.view(np.int64)
    lo = np.float64(np.array([ymin]).view(np.int64)[0])
    span = np.float64(np.array([ymax]).view(np.int64)[0]) - lo
    scale = NBINS / span if span > 0 else 0.0
    e_bin = np.zeros(NBINS)
    n_bin = np.zeros(NBINS, np.int64)
    kbin = np.empty(H * W, np.int16)  # each pixel's bin, −1 where it has no energy
    for v in range(H):
        om = row_omega[v]
        for u in range(W):
            p = v * W + u
            if y[v, u] > 0.0:
                k = min(int((np.float64(bits[p]) - lo) * scale), NBINS - 1)
                e_bin[k] += y[v, u] * om
                n_bin[k] += 1
                kbin[p] = k
            else:
                kbin[p] = -1
    above = np.zeros(NBINS + 1)
    for k in range(NBINS - 1, -1, -1):
        above[k] = above[k + 1] + e_bin[k]
    kb = 0
    for k in range(NBINS - 1, -1, -1):
        if above[k] >= target:
            kb = k
            break
    count = n_bin[kb]
    yb = np.empty(count)
    eb = np.empty(count)
    j = 0
    for v in range(H):
        om = row_omega[v]
        for u in range(W):
            p = v * W + u
            if kbin[p] == kb:
                yb[j] = y[v, u]
                eb[j] = y[v, u] * om
                j += 1
    if count == 0:  # not reached: the crossing bin holds energy
        mask[:] = False
        return np.inf, total, lowest, finite
    order = np.argsort(-yb, kind="mergesort")
    cum = above[kb + 1]
    threshold = yb[order[count - 1]]
    for i in range(count):
        cum += eb[order[i]]
        if cum >= target:
            threshold = yb[order[i]]
            break
    K = sh.shape[0]
    if use_basis == 2:
        n = tc.shape[0]
        acc = np.zeros((n, 2, 3))
        for v in range(H):
            acc[:] = 0.0
            hit = False
            for u in range(W):
                d = y[v, u] >= threshold and (not use_valid or valid[v, u])
                mask[v, u] = d
                if d:
                    hit = True
                    r = np.float64(radiance[v, u, 0])
                    g = np.float64(radiance[v, u, 1])
                    b = np.float64(radiance[v, u, 2])
                    for m in range(n):
                        cm = tc[m, u]
                        sm = ts[m, u]
                        acc[m, 0, 0] += r * cm
                        acc[m, 0, 1] += g * cm
                        acc[m, 0, 2] += b * cm
                        acc[m, 1, 0] += r * sm
                        acc[m, 1, 1] += g * sm
                        acc[m, 1, 2] += b * sm
            if hit:
                for k in range(K):
                    wk = row_w[v, k]
                    a, s_ = m_abs[k], m_sin[k]
                    sh[k, 0] += wk * acc[a, s_, 0]
                    sh[k, 1] += wk * acc[a, s_, 1]
                    sh[k, 2] += wk * acc[a, s_, 2]
        return threshold, total, lowest, finite
    for v in range(H):
        for u in range(W):
            d = y[v, u] >= threshold and (not use_valid or valid[v, u])
            mask[v, u] = d
            if d and use_basis == 1:
                p = v * W + u
                r = np.float64(radiance[v, u, 0])
                g = np.float64(radiance[v, u, 1])
                b = np.float64(radiance[v, u, 2])
                for k in range(K):
                    t = basis[p, k]
                    sh[k, 0] += r * t
                    sh[k, 1] += g * t
                    sh[k, 2] += b * t
    return threshold, total, lowest, finite
