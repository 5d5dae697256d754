"""Kernels of the map translation (:func:`rgbd_envmap.envmap.translation.translate`), called from that module only.

The depth-aware warp: each source row is reprojected (float32, vectorised) into a 3-row ring just
before it is splatted, so there are no full-map temporaries; the z-buffer is one int64 key per target
pixel, float32 distance bits above the source pixel's index, so ``min`` keeps the closest sample and,
on equal distances, the first in raster order, exactly what a sequential "closer wins" gives; a last
pass writes each output pixel once. Both the key updates and the last pass's colour gather prefetch
ahead: where the move shears or magnifies (the table under the origin), neighbouring output pixels
come from source rows far apart. On two threads, the busy rows are taken in 16 chunks of equal valid
pixels from a shared counter, each thread with its own key buffer, and the output pass takes the
minimum of both buffers. What the warp computes, pixel by pixel, is
:func:`rgbd_envmap.reference.envmap.translate_reference`; the tests compare the two exactly.

Gardner et al.'s backward warp is :func:`gardner_rows`: each target pixel's ray meets the sphere of
the given radius around the old origin, and the source pixel there gives its colour.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from rgbd_envmap._kernels.envmap_common import ATAN_POLY, _mn, _mx, atan2_branchless
from rgbd_envmap._kernels.intrinsics import (
    PRANGE_ONLY,
    bits_f32,
    compress16,
    f32_bits,
    fetch_add,
    min_run8,
    prefetch,
    store_nt,
)

__all__ = ["translate_kernel", "translate_kernel_2t", "gardner_rows", "reproject_row", "atan2_f32", "N_SPARE", "NO_KEY"]



#: float32 copies of :data:`ATAN_POLY` for :func:`atan2_f32`.
_ATAN_POLY_F32 = tuple(np.float32(c) for c in ATAN_POLY)
_F32_HALF_PI = np.float32(0.5 * math.pi)
_F32_PI = np.float32(math.pi)


@numba.njit(cache=True, fastmath=True, inline="always")
def atan2_f32(y, x):  # pragma: no cover - compiled
    """:func:`atan2_branchless` in float32 for float32 y, x (8 lanes per AVX2 instruction instead of
    4). Error ≤ 3e-7 rad (tests): 1e-4 of a 2000×1000 pixel."""
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = _ATAN_POLY_F32
    ax, ay = abs(x), abs(y)
    mx = _mx(ax, ay)
    t = _mn(ax, ay) / (mx if mx > np.float32(0.0) else np.float32(1.0))
    t2 = t * t
    p = p8
    p = p * t2 + p7
    p = p * t2 + p6
    p = p * t2 + p5
    p = p * t2 + p4
    p = p * t2 + p3
    p = p * t2 + p2
    p = p * t2 + p1
    p = p * t2 + p0
    a = t * p
    a = _F32_HALF_PI - a if ay > ax else a
    a = _F32_PI - a if x < np.float32(0.0) else a
    return -a if y < np.float32(0.0) else a


#: The output pass prefetches the source colours of the pixel this many pixels ahead: the winners of
#: neighbouring target pixels come from source rows far apart where the move magnifies or shears
#: (128 measured best of 32 to 256).
_GATHER_AHEAD = 128

#: The one-pixel key updates prefetch the target key of the source pixel this many columns ahead
#: (128 measured best of 16 to 256).
_SCATTER_AHEAD = 128

#: The 2×2 and magnified footprints prefetch the keys of the footprint this many list entries ahead.
_LIST_AHEAD = 8

#: The key of a target pixel no source pixel has landed on (see :func:`translate_kernel`).
NO_KEY = np.iinfo(np.int64).max


@numba.njit(cache=True, fastmath=True)
def reproject_row(depth, r, s, c, col_sin, col_cos, ox, oy, oz, kv, ku, pv, pu, pd):  # pragma: no cover - compiled
    """Where the pixels of row r land seen from the new origin ((ox, oy, oz): the old origin
    relative to the new one): continuous (v, u) and distance into pv, pu, pd. float32 and
    branch-free, so it vectorises 8 wide."""
    for k in range(depth.shape[1]):
        d = depth[r, k]
        x = ox + d * s * col_cos[k]
        y = oy + d * s * col_sin[k]
        z = oz + d * c
        h = math.sqrt(x * x + y * y)
        pd[k] = math.sqrt(h * h + z * z)
        pv[k] = atan2_f32(h, z) * kv
        pu[k] = (atan2_f32(y, x) + _F32_PI) * ku


@numba.njit(cache=True, fastmath=True, inline="always")
def _extent_at(c, left, right, depth, valid, r, up, down, pv, pu, sr, su, sd, max_rel_jump, fw, hv, hu):  # pragma: no cover - compiled
    """Half the (v, u) distance from where pixel (r, c) lands to where its depth-continuous
    4-neighbours land (≥ 0.5) into hv[c], hu[c]; a neighbour that is invalid or more than
    ``max_rel_jump`` away in relative depth does not count. The longitude difference wraps.
    Every value is loaded before it is selected, so that the loop over c vectorises."""
    d = depth[r, c]
    a, b = pv[sr, c], pu[sr, c]
    lim = max_rel_jump * d
    o1 = valid[up, c] & (abs(depth[up, c] - d) <= lim)
    o2 = valid[down, c] & (abs(depth[down, c] - d) <= lim)
    o3 = valid[r, left] & (abs(depth[r, left] - d) <= lim)
    o4 = valid[r, right] & (abs(depth[r, right] - d) <= lim)
    v1 = abs(pv[su, c] - a)
    v2 = abs(pv[sd, c] - a)
    v3 = abs(pv[sr, left] - a)
    v4 = abs(pv[sr, right] - a)
    e1 = abs(pu[su, c] - b)
    e2 = abs(pu[sd, c] - b)
    e3 = abs(pu[sr, left] - b)
    e4 = abs(pu[sr, right] - b)
    e1 = _mn(e1, fw - e1)
    e2 = _mn(e2, fw - e2)
    e3 = _mn(e3, fw - e3)
    e4 = _mn(e4, fw - e4)
    zero = np.float32(0.0)
    v1 = v1 if o1 else zero
    v2 = v2 if o2 else zero
    v3 = v3 if o3 else zero
    v4 = v4 if o4 else zero
    e1 = e1 if o1 else zero
    e2 = e2 if o2 else zero
    e3 = e3 if o3 else zero
    e4 = e4 if o4 else zero
    half = np.float32(0.5)
    hv[c] = _mx(half * _mx(_mx(v1, v2), _mx(v3, v4)), half)
    hu[c] = _mx(half * _mx(_mx(e1, e2), _mx(e3, e4)), half)


@numba.njit(cache=True, fastmath=True)
def _extents_row(depth, valid, r, up, down, pv, pu, sr, su, sd, max_rel_jump, hv, hu):  # pragma: no cover - compiled
    """:func:`_extent_at` for row r; the seam columns apart, so that the loop over the others has
    plain c ± 1 neighbours and vectorises."""
    width = depth.shape[1]
    fw = np.float32(width)
    for c in (0, width - 1):
        left = c - 1 if c > 0 else width - 1
        right = c + 1 if c + 1 < width else 0
        _extent_at(c, left, right, depth, valid, r, up, down, pv, pu, sr, su, sd, max_rel_jump, fw, hv, hu)
    zero, half = np.float32(0.0), np.float32(0.5)
    # _extent_at written out: inlined, it increfs its array arguments per pixel and nothing vectorises.
    for c in range(1, width - 1):
        d = depth[r, c]
        va, ua = pv[sr, c], pu[sr, c]
        lim = max_rel_jump * d
        o1 = valid[up, c] & (abs(depth[up, c] - d) <= lim)
        o2 = valid[down, c] & (abs(depth[down, c] - d) <= lim)
        o3 = valid[r, c - 1] & (abs(depth[r, c - 1] - d) <= lim)
        o4 = valid[r, c + 1] & (abs(depth[r, c + 1] - d) <= lim)
        v1 = abs(pv[su, c] - va)
        v2 = abs(pv[sd, c] - va)
        v3 = abs(pv[sr, c - 1] - va)
        v4 = abs(pv[sr, c + 1] - va)
        e1 = abs(pu[su, c] - ua)
        e2 = abs(pu[sd, c] - ua)
        e3 = abs(pu[sr, c - 1] - ua)
        e4 = abs(pu[sr, c + 1] - ua)
        e1 = _mn(e1, fw - e1)
        e2 = _mn(e2, fw - e2)
        e3 = _mn(e3, fw - e3)
        e4 = _mn(e4, fw - e4)
        v1 = v1 if o1 else zero
        v2 = v2 if o2 else zero
        v3 = v3 if o3 else zero
        v4 = v4 if o4 else zero
        e1 = e1 if o1 else zero
        e2 = e2 if o2 else zero
        e3 = e3 if o3 else zero
        e4 = e4 if o4 else zero
        hv[c] = _mx(half * _mx(_mx(v1, v2), _mx(v3, v4)), half)
        hu[c] = _mx(half * _mx(_mx(e1, e2), _mx(e3, e4)), half)


@numba.njit(cache=True, inline="always")
def _span32(x, half, limit):  # pragma: no cover - compiled
    """Pixels k whose centre k + 0.5 lies within ``half`` (≥ 0.5, at most ``limit``) of continuous
    coordinate x, all float32: ``_span`` of the update kernels in the precision of the landing
    positions, as :func:`_splat_targets` computes it 16 lanes at a time."""
    h = _mn(_mx(half, np.float32(0.5)), limit)
    return int(np.ceil(x - h - np.float32(0.5))), int(np.floor(x + h - np.float32(0.5)))


#: Keys past the map's end in the key buffer: the one-pixel loop updates one of them (by column) for
#: every pixel that is not a one-pixel footprint, a store nobody reads instead of a branch.
N_SPARE = 8

@numba.njit(cache=True, error_model="numpy")
def _splat_targets(valid, r, pv, pu, pd, sr, hv, hu, height, width, max_splat, min_col_limit, ta, tb, tc, td, t1, keys, is2,
                   isl):  # pragma: no cover - compiled
    """For each pixel of row r, the flat target indices of its footprint when it covers at most 2×2
    pixels (ta..td, int32, repeats allowed: the one pixel (v, u) falls in when both extents are
    0.5); is2 / isl flag a valid footprint of 2 to 4 pixels / a larger one (left to the caller,
    which finds its first target in ta and its column count (0: recompute with the landing row's
    column limit), first row and last row in tb, tc, td).
    No branches, so the row vectorises: the spans are :func:`_span32`'s (float32, 16 lanes), the
    indices int32. The column limit of the landing row (a table lookup, which kept the loop scalar)
    is replaced by its minimum over rows: a footprint it would clip goes to the caller as large, and
    for the others the two limits agree.

    For the caller's scalar loops, also per pixel: t1, the target of a one-pixel footprint or else a
    spare key's index (n + c % :data:`N_SPARE`); keys, the pixel's z-buffer key (distance bits,
    source index): here, vectorised, they cost well under half of what the scalar loop took."""
    fw, fh = np.float32(width), np.float32(height)
    half, one = np.float32(0.5), np.float32(1.0)
    lim_v = np.float32(max_splat)
    n = height * width
    base = r * width
    for c in range(width):
        nd = pd[sr, c]
        v, u = pv[sr, c], pu[sr, c]
        h_v, h_u = hv[c], hu[c]
        row = _mn(np.floor(v), fh - one)  # v, u ≥ 0: floor is int()'s truncation
        col = np.floor(u)
        col = col - fw if col >= fw else col
        h = _mn(_mx(h_v, half), lim_v)
        r0, r1 = np.ceil(v - h - half), np.floor(v + h - half)
        h = _mn(_mx(h_u, half), min_col_limit)
        c0, c1 = np.ceil(u - h - half), np.floor(u + h - half)
        single = (h_v == half) & (h_u == half)
        large = ((r1 - r0 > one) | (c1 - c0 > one) | (_mx(h_u, half) > min_col_limit)) & ~single
        c0w = c0 + fw if c0 < 0.0 else (c0 - fw if c0 >= fw else c0)
        c1w = c0w + (c1 - c0)
        c1w = c1w - fw if c1w >= fw else c1w
        ra = np.int32(row if single else _mx(r0, np.float32(0.0)))
        rb = np.int32(row if single else _mn(r1, fh - one))
        ca = np.int32(col if single else c0w)
        cb = np.int32(col if single else c1w)
        ok = valid[r, c] & (nd > 0.0) & (nd < np.inf)
        t_a, t_d = ra * width + ca, rb * width + cb
        # A larger footprint keeps ta and, in tb..td, its column count (0 where the column limit of
        # its landing row may differ from the minimum used here), first and last row: its loop
        # then needs no spans of its own. New arrays for them would cost more than they save: past
        # eight arrays, LLVM stops vectorising this loop.
        n_c = np.int32(_mn(c1 - c0 + one, fw) if _mx(h_u, half) <= min_col_limit else np.float32(0.0))
        ta[c] = t_a
        tb[c] = n_c if large else ra * width + cb
        tc[c] = ra if large else rb * width + ca
        td[c] = rb if large else t_d
        t1[c] = t_a if (ok & ~large & (t_a == t_d)) else np.int32(n + (c & (N_SPARE - 1)))
        keys[c] = (np.int64(f32_bits(nd)) << 32) | (base + c)
        is2[c] = ok & ~large & (t_a != t_d)
        isl[c] = ok & large


@numba.njit(cache=True)
def _busy_rows(valid):  # pragma: no cover - compiled
    """Per row, how many pixels are valid (rows with none are not reprojected: most of a map still
    being captured)."""
    height, width = valid.shape
    busy = np.zeros(height, np.int64)
    for t in range(height):
        k = 0
        for c in range(width):
            k += valid[t, c]
        busy[t] = k
    return busy


@numba.njit(cache=True)
def _warp_rows(lo, hi, busy, depth, valid, row_sin, row_cos, col_sin, col_cos, ox, oy, oz, max_rel_jump, max_splat,
               col_limit, key_flat, pv, pu, pd, ext_v, ext_u, ta, tb, tc, td, t1, l2, ll, keys, is2, isl):  # pragma: no cover - compiled
    """The key updates of source rows ``lo`` to ``hi`` − 1 into ``key_flat`` (see
    :func:`translate_kernel`); returns the lowest and highest flat target index reached (n, −1
    for none). Row t + 1 is reprojected into a 3-row ring before row t is splatted (row lo − 1 too),
    so the (v, u) of a pixel's 4-neighbours are at hand without full-map planes."""
    height, width = depth.shape
    n = height * width
    min_col_limit = col_limit.min()
    kv = np.float32(height / math.pi)
    ku = np.float32(width / (2.0 * math.pi))
    p_lo, p_hi = n, -1  # the flat target indices reached
    for t in range(_mx(lo - 1, 0), _mn(hi + 1, height + 1)):
        if t < height and busy[t] > 0:
            # Whole rows: skipping runs of empty 64-column chunks instead (bounds read from memory)
            # made these loops 2-8× slower although they stayed vectorised.
            slot = t % 3
            reproject_row(depth, t, row_sin[t], row_cos[t], col_sin, col_cos, ox, oy, oz, kv, ku,
                           pv[slot], pu[slot], pd[slot])
        r = t - 1
        if r < lo or busy[r] == 0:
            continue
        up = r - 1 if r > 0 else r
        down = r + 1 if r + 1 < height else r
        sr, su, sd = r % 3, up % 3, down % 3
        _extents_row(depth, valid, r, up, down, pv, pu, sr, su, sd, max_rel_jump, ext_v, ext_u)
        _splat_targets(valid, r, pv, pu, pd, sr, ext_v, ext_u, height, width, max_splat, min_col_limit, ta, tb, tc, td,
                       t1, keys, is2, isl)
        for c in range(width):  # vectorised
            p = t1[c]
            p_lo = _mn(p_lo, p)  # a spare key's index is ≥ n
            p_hi = _mx(p_hi, p if p < n else -1)
        # One-pixel footprints (83 % of a full map's pixels), branch-free: every other pixel updates
        # a spare key past the map's end instead; the rest are listed for the two loops below, so
        # that no branch depends on the mix of footprint kinds (mispredicted wherever they mix).
        # Everything else per pixel was computed in the vectorised loops above.
        for c in range(width):
            prefetch(key_flat, t1[_mn(c + _SCATTER_AHEAD, width - 1)])
            p = t1[c]
            key_flat[p] = _mn(key_flat[p], keys[c])
        # The other footprints' columns listed 16 at a time (a compress-store each; appending in
        # the loop above cost a store and an add per pixel).
        n2 = nl = 0
        for c0 in range(0, width, 16):
            n2 = compress16(is2, c0, l2, n2)
            nl = compress16(isl, c0, ll, nl)
        # At most 2×2 pixels: four updates (repeats are harmless).
        for i in range(n2):
            c = l2[i]
            c_pf = l2[_mn(i + _LIST_AHEAD, n2 - 1)]
            prefetch(key_flat, ta[c_pf])
            prefetch(key_flat, td[c_pf])
            kk = keys[c]
            p, q = ta[c], tb[c]
            key_flat[p] = _mn(key_flat[p], kk)
            key_flat[q] = _mn(key_flat[q], kk)
            p_lo = _mn(p_lo, _mn(p, q))
            p, q = tc[c], td[c]
            key_flat[p] = _mn(key_flat[p], kk)
            key_flat[q] = _mn(key_flat[q], kk)
            p_hi = _mx(p_hi, _mx(p, q))
        # Magnified footprints: row runs of at most two contiguous segments (the seam); a run longer
        # than the row covers it once. Runs are updated 8 keys at a time (:func:`min_run8`).
        for i in range(nl):
            c = ll[i]
            c_pf = ll[_mn(i + _LIST_AHEAD, nl - 1)]
            prefetch(key_flat, ta[c_pf])  # near the footprint's first and last row
            prefetch(key_flat, ta[c_pf] + (td[c_pf] - tc[c_pf]) * width)
            kk = keys[c]
            rr0, rr1, n_c = np.int64(tc[c]), np.int64(td[c]), np.int64(tb[c])
            a0 = np.int64(ta[c]) - rr0 * width
            if n_c == 0:  # wider than the narrowest column limit: the landing row's limit decides
                v, u = pv[sr, c], pu[sr, c]
                r0, r1 = _span32(v, ext_v[c], np.float32(max_splat))
                c0, c1 = _span32(u, ext_u[c], col_limit[_mn(int(v), height - 1)])
                n_c = _mn(c1 - c0 + 1, width)
                a0 = c0 + width if c0 < 0 else c0  # c0 % width: c0 is within [-width / 2 - 1, width]
                a0 = a0 - width if a0 >= width else a0
                if a0 < 0 or a0 >= width:
                    a0 = c0 % width
                rr0, rr1 = _mx(r0, 0), _mn(r1, height - 1)
            m = _mn(a0 + n_c, width) - a0
            b1 = a0 + n_c - width
            p_lo = _mn(p_lo, rr0 * width)
            p_hi = _mx(p_hi, rr1 * width + width - 1)
            for rr in range(rr0, rr1 + 1):
                q = rr * width + a0
                for j0 in range(0, m, 8):
                    min_run8(key_flat, q + j0, m - j0, kk)
                for cc in range(rr * width, rr * width + b1):
                    key_flat[cc] = _mn(key_flat[cc], kk)
    return p_lo, p_hi


