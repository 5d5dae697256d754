"""Tests for the colour-correction matrix in rgbd_envmap.colour (paper 003 §5): estimate_ccm, apply_ccm,
invert_ccm.

References, each computed here independently of the code under test: colour-science's
``matrix_colour_correction`` ('Cheung 2004', 3 terms, a Moore–Penrose pseudo-inverse fit), the closed
form of the normal equations (:func:`rgbd_envmap.reference.colour.ccm_least_squares_reference`), and
colour-science's ColorChecker data, colour-space conversions and CIEDE2000 for the colour-error figure.

Camera model used by the ColorChecker tests (one "frame" per trial): reference linear sRGB of the 24
patches of 'ColorChecker24 - After November 2014' (clipped at 0: the cyan patch's R is −0.043, outside
the sRGB gamut, and a camera cannot see a negative value) → per-channel gains log-uniform in
[0.25, 4] (exposure × white balance) → channel mixing I + off-diagonals uniform in ±0.05 → 50 pixels
per patch with Gaussian noise σ = 0.5 % of the signal + 0.002 → clip to [0, 1]. Pixels with a channel at
1.0 are dropped by estimate_ccm's ``saturation`` rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import colour as colour_science  # colour-science; not to be confused with rgbd_envmap.colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rgbd_envmap import colour
from rgbd_envmap.colour import CCM_METHODS, CCMResult, apply_ccm, estimate_ccm, invert_ccm
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    ShapeError,
    UnknownMethodError,
)
from rgbd_envmap.reference.colour import ccm_least_squares_reference


@dataclass(frozen=True)
class _Tolerances:
    vs_colour_science: float = 1e-6  #: matrix entries, estimate_ccm vs colour-science 'Cheung 2004'
    vs_closed_form: float = 1e-9  #: matrix entries vs (AᵀA)⁻¹AᵀB in float64 (measured ~1e-13)
    mse_rel: float = 1e-9  #: MSE from the normal-equation sums vs the direct residual mean
    mse_floor: float = 1e-12  #: MSE of a noise-free fit (cancellation floor of the sums formula)
    exact_recovery: float = 1e-9  #: noise-free data: recovered matrix vs the true one
    round_trip_f64: float = 1e-12  #: apply(apply(x, M), invert(M)) vs x
    round_trip_f32: float = 1e-5
    colorchecker_de00: float = 1.0  #: mean CIEDE2000 over accepted trials (measured 0.12)
    colorchecker_accept_rate: float = 0.95  #: share of trials with enough unsaturated pairs (measured 0.975)
    outlier_in_range_dm: float = 0.02  #: max |ΔM| after one in-range gross outlier in 1000 (measured 0.0095)
    outlier_bright_dm: float = 0.05  #: max |ΔM| after one radiance-20 outlier in 1000 (measured 0.031)


TOL = _Tolerances()
TRUE_M = np.array([[1.1, 0.04, -0.02], [0.03, 0.95, 0.02], [-0.03, 0.05, 1.3]])
D65 = colour_science.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]


def _random_pairs(n: int, seed: int, noise: float = 0.002, matrix: np.ndarray = TRUE_M) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    src = rng.uniform(0.05, 0.95, (n, 3))
    return src, src @ matrix.T + noise * rng.standard_normal((n, 3))


# ------------------------------------------------------------------------------------------------
# ColorChecker helpers
# ------------------------------------------------------------------------------------------------


def _colorchecker_linear_srgb() -> np.ndarray:
    cc = colour_science.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    xyY = np.array(list(cc.data.values()))
    rgb = colour_science.XYZ_to_sRGB(
        colour_science.xyY_to_XYZ(xyY), illuminant=cc.illuminant, apply_cctf_encoding=False
    )
    return np.clip(rgb, 0.0, None)  # the cyan patch's R is −0.043: out of gamut, seen as 0


REF = _colorchecker_linear_srgb()
GREYS = np.arange(18, 24)  # white 9.5 … black 2
CHROMATIC = np.arange(18)


def _lab(rgb_linear: np.ndarray) -> np.ndarray:
    xyz = colour_science.sRGB_to_XYZ(rgb_linear, apply_cctf_decoding=False)
    return colour_science.XYZ_to_Lab(xyz, D65)


def _de00(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return colour_science.delta_E(_lab(a), _lab(b), method="CIE 2000")


def _camera(rng: np.random.Generator, gains: np.ndarray | None = None) -> np.ndarray:
    """(3, 3) camera transform diag(gains) @ (I + mixing)."""
    g = np.exp(rng.uniform(np.log(0.25), np.log(4.0), 3)) if gains is None else np.asarray(gains, np.float64)
    mix = np.eye(3) + rng.uniform(-0.05, 0.05, (3, 3)) * (1.0 - np.eye(3))
    return np.diag(g) @ mix


def _capture(rng: np.random.Generator, cam: np.ndarray, patches: np.ndarray, px: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame pixels float32, reference colours float32), px noisy pixels per patch, clipped to [0, 1]."""
    clean = np.repeat(REF[patches] @ cam.T, px, axis=0)
    noisy = clean + rng.standard_normal(clean.shape) * (0.005 * np.abs(clean) + 0.002)
    return np.clip(noisy, 0.0, 1.0).astype(np.float32), np.repeat(REF[patches], px, axis=0).astype(np.float32)


