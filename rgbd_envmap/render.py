"""Offscreen rasterisation of the virtual object and its shadow plane, and compositing over the live
colour frame (paper 003 §7.2; DESIGN.md §4 stage 10).

Two steps, one per function:

* :class:`Renderer` rasterises, with a virtual camera matching the colour camera's intrinsics
  (undistorted pinhole; OpenCV pixel centres), the PRT-shaded object (per-vertex linear colours) and
  the shadow plane (per-vertex alpha), both Gouraud-interpolated (perspective-correct), with a depth
  test so the object hides the plane behind it. No lighting is applied: the colours are already the
  shaded radiance. It returns a :class:`Layer`.
* :func:`composite` maps the object's colours from the reference colour space into the current
  frame's by the inverse of the latest accepted correction matrix, clips and sRGB-encodes them and
  draws them over the frame; the shadow plane is a dark-grey plane alpha-blended **in linear light**
  (docs/render.md explains the choice).

Two backends produce the same :class:`Layer` (tests compare them pixel for pixel):

* ``"pyrender"`` (the reference): pyrender 0.1.45 on an EGL (or OSMesa) context, with a subclass of
  its ``Renderer`` that draws into a single-sample float32 framebuffer (pyrender's own is 4× MSAA
  RGBA8, which would quantise linear colours to 8 bits and blend mask edges), clears, draws and reads
  back only the scissor rectangle that bounds the projected geometry, and skips the depth readback.
  The scene (two meshes and a camera) is built once; per frame only the camera pose and the vertex
  buffers (positions, colours, alphas) are updated (``glBufferSubData``).
* ``"numba"`` (the default; 2–3× faster than pyrender on llvmpipe, docs/render.md): a
  single-threaded z-buffer triangle rasteriser written here: near-plane and guard-band clipping in
  camera space, vertices snapped to 1/256 pixel and integer edge functions with a top-left-style tie
  rule (watertight: a pixel centre on an edge shared by two triangles is drawn exactly once),
  perspective-correct interpolation.

Conventions: ``T_world_from_cam`` is an OpenCV camera pose (x right, y down, z forward); pixel
(column u, row v) has its centre at integer (u, v); the rasteriser covers a pixel when its centre lies
inside the projected triangle. The pyrender camera therefore gets principal point (cx + ½, cy + ½),
because OpenGL puts pixel centres at half-integers (window coordinates; checked in the tests against
:func:`rgbd_envmap.geometry.project_points`). Only :func:`rgbd_envmap.geometry.opengl_from_opencv`
flips camera axes.

References:
    Monroy, Hudon, Smolic (2018), Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §7.1 (dark-grey shadow plane with alpha from the irradiance ratio) and §7.2
    (compositing with the inverse correction matrix and a virtual camera matching the colour camera).
    Gouraud, H. (1971), Continuous shading of curved surfaces, IEEE Trans. Computers C-20(6).
    Pineda, J. (1988), A parallel algorithm for polygon rasterization, SIGGRAPH '88 (edge functions).
    Sutherland, I. E., Hodgman, G. W. (1974), Reentrant polygon clipping, CACM 17(1).
    Heckbert, P., Moreton, H. (1991), Interpolation for polygon texture mapping and shading
    (perspective-correct interpolation of attribute / z and 1 / z).
    IEC 61966-2-1:1999 (sRGB transfer function).
"""

from __future__ import annotations

import os

# PyOpenGL picks its platform when first imported; pyrender needs a headless one (EGL works with
# Mesa's llvmpipe). A value the caller has already set wins.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from rgbd_envmap.checks import check_array, check_method, check_range
from rgbd_envmap.colour import srgb8_to_linear_lut, srgb_to_linear
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)
from rgbd_envmap.geometry import opengl_from_opencv
from rgbd_envmap.types import Intrinsics, RigidTransform

__all__ = [
    "BACKENDS",
    "Layer",
    "Renderer",
    "RendererUnavailableError",
    "composite",
    "egl_available",
]

#: Rasteriser backends accepted by :class:`Renderer`; ``"pyrender"`` is the reference, ``"numba"`` the
#: default (faster on a CPU; the tests hold the two to the same result).
BACKENDS: tuple[str, ...] = ("pyrender", "numba")

#: Sub-pixel precision of the numba rasteriser: vertices snap to 1 / 2**_SUBPIXEL_BITS pixel
#: (8 bits, as in Mesa's llvmpipe), so edge functions are exact int64 arithmetic.
_SUBPIXEL_BITS = 8
_SUBPIXEL = 1 << _SUBPIXEL_BITS
#: Guard band in pixels: triangles reaching further outside the image are clipped in camera space, which
#: keeps the fixed-point coordinates (and their products in the edge functions) well inside int64.
_GUARD_PX = 4096.0
#: Marks a projected vertex that needs clipping (its fixed-point x is never this inside the guard band).
_CLIP = np.int32(np.iinfo(np.int32).min)
#: Plane alphas this far outside [0, 1] (rounding in the PRT ratio) are clipped rather than rejected.
_ALPHA_SLACK = 1e-6
#: Marker values in the GL colour attachment's alpha: the object writes 1, the plane 0.5, the clear 0.
_GL_OBJECT_ALPHA = 1.0
_GL_PLANE_ALPHA = 0.5


