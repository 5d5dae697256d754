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

       |P_a − P_b| > max_stretch · s · min(z_a, z_b) / f,     f = √|fx fy| (focal lengths are signed),

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
   pixel when no triangle covers it (:func:`rgbd_envmap._kernels.kinect.rim_row`), so that sub-pixel
   motion does not shave a row off the history at every boundary every other frame.
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
Defaults and their measured effect: docs/design/kinect_merge.md.

Depth maps are (H, W) float32 **z-depth** in metres with an explicit ``known`` mask; depth values
under ``known == False`` are never read and come back as 0. A known pixel with NaN, inf or depth ≤ 0
is treated as unknown (never an error). All hot loops are single-threaded numba kernels
(:mod:`rgbd_envmap._kernels.kinect`, whose docstring describes their data layout;
benchmarks/bench_kinect.py times them beside ``cv2.warpFrame``, ``cv2.RgbdNormals`` and kornia).
:func:`rgbd_envmap.reference.kinect.warp_reference` is the warp written out in float64 loops.

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
import numpy as np

from rgbd_envmap._kernels import kinect as kernels
from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.colour.nv21 import srgb8_to_linear_lut
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics, RGBDFrame, RigidTransform, check_transform

__all__ = [
    "KinectMergeConfig",
    "KinectMergeResult",
    "KinectMerger",
    "warp_depth",
    "merge_depth",
    "normals_from_depth",
    "kinect_rgbd_frame",
]

@dataclass(frozen=True)
class KinectMergeConfig:
    """Settings of the warp / merge / normals stage (paper 001 §4.2 gives no values; these are measured
    on the simulated Kinect in docs/design/kinect_merge.md)."""

    #: a triangle (warp) or a neighbour (normals) is dropped when a 3-D edge is longer than this many
    #: pixel footprints (footprint: s · min(z_a, z_b) / √|fx fy|, s = 1 side, √2 diagonal).
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
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or not 0 <= r <= 64:
            # The test reads a (2r + 1)² window per pixel: past 64 it costs seconds per frame.
            raise RangeError(f"KinectMergeConfig.occlusion_radius_px: expected an integer in [0, 64], got {r!r}")
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
# Kernel calls (the kernels: rgbd_envmap._kernels.kinect)
# --------------------------------------------------------------------------------------------------


def _window_min_into(nd: np.ndarray, nk: np.ndarray, r: int, tmp: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The smallest valid new depth within ``r`` pixels (Chebyshev) of each pixel, +inf where there
    is none: a (2r+1)² erosion (OpenCV's, far faster than a numba loop). Returns ``out`` (or ``tmp``
    when r = 0)."""
    kernels.valid_or_inf_into(nd, nk, tmp)
    if r == 0 or tmp.size == 0:
        return tmp
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    cv2.erode(tmp, kernel, dst=out, borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    return out


class _Workspace:
    """Image-sized scratch of the merger for one image size, kept between frames: allocated on every
    call it would cost page faults on every call."""

    def __init__(self, height: int, width: int) -> None:
        h, w = height, width
        # edge flags of the last merged map (written by the merge, read by the next warp)
        self.E = np.zeros((4, h, w), np.bool_)
        self.zw = np.empty((h, 2 * w), np.float32)  # z-buffer: (weight, z) pairs, see kernels.warp_kernel
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
    kernels.warp_kernel(depth, ws.E, weight, np.ascontiguousarray(rotation, np.float64),
                        np.ascontiguousarray(translation, np.float64), rays, use_table, rx, ry, rx32, ry32, cam,
                        dist, has_dist, float(near_m), ws.zw, ws.s_t, ws.s_z, ws.s_w)


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
    return rays, use_table, rx, ry, cam, dist, math.sqrt(abs(i.fx * i.fy)), use_table, rx32, ry32


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
    if name == "T_world_from_cam":  # a pose: named frames must lead into the world
        check_transform(T, name, "world")
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
    clean = kernels.clean_depth(depth, kn)
    ws = _Workspace(*shape)
    kernels.normals_edges(clean, rays, use_table, rx32, ry32, np.float32(k_side2), np.float32(k_diag2), ws.E)
    _warp_into(ws, clean, wts, T.rotation, T.translation, cam_args, float(near_m))
    return kernels.unpack_warp(ws.zw)


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
    return kernels.merge_arrays(wd, ww, wk, nd, nk, near_new, np.float32(max_weight), np.float32(threshold),
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
    return kernels.normals_edges(kernels.clean_depth(depth, kn), rays, use_table, rx32, ry32,
                                 np.float32(k_side2), np.float32(k_diag2), edges)


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
    return RGBDFrame(rgb, depth, kn, T, intr, check_number(timestamp_ns, "timestamp_ns", integer=True))


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
            ws.zw.view(np.uint64).fill(kernels.EMPTY_KEY)
        else:
            # T_cur_from_prev = inv(T_world_from_cur) @ T_world_from_prev, as rotation and translation
            Rc, tc = T.rotation, T.translation
            Rp, tp = self._T_world_from_prev.rotation, self._T_world_from_prev.translation
            _warp_into(ws, self._depth, self._weight, Rc.T @ Rp, Rc.T @ (tp - tc), self._cam, cfg.near_m)
        near_new = _window_min_into(depth, kn, cfg.occlusion_radius_px, ws.near_tmp, ws.near_new)
        rays, use_table = self._cam[:2]
        rx32, ry32 = self._cam[8:10]
        md, mw, mk, normals, nvalid, counts = kernels.merge_normals(
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