# ------------------------------------------------------------------------------------------------
# Against independent references
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_colour_science_cheung2004(seed: int) -> None:
    src, dst = _random_pairs(5000, seed, noise=0.02)
    rng = np.random.default_rng(seed + 100)
    m_random = rng.uniform(-0.5, 0.5, (3, 3)) + np.eye(3)  # an arbitrary, not near-diagonal, matrix
    dst = src @ m_random.T + 0.02 * rng.standard_normal(src.shape)
    expected = colour_science.characterisation.matrix_colour_correction(src, dst, method="Cheung 2004", terms=3)
    r = estimate_ccm(src, dst)
    assert r.accepted and r.method == "least_squares"
    np.testing.assert_allclose(r.matrix, expected, rtol=0, atol=TOL.vs_colour_science)
    np.testing.assert_allclose(r.matrix, ccm_least_squares_reference(src, dst), rtol=0, atol=TOL.vs_closed_form)


LEAST_SQUARES_METHODS = tuple(m for m in CCM_METHODS if m != "ridge")


@pytest.mark.parametrize("method", LEAST_SQUARES_METHODS)
def test_every_method_gives_the_least_squares_matrix(method: str) -> None:
    src, dst = _random_pairs(3000, 7, noise=0.01)
    r = estimate_ccm(src.astype(np.float32), dst.astype(np.float32), method)
    a, b = src.astype(np.float32).astype(np.float64), dst.astype(np.float32).astype(np.float64)
    assert r.accepted and r.method == method and r.n_pairs == 3000
    np.testing.assert_allclose(r.matrix, ccm_least_squares_reference(a, b), rtol=0, atol=TOL.vs_closed_form)


@pytest.mark.parametrize("method", CCM_METHODS)
def test_mse_is_mean_over_pairs_and_channels(method: str) -> None:
    src, dst = _random_pairs(2000, 3, noise=0.05)
    r = estimate_ccm(src, dst, method)
    direct = np.mean((src @ r.matrix.T - dst) ** 2)  # mean over 2000 × 3 values
    assert r.mse == pytest.approx(direct, rel=TOL.mse_rel)
    assert r.mse == pytest.approx(0.05**2, rel=0.1)  # the noise variance per channel


def test_recovers_a_known_matrix_from_float32_pixels() -> None:
    src, _ = _random_pairs(38_528, 11)
    src32 = src.astype(np.float32)
    r = estimate_ccm(src32, src32.astype(np.float64) @ TRUE_M.T)
    np.testing.assert_allclose(r.matrix, TRUE_M, rtol=0, atol=TOL.exact_recovery)
    # The MSE comes from the normal-equation sums, tr(BᵀB) − tr(XᵀAᵀB): cancellation leaves an absolute
    # floor near 1e-13 × the mean square of dst (measured 1.7e-14 here), irrelevant next to the 5e-2 gate.
    assert r.mse < TOL.mse_floor and r.accepted


