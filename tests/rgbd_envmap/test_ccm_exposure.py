"""The correction matrix with a known exposure ratio (``known_gain``): the free fit's white balance,
the known overall gain, so that a change of the scene's light is not absorbed as an exposure change."""

import math

import numpy as np
import pytest

from rgbd_envmap.colour.ccm import (
    GAIN_CHANNELS,
    CCMResult,
    ccm_from_sums,
    ccm_sums,
    estimate_ccm,
    matrix_gain,
)
from rgbd_envmap.errors import DTypeError, RangeError, UnknownMethodError

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _scene(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.02, 0.45, (n, 3)), rng


def _pairs(exposure, wb, light=1.0, noise=0.0, n=4000, seed=0):
    """Map colours (reference frame: exposure 1, white balance 1, the scene's original light) and a
    frame's colours at ``exposure`` × ``wb`` after the scene's light changed by ``light``."""
    radiance, rng = _scene(n, seed)
    dst = radiance
    src = light * radiance * exposure * np.asarray(wb)
    if noise:
        src = src + rng.normal(0.0, noise, src.shape)
    return src, dst


@pytest.mark.parametrize("method", ["least_squares", "ridge"])
@pytest.mark.parametrize("light", [0.4, 1.0, 2.5])
def test_a_neutral_light_change_is_not_absorbed_with_the_green_gain_known(method, light):
    exposure, wb = 1.7, np.array([1.25, 1.0, 0.8])  # the simulated camera's white balance: green gain 1
    src, dst = _pairs(exposure, wb, light)
    true = np.diag(1.0 / (exposure * wb))  # diag(g_reference / g_frame): the camera's correction only
    free = estimate_ccm(src, dst, method, saturation=None)  # (no clipping in this synthetic frame)
    fixed = estimate_ccm(src, dst, method, saturation=None, known_gain=1.0 / exposure)
    assert free.accepted and fixed.accepted
    np.testing.assert_allclose(free.matrix, true / light, rtol=1e-6, atol=1e-9)  # the paper's fit takes it in
    np.testing.assert_allclose(fixed.matrix, true, rtol=1e-6, atol=1e-9)
    # fitted / known gain: the map's brightness over the frame's at the same surfaces
    assert fixed.fitted_gain / (1.0 / exposure) == pytest.approx(1.0 / light, rel=1e-6)
    assert free.fitted_gain is None


def test_the_luminance_gain_is_off_by_the_white_balance_luminance():
    """"luminance" holds the Rec. 709 response to grey at the known gain; the simulated camera's
    white balance moves it (green fixed), so the matrix is off by that factor, as documented."""
    exposure, wb = 2.0, np.array([1.3, 1.0, 0.7])
    src, dst = _pairs(exposure, wb, light=0.5)
    r = estimate_ccm(src, dst, "least_squares", known_gain=0.5, gain_channel="luminance")
    assert LUMA @ r.matrix.sum(axis=1) == pytest.approx(0.5, rel=1e-9)
    true = np.diag(1.0 / (exposure * wb))
    np.testing.assert_allclose(r.matrix, true * (0.5 / (LUMA @ true.sum(axis=1))), rtol=1e-6, atol=1e-9)


def test_the_matrix_is_the_known_gain_times_an_independent_free_fit_normalised():
    """Against numpy's lstsq (not our kernel) with channel mixing and noise; gates and MSE are the
    free fit's."""
    radiance, rng = _scene(3000, seed=3)
    mix = np.array([[1.1, 0.08, -0.02], [0.05, 0.9, 0.04], [-0.03, 0.1, 1.2]])
    dst = radiance
    src = radiance @ np.linalg.inv(mix).T * 0.7 + rng.normal(0.0, 0.003, radiance.shape)
    free_lstsq = np.linalg.lstsq(src, dst, rcond=None)[0].T
    for channel, w in (("green", np.array([0.0, 1.0, 0.0])), ("luminance", LUMA)):
        r = estimate_ccm(src, dst, "least_squares", known_gain=0.9, gain_channel=channel)
        expected = 0.9 * free_lstsq / (w @ free_lstsq.sum(axis=1))
        np.testing.assert_allclose(r.matrix, expected, rtol=1e-9, atol=1e-12)
        assert r.fitted_gain == pytest.approx(w @ free_lstsq.sum(axis=1), rel=1e-9)
        free = estimate_ccm(src, dst, "least_squares")
        assert (r.mse, r.condition, r.n_pairs, r.accepted, r.reason) == (free.mse, free.condition, free.n_pairs,
                                                                          free.accepted, free.reason)


def test_without_known_gain_the_result_is_todays_bit_for_bit():
    src, dst = _pairs(1.3, (1.2, 1.0, 0.9), light=0.6, noise=0.002)
    for method in ("least_squares", "ridge"):
        assert estimate_ccm(src, dst, method) == estimate_ccm(src, dst, method, known_gain=None, gain_channel="luminance")


