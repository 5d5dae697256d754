"""Kernels of the receivers' occlusion by the object (:func:`rgbd_envmap.render.differential.receiver_occlusion`),
called from that module only.

Each receiver vertex casts m stratified rays into the cone of the object's bounding sphere; the
rays the object blocks add their weight to the vertex's share F of blocked cosine-weighted light and
their weight × the SH basis to its blocked transfer B_k. numpy built the rays as (N, m, 3)
temporaries (a dozen of them, then an index gather for the front-facing ones) and the basis of every
blocked ray as an (N, n²) table before a sparse product summed it per vertex: a third of the
rebuild's time. Here one pass writes the front-facing rays, and one pass sums weight × basis per
vertex without the table.

What they compute, one ray at a time in plain Python: :func:`rgbd_envmap.reference.render_differential.cone_rays`
and :func:`~rgbd_envmap.reference.render_differential.ray_sh_sums`; the tests compare each pair bit for
bit (no fastmath: the same operations in the same order) and against :func:`rgbd_envmap.render.differential.cone_directions`
and :func:`rgbd_envmap.sh.basis` to rounding.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["cone_rays_kernel", "ray_sh_sums_kernel"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def cone_rays_kernel(points, normals, axis, cos_max, pattern, offset, idx, org, dirs, owner, cosines):  # pragma: no cover - compiled
    """For each receiver ``idx[c]`` and each point (u0, u1) of ``pattern`` (m, 2): the direction
    cos_t · a + sin_t cos φ · t + sin_t sin φ · b in the cone around its unit ``axis`` a of half-angle
    acos(``cos_max``), with cos_t = 1 − u0 (1 − cos_max), sin_t = √max(0, 1 − cos_t²), φ = 2π u1 and
    (t, b) completing a: t = a × h / |a × h| (h = x if |a_x| < 0.9 else y), b = a × t. The rays that
    leave the front of the surface (n · d > 0) are written in order: origin point + ``offset`` · n,
    the direction, c (``owner``) and n · d (``cosines``). Returns how many; the outputs hold
    len(idx) · m rows."""
    m = pattern.shape[0]
    two_pi = 2.0 * math.pi
    j = 0
    for c in range(idx.shape[0]):
        i = idx[c]
        a0, a1, a2 = axis[i, 0], axis[i, 1], axis[i, 2]
        if abs(a0) < 0.9:
            h0, h1, h2 = 1.0, 0.0, 0.0
        else:
            h0, h1, h2 = 0.0, 1.0, 0.0
        t0 = a1 * h2 - a2 * h1
        t1 = a2 * h0 - a0 * h2
        t2 = a0 * h1 - a1 * h0
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / tn, t1 / tn, t2 / tn
        b0 = a1 * t2 - a2 * t1
        b1 = a2 * t0 - a0 * t2
        b2 = a0 * t1 - a1 * t0
        n0, n1, n2 = normals[i, 0], normals[i, 1], normals[i, 2]
        one_minus = 1.0 - cos_max[i]
        for s in range(m):
            ct = 1.0 - pattern[s, 0] * one_minus
            st = math.sqrt(max(0.0, 1.0 - ct * ct))
            phi = two_pi * pattern[s, 1]
            sc = st * math.cos(phi)
            ss = st * math.sin(phi)
            d0 = ct * a0 + sc * t0 + ss * b0
            d1 = ct * a1 + sc * t1 + ss * b1
            d2 = ct * a2 + sc * t2 + ss * b2
            cs = n0 * d0 + n1 * d1 + n2 * d2
            if cs > 0.0:
                org[j, 0] = points[i, 0] + offset * n0
                org[j, 1] = points[i, 1] + offset * n1
                org[j, 2] = points[i, 2] + offset * n2
                dirs[j, 0] = d0
                dirs[j, 1] = d1
                dirs[j, 2] = d2
                owner[j] = c
                cosines[j] = cs
                j += 1
    return j


@numba.njit(cache=True, nogil=True, error_model="numpy")
def ray_sh_sums_kernel(dirs, weights, owner, bands, out_sh, out_w):  # pragma: no cover - compiled
    """For each ray r in order: ``out_w[owner[r]]`` += w_r and ``out_sh[owner[r], k]`` += w_r · Y_k(d_r)
    for the real SH basis of ``bands`` bands at the unit direction ``dirs[r]`` (k = l(l + 1) + m,
    Condon–Shortley phase: :func:`rgbd_envmap.sh.basis`), from the recurrences of
    :func:`rgbd_envmap.sh.legendre` on Q_lm = K_lm P_l^m / sin^m θ and (x + iy)^m."""
    n = bands
    q = np.empty(n * n)
    y = np.empty(n * n)
    inv_sqrt4pi = 1.0 / math.sqrt(4.0 * math.pi)
    sqrt2 = math.sqrt(2.0)
    for r in range(dirs.shape[0]):
        x, yy, z = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        w = weights[r]
        o = owner[r]
        # the Legendre part, as sh.legendre
        q_mm = inv_sqrt4pi
        for m in range(n):
            if m > 0:
                q_mm = -math.sqrt((2 * m + 1) / (2 * m)) * q_mm
            scale = sqrt2 if m > 0 else 1.0
            q_prev2 = 0.0
            q_prev = q_mm
            for l in range(m, n):
                if l == m:
                    v = q_mm
                elif l == m + 1:
                    v = math.sqrt(2 * m + 3) * z * q_mm
                else:
                    a = math.sqrt((4 * l * l - 1) / (l * l - m * m))
                    b = math.sqrt(((l - 1) ** 2 - m * m) / (4 * (l - 1) ** 2 - 1))
                    v = a * (z * q_prev - b * q_prev2)
                if l > m:
                    q_prev2, q_prev = q_prev, v
                k0 = l * (l + 1)
                q[k0 + m] = scale * v
                if m > 0:
                    q[k0 - m] = scale * v
        # × cos mφ / sin mφ sin^m θ, as sh.basis
        for k in range(n * n):
            y[k] = q[k]
        c, s = 1.0, 0.0
        for m in range(1, n):
            c, s = c * x - s * yy, c * yy + s * x
            for l in range(m, n):
                k0 = l * (l + 1)
                y[k0 + m] *= c
                y[k0 - m] *= s
        out_w[o] += w
        for k in range(n * n):
            out_sh[o, k] += w * y[k]
