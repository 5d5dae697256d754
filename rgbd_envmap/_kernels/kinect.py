"""Kernels of the Kinect path's warp, merge and normals (:mod:`rgbd_envmap.ingest.kinect`), called
from that module only.

What the warp computes is written plainly, in float64 loops over quads, triangles and pixels, in
:func:`rgbd_envmap.reference.kinect.warp_reference`; the tests compare the two (same coverage, same
weights, depth within float32 rounding).

Data layout. A depth map enters the kernels "clean": float32 z-depth with 0 wherever the pixel is
unknown or not finite and > 0. Camera-frame points (float32 x, y, z from float32 rays) exist only in
a ring of three rows and a zero row inside the merge / normals kernels; a zero point (unknown, or
outside the image) fails every stretch test by itself (min(z_a, z_b) = 0). The merge leaves the
edge flags of the map it produced in E (4, H, W) bool (edge right, down, diagonal, anti-diagonal
usable), which is all the next warp needs of the previous view's geometry.

Warp (:func:`warp_kernel`): one pass over the rows with a ring of three vertex rows and two quad
rows; nothing image-sized is written but the z-buffer. A vertex is kept as its pixel cell
ceil(x − ε), ceil(y − ε) (whole numbers in float32) and the offset of its position from that cell,
with z and 1/z (float32). Without distortion the offset comes from the vertex's displacement from its
own pixel centre, computed in float32 with an error relative to the motion (~1e-7 px per pixel of
motion; exactly 0 for no motion); with distortion the position is projected in float64.

Rasterisation. Pixel centres are enumerated half-open, [x_min − ε, x_max − ε) × [y_min − ε,
y_max − ε) per quad, so a pixel centre on a shared vertex or edge is tried by one quad only (under
an identity warp every quad holds exactly its top-left pixel). Since ceil is monotonic, a quad's box
is the min / max of its vertices' cells, the same for every quad that shares a vertex. A branch-free
float32 pass (8 lanes) resolves every quad whose box holds one pixel centre — 97–99 % of them for
frame-to-frame motion — with barycentrics from positions relative to that pixel centre, (cell −
pixel) + offset, within ~1e-7 px of the exact ones whatever the motion (inclusive test, tolerance
2e-6). The rest — several candidate pixels, a quad folded over itself, or a triangle of less than
1/32 px² — go to a float64 rasteriser. The z-buffer holds (weight, z) float32 pairs that read as one
uint64 with z in the high half; a positive float orders like its bits, so z-buffering the one-pixel
results is a branch-free integer min. Pixel centres on the outer boundary of a surface are caught by
splatting the rim vertices (:func:`rim_row`), after the last row, since any triangle may still
cover their pixel.

Why the code is shaped as it is (benchmarks/bench_kinect.py times it): LLVM does not vectorise a
loop that writes several arrays while reading others when it cannot rule out aliasing (too many
runtime checks), so hot loops write few arrays, outputs handed to the caller are allocated inside
the kernels, and per-row scratch lives in small local buffers; numba widens integer arithmetic to
64 bits, so the 8-lane float32 loops keep flags as bools and cells as float32; image-sized scratch
allocated and freed on every call costs page faults on every call, so it lives in a workspace that
:class:`rgbd_envmap.ingest.kinect.KinectMerger` keeps between frames.
"""

from __future__ import annotations

import math
import sys
from collections import namedtuple

import numba
import numpy as np

__all__ = [
    "NJ",
    "EMPTY_KEY",
    "ZI",
    "WI",
    "Ring",
    "clean_depth",
    "edge_ok",
    "vertex",
    "vertex_row",
    "vertex_row32",
    "vertex_into",
    "code_row",
    "fast_row",
    "xyi",
    "tri",
    "scatter_row",
    "rim_row",
    "warp_kernel",
    "unpack_warp",
    "valid_or_inf_into",
    "merge_pixel",
    "merge_arrays",
    "ring_slot",
    "points_row",
    "normals_edges_row",
    "merge_normals",
    "normals_edges",
]

# Barycentric tolerance of the rasteriser (a pixel centre within this of a triangle counts as inside):
# it keeps pixel centres that sit exactly on a vertex or a shared edge from being lost to rounding,
# e.g. under an identity warp, where every vertex lands on its own pixel centre ± 1e-13 px.
BARY_EPS = 1e-7

#: numba options of the kernels that are not inlined.
NJ = {"cache": True, "error_model": "numpy"}

# The warp's ring of three vertex rows (see :func:`warp_kernel`): pixel cells of the screen positions,
# the offsets from them, z and 1/z (float32); quad codes of two quad rows (uint8, zero-bordered) and
# their split / drawn-triangle flags.
Ring = namedtuple("Ring", "CX CY FX FY Z IZ C A TA TB")

# Triangles of the quad with corners 00 = (v, u), 01 = (v, u+1), 10 = (v+1, u), 11 = (v+1, u+1):
# bit 0: 00-01-10 and bit 1: 01-11-10 (split along 01–10); bit 2: 00-01-11 and bit 3: 00-11-10
# (split along 00–11). Masks of the triangles that use each corner:
USES_00, USES_01, USES_10, USES_11 = 13, 7, 11, 14
# Rim splats: the lowest set bit of a 4-bit mask, and for a vertex that is corner 00, 01, 10, 11 of
# quad q = 0 … 3 ((v, u), (v, u−1), (v−1, u), (v−1, u−1)), the other two vertices of triangle ``bit``
# of that quad as (dv, du, dv, du) relative to the vertex.
LOWBIT = np.array([0, 0, 1, 0, 2, 0, 1, 0, 3, 0, 1, 0, 2, 0, 1, 0], np.int64)


