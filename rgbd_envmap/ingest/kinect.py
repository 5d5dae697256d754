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
   pixel when no triangle covers it (see :func:`_rim_row`), so that sub-pixel motion does not shave
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
import sys
from collections import namedtuple
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
# unknown or not finite and > 0. Camera-frame points (float32 x, y, z from float32 rays) exist only in
# a ring of three rows and a zero row inside the merge / normals kernels; a zero point (unknown, or
# outside the image) fails every stretch test by itself (min(z_a, z_b) = 0). The merge leaves the
# edge flags of the map it produced in E (4, H, W) bool (edge right, down, diagonal, anti-diagonal
# usable), which is all the next warp needs of the previous view's geometry.
#
# Warp (:func:`_warp_kernel`): one pass over the rows with a ring of three vertex rows and two quad
# rows; nothing image-sized is written but the z-buffer. A vertex is kept as its pixel cell
# ceil(x − ε), ceil(y − ε) (whole numbers in float32) and the offset of its position from that cell,
# with z and 1/z (float32). Without distortion the offset comes from the vertex's displacement from its
# own pixel centre, computed in float32 with an error relative to the motion (~1e-7 px per pixel of
# motion; exactly 0 for no motion); with distortion the position is projected in float64.
#
# Rasterisation. Pixel centres are enumerated half-open, [x_min − ε, x_max − ε) × [y_min − ε,
# y_max − ε) per quad, so a pixel centre on a shared vertex or edge is tried by one quad only (under
# an identity warp every quad holds exactly its top-left pixel). Since ceil is monotonic, a quad's box
# is the min / max of its vertices' cells, the same for every quad that shares a vertex. A branch-free
# float32 pass (8 lanes) resolves every quad whose box holds one pixel centre — 97–99 % of them for
# frame-to-frame motion — with barycentrics from positions relative to that pixel centre, (cell −
# pixel) + offset, within ~1e-7 px of the exact ones whatever the motion (inclusive test, tolerance
# 2e-6). The rest — several candidate pixels, a quad folded over itself, or a triangle of less than
# 1/32 px² — go to a float64 rasteriser. The z-buffer holds (weight, z) float32 pairs that read as one
# uint64 with z in the high half; a positive float orders like its bits, so z-buffering the one-pixel
# results is a branch-free integer min. Pixel centres on the outer boundary of a surface are caught by
# splatting the rim vertices (:func:`_rim_row`), after the last row, since any triangle may still
# cover their pixel.
#
# Speed notes (this 2-core machine, measured in benchmarks/bench_kinect.py): LLVM does not vectorise a
# loop that writes several arrays while reading others when it cannot rule out aliasing (too many
# runtime checks), so hot loops write few arrays, outputs handed to the caller are allocated inside
# the kernels, and per-row scratch lives in small local buffers; numba widens integer arithmetic to
# 64 bits, so the 8-lane float32 loops keep flags as bools and cells as float32; image-sized scratch
# allocated and freed on every call costs page faults on every call (about 10 ms for 12 MB here), so
# it lives in a :class:`_Workspace` that :class:`KinectMerger` keeps between frames.

_NJ = {"cache": True, "error_model": "numpy"}

# The warp's ring of three vertex rows (see :func:`_warp_kernel`): pixel cells of the screen positions,
# the offsets from them, z and 1/z (float32); quad codes of two quad rows (uint8, zero-bordered) and
# their split / drawn-triangle flags.
_Ring = namedtuple("_Ring", "CX CY FX FY Z IZ C A TA TB")

# Triangles of the quad with corners 00 = (v, u), 01 = (v, u+1), 10 = (v+1, u), 11 = (v+1, u+1):
# bit 0: 00-01-10 and bit 1: 01-11-10 (split along 01–10); bit 2: 00-01-11 and bit 3: 00-11-10
# (split along 00–11). Masks of the triangles that use each corner:
_USES_00, _USES_01, _USES_10, _USES_11 = 13, 7, 11, 14
# Rim splats: the lowest set bit of a 4-bit mask, and for a vertex that is corner 00, 01, 10, 11 of
# quad q = 0 … 3 ((v, u), (v, u−1), (v−1, u), (v−1, u−1)), the other two vertices of triangle ``bit``
# of that quad as (dv, du, dv, du) relative to the vertex.
_LOWBIT = np.array([0, 0, 1, 0, 2, 0, 1, 0, 3, 0, 1, 0, 2, 0, 1, 0], np.int64)


