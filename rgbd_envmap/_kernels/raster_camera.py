"""Kernels of the virtual camera: per-vertex projection to fixed-point screen positions and bounds.

A vertex in front of the near plane and inside the guard band gets its screen position snapped to
1 / 2**:data:`SUBPIXEL_BITS` pixel (pixel centres at multiples of :data:`SUBPIXEL`); any other is
marked :data:`CLIP`, and the rasteriser (:mod:`rgbd_envmap._kernels.raster`) clips its triangles in
camera space. Called from :mod:`rgbd_envmap.render.camera` only.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["SUBPIXEL_BITS", "SUBPIXEL", "GUARD_PX", "CLIP", "grow", "prepare_vertices"]

#: Sub-pixel precision of the numba rasteriser: vertices snap to 1 / 2**SUBPIXEL_BITS pixel
#: (8 bits, as in Mesa's llvmpipe), so edge functions are exact int64 arithmetic.
SUBPIXEL_BITS = 8
SUBPIXEL = 1 << SUBPIXEL_BITS
#: Guard band in pixels: triangles reaching further outside the image are clipped in camera space, which
#: keeps the fixed-point coordinates (and their products in the edge functions) well inside int64.
GUARD_PX = 4096.0
#: Marks a projected vertex that needs clipping (its fixed-point x is never this inside the guard band).
CLIP = np.int32(np.iinfo(np.int32).min)


@numba.njit(cache=True, inline="always")
def grow(bounds, u, v):  # pragma: no cover - compiled
    """Grow ``bounds`` = [umin, umax, vmin, vmax] to include the point (u, v)."""
    bounds[0] = min(bounds[0], u)
    bounds[1] = max(bounds[1], u)
    bounds[2] = min(bounds[2], v)
    bounds[3] = max(bounds[3], v)


@numba.njit(cache=True)
def prepare_vertices(pc, faces, near, fx, fy, cx, cy, width, height, xy, iz, bounds):  # pragma: no cover
    """Project camera-frame vertices ``pc`` (V, 3) once per frame.

    Writes per vertex: ``xy`` (V, 2) int32 the screen position in fixed point (1/256 px, pixel centres at
    multiples of 256), or :data:`CLIP` in x when the vertex is not usable without clipping (z < near or
    outside the guard band); ``iz`` = 1/z (0 behind the near plane). Grows ``bounds`` = [umin, umax,
    vmin, vmax] by the projection of every part of the mesh in front of the near plane: the vertices
    there, and the points where edges cross z = near (only looked for when some vertex is behind
    it). Returns True when some vertex is in front.
    """
    g = GUARD_PX
    n_behind = 0
    for i in range(pc.shape[0]):
        z = pc[i, 2]
        if z >= near:
            inv = 1.0 / z
            u = fx * pc[i, 0] * inv + cx
            v = fy * pc[i, 1] * inv + cy
            grow(bounds, u, v)
            iz[i] = inv
            if -g <= u <= width - 1.0 + g and -g <= v <= height - 1.0 + g:
                xy[i, 0] = np.int32(np.floor(u * SUBPIXEL + 0.5))
                xy[i, 1] = np.int32(np.floor(v * SUBPIXEL + 0.5))
            else:
                xy[i, 0] = CLIP
        else:
            xy[i, 0] = CLIP
            iz[i] = 0.0
            n_behind += 1
    if n_behind:
        for f in range(faces.shape[0]):
            for k in range(3):
                a = faces[f, k]
                b = faces[f, (k + 1) % 3]
                za = pc[a, 2]
                zb = pc[b, 2]
                if (za >= near) != (zb >= near):
                    t = (near - za) / (zb - za)
                    grow(bounds, fx * (pc[a, 0] + t * (pc[b, 0] - pc[a, 0])) / near + cx,
                          fy * (pc[a, 1] + t * (pc[b, 1] - pc[a, 1])) / near + cy)
    return n_behind < pc.shape[0]