def rim_triangles() -> np.ndarray:
    tris = ((0, 1, 2), (1, 3, 2), (0, 1, 3), (0, 3, 2))  # corners 0 = 00, 1 = 01, 2 = 10, 3 = 11
    table = np.zeros((4, 4, 4), np.int64)
    for q in range(4):  # the vertex is corner q of quad q, whose origin is (−(q >> 1), −(q & 1)) from it
        for bit, corners in enumerate(tris):
            if q in corners:
                others = [c for c in corners if c != q]
                table[q, bit] = [d for c in others for d in ((c >> 1) - (q >> 1), (c & 1) - (q & 1))]
    return table


RIM_TRI = rim_triangles()
# Half-open shift of the pixel-centre enumeration, pixels.
ENUM_EPS = 1e-6
# Vertex pixel cells beyond ±this are "far off-screen" (whole numbers stay exact in float32).
CELL_LIM = float(1 << 22)
# One-pixel pass in float32 pixel-relative coordinates (errors ≲ 1e-7 px): its barycentric tolerance,
# and the smallest |2 · area| (px²) of a triangle it handles; thinner ones go to the float64 rasteriser.
BARY_EPS32 = np.float32(2e-6)
AREA_MIN32 = np.float32(1.0 / 16.0)
# The z-buffer holds (weight, z) float32 pairs; read as one uint64, z is the high half.
ZI, WI = (1, 0) if sys.byteorder == "little" else (0, 1)
EMPTY_KEY = np.uint64(0x7F800000 << 32)  # z = +inf, weight 0


@numba.njit(**NJ)
def clean_depth(depth, known):  # pragma: no cover - compiled
    """float32 copy of ``depth`` with 0 wherever the pixel is unknown, non-finite or ≤ 0."""
    h, w = depth.shape
    out = np.empty((h, w), np.float32)
    for v in range(h):
        for u in range(w):
            d = depth[v, u]
            out[v, u] = d if (known[v, u] and d > 0.0 and d < np.inf) else np.float32(0.0)
    return out


@numba.njit(cache=True, error_model="numpy", inline="always")
def edge_ok(xa, ya, za, xb, yb, zb, k2):  # pragma: no cover - compiled
    """3-D edge a–b at most √k2 · min(za, zb) long; False when either end is invalid (z = 0)."""
    dx = xa - xb
    dy = ya - yb
    dz = za - zb
    zm = min(za, zb)
    return dx * dx + dy * dy + dz * dz <= k2 * zm * zm


@numba.njit(cache=True, error_model="numpy", inline="always")
def vertex(x, y, pz, r, t, cam, dist, has_dist, near):  # pragma: no cover - compiled
    """Screen x, y, 1/z (0: invalid) and z of the point z · (x, y, 1) moved by (r, t)."""
    px, py = x * pz, y * pz
    qx = r[0] * px + r[1] * py + r[2] * pz + t[0]
    qy = r[3] * px + r[4] * py + r[5] * pz + t[1]
    qz = r[6] * px + r[7] * py + r[8] * pz + t[2]
    iz = 1.0 / qz
    iz = iz if (pz > 0.0 and qz >= near) else 0.0
    xn, yn = qx * iz, qy * iz
    if has_dist:
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]))
        xd = xn * radial + 2.0 * dist[2] * xn * yn + dist[3] * (r2 + 2.0 * xn * xn)
        yd = yn * radial + dist[2] * (r2 + 2.0 * yn * yn) + 2.0 * dist[3] * xn * yn
        xn, yn = xd, yd
    return cam[0] * xn + cam[2], cam[1] * yn + cam[3], iz, qz


@numba.njit(cache=True, error_model="numpy", inline="always")
def vertex_row(depth, v, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, s):  # pragma: no cover
    """Vertex row ``v`` of a clean depth map, warped, into slot ``s`` of the ring ``R``: the pixel cell
    ceil(x − ε), ceil(y − ε) of the screen position (whole numbers as float32, exact: clamped to
    ±CELL_LIM, NaN counts as far off-screen), the offset of the position from it (float32, in
    (−1, ε] on screen), z and 1/z (float32; 1/z = 0: invalid). Projected in float64, so that an
    identity warp puts every vertex on its pixel centre to ~1e-13 px."""
    w = depth.shape[1]
    if use_table:
        for u in range(w):
            vertex_into(rays[v, u, 0], rays[v, u, 1], depth[v, u], r, t, c, k, has_dist, near, R, s, u)
    else:
        yr = ry[v]
        for u in range(w):
            vertex_into(rx[u], yr, depth[v, u], r, t, c, k, has_dist, near, R, s, u)


@numba.njit(cache=True, error_model="numpy", inline="always")
def vertex_row32(depth, v, rx32, ry32, e, t, f, near, R, s):  # pragma: no cover - compiled
    """:func:`vertex_row` for a camera without distortion, in float32 (8 lanes), by the displacement of
    each vertex from its own pixel centre rather than its position: with r = (rx, ry, 1) the pixel's
    ray, p = d r, q = (I + M) p + t and m = M r,

        x − u = fx (x_n − rx) = fx (d (m_x − rx m_z) + t_x − rx t_z) / q_z,     q_z = d + d m_z + t_z,

    whose rounding error is relative to the motion, not to the image size (~1e-7 px per pixel of
    motion); no motion (M = 0, t = 0) gives exactly 0 and q_z = d. ``e`` holds M = R − I row-major,
    ``t`` the translation and ``f`` = (fx, fy), all float32."""
    w = depth.shape[1]
    zero = np.float32(0.0)
    one = np.float32(1.0)
    eps = np.float32(ENUM_EPS)
    lim = np.float32(CELL_LIM)
    yr = ry32[v]
    fv = np.float32(v)
    a0 = e[1] * yr + e[2]
    a1 = e[4] * yr + e[5]
    a2 = e[7] * yr + e[8]
    b1 = t[1] - yr * t[2]
    for u in range(w):
        xr = rx32[u]
        d = depth[v, u]
        e0 = e[0] * xr + a0
        e1 = e[3] * xr + a1
        e2 = e[6] * xr + a2
        qz = d + (d * e2 + t[2])
        iz = one / qz
        iz = iz if (d > zero and qz >= near) else zero
        dx = f[0] * (d * (e0 - xr * e2) + (t[0] - xr * t[2])) * iz
        dy = f[1] * (d * (e1 - yr * e2) + b1) * iz
        cx = np.ceil(dx - eps)
        cy = np.ceil(dy - eps)
        cx = cx if abs(cx) < lim else lim
        cy = cy if abs(cy) < lim else lim
        R.CX[s, u] = np.float32(u) + cx
        R.CY[s, u] = fv + cy
        R.FX[s, u] = dx - cx
        R.FY[s, u] = dy - cy
        R.Z[s, u] = qz
        R.IZ[s, u] = iz


