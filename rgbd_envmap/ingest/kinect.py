"""Kinect-style ingest (paper 001 §4.2): warp the previous filtered depth map into the current view,
merge it with the new depth, estimate normals, and hand out an RGB-D frame.

A 640×480 structured-light depth camera is noisy and leaves holes at depth edges, in projector
shadows and on dark or shiny surfaces. Knecht et al. reuse the previous frames in screen space:

1. **Warp** (:func:`warp_depth`). The previous filtered z-depth map is a triangle mesh with one vertex
   per pixel centre. Each vertex is unprojected with its depth, moved by ``T_cur_from_prev`` and
   projected into the current view; the triangles are rasterised with a z-buffer (closest wins).
   Per-pixel z comes from interpolating 1/z with the screen-space barycentrics, which is exact for a
   planar triangle under perspective. A triangle is dropped when a vertex is invalid (unknown,
   non-finite, ≤ 0, or closer than ``near_m`` after the move) or when it is *stretched*: one of its
   3-D edges is longer than ``max_stretch`` pixel footprints,

       |P_a − P_b| > max_stretch · s · min(z_a, z_b) / f,     f = √(fx fy),

   with s = 1 for a side and √2 for a diagonal of the pixel grid. A fronto-parallel surface has
   stretch 1 and a surface seen at incidence θ has 1/cos θ, so the default 20 keeps surfaces up to
   87° and Kinect noise out to 4.5 m (3σ of a neighbour difference is ≤ 16 footprints there), and
   drops every depth jump larger than 20 footprints (3.8 % of the depth at f = 525 px): no depth is
   interpolated across a foreground / background edge. Each grid quad is split along the diagonal
   (u+1, v)–(u, v+1) when that diagonal is not stretched, else along (u, v)–(u+1, v+1), and each of its
   two triangles is drawn only if all three of its edges pass, so a quad with one corner across an
   edge still contributes the half on the other side. A pixel takes the weight of the nearest vertex
   (largest barycentric coordinate) of the winning triangle: weights are counts and are copied, not
   blended, as in the paper. The rim vertices of every surface are also splatted onto their nearest
   pixel when no triangle covers it (see :func:`_rim_splat`), so that sub-pixel motion does not shave
   a row off the history at every boundary every other frame.
2. **Merge** (:func:`merge_depth`). Where both the warped and the new depth are valid and agree,
   a running average with capped weights, as in KinectFusion (Newcombe et al. 2011):
   ``d = d_w + (d_n − d_w) / (w_w + 1)``, ``w = min(w_w + 1, max_weight)``. Written this way,
   averaging two equal values returns them bit for bit. Where they disagree by more than

       τ(z) = threshold_abs_m + threshold · z_new        (default: 3 % of the new depth)

   they belong to different surfaces (something moved, a disocclusion, a pose error) and the new
   value wins with weight 1. The threshold is relative because a triangulation sensor's noise grows
   with depth (σ_z ∝ z² for Kinect v1: 1.9 mm at 1 m, 14 mm at 3 m after Nguyen et al. 2012) while a
   foreground object in a room rarely sits within a few per cent of the depth of what is behind it.
   Only the new value valid: it is taken with weight 1. Only the warped value valid (a hole of the
   new frame filled from history): it is kept with its weight, unless a new measurement within
   ``occlusion_radius_px`` (2) pixels is closer by more than τ — then the pixel most likely lies on
   the rim of a foreground surface whose edge pixels the sensor dropped (a Kinect loses both sides of
   every depth edge), and the warp would put background there; it becomes unknown. The paper has no
   such test; on the simulated Kinect it cuts the pixels more than 5 % off from 0.47 % to 0.16 %.
3. **Normals** (:func:`normals_from_depth`). Camera-frame positions P = z · ray; the normal is the
   cross product of the horizontal and vertical differences (central differences P(u+1) − P(u−1)
   where both neighbours are usable, else the one-sided difference), normalised and flipped to face
   the camera (n · P < 0). A neighbour is usable when it is known and the edge to it is not
   stretched (same test as the warp), so normals never straddle a depth edge.

:class:`KinectMerger` keeps the state (filtered depth, weights, pose, the warp's scratch arrays)
between frames and runs the three steps; :func:`kinect_rgbd_frame` wraps the merged depth and the
registered colour image into an :class:`~rgbd_envmap.types.RGBDFrame` that continues through
reliability marking, colour correction and the environment map exactly like the Tango path.
Defaults and their measured effect: docs/kinect_merge.md.

Depth maps are (H, W) float32 **z-depth** in metres with an explicit ``known`` mask; depth values
under ``known == False`` are never read and come back as 0. A known pixel with NaN, inf or depth ≤ 0
is treated as unknown (never an error). All hot loops are single-threaded numba kernels
(benchmarks/bench_kinect.py times them beside ``cv2.warpFrame``, ``cv2.RgbdNormals`` and kornia).

Example:
    >>> import numpy as np
    >>> from rgbd_envmap.types import Intrinsics, RigidTransform
    >>> intr = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)
    >>> merger = KinectMerger(intr)
    >>> depth = np.full((48, 64), 2.0, np.float32); known = np.ones((48, 64), bool)
    >>> out = merger.step(depth, known, RigidTransform.identity())
    >>> out = merger.step(depth, known, RigidTransform.identity())
    >>> bool((out.depth_m == depth).all()), float(out.weight.max())
    (True, 2.0)

References:
    Knecht, Traxler, Mattausch, Wimmer (2012). Reciprocal Shading for Mixed Reality. Computers &
    Graphics, §4.2 (warp of the previous depth mesh, merge, normals by cross products), §6.1.
    Newcombe, Izadi, Hilliges et al. (2011). KinectFusion: Real-time Dense Surface Mapping and
    Tracking. ISMAR, §3.3 (weighted running average with a weight cap).
    Nguyen, Izadi, Lovell (2012). Modeling Kinect Sensor Noise for Improved 3D Reconstruction and
    Tracking. 3DIMPVT (axial noise σ_z = 0.0012 + 0.0019 (z − 0.4)² m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
import numpy as np

from rgbd_envmap.checks import check_array
from rgbd_envmap.colour import srgb8_to_linear_lut
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics, RGBDFrame, RigidTransform

__all__ = [
    "KinectMergeConfig",
    "KinectMergeResult",
    "KinectMerger",
    "warp_depth",
    "merge_depth",
    "normals_from_depth",
    "kinect_rgbd_frame",
]

# Barycentric tolerance of the rasteriser (a pixel centre within this of a triangle counts as inside):
# it keeps pixel centres that sit exactly on a vertex or a shared edge from being lost to rounding,
# e.g. under an identity warp, where every vertex lands on its own pixel centre ± 1e-13 px.
_BARY_EPS = 1e-7


@dataclass(frozen=True)
class KinectMergeConfig:
    """Settings of the warp / merge / normals stage (paper 001 §4.2 gives no values; these are measured
    on the simulated Kinect in docs/kinect_merge.md)."""

    #: a triangle (warp) or a neighbour (normals) is dropped when a 3-D edge is longer than this many
    #: pixel footprints (footprint: s · min(z_a, z_b) / √(fx fy), s = 1 side, √2 diagonal).
    max_stretch: float = 20.0
    #: weight cap of the running average (new samples never weigh less than 1 / (max_weight + 1)).
    max_weight: float = 32.0
    #: relative part of the disagreement threshold τ(z) = threshold_abs_m + threshold · z_new.
    threshold: float = 0.03
    #: absolute part of τ(z), metres.
    threshold_abs_m: float = 0.0
    #: warped vertices closer than this to the current camera (z-depth, metres) are dropped.
    near_m: float = 0.05
    #: a pixel known only from the warp is dropped when a new measurement within this many pixels is
    #: closer by more than τ (it lies on the rim of a foreground surface whose edge the sensor
    #: dropped); 0 switches the test off.
    occlusion_radius_px: int = 2

    def __post_init__(self) -> None:
        r = self.occlusion_radius_px
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 0:
            raise RangeError(f"KinectMergeConfig.occlusion_radius_px: expected an integer ≥ 0, got {r!r}")
        object.__setattr__(self, "occlusion_radius_px", int(r))
        for name in ("max_stretch", "max_weight", "threshold", "threshold_abs_m", "near_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise InvalidInputError(f"KinectMergeConfig.{name}: expected a number, got {value!r}")
            object.__setattr__(self, name, float(value))
        _check_stretch(self.max_stretch, "KinectMergeConfig.max_stretch")
        _check_merge_params(self.max_weight, self.threshold, self.threshold_abs_m, "KinectMergeConfig.")
        if not (math.isfinite(self.near_m) and self.near_m > 0.0):
            raise RangeError(f"KinectMergeConfig.near_m: expected a finite value > 0, got {self.near_m}")


def _check_stretch(value: float, name: str) -> float:
    value = float(value)
    if not (value >= 1.0):  # NaN fails too; inf is allowed (never drop)
        raise RangeError(f"{name}: expected a value ≥ 1 (pixel footprints), got {value}")
    return value


def _check_merge_params(max_weight: float, threshold: float, threshold_abs_m: float, prefix: str = "") -> None:
    if not (math.isfinite(max_weight) and max_weight >= 1.0):
        raise RangeError(f"{prefix}max_weight: expected a finite value ≥ 1, got {max_weight}")
    if not (threshold >= 0.0):
        raise RangeError(f"{prefix}threshold: expected a value ≥ 0 (fraction of the new depth), got {threshold}")
    if not (threshold_abs_m >= 0.0):
        raise RangeError(f"{prefix}threshold_abs_m: expected a value ≥ 0 (metres), got {threshold_abs_m}")


# --------------------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------------------
#
# Data layout. A depth map enters the kernels "clean": float32 z-depth with 0 wherever the pixel is
# unknown or not finite and > 0. Camera-frame points live in zero-padded float32 planes
# P (3, H+2, W+2) (X, Y, Z; Z = 0 marks an invalid pixel and the border), so neighbour tests need no
# bounds checks and the stretch test of an edge to an invalid vertex fails by itself
# (min(z_a, z_b) = 0). Warped vertices are V (3, H, W) float64: screen x, screen y and 1/z in the
# current view (1/z = 0: invalid), computed from the clean depth in float64 so that an identity warp is
# exact. Quad codes sit in a zero-padded (H+1, W+1) uint8 array, quad (v, u) at [v+1, u+1].
#
# Rasterisation. Pixel centres are enumerated half-open, [x_min − ε, x_max − ε) × [y_min − ε,
# y_max − ε) per quad, so a pixel centre on a shared vertex or edge is tried by one quad only (under
# an identity warp every quad holds exactly its top-left pixel); the barycentric test itself is
# inclusive (−1e-7). A first, branch-free pass (vectorised by LLVM) resolves every quad whose box holds
# one pixel centre — nearly all of them for frame-to-frame motion — and a scalar pass z-buffers those
# results and rasterises the rest in full. Pixel centres on the outer boundary of a surface are caught
# by splatting the rim vertices (:func:`_rim_splat`).
#
# Speed notes (this 2-core machine, measured in benchmarks/bench_kinect.py): LLVM does not vectorise a
# loop that writes an array passed in from outside while reading others (it cannot rule out
# aliasing), so outputs handed to the caller are allocated inside the kernels and persistent scratch is
# written through small per-row buffers; and image-sized scratch allocated and freed on every call
# costs page faults on every call (about 10 ms for 12 MB here), so it lives in a :class:`_Workspace`
# that :class:`KinectMerger` keeps between frames.

_NJ = {"cache": True, "error_model": "numpy"}

# Triangles of the quad with corners 00 = (v, u), 01 = (v, u+1), 10 = (v+1, u), 11 = (v+1, u+1):
# bit 0: 00-01-10 and bit 1: 01-11-10 (split along 01–10); bit 2: 00-01-11 and bit 3: 00-11-10
# (split along 00–11). Masks of the triangles that use each corner:
_USES_00, _USES_01, _USES_10, _USES_11 = 13, 7, 11, 14
# Per-quad 1/z of the vectorised pass meaning "rasterise this quad in full".
_SLOW = -1.0
# Half-open shift of the pixel-centre enumeration, pixels.
_ENUM_EPS = 1e-6


@numba.njit(**_NJ)
def _clean_depth(depth, known):  # pragma: no cover - compiled
    """float32 copy of ``depth`` with 0 wherever the pixel is unknown, non-finite or ≤ 0."""
    h, w = depth.shape
    out = np.empty((h, w), np.float32)
    for v in range(h):
        for u in range(w):
            d = depth[v, u]
            out[v, u] = d if (known[v, u] and d > 0.0 and d < np.inf) else np.float32(0.0)
    return out


@numba.njit(**_NJ)
def _points_into(depth, rays, use_table, rx, ry, P):  # pragma: no cover - compiled
    """Point planes of a clean depth map into the interior of the zero-bordered float32 ``P``."""
    h, w = depth.shape
    for v in range(h):
        if use_table:
            for u in range(w):
                d = np.float64(depth[v, u])
                P[0, v + 1, u + 1] = np.float32(rays[v, u, 0] * d)
                P[1, v + 1, u + 1] = np.float32(rays[v, u, 1] * d)
                P[2, v + 1, u + 1] = depth[v, u]
        else:
            yr = ry[v]
            for u in range(w):
                d = np.float64(depth[v, u])
                P[0, v + 1, u + 1] = np.float32(rx[u] * d)
                P[1, v + 1, u + 1] = np.float32(yr * d)
                P[2, v + 1, u + 1] = depth[v, u]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _edge_ok(xa, ya, za, xb, yb, zb, k2):  # pragma: no cover - compiled
    """3-D edge a–b at most √k2 · min(za, zb) long; False when either end is invalid (z = 0)."""
    dx = xa - xb
    dy = ya - yb
    dz = za - zb
    zm = min(za, zb)
    return dx * dx + dy * dy + dz * dz <= k2 * zm * zm


@numba.njit(cache=True, error_model="numpy", inline="always")
def _vertex(x, y, pz, r, t, cam, dist, has_dist, near):  # pragma: no cover - compiled
    """Screen x, y and 1/z (0: invalid) of the point z · (x, y, 1) moved by (r, t)."""
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
    return cam[0] * xn + cam[2], cam[1] * yn + cam[3], iz


@numba.njit(**_NJ)
def _vertices_into(depth, rays, use_table, rx, ry, rot, trans, cam, dist, has_dist, near, V, G):  # pragma: no cover
    """Screen position and 1/z in the current view of every pixel of a clean depth map; ``G`` is 1.0
    where the vertex is valid (a float32 copy of 1/z > 0, which keeps :func:`_codes_into` in one
    float width and lets LLVM vectorise it)."""
    h, w = depth.shape
    r = (rot[0, 0], rot[0, 1], rot[0, 2], rot[1, 0], rot[1, 1], rot[1, 2], rot[2, 0], rot[2, 1], rot[2, 2])
    t = (trans[0], trans[1], trans[2])
    c = (cam[0], cam[1], cam[2], cam[3])
    k = (dist[0], dist[1], dist[2], dist[3], dist[4])
    r_x = np.empty(w, np.float64)
    r_y = np.empty(w, np.float64)
    r_i = np.empty(w, np.float64)
    for v in range(h):
        if use_table:
            for u in range(w):
                r_x[u], r_y[u], r_i[u] = _vertex(rays[v, u, 0], rays[v, u, 1], np.float64(depth[v, u]), r, t, c, k,
                                                 has_dist, near)
        else:
            yr = ry[v]
            for u in range(w):
                r_x[u], r_y[u], r_i[u] = _vertex(rx[u], yr, np.float64(depth[v, u]), r, t, c, k, has_dist, near)
        for u in range(w):
            V[0, v, u] = r_x[u]
            V[1, v, u] = r_y[u]
            V[2, v, u] = r_i[u]
            G[v, u] = np.float32(r_i[u] > 0.0)


@numba.njit(**_NJ)
def _codes_into(P, G, k2s, k2d, code):  # pragma: no cover - compiled
    """Which triangles of each quad survive: all three vertices valid in the current view and no
    stretched edge (lengths measured in the previous view; a rigid move keeps them)."""
    h, w = P.shape[1] - 2, P.shape[2] - 2
    row = np.empty(max(w - 1, 0), np.uint8)
    for v in range(h - 1):
        for u in range(w - 1):
            x00, y00, z00 = P[0, v + 1, u + 1], P[1, v + 1, u + 1], P[2, v + 1, u + 1]
            x01, y01, z01 = P[0, v + 1, u + 2], P[1, v + 1, u + 2], P[2, v + 1, u + 2]
            x10, y10, z10 = P[0, v + 2, u + 1], P[1, v + 2, u + 1], P[2, v + 2, u + 1]
            x11, y11, z11 = P[0, v + 2, u + 2], P[1, v + 2, u + 2], P[2, v + 2, u + 2]
            top = _edge_ok(x00, y00, z00, x01, y01, z01, k2s)
            bot = _edge_ok(x10, y10, z10, x11, y11, z11, k2s)
            lef = _edge_ok(x00, y00, z00, x10, y10, z10, k2s)
            rig = _edge_ok(x01, y01, z01, x11, y11, z11, k2s)
            anti = _edge_ok(x01, y01, z01, x10, y10, z10, k2d)
            main = _edge_ok(x00, y00, z00, x11, y11, z11, k2d) & (not anti)
            g00 = G[v, u] > 0.0
            g01 = G[v, u + 1] > 0.0
            g10 = G[v + 1, u] > 0.0
            g11 = G[v + 1, u + 1] > 0.0
            c = np.uint8(anti & top & lef & g00 & g01 & g10)
            c |= np.uint8(anti & rig & bot & g01 & g11 & g10) << 1
            c |= np.uint8(main & top & rig & g00 & g01 & g11) << 2
            c |= np.uint8(main & bot & lef & g00 & g11 & g10) << 3
            row[u] = c
        for u in range(w - 1):
            code[v + 1, u + 1] = row[u]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _tri(xa, ya, iza, wa, xb, yb, izb, wb, xc, yc, izc, wc, xlo, xhi, ylo, yhi, izbuf, wbuf):  # pragma: no cover
    """General rasteriser for one triangle over the pixel box [xlo, xhi] × [ylo, yhi]."""
    area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
    if not abs(area) > 1e-12:
        return
    inv = 1.0 / area
    for py in range(ylo, yhi + 1):
        for px in range(xlo, xhi + 1):
            ba = ((xb - px) * (yc - py) - (xc - px) * (yb - py)) * inv
            bb = ((xc - px) * (ya - py) - (xa - px) * (yc - py)) * inv
            bc = 1.0 - ba - bb
            if ba < -_BARY_EPS or bb < -_BARY_EPS or bc < -_BARY_EPS:
                continue
            izp = ba * iza + bb * izb + bc * izc
            if izp > izbuf[py, px]:
                izbuf[py, px] = izp
                if ba >= bb and ba >= bc:
                    wbuf[py, px] = wa
                elif bb >= bc:
                    wbuf[py, px] = wb
                else:
                    wbuf[py, px] = wc


@numba.njit(cache=True, error_model="numpy", inline="always")
def _scatter_row(V, code, weight, v, r_iz, r_w, r_t, izbuf, wbuf):  # pragma: no cover - compiled
    """z-buffer one row of one-pixel quads (closest wins); rasterise its ``_SLOW`` quads in full."""
    h, w = V.shape[1], V.shape[2]
    izf = izbuf.reshape(-1)
    wf = wbuf.reshape(-1)
    for u in range(w - 1):
        iz = r_iz[u]
        if iz > 0.0:
            t = r_t[u]
            if iz > izf[t]:
                izf[t] = iz
                wf[t] = r_w[u]
        elif iz == _SLOW:
            c = code[v + 1, u + 1]
            x0, y0, i0, w0 = V[0, v, u], V[1, v, u], V[2, v, u], weight[v, u]
            x1, y1, i1, w1 = V[0, v, u + 1], V[1, v, u + 1], V[2, v, u + 1], weight[v, u + 1]
            x2, y2, i2, w2 = V[0, v + 1, u], V[1, v + 1, u], V[2, v + 1, u], weight[v + 1, u]
            x3, y3, i3, w3 = V[0, v + 1, u + 1], V[1, v + 1, u + 1], V[2, v + 1, u + 1], weight[v + 1, u + 1]
            # box of the drawn triangles: an unused corner takes a used corner's position
            bx0, by0 = (x0, y0) if c & _USES_00 else (x1, y1)
            bx1, by1 = (x1, y1) if c & _USES_01 else (x0, y0)
            bx2, by2 = (x2, y2) if c & _USES_10 else (x1, y1)
            bx3, by3 = (x3, y3) if c & _USES_11 else (x0, y0)
            xlo = max(math.ceil(min(min(bx0, bx1), min(bx2, bx3)) - _ENUM_EPS), 0)
            xhi = min(math.ceil(max(max(bx0, bx1), max(bx2, bx3)) - _ENUM_EPS) - 1, w - 1)
            ylo = max(math.ceil(min(min(by0, by1), min(by2, by3)) - _ENUM_EPS), 0)
            yhi = min(math.ceil(max(max(by0, by1), max(by2, by3)) - _ENUM_EPS) - 1, h - 1)
            if c & 1:
                _tri(x0, y0, i0, w0, x1, y1, i1, w1, x2, y2, i2, w2, xlo, xhi, ylo, yhi, izbuf, wbuf)
            if c & 2:
                _tri(x1, y1, i1, w1, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, izbuf, wbuf)
            if c & 4:
                _tri(x0, y0, i0, w0, x1, y1, i1, w1, x3, y3, i3, w3, xlo, xhi, ylo, yhi, izbuf, wbuf)
            if c & 8:
                _tri(x0, y0, i0, w0, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, izbuf, wbuf)


@numba.njit(**_NJ)
def _raster_into(V, code, weight, izbuf, wbuf):  # pragma: no cover - compiled
    """Rasterise the coded triangles into the z-buffer (``izbuf`` zero on entry).

    Per row of quads, a branch-free pass (vectorised) resolves every quad whose box holds exactly one
    pixel centre: the 1/z at that pixel (0: the centre is in neither triangle), its weight and flat
    index; a quad with several candidate pixels, or folded over itself, is marked ``_SLOW``. A scalar
    pass then z-buffers the row's results and rasterises the ``_SLOW`` quads in full."""
    h, w = V.shape[1], V.shape[2]
    n = max(w - 1, 0)
    r_iz = np.empty(n, np.float64)
    r_w = np.empty(n, np.float32)
    r_t = np.empty(n, np.int32)
    for v in range(h - 1):
        for u in range(w - 1):
            c = code[v + 1, u + 1]
            x0, y0, i0, w0 = V[0, v, u], V[1, v, u], V[2, v, u], weight[v, u]
            x1, y1, i1, w1 = V[0, v, u + 1], V[1, v, u + 1], V[2, v, u + 1], weight[v, u + 1]
            x2, y2, i2, w2 = V[0, v + 1, u], V[1, v + 1, u], V[2, v + 1, u], weight[v + 1, u]
            x3, y3, i3, w3 = V[0, v + 1, u + 1], V[1, v + 1, u + 1], V[2, v + 1, u + 1], weight[v + 1, u + 1]
            # the two triangles of the split share the diagonal da–db; their apexes are pa and pb
            anti = (c & 3) != 0
            da_x, da_y, da_i, da_w = (x1, y1, i1, w1) if anti else (x0, y0, i0, w0)
            db_x, db_y, db_i, db_w = (x2, y2, i2, w2) if anti else (x3, y3, i3, w3)
            pa_x, pa_y, pa_i, pa_w = (x0, y0, i0, w0) if anti else (x1, y1, i1, w1)
            pb_x, pb_y, pb_i, pb_w = (x3, y3, i3, w3) if anti else (x2, y2, i2, w2)
            ta = (c & 5) != 0
            tb = (c & 10) != 0
            # box of the drawn triangles (the apex of an absent triangle may be an invalid vertex)
            qa_x = pa_x if ta else da_x
            qa_y = pa_y if ta else da_y
            qb_x = pb_x if tb else da_x
            qb_y = pb_y if tb else da_y
            xlo = np.ceil(min(min(da_x, db_x), min(qa_x, qb_x)) - _ENUM_EPS)
            xhi = np.ceil(max(max(da_x, db_x), max(qa_x, qb_x)) - _ENUM_EPS) - 1.0
            ylo = np.ceil(min(min(da_y, db_y), min(qa_y, qb_y)) - _ENUM_EPS)
            yhi = np.ceil(max(max(da_y, db_y), max(qa_y, qb_y)) - _ENUM_EPS) - 1.0
            px = max(min(xlo, w - 1.0), 0.0)
            py = max(min(ylo, h - 1.0), 0.0)
            # side of the diagonal, then the barycentrics of the triangle on that side
            ex, ey = db_x - da_x, db_y - da_y
            sa = ex * (pa_y - da_y) - ey * (pa_x - da_x)
            sb = ex * (pb_y - da_y) - ey * (pb_x - da_x)
            e = ex * (py - da_y) - ey * (px - da_x)
            use_a = ta and (e * sa >= 0.0 or not tb)
            ax = pa_x if use_a else pb_x
            ay = pa_y if use_a else pb_y
            ai = pa_i if use_a else pb_i
            aw = pa_w if use_a else pb_w
            ar = sa if use_a else sb
            inv = 1.0 / ar
            b_apex = e * inv
            b_da = ((db_x - px) * (ay - py) - (ax - px) * (db_y - py)) * inv
            b_db = 1.0 - b_apex - b_da
            inside = abs(ar) > 1e-12 and min(b_apex, min(b_da, b_db)) >= -_BARY_EPS
            iz = b_apex * ai + b_da * da_i + b_db * db_i
            wt = aw if (b_apex >= b_da and b_apex >= b_db) else (da_w if b_da >= b_db else db_w)
            inside_img = xlo >= 0.0 and xlo <= w - 1.0 and ylo >= 0.0 and ylo <= h - 1.0
            single = xlo == xhi and ylo == yhi and inside_img
            none = xlo > xhi or ylo > yhi or xhi < 0.0 or yhi < 0.0 or xlo > w - 1.0 or ylo > h - 1.0
            folded = ta and tb and not (sa * sb < 0.0)
            fast = single and not folded
            iz = iz if (fast and inside) else 0.0
            iz = _SLOW if (c != 0 and not none and not fast) else iz
            r_iz[u] = iz
            r_w[u] = wt
            r_t[u] = np.int32(py * w + px)
        _scatter_row(V, code, weight, v, r_iz, r_w, r_t, izbuf, wbuf)


