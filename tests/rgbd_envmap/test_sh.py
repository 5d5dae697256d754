"""Tests for rgbd_envmap.sh: real SH basis, equirect projection with the stage-8 fill, irradiance.

References are independent of the code under test: the table of the first 9 functions in
docs/reference/conventions.md, scipy.special.sph_harm_y (complex SH) converted to the real
Condon–Shortley basis, quadrature on an equirect grid with directions and solid angles re-derived
here, Gauss–Legendre × uniform-azimuth quadrature (exact for band-limited products), closed-form
coefficients of the constant and hemisphere functions, two implementations of the fill rule in
rgbd_envmap.reference.sh_fill (a slow obvious per-pixel search and a vectorised one that shifts the
mask one distance at a time), the projection summed over pixels in float64
(rgbd_envmap.reference.sh_projection) and a brute-force clamped-cosine convolution; for band
selection, the shading T[:, :n²] @ L[:n²] formed explicitly for every n.

Tolerances:
    basis vs scipy: 1e-6 absolute (both float64, values O(1)).
    orthonormality by equirect quadrature on 200×400: 1e-3 (midpoint-rule error ~ (l π / H)²;
        measured 1.4e-4 at l ≤ 7); by Gauss–Legendre quadrature: 1e-10 up to 30 bands (exact rule).
    projection vs float64 brute force: 1e-5 relative to the largest coefficient (float32 row sums);
        vs rgbd_envmap.reference.sh_projection on small maps: 1e-6.
    fill plan, fill and tracker state vs rgbd_envmap.reference.sh_fill: exact.
    hemisphere at 3 bands: the 3-band result is exactly π/2 + (π/2) z (L_20 of the hemisphere is 0),
        so the only error is quadrature of the map, < 1e-4 at 250×500.
    band-selection errors vs explicit float64 shading: 1e-9 relative for float64 transfer and the
        Gram path (which loses ~1e-16 / e² relative in e², negligible for e ≳ 1e-6); 1e-6 for a
        float32 transfer, whose products select_bands forms in float32.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.special import eval_legendre, sph_harm_y

from rgbd_envmap import sh
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)
from rgbd_envmap.reference import sh_fill as fill_ref
from rgbd_envmap.reference import sh_projection as projection_ref

# --- independent references -----------------------------------------------------------------------

def grid(H, W):
    """(H, W, 3) float64 directions and (H, W) exact solid angles, from docs/reference/conventions.md."""
    theta = np.pi * (np.arange(H) + 0.5) / H
    phi = 2 * np.pi * (np.arange(W) + 0.5) / W - np.pi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    edges = np.cos(np.pi * np.arange(H + 1) / H)
    omega = np.repeat(((2 * np.pi / W) * (edges[:-1] - edges[1:]))[:, None], W, 1)
    return d, omega


def scipy_real_sh(dirs, bands):
    """Real SH with Condon–Shortley phase from scipy's complex SH.

    scipy's Y_l^m already carries the CS phase (Y_1^1 = −√(3/8π) sin θ e^{iφ}), so the real basis
    *with* the phase is m > 0: √2 Re Y_l^m; m < 0: √2 Im Y_l^|m|; m = 0: Y_l^0. An extra (−1)^m
    factor would cancel the phase and give +0.488603 x for Y_1,1, contradicting the conventions; the
    test ``test_scipy_mapping_pins_condon_shortley_signs`` pins this."""
    d = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    theta = np.arccos(np.clip(d[..., 2], -1, 1))
    phi = np.arctan2(d[..., 1], d[..., 0])
    out = np.empty(d.shape[:-1] + (bands * bands,))
    for l in range(bands):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            if m > 0:
                v = math.sqrt(2) * y.real
            elif m < 0:
                v = math.sqrt(2) * y.imag
            else:
                v = y.real
            out[..., l * (l + 1) + m] = v
    return out


def brute_project(rad, bands):
    d, omega = grid(*rad.shape[:2])
    Y = scipy_real_sh(d.reshape(-1, 3), bands)
    return Y.T @ (rad.reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1))


def smooth_map(H, W, seed=0):
    rng = np.random.default_rng(seed)
    d, _ = grid(H, W)
    out = np.ones((H, W, 3)) * 0.5
    for c in range(3):
        for _ in range(4):
            a = rng.normal(size=3)
            out[..., c] += 0.3 * np.sin(d @ a + rng.uniform(0, 6))
    return out.astype(np.float32)


# --- basis ----------------------------------------------------------------------------------------

def test_first_nine_match_design_table():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(50, 3))
    x, y, z = (d / np.linalg.norm(d, axis=1, keepdims=True)).T
    want = np.stack([0.282095 + 0 * x, -0.488603 * y, 0.488603 * z, -0.488603 * x, 1.092548 * x * y,
                     -1.092548 * y * z, 0.315392 * (3 * z * z - 1), -1.092548 * x * z,
                     0.546274 * (x * x - y * y)], -1)
    np.testing.assert_allclose(sh.basis(d, 3), want, atol=2e-6)


def test_scipy_mapping_pins_condon_shortley_signs():
    # The reference conversion itself must give the conventions' band-1 signs.
    Y = scipy_real_sh(np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]), 2)
    np.testing.assert_allclose([Y[0, 1], Y[1, 2], Y[2, 3]], [-0.488603, 0.488603, -0.488603], atol=1e-6)


@pytest.mark.parametrize("bands", [1, 2, 5, 8])
def test_basis_matches_scipy(bands):
    rng = np.random.default_rng(bands)
    d = rng.normal(size=(500, 3))
    np.testing.assert_allclose(sh.basis(d, bands), scipy_real_sh(d, bands), atol=1e-6, rtol=0)


def test_basis_matches_scipy_at_poles_and_seam():
    d = np.array([[0, 0, 1.0], [0, 0, -1.0], [-1.0, 0, 0], [-1.0, -1e-12, 0], [1e-9, 0, 1]])
    np.testing.assert_allclose(sh.basis(d, 8), scipy_real_sh(d, 8), atol=1e-6)


def test_orthonormal_by_quadrature():
    d, omega = grid(200, 400)
    Y = sh.basis(d.reshape(-1, 3), 8)
    gram = Y.T @ (Y * omega.reshape(-1, 1))
    assert np.abs(gram - np.eye(64)).max() <= 1e-3


def gauss_sphere(bands):
    """Directions and weights of a rule exact for products of two band-(bands) functions:
    Gauss–Legendre in z = cos θ (exact to degree 2·bands − 1) × 2·bands uniform azimuths."""
    z, wz = np.polynomial.legendre.leggauss(bands)
    phi = 2 * np.pi * np.arange(2 * bands) / (2 * bands)
    Z, P = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - Z ** 2)
    d = np.stack([s * np.cos(P), s * np.sin(P), Z], -1).reshape(-1, 3)
    w = np.repeat(wz * (np.pi / bands), 2 * bands)
    return d, w


def test_basis_shapes_scaling_and_tiling():
    rng = np.random.default_rng(2)
    d = rng.normal(size=(6, 3))
    one = sh.basis(d, 5)
    assert one.shape == (6, 25) and one.dtype == np.float64
    np.testing.assert_array_equal(sh.basis(d.reshape(2, 3, 3), 5), one.reshape(2, 3, 25))
    np.testing.assert_allclose(sh.basis(7.5 * d, 5), one, atol=1e-14)
    assert sh.basis(np.array([0.0, 0, 1]), 3).shape == (9,)
    assert sh.basis(np.array([[0, 0, 1]]), 3).shape == (1, 9)  # integer input accepted


def test_high_band_count_is_exactly_orthonormal():
    # 30 bands = 900 functions; an exact quadrature leaves only rounding (the recurrence is stable).
    d, w = gauss_sphere(30)
    Y = sh.basis(d, 30)
    assert np.isfinite(Y).all()
    np.testing.assert_allclose(Y.T @ (Y * w[:, None]), np.eye(900), atol=1e-10)


def test_basis_empty_input():
    assert sh.basis(np.zeros((0, 3)), 5).shape == (0, 25)
    assert sh.irradiance(np.zeros((9, 3)), np.zeros((0, 3))).shape == (0, 3)


def test_bad_directions_give_nan_rows():
    d = np.array([[0, 0, 0], [np.nan, 0, 1], [np.inf, 0, 0], [0, 0, 1]], float)
    Y = sh.basis(d, 3)
    assert np.isnan(Y[:3]).all() and np.isfinite(Y[3]).all()


@pytest.mark.parametrize("bad", [np.zeros((4, 2)), np.zeros(3 * 4), np.zeros((2, 4))])
def test_basis_wrong_shape(bad):
    with pytest.raises(ShapeError):
        sh.basis(bad)


def test_basis_bad_bands():
    with pytest.raises(RangeError):
        sh.basis(np.array([0, 0, 1.0]), 0)
    with pytest.raises(DTypeError):
        sh.basis(np.array([0, 0, 1.0]), 2.5)


@settings(max_examples=50, deadline=None)
@given(st.tuples(*[st.floats(-10, 10, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3))
def test_basis_addition_theorem(v):
    # Σ_m Y_lm(d)² = (2l + 1) / (4π) for every unit d.
    Y = sh.basis(np.array(v), 6)
    for l in range(6):
        assert abs((Y[l * l:(l + 1) ** 2] ** 2).sum() - (2 * l + 1) / (4 * np.pi)) < 1e-9


# --- projection -----------------------------------------------------------------------------------

def test_constant_map():
    L = sh.project_equirect(np.ones((100, 200, 3), np.float32))
    assert L.shape == (25, 3) and L.dtype == np.float64
    np.testing.assert_allclose(L[0], 2 * np.sqrt(np.pi), rtol=1e-6)
    # m ≠ 0 vanish exactly (DFT of a constant row); m = 0, l even carry the midpoint-rule error of
    # pixel-centre sampling in θ, O((π/H)²): 4.4e-4 at H = 100.
    m = np.concatenate([np.arange(-l, l + 1) for l in range(5)])
    assert np.abs(L[m != 0]).max() < 1e-6
    assert np.abs(L[1:]).max() < 1e-3
    E = sh.irradiance(L, np.random.default_rng(0).normal(size=(100, 3)))
    np.testing.assert_allclose(E, np.pi, rtol=2e-4)
    L_big = sh.project_equirect(np.ones((1000, 2000, 3), np.float32))
    assert np.abs(L_big[1:]).max() < 1e-5  # error shrinks as 1/H²


def test_hemisphere_light_three_bands():
    H, W = 250, 500
    rad = np.zeros((H, W, 3), np.float32)
    rad[: H // 2] = 1.0  # z > 0 exactly: the horizon is the edge between rows H/2 − 1 and H/2
    L = sh.project_equirect(rad, bands=3)
    # closed form: L00 = √π, L10 = √(3π)/2, every other coefficient 0 (L20 ∝ ∫₀¹ 3z² − 1 dz = 0).
    want = np.zeros((9, 3))
    want[0], want[2] = np.sqrt(np.pi), np.sqrt(3 * np.pi) / 2
    np.testing.assert_allclose(L, want, atol=1e-4)
    E = sh.irradiance(L, np.array([[0, 0, 1.0], [0, 0, -1], [1, 0, 0], [0, 1, 0]]))
    np.testing.assert_allclose(E[:, 0], [np.pi, 0, np.pi / 2, np.pi / 2], atol=1e-4)


@pytest.mark.slow
def test_projection_matches_float64_brute_force_2000x1000():
    # Brute force: every pixel's basis row (sh.basis, itself checked against scipy above) × its
    # exact solid angle, summed in float64. The map has structure at every m the projection uses.
    rad = smooth_map(1000, 2000)
    rng = np.random.default_rng(11)
    rad += rng.uniform(0, 0.2, rad.shape).astype(np.float32)  # plus pixel noise
    d, omega = grid(1000, 2000)
    ref = np.zeros((25, 3))
    for v0 in range(0, 1000, 100):  # chunks keep memory small
        Y = sh.basis(d[v0:v0 + 100].reshape(-1, 3), 5)
        ref += Y.T @ (rad[v0:v0 + 100].reshape(-1, 3).astype(np.float64) * omega[v0:v0 + 100].reshape(-1, 1))
    L = sh.project_equirect(rad, bands=5)
    assert np.abs(L - ref).max() <= 1e-5 * np.abs(ref).max()
    planes = np.ascontiguousarray(np.moveaxis(rad, -1, 0))
    np.testing.assert_array_equal(sh.project_planar(planes), L)  # same sums in the same order
    np.testing.assert_array_equal(sh.project_equirect(planes.transpose(1, 2, 0)), L)


@pytest.mark.parametrize("H,W", [(40, 80), (20, 36), (15, 30), (9, 27), (5, 6), (2, 4), (1, 1), (3, 2)])
@pytest.mark.parametrize("bands", [1, 5, 6, 11])
def test_projection_matches_scipy_brute_force_any_size(H, W, bands):
    # W % 4 == 0 takes the folded kernel, other widths the plain one; 6 and 11 bands need 2 and 3
    # passes of 5 orders m.
    rng = np.random.default_rng(H * W + bands)
    rad = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    ref = brute_project(rad, bands)
    L = sh.project_equirect(rad, bands=bands)
    assert np.abs(L - ref).max() <= 1e-6 * max(np.abs(ref).max(), 1e-300)


def test_projection_of_basis_function_recovers_it():
    d, _ = grid(200, 400)
    Y = scipy_real_sh(d.reshape(-1, 3), 6).reshape(200, 400, 36)
    for k in (0, 3, 10, 17, 35):
        rad = np.repeat(Y[..., k:k + 1], 3, -1).astype(np.float32)
        L = sh.project_equirect(rad, bands=6)
        e = np.zeros(36)
        e[k] = 1
        np.testing.assert_allclose(L[:, 0], e, atol=2e-3)


@pytest.mark.parametrize("col", [0, -1])
def test_seam_columns(col):
    H, W = 40, 80
    rad = np.zeros((H, W, 3), np.float32)
    rad[:, col] = np.linspace(0.1, 2, H)[:, None] * np.array([1, 2, 3])
    np.testing.assert_allclose(sh.project_equirect(rad, bands=6), brute_project(rad, 6), atol=1e-6)


def test_seam_columns_mirror():
    # column 0 (φ just above −π) and column W − 1 (just below +π) are mirror images in y:
    # m < 0 coefficients (sin mφ) flip sign, m ≥ 0 coefficients agree.
    H, W = 40, 80
    a = np.zeros((H, W, 3), np.float32)
    b = np.zeros((H, W, 3), np.float32)
    a[:, 0] = b[:, -1] = np.linspace(0.1, 2, H)[:, None]
    La, Lb = sh.project_equirect(a, bands=6), sh.project_equirect(b, bands=6)
    m = np.concatenate([np.arange(-l, l + 1) for l in range(6)])
    np.testing.assert_allclose(La, np.where(m[:, None] < 0, -Lb, Lb), atol=1e-6)
    assert np.abs(La[m < 0]).max() > 1e-3  # the test can fail


@pytest.mark.parametrize("row", [0, -1])
def test_pole_rows(row):
    H, W = 60, 120
    rad = np.zeros((H, W, 3), np.float32)
    rad[row] = 1.0
    L = sh.project_equirect(rad, bands=6)
    np.testing.assert_allclose(L, brute_project(rad, 6), atol=1e-7)
    m = np.concatenate([np.arange(-l, l + 1) for l in range(6)])
    assert np.abs(L[m != 0]).max() < 1e-7
    l = np.concatenate([[l] * (2 * l + 1) for l in range(6)])
    other = sh.project_equirect(rad[::-1].copy(), bands=6)  # the opposite pole: (−1)^l for m = 0
    np.testing.assert_allclose(other[m == 0], (L * (-1.0) ** l[:, None])[m == 0], atol=1e-7)


def test_projection_bands_are_nested():
    rad = smooth_map(50, 100, seed=3)
    np.testing.assert_allclose(sh.project_equirect(rad, bands=3), sh.project_equirect(rad, bands=7)[:9],
                               atol=1e-9)


def test_valid_all_true_equals_none_and_nan_under_invalid_ignored():
    rad = smooth_map(30, 60, seed=4)
    np.testing.assert_array_equal(sh.project_equirect(rad, np.ones((30, 60), bool)), sh.project_equirect(rad))
    valid = np.ones((30, 60), bool)
    valid[5, 7] = False
    bad = rad.copy()
    bad[5, 7] = np.nan
    filled = rad.copy()
    filled[5, 7] = rad[4, 7]  # the pixel above, at distance 1 (ties: up first)
    np.testing.assert_allclose(sh.project_equirect(bad, valid), sh.project_equirect(filled), atol=1e-7)


# --- fill rule --------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed,frac", [(0, 0.3), (1, 0.8), (2, 0.97), (3, 0.999)])
def test_fill_matches_slow_rule(seed, frac):
    rng = np.random.default_rng(seed)
    H, W = 30, 60
    rad = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    valid = rng.uniform(size=(H, W)) > frac
    rad[~valid] = np.nan
    out, used = sh.fill_missing(rad, valid, radius_px=12)
    want, want_used = fill_ref.fill_missing(rad, valid, radius_px=12)
    np.testing.assert_array_equal(used, want_used)
    np.testing.assert_array_equal(out[used], want[used].astype(np.float32))
    assert (out[~used] == 0).all()


def test_fill_wraps_across_seam():
    H, W = 5, 120
    rad = np.zeros((H, W, 3), np.float32)
    valid = np.zeros((H, W), bool)
    valid[2, W - 3] = True
    rad[2, W - 3] = 7
    valid[2, 40] = True
    rad[2, 40] = 1
    out, used = sh.fill_missing(rad, valid)
    assert used[2, 0] and out[2, 0, 0] == 7  # 3 px left across the seam beats 40 px right
    assert used[2, 30] and out[2, 30, 0] == 1


def test_fill_beyond_50_is_skipped_and_ties_prefer_up():
    H, W = 120, 240
    rad = np.zeros((H, W, 3), np.float32)
    valid = np.zeros((H, W), bool)
    valid[0, 0] = True
    rad[0, 0] = 5
    out, used = sh.fill_missing(rad, valid)
    assert used[50, 0] and not used[51, 0]  # straight down: 50 px reaches, 51 does not
    assert used[0, 50] and used[0, W - 50] and not used[0, 51] and not used[0, W - 51]
    assert not used[1, 1]  # diagonal neighbours are not among the 4 directions
    valid[:] = False
    valid[10, 10] = valid[12, 10] = valid[11, 9] = valid[11, 11] = True
    rad[10, 10], rad[12, 10], rad[11, 9], rad[11, 11] = 1, 2, 3, 4
    out, _ = sh.fill_missing(rad, valid)
    assert out[11, 10, 0] == 1


def test_projection_with_missing_equals_projection_of_filled():
    rng = np.random.default_rng(5)
    rad = smooth_map(60, 120, seed=5)
    valid = rng.uniform(size=(60, 120)) > 0.2
    valid[:, 10:75] = False  # a band wider than 2×50 px in longitude only partly fillable
    valid[:20] = False
    want_rad, used = fill_ref.fill_missing(rad, valid, radius_px=50)
    assert not used.all() and used.any()
    want = brute_project(np.where(used[..., None], want_rad, 0.0), 5)
    np.testing.assert_allclose(sh.project_equirect(rad, valid), want, atol=1e-5)


# --- irradiance -------------------------------------------------------------------------------------

def test_band_factors():
    np.testing.assert_allclose(sh.lambertian_band_factors(7),
                               [np.pi, 2 * np.pi / 3, np.pi / 4, 0, -np.pi / 24, 0, np.pi / 64], rtol=1e-12)
    # general l: Â_l = 2π ∫₀¹ z P_l(z) dz (Funk–Hecke for the clamped cosine), by quadrature
    want = [2 * np.pi * quad(lambda z, l=l: z * eval_legendre(l, z), 0, 1, epsabs=1e-13)[0] for l in range(16)]
    np.testing.assert_allclose(sh.lambertian_band_factors(16), want, rtol=1e-9, atol=1e-12)


def test_irradiance_matches_cosine_convolution_of_band_limited_map():
    # Funk–Hecke: for a band-limited radiance, SH irradiance is *exactly* its clamped-cosine convolution.
    H, W = 200, 400
    d, omega = grid(H, W)
    rng = np.random.default_rng(6)
    L = rng.normal(size=(25, 3))
    rad = (scipy_real_sh(d.reshape(-1, 3), 5) @ L).reshape(H, W, 3)
    normals = rng.normal(size=(20, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    brute = np.maximum(normals @ d.reshape(-1, 3).T, 0) @ (rad.reshape(-1, 3) * omega.reshape(-1, 1))
    np.testing.assert_allclose(sh.irradiance(L, normals), brute, atol=2e-3 * np.abs(brute).max())


def test_irradiance_of_small_source_vs_brute_force():
    # A small bright cap (radius 5°) around s; brute-force clamped-cosine convolution on the map.
    # 5 bands truncate the cosine lobe: error ≲ 0.12 · max E (measured 0.09); 9 bands: ≲ 0.04.
    H, W = 300, 600
    d, omega = grid(H, W)
    s = np.array([0.3, -0.4, 0.85])
    s /= np.linalg.norm(s)
    rad = np.repeat((d @ s > np.cos(np.radians(5)))[..., None], 3, -1).astype(np.float32) * 100
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(200, 3))
    brute = np.maximum((normals / np.linalg.norm(normals, axis=1, keepdims=True)) @ d.reshape(-1, 3).T, 0) \
        @ (rad.reshape(-1, 3) * omega.reshape(-1, 1))
    for bands, tol in ((5, 0.12), (9, 0.04)):
        E = sh.irradiance(sh.project_equirect(rad, bands=bands), normals)
        assert np.abs(E - brute).max() <= tol * brute.max()
    # at the source direction the exact value is π sin²(5°) · 100
    E = sh.irradiance(sh.project_equirect(rad, bands=9), s)
    assert abs(E[0] - np.pi * np.sin(np.radians(5)) ** 2 * 100) < 0.03 * E[0]


def test_irradiance_shapes_and_errors():
    L = np.zeros((9, 3))
    L[0] = 1
    assert sh.irradiance(L, np.zeros((2, 4, 3)) + [0, 0, 1]).shape == (2, 4, 3)
    assert np.isnan(sh.irradiance(L, np.zeros((1, 3)))).all()
    with pytest.raises(ShapeError):
        sh.irradiance(np.zeros((8, 3)), np.array([0, 0, 1.0]))
    with pytest.raises(ShapeError):
        sh.irradiance(np.zeros((9, 2)), np.array([0, 0, 1.0]))
    with pytest.raises(ShapeError):
        sh.irradiance(L, np.zeros((4, 2)))
    bad = L.copy()
    bad[3, 1] = np.nan
    with pytest.raises(NonFiniteError):
        sh.irradiance(bad, np.array([0, 0, 1.0]))


# --- projection hard cases ---------------------------------------------------------------------------

def test_projection_errors():
    rad = np.ones((10, 20, 3), np.float32)
    with pytest.raises(ShapeError):
        sh.project_equirect(np.ones((10, 20)))
    with pytest.raises(ShapeError):
        sh.project_equirect(np.ones((10, 20, 4)))
    with pytest.raises(ShapeError):
        sh.project_equirect(rad, np.ones((10, 21), bool))
    with pytest.raises(DTypeError):
        sh.project_equirect(rad, np.ones((10, 20)))
    with pytest.raises(RangeError):
        sh.project_equirect(rad, bands=0)
    for bad_value in (np.nan, np.inf):
        bad = rad.copy()
        bad[3, 4, 1] = bad_value
        with pytest.raises(NonFiniteError):
            sh.project_equirect(bad)
        valid = np.ones((10, 20), bool)
        valid[0, 0] = False
        with pytest.raises(NonFiniteError, match="valid"):
            sh.project_equirect(bad, valid)
    assert issubclass(NonFiniteError, RgbdEnvmapError) and issubclass(NonFiniteError, ValueError)


def test_projection_does_not_mutate_input():
    rad = smooth_map(20, 40)
    valid = np.ones((20, 40), bool)
    valid[3, 3] = False
    r0, v0 = rad.copy(), valid.copy()
    sh.project_equirect(rad, valid)
    np.testing.assert_array_equal(rad, r0)
    np.testing.assert_array_equal(valid, v0)


def test_float64_and_single_band():
    rad = smooth_map(20, 40).astype(np.float64)
    L = sh.project_equirect(rad, bands=1)
    assert L.shape == (1, 3)
    np.testing.assert_allclose(L, brute_project(rad, 1), rtol=1e-6)


def test_projection_empty_all_invalid_and_overflow():
    for shape in [(0, 0, 3), (0, 8, 3), (4, 0, 3)]:
        with pytest.raises(ShapeError, match="non-empty"):
            sh.project_equirect(np.zeros(shape, np.float32))
    with pytest.raises(ShapeError, match="non-empty"):
        sh.project_planar(np.zeros((3, 0, 8), np.float32))
    # no data at all: nothing can be filled, nothing contributes (values under valid=False unread)
    rad = np.full((10, 20, 3), np.nan, np.float32)
    np.testing.assert_array_equal(sh.project_equirect(rad, np.zeros((10, 20), bool)), np.zeros((25, 3)))
    filled, used = sh.fill_missing(rad, np.zeros((10, 20), bool))
    assert not used.any() and (filled == 0).all()
    with pytest.raises(NonFiniteError, match="overflow"):
        sh.project_equirect(np.full((10, 20, 3), 3e38, np.float32))


def test_layouts_and_dtypes_agree():
    rng = np.random.default_rng(12)
    rad = smooth_map(30, 60, seed=12)
    valid = rng.uniform(size=(30, 60)) > 0.3
    rad_nan = np.where(valid[..., None], rad, np.nan).astype(np.float32)
    want = sh.project_equirect(rad_nan, valid, bands=6)
    planes = np.ascontiguousarray(np.moveaxis(rad_nan, -1, 0))
    np.testing.assert_array_equal(sh.project_planar(planes, valid, bands=6), want)
    np.testing.assert_array_equal(sh.project_equirect(planes.transpose(1, 2, 0), valid, bands=6), want)
    big = np.zeros((40, 90, 3), np.float32)
    big[5:35, 10:70] = rad_nan
    np.testing.assert_array_equal(sh.project_equirect(big[5:35, 10:70], valid, bands=6), want)  # strided view
    np.testing.assert_allclose(sh.project_equirect(rad_nan.astype(np.float64), valid, bands=6), want, atol=1e-12)
    np.testing.assert_array_equal(sh.project_planar(planes.astype(np.float64), valid, bands=6), want)
    np.testing.assert_array_equal(sh.project_equirect(rad_nan, np.asfortranarray(valid), bands=6), want)


def test_project_planar_errors():
    with pytest.raises(ShapeError):
        sh.project_planar(np.zeros((10, 20, 3), np.float32))
    with pytest.raises(ShapeError):
        sh.project_planar(np.zeros((3, 10, 20), np.float32), np.ones((20, 10), bool))
    with pytest.raises(DTypeError):
        sh.project_planar(np.zeros((3, 10, 20), bool))
    with pytest.raises(RangeError):
        sh.project_planar(np.zeros((3, 10, 20), np.float32), fill_radius_px=0)


# --- the stage-8 fill on realistic masks ------------------------------------------------------------



def blob_crack_mask(H, W, frac, seed, cap_rows=0):
    """~frac missing in discs (radius 1–H/40) and 1–2 px polylines, optionally a missing top cap."""
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(seed)
    miss = np.zeros((H, W), np.uint8)
    for _ in range(max(2, W // 50)):
        pts = np.cumsum(rng.normal(0, W / 30, (5, 2)), 0) + rng.uniform([0, 0], [W, H])
        cv2.polylines(miss, [pts.astype(np.int32).reshape(-1, 1, 2)], False, 1, int(rng.integers(1, 3)))
    while miss.mean() < frac:
        c = rng.uniform([0, 0], [W, H]).astype(int)
        cv2.circle(miss, (int(c[0]), int(c[1])), int(rng.integers(1, max(2, H // 40))), 1, -1)
    miss[:, :3] |= miss[:, -3:]  # some runs across the seam
    miss[:cap_rows] = 1
    return miss == 0


def test_vectorised_reference_matches_slow_rule():
    rng = np.random.default_rng(13)
    for seed in range(3):
        valid = rng.uniform(size=(20, 44)) > 0.7
        valid[:4] = False
        rad = rng.uniform(0, 1, (20, 44, 3)).astype(np.float32)
        want, want_used = fill_ref.fill_missing(rad, valid, radius_px=7)
        out, used = fill_ref.fill_missing_by_distance(rad, valid, radius_px=7)
        np.testing.assert_array_equal(used, want_used)
        np.testing.assert_array_equal(out, want.astype(np.float32))


@pytest.mark.slow
@pytest.mark.parametrize("cap_rows", [0, 120])
def test_fill_and_projection_on_realistic_mask(cap_rows):
    # 3 % missing in blobs and cracks at 500×1000 (and a missing polar cap of 120 rows: pixels more
    # than 50 rows from data are skipped).
    H, W = 500, 1000
    valid = blob_crack_mask(H, W, 0.03, seed=cap_rows, cap_rows=cap_rows)
    rad = smooth_map(H, W, seed=14) + np.random.default_rng(14).uniform(0, 0.1, (H, W, 3)).astype(np.float32)
    want, want_used = fill_ref.fill_missing_by_distance(rad, valid)
    rad[~valid] = np.nan  # never read
    out, used = sh.fill_missing(rad, valid)
    np.testing.assert_array_equal(used, want_used)
    np.testing.assert_array_equal(out, want)
    assert cap_rows == 0 or not used[:cap_rows - 50].any()
    L = sh.project_equirect(rad, valid)
    d, omega = grid(H, W)
    ref = sh.basis(d.reshape(-1, 3), 5).T @ (want.reshape(-1, 3).astype(np.float64) * omega.reshape(-1, 1))
    assert np.abs(L - ref).max() <= 1e-5 * np.abs(ref).max()


@st.composite
def masks(draw):
    H = draw(st.integers(1, 16))
    W = draw(st.integers(1, 40))
    valid = np.ones((H, W), bool)
    for _ in range(draw(st.integers(0, 6))):  # missing rectangles, rows, columns (maybe wrapping)
        v0, v1 = sorted(draw(st.tuples(st.integers(0, H), st.integers(0, H))))
        u0 = draw(st.integers(0, W - 1))
        width = draw(st.integers(0, W))
        cols = (u0 + np.arange(width)) % W
        valid[v0:v1, cols] = False
    noise = draw(st.floats(0, 1))
    seed = draw(st.integers(0, 2 ** 16))
    valid &= np.random.default_rng(seed).uniform(size=(H, W)) >= noise * 0.5
    radius = draw(st.integers(1, 12))
    return valid, radius, seed


@settings(max_examples=60, deadline=None)
@given(masks())
def test_fill_property_matches_slow_rule(case):
    valid, radius, seed = case
    H, W = valid.shape
    rad = np.random.default_rng(seed).uniform(0, 1, (H, W, 3)).astype(np.float32)
    want, want_used = fill_ref.fill_missing(rad, valid, radius_px=radius)
    rad[~valid] = np.nan
    out, used = sh.fill_missing(rad, valid, radius_px=radius)
    np.testing.assert_array_equal(used, want_used)
    np.testing.assert_array_equal(out[used], want[used].astype(np.float32))
    L = sh.project_equirect(rad, valid, bands=3, fill_radius_px=radius)
    ref = brute_project(np.where(want_used[..., None], want, 0.0), 3)
    assert np.abs(L - ref).max() <= 1e-6 * max(1.0, np.abs(ref).max())


@settings(max_examples=60, deadline=None)
@given(masks())
def test_fill_plan_states_the_reference_sources_and_keys(case):
    """The plan lists every missing pixel in raster order with the source and rank key the rule
    gives it, and marks the rows that contribute nothing."""
    valid, radius, _ = case
    H, W = valid.shape
    want_src, want_key = fill_ref.fill_sources(valid, radius)
    plan = sh.fill_plan(valid, radius)
    p = np.repeat(np.arange(H), np.diff(plan.row_ptr)) * W + plan.col
    np.testing.assert_array_equal(p, np.flatnonzero(~valid.reshape(-1)))
    np.testing.assert_array_equal(plan.src, want_src[p])
    np.testing.assert_array_equal(plan.key, want_key[p])
    contributes = valid.any(1) | (want_src.reshape(H, W) >= 0).any(1)
    np.testing.assert_array_equal(plan.empty, ~contributes)


@pytest.mark.parametrize("H,W,bands,radius", [(12, 24, 5, 50), (9, 27, 6, 3), (16, 20, 11, 5), (5, 6, 1, 2),
                                              (1, 1, 3, 1)])
def test_projection_matches_the_reference_sum(H, W, bands, radius):
    """rgbd_envmap.reference.sh_projection sums Y_k · radiance · Ω over the filled pixels in float64;
    the library's float32 row sums agree to float32 rounding."""
    rng = np.random.default_rng(H * W + bands)
    rad = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    valid = rng.uniform(size=(H, W)) > 0.5
    valid[: H // 3] = False
    planes = np.ascontiguousarray(np.moveaxis(rad, -1, 0))
    for mask in (None, valid):
        ref = projection_ref.project_equirect(rad, mask, bands, radius)
        for L in (sh.project_equirect(rad, mask, bands, fill_radius_px=radius),
                  sh.project_planar(planes, mask, bands, fill_radius_px=radius)):
            assert np.abs(L - ref).max() <= 1e-6 * max(np.abs(ref).max(), 1e-300)


def test_fill_plan_checks_its_arguments():
    with pytest.raises(ShapeError):
        sh.fill_plan(np.ones((2, 3, 1), bool))
    with pytest.raises(DTypeError):
        sh.fill_plan(np.ones((2, 3)))
    with pytest.raises(RangeError):
        sh.fill_plan(np.ones((2, 3), bool), 0)


def test_fill_single_data_pixel_in_row_and_wrapping_runs():
    H, W = 3, 16
    rad = np.zeros((H, W, 3), np.float32)
    valid = np.zeros((H, W), bool)
    valid[1, 5] = True
    rad[1, 5] = 9
    out, used = sh.fill_missing(rad, valid, radius_px=8)
    # row 1: columns 5 − 8 … 5 + 8 (wrapping) reach the one pixel; left wins at equal distance 8
    assert used[1].all() and (out[1, :, 0] == 9).all()
    assert used[0, 5] and used[2, 5] and not used[0, 4]  # vertical only straight up / down
    valid[:] = True
    valid[1, :3] = valid[1, -2:] = False  # one run across the seam: columns 14, 15, 0, 1, 2
    rad[:] = (np.arange(W) + 100 * np.arange(H)[:, None])[..., None]  # value = 100 v + u
    out, _ = sh.fill_missing(rad, valid)
    np.testing.assert_array_equal(out[1, [14, 15, 0, 1, 2], 0], [14, 15, 0, 1, 2])  # up (row 0) first
    valid[0] = valid[2] = False  # now only horizontal sources: 113 on the left, 103 on the right
    out, used = sh.fill_missing(rad, valid)
    np.testing.assert_array_equal(out[1, [14, 15, 0, 1, 2], 0], [113, 113, 113, 103, 103])  # tie at 0 → left
    out, used = sh.fill_missing(rad, valid, radius_px=1)
    np.testing.assert_array_equal(used[1, [14, 15, 0, 1, 2]], [True, False, False, False, True])
    assert out[1, 14, 0] == 113 and out[1, 2, 0] == 103


# --- band selection -----------------------------------------------------------------------------------

def unshadowed_transfer(normals, bands):
    """T_k(n) = Â_l Y_k(n): the PRT transfer of an unoccluded vertex (Funk–Hecke)."""
    a = sh.lambertian_band_factors(bands)
    return sh.basis(normals, bands) * a[np.repeat(np.arange(bands), 2 * np.arange(bands) + 1)]


def sphere_normals(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def explicit_errors(L, T, N, w=None):
    w = np.ones(T.shape[0]) if w is None else w
    ref = T[:, :N * N] @ L[:N * N]
    norm = lambda X: np.sqrt((w[:, None] * X * X).sum())
    return np.array([norm(T[:, :n * n] @ L[:n * n] - ref) / norm(ref) for n in range(1, N + 1)])


def test_unshadowed_transfer_shades_like_irradiance():
    n = sphere_normals(50)
    L = np.random.default_rng(1).normal(size=(36, 3))
    np.testing.assert_allclose(unshadowed_transfer(n, 6) @ L, sh.irradiance(L, n), atol=1e-12)


def test_select_bands_constant_environment_needs_one_band():
    L = sh.project_equirect(np.full((100, 200, 3), 0.7, np.float32), bands=8)
    T = unshadowed_transfer(sphere_normals(2000), 8).astype(np.float32)
    r = sh.select_bands(L, T)
    assert r.bands == 1 and r.max_bands == 8 and not r.degenerate
    assert r.errors[0] < 1e-3  # only the θ-quadrature residue of the even bands


def test_select_bands_directional_light_needs_more():
    # a small bright source (radius 5°) over a dim uniform background
    d, _ = grid(200, 400)
    s = np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85])
    rad = (0.05 + 50.0 * (d @ s > np.cos(np.radians(5))))[..., None].repeat(3, -1).astype(np.float32)
    L = sh.project_equirect(rad, bands=8)
    T = unshadowed_transfer(sphere_normals(5000), 8)
    r = sh.select_bands(L, T, tolerance=0.01)
    assert r.bands >= 5
    assert r.errors[r.bands - 1] <= 0.01 < r.errors[r.bands - 2]  # the fewest that pass
    np.testing.assert_allclose(r.errors, explicit_errors(L, T, 8), rtol=1e-9, atol=1e-12)
    # a looser tolerance never needs more bands
    assert sh.select_bands(L, T, tolerance=0.1).bands <= r.bands


