"""Kernels of the PRT stage: the rays of the transfer quadrature, diffuse shading, shadow alpha.

- :func:`upper_rays`, :func:`blocked_weights`: the rays cast per (vertex, direction) pair above the
  vertex's horizon, and the quadrature weights from their hits (open3d casts the rays in between).
- :func:`shade` (with :func:`shade_weights`, :func:`shade_with_weights`): outgoing radiance
  (albedo / π) Σ_k L_k T_k per vertex, single-threaded: the (V, 25) × (25, 3) product is too small
  for threads.
- :func:`shadow_alpha` (with :func:`luminance_dots`): clip(1 − E_with / E_without, 0, 1) per shadow
  plane vertex.

What they compute, in plain numpy: :mod:`rgbd_envmap.reference.prt`. Called from
:mod:`rgbd_envmap.prt` only.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["upper_rays", "blocked_weights", "shade_weights", "shade", "shade_with_weights", "luminance_dots",
           "shadow_alpha"]


@numba.njit(cache=True)
def upper_rays(origins, dirs, cos):  # pragma: no cover - compiled
    """Rays (origin, direction) for every (vertex, direction) pair with cos > 0, row-major, and the
    flat index of each pair in ``cos``."""
    c, N = cos.shape
    count = 0
    for i in range(c):
        for j in range(N):
            if cos[i, j] > 0.0:
                count += 1
    rays = np.empty((count, 6), dtype=np.float32)
    flat = np.empty(count, dtype=np.int64)
    r = 0
    for i in range(c):
        for j in range(N):
            if cos[i, j] > 0.0:
                rays[r, 0] = origins[i, 0]
                rays[r, 1] = origins[i, 1]
                rays[r, 2] = origins[i, 2]
                rays[r, 3] = dirs[j, 0]
                rays[r, 4] = dirs[j, 1]
                rays[r, 5] = dirs[j, 2]
                flat[r] = i * N + j
                r += 1
    return rays, flat


@numba.njit(cache=True)
def blocked_weights(cos, flat, hit, blocked_part):  # pragma: no cover - compiled
    """(c, N) float32 quadrature weights: cos where a cast ray was blocked (``blocked_part``) or
    cos where it escaped (otherwise), 0 elsewhere."""
    c, N = cos.shape
    w = np.zeros((c, N), dtype=np.float32)
    for r in range(flat.shape[0]):
        if (hit[r] != 0) == blocked_part:
            i = flat[r] // N
            j = flat[r] - i * N
            w[i, j] = cos[i, j]
    return w


@numba.njit(cache=True)
def shade_weights(L, albedo, pi, K):  # pragma: no cover - compiled
    """(3, K) float32 weights L[k, c] · (albedo[c] / π), rounded as numpy's
    ``(L * (albedo / math.pi)).astype(float32)`` rounds them: ``pi`` has albedo's dtype (numpy divides
    a float32 albedo by π in float32), products in the wider of the two dtypes. No fastmath here:
    the division must stay a division."""
    wt = np.empty((3, K), np.float32)
    for c in range(3):
        s = albedo[c] / pi
        for k in range(K):
            wt[c, k] = np.float32(L[k, c] * s)
    return wt


@numba.njit(cache=True)
def shade(T, L, albedo, pi, K, out):  # pragma: no cover - compiled
    """out[v] = Σ_k T[v, k] L[k] · albedo / π, the weights rounded as :func:`shade_weights` says."""
    shade_with_weights(T, shade_weights(L, albedo, pi, K), K, out)


@numba.njit(cache=True, fastmath=True)
def shade_with_weights(T, wt, K, out):  # pragma: no cover - compiled
    """out[v] = Σ_k T[v, k] wt[:, k]; ``wt`` is (3, K) contiguous: reading the weights along k (not the
    (K, 3) table's strided columns) lets the three reductions vectorise."""
    for v in range(T.shape[0]):
        row = T[v]
        r = np.float32(0.0)
        g = np.float32(0.0)
        b = np.float32(0.0)
        for k in range(K):
            t = row[k]
            r += t * wt[0, k]
            g += t * wt[1, k]
            b += t * wt[2, k]
        out[v, 0] = r
        out[v, 1] = g
        out[v, 2] = b


@numba.njit(cache=True, fastmath=True)
def luminance_dots(T, w, out):  # pragma: no cover - compiled
    """out[p] = Σ_k T[p, k] w[k] in float32 (fastmath: SIMD partial sums)."""
    K = w.shape[0]
    for p in range(T.shape[0]):
        acc = np.float32(0.0)
        for k in range(K):
            acc += T[p, k] * w[k]
        out[p] = acc


@numba.njit(cache=True)
def shadow_alpha(T_with, T_without, L, lum, tiny_factor):  # pragma: no cover - compiled
    """:func:`rgbd_envmap.prt.shadow_alpha` after validation: float32 sums like BLAS's (in their own
    order)."""
    K = min(T_with.shape[1], L.shape[0])
    w = np.empty(K, np.float32)
    for k in range(K):  # luminance of each coefficient, float64 then rounded to float32
        w[k] = np.float32(L[k, 0] * lum[0] + L[k, 1] * lum[1] + L[k, 2] * lum[2])
    mean_lum = abs(L[0, 0] * lum[0] + L[0, 1] * lum[1] + L[0, 2] * lum[2]) / np.sqrt(4.0 * np.pi)
    tiny = np.float32(max(tiny_factor * np.pi * mean_lum, 1e-12))  # compared in float32
    P = T_with.shape[0]
    e_with = np.empty(P, np.float32)
    e_without = np.empty(P, np.float32)
    luminance_dots(T_with, w, e_with)
    luminance_dots(T_without, w, e_without)
    alpha = np.empty(P, np.float32)
    for p in range(P):
        ratio = e_with[p] / e_without[p] if e_without[p] > tiny else np.float32(1.0)
        a = np.float32(1.0) - ratio
        a = np.float32(0.0) if a < 0.0 else a  # np.clip(a, 0, 1), NaN (a NaN transfer) passing through
        alpha[p] = np.float32(1.0) if a > 1.0 else a
    return alpha
