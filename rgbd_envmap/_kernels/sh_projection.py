"""Kernels of the SH projection of an equirect map: per-row longitude sums, combined over rows.

Per row and channel the projection needs the 2n − 1 longitude sums Σ_u r(u) cos(mφ_u) and
Σ_u r(u) sin(mφ_u). Pixel-centre azimuths are symmetric: columns u, W − 1 − u have azimuths ±φ, and
columns u, u ± W/2 differ by π, so with W divisible by 4 the four columns q, W − 1 − q, W/2 − 1 − q,
W/2 + q share |cos mφ|, |sin mφ| up to the signs (−1)^m and ±1. Folding them first (4 loads, 8 adds)
leaves one multiply-add per quarter of the row per (m, cos/sin). Each row is first copied to a small
buffer (a sequential read that the hardware prefetcher streams; the folded loads run backwards and
would not be), its missing pixels are filled there from the fill plan
(:mod:`rgbd_envmap._kernels.sh_fill`), and the fold and the sums run from L1 with 10 float32
accumulators per pass of 5 orders m (one pass for the default 5 bands). The row sums are then
weighted by the Legendre part times the row's solid angle and added in float64.

What they compute, in plain numpy: :func:`rgbd_envmap.reference.sh_projection.project_equirect`
(equal to float32 rounding of the row sums). Called from :mod:`rgbd_envmap.sh.projection` only.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["BLOCK", "FASTMATH", "U0", "U1", "U2", "U4", "row_sums_folded", "row_sums_plain", "accumulate_row",
           "project_planar", "project_interleaved"]

#: Orders m per pass of the row sums (10 float32 accumulators: 5 cos, 5 sin).
BLOCK = 5
#: Reassociation lets LLVM vectorise the float32 reductions. No 'nnan' / 'ninf': NaN and inf must
#: propagate into the sums, the finiteness check of the result relies on it.
FASTMATH = {"reassoc", "contract"}
U0 = np.uint64(0)
U1 = np.uint64(1)
U2 = np.uint64(2)
U4 = np.uint64(4)


@numba.njit(fastmath=FASTMATH, inline="always", cache=True)
def row_sums_folded(r, tcb, tsb, o):  # pragma: no cover - compiled
    """o[m, 0] = Σ_u cos(mφ_u) r[u], o[m, 1] = Σ_u sin(mφ_u) r[u] for m < 5 · nblocks; W % 4 == 0.
    tcb, tsb: (nblocks, 5, W/4) cos / sin of mφ_q at the first quarter's azimuths."""
    # unsigned indices: numba's negative-index wrap on signed ones blocks vectorisation of r[W − 1 − q]
    W = np.uint64(r.shape[0])
    Q = W // U4
    h = W // U2
    for j in range(tcb.shape[0]):
        tc = tcb[j]
        ts = tsb[j]
        # m = 5j + i: the parity of m flips with j; scaling the second pair by sg swaps the
        # even / odd combinations instead of branching.
        sg = np.float32(1.0) if j % 2 == 0 else np.float32(-1.0)
        c0 = c1 = c2 = c3 = c4 = np.float32(0.0)
        s0 = s1 = s2 = s3 = s4 = np.float32(0.0)
        for q in range(Q):
            a = r[q]
            b = r[W - U1 - q]
            c = r[h - U1 - q]
            d = r[h + q]
            p1 = a + b
            p2 = sg * (c + d)
            m1 = a - b
            m2 = sg * (d - c)
            ce = p1 + p2
            co = p1 - p2
            se = m1 + m2
            so = m1 - m2
            c0 += tc[0, q] * ce
            c1 += tc[1, q] * co
            c2 += tc[2, q] * ce
            c3 += tc[3, q] * co
            c4 += tc[4, q] * ce
            s0 += ts[0, q] * se
            s1 += ts[1, q] * so
            s2 += ts[2, q] * se
            s3 += ts[3, q] * so
            s4 += ts[4, q] * se
        k = BLOCK * j
        o[k, 0] = c0
        o[k + 1, 0] = c1
        o[k + 2, 0] = c2
        o[k + 3, 0] = c3
        o[k + 4, 0] = c4
        o[k, 1] = s0
        o[k + 1, 1] = s1
        o[k + 2, 1] = s2
        o[k + 3, 1] = s3
        o[k + 4, 1] = s4


