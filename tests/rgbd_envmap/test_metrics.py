"""Tests for rgbd_envmap.metrics: WS-PSNR, sphere-weighted correlation, coverage, data loss, depth errors.

References are independent of the code under test: pixel solid angles re-derived here from the
docs/reference/conventions.md cos-difference formula with ``math.cos`` (never through ``geometry``), Sun et al.'s
cos(latitude) ERP weights, ``np.cov(..., aweights=...)`` for the weighted Pearson correlation, and
hand-worked values for the closed forms.
"""

from __future__ import annotations

import doctest
import math
import warnings
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgbd_envmap import metrics
from rgbd_envmap.errors import DTypeError, NonFiniteError, RangeError, RgbdEnvmapError, ShapeError


@dataclass(frozen=True)
class _Tolerances:
    db: float = 1e-10  #: dB, float64 closed forms (ratios of weighted sums)
    rel: float = 1e-12  #: relative, a float64 metric against an independent float64 computation
    corr: float = 1e-12  #: correlation coefficients computed in float64
    coverage: float = 1e-14  #: absolute, solid-angle fractions (sums of ~1e3-1e5 float64 terms)
    noise_corr: float = 0.02  #: |r| of two independent seeded noise maps of 128×256 (≈ 6σ)
    m: float = 1e-12  #: metres, depth error summaries


TOL = _Tolerances()


def _row_solid_angles(h: int, w: int) -> np.ndarray:
    """(H,) exact solid angle of one pixel in each row: (2π/W)(cos θ_top − cos θ_bottom)."""
    return np.array([(2 * math.pi / w) * (math.cos(math.pi * v / h) - math.cos(math.pi * (v + 1) / h))
                     for v in range(h)])


def _pixel_weights(h: int, w: int) -> np.ndarray:
    return np.repeat(_row_solid_angles(h, w)[:, None], w, axis=1)


def _sun_weights(h: int, w: int) -> np.ndarray:
    """Sun et al. (2017) ERP weights: w(i, j) = cos((j + 0.5 − N/2) π / N), j the row, N = H."""
    j = np.arange(h)
    return np.repeat(np.cos((j + 0.5 - h / 2) * np.pi / h)[:, None], w, axis=1)


def _reference_ws_psnr(a, b, weights, valid=None, peak=1.0) -> float:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    valid = np.ones(a.shape[:2], bool) if valid is None else valid
    wv = weights[valid]
    err = ((a[valid] - b[valid]) ** 2).mean(axis=1)
    wmse = np.sum(wv * err) / np.sum(wv)
    return 10 * math.log10(peak**2 / wmse)


