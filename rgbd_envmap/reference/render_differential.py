"""Reference of the differential composite
(:func:`rgbd_envmap.render.composite.composite_differential`), with whole-image numpy operations.

Per pixel, in this order of precedence:

- the object (``object_layer.mask``): its colour c (reference space) becomes M⁻¹ c (M⁻¹ the inverse
  correction matrix; none: c), encoded to 8-bit sRGB;
- a real surface near the object (``receiver_layer.mask``): the frame decoded to linear x becomes
  M⁻¹ (ratio ⊙ (M x)), ratio the receiver layer's colour (E_with / E_without per channel in the
  reference space, M = the correction matrix), left unchanged where the ratio is within
  ``RATIO_EPS`` = 1e-3 of 1 in every channel (far from the object, where it is 1 up to rounding);
- else where the shadow plane has alpha a > 0 (the fallback where the map has no geometry): the
  paper-003 blend (1 − a) x + a M⁻¹ (g, g, g);
- elsewhere the frame is unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.colour import srgb8_to_linear_lut
from rgbd_envmap.reference.render_composite import encode_srgb8
from rgbd_envmap.render.layer import Layer

__all__ = ["RATIO_EPS", "composite_differential", "cone_rays", "faces_touching", "light_irradiance", "light_weights",
           "ray_sh_sums", "receiver_ratio_terms", "shadow_ray_candidates"]

RATIO_EPS = 1e-3


def _apply(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(n, 3) rows x ↦ M x, each sum written out in the kernel's order (bit-identical results)."""
    return np.stack([m[k, 0] * x[:, 0] + m[k, 1] * x[:, 1] + m[k, 2] * x[:, 2] for k in range(3)], axis=1)


def composite_differential(frame_srgb: np.ndarray, object_layer: Layer, receiver_layer: Layer, *,
                           ccm_inverse: np.ndarray | None = None, shadow_grey: float = 0.15) -> np.ndarray:
    """The (H, W, 3) uint8 frame with the object and its effect on the real surfaces drawn over it."""
    out = np.array(frame_srgb, np.uint8, copy=True)
    m_inv = np.eye(3) if ccm_inverse is None else np.asarray(ccm_inverse, np.float64)
    m = np.linalg.inv(m_inv)
    lut = srgb8_to_linear_lut()
    obj = object_layer.mask
    out[obj] = encode_srgb8(_apply(m_inv, object_layer.colour[obj].astype(np.float64)))
    rec = ~obj & receiver_layer.mask & ~(np.abs(receiver_layer.colour.astype(np.float64) - 1.0) <= RATIO_EPS).all(axis=-1)
    x = lut[out[rec]].astype(np.float64)
    ratio = receiver_layer.colour[rec].astype(np.float64)
    out[rec] = encode_srgb8(_apply(m_inv, _apply(m, x) * ratio))
    plane = ~obj & ~receiver_layer.mask & (object_layer.plane_alpha > 0)
    a = object_layer.plane_alpha[plane].astype(np.float64)[:, None]
    grey = m_inv @ np.full(3, float(shadow_grey))
    out[plane] = encode_srgb8((1.0 - a) * lut[out[plane]].astype(np.float64) + a * grey)
    return out


def light_weights(points, normals, positions, directions, origin) -> np.ndarray:
    """The irradiance per unit power each light gives each point, one pair at a time: (N, n) with,
    for light j with a finite position p_j (``positions`` (n, 3) or None), I_j max(0, n·Δ) / |Δ|³,
    Δ = p_j − x, |Δ|² at least 1e-12, I_j = |p_j − origin|² (a point light whose power is its
    radiant intensity spread as the map saw it from its origin); for a light without one,
    max(0, n·d_j) (a distant light)."""
    import math

    pts, nrm = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    dirs = np.asarray(directions, np.float64)
    out = np.zeros((len(pts), len(dirs)))
    for j in range(len(dirs)):
        p = None if positions is None else np.asarray(positions[j], np.float64)
        positioned = p is not None and bool(np.isfinite(p).all())
        if positioned:
            o = np.asarray(origin, np.float64)
            intensity = float(np.sum((p - o) ** 2))
        for i in range(len(pts)):
            x, m = pts[i], nrm[i]
            if positioned:
                d0, d1, d2 = float(p[0] - x[0]), float(p[1] - x[1]), float(p[2] - x[2])
                c = float(m[0]) * d0 + float(m[1]) * d1 + float(m[2]) * d2
                if c > 0.0:
                    r2 = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-12)
                    out[i, j] = c * (intensity / (r2 * math.sqrt(r2)))
            else:
                c = float(m[0]) * float(dirs[j, 0]) + float(m[1]) * float(dirs[j, 1]) + float(m[2]) * float(dirs[j, 2])
                out[i, j] = c if c > 0.0 else 0.0
    return out