def _rim_triangles() -> np.ndarray:
    tris = ((0, 1, 2), (1, 3, 2), (0, 1, 3), (0, 3, 2))  # corners 0 = 00, 1 = 01, 2 = 10, 3 = 11
    table = np.zeros((4, 4, 4), np.int64)
    for q in range(4):  # the vertex is corner q of quad q, whose origin is (−(q >> 1), −(q & 1)) from it
        for bit, corners in enumerate(tris):
            if q in corners:
                others = [c for c in corners if c != q]
                table[q, bit] = [d for c in others for d in ((c >> 1) - (q >> 1), (c & 1) - (q & 1))]
    return table


_RIM_TRI = _rim_triangles()
# Half-open shift of the pixel-centre enumeration, pixels.
_ENUM_EPS = 1e-6
# Vertex pixel cells beyond ±this are "far off-screen" (whole numbers stay exact in float32).
_CELL_LIM = float(1 << 22)
# One-pixel pass in float32 pixel-relative coordinates (errors ≲ 1e-7 px): its barycentric tolerance,
# and the smallest |2 · area| (px²) of a triangle it handles; thinner ones go to the float64 rasteriser.
_BARY_EPS32 = np.float32(2e-6)
_AREA_MIN32 = np.float32(1.0 / 16.0)
# The z-buffer holds (weight, z) float32 pairs; read as one uint64, z is the high half.
_ZI, _WI = (1, 0) if sys.byteorder == "little" else (0, 1)
_EMPTY_KEY = np.uint64(0x7F800000 << 32)  # z = +inf, weight 0


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
def _vertex_row(depth, v, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, s):  # pragma: no cover
    """Vertex row ``v`` of a clean depth map, warped, into slot ``s`` of the ring ``R``: the pixel cell
    ceil(x − ε), ceil(y − ε) of the screen position (whole numbers as float32, exact: clamped to
    ±_CELL_LIM, NaN counts as far off-screen), the offset of the position from it (float32, in
    (−1, ε] on screen), z and 1/z (float32; 1/z = 0: invalid). Projected in float64, so that an
    identity warp puts every vertex on its pixel centre to ~1e-13 px."""
    w = depth.shape[1]
    if use_table:
        for u in range(w):
            _vertex_into(rays[v, u, 0], rays[v, u, 1], depth[v, u], r, t, c, k, has_dist, near, R, s, u)
    else:
        yr = ry[v]
        for u in range(w):
            _vertex_into(rx[u], yr, depth[v, u], r, t, c, k, has_dist, near, R, s, u)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _vertex_row32(depth, v, rx32, ry32, e, t, f, near, R, s):  # pragma: no cover - compiled
    """:func:`_vertex_row` for a camera without distortion, in float32 (8 lanes), by the displacement of
    each vertex from its own pixel centre rather than its position: with r = (rx, ry, 1) the pixel's
    ray, p = d r, q = (I + M) p + t and m = M r,

        x − u = fx (x_n − rx) = fx (d (m_x − rx m_z) + t_x − rx t_z) / q_z,     q_z = d + d m_z + t_z,

    whose rounding error is relative to the motion, not to the image size (~1e-7 px per pixel of
    motion); no motion (M = 0, t = 0) gives exactly 0 and q_z = d. ``e`` holds M = R − I row-major,
    ``t`` the translation and ``f`` = (fx, fy), all float32."""
    w = depth.shape[1]
    zero = np.float32(0.0)
    one = np.float32(1.0)
    eps = np.float32(_ENUM_EPS)
    lim = np.float32(_CELL_LIM)
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
def _vertex_into(xr, yr, d, r, t, c, k, has_dist, near, R, s, u):  # pragma: no cover - compiled
    x, y, iz, qz = _vertex(xr, yr, np.float64(d), r, t, c, k, has_dist, near)
    cx = np.ceil(x - _ENUM_EPS)
    cy = np.ceil(y - _ENUM_EPS)
    cx = cx if abs(cx) < _CELL_LIM else _CELL_LIM
    cy = cy if abs(cy) < _CELL_LIM else _CELL_LIM
    R.CX[s, u] = np.float32(cx)
    R.CY[s, u] = np.float32(cy)
    R.FX[s, u] = np.float32(x - cx)
    R.FY[s, u] = np.float32(y - cy)
    R.Z[s, u] = np.float32(qz)
    R.IZ[s, u] = np.float32(iz)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _code_row(E, v, R, s0, s1, cs):  # pragma: no cover - compiled
    """Which triangles of each quad of row ``v`` survive: all three vertices valid in the current view
    and no stretched edge (the edge flags ``E`` of the previous map, see :func:`_normals_edges_row`; a
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
def _fast_row(R, weight, v, s0, s1, cs, h, r_zw, r_t, r_slow):  # pragma: no cover - compiled
    """Branch-free float32 pass over quad row ``v``. For a quad whose drawn triangles' box holds exactly
    one pixel centre: the z there (+inf: the centre is in neither triangle), its weight and pixel.
    ``r_slow``: the quad needs the full float64 rasteriser (several candidate pixels, folded over
    itself, or a triangle thinner than ``_AREA_MIN32``).

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
        inside = min(b_apex, min(b_da, b_db)) >= -_BARY_EPS32
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
        thin = (ta and not abs(sa) >= _AREA_MIN32) or (tb and not abs(sb) >= _AREA_MIN32)
        fast = single and not folded and not thin
        drawn = ta or tb
        r_zw[2 * u + _ZI] = z if (fast and inside and drawn) else inf
        r_zw[2 * u + _WI] = wt
        r_t[u] = np.int32(np.int32(py) * wi + np.int32(px))
        r_slow[u] = drawn and not none and not fast


