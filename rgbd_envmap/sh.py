"""Real spherical harmonics: basis, projection of equirect maps, Lambertian irradiance (paper 003 §7.1).

Convention (DESIGN.md §3, docs/CONVENTIONS.md):

- The basis is **real** and **orthonormal** over the sphere, with the **Condon–Shortley phase**
  included in the associated Legendre functions P_l^m. For l ≥ 0 and 0 < m ≤ l::

      Y_l,0  = K_l0 P_l^0(cos θ)
      Y_l,m  = √2 K_lm P_l^m(cos θ) cos(mφ)
      Y_l,-m = √2 K_lm P_l^m(cos θ) sin(mφ)
      K_lm   = sqrt((2l + 1) / (4π) · (l − m)! / (l + m)!)

  with θ the polar angle from +z and φ the azimuth from +x towards +y.
- Flat index **k = l(l + 1) + m**. "n bands" means l = 0 … n − 1, n² functions; the default is 5 bands.
- Coefficient arrays are **(n², 3)** float64: index k, then linear RGB.

The first 9 functions, for a unit vector d = (x, y, z):

    ===  ========  ===========================
     k    (l, m)    Y_lm(d)
    ===  ========  ===========================
     0    (0, 0)    0.282095
     1    (1, −1)   −0.488603 y
     2    (1, 0)    0.488603 z
     3    (1, 1)    −0.488603 x
     4    (2, −2)   1.092548 xy
     5    (2, −1)   −1.092548 yz
     6    (2, 0)    0.315392 (3z² − 1)
     7    (2, 1)    −1.092548 xz
     8    (2, 2)    0.546274 (x² − y²)
    ===  ========  ===========================

Evaluation uses no trigonometry of angles: sin^m θ cos(mφ) and sin^m θ sin(mφ) are the real and
imaginary parts of (x + iy)^m, and the remaining polynomial in z = cos θ comes from the standard
stable three-term recurrence on the *normalised* functions (no factorials, no overflow), so any number
of bands ≥ 1 works.

Projection of an equirect map is separable: Y_k at pixel (v, u) is a row factor (Legendre part,
depends on v) times a column factor (cos(mφ_u) or sin(|m|φ_u)). So each row is first reduced to its
2n − 1 longitude sums (float32, one row at a time, in a numba kernel that folds the four columns
sharing |cos mφ|, |sin mφ|; see the comment above ``_row_sums_folded``), and the rows are then
combined in float64 with the Legendre weights times the exact row solid angle. The tables depend only
on (H, W, bands) and are cached. Planar (3, H, W) storage (``EnvironmentMap``) is read in place.
docs/sh.md describes the algorithm and its measured cost.

Missing pixels (DESIGN.md §4 stage 8): a pixel with ``valid = False`` takes the radiance of the
closest data pixel along the 4-connected directions (up, down, left, right) within 50 pixels.
Longitude wraps across the seam; rows do not wrap across the poles. Ties at the same distance are
broken in the fixed order up, down, left, right. A pixel with no data pixel within 50 steps in any of
the four directions is skipped (contributes nothing).

Invalid input:

- ``basis`` / ``irradiance``: a zero-length or non-finite direction gives a **NaN row** (like
  ``geometry.directions_to_equirect``); it does not raise, so one bad normal does not spoil a batch.
- Wrong shapes raise :class:`ShapeError`; ``bands < 1`` raises :class:`RangeError`; a non-integer
  ``bands`` raises :class:`DTypeError`.
- ``project_equirect`` / ``project_planar``: NaN or infinity in the radiance at a pixel that
  contributes (valid pixels, or every pixel when ``valid`` is None) raises :class:`NonFiniteError`.
  Values under ``valid = False`` are never used except as fill sources (which are valid by
  definition), so they may be NaN. An empty map (H or W = 0) raises :class:`ShapeError`; a map with
  no data at all gives zero coefficients.
  ``irradiance``: non-finite coefficients raise :class:`NonFiniteError`.
- ``select_bands``: see its docstring (zero shading is reported, not raised).

References:
    - P.-P. Sloan, "Stupid Spherical Harmonics (SH) Tricks", GDC 2008 (basis, sign convention).
    - R. Ramamoorthi and P. Hanrahan, "An Efficient Representation for Irradiance Environment Maps",
      SIGGRAPH 2001 (clamped-cosine band factors Â_l).
    - Paper 003 §7.1 (25 coefficients per channel from the EM; filling of missing EM pixels).
    - P.-P. Sloan, J. Kautz, J. Snyder, "Precomputed Radiance Transfer for Real-Time Rendering in
      Dynamic, Low-Frequency Lighting Environments", SIGGRAPH 2002 (transfer vectors, used by
      ``select_bands``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from rgbd_envmap._intrinsics import _prefetch
from rgbd_envmap.checks import check_array, check_finite, check_positive_int
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    ShapeError,
)
from rgbd_envmap.geometry import equirect_solid_angles

__all__ = [
    "FILL_RADIUS_PX",
    "BandSelection",
    "TransferGram",
    "basis",
    "fill_missing",
    "irradiance",
    "lambertian_band_factors",
    "n_bands",
    "project_equirect",
    "project_planar",
    "IncrementalProjection",
    "select_bands",
    "transfer_gram",
]

FILL_RADIUS_PX = 50
"""Largest distance, in pixels along one of the 4 directions, from which a missing EM pixel is filled
(DESIGN.md §4 stage 8)."""


# --- Legendre part ----------------------------------------------------------------------------------

def _legendre_scaled(z: np.ndarray, bands: int) -> np.ndarray:
    """(..., bands²) float64 array A with A[..., k] = c_m K_l|m| P_l^|m|(z) / sin^|m| θ for k = (l, m),
    c_m = √2 for m ≠ 0 else 1 (the same value at ±m). Condon–Shortley phase included.

    Recurrence on normalised functions Q_lm = K_lm P_l^m / sin^m θ:
    Q_00 = 1/√(4π); Q_mm = −√((2m + 1) / (2m)) Q_{m−1,m−1}; Q_{m+1,m} = √(2m + 3) z Q_mm;
    Q_lm = a_lm (z Q_{l−1,m} − b_lm Q_{l−2,m}), a = √((4l² − 1)/(l² − m²)),
    b = √(((l − 1)² − m²)/(4(l − 1)² − 1)).
    """
    out = np.empty(z.shape + (bands * bands,), dtype=np.float64)
    q_mm = np.full(z.shape, 1.0 / math.sqrt(4.0 * math.pi))
    for m in range(bands):
        if m > 0:
            q_mm = -math.sqrt((2 * m + 1) / (2 * m)) * q_mm
        scale = math.sqrt(2.0) if m > 0 else 1.0
        q_prev2 = None
        q_prev = q_mm
        for l in range(m, bands):
            if l == m:
                q = q_mm
            elif l == m + 1:
                q = math.sqrt(2 * m + 3) * z * q_mm
            else:
                a = math.sqrt((4 * l * l - 1) / (l * l - m * m))
                b = math.sqrt(((l - 1) ** 2 - m * m) / (4 * (l - 1) ** 2 - 1))
                q = a * (z * q_prev - b * q_prev2)
            if l > m:
                q_prev2, q_prev = q_prev, q
            k0 = l * (l + 1)
            out[..., k0 + m] = scale * q
            if m > 0:
                out[..., k0 - m] = scale * q
    return out


def n_bands(n_coeffs: int) -> int:
    """Number of bands n for n² coefficients; :class:`ShapeError` unless ``n_coeffs`` is a square ≥ 1."""
    n = math.isqrt(int(n_coeffs))
    if n < 1 or n * n != n_coeffs:
        raise ShapeError(f"coeffs: expected n² rows (1, 4, 9, 16, 25, ...), got {n_coeffs}")
    return n


def basis(dirs: np.ndarray, bands: int = 5) -> np.ndarray:
    """Real SH basis at directions.

    Args:
        dirs: (..., 3) float directions; need not be unit length (normalised here). A zero-length or
            non-finite direction gives a NaN row.
        bands: number of bands n ≥ 1 (l = 0 … n − 1).

    Returns:
        (..., n²) float64, column k = l(l + 1) + m.

    Example:
        >>> basis(np.array([0.0, 0.0, 1.0]), bands=2).round(6)
        array([ 0.282095, -0.      ,  0.488603, -0.      ])
    """
    bands = check_positive_int(bands, "bands")
    d = check_array(dirs, "dirs", shape=("*", 3), dtype=("float", "int")).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt(np.einsum("...i,...i->...", d, d))
        bad = ~np.isfinite(norm) | (norm == 0.0)
        d = d / np.where(bad, 1.0, norm)[..., None]
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    if bad.any():
        x, y, z = (np.where(bad, 0.0, t) for t in (x, y, z))  # keep NaN out of the arithmetic
    out = _legendre_scaled(z, bands)
    # (x + iy)^m = sin^m θ (cos mφ + i sin mφ), built up by complex multiplication.
    c = np.ones_like(x)
    s = np.zeros_like(x)
    for m in range(1, bands):
        c, s = c * x - s * y, c * y + s * x
        for l in range(m, bands):
            k0 = l * (l + 1)
            out[..., k0 + m] *= c
            out[..., k0 - m] *= s
    if bad.any():
        out[bad] = np.nan
    return out


def lambertian_band_factors(bands: int) -> np.ndarray:
    """(bands,) float64 clamped-cosine factors Â_l = (π, 2π/3, π/4, 0, −π/24, 0, π/64, …)
    (Ramamoorthi & Hanrahan 2001, eq. 8): Â_l = 2π (−1)^(l/2 − 1) / ((l + 2)(l − 1)) · C(l, l/2) / 2^l
    for even l ≥ 2, 0 for odd l > 1."""
    bands = check_positive_int(bands, "bands")
    a = np.zeros(bands)
    a[0] = math.pi
    if bands > 1:
        a[1] = 2.0 * math.pi / 3.0
    for l in range(2, bands, 2):
        a[l] = (2.0 * math.pi * (-1) ** (l // 2 - 1) / ((l + 2) * (l - 1))
                * math.comb(l, l // 2) / 2.0 ** l)
    return a


def irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance E(n) = Σ_l Â_l Σ_m L_lm Y_lm(n) of an SH radiance environment.

    Args:
        coeffs: (n², 3) radiance coefficients (linear RGB), finite.
        normals: (..., 3) surface normals (normalised here; zero / non-finite → NaN row).

    Returns:
        (..., 3) float64 irradiance. Outgoing Lambertian radiance is (albedo / π) · E.
    """
    L = check_array(coeffs, "coeffs", shape=("K", 3), dtype=("float", "int"), finite=True)
    bands = n_bands(L.shape[0])
    normals = check_array(normals, "normals", shape=("*", 3), dtype=("float", "int"))
    a = lambertian_band_factors(bands)
    l_of_k = np.repeat(np.arange(bands), 2 * np.arange(bands) + 1)
    return basis(normals, bands) @ (a[l_of_k, None] * L.astype(np.float64))