def shadow_ray_candidates(origins, positions, has_pos, directions, centre, radius, cull) -> tuple:
    """The shadow rays :func:`rgbd_envmap.render.differential.light_visibility` casts, one (point,
    light) pair at a time: (rows, cols, vectors) in point-major order. The ray of point i and light j
    runs from ``origins[i]`` by v = ``positions[j]`` − origins[i] (``has_pos[j]``) or 1 km along
    ``directions[j]``; with ``cull`` it is kept only if the segment passes within ``radius`` of
    ``centre``: t = clip(w·v / max(|v|², 1e-300), 0, 1) with w = centre − origins[i], and
    |w − t v|² ≤ radius²."""
    org, pos, dirs = (np.asarray(a, np.float64) for a in (origins, positions, directions))
    c = np.asarray(centre, np.float64)
    rows, cols, vecs = [], [], []
    for i in range(len(org)):
        x = org[i]
        w0, w1, w2 = float(c[0] - x[0]), float(c[1] - x[1]), float(c[2] - x[2])
        for j in range(len(has_pos)):
            if has_pos[j]:
                v0, v1, v2 = float(pos[j, 0] - x[0]), float(pos[j, 1] - x[1]), float(pos[j, 2] - x[2])
            else:
                v0, v1, v2 = float(dirs[j, 0] * 1e3), float(dirs[j, 1] * 1e3), float(dirs[j, 2] * 1e3)
            if cull:
                t = (w0 * v0 + w1 * v1 + w2 * v2) / max(v0 * v0 + v1 * v1 + v2 * v2, 1e-300)
                t = min(max(t, 0.0), 1.0)
                g0, g1, g2 = w0 - t * v0, w1 - t * v1, w2 - t * v2
                if not (g0 * g0 + g1 * g1 + g2 * g2 <= radius * radius):
                    continue
            rows.append(i)
            cols.append(j)
            vecs.append((v0, v1, v2))
    return (np.array(rows, np.int64), np.array(cols, np.int64), np.array(vecs, np.float64).reshape(-1, 3))


def light_irradiance(points, normals, positions, directions, origin, power, visible) -> tuple[np.ndarray, np.ndarray]:
    """(without shadows, with them): (N, 3) each, Σ_j w_ij power_j and Σ_j (w_ij v_ij) power_j with
    w from :func:`light_weights` and v_ij = ``visible[i, j]`` as 1.0 / 0.0, the lights added one
    after the other in their order."""
    w = light_weights(points, normals, positions, directions, origin)
    p = np.asarray(power, np.float64)
    v = np.asarray(visible, bool).astype(np.float64)
    out_all = np.zeros((len(w), 3))
    out_visible = np.zeros((len(w), 3))
    for j in range(p.shape[0]):
        out_all = out_all + w[:, j:j + 1] * p[j]
        out_visible = out_visible + (w[:, j] * v[:, j])[:, None] * p[j]
    return out_all, out_visible


