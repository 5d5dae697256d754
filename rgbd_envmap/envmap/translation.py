"""Translation of the environment map (paper 003 §6.2): a new map seen from a displaced origin.

``method="depth"`` reprojects every valid pixel with its depth. Each pixel covers the target pixels
within half the distance to where its 4-neighbours land, so magnified regions (moving towards a
surface, oblique floors and ceilings) stay closed; neighbours across a depth jump are ignored, so
the disoccluded region behind an edge stays empty instead of being smeared. ``method="gardner"``
(Gardner et al. 2017) assumes every pixel lies on a sphere of fixed radius around the old origin and
warps backwards (no holes, wrong parallax). The pixel-by-pixel spec of the depth warp is
:func:`rgbd_envmap.reference.envmap.translate_reference`.

References:
    Monroy, Hudon, Smolic (2018), §6.2.
    Gardner et al. (2017), Learning to Predict Indoor Illumination from a Single Image, §4 (warping).
"""

from __future__ import annotations

import math
import threading
from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import translate as kernels
from rgbd_envmap._kernels.parallel import parallel_call, usable_threads
from rgbd_envmap.checks import check_array, check_method, check_number, check_positive_int
from rgbd_envmap.envmap.map import EnvironmentMap, check_map
from rgbd_envmap.envmap.map_update import MAX_SPLAT_PX
from rgbd_envmap.envmap.tables import col_limits, trig_columns
from rgbd_envmap.errors import InvalidInputError

__all__ = ["translate", "reprojected_coordinates", "TRANSLATE_METHODS"]

TRANSLATE_METHODS = ("depth", "gardner")