@numba.njit(cache=True)
def _gather(p0, p1, key_a, key_b, two, planes, out_planes, out_depth, out_valid, p_lo, p_hi):  # pragma: no cover - compiled
    """The output pass over flat pixels ``p0`` to ``p1`` − 1: every output pixel written once, in
    order, from its key (the minimum of ``key_a`` and, with ``two``, ``key_b``), the keys reset on the
    way (a key holds the flat source index). Outside [p_lo, p_hi], the span of target pixels
    reached, the keys are not read."""
    n = out_depth.size
    src_flat = planes.reshape(3, n)
    dst0, dst1, dst2 = out_planes[0].reshape(n), out_planes[1].reshape(n), out_planes[2].reshape(n)
    depth_flat = out_depth.reshape(n)
    valid_flat = out_valid.reshape(n)
    zero = np.float32(0.0)
    for p in range(p0, p1):
        if p + _GATHER_AHEAD <= p_hi:
            k_ahead = _mn(key_a[p + _GATHER_AHEAD], key_b[p + _GATHER_AHEAD]) if two else key_a[p + _GATHER_AHEAD]
            s_ahead = k_ahead & 0xFFFFFFFF if k_ahead != NO_KEY else 0
            prefetch(src_flat[0], s_ahead)
            prefetch(src_flat[1], s_ahead)
            prefetch(src_flat[2], s_ahead)
        inside = p_lo <= p <= p_hi
        kk = key_a[p] if inside else NO_KEY
        if two and inside:
            kb = key_b[p]
            if kb != NO_KEY:
                key_b[p] = NO_KEY
                kk = _mn(kk, kb)
        if kk == NO_KEY:
            store_nt(depth_flat, p, zero)
            valid_flat[p] = False
            store_nt(dst0, p, zero)
            store_nt(dst1, p, zero)
            store_nt(dst2, p, zero)
        else:
            key_a[p] = NO_KEY
            s = kk & 0xFFFFFFFF
            store_nt(depth_flat, p, bits_f32(np.int32(kk >> 32)))
            valid_flat[p] = True
            store_nt(dst0, p, src_flat[0, s])
            store_nt(dst1, p, src_flat[1, s])
            store_nt(dst2, p, src_flat[2, s])