@numba.njit(cache=True, error_model="numpy", inline="always")
def vertex_into(xr, yr, d, r, t, c, k, has_dist, near, R, s, u):  # pragma: no cover - compiled
    x, y, iz, qz = vertex(xr, yr, np.float64(d), r, t, c, k, has_dist, near)
    cx = np.ceil(x - ENUM_EPS)
    cy = np.ceil(y - ENUM_EPS)
    cx = cx if abs(cx) < CELL_LIM else CELL_LIM
    cy = cy if abs(cy) < CELL_LIM else CELL_LIM
    R.CX[s, u] = np.float32(cx)
    R.CY[s, u] = np.float32(cy)
    R.FX[s, u] = np.float32(x - cx)
    R.FY[s, u] = np.float32(y - cy)
    R.Z[s, u] = np.float32(qz)
    R.IZ[s, u] = np.float32(iz)


@numba.njit(cache=True, error_model="numpy", inline="always")
def code_row(E, v, R, s0, s1, cs):  # pragma: no cover - compiled
    """Which triangles of each quad of row ``v`` survive: all three vertices valid in the current view
    and no stretched edge (the edge flags ``E`` of the previous map, see :func:`normals_edges_row`; a
    rigid move keeps lengths). Into ``R.C[cs, 1:w]`` (the bits), ``R.A[cs]`` (split along 01–10),
    ``R.TA[cs]`` / ``R.TB[cs]`` (the triangle with apex 00 resp. 11 of that split, or 01 resp. 10 of
    the other, is drawn)."""
    w = E.shape[2]
    G = R.IZ
    C, A, TA, TB = R.C, R.A, R.TA, R.TB
    for u in range(w - 1):
        top = E[0, v, u]
        bot = E[0, v + 1, u]
        lef = E[1, v, u]
        rig = E[1, v, u + 1]
        anti = E[3, v, u]
        main = E[2, v, u] & (not anti)
        g00 = G[s0, u] > 0.0
        g01 = G[s0, u + 1] > 0.0
        g10 = G[s1, u] > 0.0
        g11 = G[s1, u + 1] > 0.0
        t0 = anti & top & lef & g00 & g01 & g10
        t1 = anti & rig & bot & g01 & g11 & g10
        t2 = main & top & rig & g00 & g01 & g11
        t3 = main & bot & lef & g00 & g11 & g10
        C[cs, u + 1] = np.uint8(t0) | (np.uint8(t1) << 1) | (np.uint8(t2) << 2) | (np.uint8(t3) << 3)
        A[cs, u] = anti
        TA[cs, u] = t0 | t2
        TB[cs, u] = t1 | t3


