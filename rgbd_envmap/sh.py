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
depends on v) times a column factor (cos(mφ_u) or sin(|m|φ_u)). So each row is first reduced by a
small DFT over longitude (one float32 matrix product for the whole map, float32 accumulation over one
row only), and the rows are then combined in float64 with the Legendre weights times the exact row
solid angle. The tables depend only on (H, W, bands) and are cached.

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
- ``project_equirect``: NaN or infinity in the radiance at a pixel that contributes (valid pixels, or
  every pixel when ``valid`` is None) raises :class:`NonFiniteError`. Values under ``valid = False``
  are never read except as fill sources (which are valid by definition), so they may be NaN.
  ``irradiance``: non-finite coefficients raise :class:`NonFiniteError`.

References:
    - P.-P. Sloan, "Stupid Spherical Harmonics (SH) Tricks", GDC 2008 (basis, sign convention).
    - R. Ramamoorthi and P. Hanrahan, "An Efficient Representation for Irradiance Environment Maps",
      SIGGRAPH 2001 (clamped-cosine band factors Â_l).
    - Paper 003 §7.1 (25 coefficients per channel from the EM; filling of missing EM pixels).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

from rgbd_envmap.checks import check_array, check_finite, check_positive_int
from rgbd_envmap.errors import NonFiniteError, ShapeError
from rgbd_envmap.geometry import equirect_solid_angles

__all__ = [
    "FILL_RADIUS_PX",
    "basis",
    "fill_missing",
    "irradiance",
    "lambertian_band_factors",
    "n_bands",
    "project_equirect",
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

@numba.njit(cache=True)
def _fill_kernel(radiance, valid, radius):  # pragma: no cover - compiled
    H, W, C = radiance.shape
    out = np.empty((H, W, C), dtype=np.float32)
    used = np.ones((H, W), dtype=np.bool_)
    for v in range(H):
        for u in range(W):
            if valid[v, u]:
                for c in range(C):
                    out[v, u, c] = radiance[v, u, c]
                continue
            sv = -1
            su = -1
            for dist in range(1, radius + 1):
                # fixed tie order: up, down, left, right
                if v - dist >= 0 and valid[v - dist, u]:
                    sv, su = v - dist, u
                elif v + dist < H and valid[v + dist, u]:
                    sv, su = v + dist, u
                elif valid[v, (u - dist) % W]:
                    sv, su = v, (u - dist) % W
                elif valid[v, (u + dist) % W]:
                    sv, su = v, (u + dist) % W
                if sv >= 0:
                    break
            if sv >= 0:
                for c in range(C):
                    out[v, u, c] = radiance[sv, su, c]
            else:
                used[v, u] = False
                for c in range(C):
                    out[v, u, c] = 0.0
    return out, used


def fill_missing(radiance: np.ndarray, valid: np.ndarray, radius_px: int = FILL_RADIUS_PX
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing EM pixels from the closest data pixel along up / down / left / right.

    Args:
        radiance: (H, W, 3) float linear radiance; values under ``valid = False`` are not read.
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
    return _fill_kernel(rad, np.ascontiguousarray(valid), radius_px)


# --- projection ---------------------------------------------------------------------------------------

@lru_cache(maxsize=8)
def _projection_tables(height: int, width: int, bands: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cached tables for ``project_equirect``.

    Returns (K, row_w, col_index):
        K: (3W, 3(2n − 1)) float32, the longitude DFT table expanded over the interleaved RGB channels
           (kron with I₃), so one matrix product reduces every row of the (H, 3W) radiance view.
           Table column j ↔ m = j − (n − 1): sin(|m|φ) for m < 0, cos(mφ) for m ≥ 0.
        row_w: (H, n²) float64, the Legendre part of Y_k at each row (incl. sin^|m| θ and √2) times the
           exact solid angle of one pixel of that row.
        col_index: (n²,) index of the table column used by each k.
    """
    n = bands
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    m = np.arange(-(n - 1), n)
    trig = np.where(m[:, None] < 0, np.sin(np.abs(m)[:, None] * phi), np.cos(m[:, None] * phi))
    K = np.kron(trig.T, np.eye(3)).astype(np.float32)  # (3W, 3(2n − 1)); row 3u + c, column 3j + c
    K.setflags(write=False)
    leg = _legendre_scaled(np.cos(theta), n)
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(n)])
    leg *= np.sin(theta)[:, None] ** np.abs(m_of_k)[None, :]
    row_w = leg * equirect_solid_angles(height, width)[:, :1]
    row_w.setflags(write=False)
    col_index = m_of_k + (n - 1)
    col_index.setflags(write=False)
    return K, row_w, col_index


def project_equirect(radiance: np.ndarray, valid: np.ndarray | None = None, bands: int = 5) -> np.ndarray:
    """SH coefficients L_k = Σ_p Y_k(d_p) radiance_p Ω_p of an equirect radiance map.

    Args:
        radiance: (H, W, 3) float linear radiance (float32 is the fast path; other dtypes are
            converted to float32). Directions and exact solid angles follow docs/CONVENTIONS.md.
        valid: (H, W) bool or None (every pixel has data). Missing pixels are filled first as in
            DESIGN.md §4 stage 8 (see :func:`fill_missing`); pixels that cannot be filled are skipped.
        bands: number of bands n ≥ 1.

    Returns:
        (n², 3) float64 coefficients.

    Raises:
        ShapeError: wrong shapes. RangeError / DTypeError: bad ``bands``. NonFiniteError: NaN or
        infinity at a contributing pixel (or a sum that overflows).
    """
    bands = check_positive_int(bands, "bands")
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    H, W = rad.shape[:2]
    if valid is not None:
        valid = check_array(valid, "valid", shape=(H, W), dtype="bool")
        if valid.all():
            valid = None
    if valid is None:
        work = np.ascontiguousarray(rad, dtype=np.float32)
    else:
        work, _ = _fill_kernel(rad, np.ascontiguousarray(valid), FILL_RADIUS_PX)
    K, row_w, col_index = _projection_tables(H, W, bands)
    # (H, 3W) @ (3W, 3(2n − 1)) → per row, per table column j, per channel c: Σ_u trig_j(u) r(u, c).
    with np.errstate(invalid="ignore", over="ignore"):
        rows = (work.reshape(H, 3 * W) @ K).reshape(H, 2 * bands - 1, 3).astype(np.float64)
        coeffs = np.einsum("vk,vkc->kc", row_w, rows[:, col_index, :])
    if not np.isfinite(coeffs).all():  # NaN/inf propagate through the matmul (NaN·0 = NaN)
        # Non-finite input propagates into the sums; find it for the message (cheap path otherwise).
        if valid is None:
            check_finite(rad, "radiance")
        else:
            check_finite(rad[valid], "radiance (at valid pixels)")
        raise NonFiniteError("radiance: the projection overflowed float32/float64; scale the map down")
    return coeffs
