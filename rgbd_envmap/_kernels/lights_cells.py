"""Kernel of the cell sums of the light samplers (:mod:`rgbd_envmap.lights.cells`), called from that
module only.

One pass over an equirect map adds each valid pixel's radiance × solid angle into the cell its centre
falls in (a HEALPix cell of the Q2-Tree, a square cell of the Hemigon mapping). Channels of ``out``:
0–2 the RGB power, and with depth 3 the luminance power × distance, 4 the solid angle × distance,
5 the valid solid angle. The same pass returns what the input checks need (the smallest value and
whether any value was NaN or infinite), so the map is read once. What it computes, in plain numpy:
:func:`rgbd_envmap.reference.lights.cell_sums` (equal to float64 rounding).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["cell_sums"]


@numba.njit(cache=True, error_model="numpy")
def cell_sums(radiance, valid, use_valid, row_omega, cell, depth, use_depth, wr, wg, wb, out):  # pragma: no cover - compiled
    """Add into ``out`` (ncells, 3 or 6) float64 (zeroed by the caller); returns (smallest value,
    finite) over the valid pixels. ``valid`` and ``depth`` may be 1×1 dummies when unused.

    A row's consecutive pixels that share a cell are summed in registers first and added to ``out``
    once per run (a row crosses a cell in about 1.6 pixels at the equator, far more near the poles)."""
    H = radiance.shape[0]
    W = radiance.shape[1]
    lo = np.float32(np.inf)
    finite = True
    for v in range(H):
        om = row_omega[v]
        cur = -1
        sr = sg = sb = s3 = s4 = s5 = 0.0
        for u in range(W):
            if use_valid and not valid[v, u]:
                continue
            r0 = radiance[v, u, 0]
            g0 = radiance[v, u, 1]
            b0 = radiance[v, u, 2]
            lo = min(lo, min(r0, min(g0, b0)))
            r = np.float64(r0)
            g = np.float64(g0)
            b = np.float64(b0)
            c = cell[v, u]
            if c != cur:
                if cur >= 0:
                    if not np.isfinite(sr + sg + sb):  # NaN and inf reach the run's sums
                        finite = False
                    out[cur, 0] += sr * om
                    out[cur, 1] += sg * om
                    out[cur, 2] += sb * om
                    if use_depth:
                        out[cur, 3] += s3 * om
                        out[cur, 4] += s4 * om
                        out[cur, 5] += s5 * om
                cur = c
                sr = sg = sb = s3 = s4 = s5 = 0.0
            sr += r
            sg += g
            sb += b
            if use_depth:
                d = np.float64(depth[v, u])
                s3 += (wr * r + wg * g + wb * b) * d
                s4 += d
                s5 += 1.0
        if cur >= 0:
            if not np.isfinite(sr + sg + sb):
                finite = False
            out[cur, 0] += sr * om
            out[cur, 1] += sg * om
            out[cur, 2] += sb * om
            if use_depth:
                out[cur, 3] += s3 * om
                out[cur, 4] += s4 * om
                out[cur, 5] += s5 * om
    return lo, finite
