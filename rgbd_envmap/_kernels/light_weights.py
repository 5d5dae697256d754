"""Kernel of the lights' unshadowed irradiance weights (:mod:`rgbd_envmap.render.differential`),
called from that module only.

What it computes, one point and light at a time in plain Python:
:func:`rgbd_envmap.reference.render_differential.light_weights`; the tests compare the two bit for bit (no fastmath: the same operations in the same order). numpy
formed the (N, n) weights from a dozen (N, n) temporaries (the products n·p − n·x and the expanded
|p − x|²); one pass over the points writes each weight once, from Δ = p − x itself (no cancellation
in |p|² − 2 x·p + |x|² either).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["light_weights_kernel"]


@numba.njit(cache=True, nogil=True)
def light_weights_kernel(points, normals, positions, has_pos, directions, intensity, out):  # pragma: no cover - compiled
    """``out[i, j]``: for a light with a position (``has_pos[j]``), I_j max(0, n_i·Δ) / |Δ|³ with
    Δ = positions[j] − points[i] and |Δ|² at least 1e-12; for a distant one, max(0, n_i·directions[j]).
    ``intensity`` (n,) I_j = |p_j − origin|² (unused for distant lights)."""
    N = points.shape[0]
    n = out.shape[1]
    for i in range(N):
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        m0, m1, m2 = normals[i, 0], normals[i, 1], normals[i, 2]
        for j in range(n):
            if has_pos[j]:
                d0 = positions[j, 0] - x0
                d1 = positions[j, 1] - x1
                d2 = positions[j, 2] - x2
                c = m0 * d0 + m1 * d1 + m2 * d2
                if c > 0.0:
                    r2 = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-12)
                    out[i, j] = c * (intensity[j] / (r2 * np.sqrt(r2)))
                else:
                    out[i, j] = 0.0
            else:
                c = m0 * directions[j, 0] + m1 * directions[j, 1] + m2 * directions[j, 2]
                out[i, j] = c if c > 0.0 else 0.0
