"""Real spherical harmonics: the basis, its Legendre part, and Lambertian irradiance (paper 003 §7.1).

Convention (docs/reference/conventions.md):

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
stable three-term recurrence on the *normalised* functions (:func:`legendre`: no factorials, no
overflow), so any number of bands ≥ 1 works.

Invalid input: a zero-length or non-finite direction gives a **NaN row** in :func:`basis` and
:func:`irradiance` (like ``geometry.directions_to_equirect``); it does not raise, so one bad normal
does not spoil a batch. Wrong shapes raise :class:`ShapeError`; ``bands < 1`` raises
:class:`RangeError`; a non-integer ``bands`` raises :class:`DTypeError`; non-finite coefficients in
:func:`irradiance` raise :class:`NonFiniteError`.

References:
    - P.-P. Sloan, "Stupid Spherical Harmonics (SH) Tricks", GDC 2008 (basis, sign convention).
    - R. Ramamoorthi and P. Hanrahan, "An Efficient Representation for Irradiance Environment Maps",
      SIGGRAPH 2001 (clamped-cosine band factors Â_l).
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.checks import check_array, check_number, check_positive_int
from rgbd_envmap.errors import RangeError, ShapeError

__all__ = ["basis", "irradiance", "lambertian_band_factors", "legendre", "n_bands", "check_bands", "MAX_BANDS"]

#: the most bands :func:`basis` evaluates (1,024 functions per direction; the pipeline uses 5, and
#: 8 already resolve irradiance within 0.4 %).
MAX_BANDS = 32


def check_bands(bands: object, name: str = "bands") -> int:
    """``bands`` as an int from 1 to :data:`MAX_BANDS`, else the project's typed error naming it."""
    n = check_positive_int(bands, name)
    if n > MAX_BANDS:
        raise RangeError(f"{name}: expected at most {MAX_BANDS} bands (n bands are n² coefficients per colour "
                         f"channel and per direction or vertex), got {n}")
    return n


def legendre(z: np.ndarray, bands: int) -> np.ndarray:
    """The Legendre part of the basis: Y_k = legendre(cos θ)[k] · sin^|m| θ · (cos mφ or sin |m|φ).

    Args:
        z: (...) float64 array of cos θ in [−1, 1].
        bands: number of bands n ≥ 1.

    Returns:
        (..., n²) float64 array A with A[..., k] = c_m K_l|m| P_l^|m|(z) / sin^|m| θ for
        k = (l, m), c_m = √2 for m ≠ 0 else 1 (the same value at ±m). Condon–Shortley phase
        included.

    Recurrence on normalised functions Q_lm = K_lm P_l^m / sin^m θ:
    Q_00 = 1/√(4π); Q_mm = −√((2m + 1) / (2m)) Q_{m−1,m−1}; Q_{m+1,m} = √(2m + 3) z Q_mm;
    Q_lm = a_lm (z Q_{l−1,m} − b_lm Q_{l−2,m}), a = √((4l² − 1)/(l² − m²)),
    b = √(((l − 1)² − m²)/(4(l − 1)² − 1)).
    """
    bands = check_bands(bands)
    z = check_array(z, "z", dtype=("float", "int"))  # NaN stays NaN, in its own entry only
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
    n_coeffs = check_number(n_coeffs, "n_coeffs", integer=True)
    if n_coeffs < 1:
        raise ShapeError(f"coeffs: expected n² rows (1, 4, 9, 16, 25, ...), got {n_coeffs}")
    n = math.isqrt(n_coeffs)
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
    bands = check_bands(bands)
    d = check_array(dirs, "dirs", shape=("*", 3), dtype=("float", "int")).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        # scaled by the largest component first: the squares of a finite 1e160 (or 1e-170) direction
        # would overflow (underflow) the norm
        big = np.max(np.abs(d), axis=-1)
        d = d / np.where(np.isfinite(big) & (big > 0.0), big, 1.0)[..., None]
        norm = np.sqrt(np.einsum("...i,...i->...", d, d))
        bad = ~np.isfinite(norm) | (norm == 0.0)
        d = d / np.where(bad, 1.0, norm)[..., None]
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    if bad.any():
        x, y, z = (np.where(bad, 0.0, t) for t in (x, y, z))  # keep NaN out of the arithmetic
    out = legendre(z, bands)
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
    bands = check_bands(bands)
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
