"""Kernels of the incremental SH projection (:class:`rgbd_envmap.sh.IncrementalProjection`).

c_k = Σ_p w_p Y_k(p) L̃(p), L̃ the filled map, is linear in the map. Between two frames the update
writes a few percent of the pixels, while a full projection reads every pixel and re-plans every
missing one. The tracker keeps the coefficients and, per pixel, the fill state as one rank key
(:data:`KEY_DATA` for data, 4 · distance + direction of the source it copies, or "none"; the key
names the source, so no index is stored: one byte per pixel for radii ≤ 62), and applies the map's
change log:

A. a pixel that had data changes colour by Δ: c += Δ ⊗ w Y at the pixel and at every missing pixel
   that copies it; those lie on the four straight runs of missing pixels that start next to it (a
   source is the closest data pixel along its line, so everything between is missing);
B. a pixel gets data: its fill contribution (if any) is replaced by its own;
C. missing pixels near a new data pixel may now copy it: walk the four runs of missing pixels from
   it (≤ radius) and switch each pixel whose current source ranks worse (distance, then up, down,
   left, right as in the rule): c += w Y (L_new − L_old source).

Valid pixels only appear (the update never removes data), so A–C keep the state equal to a fresh
fill plan; anything else (the log overflowed, the arrays were edited, another map) rebuilds in full.

Per change the kernels stage Δ and cos φ, sin φ (a scalar loop: its loads are gathers), then form
30 multiply-adds vectorised over a row's changes (:func:`reduce_row`), which costs far less than
adding each change to its row's sums in memory through a cos / sin table. Changes off the current
row (copies met walking a column, switched fills) are buffered as records and sorted by row
(:func:`flush`). Called from :mod:`rgbd_envmap.sh.incremental` only.
"""

from __future__ import annotations

import numba
import numpy as np

from rgbd_envmap._kernels.intrinsics import prefetch
from rgbd_envmap._kernels.sh_fill import NO_KEY
from rgbd_envmap._kernels.sh_projection import BLOCK, FASTMATH, U0, U1, U2

__all__ = ["AHEAD", "KEY_DATA", "NO_KEY", "BLOCK", "source", "reduce_block", "reduce_row", "stage", "flush",
           "contract_rows", "dense_fill_state", "scratch_sizes", "apply_changes"]

#: How far ahead (log entries in A, new data pixels in C) :func:`apply_changes` prefetches the map and
#: the fill state: between two SH updates the pipeline's other stages evict the fill state from the
#: cache, and the hardware prefetcher does not follow these sparse, row-skipping reads.
AHEAD = np.uint64(32)
KEY_DATA = 0  # fill key of a pixel with data (a source's key is 4 · distance + direction ≥ 4)


@numba.njit(cache=True, inline="always")
def source(p, u, kk, W):  # pragma: no cover - compiled
    """Flat index of the data pixel that missing pixel p (column u) copies, from its rank key kk:
    the key names the direction and the distance, so the tracker stores no source indices."""
    d = kk >> 2
    r = kk & 3
    if r == 0:
        return p - d * W
    if r == 1:
        return p + d * W
    q = u - d if r == 2 else u + d  # d < W: at most one wrap across the seam
    q = q + W if q < 0 else (q - W if q >= W else q)
    return p - u + q