class RendererUnavailableError(RgbdEnvmapError, RuntimeError):
    """The requested backend cannot run here (e.g. no EGL / OpenGL context), or the renderer is closed."""


# ------------------------------------------------------------------------------------------------
# The result
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Layer:
    """What the rasteriser produced for one frame (read-only arrays).

    Attributes:
        colour: (H, W, 3) float32 linear RGB of the object in the **reference** colour space (what
            the PRT shading produced), Gouraud-interpolated; 0 outside ``mask``. Negative vertex colours
            are clamped to 0 before interpolation; values above 1 are kept.
        mask: (H, W) bool, True where the object is the nearest surface.
        plane_alpha: (H, W) float32 in [0, 1], the shadow plane's interpolated alpha where the plane is
            the nearest surface; 0 where the plane is not visible or the object hides it.
        bbox: (row0, row1, col0, col1), half-open, a rectangle outside which every array is zero (and
            ``mask`` False), or None when nothing is visible. :func:`composite` works inside it only.
    """

    colour: np.ndarray
    mask: np.ndarray
    plane_alpha: np.ndarray
    bbox: tuple[int, int, int, int] | None

    def __post_init__(self) -> None:
        colour = check_array(self.colour, "Layer.colour", shape=("H", "W", 3), dtype=np.float32)
        h, w = colour.shape[:2]
        mask = check_array(self.mask, "Layer.mask", shape=(h, w), dtype=np.bool_)
        alpha = check_array(self.plane_alpha, "Layer.plane_alpha", shape=(h, w), dtype=np.float32)
        if self.bbox is not None:
            r0, r1, c0, c1 = (int(x) for x in self.bbox)
            if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w):
                raise InvalidInputError(
                    f"Layer.bbox: expected 0 <= row0 < row1 <= {h} and 0 <= col0 < col1 <= {w}, got {self.bbox}")
            object.__setattr__(self, "bbox", (r0, r1, c0, c1))
        for name, arr in (("colour", colour), ("mask", mask), ("plane_alpha", alpha)):
            if arr.flags.writeable:
                arr = arr.view()
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def empty(cls, height: int, width: int) -> Layer:
        """A layer with nothing visible (what an object behind the camera or out of view gives)."""
        return cls(np.zeros((height, width, 3), np.float32), np.zeros((height, width), bool),
                   np.zeros((height, width), np.float32), None)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width)."""
        return self.mask.shape

    @property
    def is_empty(self) -> bool:
        """True when neither the object nor the plane covers a pixel."""
        if self.bbox is None:
            return True
        r0, r1, c0, c1 = self.bbox
        return not (self.mask[r0:r1, c0:c1].any() or self.plane_alpha[r0:r1, c0:c1].any())


# ------------------------------------------------------------------------------------------------
# Input checks shared by the backends
# ------------------------------------------------------------------------------------------------


def _as_pose(T_world_from_cam: object) -> RigidTransform:
    if isinstance(T_world_from_cam, RigidTransform):
        return T_world_from_cam
    m = check_array(T_world_from_cam, "T_world_from_cam", shape=(4, 4), dtype=("float", "int"), finite=True)
    return RigidTransform(m.astype(np.float64), "world", "cam")


def _check_mesh(vertices: object, faces: object, prefix: str) -> tuple[np.ndarray, np.ndarray]:
    v = check_array(vertices, f"{prefix}_vertices_world", shape=("N", 3), dtype=("float", "int"), finite=True)
    f = check_array(faces, f"{prefix}_faces", shape=("F", 3), dtype="int")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise RangeError(
            f"{prefix}_faces: expected vertex indices in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    # Faces as a read-only view either way: numba compiles one specialisation of the rasteriser
    # per array flag, and the object's faces are read-only, the plane's not (5.5 s of a first run).
    f = np.ascontiguousarray(f, dtype=np.int32).view()
    f.flags.writeable = False
    return v.astype(np.float64, copy=False), f


def _check_inputs(T_world_from_cam, object_vertices_world, object_faces, object_colours,
                  plane_vertices_world, plane_faces, plane_alpha):
    pose = _as_pose(T_world_from_cam)
    ov, of = _check_mesh(object_vertices_world, object_faces, "object")
    oc = check_array(object_colours, "object_colours", shape=(len(ov), 3), dtype="float", finite=True)
    pv, pf = _check_mesh(plane_vertices_world, plane_faces, "plane")
    pa = check_array(plane_alpha, "plane_alpha", shape=(len(pv),), dtype="float", finite=True)
    check_range(pa, "plane_alpha", -_ALPHA_SLACK, 1.0 + _ALPHA_SLACK)
    oc = np.maximum(oc, 0.0).astype(np.float32)
    return pose, ov, of, oc, pv, pf, np.clip(pa, 0.0, 1.0).astype(np.float32)


def _to_camera(pose: RigidTransform, points_world: np.ndarray) -> np.ndarray:
    """(N, 3) world points → camera frame, float64 (p_cam = Rᵀ (p_world − t))."""
    r = pose.rotation
    return (points_world - pose.translation) @ r


# ------------------------------------------------------------------------------------------------
# Per-vertex projection and screen-space bounds (both backends)
# ------------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _grow(bounds, u, v):  # pragma: no cover - compiled
    bounds[0] = min(bounds[0], u)
    bounds[1] = max(bounds[1], u)
    bounds[2] = min(bounds[2], v)
    bounds[3] = max(bounds[3], v)


@numba.njit(cache=True)
def _prepare_vertices(pc, faces, near, fx, fy, cx, cy, width, height, xy, iz, bounds):  # pragma: no cover
    """Project camera-frame vertices ``pc`` (V, 3) once per frame.

    Writes per vertex: ``xy`` (V, 2) int32 the screen position in fixed point (1/256 px, pixel centres at
    multiples of 256), or :data:`_CLIP` in x when the vertex is not usable without clipping (z < near or
    outside the guard band); ``iz`` = 1/z (0 behind the near plane). Grows ``bounds`` = [umin, umax, vmin, vmax] by the projection of every part of the mesh in
    front of the near plane: the vertices there, and the points where edges cross z = near (only
    looked for when some vertex is behind it). Returns True when some vertex is in front.
    """
    g = _GUARD_PX
    n_behind = 0
    for i in range(pc.shape[0]):
        z = pc[i, 2]
        if z >= near:
            inv = 1.0 / z
            u = fx * pc[i, 0] * inv + cx
            v = fy * pc[i, 1] * inv + cy
            _grow(bounds, u, v)
            iz[i] = inv
            if -g <= u <= width - 1.0 + g and -g <= v <= height - 1.0 + g:
                xy[i, 0] = np.int32(np.floor(u * _SUBPIXEL + 0.5))
                xy[i, 1] = np.int32(np.floor(v * _SUBPIXEL + 0.5))
            else:
                xy[i, 0] = _CLIP
        else:
            xy[i, 0] = _CLIP
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
                    _grow(bounds, fx * (pc[a, 0] + t * (pc[b, 0] - pc[a, 0])) / near + cx,
                          fy * (pc[a, 1] + t * (pc[b, 1] - pc[a, 1])) / near + cy)
    return n_behind < pc.shape[0]


class _Projected:
    """A mesh's per-frame vertex data: camera-frame positions and their projection."""

    def __init__(self, pc: np.ndarray, faces: np.ndarray, intr: Intrinsics, near: float, bounds: np.ndarray):
        n = len(pc)
        self.pc, self.faces = pc, faces
        self.xy = np.empty((n, 2), np.int32)
        self.iz = np.empty(n, np.float64)
        self.any_front = bool(len(faces)) and _prepare_vertices(
            pc, faces, near, intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height, self.xy, self.iz, bounds)