@pytest.mark.parametrize("weighted", [False, True])
def test_select_bands_matches_explicit_shading_raw_and_gram(weighted):
    rng = np.random.default_rng(3)
    T = rng.normal(size=(400, 49)).astype(np.float32)  # "shadowed": no band is zero
    L = rng.normal(size=(64, 3)) / (1 + np.arange(64))[:, None]
    w = rng.uniform(0, 2, 400) if weighted else None
    want = explicit_errors(L, T.astype(np.float64), 7, w)
    raw = sh.select_bands(L, T, tolerance=0.05, weights=w)
    gram = sh.select_bands(L, sh.transfer_gram(T, w), tolerance=0.05)
    for r, rtol in ((raw, 1e-6), (gram, 1e-9)):  # raw float32 transfer: float32 products
        assert r.max_bands == 7  # transfer has 7 bands, coeffs 8
        np.testing.assert_allclose(r.errors, want, rtol=rtol, atol=1e-12)
        assert r.bands == int(np.argmax(want <= 0.05)) + 1
    assert sh.select_bands(L, T, 0.0).bands == 7  # tolerance 0: the maximum
    assert sh.select_bands(L, T, 0.0, max_bands=4).bands == 4
    assert sh.select_bands(L, T, 1.0).bands == 1


def test_select_bands_tolerance_zero_and_zero_bands():
    # Unshadowed transfer: Â_l = 0 for odd l ≥ 3, so band l = 7 adds exactly nothing and 7 bands
    # reproduce 8 exactly; with max_bands = 7 (top band l = 6, nonzero) tolerance 0 gives 7.
    L = np.random.default_rng(4).normal(size=(64, 3))
    T = unshadowed_transfer(sphere_normals(500), 8)
    assert sh.select_bands(L, T, 0.0).bands == 7
    assert sh.select_bands(L, T, 0.0, max_bands=7).bands == 7
    assert sh.select_bands(L, sh.transfer_gram(T), 0.0).bands == 7