@numba.njit(cache=True, error_model="numpy", inline="always")
def _xyi(R, s, u):  # pragma: no cover - compiled
    """float64 screen x, y and 1/z of vertex ``u`` of ring slot ``s`` (1/z from z, so that 1/(1/z)
    rounds back to z; 0 for an invalid vertex)."""
    iz = 1.0 / np.float64(R.Z[s, u])
    return (np.float64(R.CX[s, u]) + np.float64(R.FX[s, u]), np.float64(R.CY[s, u]) + np.float64(R.FY[s, u]),
            iz if R.IZ[s, u] > 0.0 else 0.0)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _tri(xa, ya, iza, wa, xb, yb, izb, wb, xc, yc, izc, wc, xlo, xhi, ylo, yhi, zw):  # pragma: no cover
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
            if ba < -_BARY_EPS or bb < -_BARY_EPS or bc < -_BARY_EPS:
                continue
            z = np.float32(1.0 / (ba * iza + bb * izb + bc * izc))
            if z < zw[py, 2 * px + _ZI]:
                zw[py, 2 * px + _ZI] = z
                if ba >= bb and ba >= bc:
                    zw[py, 2 * px + _WI] = wa
                elif bb >= bc:
                    zw[py, 2 * px + _WI] = wb
                else:
                    zw[py, 2 * px + _WI] = wc


@numba.njit(cache=True, error_model="numpy", inline="always")
def _scatter_row(R, weight, v, s0, s1, cs, r_zw, r_t, r_slow, zw):  # pragma: no cover
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
        x0, y0, i0 = _xyi(R, s0, u)
        x1, y1, i1 = _xyi(R, s0, u + 1)
        x2, y2, i2 = _xyi(R, s1, u)
        x3, y3, i3 = _xyi(R, s1, u + 1)
        w0, w1, w2, w3 = weight[v, u], weight[v, u + 1], weight[v + 1, u], weight[v + 1, u + 1]
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
            _tri(x0, y0, i0, w0, x1, y1, i1, w1, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)
        if c & 2:
            _tri(x1, y1, i1, w1, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)
        if c & 4:
            _tri(x0, y0, i0, w0, x1, y1, i1, w1, x3, y3, i3, w3, xlo, xhi, ylo, yhi, zw)
        if c & 8:
            _tri(x0, y0, i0, w0, x3, y3, i3, w3, x2, y2, i2, w2, xlo, xhi, ylo, yhi, zw)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _rim_row(R, weight, v, h, flags, s_t, s_z, s_w, n):  # pragma: no cover - compiled
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
        used = (c00 & _USES_00) | (c01 & _USES_01) | (c10 & _USES_10) | (c11 & _USES_11)
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
        b0 = C[ca, u + 1] & _USES_00
        b1 = C[ca, u] & _USES_01
        b2 = C[cb, u + 1] & _USES_10
        b3 = C[cb, u] & _USES_11
        q = 0 if b0 else (1 if b1 else (2 if b2 else 3))
        bits = b0 if b0 else (b1 if b1 else (b2 if b2 else b3))
        o = _RIM_TRI[q, _LOWBIT[bits]]  # its other two vertices, relative to this one
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