def _project_meshes(pose, meshes, intr: Intrinsics, near: float):
    """Transform and project each (vertices_world, faces); returns the :class:`_Projected` meshes and the
    half-open (row0, row1, col0, col1) bounding the pixel centres the visible geometry can cover
    (clipped to the image, one pixel of margin for vertex snapping), or None when nothing can be."""
    bounds = np.array([np.inf, -np.inf, np.inf, -np.inf])
    projected = [_Projected(_to_camera(pose, v), f, intr, near, bounds) for v, f in meshes]
    if not any(p.any_front for p in projected) or not np.isfinite(bounds).all():
        return projected, None
    big = 1e9  # projections of points near the near plane can be huge; clamp before int conversion
    umin, umax, vmin, vmax = np.clip(bounds, -big, big)
    c0 = max(int(np.floor(umin)) - 1, 0)
    c1 = min(int(np.floor(umax)) + 2, intr.width)
    r0 = max(int(np.floor(vmin)) - 1, 0)
    r1 = min(int(np.floor(vmax)) + 2, intr.height)
    if c0 >= c1 or r0 >= r1:
        return projected, None
    return projected, (r0, r1, c0, c1)


# ------------------------------------------------------------------------------------------------
# The numba rasteriser
# ------------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _owns_edge(dx, dy):  # pragma: no cover - compiled
    """Tie rule for a pixel centre exactly on an edge (a→b, dx = xb − xa, dy = yb − ya): of the two
    triangles sharing the edge (which see it in opposite directions) exactly one owns it."""
    return dy > 0 or (dy == 0 and dx < 0)


