"""Tests for rgbd_envmap.sh: real SH basis, equirect projection with the stage-8 fill, irradiance.

References are independent of the code under test: the DESIGN.md §3 table of the first 9 functions,
scipy.special.sph_harm_y (complex SH) converted to the real Condon–Shortley basis, quadrature on an
equirect grid with directions and solid angles re-derived here, closed-form coefficients of the
constant and hemisphere functions, a slow obvious implementation of the fill rule and a brute-force
clamped-cosine convolution.

Tolerances:
    basis vs scipy: 1e-6 absolute (both float64, values O(1)).
    orthonormality by quadrature on 400×800: 1e-3 (midpoint-rule error ~ (l π / H)² ≈ 3e-4 at l = 7).
    projection vs float64 brute force: 1e-5 relative to the largest coefficient (float32 row sums).
    hemisphere at 3 bands: the 3-band result is exactly π/2 + (π/2) z (L_20 of the hemisphere is 0),
        so the only error is quadrature of the map, < 1e-4 at 250×500.
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
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)

# --- independent references -----------------------------------------------------------------------

def grid(H, W):
    """(H, W, 3) float64 directions and (H, W) exact solid angles, from CONVENTIONS.md."""
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
    factor would cancel the phase and give +0.488603 x for Y_1,1, contradicting DESIGN.md §3; the
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


def slow_fill(rad, valid, radius=50):
    """The stage-8 rule written out: nearest data pixel along up/down/left/right, ties in that order."""
    H, W, _ = rad.shape
    out = np.zeros_like(rad, dtype=np.float64)
    used = np.ones((H, W), bool)
    for v in range(H):
        for u in range(W):
            if valid[v, u]:
                out[v, u] = rad[v, u]
                continue
            best = None
            for order, (dv, du) in enumerate([(-1, 0), (1, 0), (0, -1), (0, 1)]):
                for dist in range(1, radius + 1):
                    vv, uu = v + dv * dist, (u + du * dist) % W
                    if not 0 <= vv < H:
                        break
                    if valid[vv, uu]:
                        if best is None or (dist, order) < best[0]:
                            best = ((dist, order), (vv, uu))
                        break
            if best is None:
                used[v, u] = False
            else:
                out[v, u] = rad[best[1]]
    return out, used


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
    # The reference conversion itself must give DESIGN's band-1 signs.
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
    d, omega = grid(400, 800)
    Y = sh.basis(d.reshape(-1, 3), 8)
    gram = Y.T @ (Y * omega.reshape(-1, 1))
    assert np.abs(gram - np.eye(64)).max() <= 1e-3


def test_basis_shapes_scaling_and_tiling():
    rng = np.random.default_rng(2)
    d = rng.normal(size=(6, 3))
    one = sh.basis(d, 5)
    assert one.shape == (6, 25) and one.dtype == np.float64
    np.testing.assert_array_equal(sh.basis(d.reshape(2, 3, 3), 5), one.reshape(2, 3, 25))
    np.testing.assert_allclose(sh.basis(7.5 * d, 5), one, atol=1e-14)
    assert sh.basis(np.array([0.0, 0, 1]), 3).shape == (9,)
    assert sh.basis(np.array([[0, 0, 1]]), 3).shape == (1, 9)  # integer input accepted


def test_high_band_count_is_finite_and_normalised():
    d, omega = grid(200, 400)
    Y = sh.basis(d.reshape(-1, 3), 30)
    assert np.isfinite(Y).all()
    norms = (Y * Y * omega.reshape(-1, 1)).sum(0)
    np.testing.assert_allclose(norms, 1.0, atol=5e-2)


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


def test_projection_matches_float64_brute_force_2000x1000():
    rad = smooth_map(1000, 2000)
    L = sh.project_equirect(rad, bands=5)
    d, omega = grid(1000, 2000)
    ref = np.zeros((25, 3))
    for v0 in range(0, 1000, 100):  # chunks keep memory small
        Y = scipy_real_sh(d[v0:v0 + 100].reshape(-1, 3), 5)
        ref += Y.T @ (rad[v0:v0 + 100].reshape(-1, 3).astype(np.float64) * omega[v0:v0 + 100].reshape(-1, 1))
    assert np.abs(L - ref).max() <= 1e-5 * np.abs(ref).max()


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
    want, want_used = slow_fill(rad, valid, radius=12)
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
    want_rad, used = slow_fill(rad, valid, radius=50)
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
