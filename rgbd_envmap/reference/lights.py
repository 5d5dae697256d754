"""Readable references of the light samplers' cores (:mod:`rgbd_envmap.lights`), used by the tests,
and the test scene they are run on.

Each function recomputes from scratch, in float64, without the library's tables, kernels or
shortcuts: pixel directions and solid angles from the equirect formulas of
docs/reference/conventions.md, HEALPix cells per level from ``healpy.vec2pix`` (not from a pyramid),
and the Q2-Tree grown one split at a time as Algorithm 1 of paper 002 writes it.
"""

from __future__ import annotations

import heapq

import numpy as np

from rgbd_envmap.reference.sh_projection import pixel_directions, pixel_solid_angles  # noqa: F401 (used here and by tests)

__all__ = ["pixel_directions", "pixel_solid_angles", "map_integral", "brute_force_irradiance", "luminance_cdf",
           "cell_sums", "direct_split", "light_grid", "pharr", "q2tree", "room_map", "split_parts", "weighted_kmeans", "LUMINANCE"]

#: Rec. 709 luminance weights.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _masked(radiance, valid):
    rad = np.asarray(radiance, np.float64)
    if valid is None:
        return rad
    return np.where(np.asarray(valid)[..., None], rad, 0.0)


def map_integral(radiance, valid=None) -> np.ndarray:
    """(3,) Σ over valid pixels of L · Ω."""
    rad = _masked(radiance, valid)
    om = pixel_solid_angles(*rad.shape[:2])
    return np.sum(rad * om[..., None], axis=(0, 1))


def brute_force_irradiance(radiance, normals, valid=None) -> np.ndarray:
    """(m, 3) E(n) = Σ_p L_p Ω_p max(0, n · d_p): the clamped-cosine convolution of the map at each
    of the (m, 3) unit normals, over every pixel."""
    rad = _masked(radiance, valid)
    H, W = rad.shape[:2]
    d = pixel_directions(H, W).reshape(-1, 3)
    lw = (rad * pixel_solid_angles(H, W)[..., None]).reshape(-1, 3)
    out = np.zeros((len(normals), 3))
    for s in range(0, len(normals), 16):
        cos = np.maximum(np.asarray(normals[s:s + 16], np.float64) @ d.T, 0.0)
        out[s:s + 16] = cos @ lw
    return out


def luminance_cdf(radiance, valid=None) -> np.ndarray:
    """(H·W,) the running sum of Y · Ω in row-major order (invalid pixels add 0)."""
    rad = _masked(radiance, valid)
    y = rad @ LUMINANCE
    return np.cumsum((y * pixel_solid_angles(*rad.shape[:2])).ravel())


def cell_sums(radiance, valid, cell, ncells, depth=None) -> np.ndarray:
    """(ncells, 3) Σ L · Ω per cell (``cell`` (H, W) int), or with depth (ncells, 6): also
    Σ Y·Ω·depth, Σ Ω·depth, Σ Ω over valid pixels."""
    rad = _masked(radiance, valid)
    H, W = rad.shape[:2]
    om = pixel_solid_angles(H, W)
    ok = np.ones((H, W)) if valid is None else np.asarray(valid, np.float64)
    c = np.asarray(cell).ravel()
    cols = [np.bincount(c, (rad[..., k] * om).ravel(), ncells) for k in range(3)]
    if depth is not None:
        dep = np.where(ok > 0, np.asarray(depth, np.float64), 0.0)
        y = rad @ LUMINANCE
        cols += [np.bincount(c, (y * om * dep).ravel(), ncells), np.bincount(c, (om * dep).ravel(), ncells),
                 np.bincount(c, (om * ok).ravel(), ncells)]
    return np.stack(cols, axis=1)


def _radical_inverse(i: int, base: int) -> float:
    out, f = 0.0, 1.0 / base
    while i > 0:
        out += f * (i % base)
        i //= base
        f /= base
    return out