@numba.njit(cache=True, inline="always")
def _raster_triangle(xy, iz, attr, i0, i1, i2, is_plane, inv_far, r0, r1, c0, c1,
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
    px0 = max(-((-min(x0, min(x1, x2))) >> _SUBPIXEL_BITS), c0)
    px1 = min(max(x0, max(x1, x2)) >> _SUBPIXEL_BITS, c1 - 1)
    if px0 > px1:
        return
    py0 = max(-((-min(y0, min(y1, y2))) >> _SUBPIXEL_BITS), r0)
    py1 = min(max(y0, max(y1, y2)) >> _SUBPIXEL_BITS, r1 - 1)
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
    b0 = 0 if _owns_edge(e0dx, e0dy) else 1
    b1 = 0 if _owns_edge(e1dx, e1dy) else 1
    b2 = 0 if _owns_edge(e2dx, e2dy) else 1
    inv_area = 1.0 / area
    n_attr = attr.shape[1]
    sx = px0 * _SUBPIXEL
    for py in range(py0, py1 + 1):
        sy = py * _SUBPIXEL
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
            w0 -= e0dy * _SUBPIXEL
            w1 -= e1dy * _SUBPIXEL
            w2 -= e2dy * _SUBPIXEL


@numba.njit(cache=True)
def _raster_mesh(pc, faces, attr, xy, iz, is_plane, near, far, fx, fy, cx, cy, width, height,
                 r0, r1, c0, c1, invz, colour, mask, alpha):  # pragma: no cover - compiled
    """Rasterise every triangle of one mesh into the z-buffer ``invz`` (1/z, 0 = empty) and the layer
    arrays, within rows [r0, r1) and columns [c0, c1). ``xy, iz`` from :func:`_prepare_vertices`;
    triangles with a vertex marked :data:`_CLIP` are clipped in camera space first."""
    n_attr = attr.shape[1]
    inv_far = 1.0 / far
    # Clip planes n·(x, y, z) + d ≥ 0 in camera space: near, and the four guard-band planes
    # u ≥ −G, u ≤ W − 1 + G, v ≥ −G, v ≤ H − 1 + G.
    g = _GUARD_PX
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
        if xy[i0, 0] != _CLIP and xy[i1, 0] != _CLIP and xy[i2, 0] != _CLIP:
            _raster_triangle(xy, iz, attr, i0, i1, i2, is_plane, inv_far, r0, r1, c0, c1,
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
            cxy[k, 0] = np.int32(np.floor((fx * poly[k, 0] / z + cx) * _SUBPIXEL + 0.5))
            cxy[k, 1] = np.int32(np.floor((fy * poly[k, 1] / z + cy) * _SUBPIXEL + 0.5))
            for c in range(n_attr):
                cattr[k, c] = poly[k, 3 + c]
        for k in range(1, n - 1):  # fan-triangulate the convex clipped polygon
            _raster_triangle(cxy, ciz, cattr, 0, k, k + 1, is_plane, inv_far, r0, r1, c0, c1,
                             invz, colour, mask, alpha)


class _NumbaBackend:
    name = "numba"

    def __init__(self, intr: Intrinsics, near: float, far: float, crop: bool) -> None:
        self._intr = intr
        self._near = near
        self._far = far
        self._crop = crop
        self._invz = np.zeros((intr.height, intr.width), np.float64)

    def draw(self, pose, ov, of, oc, pv, pf, pa) -> Layer:
        intr = self._intr
        (obj, plane), bbox = _project_meshes(pose, ((ov, of), (pv, pf)), intr, self._near)
        if bbox is None:
            return Layer.empty(intr.height, intr.width)
        if not self._crop:
            bbox = (0, intr.height, 0, intr.width)
        r0, r1, c0, c1 = bbox
        colour = np.zeros((intr.height, intr.width, 3), np.float32)
        mask = np.zeros((intr.height, intr.width), bool)
        alpha = np.zeros((intr.height, intr.width), np.float32)
        invz = self._invz
        invz[r0:r1, c0:c1] = 0.0
        args = (self._near, self._far, intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height,
                r0, r1, c0, c1, invz, colour, mask, alpha)
        for mesh, attr, is_plane in ((obj, oc, False), (plane, pa.reshape(-1, 1), True)):
            if mesh.any_front:
                _raster_mesh(mesh.pc, mesh.faces, attr, mesh.xy, mesh.iz, is_plane, *args)
        return Layer(colour, mask, alpha, bbox)

    def close(self) -> None:
        self._invz = None


# ------------------------------------------------------------------------------------------------
# The pyrender backend
# ------------------------------------------------------------------------------------------------


def _make_platform(width: int, height: int):
    """An offscreen GL platform for pyrender (EGL or OSMesa, per ``PYOPENGL_PLATFORM``)."""
    name = os.environ.get("PYOPENGL_PLATFORM", "")
    if name == "egl":
        from pyrender.platforms import egl

        device = egl.get_device_by_index(int(os.environ.get("EGL_DEVICE_ID", "0")))
        platform = egl.EGLPlatform(width, height, device=device)
    elif name == "osmesa":
        from pyrender.platforms.osmesa import OSMesaPlatform

        platform = OSMesaPlatform(width, height)
    else:
        raise RendererUnavailableError(
            f"PYOPENGL_PLATFORM: expected 'egl' or 'osmesa' for offscreen rendering, got {name!r}")
    platform.init_context()
    platform.make_current()
    return platform


@lru_cache(maxsize=1)
def _layer_renderer_class():
    """pyrender.Renderer subclass drawing into a single-sample RGBA32F framebuffer inside a scissor
    rectangle, uploading pending vertex data before drawing, and reading back only that rectangle's
    colour (no depth readback). Built lazily so importing this module does not import OpenGL."""
    import pyrender
    from OpenGL import GL

    class _LayerGLRenderer(pyrender.Renderer):
        def __init__(self, width: int, height: int) -> None:
            super().__init__(width, height)
            self.scissor = (0, 0, width, height)  # x, y (GL: from the bottom), w, h
            self.pending: list[tuple[object, np.ndarray]] = []

        def _update_context(self, scene, flags):
            super()._update_context(scene, flags)
            for primitive, data in self.pending:
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, primitive._buffers[0])
                GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
            self.pending = []

        def _configure_main_framebuffer(self):
            if self._main_fb is not None:
                return
            w, h = self.viewport_width, self.viewport_height
            self._main_cb, self._main_db = GL.glGenRenderbuffers(2)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_cb)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA32F, w, h)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_db)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, w, h)
            self._main_fb = GL.glGenFramebuffers(1)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER,
                                         self._main_cb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER,
                                         self._main_db)
            status = GL.glCheckFramebufferStatus(GL.GL_DRAW_FRAMEBUFFER)
            if status != GL.GL_FRAMEBUFFER_COMPLETE:
                raise RendererUnavailableError(f"float32 framebuffer is incomplete (status {status:#x})")
            # pyrender's forward pass draws into _main_fb_ms: the same single-sample buffer here.
            self._main_fb_ms = self._main_fb
            self._main_fb_dims = (w, h)

        def _delete_main_framebuffer(self):
            if self._main_fb is not None:
                GL.glDeleteFramebuffers(1, [self._main_fb])
                GL.glDeleteRenderbuffers(2, [self._main_cb, self._main_db])
            self._main_fb = self._main_cb = self._main_db = None
            self._main_fb_ms = self._main_cb_ms = self._main_db_ms = None
            self._main_fb_dims = (None, None)

        def _configure_forward_pass_viewport(self, flags):
            super()._configure_forward_pass_viewport(flags)
            GL.glEnable(GL.GL_SCISSOR_TEST)  # also limits the glClear in the forward pass
            GL.glScissor(*self.scissor)

        def _read_main_framebuffer(self, scene, flags):
            x, y, w, h = self.scissor
            out = np.empty((h, w, 4), np.float32)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
            GL.glReadPixels(x, y, w, h, GL.GL_RGBA, GL.GL_FLOAT, out)
            return out  # rows bottom-up, as GL stores them

    return _LayerGLRenderer