@numba.njit(cache=True, fastmath=FASTMATH, inline="always")
def reduce_block(st, i0, i1, a, j, first, store):  # pragma: no cover - compiled
    """One block of 5 orders (sums a[:, j:j + 10]) of :func:`reduce_row`. ``first``, ``store``:
    constants after inlining, so each combination is its own branch-free loop. The first block
    starts from e^{i0φ} = 1 instead of loading it: its order-1 term is (cos φ, sin φ) itself, exactly
    what 1 · c − 0 · s would give, and the sin(0φ) sum, which no coefficient uses, is skipped.
    ``store`` writes the next block's first order to st[2], st[3]."""
    c1 = st[0]
    s1 = st[1]
    bc = st[2]
    bs = st[3]
    x0 = st[4]
    x1 = st[5]
    x2 = st[6]
    a00 = a01 = a02 = a03 = a04 = a05 = a06 = a07 = a08 = a09 = 0.0
    a10 = a11 = a12 = a13 = a14 = a15 = a16 = a17 = a18 = a19 = 0.0
    a20 = a21 = a22 = a23 = a24 = a25 = a26 = a27 = a28 = a29 = 0.0
    for i in range(i0, i1):
        c = c1[i]
        s = s1[i]
        if first:
            q1c = c
            q1s = s
        else:
            q0c = bc[i]
            q0s = bs[i]
            q1c = q0c * c - q0s * s
            q1s = q0c * s + q0s * c
        q2c = q1c * c - q1s * s
        q2s = q1c * s + q1s * c
        q3c = q2c * c - q2s * s
        q3s = q2c * s + q2s * c
        q4c = q3c * c - q3s * s
        q4s = q3c * s + q3s * c
        if store:
            bc[i] = q4c * c - q4s * s
            bs[i] = q4c * s + q4s * c
        x = x0[i]
        if first:
            a00 += x
        else:
            a00 += q0c * x
            a05 += q0s * x
        a01 += q1c * x
        a02 += q2c * x
        a03 += q3c * x
        a04 += q4c * x
        a06 += q1s * x
        a07 += q2s * x
        a08 += q3s * x
        a09 += q4s * x
        x = x1[i]
        if first:
            a10 += x
        else:
            a10 += q0c * x
            a15 += q0s * x
        a11 += q1c * x
        a12 += q2c * x
        a13 += q3c * x
        a14 += q4c * x
        a16 += q1s * x
        a17 += q2s * x
        a18 += q3s * x
        a19 += q4s * x
        x = x2[i]
        if first:
            a20 += x
        else:
            a20 += q0c * x
            a25 += q0s * x
        a21 += q1c * x
        a22 += q2c * x
        a23 += q3c * x
        a24 += q4c * x
        a26 += q1s * x
        a27 += q2s * x
        a28 += q3s * x
        a29 += q4s * x
    for ch in range(3):
        r = a[ch]
        if ch == 0:
            t = (a00, a01, a02, a03, a04, a05, a06, a07, a08, a09)
        elif ch == 1:
            t = (a10, a11, a12, a13, a14, a15, a16, a17, a18, a19)
        else:
            t = (a20, a21, a22, a23, a24, a25, a26, a27, a28, a29)
        for i in range(2 * BLOCK):
            r[j + i] += t[i]


@numba.njit(cache=True, fastmath=FASTMATH, inline="always")
def reduce_row(st, i0, i1, a, records):  # pragma: no cover - compiled
    """a (3, P) += the longitude sums of the changes st[:, i0:i1], all in one row. ``st`` (7, N):
    cos φ_u, sin φ_u, cos, sin of the block's first order m (blocks after the first only; written
    here), Δ per channel. The other orders of a block come from the first by complex
    multiplication by e^{iφ}, so the loop needs no table lookups (gathers) and the 30 sums stay in
    registers.

    ``records`` (a constant): the records' loop in :func:`flush` always stores the next block's
    start; that store (st may alias its inputs) keeps LLVM from vectorising the loop, and so fixes
    its rounding (vectorised, its sums would reassociate across SIMD lanes and the coefficients
    change in the last bits). A row's own changes (``records`` False) vectorise either way; with
    5 bands their loop stores nothing."""
    nb = a.shape[1] // (2 * BLOCK)
    if nb == 1 and not records:
        reduce_block(st, i0, i1, a, 0, True, False)
    else:
        reduce_block(st, i0, i1, a, 0, True, True)
        for j in range(1, nb):
            reduce_block(st, i0, i1, a, 2 * BLOCK * j, False, True)