@numba.njit(**_NJ)
def _warp_kernel(depth, E, weight, rot, trans, rays, use_table, rx, ry, rx32, ry32, cam, dist, has_dist, near, zw,
                 s_t, s_z, s_w):  # pragma: no cover - compiled
    """Warp a clean depth map (its edge flags ``E``, its weights) by p ↦ rot · p + trans into the
    z-buffer ``zw`` (H, 2W) float32: pairs [2u + _ZI] = the z-depth of each pixel (negated for a rim
    splat, +inf where nothing landed), [2u + _WI] = its weight. ``s_t, s_z, s_w`` (length ≥ H·W) hold
    the rim splat list. Returns the number of rim splat candidates.

    One pass over the rows: per quad row v it warps vertex row v + 1 into a ring of three rows, codes
    the quads, runs the vectorised one-pixel pass, z-buffers it and rasterises the rest, and collects
    the rim splats of vertex row v. The splats go in after the last row, since any triangle may still
    cover their pixel. Nothing image-sized is written but the z-buffer and its weights."""
    h, w = depth.shape
    zw.view(np.uint64)[:, :] = _EMPTY_KEY
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
    R = _Ring(f[0], f[1], f[2], f[3], f[4], f[5],
              np.zeros((2, w + 1), np.uint8),  # codes of quad rows v (slot v % 2) and v − 1; borders stay 0
              np.empty((2, w), np.bool_), np.empty((2, w), np.bool_), np.empty((2, w), np.bool_))
    n = max(w - 1, 0)
    r_zw = np.empty(2 * n, np.float32)  # (weight, z) pairs, see _scatter_row
    r_t = np.empty(n, np.int32)
    r_slow = np.empty(n, np.bool_)
    flags = np.empty(w, np.bool_)
    n_splat = 0
    if use_table:
        _vertex_row(depth, 0, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, 0)
    else:
        _vertex_row32(depth, 0, rx32, ry32, e32, t32, f32, near32, R, 0)
    for v in range(h):
        s0 = v % 3
        cs = v % 2
        if v + 1 < h:
            s1 = (v + 1) % 3
            if use_table:
                _vertex_row(depth, v + 1, rays, use_table, rx, ry, r, t, c, k, has_dist, near, R, s1)
            else:
                _vertex_row32(depth, v + 1, rx32, ry32, e32, t32, f32, near32, R, s1)
            _code_row(E, v, R, s0, s1, cs)
            _fast_row(R, weight, v, s0, s1, cs, h, r_zw, r_t, r_slow)
            _scatter_row(R, weight, v, s0, s1, cs, r_zw, r_t, r_slow, zw)
        else:
            R.C[cs, :] = 0
        n_splat = _rim_row(R, weight, v, h, flags, s_t, s_z, s_w, n_splat)
    # rim splats where no triangle landed, stored as −z (closest splat wins)
    zf = zw.reshape(-1)
    for i in range(n_splat):
        j = 2 * s_t[i]
        cur = zf[j + _ZI]
        if cur > 0.0 and cur < np.inf:
            continue
        if cur < 0.0 and not s_z[i] < -cur:
            continue
        zf[j + _ZI] = -s_z[i]
        zf[j + _WI] = s_w[i]
    return n_splat