# --- missing-pixel fill (stage 8) ---------------------------------------------------------------------
#
# The fill is planned once from the mask, then applied while each row is staged for the projection,
# so no filled copy of the map is ever written. The plan lists the missing pixels row by row with the
# flat index of the data pixel each one copies (−1: none within the radius). Cost: one pass over the
# mask 8 pixels (one uint64) at a time, counting the missing pixels of each row, then O(1) work per
# missing pixel: the vertical source comes from per-column state carried down (then up) the list of
# missing pixels (the run of missing pixels above a pixel shares its data row), the horizontal one
# from the runs of missing columns in the row. A missing polar cap therefore costs O(1) per pixel,
# not a 50-step search per pixel.

_NO_KEY = np.iinfo(np.int32).max  # fill key of a missing pixel without a source
_ALL_VALID = np.uint64(0x0101010101010101)  # eight bool bytes, all True
_BYTE_SUM = np.uint64(0x0101010101010101)  # the top byte of x · this is the sum of x's eight bytes


@numba.njit(cache=True)
def _fill_plan(bytes_, words, H, W, radius):  # pragma: no cover - compiled
    """bytes_: (H, W8) uint8 view of the bool mask (columns ≥ W padded True), words: its (H, W8 / 8)
    uint64 view (used only to skip and count eight pixels at a time, so byte order does not matter).

    Returns (row_ptr (H + 1,) int64, col (n,) int32, src (n,) int64, empty (H,) bool, key (n,)
    int32): the missing pixels of row v are col[row_ptr[v]:row_ptr[v + 1]] (increasing); src is the
    flat index v' W + u' of the data pixel each copies, or −1; ``empty[v]``: row v contributes
    nothing (no pixel has or gets data), so the projection skips it without reading it; key =
    4 · distance + direction (0 up, 1 down, 2 left, 3 right), the order the rule ranks sources in
    (:data:`_NO_KEY` without a source)."""
    nw = words.shape[1]
    sh56 = np.uint64(56)
    # 1. missing pixels per row: 8 − (sum of the eight 0/1 bytes), the byte sum by one multiply
    row_ptr = np.zeros(H + 1, np.int64)
    for v in range(H):
        cnt = 0
        for w in range(nw):
            x = words[v, w]
            if x != _ALL_VALID:
                cnt += 8 - np.int64((x * _BYTE_SUM) >> sh56)
        row_ptr[v + 1] = row_ptr[v] + cnt
    n = row_ptr[H]
    col = np.empty(n + 8, np.int32)
    src = np.full(n, -1, np.int64)
    dist = np.full(n, radius + 1, np.int32)
    key = np.full(n, _NO_KEY, np.int32)
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
            if x != _ALL_VALID:
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
def _apply_fill(rad, row_ptr, col, src, out, used):  # pragma: no cover - compiled
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


def _plan(valid: np.ndarray, radius_px: int) -> tuple[np.ndarray, ...]:
    H, W = valid.shape
    if W % 8:
        valid = np.pad(valid, ((0, 0), (0, 8 - W % 8)), constant_values=True)
    b = np.ascontiguousarray(valid).view(np.uint8)
    return _fill_plan(b, b.view(np.uint64), H, W, radius_px)