@numba.njit(**_NJ)
def _rim_flags_into(code, rim):  # pragma: no cover - compiled
    """rim[v, u] = True for a vertex used by some triangle but not surrounded by four full quads."""
    h, w = rim.shape
    row = np.empty(w, np.bool_)
    for v in range(h):
        for u in range(w):
            c00 = code[v + 1, u + 1]
            c01 = code[v + 1, u]
            c10 = code[v, u + 1]
            c11 = code[v, u]
            used = (c00 & _USES_00) | (c01 & _USES_01) | (c10 & _USES_10) | (c11 & _USES_11)
            full = (((c00 == 3) | (c00 == 12)) & ((c01 == 3) | (c01 == 12))
                    & ((c10 == 3) | (c10 == 12)) & ((c11 == 3) | (c11 == 12)))
            row[u] = (used != 0) & (not full)
        for u in range(w):
            rim[v, u] = row[u]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _triangle(qv, qu, bit):  # pragma: no cover - compiled
    """Pixel rows / columns of the three vertices of triangle ``bit`` of quad (qv, qu)."""
    if bit == 0:
        return qv, qu, qv, qu + 1, qv + 1, qu
    if bit == 1:
        return qv, qu + 1, qv + 1, qu + 1, qv + 1, qu
    if bit == 2:
        return qv, qu, qv, qu + 1, qv + 1, qu + 1
    return qv, qu, qv + 1, qu + 1, qv + 1, qu