@numba.njit(cache=True, inline="always")
def stage(st, i, phi1, u, d0, d1, d2):  # pragma: no cover - compiled
    """Stage change i for :func:`reduce_row`: cos φ_u, sin φ_u and Δ (st[2], st[3] are its own)."""
    st[0, i] = phi1[u, 0]
    st[1, i] = phi1[u, 1]
    st[4, i] = d0
    st[5, i] = d1
    st[6, i] = d2


@numba.njit(cache=True, fastmath=FASTMATH)
def flush(rec_v, rec_u, rec_d, nr, phi1, st, start, acc, dirty):  # pragma: no cover - compiled
    """Add the nr recorded changes (row, column, Δ) in any order to the row sums: sort them by row
    (counting sort into ``st``), then :func:`reduce_row` each row. Returns 0 (the records left)."""
    H = acc.shape[0]
    start[:] = 0
    for i in range(nr):
        start[rec_v[i] + 1] += 1
    for v in range(H):
        start[v + 1] += start[v]
    for i in range(nr):  # afterwards start[v] is where row v ends
        v = rec_v[i]
        j = start[v]
        start[v] = j + 1
        stage(st, j, phi1, rec_u[i], rec_d[0, i], rec_d[1, i], rec_d[2, i])
    b = 0
    for v in range(H):
        e = start[v]
        if e > b:
            dirty[v] = True
            reduce_row(st, b, e, acc[v], True)
        b = e
    return 0


@numba.njit(cache=True)
def contract_rows(acc, dirty, row_w, m_col, c):  # pragma: no cover - compiled
    """c[k] += Σ_v row_w[v, k] acc[v, :, m_col[k]] over the dirty rows, which are then reset."""
    for v in range(acc.shape[0]):
        if not dirty[v]:
            continue
        dirty[v] = False
        for k in range(c.shape[0]):
            w = row_w[v, k]
            j = m_col[k]
            for ch in range(3):
                c[k, ch] += w * acc[v, ch, j]
        for ch in range(3):
            for j in range(acc.shape[2]):
                acc[v, ch, j] = 0.0


@numba.njit(cache=True)
def dense_fill_state(row_ptr, col, key, W, state, none):  # pragma: no cover - compiled
    """The plan's keys as a dense per-pixel state: 0 data, the rank key, ``none`` without a source."""
    state[:] = KEY_DATA
    for v in range(row_ptr.shape[0] - 1):
        for t in range(row_ptr[v], row_ptr[v + 1]):
            state[v * W + col[t]] = key[t] if key[t] != NO_KEY else none


def scratch_sizes(H: int, W: int, n: int, records: int) -> tuple[int, int]:
    """Sizes of :func:`apply_changes`' float64 and int64 scratch for n logged pixels."""
    return 14 * W + 10 * records, 2 * records + H + 1 + W + n


