"""Kernels of reliability marking (:mod:`rgbd_envmap.depth.reliability`), called from that module only.

What they compute is written plainly in :mod:`rgbd_envmap.reference.reliability`; the tests compare
the statistics with those references and the verdicts exactly.

Both discontinuity kernels stream over the image with a ring of three zero-padded rows (an unknown or
outside neighbour contributes 0), so nothing image-sized is allocated besides the outputs. Each image
row is computed branch-free into row buffers (which LLVM vectorises), then judged by
:func:`verdict_row`. With ``full`` False only ``passed`` and ``testable`` are written (``stat``,
``n_nb``, ``threshold`` may be 1×1 dummies). The exposure rule is a separate pass over ``passed``
(``exposure_and_*``). The error model is numpy's: a division by zero or an overflow gives inf / NaN
(then rejected), never an exception.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "threshold_of",
    "verdict_row",
    "monroy2018_row",
    "monroy2018_kernel",
    "noise_model_row",
    "noise_model_kernel",
    "exposure_and_f64",
    "exposure_and_f32",
]


@numba.njit(cache=True, error_model="numpy")
def threshold_of(nb, t0, t1, t2, t3, t4, t5, t6, t7, t8):  # pragma: no cover - compiled
    """The threshold for ``nb`` (a float 0 … 8) known neighbours, as a chain of selects: a table lookup
    kept the loops scalar (LLVM could not bound the table's reads against the stores)."""
    return (t8 if nb == 8.0 else t7 if nb == 7.0 else t6 if nb == 6.0 else t5 if nb == 5.0 else t4 if nb == 4.0
            else t3 if nb == 3.0 else t2 if nb == 2.0 else t1 if nb == 1.0 else t0)


@numba.njit(cache=True, error_model="numpy")
def verdict_row(
    r, t_row, count_row, centre_mask, thr_by_nb, min_nb, full, stat, n_nb, threshold, passed, testable,
):  # pragma: no cover - compiled
    """Judge image row ``r``: statistic ``t_row[c]``, ``count_row[c]`` known pixels in the window
    (centre included), ``centre_mask[c + 1]`` > 0 where the pixel itself is known. A pixel is
    testable when it has ≥ min(``min_nb``, its in-image neighbours) known neighbours and
    ``thr_by_nb`` has a threshold (≥ 0) for that count; it passes when testable and the statistic is
    ≤ the threshold (false for NaN: overflowed arithmetic).

    Everything runs in float64 lanes so that the loop is SIMD: the neighbour count (an exact small
    integer) stays a float. Inside the row every pixel needs min(``min_nb``, rows in image × 3 − 1)
    neighbours; when that is 8 (the default, away from the top and bottom rows), or when every count
    has the same threshold (``monroy2018``), only ``thr_by_nb[8]`` can apply and the select chain is
    skipped. The first and last column, with fewer in-image neighbours, are judged again after.
    """
    h = passed.shape[0]
    w = t_row.shape[0]
    rows_in = min(r + 1, h - 1) - max(r - 1, 0) + 1
    t0, t1, t2, t3, t4 = thr_by_nb[0], thr_by_nb[1], thr_by_nb[2], thr_by_nb[3], thr_by_nb[4]
    t5, t6, t7, t8 = thr_by_nb[5], thr_by_nb[6], thr_by_nb[7], thr_by_nb[8]
    uniform = t0 == t8 and t1 == t8 and t2 == t8 and t3 == t8 and t4 == t8 and t5 == t8 and t6 == t8 and t7 == t8
    prow = passed[r]
    trow = testable[r]
    need = float(min(min_nb, rows_in * 3 - 1))
    if need >= 8.0 or uniform:  # only thr_by_nb[8] can apply
        for c in range(w):
            nb = min(max(count_row[c] - 1.0, 0.0), 8.0)
            ok_test = (centre_mask[c + 1] > 0.0) & (t8 >= 0.0) & (nb >= need)
            prow[c] = ok_test & (t_row[c] <= t8)
            trow[c] = ok_test
    else:
        for c in range(w):
            nb = min(max(count_row[c] - 1.0, 0.0), 8.0)
            t = threshold_of(nb, t0, t1, t2, t3, t4, t5, t6, t7, t8)
            ok_test = (centre_mask[c + 1] > 0.0) & (t >= 0.0) & (nb >= need)
            prow[c] = ok_test & (t_row[c] <= t)
            trow[c] = ok_test
    for c in (0, w - 1):  # (twice the same pixel when w = 1: harmless)
        n_in = rows_in * (min(c + 1, w - 1) - max(c - 1, 0) + 1) - 1
        nb = min(max(count_row[c] - 1.0, 0.0), 8.0)
        t = threshold_of(nb, t0, t1, t2, t3, t4, t5, t6, t7, t8)
        ok_test = (centre_mask[c + 1] > 0.0) & (t >= 0.0) & (nb >= float(min(min_nb, n_in)))
        prow[c] = ok_test & (t_row[c] <= t)
        trow[c] = ok_test
    if full:
        for c in range(w):
            nb = min(max(count_row[c] - 1.0, 0.0), 8.0)
            t = threshold_of(nb, t0, t1, t2, t3, t4, t5, t6, t7, t8)
            s = t_row[c]
            s = s if s == s else np.inf  # NaN from overflowed arithmetic: reported as +inf
            stat[r, c] = s if trow[c] else 0.0
            threshold[r, c] = t if trow[c] else 0.0
            n_nb[r, c] = np.int8(nb) if centre_mask[c + 1] > 0.0 else np.int8(0)


@numba.njit(cache=True, error_model="numpy")
def monroy2018_row(depth, known, r, slot, d_ring, m_ring):  # pragma: no cover - compiled
    for c in range(depth.shape[1]):
        z = depth[r, c]
        ok = known[r, c] and z > 0.0 and z < np.inf  # NaN fails z > 0
        d_ring[slot, c + 1] = z if ok else 0.0
        m_ring[slot, c + 1] = 1.0 if ok else 0.0


@numba.njit(cache=True, error_model="numpy")
def monroy2018_kernel(
    depth, known, thr_by_nb, min_nb, full, stat, n_nb, threshold, passed, testable
):  # pragma: no cover - compiled
    h, w = depth.shape
    d_ring = np.zeros((3, w + 2))
    m_ring = np.zeros((3, w + 2))
    t_row = np.empty(w)
    count_row = np.empty(w)
    monroy2018_row(depth, known, 0, 1, d_ring, m_ring)  # ring slot of image row i: (i + 1) % 3
    for r in range(h):
        below = (r + 2) % 3
        if r + 1 < h:
            monroy2018_row(depth, known, r + 1, below, d_ring, m_ring)
        else:
            d_ring[below, :] = 0.0
            m_ring[below, :] = 0.0
        d_a, d_c, d_b = d_ring[r % 3], d_ring[(r + 1) % 3], d_ring[below]
        m_a, m_c, m_b = m_ring[r % 3], m_ring[(r + 1) % 3], m_ring[below]
        for c in range(w):
            d = d_c[c + 1]
            s = 0.0
            n = 0.0
            for j in range(3):  # row by row, the centre adding exactly 0; unknown neighbours × 0
                e = (d_a[c + j] - d) * m_a[c + j]
                s += e * e
                e = (d_c[c + j] - d) * m_c[c + j]
                s += e * e
                e = (d_b[c + j] - d) * m_b[c + j]
                s += e * e
                n += m_a[c + j] + m_c[c + j] + m_b[c + j]
            t_row[c] = s / d  # d = 0 at unknown pixels: inf / NaN, never read
            count_row[c] = n
        verdict_row(
            r, t_row, count_row, m_c, thr_by_nb, min_nb, full, stat, n_nb, threshold, passed, testable,
        )


@numba.njit(cache=True, error_model="numpy")
def noise_model_row(depth, known, r, slot, noise_rel, noise_abs, w_ring, wy_ring, wyy_ring, n_ring):  # pragma: no cover
    # With y = 1/z and weight W = 1/σ_y² = z⁴/σ_z²: W, W·y and W·y² from one division (q = z/σ_z).
    for c in range(depth.shape[1]):
        z = float(depth[r, c])
        ok = known[r, c] & (z > 0.0) & (z < np.inf)  # NaN fails z > 0
        z = z if ok else 1.0
        q = z / (noise_abs + noise_rel * z)
        wyy = q * q
        wy = wyy * z
        wt = wy * z
        ok = ok & (wt > 0.0) & (wt < np.inf)  # weight not representable (absurd depth): unknown
        w_ring[slot, c + 1] = wt if ok else 0.0
        wy_ring[slot, c + 1] = wy if ok else 0.0
        wyy_ring[slot, c + 1] = wyy if ok else 0.0
        n_ring[slot, c + 1] = 1.0 if ok else 0.0


@numba.njit(cache=True, error_model="numpy")
def noise_model_kernel(
    depth, known, noise_rel, noise_abs, thr_by_nb, min_nb, full, stat, n_nb, threshold, passed, testable,
):  # pragma: no cover - compiled
    h, w = depth.shape
    w_ring = np.zeros((3, w + 2))
    wy_ring = np.zeros((3, w + 2))
    wyy_ring = np.zeros((3, w + 2))
    n_ring = np.zeros((3, w + 2))
    # Row and slot as int64, not literals (numba compiled the row kernel a second time for them).
    noise_model_row(depth, known, np.int64(0), np.int64(1), noise_rel, noise_abs, w_ring, wy_ring, wyy_ring, n_ring)
    # The ten weighted sums over the 3×3 window (offsets u = column, v = row, in {−1, 0, 1}) are
    # separable: column sums with [1 1 1], [−1 0 1], [1 0 1], then the same along the row.
    a1 = np.empty(w + 2)
    ad = np.empty(w + 2)
    a2 = np.empty(w + 2)
    b1 = np.empty(w + 2)
    bd = np.empty(w + 2)
    c1 = np.empty(w + 2)
    n1 = np.empty(w + 2)
    t_row = np.empty(w)
    count_row = np.empty(w)
    for r in range(h):
        below = (r + 2) % 3  # ring slot of image row i: (i + 1) % 3
        if r + 1 < h:
            noise_model_row(depth, known, r + 1, below, noise_rel, noise_abs, w_ring, wy_ring, wyy_ring, n_ring)
        else:
            w_ring[below, :] = 0.0
            wy_ring[below, :] = 0.0
            wyy_ring[below, :] = 0.0
            n_ring[below, :] = 0.0
        above = r % 3
        centre = (r + 1) % 3
        w_a, w_c, w_b = w_ring[above], w_ring[centre], w_ring[below]
        wy_a, wy_c, wy_b = wy_ring[above], wy_ring[centre], wy_ring[below]
        q_a, q_c, q_b = wyy_ring[above], wyy_ring[centre], wyy_ring[below]
        n_a, n_c, n_b = n_ring[above], n_ring[centre], n_ring[below]
        # One output per loop: with all seven in one loop it ran at half the speed.
        for c in range(w + 2):
            a1[c] = w_a[c] + w_c[c] + w_b[c]
        for c in range(w + 2):
            ad[c] = w_b[c] - w_a[c]
        for c in range(w + 2):
            a2[c] = w_a[c] + w_b[c]
        for c in range(w + 2):
            b1[c] = wy_a[c] + wy_c[c] + wy_b[c]
        for c in range(w + 2):
            bd[c] = wy_b[c] - wy_a[c]
        for c in range(w + 2):
            c1[c] = q_a[c] + q_c[c] + q_b[c]
        for c in range(w + 2):
            n1[c] = n_a[c] + n_c[c] + n_b[c]
        for c in range(w):
            s0 = a1[c] + a1[c + 1] + a1[c + 2]
            su = a1[c + 2] - a1[c]
            suu = a1[c + 2] + a1[c]
            sv = ad[c] + ad[c + 1] + ad[c + 2]
            suv = ad[c + 2] - ad[c]
            svv = a2[c] + a2[c + 1] + a2[c + 2]
            sy = b1[c] + b1[c + 1] + b1[c + 2]
            suy = b1[c + 2] - b1[c]
            svy = bd[c] + bd[c + 1] + bd[c + 2]
            syy = c1[c] + c1[c + 1] + c1[c + 2]
            # Weighted least squares y ≈ β₀ + β₁u + β₂v: centring on the weighted means removes β₀;
            # the 2×2 normal equations in closed form give RSS = Cyy − [Cuy Cvy] C⁻¹ [Cuy Cvy]ᵀ.
            # Every C is scaled by s0 so that one division remains. Windows with < 4 known pixels
            # give 0 / 0 here; they are never tested (verdict_row).
            cuu = s0 * suu - su * su
            cvv = s0 * svv - sv * sv
            cuv = s0 * suv - su * sv
            cuy = s0 * suy - su * sy
            cvy = s0 * svy - sv * sy
            cyy = s0 * syy - sy * sy
            det = cuu * cvv - cuv * cuv
            t = (cyy * det - (cvv * cuy * cuy - 2.0 * cuv * cuy * cvy + cuu * cvy * cvy)) / (s0 * det)
            t_row[c] = 0.0 if t < 0.0 else t  # rounding can go below 0; NaN stays NaN (→ rejected)
            count_row[c] = n1[c] + n1[c + 1] + n1[c + 2]
        verdict_row(
            r, t_row, count_row, n_ring[centre], thr_by_nb, min_nb, full, stat, n_nb, threshold, passed, testable,
        )


@numba.njit(cache=True, error_model="numpy")
def exposure_and_f64(rgb, dark, bright, passed):  # pragma: no cover - compiled
    """passed &= the exposure rule, on (H, W, 3) float64 (any finite dark, bright), SIMD."""
    flat = rgb.reshape(-1)
    out = passed.reshape(-1)
    for i in range(out.shape[0]):
        x = flat[3 * i]
        y = flat[3 * i + 1]
        z = flat[3 * i + 2]
        total = x + y + z
        finite = total - total == 0.0  # False when a channel is NaN or inf (or the sum overflows)
        under = (x < dark) & (y < dark) & (z < dark)
        over = (x > bright) & (y > bright) & (z > bright)
        out[i] = out[i] & finite & ~(under | over)


@numba.njit(cache=True, error_model="numpy")
def exposure_and_f32(rgb, dark, bright, passed):  # pragma: no cover - compiled
    """passed &= the exposure rule, on (H, W, 3) float32 with float32 ``dark`` / ``bright`` (the
    smallest float32 ≥ the float64 ``dark``, the largest ≤ ``bright``; the API module computes them):
    eight lanes instead of four, and the same verdicts as comparing with the float64 thresholds. The
    finiteness test sums the channels in float32, as the rule always has for float32 colour (so
    channels near the float32 maximum, whose sum overflows, count as non-finite)."""
    flat = rgb.reshape(-1)
    out = passed.reshape(-1)
    for i in range(out.shape[0]):
        x = flat[3 * i]
        y = flat[3 * i + 1]
        z = flat[3 * i + 2]
        total = x + y + z
        finite = total - total == total - total  # False when a channel is NaN or inf (or the sum overflows)
        under = (x < dark) & (y < dark) & (z < dark)
        over = (x > bright) & (y > bright) & (z > bright)
        out[i] = out[i] & finite & ~(under | over)