def test_select_bands_degenerate_black_scene():
    T = unshadowed_transfer(sphere_normals(100), 5)
    r = sh.select_bands(np.zeros((25, 3)), T)
    assert r.degenerate and r.bands == 1 and (r.errors == 0).all()
    r = sh.select_bands(np.zeros((25, 3)), sh.transfer_gram(T))
    assert r.degenerate and r.bands == 1
    assert sh.select_bands(np.ones((25, 3)), np.zeros((10, 25))).degenerate  # zero transfer


def test_select_bands_result_is_frozen():
    r = sh.select_bands(np.ones((9, 3)), unshadowed_transfer(sphere_normals(10), 3))
    with pytest.raises(AttributeError):
        r.bands = 2
    with pytest.raises(ValueError):
        r.errors[0] = 1.0
    g = sh.transfer_gram(np.ones((4, 9)))
    assert g.gram.shape == (9, 9) and g.n_vertices == 4 and not g.gram.flags.writeable


def test_select_bands_bad_input():
    T = unshadowed_transfer(sphere_normals(20), 4)
    L = np.ones((16, 3))
    bad = L.copy()
    bad[3, 1] = np.nan
    with pytest.raises(NonFiniteError):
        sh.select_bands(bad, T)
    Tb = T.copy()
    Tb[5, 2] = np.inf
    with pytest.raises(NonFiniteError):
        sh.select_bands(L, Tb)
    with pytest.raises(NonFiniteError):
        sh.transfer_gram(Tb)
    for tol in (-0.1, np.nan, np.inf):
        with pytest.raises(RangeError):
            sh.select_bands(L, T, tol)
    with pytest.raises(DTypeError):
        sh.select_bands(L, T, "small")
    for mb in (0, 5):
        with pytest.raises(RangeError):
            sh.select_bands(L, T, max_bands=mb)
    with pytest.raises(ShapeError):
        sh.select_bands(np.ones((15, 3)), T)
    with pytest.raises(ShapeError):
        sh.select_bands(L, T[:, :15])
    with pytest.raises(ShapeError):
        sh.select_bands(L, np.zeros((0, 16)))
    with pytest.raises(ShapeError):
        sh.select_bands(L, T[:, :, None])
    with pytest.raises(ShapeError):
        sh.select_bands(L, T, weights=np.ones(19))
    with pytest.raises(RangeError):
        sh.select_bands(L, T, weights=-np.ones(20))
    with pytest.raises(InvalidInputError):
        sh.select_bands(L, sh.transfer_gram(T), weights=np.ones(20))
    assert issubclass(InvalidInputError, RgbdEnvmapError)