@numba.njit(cache=True, fastmath=FASTMATH)
def apply_changes(flat, H, W, index, old, was_valid, state, none, phi1, radius, acc, dirty, n_records, fscr, iscr):  # pragma: no cover
    """Steps A–C of the module docstring. ``flat``: (3, H W) float32 map after the writes;
    ``state``: (H W,) the fill key of every pixel (0: data, 4 · distance + direction: copies the
    pixel that names, ``none``: no source); ``phi1``: (W, 2) cos φ_u, sin φ_u. The changes accumulate as per-row longitude sums
    in ``acc`` (H, 3, P) with ``dirty`` rows (P: per block of 5 orders m, the 5 cos(mφ) then the
    5 sin(mφ) sums); :func:`contract_rows` turns them into coefficients (30 multiply-adds per
    changed pixel for 5 bands instead of 75). The sums are formed by :func:`reduce_row` over a
    row's changes staged together: the log's pixels row by row, other changes through records
    sorted by row (:func:`flush`), which is much faster than adding each change to its row's sums in
    memory. ``fscr``, ``iscr``: float64 / int64 scratch of :func:`scratch_sizes` (kept by the caller,
    so that no call pays the page faults of a fresh ~1 MB allocation)."""
    n = index.shape[0]
    f0 = flat[0]
    f1 = flat[1]
    f2 = flat[2]
    R = n_records
    st = fscr[:14 * W].reshape(7, 2 * W)  # one row's staged changes (≤ W written, ≤ W copies met along it)
    srt = fscr[14 * W:14 * W + 7 * R].reshape(7, R)  # the records sorted by row, staged for reduce_row
    rec_d = fscr[14 * W + 7 * R:14 * W + 10 * R].reshape(3, R)  # other changes: row, column, Δ
    rec_v = iscr[:R]
    rec_u = iscr[R:2 * R]
    start = iscr[2 * R:2 * R + H + 1]
    todo = iscr[2 * R + H + 1:2 * R + H + 1 + W]  # a row's written pixels that need more than staging
    fresh = iscr[2 * R + H + 1 + W:]  # the pixels that get data, for C
    nf = 0
    nr = np.int64(0)  # not a literal 0: numba would compile flush a second time for a literal
    # A (and B's colours). The log lists pixels in raster order. B only reads the state here: A's
    # walks must see it as it was.
    last = np.uint64(n - 1)
    e1 = 0
    while e1 < n:
        e0 = e1
        v = index[e0] // W
        row = v * W
        while e1 < n and index[e1] < row + W:
            e1 += 1
        k = e1 - e0
        # unsigned indices: numba's wrap-around of negative ones costs more than the loop's work
        uw = np.uint64(W)
        ur = np.uint64(row)
        up = uw if v > 0 else np.uint64(0)
        down = uw if v < H - 1 else np.uint64(0)
        nt = 0
        for i in range(k):
            e = np.uint64(e0 + i)
            pa = np.uint64(index[min(e + AHEAD, last)])  # its colours and the state row below
            prefetch(f0, pa)
            prefetch(f1, pa)
            prefetch(f2, pa)
            prefetch(state, pa + uw)
            p = np.uint64(index[e])
            u = p - ur
            w = was_valid[e]
            d0 = np.float64(f0[p]) - np.float64(old[e, U0])  # read for new data pixels too, then
            d1 = np.float64(f1[p]) - np.float64(old[e, U1])  # dropped: no branch
            d2 = np.float64(f2[p]) - np.float64(old[e, U2])
            stage(st, i, phi1, u, d0 if w else 0.0, d1 if w else 0.0, d2 if w else 0.0)
            # A. nearly every written pixel has data on all four sides: nothing copies it, no
            # walks. The others, and B's pixels, are listed (without a branch) for the loop below.
            left = p - U1 if u > 0 else p + uw - U1
            right = p + U1 if u < uw - U1 else p + U1 - uw
            todo[nt] = i
            nt += (not w) | ((state[left] | state[right] | state[p - up] | state[p + down]) != KEY_DATA)
        kw = k  # copies found along the row are staged after the row's written pixels
        for t in range(nt):
            i = todo[t]
            e = e0 + i
            p = index[e]
            u = p - row
            if not was_valid[e]:
                # B. a new data pixel: its own colour replaces what it copied
                fresh[nf] = p
                nf += 1
                kk = np.int64(state[p])
                s = source(p, u, kk, W) if kk != none else -1
                st[4, i] = np.float64(f0[p]) - (np.float64(f0[s]) if s >= 0 else 0.0)
                st[5, i] = np.float64(f1[p]) - (np.float64(f1[s]) if s >= 0 else 0.0)
                st[6, i] = np.float64(f2[p]) - (np.float64(f2[s]) if s >= 0 else 0.0)
                continue
            d0 = st[4, i]
            d1 = st[5, i]
            d2 = st[6, i]
            if d0 == 0.0 and d1 == 0.0 and d2 == 0.0:
                continue
            # The key names the source's side, so a pixel on a row shorter than twice the radius,
            # which the walks meet from both sides, is counted once.
            for side in range(2):  # along the row, wrapping at the seam
                step = -1 if side == 0 else 1
                rank = 3 if side == 0 else 2  # walking left, p is on the visited pixel's right
                qu = u
                for d in range(1, radius + 1):
                    qu += step
                    qu = qu + W if qu < 0 else (qu - W if qu >= W else qu)
                    s = state[row + qu]
                    if s == KEY_DATA:
                        break
                    if s == 4 * d + rank:
                        stage(st, kw, phi1, qu, d0, d1, d2)
                        kw += 1
            for side in range(2):  # along the column, not across a pole
                step = -1 if side == 0 else 1
                rank = 1 if side == 0 else 0  # walking up, p is below the visited pixel
                qv = v
                for d in range(1, radius + 1):
                    qv += step
                    if qv < 0 or qv >= H:
                        break
                    s = state[qv * W + u]
                    if s == KEY_DATA:
                        break
                    if s == 4 * d + rank:
                        if nr == n_records:
                            nr = flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)
                        rec_v[nr] = qv
                        rec_u[nr] = u
                        rec_d[0, nr] = d0
                        rec_d[1, nr] = d1
                        rec_d[2, nr] = d2
                        nr += 1
        dirty[v] = True
        reduce_row(st, 0, kw, acc[v], False)
    # B. the new data pixels are data from now on
    for i in range(nf):
        state[fresh[i]] = KEY_DATA
    # C. missing pixels along the four runs from each new data pixel may copy it now
    uw = np.uint64(W)
    lastf = np.uint64(max(nf - 1, 0))
    for i in range(nf):
        pa = np.uint64(fresh[min(np.uint64(i) + AHEAD, lastf)])  # the state rows above and below
        prefetch(state, pa - uw)
        prefetch(state, pa + uw)
        p = fresh[i]
        v = p // W
        u = p - v * W
        # New data mostly comes in patches: inside one, all four neighbours have data (new pixels
        # are data by now) and every walk would stop at its first step. One test for all four
        # (unsigned, as in A; a pole tests p itself) skips the four unpredictable loop exits.
        pp = np.uint64(p)
        lq = pp - U1 if u > 0 else pp + uw - U1
        rq = pp + U1 if u < W - 1 else pp + U1 - uw
        aq = pp - uw if v > 0 else pp
        bq = pp + uw if v < H - 1 else pp
        if (state[lq] | state[rq] | state[aq] | state[bq]) == KEY_DATA:
            continue
        l0 = np.float64(f0[p])
        l1 = np.float64(f1[p])
        l2 = np.float64(f2[p])
        for dirn in range(4):
            # walking up from p, p is *below* the visited pixels (rank 1), and so on
            dv = -1 if dirn == 0 else (1 if dirn == 1 else 0)
            du = -1 if dirn == 2 else (1 if dirn == 3 else 0)
            rank = 1 if dirn == 0 else (0 if dirn == 1 else (3 if dirn == 2 else 2))
            qv = v
            qu = u
            for d in range(1, radius + 1):
                qv += dv
                if qv < 0 or qv >= H:
                    break
                qu += du
                qu = qu + W if qu < 0 else (qu - W if qu >= W else qu)
                q = qv * W + qu
                kq = np.int64(state[q])
                if kq == KEY_DATA:
                    break
                k = 4 * d + rank
                if k < kq:
                    s = source(q, qu, kq, W) if kq != none else -1
                    if nr == n_records:
                        nr = flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)
                    rec_v[nr] = qv
                    rec_u[nr] = qu
                    rec_d[0, nr] = l0 - (np.float64(f0[s]) if s >= 0 else 0.0)
                    rec_d[1, nr] = l1 - (np.float64(f1[s]) if s >= 0 else 0.0)
                    rec_d[2, nr] = l2 - (np.float64(f2[s]) if s >= 0 else 0.0)
                    nr += 1
                    state[q] = k
    flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)