@settings(max_examples=50, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    gains=st.tuples(*[st.floats(0.25, 4.0)] * 3),
    off=st.lists(st.floats(-0.2, 0.2), min_size=9, max_size=9),
)
def test_property_exact_data_is_recovered(seed: int, gains: tuple, off: list) -> None:
    m = np.diag(gains) @ (np.eye(3) + np.array(off).reshape(3, 3) * (1.0 - np.eye(3)))
    src = np.random.default_rng(seed).uniform(0.0, 0.99, (600, 3))
    r = estimate_ccm(src, src @ m.T)
    assert r.accepted
    np.testing.assert_allclose(r.matrix, m, rtol=0, atol=TOL.exact_recovery * np.abs(m).max())


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), gains=st.tuples(*[st.floats(0.1, 10.0)] * 3))
def test_property_condition_and_fit_are_equivariant_to_src_gains(seed: int, gains: tuple) -> None:
    """κ is invariant to per-channel gains of src (exposure, white balance) and M(src G) = M(src) G⁻¹."""
    src, dst = _random_pairs(800, seed % 1000, noise=0.01)
    g = np.diag(gains)
    r0 = estimate_ccm(src, dst, saturation=None)
    r1 = estimate_ccm(src @ g, dst, saturation=None)
    assert r1.condition == pytest.approx(r0.condition, rel=1e-9)
    np.testing.assert_allclose(r1.matrix, r0.matrix @ np.linalg.inv(g), rtol=1e-9, atol=1e-12)
    assert r1.mse == pytest.approx(r0.mse, rel=1e-6, abs=1e-15)


# ------------------------------------------------------------------------------------------------
# ColorChecker: the colour error after correction
# ------------------------------------------------------------------------------------------------


def test_colorchecker_mean_ciede2000_after_correction() -> None:
    """200 simulated frames of the chart: M maps the frame back to the reference; CIEDE2000 between the
    corrected noise-free camera colours of all 24 patches and the reference (so patches dropped as
    saturated in a trial still count: they test the matrix, not the pixels)."""
    rng = np.random.default_rng(2018)
    des, des_uncorrected, reasons = [], [], []
    for _ in range(200):
        cam = _camera(rng)
        src, dst = _capture(rng, cam, np.arange(24), px=50)
        r = estimate_ccm(src, dst)
        seen = REF @ cam.T
        des_uncorrected.append(_de00(np.clip(seen, 0, 1), REF).mean())
        if not r.accepted:
            reasons.append(r.reason)
            continue
        des.append(_de00(apply_ccm(seen, r.matrix), REF).mean())
    assert len(des) >= TOL.colorchecker_accept_rate * 200
    # Every rejection is a frame so over-exposed that fewer than 500 unsaturated pixels are left.
    assert all(reason.startswith("too few pairs") and "saturated" in reason for reason in reasons)
    assert np.mean(des) <= TOL.colorchecker_de00
    assert np.mean(des_uncorrected) > 10.0  # the gains are far from identity: the test can fail


# ------------------------------------------------------------------------------------------------
# Hard cases, each named after what it breaks
# ------------------------------------------------------------------------------------------------


def test_grey_patches_only_are_rejected_as_ill_conditioned() -> None:
    """The six greys fix only M·(1, 1, 1); the chroma directions are fitted to noise. The MSE is tiny, so
    without the condition gate the frame would be accepted with a matrix that ruins colours."""
    for seed in range(20):
        rng = np.random.default_rng(seed)
        cam = _camera(rng, gains=(1.0, 1.0, 1.0))
        src, dst = _capture(rng, cam, GREYS, px=200)
        r = estimate_ccm(src, dst)
        assert not r.accepted
        assert r.reason.startswith("ill-conditioned (condition number") and r.condition > colour.DEFAULT_MAX_CONDITION
        assert r.mse < 1e-4  # the MSE gate alone would accept it
        assert np.isfinite(r.matrix).all() and r.n_pairs == 1200  # best-effort fit still carried
        assert _de00(apply_ccm(REF[CHROMATIC] @ cam.T, r.matrix), REF[CHROMATIC]).mean() > 10.0