def test_the_sums_path_equals_estimate_ccm_and_colour_science_gets_the_same_gain():
    src, dst = _pairs(1.3, (1.2, 1.0, 0.9), light=0.6, noise=0.002)
    kw = dict(max_mse=5e-2, min_pairs=500, max_condition=1e4, noise_std=None, ridge=0.1)
    for method in ("least_squares", "ridge"):
        a = estimate_ccm(src, dst, method, known_gain=0.8)
        b = ccm_from_sums(*ccm_sums(src, dst, 1.0), method, known_gain=0.8, gain_channel="green", **kw)
        assert a == b
    cheung = estimate_ccm(src, dst, "Cheung 2004", known_gain=0.8)
    ls = estimate_ccm(src, dst, "least_squares", known_gain=0.8)
    np.testing.assert_allclose(cheung.matrix, ls.matrix, rtol=1e-8, atol=1e-10)
    assert cheung.fitted_gain == pytest.approx(ls.fitted_gain, rel=1e-8)


def test_a_fit_with_a_non_positive_gain_is_rejected():
    src, dst = _pairs(1.0, (1.0, 1.0, 1.0))
    r = estimate_ccm(src, -dst, "least_squares", known_gain=1.0)
    assert not r.accepted and r.reason.startswith("gain ") and "not > 0 and finite" in r.reason
    assert r.fitted_gain == pytest.approx(-1.0)
    # the same pairs without a known gain: a (negative) matrix that passes the paper's gate
    assert estimate_ccm(src, -dst, "least_squares").accepted


def test_rejected_and_degenerate_fits_keep_their_reasons_with_a_known_gain():
    src, dst = _pairs(1.0, (1.0, 1.0, 1.0), n=10)
    r = estimate_ccm(src, dst, known_gain=1.0)
    assert not r.accepted and r.reason.startswith("too few pairs")
    grey = np.repeat(np.linspace(0.1, 0.5, 1000)[:, None], 3, axis=1)
    r = estimate_ccm(grey, grey * 0.5, "least_squares", known_gain=2.0)
    assert not r.accepted and ("rank-deficient" in r.reason or "ill-conditioned" in r.reason)
    nan = np.full((600, 3), np.nan)
    r = estimate_ccm(nan, nan, known_gain=2.0)
    assert not r.accepted and np.array_equal(r.matrix, np.eye(3)) and r.fitted_gain is None


def test_matrix_gain_of_exposure_times_white_balance():
    m = np.diag([2.0 * 1.3, 2.0, 2.0 * 0.6])
    assert matrix_gain(m) == 2.0
    assert matrix_gain(m, "luminance") == pytest.approx(2.0 * (LUMA @ [1.3, 1.0, 0.6]))
    mixed = np.array([[1.0, 0.1, 0.0], [0.2, 0.5, 0.3], [0.0, 0.0, 1.0]])
    assert matrix_gain(mixed) == pytest.approx(1.0)  # the green row's response to grey
    assert GAIN_CHANNELS == ("green", "luminance")


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bad_known_gains_are_refused(bad):
    src, dst = _pairs(1.0, (1.0, 1.0, 1.0), n=600)
    with pytest.raises(RangeError, match="known_gain"):
        estimate_ccm(src, dst, known_gain=bad)


def test_bad_gain_channels_and_types_are_refused():
    src, dst = _pairs(1.0, (1.0, 1.0, 1.0), n=600)
    with pytest.raises(UnknownMethodError, match="gain_channel"):
        estimate_ccm(src, dst, known_gain=1.0, gain_channel="blue")
    with pytest.raises(UnknownMethodError, match="gain_channel"):
        matrix_gain(np.eye(3), "red")
    with pytest.raises(DTypeError, match="known_gain"):
        estimate_ccm(src, dst, known_gain="1.0")
    with pytest.raises(DTypeError, match="known_gain"):
        estimate_ccm(src, dst, known_gain=True)
    with pytest.raises(UnknownMethodError, match="gain_channel"):  # checked even without a known gain
        estimate_ccm(src, dst, gain_channel="blue")


def test_ccm_result_compares_its_fitted_gain():
    a = CCMResult(np.eye(3), 0.0, 10, True, "", "ridge", 1.0, 2.0)
    assert a == CCMResult(np.eye(3), 0.0, 10, True, "", "ridge", 1.0, 2.0)
    assert a != CCMResult(np.eye(3), 0.0, 10, True, "", "ridge", 1.0, 3.0)
    assert CCMResult(np.eye(3), 0.0, 10, True, "", "ridge") == CCMResult(np.eye(3), 0.0, 10, True, "", "ridge")
    assert CCMResult(np.eye(3), 0.0, 10, True, "", "ridge").fitted_gain is None
    assert a != CCMResult(np.eye(3), 0.0, 10, True, "", "ridge", 1.0)