@numba.njit(cache=True, error_model="numpy", inline="always")
def fast_row(R, weight, v, s0, s1, cs, h, r_zw, r_t, r_slow):  # pragma: no cover - compiled
    """Branch-free float32 pass over quad row ``v``. For a quad whose drawn triangles' box holds exactly
    one pixel centre: the z there (+inf: the centre is in neither triangle), its weight and pixel.
    ``r_slow``: the quad needs the full float64 rasteriser (several candidate pixels, folded over
    itself, or a triangle thinner than ``AREA_MIN32``).

    The box comes from the vertices' integer cells (min and max commute with ceil, so it is the box of
    the float64 positions); the barycentrics from float32 positions relative to the candidate pixel
    centre, (cell − pixel) + offset, within ~1e-7 px of the float64 ones whatever the motion. The
    depth is interpolated perspective-correctly around the nearest vertex n (largest barycentric):
    1/z = (1/z_n) (1 + Σ_{i≠n} b_i (z_n / z_i − 1)), exact on a constant depth and, when the pixel
    centre sits on a vertex (an identity warp), that vertex's depth bit for bit."""
    w = R.CX.shape[1]
    CX, CY, FX, FY, Z, IZ = R.CX, R.CY, R.FX, R.FY, R.Z, R.IZ
    A, TA, TB = R.A, R.TA, R.TB
    zero = np.float32(0.0)
    one = np.float32(1.0)
    inf = np.float32(np.inf)
    wm1 = np.float32(w - 1)
    hm1 = np.float32(h - 1)
    wi = np.int32(w)
    for u in range(w - 1):
        anti = A[cs, u]
        ta = TA[cs, u]
        tb = TB[cs, u]
        cx00, cy00, fx00, fy00 = CX[s0, u], CY[s0, u], FX[s0, u], FY[s0, u]
        cx01, cy01, fx01, fy01 = CX[s0, u + 1], CY[s0, u + 1], FX[s0, u + 1], FY[s0, u + 1]
        cx10, cy10, fx10, fy10 = CX[s1, u], CY[s1, u], FX[s1, u], FY[s1, u]
        cx11, cy11, fx11, fy11 = CX[s1, u + 1], CY[s1, u + 1], FX[s1, u + 1], FY[s1, u + 1]
        z00, iz00, w00 = Z[s0, u], IZ[s0, u], weight[v, u]
        z01, iz01, w01 = Z[s0, u + 1], IZ[s0, u + 1], weight[v, u + 1]
        z10, iz10, w10 = Z[s1, u], IZ[s1, u], weight[v + 1, u]
        z11, iz11, w11 = Z[s1, u + 1], IZ[s1, u + 1], weight[v + 1, u + 1]
        # the two triangles of the split share the diagonal da–db; their apexes are pa and pb
        da_cx = cx01 if anti else cx00
        da_cy = cy01 if anti else cy00
        da_fx = fx01 if anti else fx00
        da_fy = fy01 if anti else fy00
        db_cx = cx10 if anti else cx11
        db_cy = cy10 if anti else cy11
        db_fx = fx10 if anti else fx11
        db_fy = fy10 if anti else fy11
        pa_cx = cx00 if anti else cx01
        pa_cy = cy00 if anti else cy01
        pa_fx = fx00 if anti else fx01
        pa_fy = fy00 if anti else fy01
        pb_cx = cx11 if anti else cx10
        pb_cy = cy11 if anti else cy10
        pb_fx = fx11 if anti else fx10
        pb_fy = fy11 if anti else fy10
        # box of the drawn triangles (the apex of an absent triangle may be an invalid vertex)
        qa_cx = pa_cx if ta else da_cx
        qa_cy = pa_cy if ta else da_cy
        qb_cx = pb_cx if tb else da_cx
        qb_cy = pb_cy if tb else da_cy
        xlo = min(min(da_cx, db_cx), min(qa_cx, qb_cx))
        xhi = max(max(da_cx, db_cx), max(qa_cx, qb_cx)) - one
        ylo = min(min(da_cy, db_cy), min(qa_cy, qb_cy))
        yhi = max(max(da_cy, db_cy), max(qa_cy, qb_cy)) - one
        px = max(min(xlo, wm1), zero)
        py = max(min(ylo, hm1), zero)
        # positions relative to the pixel centre (px, py)
        dax = (da_cx - px) + da_fx
        day = (da_cy - py) + da_fy
        dbx = (db_cx - px) + db_fx
        dby = (db_cy - py) + db_fy
        pax = (pa_cx - px) + pa_fx
        pay = (pa_cy - py) + pa_fy
        pbx = (pb_cx - px) + pb_fx
        pby = (pb_cy - py) + pb_fy
        # side of the diagonal, then the barycentrics of the triangle on that side
        ex = dbx - dax
        ey = dby - day
        sa = ex * (pay - day) - ey * (pax - dax)
        sb = ex * (pby - day) - ey * (pbx - dax)
        e = ey * dax - ex * day
        use_a = ta and (e * sa >= zero or not tb)
        ax = pax if use_a else pbx
        ay = pay if use_a else pby
        ar = sa if use_a else sb
        inv = one / ar
        b_apex = e * inv
        b_da = (dbx * ay - ax * dby) * inv
        b_db = one - b_apex - b_da
        inside = min(b_apex, min(b_da, b_db)) >= -BARY_EPS32
        # depth and weight around the nearest vertex
        a_z = (z00 if anti else z01) if use_a else (z11 if anti else z10)
        a_iz = (iz00 if anti else iz01) if use_a else (iz11 if anti else iz10)
        a_w = (w00 if anti else w01) if use_a else (w11 if anti else w10)
        da_z = z01 if anti else z00
        da_iz = iz01 if anti else iz00
        da_w = w01 if anti else w00
        db_z = z10 if anti else z11
        db_iz = iz10 if anti else iz11
        db_w = w10 if anti else w11
        n_a = b_apex >= b_da and b_apex >= b_db
        n_da = (not n_a) and b_da >= b_db
        n_db = not (n_a or n_da)
        zn = a_z if n_a else (da_z if n_da else db_z)
        wt = a_w if n_a else (da_w if n_da else db_w)
        t_a = zero if n_a else b_apex * (zn * a_iz - one)
        t_da = zero if n_da else b_da * (zn * da_iz - one)
        t_db = zero if n_db else b_db * (zn * db_iz - one)
        z = zn / (one + (t_a + t_da + t_db))
        inside_img = xlo >= zero and xlo <= wm1 and ylo >= zero and ylo <= hm1
        single = xlo == xhi and ylo == yhi and inside_img
        none = xlo > xhi or ylo > yhi or xhi < zero or yhi < zero or xlo > wm1 or ylo > hm1
        folded = ta and tb and not (sa * sb < zero)
        thin = (ta and not abs(sa) >= AREA_MIN32) or (tb and not abs(sb) >= AREA_MIN32)
        fast = single and not folded and not thin
        drawn = ta or tb
        r_zw[2 * u + ZI] = z if (fast and inside and drawn) else inf
        r_zw[2 * u + WI] = wt
        r_t[u] = np.int32(np.int32(py) * wi + np.int32(px))
        r_slow[u] = drawn and not none and not fast


@numba.njit(cache=True, error_model="numpy", inline="always")
def xyi(R, s, u):  # pragma: no cover - compiled
    """float64 screen x, y and 1/z of vertex ``u`` of ring slot ``s`` (1/z from z, so that 1/(1/z)
    rounds back to z; 0 for an invalid vertex)."""
    iz = 1.0 / np.float64(R.Z[s, u])
    return (np.float64(R.CX[s, u]) + np.float64(R.FX[s, u]), np.float64(R.CY[s, u]) + np.float64(R.FY[s, u]),
            iz if R.IZ[s, u] > 0.0 else 0.0)


