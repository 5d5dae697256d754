"""Kernels of the map update (:func:`rgbd_envmap.envmap.map_update.update`), called from that module only.

The rules themselves are the scalar functions of :mod:`rgbd_envmap.envmap.rules`; what the update
computes, pixel by pixel, is written plainly in :func:`rgbd_envmap.reference.envmap.update_reference`
(the tests compare the two bit for bit).

How it is fast: map coordinates and footprints are computed 256 samples at a time in vectorised
loops, and each footprint is recorded with an int64 z-buffer key (float32 distance bits, then an
order code, then the fill-only flag) whose ``min`` over the samples covering a pixel is the sample a
sequential "closer wins" test in sample order keeps, so footprints can be merged in any order. They
are listed per band of 16 map rows; band by band they are merged into a one-band z-buffer that stays
in cache (a footprint of at most 2×2 pixels is four branch-free tests, one of at most 4 or 8 columns
four or eight per row) and the band's rows go through the rules at once, over the runs of 32-column
tiles they touched. The rules are branch-free selects except in the few rows where the removal rule
can hold (the device within the removal radius of the pixel's ray: a cone around the device's
direction); a row's carving candidates are projected into the frame together (a vectorised loop);
taken pixels are written in raster order, so the change log is too.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from rgbd_envmap._kernels.envmap_common import _BLOCK, block_coords, _mn, _mx, _u
from rgbd_envmap._kernels.intrinsics import PRANGE_ONLY, bits_f32, f32_bits, min_run8
from rgbd_envmap.envmap.rules import freed_limit, rule_closer, rule_empty, rule_freed, rule_removal, rule_trusted
from rgbd_envmap.geometry import brown_distort

__all__ = ["update_kernel", "measured_depth", "block_coords", "BAND_SHIFT", "TILE_SHIFT", "EMPTY_Z",
           "INDEX_MAX"]

@numba.njit(cache=True, inline="always")
def _span(x, half, limit):  # pragma: no cover - compiled
    """Pixels k whose centre k + 0.5 lies within ``half`` (≥ 0.5) of continuous coordinate x."""
    h = _mn(_mx(half, 0.5), limit)
    return int(math.ceil(x - h - 0.5)), int(math.floor(x + h - 0.5))




#: An :func:`update` z-buffer entry no sample has reached: +inf's float32 bits, no index.
EMPTY_Z = 0x7F800000 << 32
#: r0 of a sample :func:`_block_footprints` found unusable (a real r0 is ≥ −max_splat − 1).
_UNUSABLE = -float(1 << 62)


@numba.njit(cache=True, error_model="numpy")
def _block_footprints(m, qx, qy, qz, device, bx, by, bv, bu, br, height, width, row_px, col_px,
                      focal_px, splat, splat_scale, max_splat, r0, r1, c0, c1):  # pragma: no cover - compiled
    """Per sample of the block (world coordinates qx, qy, qz; the rest :func:`block_coords`
    outputs), the rows r0..r1 and (unwrapped) columns c0..c1 its footprint covers (the pixel it
    falls in without ``splat``), as whole float64 numbers; r0 = :data:`_UNUSABLE` for a non-finite
    point or a distance outside (0, float32 max). One loop without branches or float → int
    conversions (AVX2 has none for int64), so it vectorises. Every sample is divided by its
    distance, so divisions follow IEEE (``error_model="numpy"``: a sample at the origin gives inf
    and is then dropped) instead of raising. Not fastmath, so the spans are exactly the per-sample
    formulas' (:func:`_span`: ceil and floor of the same float64 expressions)."""
    fw, fh = np.float64(width), np.float64(height)
    lim_v, half_w = np.float64(max_splat), np.float64(width // 2)
    d0, d1, d2 = device[0], device[1], device[2]
    if not splat:
        for j in range(m):
            px, py, pz, r = qx[j], qy[j], qz[j], br[j]
            usable = (abs(px) < np.inf) & (abs(py) < np.inf) & (abs(pz) < np.inf) & (r > 0.0) & (np.float32(r) < np.inf)
            row = _mn(np.floor(bv[j]), fh - 1.0)  # v, u ≥ 0: floor is int()'s truncation
            col = np.floor(bu[j])
            col = col - fw if col >= fw else col
            r0[j] = row if usable else _UNUSABLE
            r1[j], c0[j], c1[j] = row, col, col
        return
    for j in range(m):
        px, py, pz, r = qx[j], qy[j], qz[j], br[j]
        # abs(x) < inf: finite, as a compare.
        usable = (abs(px) < np.inf) & (abs(py) < np.inf) & (abs(pz) < np.inf) & (r > 0.0) & (np.float32(r) < np.inf)
        v, u = bv[j], bu[j]
        ex, ey, ez = px - d0, py - d1, pz - d2
        angle = splat_scale * math.sqrt(ex * ex + ey * ey + ez * ez) / (focal_px * r)
        dx, dy = bx[j], by[j]
        s = _mx(math.sqrt(dx * dx + dy * dy) / r, 1e-6)  # sin θ, without a libm call
        h = _mn(_mx(0.5 * angle * row_px, 0.5), lim_v)
        a0, a1 = np.ceil(v - h - 0.5), np.floor(v + h - 0.5)
        h = _mn(_mx(0.5 * angle * col_px / s, 0.5), _mn(lim_v / s, half_w))
        r0[j] = a0 if usable else _UNUSABLE
        r1[j], c0[j], c1[j] = a1, np.ceil(u - h - 0.5), np.floor(u + h - 0.5)


#: The update's z-buffer covers one band of 2**BAND_SHIFT map rows at a time (see update_kernel).
BAND_SHIFT = 4
#: Its touched-tile map has one flag per run of 2**TILE_SHIFT columns: the rules visit those only
#: (at least 8 columns: the compaction reads the rules' flags 8 at a time, from tile boundaries).
TILE_SHIFT = 5
#: Sample indices fit in 30 bits of a z-buffer key (:func:`_z_key`).
INDEX_MAX = (1 << 30) - 1


@numba.njit(cache=True, inline="always")
def _z_key(r, fill_only, i):  # pragma: no cover - compiled
    """The z-buffer key of sample i at float64 distance r: the smallest key covering a pixel is the
    sample a sequential z-test in sample order keeps (a later sample replaces the stored one when
    its float64 distance is below the stored float32 distance g), so the keys can be merged with
    ``min`` in any order.

    Bits 63–32 hold g = float32(r) rounded to nearest (its bits order like the values). Among the
    samples of the smallest g, the sequential test keeps the *last* with r < g (each replaces the
    one before) or, when there is none, the *first* (none replaces it): bit 31 is 0 for r < g and
    bits 30–1 hold 2³⁰ − 1 − i then, else bit 31 is 1 and bits 30–1 hold i. Bit 0 is the sample's
    ``fill_only`` flag (below the index, it never decides)."""
    f = np.float32(r)
    code = ((INDEX_MAX - i) << 1) if np.float64(f) > r else ((1 << 31) | (i << 1))
    return (np.int64(f32_bits(f)) << 32) | code | np.int64(fill_only)


@numba.njit(cache=True, inline="always")
def _key_index(q):  # pragma: no cover - compiled
    """The sample index of z-buffer key q (:func:`_z_key`)."""
    e = (q >> 1) & INDEX_MAX
    return e if (q >> 31) & 1 else INDEX_MAX - e


@numba.njit(cache=True, inline="always")
def _z_min4(z, p1, p2, p3, p4, key):  # pragma: no cover - compiled
    """z[p] = min(z[p], key) at four entries, all loaded before any is stored (chained tests would
    forward each store to the next load); equal entries load equal keys and store equal minima."""
    q1, q2, q3, q4 = z[p1], z[p2], z[p3], z[p4]
    w1, w2 = _mn(q1, key), _mn(q2, key)
    w3, w4 = _mn(q3, key), _mn(q4, key)
    z[p1] = w1
    z[p2] = w2
    z[p3] = w3
    z[p4] = w4


@numba.njit(cache=True, inline="always")
def _z_run(z, lo, hi, key):  # pragma: no cover - compiled
    """``min`` of the keys z[lo:hi] and ``key``, in place; a select per entry, so the run vectorises."""
    for k in range(lo, hi):
        z[_u(k)] = _mn(z[_u(k)], key)


@numba.njit(cache=True, inline="always")
def _is_free(ux, uy, uz, d, origin, cam, seen):  # pragma: no cover - compiled
    """Rule "freed": the stored point origin + d·(ux, uy, uz) projects into the frame's measured
    depth with all depths of the window around its pixel farther than its z by more than tol_rel·z +
    tol_abs. ``seen``: (H, W) float32, the minimum of the measured depth over each pixel's window
    (0 where any of them is not measured or lies outside the image; :func:`_seen_arrays`). ``cam``:
    T_cam_from_world rows (12), fx, fy, cx, cy, k1, k2, p1, p2, k3, tol_rel, tol_abs."""
    px, py, pz = origin[0] + d * ux, origin[1] + d * uy, origin[2] + d * uz
    z = cam[8] * px + cam[9] * py + cam[10] * pz + cam[11]
    if not z > 0.0:
        return False
    x = cam[0] * px + cam[1] * py + cam[2] * pz + cam[3]
    y = cam[4] * px + cam[5] * py + cam[6] * pz + cam[7]
    xd, yd = brown_distort(x / z, y / z, cam[16], cam[17], cam[18], cam[19], cam[20])
    u = cam[12] * xd + cam[14]
    v = cam[13] * yd + cam[15]
    h, w = seen.shape
    if not (u >= -0.5 and v >= -0.5 and u < w - 0.5 and v < h - 0.5):  # NaN fails
        return False
    return rule_freed(z, seen[int(v + 0.5), int(u + 0.5)], cam[21], cam[22])


@numba.njit(cache=True, error_model="numpy")
def _carve_tests(n, cols, flags, st, ct, col_sc, df, base, origin, cam, seen, buf):  # pragma: no cover - compiled
    """:func:`_is_free` for the pixels (row, cols[k]), k < n, of one row (sin θ ``st``, cos θ ``ct``,
    flat index of its first pixel ``base``): flags[cols[k]] = 3 where free, else 0. The same
    arithmetic as :func:`_is_free`, in three loops: the pixels' directions and depths gathered into
    ``buf`` (4, ≥ n), the projections (selects only, so the loop vectorises; a point behind the
    camera is divided by 1 instead of z and then refused), the lookups."""
    ux, uy, dd, thr = buf[0], buf[1], buf[2], buf[3]
    for k in range(n):
        c = cols[_u(k)]
        ux[_u(k)] = st * col_sc[c, 1]
        uy[_u(k)] = st * col_sc[c, 0]
        dd[_u(k)] = df[_u(base + c)]
    h, w = seen.shape
    fh, fw = h - 0.5, w - 0.5
    ox, oy, oz = origin[0], origin[1], origin[2]
    k1, k2, p1, p2, k3 = cam[16], cam[17], cam[18], cam[19], cam[20]
    for k in range(n):
        d = np.float32(dd[_u(k)])
        px, py, pz = ox + d * np.float32(ux[_u(k)]), oy + d * np.float32(uy[_u(k)]), oz + d * ct
        z = cam[8] * px + cam[9] * py + cam[10] * pz + cam[11]
        x = cam[0] * px + cam[1] * py + cam[2] * pz + cam[3]
        y = cam[4] * px + cam[5] * py + cam[6] * pz + cam[7]
        zs = z if z > 0.0 else 1.0
        xd, yd = brown_distort(x / zs, y / zs, k1, k2, p1, p2, k3)
        u = cam[12] * xd + cam[14]
        v = cam[13] * yd + cam[15]
        inside = (z > 0.0) & (u >= -0.5) & (v >= -0.5) & (u < fw) & (v < fh)  # NaN fails
        ux[_u(k)] = np.floor(u + 0.5) if inside else -1.0  # u + 0.5 ≥ 0: floor is int()'s truncation
        uy[_u(k)] = np.floor(v + 0.5) if inside else 0.0
        thr[_u(k)] = freed_limit(z, cam[21], cam[22])
    for k in range(n):
        iu = ux[_u(k)]
        free = iu >= 0.0 and seen[int(uy[_u(k)]), int(iu)] > np.float32(thr[_u(k)])
        flags[_u(cols[_u(k)])] = 3 if free else 0


@numba.njit(cache=True)
def _footprint_records(points, colours, fill_only, origin, device, height, width, focal_px, splat, splat_scale,
                       max_splat, i0, i1, rec, rec_key, per_band, work):  # pragma: no cover - compiled
    """:func:`update_kernel`'s step 1 for samples ``i0`` to ``i1`` − 1: each usable sample's
    footprint (rows, first column, columns) and key into ``rec`` / ``rec_key`` from index ``i0`` on,
    and the count of footprints reaching band b added to ``per_band[b + 1]``. With ``work`` (one
    entry per band; empty: none), 24 + the footprint's pixels are added to its first band's entry,
    an estimate of the band's share of steps 3 and 4. Returns how many records were written."""
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    qx, qy, qz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    fr0, fr1, fc0, fc1 = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    # 1. Footprints: rows ra..rb, columns a0 (wrapped) and how many, and the key, per usable sample.
    n_rec = i0
    # Band counts: consecutive samples mostly fall in the same band, so the counts of the current
    # band b_cur and of the next (footprints reaching into it) are kept in locals and added when
    # the band changes. A loop over the one or two bands each footprint reaches, exiting after one
    # or two unpredictably, cost more than its counting (with the listing below: 135 → 85 µs a
    # frame of the recorded session; spreading the counters over lanes alone gained 15).
    b_cur, n_cur, n_next = 0, 0, 0
    for start in range(i0, i1, _BLOCK):
        m = _mn(_BLOCK, i1 - start)
        block_coords(points, start, m, origin[0], origin[1], origin[2], row_px, col_px, bx, by, bz, bv, bu, br)
        for j in range(m):  # the points again, block-local: read from (N, 3) the loop stayed scalar
            qx[j], qy[j], qz[j] = points[start + j, 0], points[start + j, 1], points[start + j, 2]
        _block_footprints(m, qx, qy, qz, device, bx, by, bv, bu, br, height, width, row_px, col_px,
                          focal_px, splat, splat_scale, max_splat, fr0, fr1, fc0, fc1)
        for j in range(m):
            i = start + j
            if fr0[j] == _UNUSABLE or not (np.isfinite(colours[_u(i), 0]) and np.isfinite(colours[_u(i), 1])
                                           and np.isfinite(colours[_u(i), 2])):
                continue
            r0, r1, c0, c1 = int(fr0[j]), int(fr1[j]), int(fc0[j]), int(fc1[j])
            ra, rb = _mx(r0, 0), _mn(r1, height - 1)
            if ra > rb:
                continue
            rec[_u(n_rec), 0], rec[_u(n_rec), 1] = ra, rb
            # c0 ≥ −width (a column half-width is at most width / 2) and ≤ width: one wrap. A span
            # wider than the map covers each column once.
            rec[_u(n_rec), 2] = c0 + width if c0 < 0 else (c0 - width if c0 >= width else c0)
            rec[_u(n_rec), 3] = _mn(c1 - c0 + 1, width)
            rec_key[_u(n_rec)] = _z_key(br[j], fill_only[_u(i)], i)
            n_rec += 1
            b0, b1 = ra >> BAND_SHIFT, rb >> BAND_SHIFT
            if work.shape[0] > 0:
                work[_u(b0)] += 24 + (rb - ra + 1) * rec[_u(n_rec - 1), 3]
            if b0 != b_cur:
                per_band[_u(b_cur + 1)] += n_cur
                per_band[_u(b_cur + 2)] += n_next
                b_cur, n_cur, n_next = b0, 0, 0
            n_cur += 1
            n_next += b1 > b0
            for b in range(b0 + 2, b1 + 1):  # footprints reaching a third band (rare)
                per_band[_u(b + 1)] += 1
    per_band[_u(b_cur + 1)] += n_cur
    per_band[_u(b_cur + 2)] += n_next
    return n_rec - i0


@numba.njit(cache=True)
def _list_footprints(rec, n_bands, k0, n0, k1, n1, per_band, listed):  # pragma: no cover - compiled
    """:func:`update_kernel`'s step 2: the records ``k0`` to ``k0 + n0`` − 1, then ``k1`` to
    ``k1 + n1`` − 1, listed per band they reach (counting sort, in that order), from the counts of
    :func:`_footprint_records`. Returns (per_band, listed): the lists of band b are
    ``listed[per_band[b]:per_band[b + 1]]`` (``listed`` is a new array when the given one is too
    short)."""
    for b in range(n_bands):
        per_band[b + 1] += per_band[b]
    if per_band[n_bands] >= listed.shape[0]:  # footprints over about two bands on average
        listed = np.empty(per_band[n_bands] + 1, np.int32)
    # The same way: the fill positions of the current band and the next in locals (the others in
    # ``fill``); a footprint within one band stores its second entry into a spare slot past the
    # last, so the lists are those of the loop over bands, in sample order.
    fill = per_band[:n_bands + 1].copy()
    spare = per_band[n_bands]
    b_cur, f_cur, f_next = 0, fill[0], fill[1]
    for part in range(2):
        lo, hi = (k0, k0 + n0) if part == 0 else (k1, k1 + n1)
        for k in range(lo, hi):
            b0, b1 = rec[_u(k), 0] >> BAND_SHIFT, rec[_u(k), 1] >> BAND_SHIFT
            if b0 != b_cur:
                fill[_u(b_cur)], fill[_u(b_cur + 1)] = f_cur, f_next
                b_cur, f_cur, f_next = b0, fill[_u(b0)], fill[_u(b0 + 1)]
            listed[_u(f_cur)] = k
            f_cur += 1
            listed[_u(f_next if b1 > b0 else spare)] = k
            f_next += b1 > b0
            for b in range(b0 + 2, b1 + 1):
                listed[_u(fill[_u(b)])] = k
                fill[_u(b)] += 1
    return per_band, listed


@numba.njit(cache=True)
def _update_bands(
    band_lo, band_hi, per_band, listed, rec, rec_key, colours, origin, device, height, width, planes, depth, valid,
    trusted_r, removal_r, zband, tiles, row_sc, col_sc, log_idx, log_old, log_valid, log_n, carve, cam, seen,
    averaged, avg, views, clipped, clip_flags, hdr,
):  # pragma: no cover - compiled
    """:func:`update_kernel`'s steps 3 and 4 for bands ``band_lo`` to ``band_hi`` − 1: the bands'
    footprints z-buffered into ``zband`` (``tiles`` flag the touched 32-column tiles), then the rules
    and writes row by row, appending to the log from ``log_n`` on. Bands touch disjoint rows, so two
    calls on disjoint band ranges, each with its own ``zband``, ``tiles`` and log, may run at once.
    ``averaged`` (H·W,) uint8, ``avg`` = (colour_average, same-surface tolerance relative, absolute,
    view_ratio) and ``views`` (H·W,) float32, ``clipped`` (N,) uint8, ``clip_flags`` (H·W,) uint8
    and ``hdr``: see :func:`update_kernel`.
    Returns (pixels touched, taken, taken that had data, of those closer, freed, carving tests, averaged,
    kept for the viewpoint, kept for clipping, log length)."""
    band_rows = 1 << BAND_SHIFT
    n_tiles = (width + (1 << TILE_SHIFT) - 1) >> TILE_SHIFT
    hw = height * width
    pf, df, vf = planes.reshape(3, hw), depth.reshape(hw), valid.reshape(hw)
    # The removal rule needs the device within removal_r of the pixel's ray, at an angle α from the
    # device's direction with dev_r·sin α < removal_r and α < 90°, so α < asin(removal_r / dev_r);
    # a row whose polar angle differs from the device's by more than that (plus two rows, far above
    # rounding) has no such pixel, and its pixels skip the ray geometry (the vectorised rules
    # below). Inside the trusted sphere the trusted rule takes every such pixel first.
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    dev_r = math.sqrt(ox * ox + oy * oy + oz * oz)
    trusted = rule_trusted(dev_r, trusted_r)
    all_rows = not trusted and not removal_r < dev_r
    theta_dev = math.acos(_mx(-1.0, _mn(1.0, oz / dev_r))) if dev_r > 0.0 else 0.0
    cap = math.asin(_mx(removal_r, 0.0) / dev_r) + 2.0 * math.pi / height if removal_r < dev_r else math.pi
    n_touched, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg, n_kept = 0, 0, 0, 0, 0, 0, 0, 0
    n_kept_clip = 0
    n_average, same_rel, same_abs, view_ratio = int(avg[0]), avg[1], avg[2], avg[3]
    # The viewpoint rule: off (one dummy entry in ``views``) for an infinite ratio; the trusted
    # sphere's samples are never refused.
    by_view = view_ratio < np.inf and not trusted
    view_on = view_ratio < np.inf
    dev32 = np.float32(dev_r)
    avg_top = np.uint8(_mx(n_average - 2, 0))  # the count after which a new sample weighs 1 / n_average
    inv = np.empty(256, np.float32)  # a new sample's weight after k samples: 1 / (k + 2), looked up
    for k in range(256):
        inv[k] = np.float32(1.0) / (np.float32(k) + np.float32(2.0))
    take_p = np.empty(width + 8, np.int64)  # + 8: the compaction stores past the last taken pixel
    freed = np.zeros(width + 8, np.bool_)
    # Carving candidates: refused pixels whose sample lies beyond the stored point by the carving
    # tolerance (distances from the origin); the rest are the same surface or nearer, and the
    # projection into the frame (the cost: ~60 ns a pixel) is skipped. Without carving: none.
    carve_scale = 1.0 + cam[21] if carve else 1.0
    carve_abs = cam[22] if carve else np.inf
    # Padded to whole 8-byte words (the padding stays 0): the compaction and the candidate listing
    # skip words of 8 pixels with nothing to do (186 → 93 µs and about −20 µs a frame).
    flags = np.zeros(((width + 7) >> 3) << 3, np.uint8)
    flag_words = flags.view(np.uint64)
    cand_c, cand_u = np.empty(width + 8, np.int64), np.empty((4, width))
    run_lo, run_hi, run_flagged = np.empty(n_tiles, np.int64), np.empty(n_tiles, np.int64), np.empty(n_tiles, np.int64)
    for band in range(band_lo, band_hi):
        if per_band[band] == per_band[band + 1]:
            continue
        row0 = band << BAND_SHIFT
        row1 = _mn(row0 + band_rows, height) - 1
        # 3. The band's z-buffer: keys merged with min, tiles flagged (plain stores).
        for e in range(per_band[band], per_band[band + 1]):
            k = listed[e]
            ra, rb, a0, n_cols = rec[k, 0], rec[k, 1], rec[k, 2], rec[k, 3]
            key = rec_key[k]
            lo_r, hi_r = _mx(ra, row0) - row0, _mn(rb, row1) - row0
            if n_cols <= 2 and rb - ra <= 1:
                # At most 2×2 pixels (nearly every sample far from the origin): four branch-free
                # tests, the entries loaded before any is stored (most footprints are one pixel
                # wide or high; tests one after the other chained store-to-load forwards through
                # one entry). Equal pixels load equal keys and store equal minima.
                cb = a0 + n_cols - 1
                cb = 0 if cb == width else cb
                pa, pb = lo_r * width, hi_r * width
                _z_min4(zband, _u(pa + a0), _u(pa + cb), _u(pb + a0), _u(pb + cb), key)
                ta, tb = lo_r * n_tiles, hi_r * n_tiles
                tiles[_u(ta + (a0 >> TILE_SHIFT))] = 1
                tiles[_u(ta + (cb >> TILE_SHIFT))] = 1
                tiles[_u(tb + (a0 >> TILE_SHIFT))] = 1
                tiles[_u(tb + (cb >> TILE_SHIFT))] = 1
                continue
            if n_cols <= 8 and a0 + n_cols <= width:
                # 3 to 8 columns that do not wrap: per row one masked 8-lane min (min_run8).
                y0, y1 = a0 >> TILE_SHIFT, (a0 + n_cols - 1) >> TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    min_run8(zband, base + a0, n_cols, key)
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                continue
            if n_cols <= 4:
                # At most 4 columns (most of the rest): per row four branch-free tests at columns
                # a0 + min(k, n_cols - 1), wrapped; duplicates load and store equal minima.
                x1, x2, x3 = a0 + _mn(1, n_cols - 1), a0 + _mn(2, n_cols - 1), a0 + n_cols - 1
                x1 = x1 - width if x1 >= width else x1
                x2 = x2 - width if x2 >= width else x2
                x3 = x3 - width if x3 >= width else x3
                # The run's tiles: those of its first and last column and, where it wraps, of the
                # map's last column (at most 32 columns: no tile between them).
                y0, y1, y2 = a0 >> TILE_SHIFT, _mn(a0 + n_cols - 1, width - 1) >> TILE_SHIFT, x3 >> TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    _z_min4(zband, _u(base + a0), _u(base + x1), _u(base + x2), _u(base + x3), key)
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                    tiles[_u(tbase + y2)] = 1
                continue
            if n_cols <= 8:
                # 5 to 8 columns: the same with eight tests per row.
                x1, x2, x3 = a0 + 1, a0 + 2, a0 + 3
                x4, x5, x6, x7 = a0 + 4, a0 + _mn(5, n_cols - 1), a0 + _mn(6, n_cols - 1), a0 + n_cols - 1
                x1 = x1 - width if x1 >= width else x1
                x2 = x2 - width if x2 >= width else x2
                x3 = x3 - width if x3 >= width else x3
                x4 = x4 - width if x4 >= width else x4
                x5 = x5 - width if x5 >= width else x5
                x6 = x6 - width if x6 >= width else x6
                x7 = x7 - width if x7 >= width else x7
                y0, y1, y2 = a0 >> TILE_SHIFT, _mn(a0 + n_cols - 1, width - 1) >> TILE_SHIFT, x7 >> TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    p0, p1, p2, p3 = _u(base + a0), _u(base + x1), _u(base + x2), _u(base + x3)
                    p4, p5, p6, p7 = _u(base + x4), _u(base + x5), _u(base + x6), _u(base + x7)
                    q0, q1, q2, q3 = zband[p0], zband[p1], zband[p2], zband[p3]
                    q4, q5, q6, q7 = zband[p4], zband[p5], zband[p6], zband[p7]
                    w0, w1, w2, w3 = _mn(q0, key), _mn(q1, key), _mn(q2, key), _mn(q3, key)
                    w4, w5, w6, w7 = _mn(q4, key), _mn(q5, key), _mn(q6, key), _mn(q7, key)
                    zband[p0] = w0
                    zband[p1] = w1
                    zband[p2] = w2
                    zband[p3] = w3
                    zband[p4] = w4
                    zband[p5] = w5
                    zband[p6] = w6
                    zband[p7] = w7
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                    tiles[_u(tbase + y2)] = 1
                continue
            # Larger footprints: per row at most two runs (the seam). The first and last tile of
            # a run are flagged by plain stores, the ones between (wide runs only) by a loop.
            a1 = _mn(a0 + n_cols, width)
            b1 = a0 + n_cols - width
            t0, t1 = a0 >> TILE_SHIFT, (a1 - 1) >> TILE_SHIFT
            s1 = (b1 - 1) >> TILE_SHIFT
            for rr in range(lo_r, hi_r + 1):
                base, tbase = rr * width, rr * n_tiles
                _z_run(zband, base + a0, base + a1, key)
                tiles[_u(tbase + t0)] = 1
                tiles[_u(tbase + t1)] = 1
                for t in range(t0 + 1, t1):
                    tiles[_u(tbase + t)] = 1
                if b1 > 0:
                    _z_run(zband, base, base + b1, key)
                    for t in range(s1 + 1):
                        tiles[_u(tbase + t)] = 1
        # 4. The rules for the band's rows, per touched pixel against the pixel's own ray.
        for rr in range(row0, row1 + 1):
            zb, tb = (rr - row0) * width, (rr - row0) * n_tiles
            base = rr * width
            n_runs = 0
            t = 0
            while t < n_tiles:  # the row's runs of flagged tiles, the flags cleared on the way
                if tiles[_u(tb + t)] == 0:
                    t += 1
                    continue
                t0 = t
                while t < n_tiles and tiles[_u(tb + t)] != 0:
                    tiles[_u(tb + t)] = 0
                    t += 1
                run_lo[n_runs], run_hi[n_runs] = t0 << TILE_SHIFT, _mn(t << TILE_SHIFT, width)
                n_runs += 1
            if n_runs == 0:
                continue
            # The taken columns of the row, in order, into take_p[:nt].
            nt = 0
            st, ct = row_sc[rr, 0], row_sc[rr, 1]
            if not (all_rows or (not trusted and abs(math.pi * (rr + 0.5) / height - theta_dev) <= cap)):
                n_cand = 0
                for j in range(n_runs):
                    lo, hi = run_lo[j], run_hi[j]
                    # Without the removal rule: selects only, so the loop vectorises; the taken
                    # pixels are then compacted branch-free (taking and refusing mix unpredictably).
                    n_flagged = 0
                    for c in range(lo, hi):
                        q = zband[_u(zb + c)]
                        hit = q != EMPTY_Z
                        closer = (bits_f32(np.int32(q >> 32)) < df[_u(base + c)]) & ((q & 1) == 0)
                        n_touched += hit
                        take = hit & ((not vf[_u(base + c)]) | closer | trusted)
                        # 2 taken; 1 refused but a carving candidate (see below); 0 otherwise.
                        far = bits_f32(np.int32(q >> 32)) > df[_u(base + c)] * carve_scale + carve_abs
                        cand = hit & far & (not take)
                        n_cand += cand
                        n_flagged += take | cand
                        flags[_u(c)] = take + take + cand
                    run_flagged[j] = n_flagged
                if n_cand > 0:  # the row's candidates, listed, then tested together: 3 freed, else 0
                    n_cand = 0
                    for j in range(n_runs):
                        for w in range(run_lo[j] >> 3, (run_hi[j] + 7) >> 3):
                            if flag_words[_u(w)] & 0x0101010101010101 == 0:  # no flag 1 among the 8
                                continue
                            for c in range(w << 3, (w << 3) + 8):
                                cand_c[_u(n_cand)] = c  # cand_c has spare slots past the last candidate
                                n_cand += flags[_u(c)] == 1
                    _carve_tests(np.int64(n_cand), cand_c, flags, st, ct, col_sc, df, base, origin, cam, seen, cand_u)
                    n_tested += n_cand
                for j in range(n_runs):
                    if run_flagged[j] == 0:  # nothing taken or tested in the run (often)
                        continue
                    # Runs start at tile boundaries (2**TILE_SHIFT ≥ 8 columns) and end at one or
                    # at the map's width, so their words hold their own flags or the padding only.
                    for w in range(run_lo[j] >> 3, (run_hi[j] + 7) >> 3):
                        if flag_words[_u(w)] == 0:  # nothing taken or tested in these 8 pixels
                            continue
                        for c in range(w << 3, (w << 3) + 8):
                            f = flags[_u(c)]
                            take_p[_u(nt)] = c
                            freed[_u(nt)] = f == 3
                            nt += f >> 1
            else:
                for j in range(n_runs):
                    for c in range(run_lo[j], run_hi[j]):
                        q = zband[_u(zb + c)]
                        if q == EMPTY_Z:
                            continue
                        n_touched += 1
                        r = bits_f32(np.int32(q >> 32))
                        p = _u(base + c)
                        freed[_u(nt)] = False
                        if rule_empty(vf[p]) or (rule_closer(r, df[p]) and (q & 1) == 0) or trusted:
                            take = True
                        else:
                            ux, uy, uz = st * col_sc[c, 1], st * col_sc[c, 0], ct
                            along = ox * ux + oy * uy + oz * uz
                            if along > 0.0:
                                px, py, pz = ox - along * ux, oy - along * uy, oz - along * uz
                                to_ray = math.sqrt(px * px + py * py + pz * pz)
                            else:
                                to_ray = dev_r  # the ray starts at the origin: the closest point is the origin
                            take = rule_removal(along, to_ray, r, df[p], removal_r)
                            if not take and carve and r > df[p] * carve_scale + carve_abs:
                                n_tested += 1
                                take = _is_free(ux, uy, uz, df[p], origin, cam, seen)
                                freed[_u(nt)] = take
                        if take:
                            take_p[_u(nt)] = c
                            nt += 1
            # The writes, in raster order (so the change log is too); the rule that took a pixel
            # is the first that holds, in the documented order. The rules' counts follow from four
            # sums (pixels taken, those that had data, those of them closer, the freed ones): a
            # freed pixel had data and was neither closer nor trusted (carving tests only pixels
            # the other rules refuse), and "trusted" holds for all pixels or none (50 µs a frame
            # less than five counts per pixel).
            n_taken += nt
            for k in range(nt):
                c = take_p[k]
                p = _u(base + c)
                q = zband[_u(zb + c)]
                i = _u(_key_index(q))
                r = bits_f32(np.int32(q >> 32))
                ok, d = vf[p], df[p]
                closer = (r < d) & ((q & 1) == 0)
                free = carve and freed[k]
                # The same surface (a freed pixel's sample lies beyond the tolerance): the colour
                # averages; anything else replaces it and restarts the count.
                surface = ok & (abs(r - d) <= d * same_rel + same_abs)
                pv = p if view_on else _u(0)  # one dummy entry without the viewpoint rule
                # The viewpoint rule: a sample of the same surface from farther than view_ratio × the
                # nearest device distance the pixel's surface was seen from is refused (kept as is).
                if by_view and surface and dev_r > views[pv] * view_ratio:
                    n_kept += 1
                    continue
                # HDR (clip flags, docs/design/hdr.md): a clipped sample never overwrites an
                # unclipped colour of the same surface; over a clipped one it keeps the larger
                # value per channel (both are lower bounds); an unclipped sample replaces a
                # clipped colour. Without ``hdr`` the flags are one-entry dummies, all 0.
                pc = p if hdr else _u(0)
                cs = clipped[i if hdr else _u(0)] != 0
                cp = clip_flags[pc] != 0
                if surface and cs and not cp:
                    n_kept_clip += 1
                    continue
                both = surface & cs & cp
                same = surface & (n_average > 1) & (cs == cp) & (not both)
                pa = p if n_average > 1 else _u(0)  # one dummy entry when not averaging
                a = averaged[pa]
                weight = inv[a]
                n_ok += ok
                n_closer += ok & closer
                n_freed += free
                n_avg += same
                if log_n < log_idx.shape[0]:
                    log_idx[_u(log_n)] = p
                    for ch in range(3):
                        log_old[_u(log_n), ch] = pf[ch, p]
                    log_valid[_u(log_n)] = ok
                if log_idx.shape[0] > 0:
                    log_n += 1
                for ch in range(3):
                    old, new = pf[ch, p], colours[i, ch]
                    pf[ch, p] = old + (new - old) * weight if same else (_mx(old, new) if both else new)
                averaged[pa] = _mn(a + np.uint8(1), avg_top) if same else np.uint8(0)
                if hdr:
                    clip_flags[pc] = np.uint8(cs)
                if view_on:
                    views[pv] = _mn(views[pv], dev32) if surface else dev32
                df[p] = r if (not ok) | free else 0.5 * (d + r)
                vf[p] = True
            for j in range(n_runs):  # the band's z-buffer is empty again where this row was touched
                for c in range(run_lo[j], run_hi[j]):
                    zband[_u(zb + c)] = EMPTY_Z
    return n_touched, n_taken - n_kept - n_kept_clip, n_ok, n_closer, n_freed, n_tested, n_avg, n_kept, n_kept_clip, log_n


@numba.njit(cache=True, inline="always")
def _rule_counts(origin, device, trusted_r, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg, n_kept,
                 n_kept_clip):  # pragma: no cover - compiled
    """The update's counts (taken, empty, closer, trusted, removal, freed, carving tests, averaged,
    kept for the viewpoint, kept for clipping)
    from four sums: a freed pixel had data and was neither closer nor trusted (carving tests only
    pixels the other rules refuse), and "trusted" holds for all pixels or none."""
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    trusted = rule_trusted(math.sqrt(ox * ox + oy * oy + oz * oz), trusted_r)
    n_trusted = n_ok - n_closer if trusted else 0
    n_removal = 0 if trusted else n_ok - n_closer - n_freed
    return np.array([n_taken, n_taken - n_ok, n_closer, n_trusted, n_removal, n_freed, n_tested, n_avg, n_kept,
                     n_kept_clip], np.int64)


@numba.njit(cache=True, parallel=PRANGE_ONLY)
def update_kernel(
    points, colours, fill_only, origin, device, height, width, focal_px, splat, splat_scale, max_splat,
    planes, depth, valid, trusted_r, removal_r, zband, tiles, rec, rec_key, listed, row_sc, col_sc,
    log_idx, log_old, log_valid, log_n, carve, cam, seen, averaged, avg, views, clipped, clip_flags, hdr, zband2,
    tiles2, log2_idx,
    log2_old, log2_valid,
):  # pragma: no cover - compiled
    """:func:`update`: the frame's samples z-buffered (the closest wins, the first on equal float32
    distances; :func:`_z_key`), then the rules per touched pixel, in raster order. Every taken pixel
    is appended to the change log (``log_*``, entries from ``log_n`` on, while they fit; a
    zero-length log records nothing).

    Band by band: the samples' footprints are recorded and listed per band of 2**BAND_SHIFT rows
    they reach, then for each band they are z-buffered into ``zband`` (one band of int64 keys,
    :data:`EMPTY_Z` between updates: it stays in cache, where a whole-map z-buffer cost a memory
    round trip per touched pixel twice) and the band's rows go through the rules at once.
    With ``carve``, a touched pixel no other rule takes, whose sample lies beyond the stored depth by
    more than the carving tolerance, is tested with :func:`_is_free` (``cam``, ``seen``; a row's
    candidates at once by :func:`_carve_tests`, the same arithmetic) and taken if free ("freed":
    the depth is replaced, not averaged).
    A taken pixel that had data, whose sample lies within ``avg[1]`` · d + ``avg[2]`` of its stored
    distance d (the same surface), averages its colour: the new sample weighs 1 / (k + 2) with k =
    ``averaged[p]`` (flat (H·W,) uint8, then min(k + 1, ``avg[0]`` − 2)), so up to ``avg[0]``
    samples count equally and later ones weigh 1 / ``avg[0]``; any other taken pixel takes the
    sample's colour and k = 0. ``avg[0]`` = 1: the colour is always replaced (the paper).
    The viewpoint rule (``avg[3]`` = view_ratio finite, the device outside the trusted sphere): such a
    same-surface pixel is kept as it is, not taken, when the device's distance from the origin
    exceeds view_ratio × ``views[p]`` (flat (H·W,) float32, the nearest device distance the pixel's
    surface was seen from: the minimum over same-surface takeovers, the device's distance after any
    other); with an infinite ratio ``views`` is a one-entry dummy, never read.
    HDR (``hdr``): ``clipped`` (N,) uint8 flags the samples with a clipped channel, ``clip_flags``
    (H·W,) uint8 the pixels whose colour came from such a sample. A taken pixel with the same-surface
    test true is kept as it is (counted, not taken) for a clipped sample over an unclipped colour;
    a clipped sample over a clipped colour keeps the larger value per channel (both are lower
    bounds of the radiance); a sample whose flag differs from the pixel's otherwise replaces the
    colour. Every other write stores the sample's flag. Without ``hdr`` both are one-entry zeros.
    Returns (pixels touched, counts: taken, empty, closer, trusted, removal, freed, carving tests,
    averaged, kept for the viewpoint, kept for clipping; new log length).

    On two threads (one where numba has one; the map, counts and change log are the same bit for
    bit): the footprints of each half of the samples are recorded at the same time and listed, then
    the bands are split where half the estimated work (footprints and their pixels,
    :func:`_footprint_records`) lies before the split, the upper part updated with ``zband`` /
    ``tiles`` and logged into ``log_*``, the lower part at the same time with ``zband2`` / ``tiles2``
    into ``log2_*`` (as long as ``log_idx``, or empty when not logging), whose entries are then
    appended, so the log stays in raster order."""
    n_bands = (height + (1 << BAND_SHIFT) - 1) >> BAND_SHIFT
    n = points.shape[0]
    mid = n >> 1
    counts2 = np.zeros((2, n_bands + 2), np.int64)
    work2 = np.zeros((2, n_bands), np.int64)
    n_recs = np.zeros(2, np.int64)
    for t in numba.prange(2):  # the footprints of each half of the samples
        n_recs[t] = _footprint_records(points, colours, fill_only, origin, device, height, width, focal_px, splat,
                                       splat_scale, max_splat, 0 if t == 0 else mid, mid if t == 0 else n, rec,
                                       rec_key, counts2[t], work2[t])
    per_band = counts2[0] + counts2[1]
    per_band, listed = _list_footprints(rec, n_bands, 0, n_recs[0], mid, n_recs[1], per_band, listed)
    # The split: where the estimated work before it first reaches half of all.
    work = work2[0] + work2[1]
    half = work.sum() >> 1
    split, done = 0, 0
    while split < n_bands and done + work[split] <= half:
        done += work[split]
        split += 1
    res = np.zeros((2, 10), np.int64)
    for t in numba.prange(2):
        # One call site (a call per branch compiled _update_bands twice, for its literal arguments).
        lo, hi, n_log = (0, split, log_n) if t == 0 else (split, n_bands, 0)
        # The per-part buffers as locals: ternaries inside a call this long compile to a call
        # numba cannot read (CALL_FUNCTION_EX).
        zb_t = zband if t == 0 else zband2
        tiles_t = tiles if t == 0 else tiles2
        li_t = log_idx if t == 0 else log2_idx
        lo_t = log_old if t == 0 else log2_old
        lv_t = log_valid if t == 0 else log2_valid
        a, b, c, d, e, f, g, k, kc, h = _update_bands(
            lo, hi, per_band, listed, rec, rec_key, colours, origin, device, height, width, planes, depth, valid,
            trusted_r, removal_r, zb_t, tiles_t, row_sc, col_sc, li_t, lo_t, lv_t,
            n_log, carve, cam, seen, averaged, avg, views, clipped, clip_flags, hdr)
        res[t, 0], res[t, 1], res[t, 2], res[t, 3], res[t, 4], res[t, 5], res[t, 6], res[t, 7] = a, b, c, d, e, f, g, k
        res[t, 8], res[t, 9] = h, kc
    # The lower part's log after the upper part's (while it fits: the log's length counts on past
    # its capacity, as the single-threaded kernel's does).
    n0, n1 = res[0, 8], res[1, 8]
    cap = log_idx.shape[0]
    for j in range(_mn(n1, _mn(log2_idx.shape[0], cap - n0))):
        log_idx[n0 + j] = log2_idx[j]
        log_old[n0 + j, 0], log_old[n0 + j, 1], log_old[n0 + j, 2] = log2_old[j, 0], log2_old[j, 1], log2_old[j, 2]
        log_valid[n0 + j] = log2_valid[j]
    log_n = n0 + n1
    t = res[0] + res[1]
    return t[0], _rule_counts(origin, device, trusted_r, t[1], t[2], t[3], t[4], t[5], t[6], t[7], t[9]), log_n



@numba.njit(cache=True)
def measured_depth(depth, known):  # pragma: no cover - compiled
    """(H, W) float32: ``depth`` where ``known`` and finite and > 0, else 0 (numpy's where and
    casts of a 224×172 frame took 70 µs)."""
    out = np.empty(depth.shape, np.float32)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            out[r, c] = np.float32(z) if known[r, c] and z > 0.0 and z < np.inf else np.float32(0.0)
    return out