# --- incremental projection --------------------------------------------------------------------------

def _fresh_state(valid, radius):
    """The fill state a fresh plan gives: (src, key) per pixel, −2 / 0 at data pixels."""
    H, W = valid.shape
    row_ptr, col, src, _, key = sh.fill_plan(valid, radius)
    s = np.full(H * W, -2, np.int64)
    k = np.zeros(H * W, np.int64)
    rows = np.repeat(np.arange(H), np.diff(row_ptr))
    s[rows * W + col] = np.where(src >= 0, src, -1)
    k[rows * W + col] = key
    return s, k


def _capture_frames(em, rng, n_frames, trusted_every=0):
    """Random frames through envmap.update: clusters of points (some straight up / down for the
    poles, some across the seam), devices far from and (every ``trusted_every``) at the origin."""
    from rgbd_envmap.envmap import update

    for i in range(n_frames):
        n = int(rng.integers(1, 400))
        centre = rng.normal(size=3)
        if i % 7 == 3:
            centre = np.array([0.0, 0.0, rng.choice([-1.0, 1.0])])  # a pole
        if i % 7 == 5:
            centre = np.array([-1.0, 0.0, 0.0])  # the seam (φ = ±π)
        pts = 2.0 * centre + rng.normal(size=(n, 3)) * rng.uniform(0.05, 0.6)
        near = trusted_every and i % trusted_every == trusted_every - 1
        dev = rng.normal(size=3) * (0.02 if near else 1.0)
        update(em, pts, rng.random((n, 3)).astype(np.float32), dev, float(rng.uniform(20, 200)))
        yield i