@lru_cache(maxsize=8)
def _trig64(height: int, width: int) -> tuple[np.ndarray, ...]:
    """float64 sin θ, cos θ of the row centres and sin φ, cos φ of the column centres (the pixel
    directions of :func:`rgbd_envmap.geometry.equirect_directions` before its float32 cast)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    return np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)


_warp_buffers = threading.local()


def _translate_buffers(height: int, width: int, part: int = 0) -> tuple[np.ndarray, ...]:
    """Scratch of :func:`translate` for one map size, per calling thread and ``part`` (0, or 1 for
    the second kernel thread of the two-thread kernel), kept between calls (a map is
    typically viewed from a moving origin many times; fresh 16 MB buffers cost page faults): the
    (H·W + :data:`kernels.N_SPARE`,) int64 key buffer (all ``NO_KEY`` between calls but the spare
    keys), three (3, W) rings of reprojected rows, the (W,) v and u extents of one row, the per-row
    outputs of :func:`_splat_targets` (ta..td, t1 int32; keys int64; is2, isl uint8) and
    the two (W,) int32 column lists of :func:`_warp_rows`."""
    cache = getattr(_warp_buffers, "by_shape", None)
    if cache is None:
        cache = _warp_buffers.by_shape = {}
    if (height, width, part) not in cache:
        for k in [k for k in cache if k[:2] != (height, width)]:
            del cache[k]  # one size at a time
        n = height * width
        if n + kernels.N_SPARE > np.iinfo(np.int32).max:  # t1 is int32
            raise InvalidInputError(f"translate: at most 2**31 - {kernels.N_SPARE + 1} pixels, got {height}×{width}")
        cache[(height, width, part)] = (np.full(n + kernels.N_SPARE, kernels.NO_KEY, np.int64),
                                  *(np.zeros((3, width), np.float32) for _ in range(3)),
                                  np.zeros(width, np.float32), np.zeros(width, np.float32),
                                  *(np.zeros(width, np.int32) for _ in range(4)),
                                  np.zeros(width, np.int32),  # t1
                                  np.zeros(width + 16, np.int32), np.zeros(width + 16, np.int32),  # l2, ll
                                  # is2, isl: 16 zero flags past the row for the last compress-store
                                  np.zeros(width, np.int64), np.zeros(width + 16, np.uint8), np.zeros(width + 16, np.uint8))
    return cache[(height, width, part)]


def _check_out(em: EnvironmentMap, out: EnvironmentMap) -> None:
    """``out`` must be another map of ``em``'s size whose arrays share no memory with ``em``'s (the
    kernel reads ``em`` while it writes ``out``)."""
    check_map(out, "out", writable=True)
    if (out.height, out.width) != (em.height, em.width):
        raise InvalidInputError(f"out: expected a {em.height}×{em.width} map, got {out.height}×{out.width}")
    mine = (em.radiance_planes, em.depth_m, em.valid)
    if out is em or any(np.may_share_memory(a, b) for a in (out.radiance_planes, out.depth_m, out.valid) for b in mine):
        raise InvalidInputError("out: must not be the map being translated nor share its arrays")


def translate(em: EnvironmentMap, offset: np.ndarray, method: str = "depth", *, radius_m: float = 2.0,
              max_splat_px: int = 8, max_rel_jump: float = 0.2, out: EnvironmentMap | None = None,
              threads: int = 2) -> EnvironmentMap:
    """A new map at ``em.origin + offset``; ``em`` is left intact (use the result in place of ``em``
    for a permanent move, or keep both for a temporary view). Paper §6.2.

    ``method="depth"`` (paper §6.2) reprojects every valid pixel with its depth; ``"gardner"``
    assumes all pixels lie on a sphere of ``radius_m`` around the old origin and samples backwards.
    ``max_rel_jump``: neighbours whose depth differs by more than this fraction are across an edge
    and do not widen a pixel's footprint. 0.2, not a tighter 0.05: surfaces seen at grazing angles
    (the table top from 5 cm above it) change depth by more than 5 % per pixel, and a tight
    threshold let holes open there on every step.

    ``out``: another map of the same size to overwrite and return instead of a new one (every
    array is rewritten, its origin set, its change log if any marked incomplete), for a caller that
    translates every frame and can reuse last frame's result (a fresh 34 MB output costs page
    faults).

    ``threads``: 1, or 2 (the default; more are used as 2, and 2 as 1 where numba has one thread)
    for the depth warp on two threads, with the same result bit for bit.

    The depth warp computes landing positions in float32 (within 1e-4 pixel) and keeps per-thread
    scratch for the last map size between calls (an (H·W + 8,) int64 key buffer, 16 MB at
    2000×1000; two of them on two threads).
    """
    check_map(em)
    check_method(method, TRANSLATE_METHODS)
    check_positive_int(threads, "threads")
    check_number(max_splat_px, "max_splat_px", low=1, high=MAX_SPLAT_PX, integer=True)
    check_number(max_rel_jump, "max_rel_jump", low=0.0)
    check_number(radius_m, "radius_m")
    off = check_array(offset, "offset", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    new_origin = em.origin + off
    if out is not None:
        _check_out(em, out)
    if method == "gardner":
        if not radius_m > 0:
            raise InvalidInputError(f"radius_m: expected a positive radius, got {radius_m}")
        if np.linalg.norm(off) >= radius_m:
            raise InvalidInputError(f"gardner: the new origin must lie inside the sphere (|offset| {np.linalg.norm(off):.3f} ≥ radius {radius_m})")
    if out is None:  # the depth kernel writes every pixel: its output is not zeroed first
        make = EnvironmentMap.uninitialised if method == "depth" else EnvironmentMap
        out = make(em.height, em.width, new_origin)
    else:
        out.origin = new_origin
        out.mark_modified()  # its change log, if any, cannot list a whole new map
    if method == "depth":
        h, w = em.height, em.width
        o = (em.origin - new_origin).astype(np.float32)
        col_limit = col_limits(h, w, int(max_splat_px)).astype(np.float32)
        # Contiguous sin / cos columns: strided reads from the (W, 2) tables kept the loop scalar.
        args = (em.depth_m, em.valid, em.radiance_planes, *trig_columns(h, w), o[0], o[1], o[2], np.float32(max_rel_jump),
                int(max_splat_px), col_limit, out.radiance_planes, out.depth_m, out.valid)
        if usable_threads(threads) >= 2:
            parallel_call(kernels.translate_kernel_2t, *args, _translate_buffers(h, w, 0), _translate_buffers(h, w, 1))
        else:
            kernels.translate_kernel(*args, *_translate_buffers(h, w))
        return out
    # Backward warp: a compiled row loop; its polynomial atan2 (within 1.2e-8 rad) may put a ray right at a
    # pixel edge into the pixel next door.
    kernels.gardner_rows(*_trig64(em.height, em.width), float(off[0]), float(off[1]), float(off[2]), float(radius_m),
                  em.radiance_planes, em.valid, out.radiance_planes, out.depth_m, out.valid,
                  np.empty(em.width, np.int64), np.empty(em.width, np.int64))
    return out


def reprojected_coordinates(em: EnvironmentMap, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where every pixel of ``em`` lands seen from ``em.origin + offset``, exactly as the depth warp
    of :func:`translate` computes it: (H, W) float32 continuous row ``v``, column ``u`` and distance
    (from the pixel's direction and ``depth_m``, valid or not; the warp uses valid pixels only)."""
    check_map(em)
    off = check_array(offset, "offset", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    h, w = em.height, em.width
    rs, rc, cs, cc = trig_columns(h, w)
    o = (-off).astype(np.float32)
    pv, pu, pd = (np.zeros((h, w), np.float32) for _ in range(3))
    kv, ku = np.float32(h / math.pi), np.float32(w / (2 * math.pi))
    for r in range(h):
        kernels.reproject_row(em.depth_m, r, rs[r], rc[r], cs, cc, o[0], o[1], o[2], kv, ku, pv[r], pu[r], pd[r])
    return pv, pu, pd