@numba.njit(cache=True)
def translate_kernel(depth, valid, planes, row_sin, row_cos, col_sin, col_cos, ox, oy, oz, max_rel_jump, max_splat,
                      col_limit, out_planes, out_depth, out_valid, key, pv, pu, pd, ext_v, ext_u, ta, tb, tc, td, t1, l2, ll,
                      keys, is2, isl):  # pragma: no cover - compiled
    """Forward warp of every valid pixel (see :func:`translate`), streaming over source rows
    (:func:`_warp_rows`), then the output pass (:func:`_gather`).

    The z-buffer is one int64 key per target pixel, float32 distance bits above the source pixel's
    index, so ``min`` keeps the closest sample and, on equal distances, the first in raster order:
    what a sequential "closer wins" gives, but branch-free and independent of the visiting order
    (so one-pixel, 2×2 and magnified footprints are updated by separate loops, and two threads may
    update key buffers of their own). The output pass writes every output pixel once from its key
    and resets the keys. ``key``: (H·W + :data:`N_SPARE`,) int64, the first H·W :data:`NO_KEY`
    between calls. Key updates prefetch the target of the pixel :data:`_SCATTER_AHEAD` columns (or
    :data:`_LIST_AHEAD` list entries) on, the output pass the source colours of the pixel
    :data:`_GATHER_AHEAD` on (prefetches never fault and change no result)."""
    height, width = depth.shape
    busy = _busy_rows(valid)
    p_lo, p_hi = _warp_rows(0, height, busy, depth, valid, row_sin, row_cos, col_sin, col_cos, ox, oy, oz, max_rel_jump,
                            max_splat, col_limit, key, pv, pu, pd, ext_v, ext_u, ta, tb, tc, td, t1, l2, ll, keys, is2, isl)
    _gather(0, height * width, key, key, False, planes, out_planes, out_depth, out_valid, p_lo, p_hi)