@numba.njit(fastmath=FASTMATH, inline="always", cache=True)
def row_sums_plain(r, tcb, tsb, o):  # pragma: no cover - compiled
    """As :func:`row_sums_folded` for any W; tables (nblocks, 5, W)."""
    W = r.shape[0]
    for j in range(tcb.shape[0]):
        tc = tcb[j]
        ts = tsb[j]
        c0 = c1 = c2 = c3 = c4 = np.float32(0.0)
        s0 = s1 = s2 = s3 = s4 = np.float32(0.0)
        for u in range(W):
            x = r[u]
            c0 += tc[0, u] * x
            c1 += tc[1, u] * x
            c2 += tc[2, u] * x
            c3 += tc[3, u] * x
            c4 += tc[4, u] * x
            s0 += ts[0, u] * x
            s1 += ts[1, u] * x
            s2 += ts[2, u] * x
            s3 += ts[3, u] * x
            s4 += ts[4, u] * x
        k = BLOCK * j
        o[k, 0] = c0
        o[k + 1, 0] = c1
        o[k + 2, 0] = c2
        o[k + 3, 0] = c3
        o[k + 4, 0] = c4
        o[k, 1] = s0
        o[k + 1, 1] = s1
        o[k + 2, 1] = s2
        o[k + 3, 1] = s3
        o[k + 4, 1] = s4


@numba.njit(fastmath=FASTMATH, inline="always", cache=True)
def accumulate_row(buf, v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs):  # pragma: no cover
    """coeffs[:, c] += the Legendre weights of row v times the longitude sums of the staged row ``buf``."""
    if folded:
        row_sums_folded(buf, tcb, tsb, sums)
    else:
        row_sums_plain(buf, tcb, tsb, sums)
    for k in range(row_w.shape[1]):
        coeffs[k, c] += row_w[v, k] * np.float64(sums[m_abs[k], m_sin[k]])


@numba.njit(fastmath=FASTMATH, cache=True)
def project_planar(planes, row_ptr, col, src, empty, tcb, tsb, folded, row_w, m_abs, m_sin):  # pragma: no cover
    """(n², 3) float64 coefficients of float32 (3, H, W) ``planes`` filled by the plan (row_ptr, col,
    src, empty), with the tables of :func:`rgbd_envmap.sh.projection.projection_tables`."""
    H, W = planes.shape[1:]  # 3 planes
    coeffs = np.zeros((row_w.shape[1], 3), np.float64)
    buf = np.empty((3, W), np.float32)
    b0 = buf[0]
    b1 = buf[1]
    b2 = buf[2]
    sums = np.empty((tcb.shape[0] * BLOCK, 2), np.float32)
    flat = planes.reshape(3, H * W)
    f0 = flat[0]
    f1 = flat[1]
    f2 = flat[2]
    for v in range(H):  # three sequential streams, one per plane
        if empty[v]:
            continue
        r0 = planes[0, v]
        r1 = planes[1, v]
        r2 = planes[2, v]
        for u in range(W):
            b0[u] = r0[u]
        for u in range(W):
            b1[u] = r1[u]
        for u in range(W):
            b2[u] = r2[u]
        for k in range(row_ptr[v], row_ptr[v + 1]):
            s = src[k]
            u = col[k]
            if s >= 0:
                b0[u] = f0[s]
                b1[u] = f1[s]
                b2[u] = f2[s]
            else:
                b0[u] = np.float32(0.0)
                b1[u] = np.float32(0.0)
                b2[u] = np.float32(0.0)
        for c in range(3):
            accumulate_row(buf[c], v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs)
    return coeffs


@numba.njit(fastmath=FASTMATH, cache=True)
def project_interleaved(rad, row_ptr, col, src, empty, tcb, tsb, folded, row_w, m_abs, m_sin):  # pragma: no cover
    """:func:`project_planar` for float32 (H, W, 3) ``rad`` (channels interleaved)."""
    H, W = rad.shape[:2]  # 3 channels
    coeffs = np.zeros((row_w.shape[1], 3), np.float64)
    buf = np.empty((3, W), np.float32)
    b0 = buf[0]
    b1 = buf[1]
    b2 = buf[2]
    sums = np.empty((tcb.shape[0] * BLOCK, 2), np.float32)
    rows = rad.reshape(H, W * 3)
    flat = rad.reshape(H * W * 3)
    u3 = np.uint64(3)
    for v in range(H):
        if empty[v]:
            continue
        r = rows[v]
        for u in range(np.uint64(W)):  # de-interleave into channel rows (unsigned: vectorises)
            i = u3 * u
            b0[u] = r[i]
            b1[u] = r[i + U1]
            b2[u] = r[i + U2]
        for k in range(row_ptr[v], row_ptr[v + 1]):
            s = src[k]
            u = col[k]
            for c in range(3):
                buf[c, u] = flat[3 * s + c] if s >= 0 else np.float32(0.0)
        for c in range(3):
            accumulate_row(buf[c], v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs)
    return coeffs