def fill_missing(radiance: np.ndarray, valid: np.ndarray, radius_px: int = FILL_RADIUS_PX
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing EM pixels from the closest data pixel along up / down / left / right.

    :func:`project_equirect` applies the same rule row by row without building this filled copy;
    this function is for looking at the result.

    Args:
        radiance: (H, W, 3) float linear radiance; values under ``valid = False`` are not used (NaN
            is fine there).
        valid: (H, W) bool, True where the EM has data.
        radius_px: largest search distance in pixels (50 in the paper).

    Returns:
        (filled (H, W, 3) float32, used (H, W) bool). ``used`` is False for pixels with no data pixel
        within ``radius_px`` in any of the 4 directions; their ``filled`` value is 0. Longitude wraps;
        rows do not cross the poles; equal distances prefer up, down, left, right in that order.
    """
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    valid = check_array(valid, "valid", shape=rad.shape[:2], dtype="bool")
    radius_px = check_positive_int(radius_px, "radius_px")
    row_ptr, col, src, _, _ = _plan(valid, radius_px)
    out = rad.astype(np.float32, order="C")  # a copy; its missing pixels are overwritten below
    used = np.ones(rad.shape[:2], bool)
    _apply_fill(rad, row_ptr, col, src, out, used)
    return out, used


# --- projection ---------------------------------------------------------------------------------------
#
# Per row and channel the kernel needs the 2n − 1 longitude sums Σ_u r(u) cos(mφ_u), Σ_u r(u) sin(mφ_u).
# Pixel-centre azimuths are symmetric: columns u, W − 1 − u have azimuths ±φ, and columns u, u ± W/2
# differ by π, so with W divisible by 4 the four columns q, W − 1 − q, W/2 − 1 − q, W/2 + q share
# |cos mφ|, |sin mφ| up to the signs (−1)^m and ±1. Folding them first (4 loads, 8 adds) leaves one
# multiply-add per quarter of the row per (m, cos/sin). Each row is first copied to a small buffer
# (a sequential read that the hardware prefetcher streams; the folded loads run backwards and would
# not be prefetched well), missing pixels are filled in that buffer, and the fold + sums run from L1
# with 10 float32 accumulators per pass of 5 orders m (blocks of 5: one pass for the default 5 bands).

_BLOCK = 5
# Reassociation lets LLVM vectorise the float32 reductions. No 'nnan' / 'ninf': NaN and inf must
# propagate into the sums, the finiteness check of the result relies on it.
_FASTMATH = {"reassoc", "contract"}
_U0 = np.uint64(0)
_U1 = np.uint64(1)
_U2 = np.uint64(2)
_U4 = np.uint64(4)


@numba.njit(fastmath=_FASTMATH, inline="always", cache=True)
def _row_sums_folded(r, tcb, tsb, o):  # pragma: no cover - compiled
    """o[m, 0] = Σ_u cos(mφ_u) r[u], o[m, 1] = Σ_u sin(mφ_u) r[u] for m < 5 · nblocks; W % 4 == 0.
    tcb, tsb: (nblocks, 5, W/4) cos / sin of mφ_q at the first quarter's azimuths."""
    # unsigned indices: numba's negative-index wrap on signed ones blocks vectorisation of r[W − 1 − q]
    W = np.uint64(r.shape[0])
    Q = W // _U4
    h = W // _U2
    for j in range(tcb.shape[0]):
        tc = tcb[j]
        ts = tsb[j]
        # m = 5j + i: the parity of m flips with j; scaling the second pair by sg swaps the
        # even / odd combinations instead of branching.
        sg = np.float32(1.0) if j % 2 == 0 else np.float32(-1.0)
        c0 = c1 = c2 = c3 = c4 = np.float32(0.0)
        s0 = s1 = s2 = s3 = s4 = np.float32(0.0)
        for q in range(Q):
            a = r[q]
            b = r[W - _U1 - q]
            c = r[h - _U1 - q]
            d = r[h + q]
            p1 = a + b
            p2 = sg * (c + d)
            m1 = a - b
            m2 = sg * (d - c)
            ce = p1 + p2
            co = p1 - p2
            se = m1 + m2
            so = m1 - m2
            c0 += tc[0, q] * ce
            c1 += tc[1, q] * co
            c2 += tc[2, q] * ce
            c3 += tc[3, q] * co
            c4 += tc[4, q] * ce
            s0 += ts[0, q] * se
            s1 += ts[1, q] * so
            s2 += ts[2, q] * se
            s3 += ts[3, q] * so
            s4 += ts[4, q] * se
        k = _BLOCK * j
        o[k, 0] = c0
        o[k + 1, 0] = c1
        o[k + 2, 0] = c2
        o[k + 3, 0] = c3
        o[k + 4, 0] = c4
        o[k, 1] = s0
        o[k + 1, 1] = s1
        o[k + 2, 1] = s2
        o[k + 3, 1] = s3
        o[k + 4, 1] = s4


@numba.njit(fastmath=_FASTMATH, inline="always", cache=True)
def _row_sums_plain(r, tcb, tsb, o):  # pragma: no cover - compiled
    """As :func:`_row_sums_folded` for any W; tables (nblocks, 5, W)."""
    W = r.shape[0]
    for j in range(tcb.shape[0]):
        tc = tcb[j]
        ts = tsb[j]
        c0 = c1 = c2 = c3 = c4 = np.float32(0.0)
        s0 = s1 = s2 = s3 = s4 = np.float32(0.0)
        for u in range(W):
            x = r[u]
            c0 += tc[0, u] * x
            c1 += tc[1, u] * x
            c2 += tc[2, u] * x
            c3 += tc[3, u] * x
            c4 += tc[4, u] * x
            s0 += ts[0, u] * x
            s1 += ts[1, u] * x
            s2 += ts[2, u] * x
            s3 += ts[3, u] * x
            s4 += ts[4, u] * x
        k = _BLOCK * j
        o[k, 0] = c0
        o[k + 1, 0] = c1
        o[k + 2, 0] = c2
        o[k + 3, 0] = c3
        o[k + 4, 0] = c4
        o[k, 1] = s0
        o[k + 1, 1] = s1
        o[k + 2, 1] = s2
        o[k + 3, 1] = s3
        o[k + 4, 1] = s4


@numba.njit(fastmath=_FASTMATH, inline="always", cache=True)
def _accumulate_row(buf, v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs):  # pragma: no cover
    if folded:
        _row_sums_folded(buf, tcb, tsb, sums)
    else:
        _row_sums_plain(buf, tcb, tsb, sums)
    for k in range(row_w.shape[1]):
        coeffs[k, c] += row_w[v, k] * np.float64(sums[m_abs[k], m_sin[k]])


@numba.njit(fastmath=_FASTMATH, cache=True)
def _project_planar(planes, row_ptr, col, src, empty, tcb, tsb, folded, row_w, m_abs, m_sin):  # pragma: no cover
    H, W = planes.shape[1:]  # 3 planes
    coeffs = np.zeros((row_w.shape[1], 3), np.float64)
    buf = np.empty((3, W), np.float32)
    b0 = buf[0]
    b1 = buf[1]
    b2 = buf[2]
    sums = np.empty((tcb.shape[0] * _BLOCK, 2), np.float32)
    flat = planes.reshape(3, H * W)
    f0 = flat[0]
    f1 = flat[1]
    f2 = flat[2]
    for v in range(H):  # three sequential streams, one per plane
        if empty[v]:
            continue
        r0 = planes[0, v]
        r1 = planes[1, v]
        r2 = planes[2, v]
        for u in range(W):
            b0[u] = r0[u]
        for u in range(W):
            b1[u] = r1[u]
        for u in range(W):
            b2[u] = r2[u]
        for k in range(row_ptr[v], row_ptr[v + 1]):
            s = src[k]
            u = col[k]
            if s >= 0:
                b0[u] = f0[s]
                b1[u] = f1[s]
                b2[u] = f2[s]
            else:
                b0[u] = np.float32(0.0)
                b1[u] = np.float32(0.0)
                b2[u] = np.float32(0.0)
        for c in range(3):
            _accumulate_row(buf[c], v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs)
    return coeffs


@numba.njit(fastmath=_FASTMATH, cache=True)
def _project_interleaved(rad, row_ptr, col, src, empty, tcb, tsb, folded, row_w, m_abs, m_sin):  # pragma: no cover
    H, W = rad.shape[:2]  # 3 channels
    coeffs = np.zeros((row_w.shape[1], 3), np.float64)
    buf = np.empty((3, W), np.float32)
    b0 = buf[0]
    b1 = buf[1]
    b2 = buf[2]
    sums = np.empty((tcb.shape[0] * _BLOCK, 2), np.float32)
    rows = rad.reshape(H, W * 3)
    flat = rad.reshape(H * W * 3)
    u3 = np.uint64(3)
    for v in range(H):
        if empty[v]:
            continue
        r = rows[v]
        for u in range(np.uint64(W)):  # de-interleave into channel rows (unsigned: vectorises)
            i = u3 * u
            b0[u] = r[i]
            b1[u] = r[i + _U1]
            b2[u] = r[i + _U2]
        for k in range(row_ptr[v], row_ptr[v + 1]):
            s = src[k]
            u = col[k]
            for c in range(3):
                buf[c, u] = flat[3 * s + c] if s >= 0 else np.float32(0.0)
        for c in range(3):
            _accumulate_row(buf[c], v, c, tcb, tsb, folded, row_w, m_abs, m_sin, sums, coeffs)
    return coeffs


@lru_cache(maxsize=8)
def _projection_tables(height: int, width: int, bands: int):
    """Cached, read-only tables for the projection (they depend only on the map size and bands).

    Returns (tcb, tsb, folded, row_w, m_abs, m_sin):
        tcb, tsb: (nblocks, 5, L) float32 cos(mφ), sin(mφ) for m = 5j + i (zero for m ≥ bands), at
            the first quarter of the columns (L = W/4, ``folded``) or at every column (L = W).
        row_w: (H, n²) float64, the Legendre part of Y_k at each row (incl. sin^|m| θ and √2) times
            the exact solid angle of one pixel of that row.
        m_abs, m_sin: (n²,) int64, where the row sum used by coefficient k sits: sums[|m|, m < 0].
    """
    n = bands
    folded = width % 4 == 0
    nblocks = -(-n // _BLOCK)
    ncols = width // 4 if folded else width
    phi = 2.0 * np.pi * (np.arange(ncols) + 0.5) / width - np.pi
    m = np.arange(nblocks * _BLOCK)
    tcb = np.cos(m[:, None] * phi[None, :])
    tsb = np.sin(m[:, None] * phi[None, :])
    tcb[n:] = 0.0
    tsb[n:] = 0.0
    tcb = tcb.astype(np.float32).reshape(nblocks, _BLOCK, ncols)
    tsb = tsb.astype(np.float32).reshape(nblocks, _BLOCK, ncols)
    theta = np.pi * (np.arange(height) + 0.5) / height
    leg = _legendre_scaled(np.cos(theta), n)
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(n)])
    leg *= np.sin(theta)[:, None] ** np.abs(m_of_k)[None, :]
    row_w = leg * equirect_solid_angles(height, width)[:, :1]
    m_abs = np.abs(m_of_k).astype(np.int64)
    m_sin = (m_of_k < 0).astype(np.int64)
    for a in (tcb, tsb, row_w, m_abs, m_sin):
        a.setflags(write=False)
    return tcb, tsb, folded, row_w, m_abs, m_sin