@pytest.mark.parametrize("shape,radius,bands", [((40, 80), 50, 5), ((50, 100), 7, 3), ((16, 8), 50, 2),
                                                ((120, 240), 50, 8), ((30, 60), 1, 1), ((24, 300), 70, 6)])
def test_incremental_projection_follows_updates_exactly(shape, radius, bands):
    """After every update the coefficients equal a full projection, and the fill state equals the
    state a fresh plan gives (source and rank of every missing pixel), so errors cannot accumulate."""
    from rgbd_envmap.envmap import EnvironmentMap

    rng = np.random.default_rng(sum(shape) + radius + bands)
    em = EnvironmentMap(*shape)
    proj = sh.IncrementalProjection(bands, fill_radius_px=radius)
    for _ in _capture_frames(em, rng, 25, trusted_every=9):
        c = proj.coefficients(em)
        ref = sh.project_planar(em.radiance_planes, em.valid, bands, fill_radius_px=radius)
        assert np.abs(c - ref).max() <= 1e-6 * max(np.abs(ref).max(), 1e-30)
        src, key = _fresh_state(em.valid, radius)
        state_src, state_key = proj._fill_state(shape[1])
        np.testing.assert_array_equal(state_src, src)
        np.testing.assert_array_equal(state_key, key)
    assert proj.incremental_updates > 10  # the incremental path ran, not only rebuilds