@numba.njit(**_NJ)
def _unpack_warp(zw):  # pragma: no cover - compiled
    h = zw.shape[0]
    w = zw.shape[1] // 2
    depth = np.empty((h, w), np.float32)
    weight = np.empty((h, w), np.float32)
    known = np.empty((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            z = abs(zw[v, 2 * u + _ZI])
            ok = z < np.inf
            depth[v, u] = z if ok else np.float32(0.0)
            weight[v, u] = zw[v, 2 * u + _WI] if ok else np.float32(0.0)
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


@numba.njit(cache=True, error_model="numpy", inline="always")
def _ring_slot(r, h):  # pragma: no cover - compiled
    """Slot of image row ``r`` in a point ring (slot 3 stays zero: the rows above and below the image)."""
    return r % 3 if (r >= 0 and r < h) else 3


@numba.njit(cache=True, error_model="numpy", inline="always")
def _points_row(depth, v, h, rays, use_table, rx32, ry32, PR):  # pragma: no cover - compiled
    """Camera-frame points (x, y, z) of row ``v`` of a clean depth map into its slot of the point ring
    ``PR`` (3, 4, W + 2) float32 (columns 0 and W + 1 stay zero)."""
    w = depth.shape[1]
    s = _ring_slot(v, h)
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
def _normals_edges_row(PR, r, h, k2s, k2d, normals, valid, E, S):  # pragma: no cover - compiled
    """Edge flags and normals of image row ``r`` from the point ring ``PR`` (rows r − 1 … r + 1).

    Edge flags, for the next warp's quad codes and for the normals: E[0] edge to the right, E[1] edge
    down, E[2] diagonal (v, u)–(v+1, u+1), E[3] diagonal (v, u+1)–(v+1, u); an edge is usable when
    both ends are known and it is not stretched (a zero point, unknown or outside, fails). Rows of E
    above ``r`` must be done. ``S`` (3, W + 1) bool: the side flags the normals read (zeroed by the
    caller: row 0 = edge right, shifted by one; rows 1, 2 = edge down of rows r, r − 1 by parity)."""
    w = PR.shape[2] - 2
    t = _ring_slot(r - 1, h)
    c = _ring_slot(r, h)
    b = _ring_slot(r + 1, h)
    for u in range(1, w + 1):
        xc, yc, zc = PR[0, c, u], PR[1, c, u], PR[2, c, u]
        xr, yr, zr = PR[0, c, u + 1], PR[1, c, u + 1], PR[2, c, u + 1]
        xb, yb, zb = PR[0, b, u], PR[1, b, u], PR[2, b, u]
        xd, yd, zd = PR[0, b, u + 1], PR[1, b, u + 1], PR[2, b, u + 1]
        E[0, r, u - 1] = _edge_ok(xc, yc, zc, xr, yr, zr, k2s)
        E[1, r, u - 1] = _edge_ok(xc, yc, zc, xb, yb, zb, k2s)
        E[2, r, u - 1] = _edge_ok(xc, yc, zc, xd, yd, zd, k2d)
        E[3, r, u - 1] = _edge_ok(xr, yr, zr, xb, yb, zb, k2d)
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


@numba.njit(**_NJ)
def _merge_normals(zw, nd, nk, near_new, max_weight, thr_rel, thr_abs, rays, use_table, rx32, ry32, k2s, k2d,
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
            a = abs(zw[v, 2 * u + _ZI])
            a_ok = a < np.inf
            b = nd[v, u]
            b_ok = nk[v, u] & (b > 0.0) & (b < np.inf)
            d, wt, averaged, occluded = _merge_pixel(a, a_ok, zw[v, 2 * u + _WI], b, b_ok, near_new[v, u], max_weight,
                                                     thr_rel, thr_abs)
            depth[v, u] = d
            weight[v, u] = wt
            known[v, u] = d > 0.0
            n_avg += averaged
            n_rep += a_ok & b_ok & (not averaged)
            n_new += b_ok & (not a_ok)
            n_held += a_ok & (not b_ok) & (not occluded)
            n_occ += occluded
        _points_row(depth, v, h, rays, use_table, rx32, ry32, PR)
        if v >= 1:
            _normals_edges_row(PR, v - 1, h, k2s, k2d, normals, valid, E, S)
    if h >= 1:
        _normals_edges_row(PR, h - 1, h, k2s, k2d, normals, valid, E, S)
    return depth, weight, known, normals, valid, np.array([n_avg, n_rep, n_new, n_held, n_occ])


@numba.njit(**_NJ)
def _normals_edges(depth, rays, use_table, rx32, ry32, k2s, k2d, E):  # pragma: no cover - compiled
    """Normals, their validity and the edge flags (into ``E``) of a clean depth map."""
    h, w = depth.shape
    normals = np.empty((h, w, 3), np.float32)
    valid = np.empty((h, w), np.bool_)
    PR = np.zeros((3, 4, w + 2), np.float32)
    S = np.zeros((3, w + 1), np.bool_)
    for v in range(h):
        _points_row(depth, v, h, rays, use_table, rx32, ry32, PR)
        if v >= 1:
            _normals_edges_row(PR, v - 1, h, k2s, k2d, normals, valid, E, S)
    if h >= 1:
        _normals_edges_row(PR, h - 1, h, k2s, k2d, normals, valid, E, S)
    return normals, valid


class _Workspace:
    """Image-sized scratch of the merger for one image size, kept between frames (see the note above)."""

    def __init__(self, height: int, width: int) -> None:
        h, w = height, width
        # edge flags of the last merged map (written by the merge, read by the next warp)
        self.E = np.zeros((4, h, w), np.bool_)
        self.zw = np.empty((h, 2 * w), np.float32)  # z-buffer: (weight, z) pairs, see _warp_kernel
        # rim splat list (only its used head is ever touched)
        self.s_t = np.empty(h * w, np.int32)
        self.s_z = np.empty(h * w, np.float32)
        self.s_w = np.empty(h * w, np.float32)
        self.near_new = np.empty((h, w), np.float32)
        self.near_tmp = np.empty((h, w), np.float32)


def _warp_into(ws: _Workspace, depth: np.ndarray, weight: np.ndarray, rotation: np.ndarray,
               translation: np.ndarray, cam_args: tuple, near_m: float) -> None:
    """Warp a clean depth map (with its edge flags in ``ws.E`` and its weights) by the rigid move
    p ↦ rotation · p + translation (``T_cur_from_prev``). Leaves in ``ws.zw`` the z-depth of each
    pixel (negated for a rim splat, +inf where nothing landed) and its weight."""
    rays, use_table, rx, ry, cam, dist, _, has_dist, rx32, ry32 = cam_args
    _warp_kernel(depth, ws.E, weight, np.ascontiguousarray(rotation, np.float64),
                 np.ascontiguousarray(translation, np.float64), rays, use_table, rx, ry, rx32, ry32, cam, dist,
                 has_dist, float(near_m), ws.zw, ws.s_t, ws.s_z, ws.s_w)


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
    rx32, ry32 = rx.astype(np.float32), ry.astype(np.float32)
    for a in (rx, ry, rays, cam, dist, rx32, ry32):
        a.setflags(write=False)
    return rays, use_table, rx, ry, cam, dist, math.sqrt(i.fx * i.fy), use_table, rx32, ry32


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
    rays, use_table = cam_args[:2]
    rx32, ry32 = cam_args[8:10]
    clean = _clean_depth(depth, kn)
    ws = _Workspace(*shape)
    _normals_edges(clean, rays, use_table, rx32, ry32, np.float32(k_side2), np.float32(k_diag2), ws.E)
    _warp_into(ws, clean, wts, T.rotation, T.translation, cam_args, float(near_m))
    return _unpack_warp(ws.zw)


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
    return _merge_arrays(wd, ww, wk, nd, nk, near_new, np.float32(max_weight), np.float32(threshold),
                         np.float32(threshold_abs_m))


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
    k_side2, k_diag2 = _stretch_k2(_check_stretch(max_stretch, "max_stretch"), _camera(intr)[6])
    cam_args = _camera(intr)
    rays, use_table = cam_args[:2]
    rx32, ry32 = cam_args[8:10]
    edges = np.empty((4, intr.height, intr.width), np.bool_)  # not needed here
    return _normals_edges(_clean_depth(depth, kn), rays, use_table, rx32, ry32, np.float32(k_side2),
                          np.float32(k_diag2), edges)


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
            ws.zw.view(np.uint64).fill(_EMPTY_KEY)
        else:
            # T_cur_from_prev = inv(T_world_from_cur) @ T_world_from_prev, as rotation and translation
            Rc, tc = T.rotation, T.translation
            Rp, tp = self._T_world_from_prev.rotation, self._T_world_from_prev.translation
            _warp_into(ws, self._depth, self._weight, Rc.T @ Rp, Rc.T @ (tp - tc), self._cam, cfg.near_m)
        near_new = _window_min_into(depth, kn, cfg.occlusion_radius_px, ws.near_tmp, ws.near_new)
        rays, use_table = self._cam[:2]
        rx32, ry32 = self._cam[8:10]
        md, mw, mk, normals, nvalid, counts = _merge_normals(
            ws.zw, depth, kn, near_new, np.float32(cfg.max_weight), np.float32(cfg.threshold),
            np.float32(cfg.threshold_abs_m), rays, use_table, rx32, ry32, np.float32(self._k_side2),
            np.float32(self._k_diag2), ws.E)
        for a in (md, mw, mk):
            a.setflags(write=False)  # the merger reads depth and weights again next frame
        self._depth, self._weight, self._T_world_from_prev = md, mw, T
        return KinectMergeResult(
            md, mk, mw, normals, nvalid, int(counts[0] + counts[1] + counts[3] + counts[4]),
            int(counts[0]), int(counts[1]), int(counts[2]), int(counts[3]), int(counts[4]),
        )