#: The two-thread translation hands out the source rows in this many chunks (see
#: :func:`translate_kernel_2t`).
_CHUNKS = 16


@numba.njit(cache=True, parallel=PRANGE_ONLY)
def translate_kernel_2t(depth, valid, planes, row_sin, row_cos, col_sin, col_cos, ox, oy, oz, max_rel_jump, max_splat,
                         col_limit, out_planes, out_depth, out_valid, bufs_a, bufs_b):  # pragma: no cover - compiled
    """:func:`translate_kernel` on two threads, with the same result bit for bit. The busy source
    rows are cut into :data:`_CHUNKS` chunks of about equal valid pixels, which the two threads take
    in turn from a shared counter (:func:`fetch_add`), each updating a key buffer of its own
    (``bufs_a`` / ``bufs_b``: the translation's buffers of each part): a static split at half the
    pixels leaves the threads unbalanced on a captured map, whose magnified footprints (the table
    under the origin) sit in the lower rows. Each chunk reprojects
    its first row's upper neighbour again. Then the output pass split at half the map's rows, each
    half taking the minimum of both buffers' keys (the key carries the source index, so that is the
    one-thread result) and resetting both."""
    height, width = depth.shape
    busy = _busy_rows(valid)
    total = busy.sum()
    bounds = np.zeros(_CHUNKS + 1, np.int64)  # chunk k: rows bounds[k] .. bounds[k + 1] - 1
    done, k = 0, 1
    for t in range(height):
        done += busy[t]
        if k < _CHUNKS and done * _CHUNKS >= k * total:
            bounds[k] = t + 1
            k += 1
    for j in range(k, _CHUNKS + 1):
        bounds[j] = height
    counter = np.zeros(1, np.int64)
    reach = np.zeros((2, 2), np.int64)
    for t in numba.prange(2):
        b = bufs_a if t == 0 else bufs_b
        lo_t, hi_t = height * width, -1
        c = fetch_add(counter, 0, 1)
        while c < _CHUNKS:
            if bounds[c + 1] > bounds[c]:
                a, z = _warp_rows(bounds[c], bounds[c + 1], busy, depth, valid, row_sin, row_cos, col_sin, col_cos, ox, oy,
                                  oz, max_rel_jump, max_splat, col_limit, b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
                                  b[8], b[9], b[10], b[11], b[12], b[13], b[14], b[15])
                lo_t, hi_t = _mn(lo_t, a), _mx(hi_t, z)
            c = fetch_add(counter, 0, 1)
        reach[t, 0], reach[t, 1] = lo_t, hi_t
    p_lo, p_hi = _mn(reach[0, 0], reach[1, 0]), _mx(reach[0, 1], reach[1, 1])
    mid = (height >> 1) * width
    n = height * width
    for t in numba.prange(2):
        _gather(0 if t == 0 else mid, mid if t == 0 else n, bufs_a[0], bufs_b[0], True, planes, out_planes, out_depth,
                out_valid, p_lo, p_hi)