def receiver_ratio_terms(t0, t1, coeffs, bt, bc, add0, add1, floor, keep, *, floor_rel: float = 1e-6,
                         high: float = 4.0, eps: float = RATIO_EPS) -> tuple[np.ndarray, np.ndarray]:
    """(ratio (R, 3) float32, far (R,) bool): the receivers' E_with / E_without from their SH
    transfers ``t0``, ``t1`` (K, R) (without / with the object; the first len(``coeffs``) rows meet
    the indirect coefficients), the object's reflected light ``bt`` (Kb, R) · ``bc`` (Kb, 3), the
    lights' terms ``add0``, ``add1`` (R, 3) and the albedo floor ``floor`` (R, 3) or None, of whose
    missed light the object leaves ``keep`` (R,):

        E0 = max(Σ_k t0[k] c_k, 0) + add0,   E1 = (max(Σ_k t1[k] c_k, 0) + Σ_k bt[k] bc_k) + add1,
        m = max(floor − E0, 0),   E0 += m,   E1 += m · keep,

    each Σ in float64 with k ascending from 0. ratio = E1 / E0 where E0 exceeds ``floor_rel`` × the
    largest E0 (else 1: no light to change), clipped to [0, ``high``], as float32; far: the vertices
    with |ratio − 1| > ``eps`` in some channel (the ones that change a pixel)."""
    def sums(t, c):
        t, c = np.asarray(t), np.asarray(c, np.float64)
        s = np.zeros((t.shape[1], 3))
        for k in range(len(c)):
            s = s + t[k].astype(np.float64)[:, None] * c[k][None, :]
        return s

    e0 = np.maximum(sums(t0, coeffs), 0.0) + add0
    e1 = (np.maximum(sums(t1, coeffs), 0.0) + sums(bt, bc)) + add1
    if floor is not None:
        m = np.maximum(np.asarray(floor, np.float64) - e0, 0.0)
        e0 = e0 + m
        e1 = e1 + m * np.asarray(keep, np.float64)[:, None]
    lim = floor_rel * max(float(e0.max(initial=0.0)), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(e0 > lim, e1 / e0, 1.0)
    ratio = np.minimum(np.maximum(r, 0.0), high).astype(np.float32)
    far = (np.abs(ratio.astype(np.float64) - 1.0) > eps).any(axis=1)
    return ratio, far


def faces_touching(faces, far) -> np.ndarray:
    """(F', 3) the rows of ``faces`` (F, 3) with a vertex marked in ``far``, in their order."""
    f = np.asarray(faces)
    far = np.asarray(far, bool)
    return f[far[f].any(axis=1)]


def cone_rays(points, normals, axis, cos_max, pattern, offset, idx) -> tuple:
    """The receivers' occlusion rays: for each receiver i = ``idx[c]`` and each stratified point
    (u0, u1) of ``pattern`` (m, 2), the direction d = cos_t a + sin_t cos φ t + sin_t sin φ b in the
    cone around its unit ``axis`` a with half-angle acos(``cos_max[i]``): cos_t = 1 − u0 (1 − cos_max),
    sin_t = √max(0, 1 − cos_t²), φ = 2π u1, and t = a × h / |a × h| (h the x axis, or the y axis where
    |a_x| ≥ 0.9), b = a × t. Kept where it leaves the front of the surface, n · d > 0. Returns
    (origins points[i] + ``offset`` n (N, 3), directions (N, 3), c (N,) int64, n · d (N,)), receiver by
    receiver, pattern point by pattern point."""
    out_o, out_d, out_c, out_cos = [], [], [], []
    for c, i in enumerate(np.asarray(idx).tolist()):
        a = [float(v) for v in axis[i]]
        h = [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0]
        t = [a[1] * h[2] - a[2] * h[1], a[2] * h[0] - a[0] * h[2], a[0] * h[1] - a[1] * h[0]]
        tn = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        t = [t[0] / tn, t[1] / tn, t[2] / tn]
        b = [a[1] * t[2] - a[2] * t[1], a[2] * t[0] - a[0] * t[2], a[0] * t[1] - a[1] * t[0]]
        n = [float(v) for v in normals[i]]
        for u0, u1 in np.asarray(pattern, np.float64).tolist():
            ct = 1.0 - u0 * (1.0 - float(cos_max[i]))
            st = math.sqrt(max(0.0, 1.0 - ct * ct))
            phi = 2.0 * math.pi * u1
            sc, ss = st * math.cos(phi), st * math.sin(phi)
            d = [ct * a[k] + sc * t[k] + ss * b[k] for k in range(3)]
            cs = n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
            if cs > 0.0:
                out_o.append([float(points[i][k]) + offset * n[k] for k in range(3)])
                out_d.append(d)
                out_c.append(c)
                out_cos.append(cs)
    return (np.array(out_o, np.float64).reshape(-1, 3), np.array(out_d, np.float64).reshape(-1, 3),
            np.array(out_c, np.int64), np.array(out_cos, np.float64))


def ray_sh_sums(dirs, weights, owner, bands: int, n_owners: int) -> tuple[np.ndarray, np.ndarray]:
    """(Σ w_r Y(d_r) per owner (n_owners, bands²), Σ w_r per owner (n_owners,)) over the rays in
    their order, Y the real SH basis at the unit directions d_r: the Legendre part of
    :func:`rgbd_envmap.sh.legendre` times the (x + iy)^m = sin^m θ (cos mφ + i sin mφ) factors, as
    :func:`rgbd_envmap.sh.basis` forms them (without its normalisation of the directions)."""
    from rgbd_envmap.sh import legendre

    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    x, y = d[:, 0], d[:, 1]
    basis = legendre(d[:, 2], bands)
    c, s = np.ones(len(d)), np.zeros(len(d))
    for m in range(1, bands):
        c, s = c * x - s * y, c * y + s * x
        for l in range(m, bands):
            basis[:, l * (l + 1) + m] *= c
            basis[:, l * (l + 1) - m] *= s
    out_sh = np.zeros((n_owners, bands * bands))
    out_w = np.zeros(n_owners)
    for r, (w, o) in enumerate(zip(np.asarray(weights, np.float64).tolist(), np.asarray(owner).tolist())):
        out_w[o] += w
        out_sh[o] += w * basis[r]
    return out_sh, out_w
