"""Reference of the Kinect path's warp (:func:`rgbd_envmap.ingest.kinect.warp_depth`), in float64 loops
over quads, triangles and pixels.

The previous z-depth map is a triangle mesh with one vertex per pixel centre. Each vertex is
unprojected with its depth, moved by ``T`` (T_cur_from_prev) and projected into the current view
(distortion included); it is invalid when its depth is unknown or it lands closer than ``near``.
Each grid quad (v, u)…(v + 1, u + 1) is split along the diagonal 01–10 when that 3-D edge is not
stretched, else along 00–11; a triangle is drawn when its three vertices are valid and none of its
edges is stretched (longer than ``max_stretch`` · s · min(z_a, z_b) / √|fx fy|, s = 1 for a side,
√2 for a diagonal). The pixel centres of a quad's half-open box are tested against each drawn
triangle (inclusive, tolerance 1e-7); 1/z is interpolated with the barycentrics and the closest
depth wins, with the weight of the triangle's nearest vertex (largest barycentric). Finally every
rim vertex (used by a drawn triangle, not surrounded by four full quads) is splatted onto its
nearest pixel when no triangle covered it, with the depth there of the plane of its first drawn
triangle.

The kernels (:mod:`rgbd_envmap._kernels.kinect`) work in float32 relative to pixel centres; the tests
ask for the same coverage and weights and the depth within float32 rounding.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.geometry import pixel_rays, project_points
from rgbd_envmap.types import Intrinsics, RigidTransform

__all__ = ["TRIANGLES", "warp_reference"]

#: Triangles of quad (v, u) as (dv, du) corners: bits 0, 1 split along 01–10, bits 2, 3 along 00–11.
TRIANGLES = (((0, 0), (0, 1), (1, 0)), ((0, 1), (1, 1), (1, 0)), ((0, 0), (0, 1), (1, 1)), ((0, 0), (1, 1), (1, 0)))


def _pinhole_rays(intr: Intrinsics) -> np.ndarray:
    """(H, W, 3) rays ((u − cx) / fx, (v − cy) / fy, 1) of a camera without distortion."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)


