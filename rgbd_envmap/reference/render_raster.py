"""Reference of the numba rasteriser (:class:`rgbd_envmap.render.Renderer`, ``backend="numba"``):
the z-buffer written out triangle by triangle.

What the renderer draws, for a camera pose ``T_world_from_cam`` (OpenCV axes) and the colour
camera's undistorted pinhole (fx, fy, cx, cy; pixel (u, v) has its centre at integer (u, v)):

1. Every vertex goes to the camera frame, p = Rᵀ (p_world − t). A vertex in front of the near plane
   (z ≥ near) projects to u = fx x / z + cx, v = fy y / z + cy, snapped to 1/256 pixel
   (⌊256 u + ½⌋, integers); it also keeps 1 / z. A vertex behind the near plane, or beyond the
   guard band of 4096 pixels around the image, is marked for clipping.
2. A triangle whose vertices are all snapped is drawn directly. Any other is clipped in camera space
   against the near plane and the four guard-band planes (Sutherland–Hodgman; colours and alphas
   are affine there, so clipping interpolates them exactly), its corners projected and snapped the
   same way, and drawn as a fan of triangles.
3. Drawing a triangle: a pixel is covered when its centre lies inside, by integer edge functions
   E_ab(p) = (x_b − x_a)(p_y − y_a) − (y_b − y_a)(p_x − x_a) on the snapped positions (the triangle
   turned counter-clockwise first); a centre exactly on an edge is drawn by the one of the two
   triangles sharing the edge that owns it (edge direction dy > 0, or dy = 0 and dx < 0), so shared
   edges are watertight. The barycentric weights over z, l_i = E_i / area · (1 / z_i), interpolate
   1/z = Σ l_i and any attribute a = Σ l_i a_i / Σ l_i (perspective-correct).
4. The z-buffer keeps the nearest: a covered pixel is written when its 1/z is larger than the
   buffer's and not beyond the far plane. The object's triangles are drawn first, in face order,
   then the shadow plane's; a plane pixel in front of the object clears the object there.

The renderer crops its work to a rectangle that bounds the projected geometry; outside it nothing
can be covered, so the reference rasterises the whole image. The library gives the same arrays bit
for bit: the same arithmetic in the same order.
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.types import Intrinsics, RigidTransform

__all__ = ["GUARD_PX", "SUBPIXEL", "rasterise"]

#: Snapping: vertices lie on a grid of 1 / SUBPIXEL pixel.
SUBPIXEL = 256
#: The guard band around the image, in pixels, beyond which triangles are clipped.
GUARD_PX = 4096.0


def _owns_edge(dx: int, dy: int) -> bool:
    """Of the two triangles that share an edge (and see it in opposite directions) exactly one owns it."""
    return dy > 0 or (dy == 0 and dx < 0)


def _snap(value: float) -> int:
    return int(math.floor(value * SUBPIXEL + 0.5))


def _draw_triangle(xy, iz, attr, i, is_plane, inv_far, invz, colour, mask, alpha) -> None:
    """Step 3 and 4 for the triangle with vertex indices ``i`` (three) of a vertex buffer: snapped
    positions ``xy`` (integers), ``iz`` = 1/z, attributes ``attr`` (one row per vertex)."""
    H, W = invz.shape
    (x0, y0), (x1, y1), (x2, y2) = (tuple(int(c) for c in xy[k]) for k in i)
    i0, i1, i2 = i
    # the pixel centres inside the bounding box (floor / ceiling of the snapped positions / 256)
    px0, px1 = max(-((-min(x0, x1, x2)) // SUBPIXEL), 0), min(max(x0, x1, x2) // SUBPIXEL, W - 1)
    py0, py1 = max(-((-min(y0, y1, y2)) // SUBPIXEL), 0), min(max(y0, y1, y2) // SUBPIXEL, H - 1)
    if px0 > px1 or py0 > py1:
        return
    area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    if area == 0:
        return
    if area < 0:  # turn it counter-clockwise: swap the second and third vertex
        x1, y1, x2, y2 = x2, y2, x1, y1
        i1, i2 = i2, i1
        area = -area
    iz0, iz1, iz2 = iz[i0], iz[i1], iz[i2]
    if iz0 < inv_far and iz1 < inv_far and iz2 < inv_far:  # wholly beyond the far plane
        return
    edges = ((x2 - x1, y2 - y1, x1, y1), (x0 - x2, y0 - y2, x2, y2), (x1 - x0, y1 - y0, x0, y0))
    py, px = np.mgrid[py0:py1 + 1, px0:px1 + 1].astype(np.int64)
    sx, sy = px * SUBPIXEL, py * SUBPIXEL
    w = [dx * (sy - ya) - dy * (sx - xa) for dx, dy, xa, ya in edges]  # w[k] is opposite vertex k
    inside = np.ones(px.shape, bool)
    for (dx, dy, _, _), wk in zip(edges, w):
        inside &= wk >= (0 if _owns_edge(dx, dy) else 1)
    inv_area = 1.0 / area
    l0, l1, l2 = w[0] * inv_area * iz0, w[1] * inv_area * iz1, w[2] * inv_area * iz2
    izp = l0 + l1 + l2
    cells = (py, px)
    write = inside & (izp > invz[cells]) & (izp >= inv_far)
    rows, cols = py[write], px[write]
    l0, l1, l2, izp = l0[write], l1[write], l2[write], izp[write]
    invz[rows, cols] = izp
    s = 1.0 / izp
    if is_plane:
        alpha[rows, cols] = (l0 * attr[i0, 0] + l1 * attr[i1, 0] + l2 * attr[i2, 0]) * s
        hidden = mask[rows, cols]  # the plane in front of the object
        mask[rows[hidden], cols[hidden]] = False
        colour[rows[hidden], cols[hidden]] = 0.0
    else:
        for c in range(attr.shape[1]):
            colour[rows, cols, c] = (l0 * attr[i0, c] + l1 * attr[i1, c] + l2 * attr[i2, c]) * s
        mask[rows, cols] = True


def _clip(poly: list[list[float]], planes) -> list[list[float]]:
    """Sutherland–Hodgman: the part of the convex polygon ``poly`` (rows: x, y, z, attributes...) on
    the positive side n·(x, y, z) + d ≥ 0 of every plane."""
    for p in planes:
        out = []
        for k in range(len(poly)):
            a, b = poly[k], poly[(k + 1) % len(poly)]
            da = p[0] * a[0] + p[1] * a[1] + p[2] * a[2] + p[3]
            db = p[0] * b[0] + p[1] * b[1] + p[2] * b[2] + p[3]
            if da >= 0:
                out.append(list(a))
            if (da >= 0) != (db >= 0):
                t = da / (da - db)
                out.append([a[c] + t * (b[c] - a[c]) for c in range(len(a))])
        poly = out
        if len(poly) < 3:
            break
    return poly


def _draw_mesh(pc, faces, attr, is_plane, intr: Intrinsics, near, far, invz, colour, mask, alpha) -> None:
    """Steps 1–4 for one mesh: camera-frame vertices ``pc`` (V, 3), faces (F, 3), attributes (V, k)."""
    fx, fy, cx, cy, W, H = intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height
    g = GUARD_PX
    inv_far = 1.0 / far
    n = len(pc)
    xy = np.zeros((n, 2), np.int64)
    iz = np.zeros(n)
    snapped = np.zeros(n, bool)
    for k in range(n):
        z = pc[k, 2]
        if z >= near:
            inv = 1.0 / z
            u = fx * pc[k, 0] * inv + cx
            v = fy * pc[k, 1] * inv + cy
            iz[k] = inv
            if -g <= u <= W - 1.0 + g and -g <= v <= H - 1.0 + g:
                xy[k] = _snap(u), _snap(v)
                snapped[k] = True
    planes = ((0.0, 0.0, 1.0, -near), (fx, 0.0, cx + g, 0.0), (-fx, 0.0, W - 1.0 + g - cx, 0.0),
              (0.0, fy, cy + g, 0.0), (0.0, -fy, H - 1.0 + g - cy, 0.0))
    for face in faces:
        i = tuple(int(k) for k in face)
        if snapped[list(i)].all():
            _draw_triangle(xy, iz, attr, i, is_plane, inv_far, invz, colour, mask, alpha)
            continue
        if all(pc[k, 2] < near for k in i):
            continue
        poly = _clip([[*pc[k], *(float(a) for a in attr[k])] for k in i], planes)
        if len(poly) < 3:
            continue
        cxy = np.zeros((len(poly), 2), np.int64)
        ciz = np.zeros(len(poly))
        for k, q in enumerate(poly):
            z = max(q[2], near)
            ciz[k] = 1.0 / z
            cxy[k] = _snap(fx * q[0] / z + cx), _snap(fy * q[1] / z + cy)
        cattr = np.array([q[3:] for q in poly])
        for k in range(1, len(poly) - 1):  # a fan over the convex clipped polygon
            _draw_triangle(cxy, ciz, cattr, (0, k, k + 1), is_plane, inv_far, invz, colour, mask, alpha)


def rasterise(T_world_from_cam: RigidTransform, intrinsics: Intrinsics, near_m: float, far_m: float,
              object_vertices_world: np.ndarray, object_faces: np.ndarray, object_colours: np.ndarray,
              plane_vertices_world: np.ndarray, plane_faces: np.ndarray, plane_alpha: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(colour (H, W, 3) float32, mask (H, W) bool, plane alpha (H, W) float32) of the object and the
    shadow plane, as :meth:`rgbd_envmap.render.Renderer.render` gives them in its
    :class:`~rgbd_envmap.render.Layer`. Object colours are clamped at 0 and plane alphas clipped to
    [0, 1] (rounded to float32) before drawing. Slow: for small meshes and images."""
    H, W = intrinsics.height, intrinsics.width
    invz = np.zeros((H, W))
    colour = np.zeros((H, W, 3), np.float32)
    mask = np.zeros((H, W), bool)
    alpha = np.zeros((H, W), np.float32)
    r, t = T_world_from_cam.rotation, T_world_from_cam.translation
    oc = np.maximum(np.asarray(object_colours), 0.0).astype(np.float32)
    pa = np.clip(np.asarray(plane_alpha), 0.0, 1.0).astype(np.float32).reshape(-1, 1)
    for vertices, faces, attr, is_plane in ((object_vertices_world, object_faces, oc, False),
                                            (plane_vertices_world, plane_faces, pa, True)):
        pc = (np.asarray(vertices, np.float64) - t) @ r  # camera frame: Rᵀ (p − t), as row vectors
        _draw_mesh(pc, np.asarray(faces), attr, is_plane, intrinsics, near_m, far_m, invz, colour, mask, alpha)
    return colour, mask, alpha
