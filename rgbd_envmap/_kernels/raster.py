"""Kernels of the numba rasteriser: a z-buffer with watertight fixed-point edge functions.

Triangles whose vertices all have a fixed-point screen position
(:func:`rgbd_envmap._kernels.raster_camera.prepare_vertices`) are rasterised directly; the others
are clipped in camera space (Sutherland–Hodgman against the near plane and the guard band, where
the attributes are affine) and fan-triangulated. A pixel is covered when its centre lies inside the
triangle; a centre exactly on an edge shared by two triangles is drawn by exactly one of them
(:func:`owns_edge`). Attributes are interpolated perspective-correctly (attribute / z and 1 / z
linear in screen space). What they compute, in plain numpy:
:mod:`rgbd_envmap.reference.render_raster`. Called from :mod:`rgbd_envmap.render.raster` only.
"""

from __future__ import annotations

import numba
import numpy as np

from rgbd_envmap._kernels.raster_camera import CLIP, GUARD_PX, SUBPIXEL, SUBPIXEL_BITS

__all__ = ["owns_edge", "raster_triangle", "raster_mesh"]


@numba.njit(cache=True, inline="always")
def owns_edge(dx, dy):  # pragma: no cover - compiled
    """Tie rule for a pixel centre exactly on an edge (a→b, dx = xb − xa, dy = yb − ya): of the two
    triangles sharing the edge (which see it in opposite directions) exactly one owns it."""
    return dy > 0 or (dy == 0 and dx < 0)


@numba.njit(cache=True, inline="always")
def raster_triangle(xy, iz, attr, i0, i1, i2, is_plane, inv_far, r0, r1, c0, c1,
                     invz, colour, mask, alpha):  # pragma: no cover - compiled
    """Rasterise triangle (i0, i1, i2) of a vertex buffer: fixed-point screen positions ``xy`` (V, 2)
    (1/256 px), ``iz`` = 1/z, linear attributes ``attr`` (V, k). Perspective-correct: attribute/z and 1/z
    are interpolated linearly in screen space. The object is drawn before the plane (as pyrender does:
    it draws the plane, a "transparent" mesh, last), both with a strict depth test."""
    x0, y0 = np.int64(xy[i0, 0]), np.int64(xy[i0, 1])
    x1, y1 = np.int64(xy[i1, 0]), np.int64(xy[i1, 1])
    x2, y2 = np.int64(xy[i2, 0]), np.int64(xy[i2, 1])
    # Pixel centres inside the bounding box (arithmetic shifts: floor division by 256); most triangles
    # of a dense mesh contain none and stop here.
    px0 = max(-((-min(x0, min(x1, x2))) >> SUBPIXEL_BITS), c0)
    px1 = min(max(x0, max(x1, x2)) >> SUBPIXEL_BITS, c1 - 1)
    if px0 > px1:
        return
    py0 = max(-((-min(y0, min(y1, y2))) >> SUBPIXEL_BITS), r0)
    py1 = min(max(y0, max(y1, y2)) >> SUBPIXEL_BITS, r1 - 1)
    if py0 > py1:
        return
    area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    if area == 0:
        return
    if area < 0:  # one orientation for the edge functions: swap v1 and v2
        x1, y1, x2, y2 = x2, y2, x1, y1
        i1, i2 = i2, i1
        area = -area
    iz0, iz1, iz2 = iz[i0], iz[i1], iz[i2]
    if iz0 < inv_far and iz1 < inv_far and iz2 < inv_far:  # wholly beyond the far plane
        return
    # Edge functions E_ab(p) = (xb − xa)(py − ya) − (yb − ya)(px − xa); w0 is opposite v0, etc.
    e0dx, e0dy = x2 - x1, y2 - y1
    e1dx, e1dy = x0 - x2, y0 - y2
    e2dx, e2dy = x1 - x0, y1 - y0
    b0 = 0 if owns_edge(e0dx, e0dy) else 1
    b1 = 0 if owns_edge(e1dx, e1dy) else 1
    b2 = 0 if owns_edge(e2dx, e2dy) else 1
    inv_area = 1.0 / area
    n_attr = attr.shape[1]
    sx = px0 * SUBPIXEL
    for py in range(py0, py1 + 1):
        sy = py * SUBPIXEL
        w0 = e0dx * (sy - y1) - e0dy * (sx - x1)
        w1 = e1dx * (sy - y2) - e1dy * (sx - x2)
        w2 = e2dx * (sy - y0) - e2dy * (sx - x0)
        for px in range(px0, px1 + 1):
            if w0 >= b0 and w1 >= b1 and w2 >= b2:
                l0 = w0 * inv_area * iz0
                l1 = w1 * inv_area * iz1
                l2 = w2 * inv_area * iz2
                izp = l0 + l1 + l2
                if izp > invz[py, px] and izp >= inv_far:
                    invz[py, px] = izp
                    s = 1.0 / izp
                    if is_plane:
                        alpha[py, px] = (l0 * attr[i0, 0] + l1 * attr[i1, 0] + l2 * attr[i2, 0]) * s
                        if mask[py, px]:  # the plane in front of the object
                            mask[py, px] = False
                            for c in range(3):
                                colour[py, px, c] = 0.0
                    else:
                        for c in range(n_attr):
                            colour[py, px, c] = (l0 * attr[i0, c] + l1 * attr[i1, c] + l2 * attr[i2, c]) * s
                        mask[py, px] = True
            w0 -= e0dy * SUBPIXEL
            w1 -= e1dy * SUBPIXEL
            w2 -= e2dy * SUBPIXEL