def test_incremental_fill_state_is_the_reference_rule():
    """The tracker's per-pixel fill state names the source and key the rule itself gives."""
    from rgbd_envmap.envmap import EnvironmentMap

    rng = np.random.default_rng(21)
    em = EnvironmentMap(30, 60)
    proj = sh.IncrementalProjection(4, fill_radius_px=6)
    for _ in _capture_frames(em, rng, 8, trusted_every=5):
        proj.coefficients(em)
        src, key = proj._fill_state(60)
        want_src, want_key = fill_ref.fill_sources(em.valid, 6)
        np.testing.assert_array_equal(src, want_src)
        np.testing.assert_array_equal(key, want_key)
    assert proj.incremental_updates > 3


def test_incremental_projection_of_a_full_map():
    """Every pixel has data: no fill at all, the state stays all data, only colour changes (A)."""
    from rgbd_envmap.envmap import EnvironmentMap

    rng = np.random.default_rng(3)
    rad = rng.random((30, 60, 3)).astype(np.float32)
    em = EnvironmentMap.from_arrays(rad, np.full((30, 60), 50.0), np.ones((30, 60), bool), np.zeros(3))
    proj = sh.IncrementalProjection(4)
    for _ in _capture_frames(em, rng, 12, trusted_every=3):
        c = proj.coefficients(em)
        ref = sh.project_planar(em.radiance_planes, em.valid, 4)
        assert np.abs(c - ref).max() <= 1e-6 * np.abs(ref).max()
    assert proj.incremental_updates >= 6
    src, key = proj._fill_state(60)
    assert (src == -2).all() and (key == 0).all()