def test_dark_grey_patches_pass_the_condition_gate_but_not_the_noise_gate() -> None:
    """Documented limit of κ: under a 0.25 gain the additive noise (0.002) is a sizeable part of the dark
    greys' signal and spreads the samples in every direction, κ falls to ~6e3 < 1e4 and the default gate
    accepts a matrix fitted to noise. Given the sensor noise, gate 4 rejects it."""
    rng = np.random.default_rng(5)
    cam = _camera(rng, gains=(0.25, 0.25, 0.25))
    src, dst = _capture(rng, cam, GREYS, px=200)
    r = estimate_ccm(src, dst)
    assert r.accepted and 1e3 < r.condition < colour.DEFAULT_MAX_CONDITION
    assert _de00(apply_ccm(REF[CHROMATIC] @ cam.T, r.matrix), REF[CHROMATIC]).mean() > 10.0
    r_noise = estimate_ccm(src, dst, noise_std=0.002)
    assert not r_noise.accepted and r_noise.reason.startswith("weak colour spread")
    # The full chart under the same gain and noise passes gate 4.
    full_src, full_dst = _capture(rng, cam, np.arange(24), px=50)
    assert estimate_ccm(full_src, full_dst, noise_std=0.002).accepted


def test_single_colour_exact_is_rank_deficient() -> None:
    src = np.tile([[0.6, 0.3, 0.1]], (1000, 1))
    r = estimate_ccm(src, src * 1.5)
    assert not r.accepted and r.reason == "rank-deficient (condition number inf)"
    assert np.isfinite(r.matrix).all()  # minimum-norm best effort
    np.testing.assert_allclose(src[:1] @ r.matrix.T, src[:1] * 1.5, atol=1e-9)  # right on that colour


@pytest.mark.parametrize("method", CCM_METHODS)
def test_a_dead_channel_is_rank_deficient(method: str) -> None:
    src, dst = _random_pairs(1000, 14)
    src[:, 2] = 0.0  # blue never seen: M's third column is undetermined
    r = estimate_ccm(src, dst, method)
    assert not r.accepted and r.reason.startswith("rank-deficient (condition number")
    assert np.isfinite(r.matrix).all() and np.isfinite(r.mse)


def test_single_colour_with_mild_noise_is_ill_conditioned() -> None:
    rng = np.random.default_rng(0)
    src = np.array([0.6, 0.4, 0.2]) * (1.0 + 0.005 * rng.standard_normal((1000, 3)))
    r = estimate_ccm(src, np.tile([0.5, 0.5, 0.5], (1000, 1)))
    assert not r.accepted and r.reason.startswith("ill-conditioned") and r.condition > 1e4


def test_single_dark_colour_with_sensor_noise_needs_noise_std() -> None:
    """The red patch (G, B ≈ 0.05) with noise 0.002: the noise alone spreads the samples enough for κ
    ≈ 1e3, so the default gate accepts; gate 4 with the sensor noise rejects it."""
    rng = np.random.default_rng(1)
    cam = _camera(rng, gains=(1.0, 1.0, 1.0))
    src, dst = _capture(rng, cam, np.array([14]), px=1000)
    assert estimate_ccm(src, dst).accepted
    r = estimate_ccm(src, dst, noise_std=0.002)
    assert not r.accepted and r.reason.startswith("weak colour spread")


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_pairs_are_too_few_whatever_min_pairs(n: int) -> None:
    src, dst = _random_pairs(n, 0)
    r = estimate_ccm(src, dst, min_pairs=1)
    assert not r.accepted and r.reason == f"too few pairs ({n} < 3)"
    assert r.n_pairs == n and np.array_equal(r.matrix, np.eye(3)) and np.isnan(r.mse)


def test_too_few_pairs_comes_first_and_still_fits() -> None:
    src, dst = _random_pairs(120, 4)
    r = estimate_ccm(src, dst)  # min_pairs 500
    assert not r.accepted and r.reason == "too few pairs (120 < 500)"
    np.testing.assert_allclose(r.matrix, ccm_least_squares_reference(src, dst), atol=TOL.vs_closed_form)
    assert estimate_ccm(src, dst, min_pairs=100).accepted


