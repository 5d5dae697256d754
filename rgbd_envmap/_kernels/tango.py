"""Kernels of the Tango ingest (:mod:`rgbd_envmap.ingest.tango`), called from that module only.

The per-packet work is split into passes that each do one thing over contiguous arrays, so that the
arithmetic passes compile to SIMD code: projection through a camera is branch-free (a rejected point
gets an "invalid" marker instead of a ``continue``) and reads the (N, 3) points as a flat array (with
2-D indexing LLVM does not vectorise the strided loads). Only the z-buffer and the bilinear lookups,
which scatter and gather, stay scalar. All arithmetic is the same IEEE sequence as a plain per-point
loop (no fastmath; numpy error model, so no division-by-zero branches), so the results are bit for
bit those of that loop, :func:`rgbd_envmap.reference.tango.rgbd_frame_reference` (tested).
"""

from __future__ import annotations

import numba
import numpy as np

from rgbd_envmap.geometry import brown_distort

__all__ = [
    "pixel_of",
    "texel_of",
    "depth_camera",
    "colour_camera",
    "project_depth",
    "project_colour",
    "project_both",
    "zbuffer",
    "bilinear",
    "depth_image_kernel",
    "colour_kernel",
    "rgbd_kernel",
    "filled_kernel",
]


@numba.njit(cache=True, error_model="numpy")
def pixel_of(x, y, z, conf, threshold, camera):  # pragma: no cover - compiled
    """row · width + col of the pixel nearest the projection of depth-frame point (x, y, z), or −1
    (confidence < threshold or NaN, non-finite, z ≤ 0, outside the image). Branch-free.
    ``camera``: :func:`depth_camera`."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3, wf, hf, w32 = camera
    ok = (conf >= threshold) & (z > 0.0) & np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    xd, yd = brown_distort(x / z, y / z, k1, k2, p1, p2, k3)
    col = np.floor(fx * xd + cx + 0.5)  # the nearest pixel centre
    row = np.floor(fy * yd + cy + 0.5)
    ok = ok & (col >= 0.0) & (col < wf) & (row >= 0.0) & (row < hf)  # NaN fails
    return np.int32(row if ok else 0.0) * w32 + np.int32(col if ok else 0.0) if ok else np.int32(-1)


@numba.njit(cache=True, error_model="numpy")
def texel_of(px, py, pz, camera):  # pragma: no cover - compiled
    """Where depth-frame point (px, py, pz) falls in a colour image: the flat offset
    (y0 · width + x0) · 3 of the top-left texel of its bilinear 2×2 (x0 = min(⌊u⌋, width − 2), so the
    2×2 stays inside) and the weights u − x0, v − y0; offset −1 when the point is behind the camera,
    non-finite, or projects outside [0, width − 1] × [0, height − 1]. Branch-free.
    ``camera``: :func:`colour_camera`."""
    (r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2, fx, fy, cx, cy, k1, k2, p1, p2, k3,
     u_max, v_max, x0_max, y0_max, w32) = camera
    x = r00 * px + r01 * py + r02 * pz + t0
    y = r10 * px + r11 * py + r12 * pz + t1
    z = r20 * px + r21 * py + r22 * pz + t2
    ok = (z > 0.0) & np.isfinite(x) & np.isfinite(y)
    xd, yd = brown_distort(x / z, y / z, k1, k2, p1, p2, k3)
    u = fx * xd + cx
    v = fy * yd + cy
    ok = ok & (u >= 0.0) & (u <= u_max) & (v >= 0.0) & (v <= v_max)  # NaN fails
    u = u if ok else 0.0
    v = v if ok else 0.0
    x0 = min(np.int32(u), x0_max)
    y0 = min(np.int32(v), y0_max)
    return (y0 * w32 + x0) * np.int32(3) if ok else np.int32(-1), u - x0, v - y0


@numba.njit(cache=True, error_model="numpy")
def depth_camera(cam, dist, height, width):  # pragma: no cover - compiled
    return (cam[0], cam[1], cam[2], cam[3], dist[0], dist[1], dist[2], dist[3], dist[4],
            float(width), float(height), np.int32(width))


@numba.njit(cache=True, error_model="numpy")
def colour_camera(rot, trans, cam, dist, width, height):  # pragma: no cover - compiled
    return (rot[0, 0], rot[0, 1], rot[0, 2], rot[1, 0], rot[1, 1], rot[1, 2], rot[2, 0], rot[2, 1], rot[2, 2],
            trans[0], trans[1], trans[2], cam[0], cam[1], cam[2], cam[3], dist[0], dist[1], dist[2], dist[3], dist[4],
            float(width - 1), float(height - 1), np.int32(max(width - 2, 0)), np.int32(max(height - 2, 0)),
            np.int32(width))


# Three loops rather than one with "which outputs" flags: with flags LLVM kept the fused loop slower.
# Each reads the (N, 3) points as a flat array: with 2-D indexing it does not vectorise.

@numba.njit(cache=True, error_model="numpy")
def project_depth(points, confidence, threshold, cam, dist, height, width, pix):  # pragma: no cover - compiled
    """pix[i] = :func:`pixel_of` of each point of C-contiguous (N, 3) ``points``."""
    c = depth_camera(cam, dist, height, width)
    flat = points.reshape(-1)
    for i in range(points.shape[0]):
        pix[i] = pixel_of(flat[3 * i], flat[3 * i + 1], flat[3 * i + 2], confidence[i], threshold, c)


@numba.njit(cache=True, error_model="numpy")
def project_colour(points, rot, trans, cam, dist, width, height, off, wu, wv):  # pragma: no cover - compiled
    """off[i], wu[i], wv[i] = :func:`texel_of` of each point (``rot``, ``trans``: T_colour_from_depth)."""
    c = colour_camera(rot, trans, cam, dist, width, height)
    flat = points.reshape(-1)
    for i in range(points.shape[0]):
        off[i], wu[i], wv[i] = texel_of(flat[3 * i], flat[3 * i + 1], flat[3 * i + 2], c)


@numba.njit(cache=True, error_model="numpy")
def project_both(points, confidence, threshold, dcam, ddist, height, width, rot, trans, ccam, cdist, cwidth, cheight,
                  pix, off, wu, wv):  # pragma: no cover - compiled
    """:func:`project_depth` and :func:`project_colour` in one pass over the points."""
    d = depth_camera(dcam, ddist, height, width)
    c = colour_camera(rot, trans, ccam, cdist, cwidth, cheight)
    flat = points.reshape(-1)
    for i in range(points.shape[0]):
        x = flat[3 * i]
        y = flat[3 * i + 1]
        z = flat[3 * i + 2]
        pix[i] = pixel_of(x, y, z, confidence[i], threshold, d)
        off[i], wu[i], wv[i] = texel_of(x, y, z, c)


@numba.njit(cache=True, error_model="numpy")
def zbuffer(points, pix, height, width):  # pragma: no cover - compiled
    """(H, W) float32 depth and int32 winning point index (−1: none) of the points at ``pix``; the
    smallest z wins a shared pixel, the earlier point a tie."""
    depth = np.zeros((height, width), np.float32)
    index = np.full((height, width), -1, np.int32)
    d = depth.reshape(-1)
    idx = index.reshape(-1)
    flat = points.reshape(-1)
    for i in range(pix.shape[0]):
        p = pix[i]
        if p >= 0:
            z = flat[3 * i + 2]
            if idx[p] < 0 or z < d[p]:
                d[p] = z
                idx[p] = i
    return depth, index


@numba.njit(cache=True, error_model="numpy")
def bilinear(order, off, wu, wv, image, lut, rgb, seen):  # pragma: no cover - compiled
    """rgb[k] = bilinear linear colour at the texel of point ``order[k]`` (see :func:`texel_of`),
    decoding the four sRGB texels through ``lut`` (float64) before interpolating; zero and
    ``seen[k]`` False where ``order[k]`` is −1 or the point has no texel."""
    h, w = image.shape[0], image.shape[1]
    flat = image.reshape(-1)
    # Unsigned offsets: no negative-index wraparound code around the twelve loads.
    du = np.uint64(3 if w > 1 else 0)  # the right / lower neighbour, clamped in a 1-wide image
    dv = np.uint64(3 * w if h > 1 else 0)
    one = np.uint64(1)
    two = np.uint64(2)
    for k in range(order.shape[0]):
        i = order[k]
        o = off[i] if i >= 0 else np.int32(-1)
        r = np.float32(0.0)
        g = np.float32(0.0)
        b = np.float32(0.0)
        if o >= 0:
            au = wu[i]
            av = wv[i]
            bu = 1.0 - au
            bv = 1.0 - av
            a0 = np.uint64(o)
            a1 = a0 + du
            c0 = a0 + dv
            c1 = c0 + du
            top = bu * lut[flat[a0]] + au * lut[flat[a1]]
            bottom = bu * lut[flat[c0]] + au * lut[flat[c1]]
            r = np.float32(bv * top + av * bottom)
            top = bu * lut[flat[a0 + one]] + au * lut[flat[a1 + one]]
            bottom = bu * lut[flat[c0 + one]] + au * lut[flat[c1 + one]]
            g = np.float32(bv * top + av * bottom)
            top = bu * lut[flat[a0 + two]] + au * lut[flat[a1 + two]]
            bottom = bu * lut[flat[c0 + two]] + au * lut[flat[c1 + two]]
            b = np.float32(bv * top + av * bottom)
        rgb[k, 0] = r
        rgb[k, 1] = g
        rgb[k, 2] = b
        seen[k] = o >= 0


@numba.njit(cache=True, error_model="numpy")
def depth_image_kernel(points, confidence, threshold, cam, dist, height, width, pix):  # pragma: no cover
    """:func:`rgbd_envmap.ingest.tango.depth_image_from_points` in one call (the scratch ``pix`` is not shared across calls)."""
    project_depth(points, confidence, threshold, cam, dist, height, width, pix)
    return zbuffer(points, pix, height, width)


@numba.njit(cache=True, error_model="numpy")
def colour_kernel(points, rot, trans, cam, dist, image, lut, off, wu, wv):  # pragma: no cover - compiled
    """Colour of each point, (rgb (N, 3) float32, seen (N,) bool), in one call."""
    n = points.shape[0]
    project_colour(points, rot, trans, cam, dist, image.shape[1], image.shape[0], off, wu, wv)
    rgb = np.empty((n, 3), np.float32)
    seen = np.empty(n, np.bool_)
    bilinear(np.arange(n), off, wu, wv, image, lut, rgb, seen)
    return rgb, seen


@numba.njit(cache=True, error_model="numpy")
def rgbd_kernel(
    points, confidence, threshold, dcam, ddist, height, width, T_colour_from_depth, ccam, cdist, image, lut, pix, off, wu, wv
):  # pragma: no cover - compiled
    """The whole point cloud → RGB-D frame: (raw depth, point index, raw known, depth, known, rgb), all
    (H, W); ``T_colour_from_depth`` is the 4×4 matrix."""
    rot = T_colour_from_depth[:3, :3]
    trans = T_colour_from_depth[:3, 3]
    project_both(points, confidence, threshold, dcam, ddist, height, width, rot, trans, ccam, cdist,
                  image.shape[1], image.shape[0], pix, off, wu, wv)
    raw, index = zbuffer(points, pix, height, width)
    rgb = np.empty((height, width, 3), np.float32)
    known = np.empty((height, width), np.bool_)
    bilinear(index.reshape(-1), off, wu, wv, image, lut, rgb.reshape(-1, 3), known.reshape(-1))
    depth = np.empty((height, width), np.float32)
    raw_known = np.empty((height, width), np.bool_)
    d = depth.reshape(-1)
    k = known.reshape(-1)
    r = raw.reshape(-1)
    rk = raw_known.reshape(-1)
    i = index.reshape(-1)
    for p in range(d.shape[0]):
        d[p] = r[p] if k[p] else np.float32(0.0)
        rk[p] = i[p] >= 0
    return raw, index, raw_known, depth, known, rgb


@numba.njit(cache=True, error_model="numpy")
def filled_kernel(
    rgb_in, depth_in, known_in, filled_depth, filled_known, rays, rot, trans, cam, dist, image, lut
):  # pragma: no cover - compiled
    """:func:`rgbd_envmap.ingest.tango.colour_filled_pixels` on (H, W) arrays: known pixels copied,
    newly filled ones coloured from the point ``ray · filled depth`` (float64), the others keep
    ``rgb_in`` / unknown / depth 0."""
    h, w = known_in.shape
    n = h * w
    kin = known_in.reshape(-1)
    kf = filled_known.reshape(-1)
    m = 0
    for p in range(n):
        if kf[p] and not kin[p]:
            m += 1
    order = np.empty(m, np.int64)
    points = np.empty((m, 3))
    fd = filled_depth.reshape(-1)
    ray = rays.reshape(-1, 3)
    j = 0
    for p in range(n):
        if kf[p] and not kin[p]:
            d = fd[p]
            points[j, 0] = ray[p, 0] * d
            points[j, 1] = ray[p, 1] * d
            points[j, 2] = ray[p, 2] * d
            order[j] = p
            j += 1
    off = np.empty(m, np.int32)
    wu = np.empty(m)
    wv = np.empty(m)
    project_colour(points, rot, trans, cam, dist, image.shape[1], image.shape[0], off, wu, wv)
    colours = np.empty((m, 3), np.float32)
    seen = np.empty(m, np.bool_)
    bilinear(np.arange(m), off, wu, wv, image, lut, colours, seen)
    rgb = rgb_in.copy()
    known = known_in.copy()
    depth = np.empty((h, w), np.float32)
    flat_rgb = rgb.reshape(-1, 3)
    kout = known.reshape(-1)
    dout = depth.reshape(-1)
    din = depth_in.reshape(-1)
    for p in range(n):
        dout[p] = din[p] if kin[p] else np.float32(0.0)
    for j in range(m):
        p = order[j]
        flat_rgb[p, 0] = colours[j, 0]
        flat_rgb[p, 1] = colours[j, 1]
        flat_rgb[p, 2] = colours[j, 2]
        kout[p] = seen[j]
        if seen[j]:
            dout[p] = np.float32(fd[p])
    return rgb, depth, known