def test_incremental_projection_rebuilds_on_log_overflow_and_large_change_sets():
    from rgbd_envmap.envmap import ChangeLog, EnvironmentMap

    rng = np.random.default_rng(5)
    em = EnvironmentMap(40, 80)
    proj = sh.IncrementalProjection(3, fill_radius_px=20)
    frames = _capture_frames(em, rng, 30)
    next(frames)
    proj.coefficients(em)
    em.change_log = ChangeLog(2)  # the next update overflows this log
    next(frames)
    c = proj.coefficients(em)
    assert (proj.full_projections, proj.incremental_updates) == (2, 0)
    np.testing.assert_allclose(c, sh.project_planar(em.radiance_planes, em.valid, 3, fill_radius_px=20),
                               rtol=1e-6, atol=1e-12)
    next(frames)
    proj.coefficients(em)
    assert (proj.full_projections, proj.incremental_updates) == (2, 1)
    proj._max_changed_fraction = 0.0  # any change set is "large": project in full
    next(frames)
    proj.coefficients(em)
    assert (proj.full_projections, proj.incremental_updates) == (3, 1)
    proj._max_changed_fraction = 1.0
    for _ in range(5):
        next(frames)
        c = proj.coefficients(em)
    assert (proj.full_projections, proj.incremental_updates) == (3, 6)
    ref = sh.project_planar(em.radiance_planes, em.valid, 3, fill_radius_px=20)
    assert np.abs(c - ref).max() <= 1e-6 * np.abs(ref).max()
    src, key = _fresh_state(em.valid, 20)
    state_src, state_key = proj._fill_state(80)
    np.testing.assert_array_equal(state_src, src)
    np.testing.assert_array_equal(state_key, key)