def test_saturated_src_pairs_are_dropped() -> None:
    """A src channel at 1.0 is clipped (true value ≥ 1): such pairs are dropped before fitting, and the
    fit equals the fit on the unsaturated pairs alone, bit for bit."""
    src, dst = _random_pairs(1000, 5)
    rng = np.random.default_rng(5)
    bright = rng.uniform(0.3, 0.9, (300, 3)) * np.array([2.0, 1.0, 1.0])  # red beyond full scale
    bright_dst = bright @ TRUE_M.T
    bright_src = np.minimum(bright, 1.0)  # what the camera records
    order = rng.permutation(1300)
    all_src, all_dst = np.vstack([src, bright_src])[order], np.vstack([dst, bright_dst])[order]
    n_sat = int((bright_src >= 1.0).any(axis=1).sum())
    keep = ~(all_src >= 1.0).any(axis=1)
    r = estimate_ccm(all_src, all_dst)
    assert r.n_pairs == 1300 - n_sat and n_sat > 100
    assert r == estimate_ccm(all_src[keep], all_dst[keep])
    biased = estimate_ccm(all_src, all_dst, saturation=None)  # keeping them pulls the fit away
    assert biased.n_pairs == 1300 and np.abs(biased.matrix - TRUE_M).max() > 0.1
    assert np.abs(r.matrix - TRUE_M).max() < 0.01


def test_too_few_pairs_reason_counts_the_drops() -> None:
    src, dst = _random_pairs(600, 6)
    src[:200] = np.nan
    src[200:350, 1] = 1.0
    r = estimate_ccm(src, dst)
    assert r.reason == "too few pairs (250 < 500; dropped 200 non-finite, 150 saturated)"


def test_one_gross_in_range_outlier_moves_the_matrix_little() -> None:
    """A mismatched pair (a bright red frame pixel paired with a dark blue EM pixel) among 1000 good ones:
    least squares is not robust, but one pair in 1000 moves M by < 0.02 and raises the MSE from 4e-6
    to ~6e-4, far below the gate."""
    src, dst = _random_pairs(1000, 8)
    r = estimate_ccm(np.vstack([src, [0.9, 0.05, 0.05]]), np.vstack([dst, [0.02, 0.05, 0.9]]))
    assert r.accepted and r.n_pairs == 1001
    assert np.abs(r.matrix - TRUE_M).max() < TOL.outlier_in_range_dm
    assert 1e-4 < r.mse < 1e-3


def test_one_bright_outlier_trips_the_mse_gate() -> None:
    """One pair whose reference is an emitter (radiance 20) among 1000 good ones: M moves by only ~0.03
    but the MSE (not robust either) rises to ~0.36 > 5e-2 and the whole frame is rejected."""
    src, dst = _random_pairs(1000, 8)
    r = estimate_ccm(np.vstack([src, [0.9, 0.9, 0.9]]), np.vstack([dst, [20.0, 20.0, 20.0]]))
    assert not r.accepted and r.reason.startswith("mse ") and r.reason.endswith(" > 0.05")
    assert 0.3 < r.mse < 0.4
    assert np.abs(r.matrix - TRUE_M).max() < TOL.outlier_bright_dm


def test_mse_gate() -> None:
    src, dst = _random_pairs(2000, 9, noise=0.3)
    r = estimate_ccm(src, dst)
    assert not r.accepted and r.reason == f"mse {r.mse:.3g} > 0.05" and 0.08 < r.mse < 0.1
    assert estimate_ccm(src, dst, max_mse=0.1).accepted


@pytest.mark.parametrize("method", CCM_METHODS)
def test_nan_and_inf_rows_are_dropped(method: str) -> None:
    src, dst = _random_pairs(1500, 10)
    bad_src, bad_dst = src.copy(), dst.copy()
    bad_src[::7, 0] = np.nan
    bad_dst[3::11, 2] = np.inf
    bad_src[5::13, 1] = -np.inf
    bad = np.isnan(bad_src).any(1) | ~np.isfinite(bad_dst).all(1) | ~np.isfinite(bad_src).all(1)
    r = estimate_ccm(bad_src, bad_dst, method)
    assert r.n_pairs == int((~bad).sum()) and r.accepted
    assert r == estimate_ccm(src[~bad], dst[~bad], method)


