"""Kernels of the receivers' shading in the differential composite (:mod:`rgbd_envmap.render.differential`),
called from that module only.

Per depth frame the receivers (the real surfaces near the object) get new SH coefficients: their
irradiance without and with the object from the indirect SH, the light the object reflects onto
them, the lights' terms and the albedo floor, then the ratio E_with / E_without and which vertices
change a pixel at all. numpy did that in a dozen (R, 3) passes, three of them matrix products of
(R, ≤ 25) transfers taken as strided slices, plus a fancy-indexed pass over the faces. Here the
transfers are stored transposed, (K, R) float32: the three products run coefficient by coefficient
over contiguous rows (vectorised over the receivers, half the bytes of float64), and one more pass
forms everything else.

What they compute, in plain numpy: :func:`rgbd_envmap.reference.render_differential.receiver_ratio_terms`
and :func:`~rgbd_envmap.reference.render_differential.faces_touching`; the tests compare them bit
for bit (float64 sums in the same order; no fastmath).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["faces_touching_kernel", "receiver_ratio_kernel"]


#: receivers per block of the products: three accumulator rows of this many float64 stay in L1
BLOCK = 512


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _accumulate(t, nk, coeffs, acc):  # pragma: no cover - compiled
    """``acc[c, i]`` = Σ_{k < nk} float64(t[k, i]) · coeffs[k, c], k ascending from 0.0, a block
    of receivers at a time (the block's sums stay in cache across the coefficients)."""
    R = t.shape[1]
    for i0 in range(0, R, BLOCK):
        i1 = min(i0 + BLOCK, R)
        a0, a1, a2 = acc[0, i0:i1], acc[1, i0:i1], acc[2, i0:i1]
        a0[:] = 0.0
        a1[:] = 0.0
        a2[:] = 0.0
        for k in range(nk):
            c0, c1, c2 = coeffs[k, 0], coeffs[k, 1], coeffs[k, 2]
            row = t[k, i0:i1]
            for i in range(i1 - i0):
                x = np.float64(row[i])
                a0[i] += x * c0
                a1[i] += x * c1
                a2[i] += x * c2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def receiver_ratio_kernel(t0, t1, nk, coeffs, bt, kb, bc, add0, add1, floor, use_floor, keep, floor_rel, high, eps,
                          s0, s1, sb, ratio, far):  # pragma: no cover - compiled
    """Fill ``ratio`` (R, 3) float32 and ``far`` (R,) bool; return how many vertices are far.

    ``t0``, ``t1`` (K, R) float32: the receivers' SH transfer without / with the object, of which
    the first ``nk`` rows meet ``coeffs`` (≥ nk, 3) float64; ``bt`` (Kb, R) float32 and ``bc``
    (≥ kb, 3): the object's reflected light, its first ``kb`` rows; ``add0``, ``add1`` (R, 3)
    float64: the lights' terms without / with the object; ``floor`` (R, 3) (read with
    ``use_floor``) and ``keep`` (R,) the share of missed light the object leaves; scratch ``s0``,
    ``s1``, ``sb`` (3, R) float64. E0 = max(Σ t0 c, 0) + add0, E1 = (max(Σ t1 c, 0) + Σ bt bc) + add1;
    then m = max(floor − E0, 0): E0 += m, E1 += m · keep; ratio = E1 / E0 where E0 > floor_rel ·
    max(max E0, 1e-300), else 1, clipped to [0, high]; far where |ratio − 1| > eps in some channel."""
    R = ratio.shape[0]
    _accumulate(t0, nk, coeffs, s0)
    _accumulate(t1, nk, coeffs, s1)
    _accumulate(bt, kb, bc, sb)
    top = 0.0
    for i in range(R):
        for c in range(3):
            e0 = max(s0[c, i], 0.0) + add0[i, c]
            e1 = (max(s1[c, i], 0.0) + sb[c, i]) + add1[i, c]
            if use_floor:
                m = max(floor[i, c] - e0, 0.0)
                e0 = e0 + m
                e1 = e1 + m * keep[i]
            s0[c, i] = e0
            s1[c, i] = e1
            if e0 > top:
                top = e0
    lim = floor_rel * max(top, 1e-300)
    n_far = 0
    for i in range(R):
        f = False
        for c in range(3):
            e0 = s0[c, i]
            r = s1[c, i] / e0 if e0 > lim else 1.0
            r = min(max(r, 0.0), high)
            r32 = np.float32(r)
            ratio[i, c] = r32
            if abs(np.float64(r32) - 1.0) > eps:
                f = True
        far[i] = f
        n_far += f
    return n_far


@numba.njit(cache=True, nogil=True)
def faces_touching_kernel(faces, far, out):  # pragma: no cover - compiled
    """Copy into ``out`` (F, 3), in order, the ``faces`` (F, 3) with a vertex marked in ``far``;
    return how many."""
    n = 0
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if far[a] or far[b] or far[c]:
            out[n, 0] = a
            out[n, 1] = b
            out[n, 2] = c
            n += 1
    return n