_NO_MISSING = (np.zeros(0, np.int32), np.zeros(0, np.int64))  # (col, src) of an empty fill plan


def _project(data: np.ndarray, planar: bool, valid: np.ndarray | None, bands: int, radius_px: int,
             name: str = "radiance") -> np.ndarray:
    """``data`` is C-contiguous float32, (3, H, W) when ``planar`` else (H, W, 3); checked already."""
    H, W = data.shape[1:] if planar else data.shape[:2]
    if valid is None:
        row_ptr, (col, src), empty = np.zeros(H + 1, np.int64), _NO_MISSING, np.zeros(H, bool)
    else:
        row_ptr, col, src, empty, _ = _plan(valid, radius_px)
    tables = _projection_tables(H, W, bands)
    kernel = _project_planar if planar else _project_interleaved
    coeffs = kernel(data, row_ptr, col, src, empty, *tables)
    if not np.isfinite(coeffs).all():  # NaN / inf propagate into the sums (cheap path otherwise)
        where = "" if valid is None else " (at valid pixels)"
        chans = [data[c] if planar else data[..., c] for c in range(3)]
        for ch in chans:
            check_finite(ch if valid is None else ch[valid], name + where)
        raise NonFiniteError(f"{name}: the projection overflowed float32/float64; scale the map down")
    return coeffs


def _check_map_size(H: int, W: int, name: str) -> None:
    if H == 0 or W == 0:
        raise ShapeError(f"{name}: expected a non-empty map, got {H}×{W} pixels")


def project_equirect(radiance: np.ndarray, valid: np.ndarray | None = None, bands: int = 5, *,
                     fill_radius_px: int = FILL_RADIUS_PX) -> np.ndarray:
    """SH coefficients L_k = Σ_p Y_k(d_p) radiance_p Ω_p of an equirect radiance map.

    Args:
        radiance: (H, W, 3) float linear radiance. Fast paths (no copy): float32 C-contiguous, and
            float32 whose channel axis is outermost in memory, i.e. the (H, W, 3) view of planar
            (3, H, W) storage such as ``EnvironmentMap.radiance``. Anything else is converted to
            float32 first. Directions and exact solid angles follow docs/CONVENTIONS.md.
        valid: (H, W) bool or None (every pixel has data). Missing pixels are filled as in
            DESIGN.md §4 stage 8 (see :func:`fill_missing`); pixels that cannot be filled are skipped.
            A map with no data at all gives zero coefficients.
        bands: number of bands n ≥ 1.
        fill_radius_px: the fill's search radius in pixels (paper: 50).

    Returns:
        (n², 3) float64 coefficients. Row sums over longitude are float32 (relative error ~1e-7),
        rows are combined in float64.

    Raises:
        ShapeError: wrong shapes or an empty map. RangeError / DTypeError: bad ``bands`` or
        ``fill_radius_px``. NonFiniteError: NaN or infinity at a contributing pixel (or a sum that
        overflows).
    """
    bands = check_positive_int(bands, "bands")
    radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    H, W = rad.shape[:2]
    _check_map_size(H, W, "radiance")
    if valid is not None:
        valid = check_array(valid, "valid", shape=(H, W), dtype="bool")
    planes = rad.transpose(2, 0, 1)
    if rad.dtype == np.float32 and planes.flags.c_contiguous:
        return _project(planes, True, valid, bands, radius_px)
    return _project(np.ascontiguousarray(rad, dtype=np.float32), False, valid, bands, radius_px)


def project_planar(planes: np.ndarray, valid: np.ndarray | None = None, bands: int = 5, *,
                   fill_radius_px: int = FILL_RADIUS_PX) -> np.ndarray:
    """:func:`project_equirect` for planar (3, H, W) radiance (the storage of ``EnvironmentMap``).

    Args:
        planes: (3, H, W) float linear radiance; float32 C-contiguous is used without a copy.
        valid, bands, fill_radius_px: as for :func:`project_equirect`.

    Returns:
        (n², 3) float64 coefficients, identical to ``project_equirect(planes.transpose(1, 2, 0), ...)``.
    """
    bands = check_positive_int(bands, "bands")
    radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
    p = check_array(planes, "planes", shape=(3, "H", "W"), dtype=("float", "int"))
    H, W = p.shape[1:]
    _check_map_size(H, W, "planes")
    if valid is not None:
        valid = check_array(valid, "valid", shape=(H, W), dtype="bool")
    return _project(np.ascontiguousarray(p, dtype=np.float32), True, valid, bands, radius_px, "planes")