@pytest.mark.parametrize("method", CCM_METHODS)
def test_all_nan_is_rejected_without_crashing(method: str) -> None:
    src = np.full((1000, 3), np.nan, dtype=np.float32)
    r = estimate_ccm(src, src, method)
    assert not r.accepted and r.n_pairs == 0
    assert r.reason == "too few pairs (0 < 500; dropped 1000 non-finite, 0 saturated)"
    assert np.array_equal(r.matrix, np.eye(3)) and np.isnan(r.mse)


def test_overflowing_values_are_rejected_as_non_finite() -> None:
    src, dst = _random_pairs(1000, 12)
    r = estimate_ccm(src, dst * 1e200)  # finite, but the sums overflow
    assert not r.accepted and r.reason.startswith("non-finite")
    assert np.array_equal(r.matrix, np.eye(3))
    r = estimate_ccm(-src * 1e200, dst)
    assert not r.accepted and r.reason.startswith("non-finite")


# ------------------------------------------------------------------------------------------------
# Layout: n-dimensional input, tiling, memory order
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", CCM_METHODS)
def test_tiling_gives_identical_results(method: str) -> None:
    src, dst = _random_pairs(1200, 13)
    src32, dst32 = src.astype(np.float32), dst.astype(np.float32)
    flat = estimate_ccm(src32, dst32, method)
    assert flat == estimate_ccm(src32.reshape(2, 600, 3), dst32.reshape(2, 600, 3), method)
    assert flat == estimate_ccm(src32.reshape(20, 10, 6, 3), dst32.reshape(20, 10, 6, 3), method)
    wide = np.concatenate([src32, dst32], axis=1)  # non-contiguous views
    assert flat == estimate_ccm(wide[:, :3], wide[:, 3:], method)
    assert flat == estimate_ccm(np.asfortranarray(src32), np.asfortranarray(dst32), method)


def test_single_row_input_is_too_few() -> None:
    r = estimate_ccm(np.array([0.2, 0.3, 0.4]), np.array([0.2, 0.3, 0.4]))
    assert r.n_pairs == 1 and not r.accepted


# ------------------------------------------------------------------------------------------------
# Bad arguments raise typed errors
# ------------------------------------------------------------------------------------------------


def test_shape_errors() -> None:
    src, dst = _random_pairs(10, 0)
    with pytest.raises(ShapeError, match="src"):
        estimate_ccm(np.zeros((10, 4)), np.zeros((10, 4)))
    with pytest.raises(ShapeError, match="dst"):
        estimate_ccm(src, dst[:9])
    with pytest.raises(ValueError):  # ShapeError is a ValueError too
        estimate_ccm(src, dst.reshape(5, 2, 3))


def test_dtype_errors() -> None:
    with pytest.raises(DTypeError, match="src"):
        estimate_ccm(np.zeros((10, 3), np.uint8), np.zeros((10, 3)))
    with pytest.raises(TypeError):
        estimate_ccm(np.zeros((10, 3)), np.zeros((10, 3), bool))


def test_unknown_method_lists_the_valid_ones() -> None:
    src, dst = _random_pairs(10, 0)
    with pytest.raises(UnknownMethodError) as info:
        estimate_ccm(src, dst, "cheung 2004")
    assert all(name in str(info.value) for name in CCM_METHODS)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"max_mse": -1.0},
        {"max_mse": float("nan")},
        {"min_pairs": 0},
        {"max_condition": 0.5},
        {"saturation": float("nan")},
        {"noise_std": -0.1},
        {"noise_std": float("inf")},
    ],
)
def test_range_errors(kwargs: dict) -> None:
    src, dst = _random_pairs(10, 0)
    with pytest.raises(RangeError):
        estimate_ccm(src, dst, **kwargs)