class _GLMesh:
    """One pyrender mesh node whose vertex buffer (position xyz, colour rgba: 7 float32) is rewritten
    each frame; rebuilt only when the faces or the vertex count change."""

    def __init__(self) -> None:
        self.node = None
        self.primitive = None
        self.faces: np.ndarray | None = None
        self.data: np.ndarray | None = None

    def update(self, scene, renderer, vertices: np.ndarray, faces: np.ndarray, rgba_fill) -> None:
        import pyrender

        n = len(vertices)
        if self.node is not None and (self.faces is None or self.faces.shape != faces.shape
                                      or len(self.data) != n or not np.array_equal(self.faces, faces)):
            scene.remove_node(self.node)
            self.node = None
        if self.data is None or len(self.data) != n:
            self.data = np.empty((n, 7), np.float32)
        self.data[:, :3] = vertices
        rgba_fill(self.data[:, 3:])
        if len(faces) == 0:
            self.faces = faces.copy()
            return
        if self.node is None:
            material = pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0), doubleSided=True)
            self.primitive = pyrender.Primitive(positions=self.data[:, :3], indices=faces, color_0=self.data[:, 3:],
                                                material=material)
            self.node = scene.add(pyrender.Mesh([self.primitive]))
            self.faces = faces.copy()
        else:
            renderer.pending.append((self.primitive, self.data))