def _reference_correlation(a, b, weights, valid=None) -> np.ndarray:
    """Per-channel weighted Pearson r through np.cov's analytic weights."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    valid = np.ones(a.shape[:2], bool) if valid is None else valid
    out = []
    for c in range(a.shape[2]):
        cov = np.cov(a[..., c][valid], b[..., c][valid], aweights=weights[valid])
        out.append(cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1]))
    return np.array(out)


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


# --------------------------------------------------------------------------------------------------
# ws_psnr
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(8, 16), (8, 16, 3), (50, 100, 3), (7, 13, 2), (1, 2), (1, 2, 3)])
@pytest.mark.parametrize("delta", [0.25, 0.1, 1e-3, -0.05])
def test_ws_psnr_of_constant_offset_is_closed_form(shape, delta):
    a = _rng(0).random(shape)
    assert metrics.ws_psnr(a, a + delta) == pytest.approx(10 * math.log10(1 / delta**2), abs=TOL.db)


def test_ws_psnr_uses_peak():
    a = np.zeros((10, 20, 3))
    assert metrics.ws_psnr(a, a + 5.0, peak=255.0) == pytest.approx(10 * math.log10(255**2 / 25), abs=TOL.db)


def test_ws_psnr_pools_channels_into_one_wmse():
    a = np.zeros((6, 12, 3))
    deltas = np.array([0.1, 0.2, 0.3])
    assert metrics.ws_psnr(a, a + deltas) == pytest.approx(10 * math.log10(1 / np.mean(deltas**2)), abs=TOL.db)


@pytest.mark.parametrize("h", [4, 8, 9, 64])
def test_ws_psnr_weights_polar_rows_less_than_equator_rows(h):
    w, delta = 2 * h, 0.5
    a = np.zeros((h, w, 3))
    polar, equator = a.copy(), a.copy()
    polar[0] = delta
    equator[h // 2] = delta
    p_polar, p_equator = metrics.ws_psnr(a, polar), metrics.ws_psnr(a, equator)
    assert p_polar > p_equator
    # Hand value: WMSE = δ² · W ω_row / 4π = δ² (cos θ_top − cos θ_bottom) / 2.
    for v, got in ((0, p_polar), (h // 2, p_equator)):
        dcos = math.cos(math.pi * v / h) - math.cos(math.pi * (v + 1) / h)
        assert got == pytest.approx(10 * math.log10(1 / (delta**2 * dcos / 2)), abs=TOL.db)


def test_ws_psnr_weighting_differs_from_plain_psnr():
    h, w = 16, 32
    a = np.zeros((h, w))
    b = a.copy()
    b[0] = 0.5  # an error confined to the polar row
    plain = 10 * math.log10(1 / np.mean((a - b) ** 2))
    assert metrics.ws_psnr(a, b) > plain + 5.0


@pytest.mark.parametrize("shape", [(8, 16, 3), (33, 66, 3), (20, 40), (5, 7, 4)])
def test_ws_psnr_matches_independent_computation(shape):
    rng = _rng(1)
    a, b = rng.random(shape), rng.random(shape)
    valid = rng.random(shape[:2]) < 0.7
    weights = _pixel_weights(*shape[:2])
    assert metrics.ws_psnr(a, b) == pytest.approx(_reference_ws_psnr(a, b, weights), rel=TOL.rel)
    assert metrics.ws_psnr(a, b, valid) == pytest.approx(_reference_ws_psnr(a, b, weights, valid), rel=TOL.rel)


@pytest.mark.parametrize("shape", [(8, 16, 3), (33, 66, 3), (100, 200)])
def test_ws_psnr_equals_sun_et_al_cos_latitude_weighting(shape):
    # The exact solid angles are exactly proportional to cos(latitude) at the pixel centre.
    rng = _rng(2)
    a, b = rng.random(shape), rng.random(shape)
    valid = rng.random(shape[:2]) < 0.5
    sun = _sun_weights(*shape[:2])
    assert metrics.ws_psnr(a, b) == pytest.approx(_reference_ws_psnr(a, b, sun), rel=TOL.rel)
    assert metrics.ws_psnr(a, b, valid) == pytest.approx(_reference_ws_psnr(a, b, sun, valid), rel=TOL.rel)


def test_ws_psnr_valid_mask_excludes_pixels():
    rng = _rng(3)
    a = rng.random((10, 20, 3))
    b = a + 0.1
    valid = np.ones((10, 20), bool)
    valid[:, 5:9] = False
    b[~valid] = 1e3  # huge errors at invalid pixels ...
    b[2, 6] = np.nan  # ... and a NaN, all ignored
    assert metrics.ws_psnr(a, b, valid) == pytest.approx(20.0, abs=TOL.db)
    assert metrics.ws_psnr(a, b, valid) > metrics.ws_psnr(a, np.nan_to_num(b))


def test_ws_psnr_of_identical_maps_is_inf():
    a = _rng(4).random((8, 16, 3))
    assert metrics.ws_psnr(a, a.copy()) == math.inf
    valid = np.zeros((8, 16), bool)
    valid[3] = True
    b = a.copy()
    b[~valid] += 1.0
    assert metrics.ws_psnr(a, b, valid) == math.inf


def test_ws_psnr_with_no_valid_pixel_is_nan_without_warning():
    a = np.zeros((4, 8, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert math.isnan(metrics.ws_psnr(a, a + 1, np.zeros((4, 8), bool)))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", ["a", "b"])
def test_ws_psnr_rejects_non_finite_at_valid_pixels(bad, where):
    a = np.zeros((4, 8, 3))
    b = a + 0.1
    (a if where == "a" else b)[1, 2, 0] = bad
    with pytest.raises(NonFiniteError, match=where):
        metrics.ws_psnr(a, b)
    valid = np.ones((4, 8), bool)
    with pytest.raises(NonFiniteError, match=f"{where}: .*valid"):
        metrics.ws_psnr(a, b, valid)
    valid[1, 2] = False
    assert metrics.ws_psnr(a, b, valid) == pytest.approx(20.0, abs=TOL.db)


def test_ws_psnr_of_same_infinity_in_both_is_rejected():
    a = np.zeros((2, 4))
    a[0, 0] = np.inf
    with pytest.raises(NonFiniteError):
        metrics.ws_psnr(a, a.copy())


def test_ws_psnr_overflow_of_finite_values_is_minus_inf():
    a = np.full((2, 4), 1e200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert metrics.ws_psnr(a, -a) == -math.inf


def test_ws_psnr_of_uint8_does_not_wrap_around():
    a = np.zeros((4, 8, 3), np.uint8)
    b = np.full((4, 8, 3), 255, np.uint8)
    assert metrics.ws_psnr(a, b, peak=255) == pytest.approx(0.0, abs=TOL.db)
    assert metrics.ws_psnr(b, a, peak=255) == pytest.approx(0.0, abs=TOL.db)


def test_ws_psnr_float32_agrees_with_float64():
    rng = _rng(5)
    a, b = rng.random((50, 100, 3)), rng.random((50, 100, 3))
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    assert metrics.ws_psnr(a32, b32) == pytest.approx(metrics.ws_psnr(a32.astype(np.float64), b32.astype(np.float64)),
                                                      rel=TOL.rel)
    assert metrics.ws_psnr(a32, b32) == pytest.approx(metrics.ws_psnr(a, b), rel=1e-6)


def test_ws_psnr_single_channel_layouts_agree():
    rng = _rng(6)
    a, b = rng.random((8, 16)), rng.random((8, 16))
    assert metrics.ws_psnr(a, b) == metrics.ws_psnr(a[..., None], b[..., None])


def test_ws_psnr_is_symmetric_and_returns_python_float():
    rng = _rng(7)
    a, b = rng.random((8, 16, 3)), rng.random((8, 16, 3))
    out = metrics.ws_psnr(a, b)
    assert type(out) is float
    assert out == pytest.approx(metrics.ws_psnr(b, a), rel=TOL.rel)


def test_ws_psnr_tiny_1x2_map():
    a = np.array([[0.0, 0.0]])
    b = np.array([[0.1, 0.3]])  # both pixels cover 2π: plain mean
    assert metrics.ws_psnr(a, b) == pytest.approx(10 * math.log10(1 / ((0.01 + 0.09) / 2)), abs=TOL.db)
    assert metrics.ws_psnr(a, b, np.array([[False, True]])) == pytest.approx(10 * math.log10(1 / 0.09), abs=TOL.db)


# --------------------------------------------------------------------------------------------------
# sphere_correlation
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(8, 16, 3), (31, 62, 3), (16, 32), (1, 2, 3)])
def test_correlation_of_affine_images_is_plus_or_minus_one(shape):
    a = _rng(10).random(shape)
    assert metrics.sphere_correlation(a, 2 * a + 1) == pytest.approx(1.0, abs=TOL.corr)
    assert metrics.sphere_correlation(a, -a) == pytest.approx(-1.0, abs=TOL.corr)
    assert metrics.sphere_correlation(a, -3 * a + 0.5) == pytest.approx(-1.0, abs=TOL.corr)


def test_correlation_of_independent_noise_is_near_zero():
    rng = _rng(11)
    a, b = rng.random((128, 256, 3)), rng.random((128, 256, 3))
    r = metrics.sphere_correlation(a, b, per_channel=True)
    assert np.all(np.abs(r) < TOL.noise_corr)


@pytest.mark.parametrize("shape", [(8, 16, 3), (40, 80, 3), (9, 18), (6, 10, 4)])
def test_correlation_matches_weighted_pearson_reference(shape):
    rng = _rng(12)
    a = rng.random(shape)
    b = 0.6 * a + 0.4 * rng.random(shape)
    valid = rng.random(shape[:2]) < 0.6
    weights = _pixel_weights(*shape[:2])
    for mask in (None, valid):
        ref = _reference_correlation(a, b, weights, mask)
        np.testing.assert_allclose(metrics.sphere_correlation(a, b, mask, per_channel=True), ref, rtol=0, atol=TOL.corr)
        assert metrics.sphere_correlation(a, b, mask) == pytest.approx(ref.mean(), abs=TOL.corr)


def test_correlation_is_weighted_by_solid_angle():
    # Noise strong near the poles and weak at the equator: the sphere weighting sees a high
    # correlation, a plain per-pixel Pearson a lower one.
    h, w = 64, 128
    rng = _rng(13)
    a = rng.random((h, w))
    lat = np.abs(np.pi * (np.arange(h) + 0.5) / h - np.pi / 2)[:, None]
    b = a + (lat > 1.2) * 3.0 * rng.standard_normal((h, w))
    got = metrics.sphere_correlation(a, b)
    plain = np.corrcoef(a.ravel(), b.ravel())[0, 1]
    sun = _reference_correlation(a, b, _sun_weights(h, w))[0]
    assert got == pytest.approx(sun, abs=TOL.corr)
    assert got > plain + 0.05


def test_correlation_is_symmetric_and_affine_invariant():
    rng = _rng(14)
    a, b = rng.random((12, 24, 3)), rng.random((12, 24, 3))
    b += a
    r = metrics.sphere_correlation(a, b)
    assert metrics.sphere_correlation(b, a) == pytest.approx(r, abs=TOL.corr)
    assert metrics.sphere_correlation(5 * a - 2, 0.1 * b + 7) == pytest.approx(r, abs=TOL.corr)


def test_correlation_constant_channel_is_nan_and_skipped_in_mean():
    rng = _rng(15)
    a = rng.random((8, 16, 3))
    b = a + 0.3 * rng.random((8, 16, 3))
    b[..., 1] = 0.1  # constant in b (0.1 is not a binary fraction: rounding must not fake variance)
    r = metrics.sphere_correlation(a, b, per_channel=True)
    assert math.isnan(r[1]) and np.isfinite(r[[0, 2]]).all()
    assert metrics.sphere_correlation(a, b) == pytest.approx(np.mean(r[[0, 2]]), abs=TOL.corr)
    a2 = a.copy()
    a2[..., 0] = 0.7  # constant in a
    r2 = metrics.sphere_correlation(a2, b, per_channel=True)
    assert np.isnan(r2[:2]).all() and math.isfinite(r2[2])


def test_correlation_constant_over_valid_pixels_only_is_nan():
    rng = _rng(16)
    a, b = rng.random((8, 16)), rng.random((8, 16))
    valid = np.zeros((8, 16), bool)
    valid[2:4] = True
    a[valid] = 0.3
    assert math.isnan(metrics.sphere_correlation(a, b, valid))
    assert math.isfinite(metrics.sphere_correlation(a, b))


@pytest.mark.parametrize("case", ["all_constant", "no_valid", "one_valid"])
def test_correlation_degenerate_cases_are_nan_without_warning(case):
    rng = _rng(17)
    a, b = rng.random((4, 8, 3)), rng.random((4, 8, 3))
    valid = None
    if case == "all_constant":
        a = np.full_like(a, 0.1)
    elif case == "no_valid":
        valid = np.zeros((4, 8), bool)
    else:
        valid = np.zeros((4, 8), bool)
        valid[1, 3] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert math.isnan(metrics.sphere_correlation(a, b, valid))
        assert np.isnan(metrics.sphere_correlation(a, b, valid, per_channel=True)).all()


def test_correlation_valid_mask_excludes_pixels():
    rng = _rng(18)
    a = rng.random((10, 20, 3))
    b = 2 * a + 1
    valid = rng.random((10, 20)) < 0.5
    b[~valid] = rng.random((np.count_nonzero(~valid), 3))
    b[~valid & (np.arange(20) % 3 == 0)] = np.nan
    assert metrics.sphere_correlation(a, b, valid) == pytest.approx(1.0, abs=TOL.corr)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("where", ["a", "b"])
def test_correlation_rejects_non_finite_at_valid_pixels(bad, where):
    rng = _rng(19)
    a, b = rng.random((4, 8, 3)), rng.random((4, 8, 3))
    (a if where == "a" else b)[2, 5, 1] = bad
    with pytest.raises(NonFiniteError, match=where):
        metrics.sphere_correlation(a, b)
    valid = np.ones((4, 8), bool)
    with pytest.raises(NonFiniteError, match=where):
        metrics.sphere_correlation(a, b, valid)
    valid[2, 5] = False
    assert math.isfinite(metrics.sphere_correlation(a, b, valid))


def test_correlation_with_one_valid_pixel_still_rejects_nan_there():
    a, b = np.zeros((2, 4)), np.ones((2, 4))
    a[1, 1] = np.nan
    valid = np.zeros((2, 4), bool)
    valid[1, 1] = True
    with pytest.raises(NonFiniteError, match="a"):
        metrics.sphere_correlation(a, b, valid)
    valid[1, 1], valid[0, 0] = False, True
    assert math.isnan(metrics.sphere_correlation(a, b, valid))


def test_correlation_tiny_1x2_map():
    a = np.array([[0.0, 1.0]])
    assert metrics.sphere_correlation(a, np.array([[3.0, 5.0]])) == pytest.approx(1.0, abs=TOL.corr)
    assert metrics.sphere_correlation(a, np.array([[5.0, 3.0]])) == pytest.approx(-1.0, abs=TOL.corr)


def test_correlation_of_uint8_and_float32_inputs():
    rng = _rng(20)
    a8 = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
    b8 = (255 - a8).astype(np.uint8)
    assert metrics.sphere_correlation(a8, b8) == pytest.approx(-1.0, abs=TOL.corr)
    a, b = rng.random((16, 32, 3)), rng.random((16, 32, 3)) + rng.random((16, 32, 3))
    b = b + a
    r32 = metrics.sphere_correlation(a.astype(np.float32), b.astype(np.float32))
    assert r32 == pytest.approx(metrics.sphere_correlation(a, b), abs=1e-6)
    assert type(r32) is float


# --------------------------------------------------------------------------------------------------
# Row blocks: the map metrics work on blocks of rows; results must not depend on where blocks split
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("block_elements", [1, 7 * 20 * 3, 10**9])  # one row, uneven split, one block
def test_metrics_do_not_depend_on_row_blocking(monkeypatch, block_elements):
    monkeypatch.setattr(metrics, "_BLOCK_ELEMENTS", block_elements)
    rng = _rng(50)
    h, w = 31, 20
    a = rng.random((h, w, 3))
    b = 0.7 * a + 0.3 * rng.random((h, w, 3))
    valid = rng.random((h, w)) < 0.8
    b_nan = b.copy()
    b_nan[~valid] = np.nan  # NaN at invalid pixels spread over many blocks
    weights = _pixel_weights(h, w)
    for bb in (b, b_nan):
        assert metrics.ws_psnr(a, bb, valid) == pytest.approx(_reference_ws_psnr(a, b, weights, valid), rel=TOL.rel)
        np.testing.assert_allclose(metrics.sphere_correlation(a, bb, valid, per_channel=True),
                                   _reference_correlation(a, b, weights, valid), rtol=0, atol=TOL.corr)
    assert metrics.ws_psnr(a, b) == pytest.approx(_reference_ws_psnr(a, b, weights), rel=TOL.rel)
    np.testing.assert_allclose(metrics.sphere_correlation(a, b, per_channel=True),
                               _reference_correlation(a, b, weights), rtol=0, atol=TOL.corr)
    b_bad = b.copy()
    b_bad[-1, -1, 2] = np.nan  # in the last block, at a valid pixel
    valid[-1, -1] = True
    with pytest.raises(NonFiniteError, match="b"):
        metrics.ws_psnr(a, b_bad, valid)
    with pytest.raises(NonFiniteError, match="b"):
        metrics.sphere_correlation(a, b_bad, valid)


def test_metrics_on_a_full_size_float32_map():
    # 1000×2000×3 float32, the pipeline's EM size, against the float64 references.
    rng = _rng(51)
    h, w = 1000, 2000
    a = rng.random((h, w, 3), dtype=np.float32)
    b = (a + 0.1 * rng.random((h, w, 3), dtype=np.float32)).astype(np.float32)
    valid = rng.random((h, w)) < 0.9
    weights = _pixel_weights(h, w)
    assert metrics.ws_psnr(a, b, valid) == pytest.approx(_reference_ws_psnr(a, b, weights, valid), rel=1e-10)
    np.testing.assert_allclose(metrics.sphere_correlation(a, b, valid, per_channel=True),
                               _reference_correlation(a, b, weights, valid), rtol=0, atol=1e-10)


def test_correlation_of_a_constant_channel_with_a_large_offset_is_nan():
    # 1000.1 is not a binary fraction: the computed weighted mean differs from it by rounding.
    rng = _rng(52)
    a = rng.random((200, 400, 2))
    a[..., 0] = 1000.1
    b = rng.random((200, 400, 2))
    r = metrics.sphere_correlation(a, b, per_channel=True)
    assert math.isnan(r[0]) and math.isfinite(r[1])
    a[0, 0, 0] = 1000.2  # one pixel differs: a real (small) correlation, not NaN
    assert math.isfinite(metrics.sphere_correlation(a, b, per_channel=True)[0])


# --------------------------------------------------------------------------------------------------
# Seam and poles: longitude rolls
# --------------------------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(shift=st.integers(-40, 40), seed=st.integers(0, 2**16), h=st.integers(1, 12))
def test_rolling_along_longitude_leaves_metrics_unchanged(shift, seed, h):
    rng = _rng(seed)
    w = 2 * h
    a = rng.random((h, w, 3))
    b = 0.5 * a + 0.5 * rng.random((h, w, 3))
    valid = rng.random((h, w)) < 0.8
    valid[0, 0] = True
    valid[-1, -1] = True  # at least two valid pixels, one at each pole row and seam column

    def roll(x):
        return np.roll(x, shift, axis=1)

    assert metrics.ws_psnr(roll(a), roll(b)) == pytest.approx(metrics.ws_psnr(a, b), rel=TOL.rel)
    assert metrics.ws_psnr(roll(a), roll(b), roll(valid)) == pytest.approx(metrics.ws_psnr(a, b, valid), rel=TOL.rel)
    np.testing.assert_allclose(metrics.sphere_correlation(roll(a), roll(b), roll(valid), per_channel=True),
                               metrics.sphere_correlation(a, b, valid, per_channel=True), rtol=0, atol=1e-10)
    assert metrics.coverage(roll(valid)) == pytest.approx(metrics.coverage(valid), abs=TOL.coverage)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), h=st.integers(1, 16), w=st.integers(2, 33))
def test_correlation_is_bounded(seed, h, w):
    rng = _rng(seed)
    a = rng.standard_normal((h, w, 2))
    b = a * rng.uniform(-2, 2) + rng.standard_normal((h, w, 2)) * rng.uniform(0, 2)
    r = metrics.sphere_correlation(a, b, per_channel=True)
    assert np.all((r >= -1.0) & (r <= 1.0))


def test_flipping_north_south_leaves_metrics_unchanged():
    # The weights are symmetric about the equator.
    rng = _rng(21)
    a, b = rng.random((10, 20, 3)), rng.random((10, 20, 3))
    valid = rng.random((10, 20)) < 0.7
    assert metrics.ws_psnr(a[::-1], b[::-1], valid[::-1]) == pytest.approx(metrics.ws_psnr(a, b, valid), rel=TOL.rel)
    assert metrics.coverage(valid[::-1]) == pytest.approx(metrics.coverage(valid), abs=TOL.coverage)


# --------------------------------------------------------------------------------------------------
# coverage, coverage_of, data_loss
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("h, w", [(1, 2), (4, 8), (9, 18), (50, 100), (7, 5)])
def test_coverage_of_all_and_none(h, w):
    assert metrics.coverage(np.ones((h, w), bool)) == pytest.approx(1.0, abs=TOL.coverage)
    assert metrics.coverage(np.zeros((h, w), bool)) == 0.0


@pytest.mark.parametrize("h", [2, 4, 10, 100, 1000])
def test_coverage_of_northern_half_is_one_half(h):
    valid = np.zeros((h, 2 * h), bool)
    valid[: h // 2] = True
    assert metrics.coverage(valid) == pytest.approx(0.5, abs=TOL.coverage)


@pytest.mark.parametrize("h, w, v", [(8, 16, 0), (8, 16, 3), (9, 18, 4), (1, 2, 0)])
def test_coverage_of_one_row_and_one_pixel_is_hand_value(h, w, v):
    valid = np.zeros((h, w), bool)
    valid[v] = True
    dcos = math.cos(math.pi * v / h) - math.cos(math.pi * (v + 1) / h)
    assert metrics.coverage(valid) == pytest.approx(dcos / 2, abs=TOL.coverage)
    one = np.zeros((h, w), bool)
    one[v, w - 1] = True
    assert metrics.coverage(one) == pytest.approx(dcos / (2 * w), abs=TOL.coverage)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), h=st.integers(1, 20), w=st.integers(1, 40))
def test_coverage_of_mask_and_complement_sum_to_one(seed, h, w):
    valid = _rng(seed).random((h, w)) < 0.4
    total = metrics.coverage(valid) + metrics.coverage(~valid)
    assert total == pytest.approx(1.0, abs=TOL.coverage)
    ref = float(np.sum(_pixel_weights(h, w)[valid]) / (4 * math.pi))
    assert metrics.coverage(valid) == pytest.approx(ref, abs=TOL.coverage)


def test_coverage_of_simple_cases():
    h, w = 10, 20
    ref = np.zeros((h, w), bool)
    ref[:5] = True  # reference: the northern hemisphere
    assert metrics.coverage_of(ref, ref) == pytest.approx(1.0, abs=TOL.coverage)
    assert metrics.coverage_of(np.ones((h, w), bool), ref) == pytest.approx(1.0, abs=TOL.coverage)
    assert metrics.coverage_of(~ref, ref) == 0.0  # data outside the reference does not count
    east = np.zeros((h, w), bool)
    east[:, :5] = True
    assert metrics.coverage_of(east, ref) == pytest.approx(0.25, abs=TOL.coverage)
    everything = np.ones((h, w), bool)
    assert metrics.coverage_of(ref, everything) == pytest.approx(metrics.coverage(ref), abs=TOL.coverage)


def test_coverage_of_with_empty_reference_is_nan():
    assert math.isnan(metrics.coverage_of(np.ones((4, 8), bool), np.zeros((4, 8), bool)))


def test_data_loss_simple_cases():
    h, w = 10, 20
    full = np.ones((h, w), bool)
    north = np.zeros((h, w), bool)
    north[:5] = True
    assert metrics.data_loss(full, full) == 0.0
    assert metrics.data_loss(full, np.zeros((h, w), bool)) == pytest.approx(1.0, abs=TOL.coverage)
    assert metrics.data_loss(full, north) == pytest.approx(0.5, abs=TOL.coverage)
    assert metrics.data_loss(north, full) == 0.0  # gains are not counted as negative loss
    shifted = np.roll(north, 5, axis=1)  # same coverage, different pixels
    shifted[5:, :5] = True
    lost = north & ~shifted
    expected = _pixel_weights(h, w)[lost].sum() / _pixel_weights(h, w)[north].sum()
    assert metrics.data_loss(north, shifted) == pytest.approx(expected, abs=TOL.coverage)
    assert metrics.data_loss(north, shifted) == pytest.approx(1 - metrics.coverage_of(shifted, north), abs=TOL.coverage)


def test_data_loss_with_nothing_before_is_nan():
    assert math.isnan(metrics.data_loss(np.zeros((4, 8), bool), np.ones((4, 8), bool)))


def test_coverage_tiny_1x2_map():
    assert metrics.coverage(np.array([[True, False]])) == pytest.approx(0.5, abs=TOL.coverage)
    loss = metrics.data_loss(np.array([[True, True]]), np.array([[False, True]]))
    assert loss == pytest.approx(0.5, abs=TOL.coverage)


# --------------------------------------------------------------------------------------------------
# depth_errors
# --------------------------------------------------------------------------------------------------


def test_depth_errors_hand_values():
    truth = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    estimate = truth + np.array([[0.1, -0.2, 0.3], [-0.4, 9.0, np.nan]])
    mask = np.array([[True, True, True], [True, False, False]])
    out = metrics.depth_errors(estimate, truth, mask)
    assert out["n"] == 4 and type(out["n"]) is int
    # |e| sorted: 0.1 0.2 0.3 0.4; p95 interpolates at rank 0.95·3 = 2.85 → 0.3 + 0.85·0.1.
    expected = {"mae": 0.25, "rmse": math.sqrt(0.30 / 4), "median_abs": 0.25, "p95_abs": 0.385, "bias": -0.05}
    for key, value in expected.items():
        assert out[key] == pytest.approx(value, abs=TOL.m), key
        assert type(out[key]) is float


def test_depth_errors_with_empty_mask_is_nan():
    out = metrics.depth_errors(np.ones((3, 4)), np.ones((3, 4)), np.zeros((3, 4), bool))
    assert out["n"] == 0
    assert all(math.isnan(out[k]) for k in ("mae", "rmse", "median_abs", "p95_abs", "bias"))


def test_depth_errors_of_exact_estimate_are_zero_and_work_for_any_shape():
    truth = _rng(30).uniform(0.2, 4.0, (2, 3, 5)).astype(np.float32)
    out = metrics.depth_errors(truth, truth.copy(), np.ones(truth.shape, bool))
    assert out["n"] == 30 and out["mae"] == out["rmse"] == out["p95_abs"] == out["bias"] == 0.0


@pytest.mark.parametrize("where", ["estimate", "truth"])
def test_depth_errors_reject_non_finite_inside_mask(where):
    est, tru = np.ones((2, 3)), np.ones((2, 3))
    (est if where == "estimate" else tru)[1, 1] = np.nan
    with pytest.raises(NonFiniteError, match=where):
        metrics.depth_errors(est, tru, np.ones((2, 3), bool))


def test_depth_errors_validation():
    with pytest.raises(ShapeError, match="truth"):
        metrics.depth_errors(np.ones((2, 3)), np.ones((3, 2)), np.ones((2, 3), bool))
    with pytest.raises(ShapeError, match="mask"):
        metrics.depth_errors(np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 2), bool))
    with pytest.raises(DTypeError, match="mask"):
        metrics.depth_errors(np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 3)))
    with pytest.raises(DTypeError, match="estimate"):
        metrics.depth_errors(np.array([["a"]]), np.ones((1, 1)), np.ones((1, 1), bool))


# --------------------------------------------------------------------------------------------------
# Validation shared by the map metrics
# --------------------------------------------------------------------------------------------------


IMAGE_METRICS = [metrics.ws_psnr, metrics.sphere_correlation]


@pytest.mark.parametrize("fn", IMAGE_METRICS)
def test_image_metrics_reject_shape_mismatch(fn):
    with pytest.raises(ShapeError, match="b"):
        fn(np.zeros((4, 8, 3)), np.zeros((4, 8, 2)))
    with pytest.raises(ShapeError, match="b"):
        fn(np.zeros((4, 8)), np.zeros((4, 8, 1)))
    with pytest.raises(ShapeError, match="valid"):
        fn(np.zeros((4, 8, 3)), np.zeros((4, 8, 3)), np.ones((4, 8, 3), bool))
    with pytest.raises(ShapeError, match="valid"):
        fn(np.zeros((4, 8, 3)), np.zeros((4, 8, 3)), np.ones((8, 4), bool))


@pytest.mark.parametrize("fn", IMAGE_METRICS)
@pytest.mark.parametrize("shape", [(8,), (2, 4, 8, 3), (0, 0), (0, 8, 3)])
def test_image_metrics_reject_bad_rank_or_empty(fn, shape):
    with pytest.raises(ShapeError, match="a"):
        fn(np.zeros(shape), np.zeros(shape))


@pytest.mark.parametrize("fn", IMAGE_METRICS)
def test_image_metrics_reject_bad_dtypes(fn):
    a = np.zeros((4, 8, 3))
    with pytest.raises(DTypeError, match="valid"):
        fn(a, a, np.ones((4, 8)))
    with pytest.raises(DTypeError, match="valid"):
        fn(a, a, np.ones((4, 8), np.uint8))
    with pytest.raises(DTypeError, match="a"):
        fn(a.astype(bool), a.astype(bool))
    with pytest.raises(DTypeError, match="b"):
        fn(a, a.astype(complex))


@pytest.mark.parametrize("peak", [0.0, -1.0, np.nan, np.inf])
def test_ws_psnr_rejects_bad_peak(peak):
    with pytest.raises(RangeError, match="peak"):
        metrics.ws_psnr(np.zeros((2, 4)), np.ones((2, 4)), peak=peak)


MASK_METRICS = [metrics.coverage, lambda v: metrics.coverage_of(v, v), lambda v: metrics.data_loss(v, v)]


@pytest.mark.parametrize("fn", MASK_METRICS)
def test_mask_metrics_reject_bad_masks(fn):
    with pytest.raises(DTypeError):
        fn(np.ones((4, 8)))
    with pytest.raises(ShapeError):
        fn(np.ones((4, 8, 1), bool))
    with pytest.raises(ShapeError):
        fn(np.ones((0, 8), bool))


def test_pair_mask_metrics_reject_shape_mismatch():
    with pytest.raises(ShapeError, match="valid"):
        metrics.coverage_of(np.ones((4, 8), bool), np.ones((8, 16), bool))
    with pytest.raises(ShapeError, match="after_valid"):
        metrics.data_loss(np.ones((4, 8), bool), np.ones((8, 16), bool))
    with pytest.raises(DTypeError, match="reference_valid"):
        metrics.coverage_of(np.ones((4, 8), bool), np.ones((4, 8)))


def test_errors_are_project_errors_and_builtins():
    with pytest.raises(RgbdEnvmapError):
        metrics.ws_psnr(np.zeros((2, 4)), np.zeros((2, 5)))
    with pytest.raises(ValueError):
        metrics.ws_psnr(np.zeros((2, 4)), np.zeros((2, 5)))
    with pytest.raises(TypeError):
        metrics.coverage(np.ones((2, 4)))


def test_inputs_are_not_modified():
    rng = _rng(40)
    a, b = rng.random((6, 12, 3)), rng.random((6, 12, 3))
    valid = rng.random((6, 12)) < 0.5
    copies = [a.copy(), b.copy(), valid.copy()]
    metrics.ws_psnr(a, b, valid)
    metrics.sphere_correlation(a, b, valid)
    metrics.coverage(valid)
    for x, y in zip((a, b, valid), copies):
        np.testing.assert_array_equal(x, y)


def test_docstring_examples():
    result = doctest.testmod(metrics, extraglobs={"np": np}, optionflags=doctest.ELLIPSIS)
    assert result.attempted >= 2 and result.failed == 0


# --- composite_errors -------------------------------------------------------------------------------


def _composite_case():
    h, w = 40, 60
    yy, xx = np.mgrid[:h, :w]
    obj = (abs(yy - 10) < 4) & (abs(xx - 15) < 4)
    disc = (yy - 25) ** 2 + (xx - 40) ** 2 < 64
    without = np.full((h, w, 3), 0.8)
    with_obj = without.copy()
    with_obj[disc] *= 0.5  # the object's shadow
    with_obj[obj] = [0.3, 0.2, 0.1]
    return with_obj, without, obj, disc


def test_composite_errors_closed_form_regions_and_values():
    with_obj, without, obj, disc = _composite_case()
    ours = with_obj.copy()
    ours[obj] *= 1.1  # 10 % too bright on the object
    ours[disc] *= 0.8  # 20 % too dark in the shadow
    e = metrics.composite_errors(ours, with_obj, without, obj, np.ones(obj.shape, bool), window_px=1)
    assert np.array_equal(e["shadow_mask"], disc)
    assert e["object_pixels"] == obj.sum() and e["shadow_pixels"] == disc.sum()
    assert e["object_rel_rmse"] == pytest.approx(0.1, rel=1e-12)
    assert e["shadow_rel_rmse"] == pytest.approx(0.2, rel=1e-12)
    both = obj | disc
    expect = np.sqrt(np.sum((ours[both] - with_obj[both]) ** 2) / np.sum(with_obj[both] ** 2))
    assert e["rel_rmse"] == pytest.approx(expect, rel=1e-12)


def test_composite_errors_window_ignores_isolated_noise_and_keeps_a_real_shadow():
    with_obj, without, obj, disc = _composite_case()
    rng = np.random.default_rng(3)
    speckle = rng.random(obj.shape) < 0.003
    yy, xx = np.mgrid[:obj.shape[0], :obj.shape[1]]
    speckle &= ((yy - 25) ** 2 + (xx - 40) ** 2 > 14 ** 2) & ~obj  # farther than the window from the shadow
    noisy = with_obj.copy()
    noisy[speckle] *= 1.3  # isolated path-tracing outliers
    e1 = metrics.composite_errors(noisy, noisy, without, obj, np.ones(obj.shape, bool), window_px=1)
    e7 = metrics.composite_errors(noisy, noisy, without, obj, np.ones(obj.shape, bool), window_px=7)
    assert (e1["shadow_mask"] & speckle).sum() == speckle.sum()
    assert not (e7["shadow_mask"] & speckle).any()
    assert (e7["shadow_mask"] & disc).sum() >= 0.9 * disc.sum()


def test_composite_errors_reads_nothing_outside_valid_and_is_nan_for_empty_regions():
    with_obj, without, obj, disc = _composite_case()
    ours = with_obj.copy()
    valid = ~obj
    ours[obj] = np.nan
    e = metrics.composite_errors(ours, with_obj, without, obj, valid, window_px=1)
    assert math.isnan(e["object_rel_rmse"]) and e["object_pixels"] == 0
    assert e["shadow_rel_rmse"] == 0.0
    same = metrics.composite_errors(without, without, without, np.zeros(obj.shape, bool), np.ones(obj.shape, bool))
    assert same["shadow_pixels"] == 0 and math.isnan(same["rel_rmse"])
    with pytest.raises(NonFiniteError, match="ours"):
        metrics.composite_errors(ours, with_obj, without, obj, np.ones(obj.shape, bool))
    with pytest.raises(RangeError, match="window_px"):
        metrics.composite_errors(ours, with_obj, without, obj, valid, window_px=4)