@numba.njit(**_NJ)
def _rim_splat(V, code, weight, rim, izbuf, wbuf):  # pragma: no cover - compiled
    """Rim vertices onto the pixels no triangle covers, stored as −1/z (closest splat wins).

    With vertices at pixel centres, a sub-pixel move shaves the outermost row or column off a region
    about every other frame, and the half-open enumeration leaves a surface's right and bottom
    boundary pixels to nobody under an identity warp; a rim vertex on its nearest pixel keeps both.
    The splat's 1/z is that of the plane of one of the vertex' drawn triangles at the pixel centre
    (extrapolated by at most half a pixel), so that planes stay exact at their rims too.
    """
    h, w = rim.shape
    for v in range(h):
        for u in range(w):
            if not rim[v, u]:
                continue
            px = int(math.floor(V[0, v, u] + 0.5))
            py = int(math.floor(V[1, v, u] + 0.5))
            if px < 0 or px >= w or py < 0 or py >= h:
                continue
            cur = izbuf[py, px]
            if cur > 0.0:
                continue
            # a drawn triangle that uses this vertex: quads (v, u), (v, u-1), (v-1, u), (v-1, u-1)
            qv, qu, bits = v, u, code[v + 1, u + 1] & _USES_00
            if bits == 0:
                qv, qu, bits = v, u - 1, code[v + 1, u] & _USES_01
            if bits == 0:
                qv, qu, bits = v - 1, u, code[v, u + 1] & _USES_10
            if bits == 0:
                qv, qu, bits = v - 1, u - 1, code[v, u] & _USES_11
            bit = 0
            while not (bits >> bit) & 1:
                bit += 1
            a0, a1, b0, b1, c0, c1 = _triangle(qv, qu, bit)
            xa, ya, xb, yb, xc, yc = V[0, a0, a1], V[1, a0, a1], V[0, b0, b1], V[1, b0, b1], V[0, c0, c1], V[1, c0, c1]
            area = (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya)
            iz = V[2, v, u]
            if abs(area) > 1e-12:
                ba = ((xb - px) * (yc - py) - (xc - px) * (yb - py)) / area
                bb = ((xc - px) * (ya - py) - (xa - px) * (yc - py)) / area
                ext = ba * V[2, a0, a1] + bb * V[2, b0, b1] + (1.0 - ba - bb) * V[2, c0, c1]
                iz = ext if ext > 0.0 else iz
            if iz <= -cur:
                continue
            izbuf[py, px] = -iz
            wbuf[py, px] = weight[v, u]