@numba.njit(cache=True, error_model="numpy", inline="always")
def tri(xa, ya, iza, wa, xb, yb, izb, wb, xc, yc, izc, wc, xlo, xhi, ylo, yhi, zw):  # pragma: no cover
    """General float64 rasteriser for one triangle over the pixel box [xlo, xhi] × [ylo, yhi]."""
    area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
    if not abs(area) > 1e-12:
        return
    inv = 1.0 / area
    for py in range(ylo, yhi + 1):
        for px in range(xlo, xhi + 1):
            ba = ((xb - px) * (yc - py) - (xc - px) * (yb - py)) * inv
            bb = ((xc - px) * (ya - py) - (xa - px) * (yc - py)) * inv
            bc = 1.0 - ba - bb
            if ba < -BARY_EPS or bb < -BARY_EPS or bc < -BARY_EPS:
                continue
            z = np.float32(1.0 / (ba * iza + bb * izb + bc * izc))
            if z < zw[py, 2 * px + ZI]:
                zw[py, 2 * px + ZI] = z
                if ba >= bb and ba >= bc:
                    zw[py, 2 * px + WI] = wa
                elif bb >= bc:
                    zw[py, 2 * px + WI] = wb
                else:
                    zw[py, 2 * px + WI] = wc


@numba.njit(cache=True, error_model="numpy", inline="always")
def scatter_row(R, weight, v, s0, s1, cs, r_zw, r_t, r_slow, zw):  # pragma: no cover
    """z-buffer the one-pixel results of quad row ``v``, then rasterise its slow quads in full.

    Branch-free: a pixel's (z, weight) pair is one uint64 whose high half holds the bits of z, and a
    positive float32 orders like its bits, so "closest wins" is an integer min (+inf never wins; of two
    equal depths the smaller weight does)."""
    h = zw.shape[0]
    w = zw.shape[1] // 2
    zk = zw.view(np.uint64).reshape(-1)
    keys = r_zw.view(np.uint64)
    for u in range(w - 1):
        t = r_t[u]
        zk[t] = min(zk[t], keys[u])
    n_slow = 0
    for u in range(w - 1):
        n_slow += r_slow[u]
    if n_slow == 0:
        return
    C = R.C
    for u in range(w - 1):
        if not r_slow[u]:
            continue
        c = C[cs, u + 1]
        x0, y0, i0 = xyi(R, s0, u)
        x1, y1, i1 = xyi(R, s0, u + 1)
        x2, y2, i2 = xyi(R, s1, u)
        x3, y3, i3 = xyi(R, s1, u + 1)
        w0, w1, w2, w3 = weight[v, u], weight[v, u + 1], weight[v + 1, u], weight[v + 1, u + 1]
        # box of the drawn triangles: an unused corner takes a used corner's position
        bx0, by0 = (x0, y0) if c & USES_00 else (x1, y1)
        bx1, by1 = (x1, y1) if c & USES_01 else (x0, y0)
        bx2, by2 = (x2, y2) if c & USES_10 else (x1, y1)
        bx3, by3 = (x3, y3) if c & USES_11 else (x0, y0)
        xlo = max(math.ceil(min(min(bx0, bx1), min(bx2, bx3)) - ENUM_EPS), 0)
        xhi = min(math.ceil(max(max(bx0, bx1), max(bx2, bx3)) - ENUM_EPS) - 1, w - 1)
        ylo = max(math.ceil(min(min(by0, by1), min(by2, by3)) - ENUM_EPS), 0)
        yhi = min(math.ceil(max(max(by0, by1), max(by2, by3)) - ENUM_EPS) - 1, h - 1)
        if c & 1:
            tri(x0, y0, i0, w0, x1, y1, i1, w1, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)
        if c & 2:
            tri(x1, y1, i1, w1, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)
        if c & 4:
            tri(x0, y0, i0, w0, x1, y1, i1, w1, x3, y3, i3, w3, xlo, xhi, ylo, yhi, zw)
        if c & 8:
            tri(x0, y0, i0, w0, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)