class _PyrenderBackend:
    name = "pyrender"

    def __init__(self, intr: Intrinsics, near: float, far: float, crop: bool) -> None:
        try:
            import pyrender

            self._platform = _make_platform(intr.width, intr.height)
            self._renderer = _layer_renderer_class()(intr.width, intr.height)
        except RendererUnavailableError:
            raise
        except Exception as exc:  # any GL / EGL failure means "not available here"
            raise RendererUnavailableError(
                f"backend 'pyrender': cannot create an offscreen OpenGL context "
                f"(PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r}): {type(exc).__name__}: {exc}") from exc
        self._pyrender = pyrender
        self._flags = (pyrender.RenderFlags.FLAT | pyrender.RenderFlags.RGBA | pyrender.RenderFlags.SKIP_CULL_FACES
                       | pyrender.RenderFlags.OFFSCREEN)
        self._intr = intr
        self._near = near
        self._crop = crop
        self._scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
        # OpenGL pixel centres sit at half-integers: shift the principal point by half a pixel.
        camera = pyrender.IntrinsicsCamera(intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5, znear=near, zfar=far)
        self._camera_node = self._scene.add(camera, pose=np.eye(4))
        self._object = _GLMesh()
        self._plane = _GLMesh()

    def draw(self, pose, ov, of, oc, pv, pf, pa) -> Layer:
        intr = self._intr
        _, bbox = _project_meshes(pose, ((ov, of), (pv, pf)), intr, self._near)
        if bbox is None:
            return Layer.empty(intr.height, intr.width)
        if not self._crop:
            bbox = (0, intr.height, 0, intr.width)
        r0, r1, c0, c1 = bbox
        # The flat shader clamps colours to [0, 1]: scale HDR colours down for the draw and back up after.
        scale = max(float(oc.max(initial=0.0)), 1.0)

        def object_rgba(dst):
            np.multiply(oc, 1.0 / scale, out=dst[:, :3])
            dst[:, 3] = _GL_OBJECT_ALPHA

        def plane_rgba(dst):
            dst[:, 0] = pa
            dst[:, 1:3] = 0.0
            dst[:, 3] = _GL_PLANE_ALPHA

        self._platform.make_current()
        self._object.update(self._scene, self._renderer, ov, of, object_rgba)
        self._plane.update(self._scene, self._renderer, pv, pf, plane_rgba)
        self._scene.set_pose(self._camera_node, opengl_from_opencv(pose).matrix)
        self._renderer.scissor = (c0, intr.height - r1, c1 - c0, r1 - r0)
        rgba = self._renderer.render(self._scene, self._flags)
        return _layer_from_rgba(rgba, scale, bbox, intr)

    def close(self) -> None:
        if self._renderer is None:
            return
        try:
            self._platform.make_current()
            self._renderer.delete()
        finally:
            self._renderer = None
            _destroy_platform(self._platform)
            self._platform = None


def _destroy_platform(platform) -> None:
    """Destroy the context only: pyrender's EGL ``delete_context`` also calls ``eglTerminate`` on the
    display, which is shared by every EGL context of the process and would kill other renderers."""
    display = getattr(platform, "_egl_display", None)
    context = getattr(platform, "_egl_context", None)
    if display is not None and context is not None:
        from OpenGL import EGL

        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(display, context)
    if display is not None:
        # Platform.__del__ calls delete_context(), which would still terminate the shared display.
        platform._egl_context = None
        platform._egl_display = None
    else:
        platform.delete_context()


@numba.njit(cache=True)
def _split_rgba(rgba, scale, r0, c0, colour, mask, alpha):  # pragma: no cover - compiled
    """Unpack the GL read-back ``rgba`` (h, w, 4), rows bottom-up, into the layer arrays at (r0, c0):
    alpha-channel marker 1 = object (rgb × scale is its colour), 0.5 = plane (red is its alpha)."""
    h = rgba.shape[0]
    obj_cut = 0.5 * (_GL_OBJECT_ALPHA + _GL_PLANE_ALPHA)
    plane_cut = 0.5 * _GL_PLANE_ALPHA
    for i in range(h):
        src = rgba[h - 1 - i]
        r = r0 + i
        for j in range(rgba.shape[1]):
            marker = src[j, 3]
            if marker > obj_cut:
                c = c0 + j
                mask[r, c] = True
                colour[r, c, 0] = src[j, 0] * scale
                colour[r, c, 1] = src[j, 1] * scale
                colour[r, c, 2] = src[j, 2] * scale
            elif marker > plane_cut:
                alpha[r, c0 + j] = src[j, 0]


def _layer_from_rgba(rgba: np.ndarray, scale: float, bbox, intr: Intrinsics) -> Layer:
    """The layer of a GL read-back of the bbox (see :func:`_split_rgba`)."""
    colour = np.zeros((intr.height, intr.width, 3), np.float32)
    mask = np.zeros((intr.height, intr.width), bool)
    alpha = np.zeros((intr.height, intr.width), np.float32)
    _split_rgba(rgba, np.float32(scale), bbox[0], bbox[2], colour, mask, alpha)
    return Layer(colour, mask, alpha, bbox)


def egl_available() -> tuple[bool, str]:
    """Whether the pyrender backend can create an offscreen context here: ``(ok, reason)``.
    Creates and destroys a 1×1 context."""
    try:
        r = _PyrenderBackend(Intrinsics(1, 1, 1.0, 1.0, 0.0, 0.0), 0.05, 20.0, True)
    except RendererUnavailableError as exc:
        return False, str(exc)
    except ImportError as exc:
        return False, f"pyrender / PyOpenGL not importable: {exc}"
    r.close()
    return True, ""


# ------------------------------------------------------------------------------------------------
# The public renderer
# ------------------------------------------------------------------------------------------------