def test_result_is_frozen_and_consistent() -> None:
    r = estimate_ccm(*_random_pairs(600, 1))
    assert isinstance(r, CCMResult) and r.matrix.dtype == np.float64 and not r.matrix.flags.writeable
    with pytest.raises(AttributeError):
        r.mse = 0.0  # type: ignore[misc]
    with pytest.raises(InvalidInputError):
        CCMResult(np.eye(3), 0.0, 600, True, "mse too high", "least_squares")
    with pytest.raises(ShapeError):
        CCMResult(np.eye(2), 0.0, 600, True, "", "least_squares")


# ------------------------------------------------------------------------------------------------
# apply_ccm / invert_ccm
# ------------------------------------------------------------------------------------------------


def test_apply_ccm_matches_a_per_pixel_product_and_keeps_float32() -> None:
    rng = np.random.default_rng(0)
    img = rng.random((4, 5, 3)).astype(np.float32)
    out = apply_ccm(img, TRUE_M)
    assert out.dtype == np.float32 and out.shape == img.shape
    expected = np.einsum("ij,hwj->hwi", TRUE_M, img.astype(np.float64))
    np.testing.assert_allclose(out, expected, rtol=1e-6, atol=1e-6)
    assert apply_ccm(img.astype(np.float64), TRUE_M).dtype == np.float64
    assert apply_ccm(img.astype(np.float16), TRUE_M).dtype == np.float32


def test_apply_ccm_propagates_nan() -> None:
    img = np.array([[np.nan, 0.5, 0.5], [0.1, 0.2, 0.3]], np.float32)
    out = apply_ccm(img, TRUE_M)
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()


def test_apply_invert_round_trip() -> None:
    rng = np.random.default_rng(1)
    x = rng.random((100, 3))
    inv = invert_ccm(TRUE_M)
    np.testing.assert_allclose(inv @ TRUE_M, np.eye(3), atol=TOL.round_trip_f64)
    np.testing.assert_allclose(apply_ccm(apply_ccm(x, TRUE_M), inv), x, atol=TOL.round_trip_f64)
    x32 = x.astype(np.float32)
    np.testing.assert_allclose(apply_ccm(apply_ccm(x32, TRUE_M), inv), x32, atol=TOL.round_trip_f32)


def test_invert_estimated_matrix_maps_reference_into_the_frame() -> None:
    """Compositing (§7.2): a reference-space colour mapped by the inverse of the estimated M is what the
    current camera would record."""
    rng = np.random.default_rng(3)
    cam = _camera(rng, gains=(0.5, 1.0, 2.0))
    src, dst = _capture(rng, cam, np.arange(24), px=50)
    r = estimate_ccm(src, dst)
    assert r.accepted
    np.testing.assert_allclose(apply_ccm(REF, invert_ccm(r.matrix)), REF @ cam.T, atol=0.01)


