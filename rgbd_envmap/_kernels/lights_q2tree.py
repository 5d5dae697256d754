"""Kernels of the Q2-Tree light sampler (:mod:`rgbd_envmap.lights.q2tree`), called from that module
only: one level of the sum pyramid up the nested HEALPix quads, and the quads' importances.

What they compute, in plain numpy: ``child.reshape(-1, 4, C).sum(axis=1)`` and
(Y^a) · Δω^b with Y the Rec. 709 luminance of the first three columns (the tests compare).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["level_up", "importance"]


@numba.njit(cache=True)
def level_up(child, parent):  # pragma: no cover - compiled
    """parent[i] = child[4i] + child[4i + 1] + child[4i + 2] + child[4i + 3] (row by row, in order)."""
    C = child.shape[1]
    for i in range(parent.shape[0]):
        for c in range(C):
            parent[i, c] = ((child[4 * i, c] + child[4 * i + 1, c]) + child[4 * i + 2, c]) + child[4 * i + 3, c]


@numba.njit(cache=True, error_model="numpy")
def importance(sums, wr, wg, wb, a, scale, out):  # pragma: no cover - compiled
    """out[i] = Y_i^a · scale with Y_i = wr·R + wg·G + wb·B of row i of ``sums`` (a = 1: Y · scale)."""
    for i in range(out.shape[0]):
        y = wr * sums[i, 0] + wg * sums[i, 1] + wb * sums[i, 2]
        out[i] = (y if a == 1.0 else y ** a) * scale