class Renderer:
    """A reusable offscreen renderer for a virtual camera matching a colour camera.

    Args:
        intrinsics: the colour camera (``fx, fy, cx, cy, width, height``); its distortion is ignored:
            the virtual camera is the undistorted pinhole with OpenCV pixel centres.
        near_m, far_m: clip distances along the optical axis (z-depth), metres; 0 < near < far.
        backend: ``"numba"`` (the default: the CPU rasteriser written here, about 2–3× faster than
            pyrender on llvmpipe, see docs/render.md) or ``"pyrender"`` (the reference: OpenGL through
            EGL); :data:`BACKENDS`. Both give the same layer up to edge pixels and float rounding.
        crop: clear, rasterise and read back only the rectangle bounding the projected geometry (the
            default); False processes the whole frame (the same result, slower; for benchmarks).

    Raises:
        RendererUnavailableError: the backend cannot run here (no EGL / OpenGL for ``"pyrender"``).
        UnknownMethodError / RangeError / DTypeError: bad arguments.

    Use as a context manager or call :meth:`close` (frees the GL context). Example::

        with Renderer(intrinsics, backend="numba") as r:
            layer = r.render(T_world_from_cam, verts, faces, colours, plane_verts, plane_faces, alpha)
            out = composite(frame_srgb8, layer, ccm_inverse=invert_ccm(M))
    """

    def __init__(self, intrinsics: Intrinsics, *, near_m: float = 0.05, far_m: float = 20.0,
                 backend: str = "numba", crop: bool = True) -> None:
        if not isinstance(intrinsics, Intrinsics):
            raise DTypeError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
        check_method(backend, BACKENDS, "backend")
        near, far = float(near_m), float(far_m)
        if not (np.isfinite(near) and np.isfinite(far)):
            raise NonFiniteError(f"near_m, far_m: expected finite values, got {near_m}, {far_m}")
        if not 0.0 < near < far:
            raise RangeError(f"near_m, far_m: expected 0 < near_m < far_m, got near_m={near_m}, far_m={far_m}")
        self.intrinsics = intrinsics
        self.near_m = near
        self.far_m = far
        self.backend = backend
        cls = _PyrenderBackend if backend == "pyrender" else _NumbaBackend
        self.crop = bool(crop)
        self._impl = cls(intrinsics, near, far, self.crop)

    def render(self, T_world_from_cam: RigidTransform | np.ndarray, object_vertices_world: np.ndarray,
               object_faces: np.ndarray, object_colours: np.ndarray, plane_vertices_world: np.ndarray,
               plane_faces: np.ndarray, plane_alpha: np.ndarray) -> Layer:
        """Rasterise the object and the shadow plane seen from ``T_world_from_cam``.

        Args:
            T_world_from_cam: the colour camera's pose (OpenCV axes), a :class:`RigidTransform` or a
                (4, 4) float array.
            object_vertices_world: (V, 3) float, metres, world frame.
            object_faces: (F, 3) int vertex indices (either winding; no back-face culling).
            object_colours: (V, 3) float linear RGB in the reference colour space (the PRT-shaded
                radiance; values above 1 are kept, negative ones clamped to 0).
            plane_vertices_world: (P, 3) float, metres.
            plane_faces: (G, 3) int.
            plane_alpha: (P,) float in [0, 1], the shadow's opacity per plane vertex (values within 1e-6
                outside are clipped; further out raise RangeError).

        Returns:
            A :class:`Layer` of the camera's size. An object and plane behind the camera or out of
            view give an empty layer (no error). Empty meshes (0 faces) are allowed.

        Raises:
            ShapeError / DTypeError / NonFiniteError / RangeError: bad inputs (message names the
            argument); RendererUnavailableError: the renderer is closed.
        """
        if self._impl is None:
            raise RendererUnavailableError("Renderer.render: the renderer is closed")
        inputs = _check_inputs(T_world_from_cam, object_vertices_world, object_faces, object_colours,
                               plane_vertices_world, plane_faces, plane_alpha)
        return self._impl.draw(*inputs)

    def close(self) -> None:
        """Free the backend's resources (the GL context for pyrender). Idempotent."""
        if self._impl is not None:
            impl, self._impl = self._impl, None
            impl.close()

    @property
    def closed(self) -> bool:
        return self._impl is None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: GL may already be gone
            pass


# ------------------------------------------------------------------------------------------------
# Compositing
# ------------------------------------------------------------------------------------------------


#: Bins of the sRGB encoder's lookup table over [0, 1]; fine enough that no bin holds two code steps.
_ENCODE_BINS = 4096


@lru_cache(maxsize=1)
def _srgb8_encoder() -> tuple[np.ndarray, np.ndarray]:
    """Exact 8-bit sRGB encoding by table: ``thresholds`` (256,) float64 holds the 255 linear values at
    which the code steps up, then +inf, so code(x) = #{t_k ≤ x} = round-half-up(255 · srgb(x))
    (evaluated in float64); ``base`` (_ENCODE_BINS,) uint8 is that count at each bin's lower edge.
    Consecutive thresholds are at least 3.0e-4 apart (at the dark end) > 1/4096, so a bin holds at most
    one step: the code of x is ``base[bin] + (x ≥ thresholds[base[bin]])``."""
    t = srgb_to_linear((np.arange(1, 256, dtype=np.float64) - 0.5) / 255.0)
    if np.diff(t).min() <= 1.0 / _ENCODE_BINS:  # a guard on the reasoning above, not on user input
        raise RgbdEnvmapError("sRGB encoder table: bins too coarse")
    base = np.searchsorted(t, np.arange(_ENCODE_BINS) / _ENCODE_BINS, side="right").astype(np.uint8)
    t = np.append(t, np.inf)
    for a in (t, base):
        a.setflags(write=False)
    return t, base