def warp_reference(depth: np.ndarray, weight: np.ndarray, known: np.ndarray, intr: Intrinsics, T: RigidTransform,
                   max_stretch: float = 20.0, near: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The warp as the module docstring states it: vertices projected with
    :func:`rgbd_envmap.geometry.project_points`, the stretch test on 3-D edges, half-open pixel-centre
    boxes per quad, an inclusive barycentric test (−1e-7), 1/z interpolated, closest wins with the
    weight of the nearest vertex, then rim vertices splatted onto uncovered nearest pixels with the
    plane depth of their first drawn triangle.

    Returns:
        (depth (H, W) float64, 0 where not known; weight (H, W) float32; known (H, W) bool).
    """
    h, w = intr.shape
    d = np.where(known & np.isfinite(depth) & (depth > 0), depth, 0).astype(np.float64)
    rays = pixel_rays(intr)[..., :2] if not intr.distortion.is_zero else _pinhole_rays(intr)[..., :2]
    P = np.dstack([rays * d[..., None], d])
    Q = P @ T.rotation.T + T.translation
    valid = (d > 0) & (Q[..., 2] >= near)
    Qs = np.where(valid[..., None], Q, [0.0, 0.0, 1.0])
    uv, _ = project_points(Qs.reshape(-1, 3), intr)
    X, Y = uv[:, 0].reshape(h, w), uv[:, 1].reshape(h, w)
    IZ = np.where(valid, 1.0 / Qs[..., 2], 0.0)
    k2 = (max_stretch / np.sqrt(abs(intr.fx * intr.fy))) ** 2

    def ok(a, b, s2):
        zm = min(P[a][2], P[b][2])
        return zm > 0 and float(np.sum((P[a] - P[b]) ** 2)) <= s2 * k2 * zm * zm

    zbuf = np.full((h, w), np.inf)
    wbuf = np.zeros((h, w), np.float32)
    codes = np.zeros((h + 1, w + 1), int)  # quad (v, u) at [v + 1, u + 1]; zero border
    for v in range(h - 1):
        for u in range(w - 1):
            c00, c01, c10, c11 = (v, u), (v, u + 1), (v + 1, u), (v + 1, u + 1)
            g = [valid[c] for c in (c00, c01, c10, c11)]
            anti = ok(c01, c10, 2.0)
            main = ok(c00, c11, 2.0) and not anti
            top, bot, lef, rig = ok(c00, c01, 1.0), ok(c10, c11, 1.0), ok(c00, c10, 1.0), ok(c01, c11, 1.0)
            bits = [anti and top and lef and g[0] and g[1] and g[2], anti and rig and bot and g[1] and g[3] and g[2],
                    main and top and rig and g[0] and g[1] and g[3], main and bot and lef and g[0] and g[3] and g[2]]
            codes[v + 1, u + 1] = sum(1 << i for i, b in enumerate(bits) if b)
            tris = [[(v + dv, u + du) for dv, du in TRIANGLES[i]] for i, b in enumerate(bits) if b]
            if not tris:
                continue
            used = {c for tri in tris for c in tri}
            xs, ys = [X[c] for c in used], [Y[c] for c in used]
            xlo, xhi = max(np.ceil(min(xs) - 1e-6), 0), min(np.ceil(max(xs) - 1e-6) - 1, w - 1)
            ylo, yhi = max(np.ceil(min(ys) - 1e-6), 0), min(np.ceil(max(ys) - 1e-6) - 1, h - 1)
            for a, b, c in tris:
                area = (X[b] - X[a]) * (Y[c] - Y[a]) - (X[c] - X[a]) * (Y[b] - Y[a])
                if abs(area) <= 1e-12:
                    continue
                for py in range(int(ylo), int(yhi) + 1):
                    for px in range(int(xlo), int(xhi) + 1):
                        ba = ((X[b] - px) * (Y[c] - py) - (X[c] - px) * (Y[b] - py)) / area
                        bb = ((X[c] - px) * (Y[a] - py) - (X[a] - px) * (Y[c] - py)) / area
                        bary = (ba, bb, 1.0 - ba - bb)
                        if min(bary) < -1e-7:
                            continue
                        z = 1.0 / (bary[0] * IZ[a] + bary[1] * IZ[b] + bary[2] * IZ[c])
                        if z < zbuf[py, px]:
                            zbuf[py, px] = z
                            wbuf[py, px] = weight[(a, b, c)[int(np.argmax(bary))]]
    covered = np.isfinite(zbuf)
    splat = np.full((h, w), np.inf)
    for v in range(h):
        for u in range(w):
            quads = [(codes[v + 1, u + 1] & 13, v, u), (codes[v + 1, u] & 7, v, u - 1),
                     (codes[v, u + 1] & 11, v - 1, u), (codes[v, u] & 14, v - 1, u - 1)]
            full = all(codes[qv + 1, qu + 1] in (3, 12) for _, qv, qu in quads)
            drawn = [(m, qv, qu) for m, qv, qu in quads if m]
            if not drawn or full:
                continue
            px, py = int(np.floor(X[v, u] + 0.5)), int(np.floor(Y[v, u] + 0.5))
            if not (0 <= px < w and 0 <= py < h) or covered[py, px]:
                continue
            m, qv, qu = drawn[0]
            a, b, c = [(qv + dv, qu + du) for dv, du in TRIANGLES[(int(m) & -int(m)).bit_length() - 1]]
            z = 1.0 / IZ[v, u]
            area = (X[b] - X[a]) * (Y[c] - Y[a]) - (X[c] - X[a]) * (Y[b] - Y[a])
            if abs(area) > 1e-12:
                ba = ((X[b] - px) * (Y[c] - py) - (X[c] - px) * (Y[b] - py)) / area
                bb = ((X[c] - px) * (Y[a] - py) - (X[a] - px) * (Y[c] - py)) / area
                ext = ba * IZ[a] + bb * IZ[b] + (1.0 - ba - bb) * IZ[c]
                z = 1.0 / ext if ext > 0 else z
            if z < splat[py, px]:
                splat[py, px] = z
                wbuf[py, px] = weight[v, u]
    zbuf = np.where(covered, zbuf, splat)
    known_out = np.isfinite(zbuf)
    return np.where(known_out, zbuf, 0.0), np.where(known_out, wbuf, 0.0), known_out
