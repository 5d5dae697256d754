"""Kernels of the SH stage's missing-pixel fill: the fill plan and its application to a copy.

The fill is planned once from the mask, then applied while each row is staged for the projection
(:mod:`rgbd_envmap._kernels.sh_projection`), so no filled copy of the map is ever written. The plan
lists the missing pixels row by row with the flat index of the data pixel each one copies (−1: none
within the radius) and its rank key. One pass over the mask handles 8 pixels (one uint64) at a
time, counting the missing pixels of each row; then each missing pixel costs O(1): the vertical
source comes from per-column state carried down (then up) the list of missing pixels (the run of
missing pixels above a pixel shares its data row), the horizontal one from the runs of missing
columns in the row. A missing polar cap therefore costs O(1) per pixel, not a 50-step search per
pixel.

The rule itself, in plain numpy: :func:`rgbd_envmap.reference.sh_fill.fill_missing`. Called from
:mod:`rgbd_envmap.sh.projection` only.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["NO_KEY", "ALL_VALID", "BYTE_SUM", "fill_plan", "apply_fill"]

NO_KEY = np.iinfo(np.int32).max  # fill key of a missing pixel without a source
ALL_VALID = np.uint64(0x0101010101010101)  # eight bool bytes, all True
BYTE_SUM = np.uint64(0x0101010101010101)  # the top byte of x · this is the sum of x's eight bytes


@numba.njit(cache=True)
def fill_plan(bytes_, words, H, W, radius):  # pragma: no cover - compiled
    """bytes_: (H, W8) uint8 view of the bool mask (columns ≥ W padded True), words: its (H, W8 / 8)
    uint64 view (used only to skip and count eight pixels at a time, so byte order does not matter).

    Returns (row_ptr (H + 1,) int64, col (n,) int32, src (n,) int64, empty (H,) bool, key (n,)
    int32): the missing pixels of row v are col[row_ptr[v]:row_ptr[v + 1]] (increasing); src is the
    flat index v' W + u' of the data pixel each copies, or −1; ``empty[v]``: row v contributes
    nothing (no pixel has or gets data), so the projection skips it without reading it; key =
    4 · distance + direction (0 up, 1 down, 2 left, 3 right), the order the rule ranks sources in
    (:data:`NO_KEY` without a source)."""
    nw = words.shape[1]
    sh56 = np.uint64(56)
    # 1. missing pixels per row: 8 − (sum of the eight 0/1 bytes), the byte sum by one multiply
    row_ptr = np.zeros(H + 1, np.int64)
    for v in range(H):
        cnt = 0
        for w in range(nw):
            x = words[v, w]
            if x != ALL_VALID:
                cnt += 8 - np.int64((x * BYTE_SUM) >> sh56)
        row_ptr[v + 1] = row_ptr[v] + cnt
    n = row_ptr[H]
    col = np.empty(n + 8, np.int32)
    src = np.full(n, -1, np.int64)
    dist = np.full(n, radius + 1, np.int32)
    key = np.full(n, NO_KEY, np.int32)
    # Vertical sources use per-column state, top-down then bottom-up: a missing pixel right below
    # (above) a missing one shares its data row; otherwise the data row is the adjacent one.
    prev = np.full(W, -2, np.int64)  # row of the last missing pixel seen in the column
    run = np.full(W, -1, np.int64)  # the data row above (below) that pixel's run; −1 (H): the pole
    # 2. top-down: list the missing pixels of each row (row-major), then their "up" source
    k = 0
    for v in range(H):
        k0 = row_ptr[v]
        k1 = row_ptr[v + 1]
        if k0 == k1:
            continue
        for w in range(nw):
            x = words[v, w]
            if x != ALL_VALID:
                for u in range(8 * w, 8 * w + 8):  # branch-free append (8 spare slots)
                    col[k] = u
                    k += 1 - np.int64(bytes_[v, u])
        for t in range(k0, k1):
            u = col[t]
            up = run[u] if prev[u] == v - 1 else v - 1
            prev[u] = v
            run[u] = up
            if up >= 0 and v - up <= radius:
                dist[t] = v - up
                src[t] = up * W + u
                key[t] = 4 * (v - up)
    # 3. bottom-up: "down" (strictly closer only: up wins ties), then left and right from the runs
    #    of missing columns in the row, wrapping across the seam, each only when strictly closer
    #    (the fixed tie order up, down, left, right).
    prev[:] = H + 1
    run[:] = H
    empty = np.zeros(H, np.bool_)
    for v in range(H - 1, -1, -1):
        k0 = row_ptr[v]
        k1 = row_ptr[v + 1]
        if k0 == k1:
            continue
        for t in range(k1 - 1, k0 - 1, -1):
            u = col[t]
            dn = run[u] if prev[u] == v + 1 else v + 1
            prev[u] = v
            run[u] = dn
            if dn < H and dn - v < dist[t] and dn - v <= radius:
                dist[t] = dn - v
                src[t] = dn * W + u
                key[t] = 4 * (dn - v) + 1
        if k1 - k0 == W:  # no data in the row: no horizontal sources
            empty[v] = True
            for t in range(k0, k1):
                if src[t] >= 0:
                    empty[v] = False
                    break
            continue
        first_end = -1  # last column of the run that starts at column 0, if any
        if col[k0] == 0:
            j = k0
            while j + 1 < k1 and col[j + 1] == col[j] + 1:
                j += 1
            first_end = col[j]
        last_start = W  # first column of the run that ends at column W − 1, if any
        if col[k1 - 1] == W - 1:
            j = k1 - 1
            while j - 1 >= k0 and col[j - 1] == col[j] - 1:
                j -= 1
            last_start = col[j]
        t0 = k0
        while t0 < k1:
            j = t0
            while j + 1 < k1 and col[j + 1] == col[j] + 1:
                j += 1
            left = col[t0] - 1 if col[t0] > 0 else last_start - 1
            right = col[j] + 1 if col[j] < W - 1 else first_end + 1
            for t in range(t0, j + 1):
                u = col[t]
                dl = u - left  # wraps across the seam when left is past u
                if dl < 0:
                    dl += W
                if dl < dist[t] and dl <= radius:
                    dist[t] = dl
                    src[t] = v * W + left
                    key[t] = 4 * dl + 2
                dr = right - u
                if dr < 0:
                    dr += W
                if dr < dist[t] and dr <= radius:
                    dist[t] = dr
                    src[t] = v * W + right
                    key[t] = 4 * dr + 3
            t0 = j + 1
    return row_ptr, col[:n], src, empty, key


@numba.njit(cache=True)
def apply_fill(rad, row_ptr, col, src, out, used):  # pragma: no cover - compiled
    """Overwrite the missing pixels of ``out`` (a copy of ``rad``) with their sources, 0 if none."""
    H, W, C = rad.shape
    for v in range(H):
        for k in range(row_ptr[v], row_ptr[v + 1]):
            u = col[k]
            s = src[k]
            if s >= 0:
                for c in range(C):
                    out[v, u, c] = rad[s // W, s % W, c]
            else:
                used[v, u] = False
                for c in range(C):
                    out[v, u, c] = 0.0
