"""Kernels of the edge-aware plane-fit denoiser (:mod:`rgbd_envmap.depth.denoise`), called from
that module only.

:func:`plane_fit_rows` is the general kernel (any window): one pass per window offset over each image
row, accumulating the nine sums of the normal equations for the whole row at once (branch-free, so
the loop vectorises), then Cramer's rule per pixel in float64; coordinates are taken relative to the
centre pixel's ray, which keeps the system well conditioned.

:func:`plane_fit_3x3` and :func:`plane_fit_5x5` are the windows the pipeline uses, bit for bit the
general kernel's result (tested): the nine sums stay in registers over the unrolled window
positions and the solve follows in the same vectorised pixel loop, so each pixel is written once;
1/z and the inlier depths are prepared in a ring of padded rows rather than full-image arrays. Two
things keep them fast and exact: flat arrays indexed by offsets (with one view per row LLVM wants
more run-time alias checks than it makes, and leaves the loop scalar), and a run-time zero to start
the sums (see :func:`plane_fit_3x3`). The float64 solve stays, as it sets the bits.

The plain least-squares fit these kernels compute is :func:`rgbd_envmap.reference.denoise.plane_fit_reference`.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["plane_fit_rows", "add_term", "load_ring_row", "centre_fit", "plane_fit_3x3", "plane_fit_5x5"]


@numba.njit(cache=True, fastmath={"reassoc", "contract"})
def plane_fit_rows(z, ok, rx, ry, half, tol_rel, min_inliers, out):  # pragma: no cover - compiled
    """``out`` (a copy of z) gets the fitted depth at pixels with enough inliers."""
    h, w = z.shape
    tol = np.float32(tol_rel)
    q = np.zeros((h, w), np.float32)  # 1/z where measured, 0 elsewhere
    zz = np.zeros((h, w), np.float32)  # z where measured, −inf elsewhere (never an inlier)
    for r in range(h):
        for c in range(w):
            if ok[r, c]:
                q[r, c] = 1.0 / z[r, c]
                zz[r, c] = z[r, c]
            else:
                zz[r, c] = -np.inf
    # nine separate row accumulators (views of one array would alias and keep the loop scalar)
    f4 = np.float32
    sxx, sxy, sx, syy, sy = np.zeros(w, f4), np.zeros(w, f4), np.zeros(w, f4), np.zeros(w, f4), np.zeros(w, f4)
    s1, bx, by, b1 = np.zeros(w, f4), np.zeros(w, f4), np.zeros(w, f4), np.zeros(w, f4)
    for r in range(h):
        sxx[:] = 0.0
        sxy[:] = 0.0
        sx[:] = 0.0
        syy[:] = 0.0
        sy[:] = 0.0
        s1[:] = 0.0
        bx[:] = 0.0
        by[:] = 0.0
        b1[:] = 0.0
        z0 = zz[r]
        x0 = rx[r]
        y0 = ry[r]
        for a in range(max(r - half, 0), min(r + half, h - 1) + 1):
            za = zz[a]
            qa = q[a]
            xa = rx[a]
            ya = ry[a]
            for b in range(-half, half + 1):
                lo = max(0, -b)
                hi = min(w, w - b)
                # aligned views: index i of each is column lo + i of the centre row and lo + i + b
                # of row a (unsigned-free, wrap-free indexing lets the loop vectorise)
                n = hi - lo
                zn = za[lo + b:hi + b]
                qn = qa[lo + b:hi + b]
                xn = xa[lo + b:hi + b]
                yn = ya[lo + b:hi + b]
                zc_ = z0[lo:hi]
                xc_ = x0[lo:hi]
                yc_ = y0[lo:hi]
                axx, axy, ax_, ayy, ay_ = sxx[lo:hi], sxy[lo:hi], sx[lo:hi], syy[lo:hi], sy[lo:hi]
                a1, abx, aby, ab1 = s1[lo:hi], bx[lo:hi], by[lo:hi], b1[lo:hi]
                for i in range(np.uint64(n)):
                    zc = zc_[i]
                    # inlier: both measured (zz = −inf otherwise fails the test) and close in depth
                    m = f4(1.0) if abs(zn[i] - zc) <= tol * zc else f4(0.0)
                    x = (xn[i] - xc_[i]) * m
                    y = (yn[i] - yc_[i]) * m
                    qq = qn[i] * m
                    axx[i] += x * x
                    axy[i] += x * y
                    ax_[i] += x
                    ayy[i] += y * y
                    ay_[i] += y
                    a1[i] += m
                    abx[i] += x * qq
                    aby[i] += y * qq
                    ab1[i] += qq
        for c in range(w):
            if not ok[r, c] or s1[c] < min_inliers:
                continue
            # Cramer's rule on [[sxx, sxy, sx], [sxy, syy, sy], [sx, sy, s1]] (a, b, c) = (bx, by, b1);
            # only c (the fit at the centre, where x = y = 0) is needed.
            # the 3×3 solve in float64 from the float32 sums
            m00, m01, m02 = np.float64(sxx[c]), np.float64(sxy[c]), np.float64(sx[c])
            m11, m12, m22 = np.float64(syy[c]), np.float64(sy[c]), np.float64(s1[c])
            v0, v1, v2 = np.float64(bx[c]), np.float64(by[c]), np.float64(b1[c])
            c00 = m11 * m22 - m12 * m12
            c01 = m12 * m02 - m01 * m22
            c02 = m01 * m12 - m11 * m02
            det = m00 * c00 + m01 * c01 + m02 * c02
            scale = m00 * m11 * m22
            if not abs(det) > 1e-9 * scale or scale == 0.0:  # collinear inliers: no plane
                continue
            pc = (m00 * (m11 * v2 - m12 * v1) - m01 * (m01 * v2 - m12 * v0) + m02 * (m01 * v1 - m11 * v0)) / det
            if pc > 0.0:
                out[r, c] = np.float32(1.0 / pc)


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy")
def add_term(s, zn, qn, xn, yn, zc, xc, yc, t):  # pragma: no cover - compiled
    """The nine sums ``s`` of :func:`plane_fit_3x3` plus one window position's terms, as
    :func:`plane_fit_rows` adds them."""
    sxx, sxy, sx, syy, sy, s1, bx, by, b1 = s
    m = np.float32(1.0) if abs(zn - zc) <= t else np.float32(0.0)
    x = (xn - xc) * m
    y = (yn - yc) * m
    qq = qn * m
    return (sxx + x * x, sxy + x * y, sx + x, syy + y * y, sy + y, s1 + m, bx + x * qq, by + y * qq, b1 + qq)


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy", inline="always")
def load_ring_row(zf, kf, zr, qr, o, q, h, w):  # pragma: no cover - compiled
    """Image row ``q`` into the ring at offset ``o``: z (−inf where unmeasured) and 1/z (0 there);
    a row outside the image is all unmeasured."""
    u = np.uint64
    if 0 <= q < h:
        src = u(q) * u(w)
        for c in range(u(w)):
            v = zf[src + c]
            ok = kf[src + c] and np.isfinite(v) and v > 0.0
            zr[o + c] = v if ok else -np.inf
            qr[o + c] = 1.0 / v if ok else np.float32(0.0)
    else:
        for c in range(u(w)):
            zr[o + c] = -np.inf
            qr[o + c] = 0.0


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy", inline="always")
def centre_fit(s, zc, fallback, min_inliers):  # pragma: no cover - compiled
    """The fitted depth at the window's centre from its nine sums ``s`` (the float64 Cramer's rule of
    :func:`plane_fit_rows`), or ``fallback``; branch-free (a failed test selects the fallback), so
    that the pixel loop vectorises."""
    sxx, sxy, sx, syy, sy, s1, bx, by, b1 = s
    m00, m01, m02 = np.float64(sxx), np.float64(sxy), np.float64(sx)
    m11, m12, m22 = np.float64(syy), np.float64(sy), np.float64(s1)
    v0, v1, v2 = np.float64(bx), np.float64(by), np.float64(b1)
    c00 = m11 * m22 - m12 * m12
    c01 = m12 * m02 - m01 * m22
    c02 = m01 * m12 - m11 * m02
    det = m00 * c00 + m01 * c01 + m02 * c02
    scale = m00 * m11 * m22
    pc = (m00 * (m11 * v2 - m12 * v1) - m01 * (m01 * v2 - m12 * v0) + m02 * (m01 * v1 - m11 * v0)) / det
    fit = (zc > -np.inf) & (s1 >= min_inliers) & (abs(det) > 1e-9 * scale) & (scale != 0.0) & (pc > 0.0)
    return np.float32(1.0 / pc) if fit else fallback


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy")
def plane_fit_3x3(z, known, zero_unknown, rxp, ryp, tol_rel, min_inliers, zero):  # pragma: no cover
    """The 3×3 window (h = 1) of :func:`plane_fit_rows` in one pass, bit for bit its result.

    Returns the (H, W) float32 output: the fit where it succeeds, else ``z``, or 0 where ``known`` is
    False when ``zero_unknown``. Measured: ``known``, finite and > 0. ``rxp`` / ``ryp``: the ray
    planes padded by one pixel. ``zero``: 0.0, a run-time value so that LLVM cannot fold the first
    ``0 + x·x`` into ``x·x``, which would change which product the second addition fuses (FMA) and
    so the sum in its last bit.

    Why it equals the general kernel: the nine window terms are added to each sum in the same order
    (row by row, left to right) with the same contractions (``contract`` only; no ``reassoc``, which
    could reorder a sum held in a register), and a window position outside the image or unmeasured
    adds exact zeros (its depth is −inf in the padded rows, so m = 0), which leave a sum unchanged.
    """
    h, w = z.shape
    f4 = np.float32
    u = np.uint64
    tol = f4(tol_rel)
    z0 = f4(zero)
    wp = u(w + 2)
    out = np.empty((h, w), np.float32)
    # rows r − 1, r, r + 1 of z (−inf where unmeasured or outside) and 1/z (0 there), padded by one
    # column each side, in a ring of three rows. Flat arrays indexed by offsets: all nine loads of
    # z come from one array, so LLVM needs few runtime alias checks and vectorises the pixel loop.
    zr = np.full(3 * (w + 2), -np.inf, np.float32)
    qr = np.zeros(3 * (w + 2), np.float32)
    xf = rxp.reshape(-1)
    yf = ryp.reshape(-1)
    zf = z.reshape(-1)
    kf = known.reshape(-1)
    of = out.reshape(-1)
    for rr in range(-1, h):
        load_ring_row(zf, kf, zr, qr, u((rr + 1) % 3) * wp + u(1), rr + 1, h, w)
        if rr < 0:
            continue
        r = u(rr)
        o0 = u((rr + 2) % 3) * wp  # ring rows r − 1, r, r + 1
        o1 = u(rr % 3) * wp
        o2 = u((rr + 1) % 3) * wp
        p0 = r * wp  # padded ray rows r − 1, r, r + 1
        p1 = p0 + wp
        p2 = p1 + wp
        row = r * u(w)
        for c in range(u(w)):
            c1 = c + u(1)
            c2 = c + u(2)
            zc = zr[o1 + c1]
            xc = xf[p1 + c1]
            yc = yf[p1 + c1]
            t = tol * zc
            s = (z0, z0, z0, z0, z0, z0, z0, z0, z0)
            s = add_term(s, zr[o0 + c], qr[o0 + c], xf[p0 + c], yf[p0 + c], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c1], qr[o0 + c1], xf[p0 + c1], yf[p0 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c2], qr[o0 + c2], xf[p0 + c2], yf[p0 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c], qr[o1 + c], xf[p1 + c], yf[p1 + c], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c1], qr[o1 + c1], xf[p1 + c1], yf[p1 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c2], qr[o1 + c2], xf[p1 + c2], yf[p1 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c], qr[o2 + c], xf[p2 + c], yf[p2 + c], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c1], qr[o2 + c1], xf[p2 + c1], yf[p2 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c2], qr[o2 + c2], xf[p2 + c2], yf[p2 + c2], zc, xc, yc, t)
            fallback = zf[row + c] if (kf[row + c] or not zero_unknown) else f4(0.0)
            of[row + c] = centre_fit(s, zc, fallback, min_inliers)
    return out


@numba.njit(cache=True, fastmath={"contract"}, error_model="numpy")
def plane_fit_5x5(z, known, zero_unknown, rxp, ryp, tol_rel, min_inliers, zero):  # pragma: no cover
    """:func:`plane_fit_3x3` for the 5×5 window (h = 2), bit for bit :func:`plane_fit_rows`'
    result, for the same reasons: the 25 window positions added row by row, left to right, those
    outside the image or unmeasured as exact zeros. A ring of five rows, the rays padded by two.
    The set-up of the arrays is written out as in :func:`plane_fit_3x3`: returned from a shared
    inline helper as a tuple, they cost this kernel its vectorisation."""
    h, w = z.shape
    f4 = np.float32
    u = np.uint64
    tol = f4(tol_rel)
    z0 = f4(zero)
    wp = u(w + 4)
    out = np.empty((h, w), np.float32)
    zr = np.full(5 * (w + 4), -np.inf, np.float32)
    qr = np.zeros(5 * (w + 4), np.float32)
    xf = rxp.reshape(-1)
    yf = ryp.reshape(-1)
    zf = z.reshape(-1)
    kf = known.reshape(-1)
    of = out.reshape(-1)
    for rr in range(-2, h):
        load_ring_row(zf, kf, zr, qr, u((rr + 2) % 5) * wp + u(2), rr + 2, h, w)
        if rr < 0:
            continue
        r = u(rr)
        o0 = u((rr + 3) % 5) * wp  # ring rows r − 2 … r + 2
        o1 = u((rr + 4) % 5) * wp
        o2 = u(rr % 5) * wp
        o3 = u((rr + 1) % 5) * wp
        o4 = u((rr + 2) % 5) * wp
        p0 = r * wp  # padded ray rows r − 2 … r + 2
        p1 = p0 + wp
        p2 = p1 + wp
        p3 = p2 + wp
        p4 = p3 + wp
        row = r * u(w)
        for c in range(u(w)):
            c1 = c + u(1)
            c2 = c + u(2)
            c3 = c + u(3)
            c4 = c + u(4)
            zc = zr[o2 + c2]
            xc = xf[p2 + c2]
            yc = yf[p2 + c2]
            t = tol * zc
            s = (z0, z0, z0, z0, z0, z0, z0, z0, z0)
            s = add_term(s, zr[o0 + c], qr[o0 + c], xf[p0 + c], yf[p0 + c], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c1], qr[o0 + c1], xf[p0 + c1], yf[p0 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c2], qr[o0 + c2], xf[p0 + c2], yf[p0 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c3], qr[o0 + c3], xf[p0 + c3], yf[p0 + c3], zc, xc, yc, t)
            s = add_term(s, zr[o0 + c4], qr[o0 + c4], xf[p0 + c4], yf[p0 + c4], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c], qr[o1 + c], xf[p1 + c], yf[p1 + c], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c1], qr[o1 + c1], xf[p1 + c1], yf[p1 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c2], qr[o1 + c2], xf[p1 + c2], yf[p1 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c3], qr[o1 + c3], xf[p1 + c3], yf[p1 + c3], zc, xc, yc, t)
            s = add_term(s, zr[o1 + c4], qr[o1 + c4], xf[p1 + c4], yf[p1 + c4], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c], qr[o2 + c], xf[p2 + c], yf[p2 + c], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c1], qr[o2 + c1], xf[p2 + c1], yf[p2 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c2], qr[o2 + c2], xf[p2 + c2], yf[p2 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c3], qr[o2 + c3], xf[p2 + c3], yf[p2 + c3], zc, xc, yc, t)
            s = add_term(s, zr[o2 + c4], qr[o2 + c4], xf[p2 + c4], yf[p2 + c4], zc, xc, yc, t)
            s = add_term(s, zr[o3 + c], qr[o3 + c], xf[p3 + c], yf[p3 + c], zc, xc, yc, t)
            s = add_term(s, zr[o3 + c1], qr[o3 + c1], xf[p3 + c1], yf[p3 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o3 + c2], qr[o3 + c2], xf[p3 + c2], yf[p3 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o3 + c3], qr[o3 + c3], xf[p3 + c3], yf[p3 + c3], zc, xc, yc, t)
            s = add_term(s, zr[o3 + c4], qr[o3 + c4], xf[p3 + c4], yf[p3 + c4], zc, xc, yc, t)
            s = add_term(s, zr[o4 + c], qr[o4 + c], xf[p4 + c], yf[p4 + c], zc, xc, yc, t)
            s = add_term(s, zr[o4 + c1], qr[o4 + c1], xf[p4 + c1], yf[p4 + c1], zc, xc, yc, t)
            s = add_term(s, zr[o4 + c2], qr[o4 + c2], xf[p4 + c2], yf[p4 + c2], zc, xc, yc, t)
            s = add_term(s, zr[o4 + c3], qr[o4 + c3], xf[p4 + c3], yf[p4 + c3], zc, xc, yc, t)
            s = add_term(s, zr[o4 + c4], qr[o4 + c4], xf[p4 + c4], yf[p4 + c4], zc, xc, yc, t)
            fallback = zf[row + c] if (kf[row + c] or not zero_unknown) else f4(0.0)
            of[row + c] = centre_fit(s, zc, fallback, min_inliers)
    return out