# --- incremental projection of a map that is being updated --------------------------------------------
#
# c_k = Σ_p w_p Y_k(p) L̃(p), L̃ the filled map, is linear in the map. Between two frames the update
# writes ~50k of 2M pixels, while a full projection reads every pixel and re-plans ~0.8M missing ones
# (11 ms on the default session). The tracker keeps the coefficients and, per pixel, the fill state
# as one rank key (data / 4 · distance + direction of the source it copies / none; the key names the
# source, so no index is stored: one byte per pixel for radii ≤ 62), and applies the map's change log:
#
# A. a pixel that had data changes colour by Δ: c += Δ ⊗ w Y at the pixel and at every missing pixel
#    that copies it; those lie on the four straight runs of missing pixels that start next to it
#    (a source is the closest data pixel along its line, so everything between is missing);
# B. a pixel gets data: its fill contribution (if any) is replaced by its own;
# C. missing pixels near a new data pixel may now copy it: walk the four runs of missing pixels from
#    it (≤ radius) and switch each pixel whose current source ranks worse (distance, then up, down,
#    left, right as in the rule): c += w Y (L_new − L_old source).
#
# Valid pixels only appear (the update never removes data), so A–C keep the state equal to a fresh
# plan; anything else (the log overflowed, the arrays were edited, another map) rebuilds in full.
#
# Cost (default session, median frame: 35k colour changes, 3k new data pixels, 9k switched fills):
# per change, staging Δ and cos φ, sin φ (a scalar loop: its loads are gathers), then 30 multiply-
# adds vectorised over a row's changes (_reduce_row). Adding changes one by one to their row's sums
# in memory through a (W, 2n − 1) cos / sin table cost ~40 ns each (C's switched fills did that
# before). Walks are rare in A (~150 written pixels a frame have a missing neighbour).
# Per phase (cycle counters in a probe copy, 94 incremental frames × 3 replays, cache evicted
# between frames as the pipeline's other stages do; median / mean ms per frame, previous version →
# this one, two runs each): A's staging and neighbour checks 0.63–0.69 / 1.03–1.09 → 0.53 / 0.80
# (prefetching, below); the rows' _reduce_row 0.17 / 0.23–0.25 → 0.10 / 0.14 (first block from
# e^{i0φ} = 1); C's walks, with their flushes, 0.10–0.11 / 0.59–0.64 → 0.06–0.07 / 0.37 (skip
# pixels inside new patches, prefetch); B's list and A's walks 0.05 / 0.14 → 0.04–0.05 / 0.12; all
# flushes: sort and stage 0.01–0.02 / 0.15–0.17 → 0.01 / 0.12, reduction 0.02 / 0.17–0.19 → 0.01 /
# 0.13. The whole update 1.94–2.03 → 1.44–1.49 ms median. Tried, not kept: staging and neighbour
# checks in two loops (LLVM then vectorises the staging with gathers: A 0.54–0.56 → 0.69–0.96 ms
# median), vectorising the records' reduction (changes the rounding, see _reduce_row), prefetching
# only every 2nd or 4th change, or the state rows above and of the pixel too (within noise).

# How far ahead (log entries in A, new data pixels in C) _apply_changes prefetches the map and the
# fill state. Between two SH updates the pipeline's other stages evict the 2 MB fill state from the
# cache, and the hardware prefetcher does not follow the sparse, row-skipping reads (measured on
# the default session, cache evicted between frames as in the pipeline: 1.66 → 1.40 ms median per
# update, 1.87 ms before any change of this version; 16 ahead ~10 % slower, 48 and 64 within noise).
_AHEAD = np.uint64(32)
_KEY_DATA = 0  # fill key of a pixel with data (a source's key is 4 · distance + direction ≥ 4)


def _key_dtype(radius: int) -> type:
    """The smallest unsigned type whose largest value (the key of a missing pixel without a source)
    is above every rank key 4 · radius + 3: one byte per pixel up to radius 62 (the paper's 50)."""
    for dt in (np.uint8, np.uint16, np.uint32):
        if 4 * radius + 3 < np.iinfo(dt).max:
            return dt
    raise RangeError(f"fill_radius_px: expected < 2³⁰, got {radius}")


@numba.njit(cache=True, inline="always")
def _source(p, u, kk, W):  # pragma: no cover - compiled
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


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _reduce_block(st, i0, i1, a, j, first, store):  # pragma: no cover - compiled
    """One block of 5 orders (sums a[:, j:j + 10]) of :func:`_reduce_row`. ``first``, ``store``:
    constants after inlining, so each combination is its own branch-free loop. The first block
    starts from e^{i0φ} = 1 instead of loading it (the previous version staged 1, 0 for every change
    and multiplied by them): its order-1 term is (cos φ, sin φ) itself, exactly what 1 · c − 0 · s
    gave, and the sin(0φ) sum, which no coefficient uses, is skipped. ``store`` writes the next
    block's first order to st[2], st[3]."""
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
        for i in range(2 * _BLOCK):
            r[j + i] += t[i]


@numba.njit(cache=True, fastmath=_FASTMATH, inline="always")
def _reduce_row(st, i0, i1, a, records):  # pragma: no cover - compiled
    """a (3, P) += the longitude sums of the changes st[:, i0:i1], all in one row. ``st`` (7, N):
    cos φ_u, sin φ_u, cos, sin of the block's first order m (blocks after the first only; written
    here), Δ per channel. The other orders of a block come from the first by complex
    multiplication by e^{iφ}, so the loop needs no table lookups (gathers) and the 30 sums stay in
    registers.

    ``records`` (a constant): the records' loop in :func:`_flush` always stores the next block's
    start, as the previous version did; that store (st may alias its inputs) keeps LLVM from
    vectorising it, and so keeps its rounding: vectorised, its sums reassociate across SIMD lanes
    (measured: coefficients differ by up to 2.6e-16 relative on the default session, for ~0.1 ms
    on frames with ~20k records). A row's own changes (``records`` False) vectorise either way, with
    the same lanes as before; with 5 bands their loop stores nothing (measured: the row reductions
    0.17 → 0.10 ms at the median frame, results bit for bit unchanged)."""
    nb = a.shape[1] // (2 * _BLOCK)
    if nb == 1 and not records:
        _reduce_block(st, i0, i1, a, 0, True, False)
    else:
        _reduce_block(st, i0, i1, a, 0, True, True)
        for j in range(1, nb):
            _reduce_block(st, i0, i1, a, 2 * _BLOCK * j, False, True)


@numba.njit(cache=True, inline="always")
def _stage(st, i, phi1, u, d0, d1, d2):  # pragma: no cover - compiled
    """Stage change i for :func:`_reduce_row`: cos φ_u, sin φ_u and Δ (st[2], st[3] are its own)."""
    st[0, i] = phi1[u, 0]
    st[1, i] = phi1[u, 1]
    st[4, i] = d0
    st[5, i] = d1
    st[6, i] = d2


@numba.njit(cache=True, fastmath=_FASTMATH)
def _flush(rec_v, rec_u, rec_d, nr, phi1, st, start, acc, dirty):  # pragma: no cover - compiled
    """Add the nr recorded changes (row, column, Δ) in any order to the row sums: sort them by row
    (counting sort into ``st``), then :func:`_reduce_row` each row. Returns 0 (the records left)."""
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
        _stage(st, j, phi1, rec_u[i], rec_d[0, i], rec_d[1, i], rec_d[2, i])
    b = 0
    for v in range(H):
        e = start[v]
        if e > b:
            dirty[v] = True
            _reduce_row(st, b, e, acc[v], True)
        b = e
    return 0


@numba.njit(cache=True)
def _contract_rows(acc, dirty, row_w, m_col, c):  # pragma: no cover - compiled
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
def _dense_fill_state(row_ptr, col, key, W, state, none):  # pragma: no cover - compiled
    """The plan's keys as a dense per-pixel state: 0 data, the rank key, ``none`` without a source."""
    state[:] = _KEY_DATA
    for v in range(row_ptr.shape[0] - 1):
        for t in range(row_ptr[v], row_ptr[v + 1]):
            state[v * W + col[t]] = key[t] if key[t] != _NO_KEY else none