@numba.njit(cache=True, error_model="numpy", inline="always")
def rim_row(R, weight, v, h, flags, s_t, s_z, s_w, n):  # pragma: no cover - compiled
    """Splat candidates of the rim vertices of row ``v`` (used by some triangle but not surrounded by
    four full quads), appended to the list ``s_t, s_z, s_w`` from index ``n``: the vertex's nearest
    pixel, the depth there of the plane of one of its drawn triangles (extrapolated by at most half a
    pixel, so that planes stay exact at their rims too; the vertex's own depth if that triangle is
    degenerate), and its weight. Returns the new length. Needs the codes of quad rows v − 1 and v and
    the vertex rows v − 1 … v + 1 in the ring."""
    C = R.C
    w = R.CX.shape[1]
    ca = v % 2  # quad row v
    cb = (v + 1) % 2  # quad row v − 1
    for u in range(w):
        c00 = C[ca, u + 1]
        c01 = C[ca, u]
        c10 = C[cb, u + 1]
        c11 = C[cb, u]
        used = (c00 & USES_00) | (c01 & USES_01) | (c10 & USES_10) | (c11 & USES_11)
        full = (((c00 == 3) | (c00 == 12)) & ((c01 == 3) | (c01 == 12))
                & ((c10 == 3) | (c10 == 12)) & ((c11 == 3) | (c11 == 12)))
        flags[u] = (used != 0) & (not full)
    sv = v % 3
    CX, CY, FX, FY, Z, IZ = R.CX, R.CY, R.FX, R.FY, R.Z, R.IZ
    for u in range(w):
        if not flags[u]:
            continue
        x = np.float64(CX[sv, u]) + np.float64(FX[sv, u])
        y = np.float64(CY[sv, u]) + np.float64(FY[sv, u])
        fx = math.floor(x + 0.5)
        fy = math.floor(y + 0.5)
        if not (fx >= 0.0 and fx < w and fy >= 0.0 and fy < h):
            continue
        px = int(fx)
        py = int(fy)
        # the first drawn triangle that uses this vertex, in quads (v, u), (v, u-1), (v-1, u), (v-1, u-1)
        b0 = C[ca, u + 1] & USES_00
        b1 = C[ca, u] & USES_01
        b2 = C[cb, u + 1] & USES_10
        b3 = C[cb, u] & USES_11
        q = 0 if b0 else (1 if b1 else (2 if b2 else 3))
        bits = b0 if b0 else (b1 if b1 else (b2 if b2 else b3))
        o = RIM_TRI[q, LOWBIT[bits]]  # its other two vertices, relative to this one
        sb, ub, sc, uc = (v + o[0]) % 3, u + o[1], (v + o[2]) % 3, u + o[3]
        xb = np.float64(CX[sb, ub]) + np.float64(FX[sb, ub])
        yb = np.float64(CY[sb, ub]) + np.float64(FY[sb, ub])
        xc = np.float64(CX[sc, uc]) + np.float64(FX[sc, uc])
        yc = np.float64(CY[sc, uc]) + np.float64(FY[sc, uc])
        # that triangle's plane at the pixel centre, around this vertex: 1/z = (1/z_v) (1 + Σ b_i (z_v / z_i − 1))
        zv = np.float64(Z[sv, u])
        z = zv
        area = (xb - x) * (yc - y) - (xc - x) * (yb - y)
        if abs(area) > 1e-12:
            inv = 1.0 / area
            bb = ((xc - px) * (y - py) - (x - px) * (yc - py)) * inv
            bc = ((x - px) * (yb - py) - (xb - px) * (y - py)) * inv
            den = 1.0 + bb * (zv * IZ[sb, ub] - 1.0) + bc * (zv * IZ[sc, uc] - 1.0)
            z = zv / den if den > 0.0 else zv
        s_t[n] = py * w + px
        s_z[n] = np.float32(z)
        s_w[n] = weight[v, u]
        n += 1
    return n


@numba.njit(**NJ)
def warp_kernel(depth, E, weight, rot, trans, rays, use_table, rx, ry, rx32, ry32, cam, dist, has_dist, near, zw,
                 s_t, s_z, s_w):  # pragma: no cover - compiled
    """Warp a clean depth map (its edge flags ``E``, its weights) by p ↦ rot · p + trans into the
    z-buffer ``zw`` (H, 2W) float32: pairs [2u + ZI] = the z-depth of each pixel (negated for a rim
    splat, +inf where nothing landed), [2u + WI] = its weight. ``s_t, s_z, s_w`` (length ≥ H·W) hold
    the rim splat list. Returns the number of rim splat candidates.

    One pass over the rows: per quad row v it warps vertex row v + 1 into a ring of three rows, codes
    the quads, runs the vectorised one-pixel pass, z-buffers it and rasterises the rest, and collects
    the rim splats of vertex row v. The splats go in after the last row, since any triangle may still
    cover their pixel. Nothing image-sized is written but the z-buffer and its weights."""
    h, w = depth.shape
    zw.view(np.uint64)[:, :] = EMPTY_KEY
    if h == 0 or w == 0:
        return 0
    r = (rot[0, 0], rot[0, 1], rot[0, 2], rot[1, 0], rot[1, 1], rot[1, 2], rot[2, 0], rot[2, 1], rot[2, 2])
    t = (trans[0], trans[1], trans[2])
    c = (cam[0], cam[1], cam[2], cam[3])
    k = (dist[0], dist[1], dist[2], dist[3], dist[4])
    e32 = (np.float32(rot[0, 0] - 1.0), np.float32(rot[0, 1]), np.float32(rot[0, 2]),
           np.float32(rot[1, 0]), np.float32(rot[1, 1] - 1.0), np.float32(rot[1, 2]),
           np.float32(rot[2, 0]), np.float32(rot[2, 1]), np.float32(rot[2, 2] - 1.0))
    t32 = (np.float32(trans[0]), np.float32(trans[1]), np.float32(trans[2]))
    f32 = (np.float32(cam[0]), np.float32(cam[1]))
    near32 = np.float32(near)
    f = np.empty((6, 3, w), np.float32)
    R = Ring(f[0], f[1], f[2], f[3], f[4], f[5],
              np.zeros((2, w + 1), np.uint8),  # codes of quad rows v (slot v % 2) and v − 1; borders stay 0
              np.empty((2, w), np.bool_), np.empty((2, w), np.bool_), np.empty((2, w), np.bool_))
    n = max(w - 1, 0)
    r_zw = np.empty(2 * n, np.float32)  # (weight, z) pairs, see scatter_row
    r_t = np.empty(n, np.int32)
    r_slow = np.empty(n, np.bool_)
    flags = np.empty(w, np.bool_)
    n_splat = 0
    if use_table:
        vertex_row(depth, 0, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, 0)
    else:
        vertex_row32(depth, 0, rx32, ry32, e32, t32, f32, near32, R, 0)
    for v in range(h):
        s0 = v % 3
        cs = v % 2
        if v + 1 < h:
            s1 = (v + 1) % 3
            if use_table:
                vertex_row(depth, v + 1, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, s1)
            else:
                vertex_row32(depth, v + 1, rx32, ry32, e32, t32, f32, near32, R, s1)
            code_row(E, v, R, s0, s1, cs)
            fast_row(R, weight, v, s0, s1, cs, h, r_zw, r_t, r_slow)
            scatter_row(R, weight, v, s0, s1, cs, r_zw, r_t, r_slow, zw)
        else:
            R.C[cs, :] = 0
        n_splat = rim_row(R, weight, v, h, flags, s_t, s_z, s_w, n_splat)
    # rim splats where no triangle landed, stored as −z (closest splat wins)
    zf = zw.reshape(-1)
    for i in range(n_splat):
        j = 2 * s_t[i]
        cur = zf[j + ZI]
        if cur > 0.0 and cur < np.inf:
            continue
        if cur < 0.0 and not s_z[i] < -cur:
            continue
        zf[j + ZI] = -s_z[i]
        zf[j + WI] = s_w[i]
    return n_splat