@numba.njit(**_NJ)
def _unpack_warp(izbuf, wbuf):  # pragma: no cover - compiled
    h, w = izbuf.shape
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            iz = abs(izbuf[v, u])
            ok = iz > 0.0
            depth[v, u] = np.float32(1.0 / iz) if ok else np.float32(0.0)
            weight[v, u] = wbuf[v, u] if ok else np.float32(0.0)
            known[v, u] = ok
    return depth, weight, known


@numba.njit(**_NJ)
def _valid_or_inf_into(nd, nk, out):  # pragma: no cover - compiled
    """out = the new depth where it is valid, +inf elsewhere."""
    h, w = nd.shape
    row = np.empty(w, np.float32)
    for v in range(h):
        for u in range(w):
            b = nd[v, u]
            row[u] = b if (nk[v, u] & (b > 0.0) & (b < np.inf)) else np.float32(np.inf)
        for u in range(w):
            out[v, u] = row[u]


def _window_min_into(nd: np.ndarray, nk: np.ndarray, r: int, tmp: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The smallest valid new depth within ``r`` pixels (Chebyshev) of each pixel, +inf where there
    is none: a (2r+1)² erosion (OpenCV's, 0.2 ms at 640×480 against ~4 ms for a numba loop here).
    Returns ``out`` (or ``tmp`` when r = 0)."""
    _valid_or_inf_into(nd, nk, tmp)
    if r == 0 or tmp.size == 0:
        return tmp
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    cv2.erode(tmp, kernel, dst=out, borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    return out


@numba.njit(cache=True, error_model="numpy", inline="always")
def _merge_pixel(a, a_ok, wa_raw, b, b_ok, near_new, max_weight, thr_rel, thr_abs):  # pragma: no cover - compiled
    """Merged (depth float32, weight float32) of one pixel, whether the two were averaged, and
    whether a warped-only value was dropped as occluded (``near_new``: the closest new depth nearby).
    Branch-free, so the loops around it vectorise."""
    wa = min(max(np.float64(wa_raw), 0.0), max_weight)
    da = np.float64(a)
    diff = np.float64(b) - da
    agree = abs(diff) <= thr_abs + thr_rel * np.float64(b)
    avg = np.float32(da + diff / (wa + 1.0))  # d_w + (d_n − d_w) / (w_w + 1): exact when equal
    averaged = a_ok & b_ok & agree
    nn = np.float64(near_new)
    occluded = a_ok & (not b_ok) & (da - nn > thr_abs + thr_rel * nn)
    d = b if b_ok else (a if a_ok else np.float32(0.0))
    wt = np.float32(1.0) if b_ok else (np.float32(wa) if a_ok else np.float32(0.0))
    d = avg if averaged else d
    wt = np.float32(min(wa + 1.0, max_weight)) if averaged else wt
    d = np.float32(0.0) if occluded else d
    wt = np.float32(0.0) if occluded else wt
    return d, wt, averaged, occluded


@numba.njit(**_NJ)
def _merge_arrays(wd, ww, wk, nd, nk, near_new, max_weight, thr_rel, thr_abs):  # pragma: no cover - compiled
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
            d, wt, _, _ = _merge_pixel(a, a_ok, ww[v, u], b, b_ok, near_new[v, u], max_weight, thr_rel, thr_abs)
            depth[v, u] = d
            weight[v, u] = wt
            known[v, u] = d > 0.0
    return depth, weight, known


@numba.njit(**_NJ)
def _merge_zbuffer(izbuf, wbuf, nd, nk, near_new, max_weight, thr_rel, thr_abs, rays, use_table, rx, ry,
                   P):  # pragma: no cover - compiled
    """Merge straight from the warp's z-buffer, and write the merged map's point planes into the
    interior of ``P``. Also returns the pixel counts: averaged, replaced (both valid but
    disagreeing), new only, warped only (held), warped only but dropped as occluded."""
    h, w = nd.shape
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    n_avg = n_rep = n_new = n_held = n_occ = 0
    r_x = np.empty(w, np.float32)
    r_y = np.empty(w, np.float32)
    for v in range(h):
        if use_table:
            for u in range(w):
                r_x[u] = rays[v, u, 0]
                r_y[u] = rays[v, u, 1]
        else:
            for u in range(w):
                r_x[u] = rx[u]
                r_y[u] = ry[v]
        for u in range(w):
            iz = abs(izbuf[v, u])
            a_ok = iz > 0.0
            a = np.float32(1.0 / iz)
            b = nd[v, u]
            b_ok = nk[v, u] & (b > 0.0) & (b < np.inf)
            d, wt, averaged, occluded = _merge_pixel(a, a_ok, wbuf[v, u], b, b_ok, near_new[v, u], max_weight,
                                                     thr_rel, thr_abs)
            depth[v, u] = d
            weight[v, u] = wt
            known[v, u] = d > 0.0
            n_avg += averaged
            n_rep += a_ok & b_ok & (not averaged)
            n_new += b_ok & (not a_ok)
            n_held += a_ok & (not b_ok) & (not occluded)
            n_occ += occluded
        for u in range(w):
            d = depth[v, u]
            P[0, v + 1, u + 1] = r_x[u] * d
            P[1, v + 1, u + 1] = r_y[u] * d
            P[2, v + 1, u + 1] = d
    return depth, weight, known, np.array([n_avg, n_rep, n_new, n_held, n_occ])


@numba.njit(**_NJ)
def _normals(P, k2):  # pragma: no cover - compiled
    h, w = P.shape[1] - 2, P.shape[2] - 2
    normals = np.empty((h, w, 3), np.float32)
    valid = np.empty((h, w), np.bool_)
    for v in range(1, h + 1):
        for u in range(1, w + 1):
            xc, yc, zc = P[0, v, u], P[1, v, u], P[2, v, u]
            xl, yl, zl = P[0, v, u - 1], P[1, v, u - 1], P[2, v, u - 1]
            xr, yr, zr = P[0, v, u + 1], P[1, v, u + 1], P[2, v, u + 1]
            xt, yt, zt = P[0, v - 1, u], P[1, v - 1, u], P[2, v - 1, u]
            xb, yb, zb = P[0, v + 1, u], P[1, v + 1, u], P[2, v + 1, u]
            lo = _edge_ok(xc, yc, zc, xl, yl, zl, k2)
            ro = _edge_ok(xc, yc, zc, xr, yr, zr, k2)
            to = _edge_ok(xc, yc, zc, xt, yt, zt, k2)
            bo = _edge_ok(xc, yc, zc, xb, yb, zb, k2)
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
            normals[v - 1, u - 1, 0] = nx * s
            normals[v - 1, u - 1, 1] = ny * s
            normals[v - 1, u - 1, 2] = nz * s
            valid[v - 1, u - 1] = ok
    return normals, valid


class _Workspace:
    """Scratch arrays of the warp for one image size, kept between frames (see the note above)."""

    def __init__(self, height: int, width: int) -> None:
        h, w = height, width
        # point planes of the last merged map and of the one being merged, swapped every frame
        # (the one-pixel border stays 0)
        self.P = [np.zeros((3, h + 2, w + 2), np.float32), np.zeros((3, h + 2, w + 2), np.float32)]
        self.V = np.empty((3, h, w), np.float64)
        self.G = np.empty((h, w), np.float32)
        self.code = np.zeros((h + 1, w + 1), np.uint8)  # the border stays 0
        self.rim = np.empty((h, w), np.bool_)
        self.izbuf = np.empty((h, w), np.float64)
        self.wbuf = np.empty((h, w), np.float32)
        self.near_new = np.empty((h, w), np.float32)
        self.near_tmp = np.empty((h, w), np.float32)


def _warp_into(ws: _Workspace, depth: np.ndarray, P: np.ndarray, weight: np.ndarray, rotation: np.ndarray,
               translation: np.ndarray, cam_args: tuple, near_m: float, k_side2: float, k_diag2: float) -> None:
    """Warp a clean depth map (with its point planes ``P`` and its weights) by the rigid move
    p ↦ rotation · p + translation (``T_cur_from_prev``). Leaves in ``ws.izbuf`` the 1/z of each pixel
    (negative for a rim splat, 0 where nothing landed) and in ``ws.wbuf`` its weight."""
    rays, use_table, rx, ry, cam, dist, _, has_dist = cam_args
    _vertices_into(depth, rays, use_table, rx, ry, np.ascontiguousarray(rotation, np.float64),
                   np.ascontiguousarray(translation, np.float64), cam, dist, has_dist, near_m, ws.V, ws.G)
    _codes_into(P, ws.G, np.float32(k_side2), np.float32(k_diag2), ws.code)
    ws.izbuf.fill(0.0)
    _raster_into(ws.V, ws.code, weight, ws.izbuf, ws.wbuf)
    _rim_flags_into(ws.code, ws.rim)
    _rim_splat(ws.V, ws.code, weight, ws.rim, ws.izbuf, ws.wbuf)


# --------------------------------------------------------------------------------------------------
# Camera helpers
# --------------------------------------------------------------------------------------------------


@lru_cache(maxsize=8)
def _camera(intrinsics: Intrinsics) -> tuple:
    """Kernel arguments that depend only on the camera (cached per intrinsics, read-only arrays).

    Without distortion the normalised ray of pixel (v, u) is ((u − cx) / fx, (v − cy) / fy), two
    small vectors; with distortion a (H, W, 2) table from :func:`rgbd_envmap.geometry.pixel_rays`.
    """
    i = intrinsics
    rx = (np.arange(i.width, dtype=np.float64) - i.cx) / i.fx
    ry = (np.arange(i.height, dtype=np.float64) - i.cy) / i.fy
    use_table = not i.distortion.is_zero
    rays = np.ascontiguousarray(pixel_rays(i)[..., :2]) if use_table else np.zeros((1, 1, 2))
    cam = np.array([i.fx, i.fy, i.cx, i.cy])
    dist = i.distortion.coefficients
    for a in (rx, ry, rays, cam, dist):
        a.setflags(write=False)
    return rays, use_table, rx, ry, cam, dist, math.sqrt(i.fx * i.fy), use_table


def _stretch_k2(max_stretch: float, f: float) -> tuple[float, float]:
    k = max_stretch / f
    return k * k, 2.0 * k * k


def _check_depth(depth_m: object, name: str, shape: tuple[int, int] | None) -> np.ndarray:
    d = check_array(depth_m, name, shape=shape if shape is not None else ("H", "W"), dtype="float")
    return np.ascontiguousarray(d, dtype=np.float32)


def _check_known(known: object, name: str, shape: tuple[int, ...]) -> np.ndarray:
    return np.ascontiguousarray(check_array(known, name, shape=shape, dtype="bool"))


def _check_intrinsics(intrinsics: object) -> Intrinsics:
    if not isinstance(intrinsics, Intrinsics):
        raise InvalidInputError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    return intrinsics


def _check_transform(T: object, name: str) -> RigidTransform:
    if not isinstance(T, RigidTransform):
        raise InvalidInputError(f"{name}: expected a RigidTransform, got {type(T).__name__}")
    return T


# --------------------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------------------


def warp_depth(
    depth_m: np.ndarray,
    weight: np.ndarray,
    known: np.ndarray,
    intrinsics: Intrinsics,
    T_cur_from_prev: RigidTransform,
    *,
    max_stretch: float = KinectMergeConfig.max_stretch,
    near_m: float = KinectMergeConfig.near_m,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward-warp a z-depth map (and its weights) from the previous view into the current one.

    The pixel grid is a triangle mesh; its vertices move by ``T_cur_from_prev`` and the triangles are
    rasterised with a z-buffer (closest wins), 1/z interpolated perspective-correctly. Triangles with
    an invalid vertex or a stretched 3-D edge (a depth discontinuity, see the module docstring) are
    dropped, so nothing is interpolated between a foreground and a background surface. Both views
    share ``intrinsics`` (Brown distortion is applied to the projected vertices; triangles are
    rasterised linearly in the distorted image).

    Args:
        depth_m: (H, W) float z-depth of the previous view, metres; read only where ``known``.
        weight: (H, W) float per-pixel weights (observation counts) carried with the depth; read only
            where ``known``.
        known: (H, W) bool. Known pixels with NaN / inf / ≤ 0 depth count as unknown.
        intrinsics: the camera, ``intrinsics.shape == (H, W)``.
        T_cur_from_prev: maps points of the previous camera frame into the current one.
        max_stretch: longest allowed 3-D edge, in pixel footprints (≥ 1; inf keeps every triangle).
        near_m: vertices closer than this to the current camera (z-depth) are dropped.

    Returns:
        ``(depth_m, weight, known)``: (H, W) float32 warped z-depth in metres (0 where not known),
        (H, W) float32 weight of the nearest vertex of the visible triangle (0 where not known),
        (H, W) bool pixels covered by a surviving triangle.

    Raises:
        ShapeError: a shape differs from ``intrinsics.shape``. DTypeError: wrong dtypes.
        NonFiniteError / RangeError: a weight at a known pixel is non-finite or negative;
        ``max_stretch`` < 1 or ``near_m`` ≤ 0.
    """
    intr = _check_intrinsics(intrinsics)
    shape = intr.shape
    depth = _check_depth(depth_m, "depth_m", shape)
    wts = np.ascontiguousarray(check_array(weight, "weight", shape=shape, dtype="float"), dtype=np.float32)
    kn = _check_known(known, "known", shape)
    T = _check_transform(T_cur_from_prev, "T_cur_from_prev")
    k_side2, k_diag2 = _stretch_k2(_check_stretch(max_stretch, "max_stretch"), _camera(intr)[6])
    if not (math.isfinite(near_m) and near_m > 0.0):
        raise RangeError(f"near_m: expected a finite value > 0, got {near_m}")
    _check_weights(wts, kn, "weight")
    cam_args = _camera(intr)
    rays, use_table, rx, ry = cam_args[:4]
    clean = _clean_depth(depth, kn)
    ws = _Workspace(*shape)
    _points_into(clean, rays, use_table, rx, ry, ws.P[0])
    _warp_into(ws, clean, ws.P[0], wts, T.rotation, T.translation, cam_args, float(near_m), k_side2, k_diag2)
    return _unpack_warp(ws.izbuf, ws.wbuf)


def _check_weights(weights: np.ndarray, known: np.ndarray, name: str) -> None:
    """Weights must be finite and ≥ 0 wherever they are read (known pixels)."""
    bad = known & ~(weights >= 0) | known & ~np.isfinite(weights)
    if bad.any():
        vals = weights[bad]
        raise RangeError(f"{name}: expected finite values ≥ 0 at known pixels, got {vals.size} others "
                         f"(e.g. {vals[0]})")


def merge_depth(
    warped_depth: np.ndarray,
    warped_weight: np.ndarray,
    warped_known: np.ndarray,
    new_depth: np.ndarray,
    new_known: np.ndarray,
    *,
    max_weight: float = KinectMergeConfig.max_weight,
    threshold: float = KinectMergeConfig.threshold,
    threshold_abs_m: float = KinectMergeConfig.threshold_abs_m,
    occlusion_radius_px: int = KinectMergeConfig.occlusion_radius_px,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge the warped filtered depth with a new measurement (weighted running average).

    Per pixel, with warped (d_w, w_w) and new d_n (weight 1):

    * both valid and |d_n − d_w| ≤ τ = ``threshold_abs_m`` + ``threshold`` · d_n:
      d = d_w + (d_n − d_w) / (w_w' + 1), w = min(w_w' + 1, ``max_weight``), with
      w_w' = min(w_w, ``max_weight``) (equal inputs give d_w bit for bit);
    * both valid and |d_n − d_w| > τ (different surfaces): d = d_n, w = 1;
    * only the new one valid: d = d_n, w = 1;
    * only the warped one valid: d = d_w, w = w_w' — unless a new measurement within
      ``occlusion_radius_px`` pixels is closer than d_w by more than τ(that measurement): then the
      pixel most likely lies on the rim of a foreground surface whose edge pixels the sensor dropped,
      the warp put background there, and it becomes unknown;
    * neither: unknown (depth 0, weight 0).

    A pixel is valid when its mask is True and its depth finite and > 0.

    Args:
        warped_depth, warped_weight, warped_known: (H, W) float z-depth (metres), float weight,
            bool mask, as :func:`warp_depth` returns them.
        new_depth, new_known: (H, W) float z-depth (metres) and bool mask of the new frame.
        max_weight: weight cap (≥ 1).
        threshold: relative disagreement threshold (fraction of the new depth, ≥ 0).
        threshold_abs_m: absolute part of the threshold, metres (≥ 0).
        occlusion_radius_px: window of the occlusion test of warped-only pixels (integer ≥ 0; 0: off).

    Returns:
        ``(depth_m, weight, known)``: (H, W) float32 merged z-depth in metres (0 where not known),
        (H, W) float32 weights in [0, ``max_weight``], (H, W) bool.
    """
    wd = _check_depth(warped_depth, "warped_depth", None)
    shape = wd.shape
    ww = np.ascontiguousarray(check_array(warped_weight, "warped_weight", shape=shape, dtype="float"), dtype=np.float32)
    wk = _check_known(warped_known, "warped_known", shape)
    nd = _check_depth(new_depth, "new_depth", shape)
    nk = _check_known(new_known, "new_known", shape)
    max_weight, threshold, threshold_abs_m = float(max_weight), float(threshold), float(threshold_abs_m)
    _check_merge_params(max_weight, threshold, threshold_abs_m)
    _check_weights(ww, wk, "warped_weight")
    r = occlusion_radius_px
    if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 0:
        raise RangeError(f"occlusion_radius_px: expected an integer ≥ 0, got {r!r}")
    near_new = _window_min_into(nd, nk, int(r), np.empty(shape, np.float32), np.empty(shape, np.float32))
    return _merge_arrays(wd, ww, wk, nd, nk, near_new, max_weight, threshold, threshold_abs_m)


def normals_from_depth(
    depth_m: np.ndarray,
    known: np.ndarray,
    intrinsics: Intrinsics,
    *,
    max_stretch: float = KinectMergeConfig.max_stretch,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit normals of a z-depth map by cross products of neighbouring 3-D positions.

    With P = z · ray at each pixel, n ∝ (P(u+1) − P(u−1)) × (P(v+1) − P(v−1)) (central differences
    where both neighbours are usable, else the one-sided difference), flipped so that n · P < 0
    (facing the camera). A neighbour is usable when known and the 3-D edge to it is at most
    ``max_stretch`` pixel footprints long, so normals never mix two surfaces across a depth edge.

    Args:
        depth_m: (H, W) float z-depth in metres; read only where ``known``.
        known: (H, W) bool (known pixels with NaN / inf / ≤ 0 depth count as unknown).
        intrinsics: the camera, ``intrinsics.shape == (H, W)``.
        max_stretch: neighbour test, pixel footprints (≥ 1).

    Returns:
        ``(normals, valid)``: (H, W, 3) float32 unit normals in the camera frame (OpenCV axes; zero
        where not valid) and (H, W) bool, True where the pixel is valid and has a usable neighbour
        horizontally and vertically.
    """
    intr = _check_intrinsics(intrinsics)
    depth = _check_depth(depth_m, "depth_m", intr.shape)
    kn = _check_known(known, "known", intr.shape)
    k_side2, _ = _stretch_k2(_check_stretch(max_stretch, "max_stretch"), _camera(intr)[6])
    rays, use_table, rx, ry = _camera(intr)[:4]
    P = np.zeros((3, intr.height + 2, intr.width + 2), np.float32)
    _points_into(_clean_depth(depth, kn), rays, use_table, rx, ry, P)
    return _normals(P, np.float32(k_side2))


def kinect_rgbd_frame(
    merged_depth: np.ndarray,
    known: np.ndarray,
    rgb_uint8: np.ndarray,
    T_world_from_cam: RigidTransform,
    intrinsics: Intrinsics,
    timestamp_ns: int,
) -> RGBDFrame:
    """The RGB-D frame of a merged depth map and its colour image.

    The depth is registered to the colour camera, as in the TUM RGB-D benchmark and the simulated
    Kinect: both images share one pixel grid and ``intrinsics``. Colour is decoded from 8-bit sRGB to
    linear float32 with :func:`rgbd_envmap.colour.srgb8_to_linear_lut`. The frame then goes through
    reliability marking (:func:`rgbd_envmap.depth.mark_reliable`), colour correction and the
    environment map like a Tango frame.

    Args:
        merged_depth: (H, W) float z-depth in metres (e.g. :class:`KinectMergeResult`.depth_m).
        known: (H, W) bool; pixels with non-finite or ≤ 0 depth become unknown.
        rgb_uint8: (H, W, 3) uint8 sRGB colour image registered to the depth.
        T_world_from_cam: the camera pose.
        intrinsics: the shared intrinsics, shape (H, W).
        timestamp_ns: capture time, integer nanoseconds.

    Returns:
        An :class:`RGBDFrame` with depth 0 where not known.
    """
    intr = _check_intrinsics(intrinsics)
    depth = _check_depth(merged_depth, "merged_depth", intr.shape)
    kn = _check_known(known, "known", intr.shape)
    rgb8 = check_array(rgb_uint8, "rgb_uint8", shape=(intr.height, intr.width, 3), dtype=np.uint8)
    T = _check_transform(T_world_from_cam, "T_world_from_cam")
    with np.errstate(invalid="ignore"):
        kn = kn & (depth > 0) & np.isfinite(depth)
    depth = np.where(kn, depth, np.float32(0.0))
    rgb = srgb8_to_linear_lut()[rgb8]
    return RGBDFrame(rgb, depth, kn, T, intr, int(timestamp_ns))


# --------------------------------------------------------------------------------------------------
# Stateful wrapper
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KinectMergeResult:
    """What one :meth:`KinectMerger.step` produces (arrays are fresh; the merger keeps its own copies).

    Attributes:
        depth_m: (H, W) float32 merged z-depth in metres, 0 where not ``known``.
        known: (H, W) bool.
        weight: (H, W) float32 weights (observation counts, capped), 0 where not known.
        normals: (H, W, 3) float32 unit camera-frame normals facing the camera, 0 where not valid.
        normals_valid: (H, W) bool.
        n_warped: pixels the warp of the previous map covered (0 on the first frame).
        n_averaged: pixels where warped and new agreed and were averaged.
        n_replaced: pixels where they disagreed and the new depth won.
        n_new_only: pixels known only in the new frame.
        n_held: pixels known only from the warp (holes of the new frame filled from history).
        n_occluded: pixels known only from the warp but dropped by the occlusion test.
    """

    depth_m: np.ndarray
    known: np.ndarray
    weight: np.ndarray
    normals: np.ndarray
    normals_valid: np.ndarray
    n_warped: int
    n_averaged: int
    n_replaced: int
    n_new_only: int
    n_held: int
    n_occluded: int


class KinectMerger:
    """Warp + merge + normals across frames (paper 001 §4.2), keeping the filtered depth, its weights
    and the previous pose, plus the scratch arrays of the warp (allocated once per merger).

    Args:
        intrinsics: the depth camera (registered to colour), shape (H, W).
        config: :class:`KinectMergeConfig`.
    """

    def __init__(self, intrinsics: Intrinsics, config: KinectMergeConfig = KinectMergeConfig()) -> None:
        self.intrinsics = _check_intrinsics(intrinsics)
        if not isinstance(config, KinectMergeConfig):
            raise InvalidInputError(f"config: expected a KinectMergeConfig, got {type(config).__name__}")
        self.config = config
        self._cam = _camera(intrinsics)
        self._k_side2, self._k_diag2 = _stretch_k2(config.max_stretch, self._cam[6])
        self._ws = _Workspace(*intrinsics.shape)
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next step starts from its own depth alone."""
        self._depth: np.ndarray | None = None  # last merged depth (0 where unknown)
        self._weight: np.ndarray | None = None
        self._P: np.ndarray | None = None  # its point planes (one of the workspace's two)
        self._T_world_from_prev: RigidTransform | None = None

    @property
    def has_history(self) -> bool:
        return self._depth is not None

    def step(self, depth_m: np.ndarray, known: np.ndarray, T_world_from_cam: RigidTransform) -> KinectMergeResult:
        """Merge a new depth frame into the history and return the filtered depth and its normals.

        Args:
            depth_m: (H, W) float z-depth in metres; read only where ``known``.
            known: (H, W) bool (known pixels with NaN / inf / ≤ 0 depth count as unknown).
            T_world_from_cam: the camera pose of this frame.

        Returns:
            A :class:`KinectMergeResult` (fresh arrays; depth, known and weight are read-only).
        """
        intr = self.intrinsics
        depth = _check_depth(depth_m, "depth_m", intr.shape)
        kn = _check_known(known, "known", intr.shape)
        T = _check_transform(T_world_from_cam, "T_world_from_cam")
        cfg = self.config
        ws = self._ws
        if self._depth is None:
            ws.izbuf.fill(0.0)
        else:
            # T_cur_from_prev = inv(T_world_from_cur) @ T_world_from_prev, as rotation and translation
            Rc, tc = T.rotation, T.translation
            Rp, tp = self._T_world_from_prev.rotation, self._T_world_from_prev.translation
            _warp_into(ws, self._depth, self._P, self._weight, Rc.T @ Rp, Rc.T @ (tp - tc), self._cam, cfg.near_m,
                       self._k_side2, self._k_diag2)
        near_new = _window_min_into(depth, kn, cfg.occlusion_radius_px, ws.near_tmp, ws.near_new)
        P = ws.P[1] if self._P is ws.P[0] else ws.P[0]
        rays, use_table, rx, ry = self._cam[:4]
        md, mw, mk, counts = _merge_zbuffer(ws.izbuf, ws.wbuf, depth, kn, near_new, cfg.max_weight, cfg.threshold,
                                           cfg.threshold_abs_m, rays, use_table, rx, ry, P)
        normals, nvalid = _normals(P, np.float32(self._k_side2))
        for a in (md, mw, mk):
            a.setflags(write=False)  # the merger reads depth and weights again next frame
        self._depth, self._weight, self._P, self._T_world_from_prev = md, mw, P, T
        return KinectMergeResult(
            md, mk, mw, normals, nvalid, int(counts[0] + counts[1] + counts[3] + counts[4]),
            int(counts[0]), int(counts[1]), int(counts[2]), int(counts[3]), int(counts[4]),
        )