@numba.njit(cache=True, fastmath=True)
def gardner_rows(row_sin, row_cos, col_sin, col_cos, ox, oy, oz, radius, planes, valid, out_planes, out_depth, out_valid,
                  rows_buf, cols_buf):  # pragma: no cover - compiled
    """Gardner et al.'s warp, backwards: each output pixel's ray from the new origin (the old one
    plus (ox, oy, oz)) meets the sphere of ``radius`` around the old origin at t = −(o·d) +
    sqrt((o·d)² − |o|² + R²); the output takes the source pixel containing o + t·d (the pixel
    index of :func:`rgbd_envmap.geometry.equirect_pixel_index`, with :func:`atan2_branchless` for
    atan2, so that the per-row loop vectorises) and t as its distance where that pixel is valid.
    The pixel-centre directions come from float64 sin / cos of the rows and columns (contiguous, so
    the loop vectorises; strided (H, W, 3) reads keep it scalar, about twice as slow);
    ``rows_buf`` / ``cols_buf``: (W,) int64."""
    height, width = valid.shape
    oo = ox * ox + oy * oy + oz * oz
    rr = radius * radius
    kv = height / math.pi
    ku = width / (2.0 * math.pi)
    zero = np.float32(0.0)
    for r in range(height):
        st, dz = row_sin[r], row_cos[r]
        for c in range(width):  # vectorised: the source pixel of each output pixel
            dx, dy = st * col_cos[c], st * col_sin[c]
            b = dx * ox + dy * oy + dz * oz
            t = -b + math.sqrt(b * b - oo + rr)
            sx, sy, sz = ox + t * dx, oy + t * dy, oz + t * dz
            theta = atan2_branchless(math.sqrt(sx * sx + sy * sy), sz)
            u = (atan2_branchless(sy, sx) + math.pi) * ku  # in [0, W]
            v = theta * kv
            col = np.floor(u)  # floor(u - 0.5 + 0.5): pixel centres at k + 0.5
            col = col - width if col >= width else col
            row = _mn(_mx(np.floor(v), 0.0), height - 1.0)
            rows_buf[c] = np.int64(row)
            cols_buf[c] = np.int64(col)
            out_depth[r, c] = np.float32(t)
        for c in range(width):  # the gathers
            sr, sc = rows_buf[c], cols_buf[c]
            ok = valid[sr, sc]
            out_valid[r, c] = ok
            out_planes[0, r, c] = planes[0, sr, sc] if ok else zero
            out_planes[1, r, c] = planes[1, sr, sc] if ok else zero
            out_planes[2, r, c] = planes[2, sr, sc] if ok else zero
            out_depth[r, c] = out_depth[r, c] if ok else zero