def pharr(radiance, n, valid=None) -> tuple[np.ndarray, np.ndarray]:
    """(directions (n, 3), power (n, 3)): Halton points 1 … n (bases 2, 3) inverted through the
    marginal CDF over rows and the conditional CDF within the row of Y · Ω, one point at a time,
    with continuous offsets inside the pixel; power = L / Y · Σ Y·Ω / n. Map with energy only."""
    rad = _masked(radiance, valid)
    H, W = rad.shape[:2]
    w = (rad @ LUMINANCE) * pixel_solid_angles(H, W)
    row_tot = w.sum(axis=1)
    total = row_tot.sum()
    marginal = np.cumsum(row_tot)
    dirs, power = [], []
    for i in range(1, n + 1):
        u1, u2 = _radical_inverse(i, 2), _radical_inverse(i, 3)
        x1 = u1 * total
        v = int(np.searchsorted(marginal, x1, side="right"))
        lo = marginal[v - 1] if v else 0.0
        fv = (x1 - lo) / row_tot[v]
        cond = np.cumsum(w[v])
        x2 = u2 * row_tot[v]
        u = int(np.searchsorted(cond, x2, side="right"))
        lo2 = cond[u - 1] if u else 0.0
        fu = (x2 - lo2) / w[v, u]
        theta = np.pi * (v + fv) / H
        phi = 2.0 * np.pi * (u + fu) / W - np.pi
        dirs.append([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        L = rad[v, u]
        power.append(L / (L @ LUMINANCE) * total / n)
    return np.array(dirs), np.array(power)


def q2tree(radiance, n, level, valid=None, a=1.0, b=0.25) -> dict:
    """Algorithm 1 of paper 002 one split at a time: {(level, index): (3,) power} of the leaves.

    Quads' powers at each level l ≤ ``level`` come from ``healpy.vec2pix`` at nside 2^l on the pixel
    centres (each pixel wholly in the quad holding its centre). The leaf of highest importance
    Y^a · (π / (3·4^l))^b (ties: lower level, then lower index) is split until there are ≥ n leaves;
    quads at ``level`` are not split."""
    import healpy

    rad = _masked(radiance, valid)
    H, W = rad.shape[:2]
    d = pixel_directions(H, W).reshape(-1, 3)
    lw = (rad * pixel_solid_angles(H, W)[..., None]).reshape(-1, 3)
    sums = []
    for lvl in range(level + 1):
        pix = healpy.vec2pix(2 ** lvl, d[:, 0], d[:, 1], d[:, 2], nest=True)
        sums.append(np.stack([np.bincount(pix, lw[:, k], 12 * 4 ** lvl) for k in range(3)], axis=1))

    def importance(lvl, p):
        return float(sums[lvl][p] @ LUMINANCE) ** a * (np.pi / (3 * 4 ** lvl)) ** b

    heap = [(-importance(0, p), 0, p) for p in range(12)]
    heapq.heapify(heap)
    finest = []
    count = 12
    while count < n and heap:
        _, lvl, p = heapq.heappop(heap)
        for c in range(4):
            child = (lvl + 1, 4 * p + c)
            if child[0] < level:
                heapq.heappush(heap, (-importance(*child), *child))
            else:
                finest.append(child)
        count += 3
    leaves = [(lvl, p) for _, lvl, p in heap] + finest
    return {leaf: sums[leaf[0]][leaf[1]] for leaf in leaves}


def direct_split(radiance, tau, valid=None, basis=None) -> tuple[np.ndarray, float, np.ndarray | None]:
    """The direct part of paper 000's split by a full sort: the valid pixels with positive luminance
    sorted from the brightest down, their energy Y · Ω accumulated until it reaches τ · (1 − 1e-12) of
    the total; every valid pixel at or above the luminance reached is direct. Returns (mask (H, W)
    bool, threshold (inf when none), Σ over direct pixels of radiance × ``basis`` row (K, 3) float64,
    or None without ``basis`` (H·W, K))."""
    rad = np.asarray(radiance, np.float64)
    H, W = rad.shape[:2]
    ok = np.ones((H, W), bool) if valid is None else np.asarray(valid, bool)
    y = LUMINANCE[0] * rad[..., 0] + LUMINANCE[1] * rad[..., 1] + LUMINANCE[2] * rad[..., 2]
    e = y * pixel_solid_angles(H, W)
    total = e[ok].sum()
    mask = np.zeros((H, W), bool)
    threshold = np.inf
    if tau > 0 and total > 0:
        pos = ok & (y > 0)
        yv, ev = y[pos], e[pos]
        order = np.argsort(-yv, kind="stable")
        cum = np.cumsum(ev[order])
        m = min(int(np.searchsorted(cum, tau * total * (1 - 1e-12), side="left")), yv.size - 1)
        threshold = float(yv[order[m]])
        mask = ok & (y >= threshold)
    if basis is None:
        return mask, threshold, None
    b = np.asarray(basis, np.float64).reshape(H * W, -1)
    return mask, threshold, (rad.reshape(-1, 3)[mask.ravel()].T @ b[mask.ravel()]).T


def light_grid(radiance, stride) -> np.ndarray:
    """The pipeline's coarse light grid, pixel by pixel: pixel (v, u) is the map's pixel
    (s // 2 + v·s, s // 2 + u·s), each channel below 0 set to 0 (NaN stays NaN)."""
    rad = np.asarray(radiance)
    H, W = rad.shape[:2]
    o = stride // 2
    rows, cols = range(o, H, stride), range(o, W, stride)
    out = np.empty((len(rows), len(cols), 3), rad.dtype)
    for v, r in enumerate(rows):
        for u, c in enumerate(cols):
            for k in range(3):
                x = rad[r, c, k]
                out[v, u, k] = 0 if x < 0 else x
    return out


def weighted_kmeans(points, weights, centres, iterations) -> tuple[np.ndarray, np.ndarray, int]:
    """Lloyd's k-means with weights, as the virtual area lights run it: (centres (k, 3), labels (N,)
    int64, iterations done).

    Each iteration assigns every point to its nearest centre (the first of equal ones) and moves
    each centre to the weighted mean of its points; a centre that got no weight moves, one after
    the other, to the point of largest weight × squared distance to its nearest centre (the
    distances of this iteration's assignment, each lowered by the centres already moved). It stops
    when no point changes its centre, or after ``iterations``; the labels returned are those of the
    final centres."""
    P = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    c = np.array(centres, np.float64)
    k = len(c)

    def nearest(c):
        e = P[:, None, :] - c[None, :, :]
        d = (e[..., 0] * e[..., 0] + e[..., 1] * e[..., 1]) + e[..., 2] * e[..., 2]
        lab = np.argmin(d, axis=1) if k else np.zeros(len(P), np.int64)
        return lab, d[np.arange(len(P)), lab] if k else np.full(len(P), np.inf)

    labels = np.full(len(P), -1, np.int64)
    done = 0
    for _ in range(iterations):
        new, d2 = nearest(c)
        if np.array_equal(new, labels):
            break
        labels = new
        done += 1
        wsum = np.zeros(k)
        sums = np.zeros((k, 3))
        for i in range(len(P)):  # in point order, as the kernel adds them
            j = labels[i]
            wsum[j] += w[i]
            sums[j] += w[i] * P[i]
        for j in range(k):
            if wsum[j] > 0:
                c[j] = sums[j] / wsum[j]
        for j in range(k):
            if wsum[j] > 0:
                continue
            i = int(np.argmax(w * d2))
            c[j] = P[i]
            e = P - c[j]
            d2 = np.minimum(d2, (e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1]) + e[:, 2] * e[:, 2])
    labels, _ = nearest(c)
    return c, labels, done


def room_map(height: int = 128, width: int = 256, lamp: float = 200.0, seed: int = 0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A test scene: the equirect map seen from (0, 0, 1) in a 4 × 5 × 2.9 m room (floor z = 0,
    ceiling z = 2.9): dim textured walls, a brown floor, a bright window (x = 2 wall, 1.6 × 1.2 m) and
    a small warm ceiling lamp (radius 0.15 m at (0.4, −0.3, 2.9), 1.9 m above the origin).

    Returns (radiance (H, W, 3) float32, depth_m (H, W) float32 Euclidean distances, origin (3,))."""
    rng = np.random.default_rng(seed)
    origin = np.array([0.0, 0.0, 1.0])
    d = pixel_directions(height, width)
    lo = np.array([-2.0, -2.5, 0.0]) - origin
    hi = np.array([2.0, 2.5, 2.9]) - origin
    with np.errstate(divide="ignore", invalid="ignore"):
        t_axis = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf))
    t = t_axis.min(axis=-1)
    axis = t_axis.argmin(axis=-1)
    p = origin + d * t[..., None]
    rad = np.empty((height, width, 3))
    base = 0.08 + 0.04 * np.sin(3 * p[..., 0]) * np.cos(2 * p[..., 1]) + 0.01 * rng.random((height, width))
    rad[:] = base[..., None] * np.array([1.0, 0.95, 0.85])
    floor = (axis == 2) & (d[..., 2] < 0)
    rad[floor] = np.array([0.12, 0.08, 0.05]) * (1 + 0.1 * rng.random((floor.sum(), 1)))
    window = (axis == 0) & (d[..., 0] > 0) & (np.abs(p[..., 1]) < 0.8) & (p[..., 2] > 0.9) & (p[..., 2] < 2.1)
    rad[window] = np.array([2.5, 2.8, 3.2])
    lamp_px = (axis == 2) & (d[..., 2] > 0) & (np.hypot(p[..., 0] - 0.4, p[..., 1] + 0.3) < 0.15)
    rad[lamp_px] = lamp * np.array([1.0, 0.85, 0.6])
    return rad.astype(np.float32), t.astype(np.float32), origin


def split_parts(points, weights, m) -> list[np.ndarray]:
    """The parts of a virtual area light (:mod:`rgbd_envmap.lights.areas`): index arrays of ``m``
    parts of ``points`` (N, 3) of about equal ``weights``, in the order the cuts make them.

    A group that is to hold p > 1 parts and has more than one point is cut in two: along the first
    world axis (x, y, z) whose weighted spread Σ w (q − μ)² is at least 0.8 of the largest, its
    points sorted by that coordinate (stable), at the prefix whose weight is nearest ⌈p/2⌉ / p of the
    group's (the first prefix reaching it, or one point fewer if that is nearer; at least one point
    on each side). The first ⌈p/2⌉ parts come from the lower side, then the rest from the upper; a
    group of one part, or of one point, is a part (and p − 1 empty ones). Zero total weight counts
    every point as 1. Every sum is taken point after point in the group's order (``np.cumsum``), as
    the kernel adds them."""
    P = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    todo = [(np.arange(len(P)), int(m))]
    out = []
    while todo:
        idx, parts = todo.pop()
        if parts == 1 or len(idx) <= 1:
            out.append(idx)
            out.extend(np.zeros(0, np.int64) for _ in range(parts - 1))
            continue
        q = P[idx]
        ww = w[idx]
        if not np.cumsum(ww)[-1] > 0:
            ww = np.ones(len(idx))
        tw = np.cumsum(ww)[-1]
        mu = np.cumsum(ww[:, None] * q, axis=0)[-1] / tw
        var = np.cumsum(ww[:, None] * ((q - mu) * (q - mu)), axis=0)[-1]
        axis = int(np.flatnonzero(var >= 0.8 * var.max())[0])
        order = np.argsort(q[:, axis], kind="stable")
        cum = np.cumsum(ww[order])
        a = (parts + 1) // 2
        target = tw * a / parts
        cut = int(np.searchsorted(cum, target, side="left")) + 1
        if cut > 1 and target - cum[cut - 2] < cum[min(cut, len(cum)) - 1] - target:
            cut -= 1
        cut = min(max(cut, 1), len(idx) - 1)
        todo.append((idx[order[cut:]], parts - a))
        todo.append((idx[order[:cut]], a))
    return out