@numba.njit(cache=True)
def raster_mesh(pc, faces, attr, xy, iz, is_plane, near, far, fx, fy, cx, cy, width, height,
                 r0, r1, c0, c1, invz, colour, mask, alpha):  # pragma: no cover - compiled
    """Rasterise every triangle of one mesh into the z-buffer ``invz`` (1/z, 0 = empty) and the layer
    arrays, within rows [r0, r1) and columns [c0, c1). ``xy, iz`` from
    :func:`~rgbd_envmap._kernels.raster_camera.prepare_vertices`; triangles with a vertex marked
    :data:`CLIP` are clipped in camera space first."""
    n_attr = attr.shape[1]
    inv_far = 1.0 / far
    # Clip planes n·(x, y, z) + d ≥ 0 in camera space: near, and the four guard-band planes
    # u ≥ −G, u ≤ W − 1 + G, v ≥ −G, v ≤ H − 1 + G.
    g = GUARD_PX
    planes = np.array([
        [0.0, 0.0, 1.0, -near],
        [fx, 0.0, cx + g, 0.0],
        [-fx, 0.0, width - 1.0 + g - cx, 0.0],
        [0.0, fy, cy + g, 0.0],
        [0.0, -fy, height - 1.0 + g - cy, 0.0],
    ])
    nv = 3 + n_attr
    poly = np.empty((9, nv))  # a triangle clipped by five planes has at most 8 vertices
    tmp = np.empty((9, nv))
    cxy = np.empty((9, 2), np.int32)  # the clipped polygon as a small vertex buffer
    ciz = np.empty(9)
    cattr = np.empty((9, n_attr))
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if xy[i0, 0] != CLIP and xy[i1, 0] != CLIP and xy[i2, 0] != CLIP:
            raster_triangle(xy, iz, attr, i0, i1, i2, is_plane, inv_far, r0, r1, c0, c1,
                             invz, colour, mask, alpha)
            continue
        if pc[i0, 2] < near and pc[i1, 2] < near and pc[i2, 2] < near:
            continue
        # Sutherland–Hodgman against the near and guard-band planes, in camera space, where the
        # attributes are affine (so clipping interpolates them exactly).
        n = 3
        for k in range(3):
            idx = faces[f, k]
            for c in range(3):
                poly[k, c] = pc[idx, c]
            for c in range(n_attr):
                poly[k, 3 + c] = attr[idx, c]
        for p in range(planes.shape[0]):
            m = 0
            for k in range(n):
                kn = (k + 1) % n
                da = planes[p, 0] * poly[k, 0] + planes[p, 1] * poly[k, 1] + planes[p, 2] * poly[k, 2] + planes[p, 3]
                db = (planes[p, 0] * poly[kn, 0] + planes[p, 1] * poly[kn, 1] + planes[p, 2] * poly[kn, 2]
                      + planes[p, 3])
                if da >= 0:
                    tmp[m, :] = poly[k, :]
                    m += 1
                if (da >= 0) != (db >= 0):
                    t = da / (da - db)
                    for c in range(nv):
                        tmp[m, c] = poly[k, c] + t * (poly[kn, c] - poly[k, c])
                    m += 1
            n = m
            for k in range(n):
                poly[k, :] = tmp[k, :]
            if n < 3:
                break
        if n < 3:
            continue
        for k in range(n):
            z = max(poly[k, 2], near)
            ciz[k] = 1.0 / z
            cxy[k, 0] = np.int32(np.floor((fx * poly[k, 0] / z + cx) * SUBPIXEL + 0.5))
            cxy[k, 1] = np.int32(np.floor((fy * poly[k, 1] / z + cy) * SUBPIXEL + 0.5))
            for c in range(n_attr):
                cattr[k, c] = poly[k, 3 + c]
        for k in range(1, n - 1):  # fan-triangulate the convex clipped polygon
            raster_triangle(cxy, ciz, cattr, 0, k, k + 1, is_plane, inv_far, r0, r1, c0, c1,
                             invz, colour, mask, alpha)

