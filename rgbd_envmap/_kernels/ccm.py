"""Kernels of the colour-correction matrix (:mod:`rgbd_envmap.colour.ccm`), called from that module only.

:func:`ccm_sums` accumulates the normal-equation sums of the pairs in one pass; :func:`fit_sums`
solves the column-equilibrated 3×3 normal equations (or the ridge system) from them through a
Jacobi eigendecomposition (:func:`sym3_eigh`), written out rather than numba's LAPACK wrappers, whose
compilation takes many seconds on a fresh machine. What they compute is the plain least-squares fit
:func:`rgbd_envmap.reference.colour.ccm_least_squares_reference`; the tests compare the two, and the
eigensolver with numpy's.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["RANK_RTOL", "ccm_sums", "sym3_eigh", "equilibrated", "eigen_solve", "fit_sums"]

#: Below this smallest / largest eigenvalue ratio of the equilibrated normal matrix the system counts as
#: numerically rank-deficient (float64 normal equations keep no significant digit along that direction).
RANK_RTOL = 1e-12


@numba.njit(cache=True, error_model="numpy")
def ccm_sums(src: np.ndarray, dst: np.ndarray, saturation: float):
    """One pass over (N, 3) src / dst: the normal-equation sums AᵀA, AᵀB and tr(BᵀB) in float64 over
    the rows kept, plus the counts kept / dropped as non-finite / dropped as saturated (any src channel
    ≥ ``saturation``). Scalar accumulators keep the loop in registers."""
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    t00 = t01 = t02 = t10 = t11 = t12 = t20 = t21 = t22 = 0.0
    bb = 0.0
    n = 0
    n_nonfinite = 0
    n_saturated = 0
    for i in range(src.shape[0]):
        a0 = np.float64(src[i, 0])
        a1 = np.float64(src[i, 1])
        a2 = np.float64(src[i, 2])
        b0 = np.float64(dst[i, 0])
        b1 = np.float64(dst[i, 1])
        b2 = np.float64(dst[i, 2])
        if not (
            math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
            and math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)
        ):
            n_nonfinite += 1
            continue
        if a0 >= saturation or a1 >= saturation or a2 >= saturation:
            n_saturated += 1
            continue
        n += 1
        s00 += a0 * a0
        s01 += a0 * a1
        s02 += a0 * a2
        s11 += a1 * a1
        s12 += a1 * a2
        s22 += a2 * a2
        t00 += a0 * b0
        t01 += a0 * b1
        t02 += a0 * b2
        t10 += a1 * b0
        t11 += a1 * b1
        t12 += a1 * b2
        t20 += a2 * b0
        t21 += a2 * b1
        t22 += a2 * b2
        bb += b0 * b0 + b1 * b1 + b2 * b2
    ata = np.empty((3, 3))
    ata[0, 0], ata[0, 1], ata[0, 2] = s00, s01, s02
    ata[1, 0], ata[1, 1], ata[1, 2] = s01, s11, s12
    ata[2, 0], ata[2, 1], ata[2, 2] = s02, s12, s22
    atb = np.empty((3, 3))
    atb[0, 0], atb[0, 1], atb[0, 2] = t00, t01, t02
    atb[1, 0], atb[1, 1], atb[1, 2] = t10, t11, t12
    atb[2, 0], atb[2, 1], atb[2, 2] = t20, t21, t22
    return ata, atb, bb, n, n_nonfinite, n_saturated


@numba.njit(cache=True)
def sym3_eigh(a):  # pragma: no cover - compiled
    """Eigenvalues (ascending) and eigenvectors (columns) of a symmetric 3×3 matrix by cyclic Jacobi
    rotations, each zeroing one off-diagonal entry (quadratic convergence: 4–6 sweeps). Written out
    rather than numba's LAPACK wrappers, which are slow to compile on a fresh machine; small
    eigenvalues of positive semi-definite matrices come out with high relative accuracy."""
    m = a.copy()
    v = np.eye(3)
    for _ in range(60):
        off = m[0, 1] * m[0, 1] + m[0, 2] * m[0, 2] + m[1, 2] * m[1, 2]
        diag = m[0, 0] * m[0, 0] + m[1, 1] * m[1, 1] + m[2, 2] * m[2, 2]
        if not off > 1e-36 * diag:  # also ends on NaN
            break
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            apq = m[p, q]
            if apq == 0.0:
                continue
            theta = (m[q, q] - m[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            t = -t if theta < 0.0 else t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            m[p, p] -= t * apq
            m[q, q] += t * apq
            m[p, q] = m[q, p] = 0.0
            arp, arq = m[r, p], m[r, q]
            m[r, p] = m[p, r] = c * arp - s * arq
            m[r, q] = m[q, r] = s * arp + c * arq
            for k in range(3):
                vkp, vkq = v[k, p], v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    w = np.array([m[0, 0], m[1, 1], m[2, 2]])
    # Ascending by insertion, as numba's argsort orders three values (its sort is slow to compile);
    # the sums reaching here are finite.
    i0, i1, i2 = 0, 1, 2
    if w[i1] < w[i0]:
        i0, i1 = i1, i0
    if w[i2] < w[i1]:
        i1, i2 = i2, i1
        if w[i1] < w[i0]:
            i0, i1 = i1, i0
    order = np.array([i0, i1, i2])
    return w[order], v[:, order]


@numba.njit(cache=True)
def equilibrated(ata):  # pragma: no cover - compiled
    """(d, condition, eigenvalues, eigenvectors of C) with ata = diag(d) C diag(d) and C's
    diagonal 1 (zero columns keep d = 1). The condition number of C is invariant to per-channel
    gains of src, i.e. to exposure and white balance, so one threshold serves every frame."""
    d = np.empty(3)
    for i in range(3):
        d[i] = math.sqrt(ata[i, i]) if ata[i, i] > 0.0 else 1.0
    c = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            c[i, j] = ata[i, j] / (d[i] * d[j])
    w, v = sym3_eigh(c)
    cond = math.inf if w[0] <= RANK_RTOL * w[2] else w[2] / w[0]
    return d, cond, w, v


@numba.njit(cache=True)
def eigen_solve(w, v, rhs, rtol):  # pragma: no cover - compiled
    """V diag(1/w) Vᵀ rhs, eigenvalues at or below rtol · the largest taken as zero (the
    pseudo-inverse, i.e. the minimum-norm solution, when the matrix is singular)."""
    inv = np.zeros(3)
    for i in range(3):
        if w[i] > rtol * w[2]:
            inv[i] = 1.0 / w[i]
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += v[i, k] * inv[k] * (v[0, k] * rhs[0, j] + v[1, k] * rhs[1, j] + v[2, k] * rhs[2, j])
            out[i, j] = acc
    return out


@numba.njit(cache=True)
def fit_sums(ata, atb, bb, n, ridge):  # pragma: no cover - compiled
    """The fit of :func:`rgbd_envmap.colour.estimate_ccm` from its sums: (matrix, mse, condition,
    well posed), in one compiled call (cheaper than the same 3×3 operations in numpy).
    ``ridge`` < 0: plain least squares through the column-equilibrated normal equations, the
    pseudo-inverse (minimum-norm solution) when they are not well posed, as a best effort;
    ``ridge`` > 0: the ridge fit, whose conditioning gate applies to the regularised system (rank
    deficiency of the data itself still counts). Solves go through the Jacobi eigendecomposition
    (:func:`sym3_eigh`); the matrices agree with LAPACK's solve to rounding (tests)."""
    d, cond, w, v = equilibrated(ata)
    well_posed = math.isfinite(cond)
    lam = ridge * (ata[0, 0] + ata[1, 1] + ata[2, 2]) / 3.0
    if lam > 0.0:
        reg = ata.copy()
        rhs = atb.copy()
        for i in range(3):
            reg[i, i] += lam
            rhs[i, i] += lam * atb[i, i] / max(ata[i, i], 1e-300)
        cond = equilibrated(reg)[1]
        wr, vr = sym3_eigh(reg)
        x = eigen_solve(wr, vr, rhs, 0.0)
        well_posed = well_posed and math.isfinite(cond)
    else:
        rhs = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                rhs[i, j] = atb[i, j] / d[i]
        y = eigen_solve(w, v, rhs, RANK_RTOL)
        x = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                x[i, j] = y[i, j] / d[i]
    sse = bb
    for i in range(3):
        for j in range(3):
            xax = 0.0
            for k in range(3):
                xax += ata[i, k] * x[k, j]
            sse += x[i, j] * (xax - 2.0 * atb[i, j])
    mse = max(sse, 0.0) / (3.0 * n) if math.isfinite(sse) else math.nan
    return x.T.copy(), mse, cond, well_posed
