"""References of the PRT stage (:mod:`rgbd_envmap.prt`): the quadrature's rays and weights, diffuse
shading and the shadow alpha, in plain numpy.

- :func:`upper_rays`, :func:`blocked_weights`: the rays :func:`rgbd_envmap.prt.compute_transfer`
  casts (one per vertex and direction above the vertex's horizon, cos = n·ω > 0) and the quadrature
  weights it takes from their hits; bit for bit what the library computes.
- :func:`shade_weights`: the float32 weights L_k · albedo / π of :func:`rgbd_envmap.prt.shade`,
  rounded as numpy rounds them; bit for bit.
- :func:`shade`: outgoing radiance (albedo / π) Σ_k L_k T_k in float64. The library sums float32
  products in float32 (vectorised), so it agrees to float32 rounding (relative ~1e-6).
- :func:`shadow_alpha`: alpha = clip(1 − E_with / E_without, 0, 1) in float64, E the luminance of
  the irradiance Σ_k L_k T_k; the library agrees to float32 rounding (≤ 1e-5 absolute).

In every case only the first K = min(transfer columns, coefficients) terms are used.
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.prt import LUMINANCE_WEIGHTS

__all__ = ["blocked_weights", "shade", "shade_weights", "shadow_alpha", "upper_rays"]

#: E_without at or below this fraction of π × the environment's mean luminance gives alpha 0.
ALPHA_TINY = 1e-6


def upper_rays(origins: np.ndarray, dirs: np.ndarray, cos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every (vertex i, direction j) pair with ``cos[i, j] > 0``, in row-major order: the ray
    (origin_i, direction_j) as one float32 row of 6, and the pair's flat index i N + j in ``cos``
    (c, N). Returns ((n, 6) float32, (n,) int64)."""
    i, j = np.nonzero(cos > 0.0)  # row-major
    rays = np.concatenate([origins[i], dirs[j]], axis=1).astype(np.float32)
    return rays, (i * cos.shape[1] + j).astype(np.int64)


def blocked_weights(cos: np.ndarray, flat: np.ndarray, hit: np.ndarray, blocked_part: bool) -> np.ndarray:
    """(c, N) float32 quadrature weights: ``cos`` at the pairs whose ray was blocked (``hit`` ≠ 0)
    when ``blocked_part``, or escaped otherwise; 0 at every other pair."""
    w = np.zeros(cos.shape, np.float32).reshape(-1)
    take = flat[(np.asarray(hit) != 0) == blocked_part]
    w[take] = cos.reshape(-1)[take]
    return w.reshape(cos.shape)


def shade_weights(coeffs: np.ndarray, albedo, K: int) -> np.ndarray:
    """(K, 3) float32 weights L_k · (albedo / π): numpy's promotion decides the rounding (a float32
    albedo is divided by π in float32, a float32 L times a float64 quotient is float64)."""
    a = np.broadcast_to(np.asarray(albedo), (3,))
    return (np.asarray(coeffs)[:K] * (a / math.pi)).astype(np.float32)


def shade(transfer: np.ndarray, coeffs: np.ndarray, albedo) -> np.ndarray:
    """(V, 3) float64 outgoing radiance (albedo / π) Σ_k L_k T_k of (V, m²) transfer vectors."""
    T = np.asarray(transfer, np.float64)
    L = np.asarray(coeffs, np.float64)
    K = min(T.shape[1], L.shape[0])
    return (T[:, :K] @ L[:K]) * (np.broadcast_to(np.asarray(albedo, np.float64), (3,)) / math.pi)


def shadow_alpha(transfer_with: np.ndarray, transfer_without: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """(P,) float64 shadow alpha of the plane vertices: E = luminance of Σ_k L_k T_k with the object
    (``transfer_with``) and without it; alpha = clip(1 − E_with / E_without, 0, 1), and 0 where
    E_without ≤ max(1e-6 · π · L̄, 1e-12), L̄ = |luminance of L_00| · Y_00 the environment's mean
    luminance (no light from above, or SH ringing below zero: the ratio means nothing there)."""
    L = np.asarray(coeffs, np.float64)
    K = min(np.shape(transfer_with)[1], L.shape[0])
    w = L[:K] @ LUMINANCE_WEIGHTS  # luminance of each coefficient
    e_with = np.asarray(transfer_with, np.float64)[:, :K] @ w
    e_without = np.asarray(transfer_without, np.float64)[:, :K] @ w
    tiny = max(ALPHA_TINY * math.pi * abs(w[0]) / math.sqrt(4.0 * math.pi), 1e-12)
    ok = e_without > tiny
    return np.where(ok, np.clip(1.0 - e_with / np.where(ok, e_without, 1.0), 0.0, 1.0), 0.0)