@numba.njit(**NJ)
def unpack_warp(zw):  # pragma: no cover - compiled
    h = zw.shape[0]
    w = zw.shape[1] // 2
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            z = abs(zw[v, 2 * u + ZI])
            ok = z < np.inf
            depth[v, u] = z if ok else np.float32(0.0)
            weight[v, u] = zw[v, 2 * u + WI] if ok else np.float32(0.0)
            known[v, u] = ok
    return depth, weight, known


@numba.njit(**NJ)
def valid_or_inf_into(nd, nk, out):  # pragma: no cover - compiled
    """out = the new depth where it is valid, +inf elsewhere."""
    h, w = nd.shape
    row = np.empty(w, np.float32)
    for v in range(h):
        for u in range(w):
            b = nd[v, u]
            row[u] = b if (nk[v, u] & (b > 0.0) & (b < np.inf)) else np.float32(np.inf)
        for u in range(w):
            out[v, u] = row[u]


@numba.njit(cache=True, error_model="numpy", inline="always")
def merge_pixel(a, a_ok, wa_raw, b, b_ok, near_new, max_weight, thr_rel, thr_abs):  # pragma: no cover - compiled
    """Merged (depth, weight) of one pixel, whether the two were averaged, and whether a warped-only
    value was dropped as occluded (``near_new``: the closest new depth nearby). All float32 (the
    difference of two agreeing depths is exact, so the average is within half an ulp of the float64
    one) and branch-free, so the loops around it vectorise 8 wide."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    wa = min(max(wa_raw, zero), max_weight)
    diff = b - a
    agree = abs(diff) <= thr_abs + thr_rel * b
    avg = a + diff / (wa + one)  # d_w + (d_n − d_w) / (w_w + 1): exact when equal
    averaged = a_ok & b_ok & agree
    occluded = a_ok & (not b_ok) & (a - near_new > thr_abs + thr_rel * near_new)
    d = b if b_ok else (a if a_ok else zero)
    wt = one if b_ok else (wa if a_ok else zero)
    d = avg if averaged else d
    wt = min(wa + one, max_weight) if averaged else wt
    d = zero if occluded else d
    wt = zero if occluded else wt
    return d, wt, averaged, occluded


@numba.njit(**NJ)
def merge_arrays(wd, ww, wk, nd, nk, near_new, max_weight, thr_rel, thr_abs):  # pragma: no cover - compiled
    h, w = nd.shape
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            a = wd[v, u]
            b = nd[v, u]
            a_ok = wk[v, u] & (a > 0.0) & (a < np.inf)
            b_ok = nk[v, u] & (b > 0.0) & (b < np.inf)
            d, wt, _, _ = merge_pixel(a, a_ok, ww[v, u], b, b_ok, near_new[v, u], max_weight, thr_rel, thr_abs)
            depth[v, u] = d
            weight[v, u] = wt
            known[v, u] = d > 0.0
    return depth, weight, known


@numba.njit(cache=True, error_model="numpy", inline="always")
def ring_slot(r, h):  # pragma: no cover - compiled
    """Slot of image row ``r`` in a point ring (slot 3 stays zero: the rows above and below the image)."""
    return r % 3 if (r >= 0 and r < h) else 3


@numba.njit(cache=True, error_model="numpy", inline="always")
def points_row(depth, v, h, rays, use_table, rx32, ry32, PR):  # pragma: no cover - compiled
    """Camera-frame points (x, y, z) of row ``v`` of a clean depth map into its slot of the point ring
    ``PR`` (3, 4, W + 2) float32 (columns 0 and W + 1 stay zero)."""
    w = depth.shape[1]
    s = ring_slot(v, h)
    if use_table:
        for u in range(w):
            d = depth[v, u]
            PR[0, s, u + 1] = np.float32(rays[v, u, 0]) * d
            PR[1, s, u + 1] = np.float32(rays[v, u, 1]) * d
            PR[2, s, u + 1] = d
    else:
        yr = ry32[v]
        for u in range(w):
            d = depth[v, u]
            PR[0, s, u + 1] = rx32[u] * d
            PR[1, s, u + 1] = yr * d
            PR[2, s, u + 1] = d


@numba.njit(cache=True, error_model="numpy", inline="always")
def normals_edges_row(PR, r, h, k2s, k2d, normals, valid, E, S):  # pragma: no cover - compiled
    """Edge flags and normals of image row ``r`` from the point ring ``PR`` (rows r − 1 … r + 1).

    Edge flags, for the next warp's quad codes and for the normals: E[0] edge to the right, E[1] edge
    down, E[2] diagonal (v, u)–(v+1, u+1), E[3] diagonal (v, u+1)–(v+1, u); an edge is usable when
    both ends are known and it is not stretched (a zero point, unknown or outside, fails). Rows of E
    above ``r`` must be done. ``S`` (3, W + 1) bool: the side flags the normals read (zeroed by the
    caller: row 0 = edge right, shifted by one; rows 1, 2 = edge down of rows r, r − 1 by parity)."""
    w = PR.shape[2] - 2
    t = ring_slot(r - 1, h)
    c = ring_slot(r, h)
    b = ring_slot(r + 1, h)
    for u in range(1, w + 1):
        xc, yc, zc = PR[0, c, u], PR[1, c, u], PR[2, c, u]
        xr, yr, zr = PR[0, c, u + 1], PR[1, c, u + 1], PR[2, c, u + 1]
        xb, yb, zb = PR[0, b, u], PR[1, b, u], PR[2, b, u]
        xd, yd, zd = PR[0, b, u + 1], PR[1, b, u + 1], PR[2, b, u + 1]
        E[0, r, u - 1] = edge_ok(xc, yc, zc, xr, yr, zr, k2s)
        E[1, r, u - 1] = edge_ok(xc, yc, zc, xb, yb, zb, k2s)
        E[2, r, u - 1] = edge_ok(xc, yc, zc, xd, yd, zd, k2d)
        E[3, r, u - 1] = edge_ok(xr, yr, zr, xb, yb, zb, k2d)
    # the side edges of row r (and down from row r − 1) for the normals, in local rows
    sb = 1 + r % 2
    st = 1 + (r + 1) % 2
    for u in range(w):
        S[0, u + 1] = E[0, r, u]
        S[sb, u] = E[1, r, u]
    if r == 0:
        for u in range(w):
            S[st, u] = False
    for u in range(1, w + 1):
        xc, yc, zc = PR[0, c, u], PR[1, c, u], PR[2, c, u]
        xl, yl, zl = PR[0, c, u - 1], PR[1, c, u - 1], PR[2, c, u - 1]
        xr, yr, zr = PR[0, c, u + 1], PR[1, c, u + 1], PR[2, c, u + 1]
        xt, yt, zt = PR[0, t, u], PR[1, t, u], PR[2, t, u]
        xb, yb, zb = PR[0, b, u], PR[1, b, u], PR[2, b, u]
        lo = S[0, u - 1]
        ro = S[0, u]
        to = S[st, u - 1]
        bo = S[sb, u - 1]
        # central difference where both neighbours are usable, else the one-sided difference
        hx = (xr if ro else xc) - (xl if lo else xc)
        hy = (yr if ro else yc) - (yl if lo else yc)
        hz = (zr if ro else zc) - (zl if lo else zc)
        gx = (xb if bo else xc) - (xt if to else xc)
        gy = (yb if bo else yc) - (yt if to else yc)
        gz = (zb if bo else zc) - (zt if to else zc)
        nx = hy * gz - hz * gy
        ny = hz * gx - hx * gz
        nz = hx * gy - hy * gx
        n2 = nx * nx + ny * ny + nz * nz
        ok = (lo or ro) and (to or bo) and n2 > 0.0
        s = np.float32(1.0) / np.sqrt(n2) if ok else np.float32(0.0)
        s = -s if nx * xc + ny * yc + nz * zc > 0.0 else s  # face the camera: n · P < 0
        normals[r, u - 1, 0] = nx * s
        normals[r, u - 1, 1] = ny * s
        normals[r, u - 1, 2] = nz * s
        valid[r, u - 1] = ok


@numba.njit(**NJ)
def merge_normals(zw, nd, nk, near_new, max_weight, thr_rel, thr_abs, rays, use_table, rx32, ry32, k2s, k2d,
                   E):  # pragma: no cover - compiled
    """Merge straight from the warp's z-buffer and, one row behind, compute the merged map's normals and
    its edge flags (into ``E``, for the next warp). Returns depth, weight, known, normals, normals'
    validity and the pixel counts: averaged, replaced (both valid but disagreeing), new only, warped
    only (held), warped only but dropped as occluded."""
    h, w = nd.shape
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    normals = np.empty((h, w, 3), np.float32)
    valid = np.empty((h, w), np.bool_)
    PR = np.zeros((3, 4, w + 2), np.float32)
    S = np.zeros((3, w + 1), np.bool_)
    n_avg = n_rep = n_new = n_held = n_occ = 0
    for v in range(h):
        for u in range(w):
            a = abs(zw[v, 2 * u + ZI])
            a_ok = a < np.inf
            b = nd[v, u]
            b_ok = nk[v, u] & (b > 0.0) & (b < np.inf)
            d, wt, averaged, occluded = merge_pixel(a, a_ok, zw[v, 2 * u + WI], b, b_ok, near_new[v, u], max_weight,
                                                     thr_rel, thr_abs)
            depth[v, u] = d
            weight[v, u] = wt
            known[v, u] = d > 0.0
            n_avg += averaged
            n_rep += a_ok & b_ok & (not averaged)
            n_new += b_ok & (not a_ok)
            n_held += a_ok & (not b_ok) & (not occluded)
            n_occ += occluded
        points_row(depth, v, h, rays, use_table, rx32, ry32, PR)
        if v >= 1:
            normals_edges_row(PR, v - 1, h, k2s, k2d, normals, valid, E, S)
    if h >= 1:
        normals_edges_row(PR, h - 1, h, k2s, k2d, normals, valid, E, S)
    return depth, weight, known, normals, valid, np.array([n_avg, n_rep, n_new, n_held, n_occ])


@numba.njit(**NJ)
def normals_edges(depth, rays, use_table, rx32, ry32, k2s, k2d, E):  # pragma: no cover - compiled
    """Normals, their validity and the edge flags (into ``E``) of a clean depth map."""
    h, w = depth.shape
    normals = np.empty((h, w, 3), np.float32)
    valid = np.empty((h, w), np.bool_)
    PR = np.zeros((3, 4, w + 2), np.float32)
    S = np.zeros((3, w + 1), np.bool_)
    for v in range(h):
        points_row(depth, v, h, rays, use_table, rx32, ry32, PR)
        if v >= 1:
            normals_edges_row(PR, v - 1, h, k2s, k2d, normals, valid, E, S)
    if h >= 1:
        normals_edges_row(PR, h - 1, h, k2s, k2d, normals, valid, E, S)
    return normals, valid