@numba.njit(cache=True, inline="always")
def _encode8(x, thresholds, base):  # pragma: no cover - compiled
    """Linear value → 8-bit sRGB code, clipping to [0, 1] (NaN → 0)."""
    if not x > 0.0:
        return 0
    if x >= 1.0:
        return 255
    k = np.int64(base[np.int64(x * _ENCODE_BINS)])
    if x >= thresholds[k]:
        k += 1
    return k


@numba.njit(cache=True)
def _composite_kernel(out, colour, mask, alpha, r0, r1, c0, c1, m, use_m, grey, lut, thresholds, base):  # pragma: no cover
    """In place on ``out`` (H, W, 3) uint8 within the bbox: object pixels ← encode(M · colour); plane
    pixels ← encode((1 − α) · decode(out) + α · grey), in linear light."""
    for r in range(r0, r1):
        orow = out[r]
        mrow = mask[r]
        arow = alpha[r]
        crow = colour[r]
        for c in range(c0, c1):
            if mrow[c]:
                cr = np.float64(crow[c, 0])
                cg = np.float64(crow[c, 1])
                cb = np.float64(crow[c, 2])
                if use_m:
                    for k in range(3):
                        orow[c, k] = _encode8(m[k, 0] * cr + m[k, 1] * cg + m[k, 2] * cb, thresholds, base)
                else:
                    orow[c, 0] = _encode8(cr, thresholds, base)
                    orow[c, 1] = _encode8(cg, thresholds, base)
                    orow[c, 2] = _encode8(cb, thresholds, base)
            else:
                a = np.float64(arow[c])
                if a > 0.0:
                    b = 1.0 - a
                    for k in range(3):
                        orow[c, k] = _encode8(b * lut[orow[c, k]] + a * grey[k], thresholds, base)


def composite(frame_srgb: np.ndarray, layer: Layer, *, ccm_inverse: np.ndarray | None = None,
              shadow_grey: float = 0.15) -> np.ndarray:
    """Draw a rendered :class:`Layer` over a live colour frame (paper 003 §7.2).

    The object's colours are in the reference colour space; ``ccm_inverse`` (the inverse of the latest
    accepted correction matrix, :func:`rgbd_envmap.colour.invert_ccm`) maps them into this frame's
    space (``dst = rgb @ ccm_inverse.T``, :func:`rgbd_envmap.colour.apply_ccm`'s convention). They are
    then clipped to [0, 1], sRGB-encoded and written where ``layer.mask`` is set. Where the shadow
    plane is visible the frame is blended towards a grey plane, **in linear light**:
    ``out = (1 − α) · frame + α · grey`` with ``frame`` decoded from sRGB and ``grey`` =
    ``ccm_inverse @ (shadow_grey, shadow_grey, shadow_grey)`` (the plane is virtual content in the
    reference space, like the object). With ``shadow_grey = 0`` this is the physical attenuation
    ``frame · (1 − α)``; docs/render.md explains why not in sRGB. 8-bit codes round half up.

    Args:
        frame_srgb: (H, W, 3) uint8 sRGB, the live colour frame (not modified).
        layer: a :class:`Layer` of the same (H, W).
        ccm_inverse: (3, 3) finite float, or None for the identity (frame space = reference space).
        shadow_grey: linear grey level of the shadow plane in the reference space, ≥ 0.

    Returns:
        (H, W, 3) uint8 sRGB, a new array; equal to ``frame_srgb`` bit for bit where the layer is empty.
    """
    frame = check_array(frame_srgb, "frame_srgb", shape=("H", "W", 3), dtype=np.uint8)
    if not isinstance(layer, Layer):
        raise DTypeError(f"layer: expected a Layer, got {type(layer).__name__}")
    if frame.shape[:2] != layer.shape:
        raise ShapeError(f"layer: expected the frame's size {frame.shape[:2]}, got {layer.shape}")
    grey_level = float(shadow_grey)
    if not np.isfinite(grey_level) or grey_level < 0.0:
        raise RangeError(f"shadow_grey: expected a finite value >= 0, got {shadow_grey}")
    if ccm_inverse is None:
        m = np.eye(3)
        use_m = False
    else:
        m = check_array(ccm_inverse, "ccm_inverse", shape=(3, 3), dtype=("float", "int"), finite=True)
        m = np.ascontiguousarray(m, dtype=np.float64)
        use_m = True
    out = frame.copy()
    if layer.bbox is None:
        return out
    grey = m @ np.full(3, grey_level)
    r0, r1, c0, c1 = layer.bbox
    _composite_kernel(out, layer.colour, layer.mask, layer.plane_alpha, r0, r1, c0, c1, m, use_m, grey,
                      srgb8_to_linear_lut(), *_srgb8_encoder())
    return out