def test_invert_ccm_errors() -> None:
    with pytest.raises(InvalidInputError, match="condition number"):
        invert_ccm(np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(InvalidInputError):
        invert_ccm(np.zeros((3, 3)))
    with pytest.raises(NonFiniteError):
        invert_ccm(np.full((3, 3), np.nan))
    with pytest.raises(ShapeError):
        invert_ccm(np.eye(4))
    with pytest.raises(NonFiniteError):
        apply_ccm(np.zeros((2, 3)), np.full((3, 3), np.inf))
    with pytest.raises(DTypeError):
        apply_ccm(np.zeros((2, 3), np.uint8), np.eye(3))


# ------------------------------------------------------------------------------------------------
# The ridge method: least squares pulled towards the per-channel (von Kries) diagonal
# ------------------------------------------------------------------------------------------------


def test_ridge_zero_is_least_squares() -> None:
    src, dst = _random_pairs(3000, 21, noise=0.01)
    r = estimate_ccm(src, dst, "ridge", ridge=0.0)
    np.testing.assert_allclose(r.matrix, ccm_least_squares_reference(src, dst), rtol=0, atol=1e-9)


def test_ridge_recovers_white_balance_from_grey_patches() -> None:
    """Grey-only pairs: least squares is rejected (its chroma columns are noise); the ridge fit falls
    back to the per-channel gains and corrects the chromatic patches it never saw."""
    for seed in range(20):
        rng = np.random.default_rng(seed)
        gains = rng.uniform(0.5, 2.0, 3)
        cam = np.diag(gains)
        src, dst = _capture(rng, cam, GREYS, px=200)
        assert not estimate_ccm(src, dst).accepted
        r = estimate_ccm(src, dst, "ridge")
        assert r.accepted
        np.testing.assert_allclose(r.matrix, np.diag(1.0 / gains), atol=0.03 * (1.0 / gains).max())
        assert _de00(apply_ccm(REF[CHROMATIC] @ cam.T, r.matrix), REF[CHROMATIC]).mean() < 2.0


def test_ridge_colorchecker_mean_ciede2000() -> None:
    rng = np.random.default_rng(2018)
    des = []
    for _ in range(100):
        cam = _camera(rng)
        src, dst = _capture(rng, cam, np.arange(24), px=50)
        r = estimate_ccm(src, dst, "ridge")
        if r.accepted:
            des.append(_de00(apply_ccm(REF @ cam.T, r.matrix), REF).mean())
    assert len(des) >= 90 and np.mean(des) <= TOL.colorchecker_de00


def test_ridge_rejects_a_negative_strength() -> None:
    src, dst = _random_pairs(600, 1)
    with pytest.raises(RangeError):
        estimate_ccm(src, dst, "ridge", ridge=-1.0)


def test_jacobi_eigh_and_the_compiled_fit_match_lapack():
    """The 3×3 Jacobi eigensolver against numpy's eigh (diagonal, rank 1 and 2, condition up to
    1e10, negative entries), and the compiled fit against numpy's solve / pinv on the same sums."""
    from rgbd_envmap._kernels.ccm import fit_sums, sym3_eigh

    rng = np.random.default_rng(3)
    cases = [np.diag([3.0, 1.0, 2.0]), np.zeros((3, 3)), np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])]
    for cond in (1.0, 1e2, 1e6, 1e10):
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        cases.append(q @ np.diag([1.0, np.sqrt(cond), cond]) @ q.T)
    a = rng.standard_normal((3, 2))
    cases.append(a @ a.T)  # rank 2
    for m in cases:
        w, v = sym3_eigh(m)
        ref = np.linalg.eigvalsh(m)
        scale = max(abs(ref).max(), 1e-300)
        np.testing.assert_allclose(w, ref, rtol=1e-12, atol=1e-14 * scale)
        np.testing.assert_allclose(v @ np.diag(w) @ v.T, m, atol=1e-13 * scale)
        np.testing.assert_allclose(v.T @ v, np.eye(3), atol=1e-13)
    src = rng.random((2000, 3))
    dst = src @ np.array([[1.2, 0.1, 0.0], [0.05, 0.9, 0.1], [0.0, -0.1, 1.4]]).T + 0.01 * rng.standard_normal((2000, 3))
    ata, atb, bb = src.T @ src, src.T @ dst, float((dst * dst).sum())
    matrix, mse, cond, well_posed = fit_sums(ata, atb, bb, 2000, -1.0)
    np.testing.assert_allclose(matrix, np.linalg.solve(ata, atb).T, rtol=1e-10, atol=1e-12)
    assert well_posed and np.isfinite(cond) and mse == pytest.approx(np.mean((src @ matrix.T - dst) ** 2), rel=1e-8)
    lam = 0.01 * np.trace(ata) / 3.0
    ridge_ref = np.linalg.solve(ata + lam * np.eye(3), atb + lam * np.diag(np.diag(atb) / np.diag(ata))).T
    np.testing.assert_allclose(fit_sums(ata, atb, bb, 2000, 0.01)[0], ridge_ref, rtol=1e-10, atol=1e-12)
    grey = np.repeat(rng.random((500, 1)), 3, axis=1)  # rank 1: minimum-norm solution, not well posed
    g_ata, g_atb = grey.T @ grey, grey.T @ grey
    g_matrix, _, g_cond, g_ok = fit_sums(g_ata, g_atb, float((grey * grey).sum()), 500, -1.0)
    assert not g_ok and g_cond == np.inf
    np.testing.assert_allclose(g_matrix, (np.linalg.pinv(g_ata) @ g_atb).T, atol=1e-9)