# Share of the pixels in one change set above which the full projection is cheaper (default session:
# incremental 4.2 ms vs full 5.5 at 350k changes, 5.7 vs 5.5 at 463k, 14.6 vs 7.1 at 590k).
_MAX_CHANGED_FRACTION = 1 / 5
_RECORDS = 1 << 13  # changes off the current row (copies met walking a column, C) sorted at a time


def _scratch_sizes(H: int, W: int, n: int, records: int) -> tuple[int, int]:
    """Sizes of :func:`_apply_changes`' float64 and int64 scratch for n logged pixels."""
    return 14 * W + 10 * records, 2 * records + H + 1 + W + n


@numba.njit(cache=True, fastmath=_FASTMATH)
def _apply_changes(flat, H, W, index, old, was_valid, state, none, phi1, radius, acc, dirty, n_records, fscr, iscr):  # pragma: no cover
    """Steps A–C above. ``flat``: (3, H W) float32 map after the writes; ``state``: (H W,) the fill
    key of every pixel (0: data, 4 · distance + direction: copies the pixel that names, ``none``:
    no source); ``phi1``: (W, 2) cos φ_u, sin φ_u. The changes accumulate as per-row longitude sums
    in ``acc`` (H, 3, P) with ``dirty`` rows (P: per block of 5 orders m, the 5 cos(mφ) then the
    5 sin(mφ) sums); :func:`_contract_rows` turns them into coefficients (30 multiply-adds per
    changed pixel for 5 bands instead of 75). The sums are formed by :func:`_reduce_row` over a
    row's changes staged together: the log's pixels row by row, other changes through records
    sorted by row (:func:`_flush`); adding each change to its row's sums in memory ran 4× slower.
    ``fscr``, ``iscr``: float64 / int64 scratch of :func:`_scratch_sizes` (kept by the caller:
    allocating ~1 MB per call cost page faults)."""
    n = index.shape[0]
    f0 = flat[0]
    f1 = flat[1]
    f2 = flat[2]
    R = n_records
    st = fscr[:14 * W].reshape(7, 2 * W)  # one row's staged changes (≤ W written, ≤ W copies met along it)
    srt = fscr[14 * W:14 * W + 7 * R].reshape(7, R)  # the records sorted by row, staged for _reduce_row
    rec_d = fscr[14 * W + 7 * R:14 * W + 10 * R].reshape(3, R)  # other changes: row, column, Δ
    rec_v = iscr[:R]
    rec_u = iscr[R:2 * R]
    start = iscr[2 * R:2 * R + H + 1]
    todo = iscr[2 * R + H + 1:2 * R + H + 1 + W]  # a row's written pixels that need more than staging
    fresh = iscr[2 * R + H + 1 + W:]  # the pixels that get data, for C
    nf = 0
    nr = np.int64(0)  # not a literal 0, which numba compiled _flush for separately (3 s on a first run)
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
            pa = np.uint64(index[min(e + _AHEAD, last)])  # its colours and the state row below
            _prefetch(f0, pa)
            _prefetch(f1, pa)
            _prefetch(f2, pa)
            _prefetch(state, pa + uw)
            p = np.uint64(index[e])
            u = p - ur
            w = was_valid[e]
            d0 = np.float64(f0[p]) - np.float64(old[e, _U0])  # read for new data pixels too, then
            d1 = np.float64(f1[p]) - np.float64(old[e, _U1])  # dropped: no branch
            d2 = np.float64(f2[p]) - np.float64(old[e, _U2])
            _stage(st, i, phi1, u, d0 if w else 0.0, d1 if w else 0.0, d2 if w else 0.0)
            # A. nearly every written pixel has data on all four sides: nothing copies it, no
            # walks. The others, and B's pixels, are listed (without a branch) for the loop below.
            left = p - _U1 if u > 0 else p + uw - _U1
            right = p + _U1 if u < uw - _U1 else p + _U1 - uw
            todo[nt] = i
            nt += (not w) | ((state[left] | state[right] | state[p - up] | state[p + down]) != _KEY_DATA)
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
                s = _source(p, u, kk, W) if kk != none else -1
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
                    if s == _KEY_DATA:
                        break
                    if s == 4 * d + rank:
                        _stage(st, kw, phi1, qu, d0, d1, d2)
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
                    if s == _KEY_DATA:
                        break
                    if s == 4 * d + rank:
                        if nr == n_records:
                            nr = _flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)
                        rec_v[nr] = qv
                        rec_u[nr] = u
                        rec_d[0, nr] = d0
                        rec_d[1, nr] = d1
                        rec_d[2, nr] = d2
                        nr += 1
        dirty[v] = True
        _reduce_row(st, 0, kw, acc[v], False)
    # B. the new data pixels are data from now on
    for i in range(nf):
        state[fresh[i]] = _KEY_DATA
    # C. missing pixels along the four runs from each new data pixel may copy it now
    uw = np.uint64(W)
    lastf = np.uint64(max(nf - 1, 0))
    for i in range(nf):
        pa = np.uint64(fresh[min(np.uint64(i) + _AHEAD, lastf)])  # the state rows above and below
        _prefetch(state, pa - uw)
        _prefetch(state, pa + uw)
        p = fresh[i]
        v = p // W
        u = p - v * W
        # New data mostly comes in patches: inside one, all four neighbours have data (new pixels
        # are data by now) and every walk would stop at its first step. One test for all four
        # (unsigned, as in A; a pole tests p itself) skips the four unpredictable loop exits
        # (measured: C 0.72 → 0.40 ms mean per frame of the default session, before prefetching).
        pp = np.uint64(p)
        lq = pp - _U1 if u > 0 else pp + uw - _U1
        rq = pp + _U1 if u < W - 1 else pp + _U1 - uw
        aq = pp - uw if v > 0 else pp
        bq = pp + uw if v < H - 1 else pp
        if (state[lq] | state[rq] | state[aq] | state[bq]) == _KEY_DATA:
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
                if kq == _KEY_DATA:
                    break
                k = 4 * d + rank
                if k < kq:
                    s = _source(q, qu, kq, W) if kq != none else -1
                    if nr == n_records:
                        nr = _flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)
                    rec_v[nr] = qv
                    rec_u[nr] = qu
                    rec_d[0, nr] = l0 - (np.float64(f0[s]) if s >= 0 else 0.0)
                    rec_d[1, nr] = l1 - (np.float64(f1[s]) if s >= 0 else 0.0)
                    rec_d[2, nr] = l2 - (np.float64(f2[s]) if s >= 0 else 0.0)
                    nr += 1
                    state[q] = k
    _flush(rec_v, rec_u, rec_d, nr, phi1, srt, start, acc, dirty)


