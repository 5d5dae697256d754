"""Kernel of the shadow rays' selection (:func:`rgbd_envmap.render.differential.light_visibility`),
called from that module only.

What it computes, one point and light at a time in plain Python:
:func:`rgbd_envmap.reference.render_differential.shadow_ray_candidates`; the tests compare the two bit
for bit (no fastmath: the same operations in the same order). numpy formed the (N, n, 3) segments and
the distance of each to the object's bounding sphere from half a dozen (N, n, 3) temporaries (96
lights × 10,000 receivers: 23 MB each), then gathered the few that pass the sphere; one pass writes
only those.
"""

from __future__ import annotations

import numba

__all__ = ["shadow_ray_candidates_kernel"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def shadow_ray_candidates_kernel(origins, positions, has_pos, directions, centre, radius, cull,
                                 rows, cols, vectors):  # pragma: no cover - compiled
    """The shadow rays to cast, written to ``rows``, ``cols`` (N·n,) int64 and ``vectors`` (N·n, 3)
    in point-major order; returns their count. The ray of point i (``origins[i]``) and light j is
    the segment to ``positions[j]`` (``has_pos[j]``) or 1 km along ``directions[j]``; with ``cull``
    only those that pass within ``radius`` of ``centre`` (the segment's nearest point, t clipped to
    [0, 1], |v|² at least 1e-300) are kept."""
    N = origins.shape[0]
    n = has_pos.shape[0]
    c0, c1, c2 = centre[0], centre[1], centre[2]
    r2 = radius * radius
    count = 0
    for i in range(N):
        x0, x1, x2 = origins[i, 0], origins[i, 1], origins[i, 2]
        w0, w1, w2 = c0 - x0, c1 - x1, c2 - x2
        for j in range(n):
            if has_pos[j]:
                v0, v1, v2 = positions[j, 0] - x0, positions[j, 1] - x1, positions[j, 2] - x2
            else:
                v0, v1, v2 = directions[j, 0] * 1e3, directions[j, 1] * 1e3, directions[j, 2] * 1e3
            if cull:
                t = (w0 * v0 + w1 * v1 + w2 * v2) / max(v0 * v0 + v1 * v1 + v2 * v2, 1e-300)
                t = min(max(t, 0.0), 1.0)
                g0, g1, g2 = w0 - t * v0, w1 - t * v1, w2 - t * v2
                if not (g0 * g0 + g1 * g1 + g2 * g2 <= r2):
                    continue
            rows[count] = i
            cols[count] = j
            vectors[count, 0] = v0
            vectors[count, 1] = v1
            vectors[count, 2] = v2
            count += 1
    return count