def test_incremental_projection_key_types():
    """One byte of fill state per pixel up to radius 62, two beyond."""
    assert sh.IncrementalProjection(fill_radius_px=50)._key_dtype is np.uint8
    assert sh.IncrementalProjection(fill_radius_px=62)._key_dtype is np.uint8
    assert sh.IncrementalProjection(fill_radius_px=63)._key_dtype is np.uint16


@pytest.mark.parametrize("records", [1, 3])
def test_incremental_projection_with_a_tiny_record_buffer(records):
    """Changes off the current row (copies met walking a column, switched fills) are buffered and
    sorted by row in batches; a buffer of 1 or 3 flushes mid-row and mid-walk and must not matter."""
    from rgbd_envmap.envmap import EnvironmentMap

    rng = np.random.default_rng(7 + records)
    em = EnvironmentMap(40, 80)
    proj = sh.IncrementalProjection(5, fill_radius_px=9)
    proj._records = records
    for _ in _capture_frames(em, rng, 20, trusted_every=7):
        c = proj.coefficients(em)
        ref = sh.project_planar(em.radiance_planes, em.valid, 5, fill_radius_px=9)
        assert np.abs(c - ref).max() <= 1e-6 * max(np.abs(ref).max(), 1e-30)
    assert proj.incremental_updates > 10


def test_incremental_projection_rebuilds_when_the_log_cannot_tell():
    from rgbd_envmap.envmap import EnvironmentMap, translate

    rng = np.random.default_rng(1)
    em = EnvironmentMap(40, 80)
    proj = sh.IncrementalProjection(3)
    np.testing.assert_array_equal(proj.coefficients(em), np.zeros((9, 3)))  # empty map
    next(_capture_frames(em, rng, 1))
    proj.coefficients(em)
    assert (proj.full_projections, proj.incremental_updates) == (1, 1)
    em.radiance_planes[:, 10, 10] = 5.0  # a direct write, announced
    em.valid[10, 10] = True
    em.mark_modified()
    c = proj.coefficients(em)
    assert proj.full_projections == 2
    np.testing.assert_allclose(c, sh.project_planar(em.radiance_planes, em.valid, 3), rtol=1e-6, atol=1e-12)
    moved = translate(em, np.array([0.05, 0.0, 0.0]))  # another map object
    c = proj.coefficients(moved)
    assert proj.full_projections == 3
    np.testing.assert_allclose(c, sh.project_planar(moved.radiance_planes, moved.valid, 3), rtol=1e-6, atol=1e-12)
    c = proj.coefficients(em)  # back to the first map: its log was not followed meanwhile
    assert proj.full_projections == 4
    c[:] = 0  # a copy: the tracker's state is untouched
    assert proj.coefficients(em).any()


def test_incremental_projection_of_non_finite_data_raises():
    from rgbd_envmap.envmap import EnvironmentMap

    # from_arrays refuses NaN where valid; a map's arrays written directly can still hold it.
    em = EnvironmentMap(20, 40)
    em.radiance_planes[:] = 1.0
    em.radiance_planes[1, 3, 4] = np.nan
    em.depth_m[:] = 1.0
    em.valid[:] = True
    with pytest.raises(NonFiniteError):
        sh.IncrementalProjection(2).coefficients(em)
    with pytest.raises(RangeError):
        sh.IncrementalProjection(0)