@lru_cache(maxsize=8)
def _column_tables(width: int, bands: int) -> tuple[np.ndarray, np.ndarray]:
    """(W, 2) float64 cos φ_u, sin φ_u, and for each coefficient k where :func:`_apply_changes`
    keeps its longitude sum: m_col (n²,) int64, 10 ⌊|m| / 5⌋ + |m| mod 5, plus 5 for sin (m < 0)."""
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    phi1 = np.ascontiguousarray(np.stack([np.cos(phi), np.sin(phi)], 1))
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(bands)])
    a = np.abs(m_of_k)
    m_col = (2 * _BLOCK * (a // _BLOCK) + a % _BLOCK + _BLOCK * (m_of_k < 0)).astype(np.int64)
    for t in (phi1, m_col):
        t.setflags(write=False)
    return phi1, m_col


class IncrementalProjection:
    """SH coefficients of an :class:`~rgbd_envmap.envmap.EnvironmentMap` that follow its updates.

    ``coefficients(em)`` returns what ``project_planar(em.radiance_planes, em.valid, bands)`` would
    (same fill rule, float64; equal to ~1e-6 relative, the full projection's float32 row sums), but
    after the first call it only visits the pixels ``envmap.update`` wrote since the previous call
    and the missing pixels whose fill they change (the map's change log,
    :meth:`~rgbd_envmap.envmap.EnvironmentMap.record_changes`, which the first call switches on).
    A full projection runs again when the log cannot describe the map's history: another map
    object (e.g. a translated view), a log overflow, or arrays written directly (call
    ``em.mark_modified()`` after doing that), and for change sets above 1/5 of the pixels (then
    the full projection is cheaper). Keeps one byte of fill state per pixel (2 MB at 2000×1000;
    two bytes for ``fill_radius_px`` > 62).

    Args:
        bands: number of SH bands n ≥ 1.
        fill_radius_px: the fill's search radius in pixels (paper: 50).
    """

    def __init__(self, bands: int = 5, *, fill_radius_px: int = FILL_RADIUS_PX) -> None:
        self.bands = check_positive_int(bands, "bands")
        self.fill_radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
        self.full_projections = 0
        self.incremental_updates = 0
        self._map = None
        self._coeffs: np.ndarray | None = None
        self._key_dtype = _key_dtype(self.fill_radius_px)
        self._key_none = int(np.iinfo(self._key_dtype).max)  # the key of a pixel without a source
        self._state: np.ndarray | None = None  # (H W,) fill key per pixel, see _apply_changes
        self._records = _RECORDS  # buffer size of the changes off the current row (tests shrink it)
        self._max_changed_fraction = _MAX_CHANGED_FRACTION
        self._fscr = np.empty(0)  # scratch of _apply_changes, kept between calls
        self._iscr = np.empty(0, np.int64)
        self._acc: np.ndarray | None = None  # (H, 3, 2n − 1) per-row longitude sums of the changes
        self._dirty: np.ndarray | None = None

    def coefficients(self, em) -> np.ndarray:
        """(n², 3) float64 coefficients of ``em`` now (a copy).

        Raises:
            ShapeError: an empty map. NonFiniteError: NaN or infinity at a contributing pixel.
        """
        tracked = self._map() if self._map is not None else None
        changes = em.take_changes() if tracked is em else None
        # Past a share of the pixels (a frame from inside the trusted sphere rewrites everything it
        # sees) projecting the whole map costs less.
        if (changes is None or not changes.complete
                or len(changes.index) > em.height * em.width * self._max_changed_fraction):
            self._rebuild(em)
        elif len(changes.index):
            H, W = em.height, em.width
            phi1, m_col = _column_tables(W, self.bands)
            n_float, n_int = _scratch_sizes(H, W, len(changes.index), self._records)
            if self._fscr.size < n_float or self._iscr.size < n_int:
                self._fscr = np.empty(max(n_float, self._fscr.size))
                self._iscr = np.empty(max(n_int, 2 * self._iscr.size), np.int64)
            _apply_changes(em.radiance_planes.reshape(3, H * W), H, W, changes.index, changes.old_radiance,
                           changes.was_valid, self._state, self._key_none, phi1, self.fill_radius_px,
                           self._acc, self._dirty, self._records, self._fscr, self._iscr)
            _contract_rows(self._acc, self._dirty, _projection_tables(H, W, self.bands)[3], m_col, self._coeffs)
            self.incremental_updates += 1
            if not np.isfinite(self._coeffs).all():
                self._rebuild(em)  # names the bad pixel
        return self._coeffs.copy()

    def _rebuild(self, em) -> None:
        import weakref

        H, W = em.height, em.width
        _check_map_size(H, W, "em")
        if H * W >= 2**31 - 1:
            raise RangeError(f"em: {H}×{W} pixels is too large for incremental tracking")
        self._map = None
        em.record_changes()
        planes = np.ascontiguousarray(em.radiance_planes, dtype=np.float32)
        row_ptr, col, src, empty, key = _plan(em.valid, self.fill_radius_px)
        coeffs = _project_planar(planes, row_ptr, col, src, empty, *_projection_tables(H, W, self.bands))
        self.full_projections += 1
        if not np.isfinite(coeffs).all():
            _project(planes, True, em.valid, self.bands, self.fill_radius_px, "em.radiance")  # raises, naming it
        if self._state is None or self._state.size != H * W or self._acc.shape[0] != H:
            self._state = np.empty(H * W, self._key_dtype)
            self._acc = np.zeros((H, 3, 2 * _BLOCK * -(-self.bands // _BLOCK)))
            self._dirty = np.zeros(H, bool)
        _dense_fill_state(row_ptr, col, key, W, self._state, self._key_none)
        self._coeffs = coeffs
        self._map = weakref.ref(em)

    def _fill_state(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """The tracked fill state as a fresh plan states it (for tests): per pixel the flat index of
        the source (−2 data, −1 none) and the rank key (0 data, ``_NO_KEY`` none), (H W,) int64."""
        k = self._state.astype(np.int64)
        p = np.arange(k.size)
        d, r = k >> 2, k & 3
        u = p % width
        side = np.where(r == 2, u - d, u + d) % width
        src = np.where(r == 0, p - d * width, np.where(r == 1, p + d * width, p - u + side))
        none = k == self._key_none
        src = np.where(k == _KEY_DATA, -2, np.where(none, -1, src))
        return src, np.where(none, _NO_KEY, k)


# --- band selection ("model only what a scene needs") -----------------------------------------------

@dataclass(frozen=True, eq=False)
class TransferGram:
    """G = Tᵀ diag(w) T of an object's per-vertex transfer vectors, for :func:`select_bands`.

    It depends only on the object (and the vertex weights), so compute it once with
    :func:`transfer_gram`; band selection from it costs O(K²) per frame instead of O(V K).

    Attributes:
        gram: (K, K) float64, read-only; K = bands² of the transfer.
        n_vertices: V, the number of transfer rows it summarises.
    """

    gram: np.ndarray
    n_vertices: int


def transfer_gram(transfer: np.ndarray, weights: np.ndarray | None = None) -> TransferGram:
    """Precompute :class:`TransferGram` from (V, K) transfer vectors (see :func:`select_bands`).

    Args:
        transfer: (V, K) float transfer vectors, V ≥ 1, K = n² (finite).
        weights: optional (V,) non-negative finite vertex weights (e.g. vertex areas); default 1.
    """
    T = _check_transfer(transfer)
    w = _check_weights(weights, T.shape[0])
    T64 = T.astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite input is reported below
        G = T64.T @ (T64 if w is None else T64 * w[:, None])
    if not np.isfinite(G).all():
        raise NonFiniteError("transfer: expected finite values, got NaN or inf (or an overflowing sum)")
    G = 0.5 * (G + G.T)
    G.setflags(write=False)
    return TransferGram(G, int(T.shape[0]))


@dataclass(frozen=True, eq=False)
class BandSelection:
    """Result of :func:`select_bands`.

    Attributes:
        bands: the chosen number of bands n (1 ≤ n ≤ ``max_bands``).
        max_bands: N, the band count of the reference shading.
        errors: (N,) float64, read-only; ``errors[n − 1]`` is the relative RMS error e_n of shading
            with n bands against N bands (so ``errors[N − 1] == 0``).
        tolerance: the tolerance the selection used.
        degenerate: True when the reference shading is zero (see :func:`select_bands`); then every
            error is reported as 0 and one band is chosen.
    """

    bands: int
    max_bands: int
    errors: np.ndarray
    tolerance: float
    degenerate: bool = False


def _check_transfer(transfer: np.ndarray) -> np.ndarray:
    T = check_array(transfer, "transfer", shape=("V", "K"), dtype="float")
    if T.shape[0] == 0:
        raise ShapeError("transfer: expected at least one vertex, got shape (0, K)")
    n = math.isqrt(T.shape[1])
    if n < 1 or n * n != T.shape[1]:
        raise ShapeError(f"transfer: expected n² columns (1, 4, 9, 16, 25, ...), got {T.shape[1]}")
    return T


def _check_weights(weights: np.ndarray | None, n_vertices: int) -> np.ndarray | None:
    if weights is None:
        return None
    w = check_array(weights, "weights", shape=(n_vertices,), dtype=("float", "int"), finite=True)
    if (w < 0).any():
        raise RangeError(f"weights: expected values ≥ 0, got minimum {w.min()}")
    return w.astype(np.float64)


# Relative size under which the reference shading counts as zero (see select_bands).
_ZERO_SHADING = 1e-12


def select_bands(coeffs: np.ndarray, transfer: np.ndarray | TransferGram, tolerance: float = 0.01,
                 max_bands: int | None = None, *, weights: np.ndarray | None = None) -> BandSelection:
    """The fewest SH bands whose shading of an object stays within ``tolerance`` of all bands.

    With per-vertex transfer vectors T (V, K) in this module's convention (T_k = ∫ V(ω) max(n·ω, 0)
    Y_k(ω) dω, see ``rgbd_envmap.prt``) and radiance coefficients L, the shading with n bands is
    S_n = T[:, :n²] L[:n²] (V, 3); the outgoing radiance is (albedo / π) S_n. With N = ``max_bands``
    the reference is S_N, and the error of n bands is the relative RMS over vertices and channels

        e_n = ‖S_n − S_N‖ / ‖S_N‖,   ‖X‖² = Σ_v w_v Σ_c X_vc²   (w_v = 1 unless ``weights``).

    The result is the smallest n with e_n ≤ ``tolerance``. Because S_n − S_N = −Σ_{j≥n} B_j with
    B_j the band-j contribution, e_n only involves the tail; from a :class:`TransferGram`
    G = Tᵀ diag(w) T it is ‖tail‖² = Σ_c L_tail,cᵀ G L_tail,c, computed in O(K²).

    Zero shading guard: if ‖S_N‖ ≤ 1e-12 · Σ_j ‖B_j‖ (a black environment, zero transfer, or bands
    that cancel exactly) there is nothing to resolve; every e_n is reported as 0, one band is chosen
    and ``degenerate`` is set. Otherwise the division is safe (‖S_N‖ > 0).

    ``tolerance = 0`` selects the fewest bands that reproduce S_N exactly, which is N unless the top
    bands contribute nothing (unshadowed transfer T_k = Â_l Y_k(n) has Â_l = 0 for odd l ≥ 3).

    Args:
        coeffs: (n_c², 3) float radiance coefficients (finite), e.g. from :func:`project_equirect`.
        transfer: (V, n_t²) float transfer vectors (V ≥ 1), or a :class:`TransferGram` of them.
        tolerance: largest accepted e_n, ≥ 0 (default 1 %).
        max_bands: N; default min(n_c, n_t). Must not exceed either.
        weights: optional (V,) non-negative vertex weights (with a raw ``transfer`` only; a
            :class:`TransferGram` has them built in).

    Returns:
        :class:`BandSelection`.

    Raises:
        ShapeError: bad shapes (non-square coefficient counts, no vertices). RangeError: negative or
        non-finite tolerance, ``max_bands`` out of range, negative weights. NonFiniteError: NaN or
        infinity in the coefficients, or in the transfer (detected through the result).
        InvalidInputError: ``weights`` given with a :class:`TransferGram`.

    Cost: 35k vertices × 64 transfer columns, 8 bands: see benchmarks/bench_sh.py (a raw transfer
    costs one pass over T per frame; a TransferGram costs microseconds).
    """
    L = check_array(coeffs, "coeffs", shape=("K", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    nb_c = n_bands(L.shape[0])
    try:
        tol = float(tolerance)
    except (TypeError, ValueError) as exc:
        raise DTypeError(f"tolerance: expected a number, got {tolerance!r}") from exc
    if not (math.isfinite(tol) and tol >= 0.0):
        raise RangeError(f"tolerance: expected a finite value ≥ 0, got {tolerance!r}")
    if isinstance(transfer, TransferGram):
        if weights is not None:
            raise InvalidInputError("weights: a TransferGram already includes its vertex weights; "
                                    "pass weights to transfer_gram instead")
        G = transfer.gram
        nb_t = math.isqrt(G.shape[0])
        T = w = None
    else:
        T = _check_transfer(transfer)
        w = _check_weights(weights, T.shape[0])
        nb_t = math.isqrt(T.shape[1])
        G = None
    if max_bands is None:
        N = min(nb_c, nb_t)
    else:
        N = check_positive_int(max_bands, "max_bands")
        if N > min(nb_c, nb_t):
            raise RangeError(f"max_bands: expected ≤ {min(nb_c, nb_t)} (coeffs have {nb_c} bands, "
                             f"transfer {nb_t}), got {N}")
    L = L[:N * N]
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite transfer is reported below
        tail, band = _tail_energies(L, N, G, T, w)
    if not (np.isfinite(tail).all() and np.isfinite(band).all()):
        raise NonFiniteError("transfer: expected finite values, got NaN or inf (or an overflowing sum)")
    tail = np.maximum(tail, 0.0)
    ref = math.sqrt(tail[0])
    degenerate = ref <= _ZERO_SHADING * float(band.sum())
    if degenerate:
        errors = np.zeros(N)
        bands = 1
    else:
        errors = np.sqrt(tail[1:]) / ref
        errors[-1] = 0.0
        bands = int(np.argmax(errors <= tol)) + 1
    errors.setflags(write=False)
    return BandSelection(bands=bands, max_bands=N, errors=errors, tolerance=tol, degenerate=degenerate)


def _tail_energies(L, N, G, T, w):
    """tail[n] = ‖Σ_{j≥n} B_j‖² for n = 0 … N (tail[0] = ‖S_N‖², tail[N] = 0) and band[j] = ‖B_j‖,
    from the Gram matrix G (when T is None) or from the transfer T directly."""
    if T is None:
        K = N * N
        M = G[:K, :K] * (L @ L.T)  # M[k, j] = G[k, j] Σ_c L[k, c] L[j, c]
        C = np.zeros((K + 1, K + 1))  # C[a, b] = Σ_{k ≥ a, j ≥ b} M[k, j]
        C[:K, :K] = M[::-1, ::-1].cumsum(0).cumsum(1)[::-1, ::-1]
        a = np.arange(N + 1) ** 2  # band j spans rows / columns a[j] … a[j + 1] − 1
        tail = C[a, a]
        block = C[a[:-1], a[:-1]] - C[a[:-1], a[1:]] - C[a[1:], a[:-1]] + C[a[1:], a[1:]]
        band = np.sqrt(np.maximum(block, 0.0))
    else:
        Lt = L.astype(T.dtype)  # float32 transfer: float32 products (BLAS sgemm), float64 sums
        sw = None if w is None else np.sqrt(w)[:, None]
        R = np.zeros((T.shape[0], 3))
        tail = np.zeros(N + 1)
        band = np.zeros(N)
        for j in range(N - 1, -1, -1):  # R = Σ_{i≥j} B_i, built from the top band down
            B = T[:, j * j:(j + 1) ** 2] @ Lt[j * j:(j + 1) ** 2]
            R += B
            Bw, Rw = (B, R) if sw is None else (B * sw, R * sw)
            band[j] = math.sqrt(float(np.vdot(Bw, Bw)))
            tail[j] = float(np.vdot(Rw, Rw))
    return tail, band
