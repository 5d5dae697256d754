"""Tests for rgbd_envmap.depth.reliability: the exposure rule and the depth-discontinuity tests of
reliability marking (paper 003 §5.2).

References used here (:mod:`rgbd_envmap.reference.reliability`): the authors' statistic
Σ (d_i − d)² / d written out with explicit loops, and the noise-model χ² recomputed per pixel with
``np.linalg.lstsq`` (weighted plane fit of 1/z), with thresholds from ``scipy.stats.chi2``; both
independent of the numba kernels. Noise follows the simulator's ToF model:
σ_z = 1 % of depth, seeded.

The module is imported directly (not through ``rgbd_envmap.depth``) so that these tests do not
depend on the hole-filling module being importable.
"""

from __future__ import annotations

import doctest
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from rgbd_envmap.depth import reliability
from rgbd_envmap.depth.reliability import (
    MIN_NEIGHBOURS_DEFAULT,
    MONROY2018_THRESHOLD,
    RELIABILITY_METHODS,
    discontinuity_passed,
    discontinuity_test,
    exposure_ok,
    mark_reliable,
)
from rgbd_envmap.errors import DTypeError, RangeError, ShapeError, UnknownMethodError
from rgbd_envmap.reference.reliability import (
    exposure_reference,
    in_image_neighbours,
    known_offsets,
    monroy2018_reference,
    noise_model_reference,
)


@dataclass(frozen=True)
class _Tolerances:
    #: noise-model statistic vs the per-pixel lstsq reference (float64; the kernel's closed-form
    #: normal equations lose a few digits to cancellation, measured ≤ 1e-10 relative).
    chi2_rel: float = 1e-8
    chi2_abs: float = 1e-8
    #: authors' statistic vs the loop reference (summation order differs: Σ(·)²/d vs Σ((·)²/d)).
    monroy_rel: float = 1e-12
    #: statistic of noise-free planes through the distorted camera: the plane model's own error.
    plane_model: float = 1e-4
    #: the same statistic for float32 vs float64 depth of the same scene (float32 rounding of z).
    f32_vs_f64_rel: float = 1e-3


TOL = _Tolerances()
NOISE_REL = 0.01  # the simulated ToF: σ = 1 % of range


def _grey(shape: tuple[int, int]) -> np.ndarray:
    return np.full(shape + (3,), 0.5)


def _noisy(z: np.ndarray, seed: int) -> np.ndarray:
    return z * (1.0 + NOISE_REL * np.random.default_rng(seed).standard_normal(z.shape))


def _step(height: int, width: int, distance_m: float, step_m: float) -> np.ndarray:
    """Fronto-parallel wall with the right half (columns ≥ width // 2) ``step_m`` farther."""
    z = np.full((height, width), distance_m)
    z[:, width // 2:] += step_m
    return z


def _slanted_wall(height: int, width: int, distance_m: float, incidence_deg: float, f_px: float = 200.0):
    """Pinhole z-depth of a plane through (0, 0, distance) tilted about the camera y axis."""
    t = np.radians(incidence_deg)
    x = (np.arange(width) - (width - 1) / 2) / f_px
    z_row = distance_m * np.cos(t) / (np.cos(t) - np.sin(t) * x)
    return np.tile(z_row, (height, 1))


# --------------------------------------------------------------------------------------------------
# Smoke, shapes, registry
# --------------------------------------------------------------------------------------------------


def test_registry_names_the_default_and_the_authors_method():
    assert RELIABILITY_METHODS == ("noise_model", "monroy2018")
    assert MONROY2018_THRESHOLD == 14.07
    assert abs(chi2.isf(0.05, 7) - MONROY2018_THRESHOLD) < 1e-2  # the authors' value: χ² 7 dof, p 0.05
    assert MIN_NEIGHBOURS_DEFAULT == {"noise_model": 8, "monroy2018": 0}


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
@pytest.mark.parametrize("shape", [(172, 224), (5, 7), (1, 1), (2, 2), (1, 9), (9, 1)])
def test_output_shape_and_dtype(method, shape):
    z = np.full(shape, 1.5)
    out = mark_reliable(_grey(shape), z, np.ones(shape, bool), method)
    assert out.shape == shape and out.dtype == bool
    t = discontinuity_test(z, np.ones(shape, bool), method)
    for a in (t.statistic, t.threshold, t.n_neighbours, t.testable, t.passed):
        assert a.shape == shape


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (4, 0)])
def test_empty_input_gives_empty_output(method, shape):
    out = mark_reliable(np.zeros(shape + (3,)), np.zeros(shape), np.zeros(shape, bool), method)
    assert out.shape == shape and out.dtype == bool
    assert exposure_ok(np.zeros(shape + (3,))).shape == shape


def test_default_is_noise_model():
    z = _step(6, 8, 2.0, 0.5)
    a = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool))
    b = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool), "noise_model")
    np.testing.assert_array_equal(a, b)


def test_inputs_are_not_modified():
    rng = np.random.default_rng(0)
    rgb, z, known = rng.uniform(size=(6, 7, 3)), rng.uniform(1, 2, (6, 7)), rng.uniform(size=(6, 7)) > 0.2
    copies = rgb.copy(), z.copy(), known.copy()
    mark_reliable(rgb, z, known)
    for a, b in zip((rgb, z, known), copies):
        np.testing.assert_array_equal(a, b)


def test_float32_and_non_contiguous_inputs_match_float64():
    z64 = _noisy(_step(40, 60, 1.0, 0.1), 1)
    rng = np.random.default_rng(2)
    known = rng.uniform(size=z64.shape) > 0.05
    rgb = rng.uniform(size=z64.shape + (3,))
    a = discontinuity_test(z64, known)
    b = discontinuity_test(z64.astype(np.float32), known)
    np.testing.assert_allclose(b.statistic, a.statistic, rtol=TOL.f32_vs_f64_rel, atol=1e-6)
    big = np.zeros((80, 120))
    big[::2, ::2] = z64
    big_known = np.zeros((80, 120), bool)
    big_known[::2, ::2] = known
    big_rgb = np.zeros((80, 120, 3))
    big_rgb[::2, ::2] = rgb
    np.testing.assert_array_equal(
        mark_reliable(big_rgb[::2, ::2], big[::2, ::2], big_known[::2, ::2]), mark_reliable(rgb, z64, known)
    )


def test_module_doctests():
    assert doctest.testmod(reliability).failed == 0


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------


def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(UnknownMethodError, match="noise_model") as info:
        mark_reliable(_grey((3, 3)), np.ones((3, 3)), np.ones((3, 3), bool), "chi2")
    assert "monroy2018" in str(info.value)
    with pytest.raises(UnknownMethodError):
        discontinuity_test(np.ones((3, 3)), np.ones((3, 3), bool), "Monroy 2018")


@pytest.mark.parametrize("rgb_shape,depth_shape,known_shape", [
    ((4, 5), (4, 5), (4, 5)),        # rgb without channels
    ((4, 5, 4), (4, 5), (4, 5)),     # RGBA
    ((5, 4, 3), (4, 5), (4, 5)),     # transposed rgb
    ((4, 5, 3), (4, 5), (5, 4)),     # known transposed
    ((4, 5, 3), (4, 5, 1), (4, 5)),  # depth with a channel axis
    ((4, 5, 3), (20,), (4, 5)),      # flat depth
])
def test_shape_mismatch_raises_shape_error(rgb_shape, depth_shape, known_shape):
    with pytest.raises(ShapeError):
        mark_reliable(np.zeros(rgb_shape), np.ones(depth_shape), np.ones(known_shape, bool))


@pytest.mark.parametrize("value", [3.0, True, "8"])
def test_min_neighbours_must_be_an_integer(value):
    with pytest.raises(DTypeError, match="min_neighbours"):
        mark_reliable(_grey((3, 3)), np.ones((3, 3)), np.ones((3, 3), bool), min_neighbours=value)


def test_known_must_be_bool_and_colour_depth_float():
    with pytest.raises(DTypeError, match="known"):
        mark_reliable(_grey((3, 3)), np.ones((3, 3)), np.ones((3, 3), np.uint8))
    with pytest.raises(DTypeError, match="rgb"):
        mark_reliable(np.full((3, 3, 3), 128, np.uint8), np.ones((3, 3)), np.ones((3, 3), bool))
    with pytest.raises(DTypeError, match="depth_m"):
        mark_reliable(_grey((3, 3)), np.ones((3, 3), np.uint16), np.ones((3, 3), bool))
    with pytest.raises(DTypeError):
        discontinuity_test(np.ones((3, 3)), np.ones((3, 3), int))


@pytest.mark.parametrize("kwargs", [
    {"min_neighbours": 2},                        # noise_model needs ≥ 3
    {"min_neighbours": 9},
    {"p_value": 0.0},
    {"p_value": 1.5},
    {"p_value": float("nan")},
    {"noise_rel": -0.01},
    {"noise_rel": 0.0, "noise_abs_m": 0.0},
    {"noise_abs_m": float("inf")},
    {"dark": float("nan")},
    {"bright": float("inf")},
])
def test_bad_parameters_raise_range_error(kwargs):
    with pytest.raises(RangeError):
        mark_reliable(_grey((3, 3)), np.ones((3, 3)), np.ones((3, 3), bool), **kwargs)


@pytest.mark.parametrize("kwargs", [{"min_neighbours": -1}, {"monroy2018_threshold": -1.0},
                                    {"monroy2018_threshold": float("inf")}])
def test_bad_parameters_of_the_authors_method(kwargs):
    with pytest.raises(RangeError):
        mark_reliable(_grey((3, 3)), np.ones((3, 3)), np.ones((3, 3), bool), "monroy2018", **kwargs)


def test_the_authors_method_accepts_any_neighbour_count():
    # A known pixel with no known neighbour has S = 0 and passes, as in the authors' sum.
    known = np.zeros((3, 3), bool)
    known[1, 1] = True
    assert mark_reliable(_grey((3, 3)), np.ones((3, 3)), known, "monroy2018")[1, 1]
    assert not mark_reliable(_grey((3, 3)), np.ones((3, 3)), known, "monroy2018", min_neighbours=1)[1, 1]


# --------------------------------------------------------------------------------------------------
# Exposure rule
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("pixel,ok", [
    ((0.04, 0.04, 0.04), False),      # all < 0.05: under-exposed
    ((0.0, 0.0, 0.0), False),
    ((-0.5, -1.0, -0.1), False),      # out of range below: dark
    ((0.05, 0.04, 0.04), True),       # one channel exactly at 0.05 is not "< 0.05"
    ((0.05, 0.05, 0.05), True),       # boundary: all exactly 0.05 is kept (strict comparison)
    ((0.0499, 0.0, 0.2), True),       # one channel ≥ 0.05
    ((0.04, 0.5, 0.04), True),
    ((0.96, 0.96, 0.96), False),      # all > 0.95: over-exposed
    ((1.0, 1.0, 1.0), False),
    ((7.0, 3.0, 2.0), False),         # emitter radiance above 1: bright
    ((0.95, 0.95, 0.95), True),       # boundary: all exactly 0.95 is kept
    ((0.95, 0.99, 0.99), True),       # one channel not > 0.95
    ((0.99, 0.5, 0.99), True),
    ((np.nan, 0.5, 0.5), False),      # non-finite colour: unreliable
    ((0.5, np.inf, 0.5), False),
    ((-np.inf, -np.inf, -np.inf), False),
])
def test_exposure_rule_on_hand_built_pixels(pixel, ok):
    assert bool(exposure_ok(np.array(pixel))) is ok
    rgb = np.full((5, 5, 3), 0.5)
    rgb[2, 2] = pixel
    out = mark_reliable(rgb, np.full((5, 5), 2.0), np.ones((5, 5), bool))
    assert bool(out[2, 2]) is ok
    assert out.sum() == 24 + ok  # the rule is per pixel: neighbours are unaffected


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_exposure_boundaries_in_float32_and_float64(dtype):
    # 0.05 and 0.95 are not exact in binary; the rule compares the stored value with the float64
    # threshold. In float32, 0.05 rounds above 0.05 and 0.95 below 0.95, so both stay "fine".
    rgb = np.array([[0.05, 0.05, 0.05], [0.95, 0.95, 0.95]], dtype=dtype)
    assert exposure_ok(rgb).tolist() == [True, True]


def test_exposure_thresholds_are_parameters():
    rgb = np.array([[0.08, 0.08, 0.08], [0.9, 0.9, 0.9]])
    assert exposure_ok(rgb).tolist() == [True, True]
    assert exposure_ok(rgb, dark=0.1, bright=0.85).tolist() == [False, False]


def test_exposure_ok_is_elementwise_over_leading_axes():
    rgb = np.random.default_rng(3).uniform(-0.1, 1.1, (6, 3))
    rgb[0] = 0.01
    rgb[1] = 0.99
    flat = exposure_ok(rgb)
    np.testing.assert_array_equal(exposure_ok(rgb.reshape(2, 3, 3)), flat.reshape(2, 3))
    np.testing.assert_array_equal(exposure_ok(rgb[None, None]), flat[None, None])


def test_exposure_rule_does_not_remove_depth_from_neighbours_tests():
    # A dark pixel is unreliable itself but its depth still counts for its neighbours, so with the
    # default "every neighbour known" rule the neighbours stay reliable.
    rgb = _grey((5, 5))
    rgb[2, 2] = 0.0
    out = mark_reliable(rgb, np.full((5, 5), 2.0), np.ones((5, 5), bool))
    assert not out[2, 2] and out.sum() == 24


# --------------------------------------------------------------------------------------------------
# The authors' statistic
# --------------------------------------------------------------------------------------------------


def test_monroy2018_matches_the_loop_reference_exactly():
    rng = np.random.default_rng(11)
    # Depths in the scale where S crosses 14.07 for some pixels (as in millimetre-like units).
    z = rng.uniform(20.0, 60.0, (9, 12))
    z[:, 6:] += 40.0
    known = rng.uniform(size=z.shape) > 0.2
    ref = monroy2018_reference(z, known)
    t = discontinuity_test(z, known, "monroy2018")
    np.testing.assert_allclose(t.statistic[known], ref[known], rtol=TOL.monroy_rel)
    assert np.all(np.abs(ref[known] - MONROY2018_THRESHOLD) > 1e-6)  # nothing ties the threshold
    expected = known & (ref <= MONROY2018_THRESHOLD)
    np.testing.assert_array_equal(t.passed, expected)
    np.testing.assert_array_equal(mark_reliable(_grey(z.shape), z, known, "monroy2018"), expected)
    assert 0 < expected.sum() < known.sum()  # both verdicts occur


def test_monroy2018_is_not_scale_free():
    # S has the unit of depth: the same scene in millimetres gives 1000× the statistic.
    z = _noisy(_step(10, 10, 1.0, 0.05), 4)
    known = np.ones(z.shape, bool)
    s_m = discontinuity_test(z, known, "monroy2018").statistic
    s_mm = discontinuity_test(1000.0 * z, known, "monroy2018").statistic
    np.testing.assert_allclose(s_mm, 1000.0 * s_m, rtol=1e-12)


@pytest.mark.parametrize("distance_m", [0.5, 1.0, 4.0])
def test_monroy2018_in_metres_keeps_even_a_30cm_step(distance_m):
    # The measured behaviour of the authors' threshold with d in metres (docs/design/reliability.md).
    z = _noisy(_step(20, 20, distance_m, 0.30), 5)
    assert mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool), "monroy2018").all()


# --------------------------------------------------------------------------------------------------
# The noise-model statistic
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("noise_abs", [0.0, 0.005])
def test_noise_model_matches_the_lstsq_reference(noise_abs):
    rng = np.random.default_rng(7)
    z = _noisy(_slanted_wall(12, 15, 1.5, 45.0), 8)
    z[3:8, 5:11] -= 0.3  # a box in front
    known = rng.uniform(size=z.shape) > 0.25
    ref, n_ref = noise_model_reference(z, known, noise_abs=noise_abs)
    t = discontinuity_test(z, known, noise_abs_m=noise_abs, min_neighbours=3)
    np.testing.assert_array_equal(t.n_neighbours, n_ref)
    ok = ~np.isnan(ref)
    np.testing.assert_array_equal(t.testable, ok)
    np.testing.assert_allclose(t.statistic[ok], ref[ok], rtol=TOL.chi2_rel, atol=TOL.chi2_abs)
    dof = n_ref[ok] - 2
    np.testing.assert_allclose(t.threshold[ok], chi2.isf(0.05, dof), rtol=1e-12)
    assert np.all(np.abs(ref[ok] - chi2.isf(0.05, dof)) > 1e-6)
    np.testing.assert_array_equal(t.passed[ok], ref[ok] <= chi2.isf(0.05, dof))
    assert not t.passed[~ok].any()


def test_noise_model_is_scale_free():
    z = _noisy(_step(12, 12, 1.0, 0.05), 9)
    known = np.ones(z.shape, bool)
    t1 = discontinuity_test(z, known).statistic
    for k in (0.37, 4.0, 1000.0):
        np.testing.assert_allclose(discontinuity_test(k * z, known).statistic, t1, rtol=1e-8, atol=1e-8)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    a=st.floats(-0.5, 0.5), b=st.floats(-0.5, 0.5), c=st.floats(0.2, 5.0),
    h=st.integers(2, 9), w=st.integers(2, 9),
)
def test_noise_free_planes_have_zero_statistic(a, b, c, h, w):
    # 1/z affine in pixel coordinates is an exact plane: T ≈ 0 and every pixel is reliable.
    vv, uu = np.mgrid[0:h, 0:w]
    inv = (1.0 / c) * (1.0 + a * (uu - w / 2) / 20 + b * (vv - h / 2) / 20)
    z = 1.0 / inv
    t = discontinuity_test(z, np.ones((h, w), bool))
    assert np.all(t.statistic < TOL.plane_model)
    assert t.passed.all()


def test_noise_free_slanted_walls_through_the_distorted_tof_camera():
    from rgbd_envmap.geometry import pixel_rays
    from sim.device import TangoDeviceConfig

    rays = pixel_rays(TangoDeviceConfig().tof.intrinsics)
    for inc in (0.0, 45.0, 70.0, 80.0):
        t_rad = np.radians(inc)
        z = 2.0 * np.cos(t_rad) / (rays @ np.array([-np.sin(t_rad), 0.0, np.cos(t_rad)]))
        ok = (z > 0.1) & (z < 10.0)
        assert discontinuity_test(z, ok).statistic.max() < TOL.plane_model


@pytest.mark.parametrize("distance_m", [0.5, 4.0])
@pytest.mark.parametrize("incidence_deg", [0.0, 70.0])
def test_noisy_wall_keeps_at_least_90_percent(distance_m, incidence_deg):
    z = _noisy(_slanted_wall(60, 80, distance_m, incidence_deg), seed=int(10 * distance_m + incidence_deg))
    out = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool))
    kept = out[1:-1, 1:-1].mean()
    assert kept >= 0.90
    assert kept <= 0.99  # and the test is not blind: about p_value = 5 % are rejected


def test_false_rejection_rate_is_p_value():
    z = _noisy(np.full((150, 200), 2.0), 12)
    for p in (0.01, 0.05, 0.2):
        rejected = 1.0 - mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool), p_value=p)[1:-1, 1:-1].mean()
        assert abs(rejected - p) < 0.25 * p + 0.003


@pytest.mark.parametrize("distance_m", [1.0, 3.0])
def test_30cm_step_is_rejected_on_both_sides(distance_m):
    z = _noisy(_step(60, 40, distance_m, 0.30), seed=int(distance_m))
    out = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool))
    assert not out[1:-1, 19].any() and not out[1:-1, 20].any()


def test_10cm_step_at_1m_is_rejected_on_both_sides():
    z = _noisy(_step(60, 40, 1.0, 0.10), seed=21)
    out = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool))
    assert not out[1:-1, 19].any() and not out[1:-1, 20].any()
    assert out[1:-1, 2:17].mean() > 0.9 and out[1:-1, 23:38].mean() > 0.9  # away from the step: kept


def test_10cm_step_at_3m_is_at_the_limit_of_any_3x3_test():
    # σ = 3 cm at 3 m, so the step is h/σ = 3.3. The plane absorbs most of a step: the noise-free
    # statistic is λ = (h/σ)² / 2 ≈ 5.6 (computed here independently), inside the 95 % range of a
    # wall (12.59 at 6 dof). With noise the step is rejected on each side about a third of the time
    # (the Monte Carlo power of this test is 37 %; the Neyman–Pearson bound of any 3×3 test, 76 %).
    z_clean = _step(60, 40, 3.0, 0.10)
    ref, _ = noise_model_reference(z_clean[:5, 17:23], np.ones((5, 6), bool))
    t = discontinuity_test(z_clean, np.ones(z_clean.shape, bool))
    np.testing.assert_allclose(t.statistic[2, 19:21], ref[2, 2:4], rtol=1e-8)
    assert 4.5 < ref[2, 2] < 6.5 and not (~t.passed[1:-1, 19:21]).any()
    near, far = [], []
    for seed in range(10):
        out = mark_reliable(_grey(z_clean.shape), _noisy(z_clean, 100 + seed), np.ones(z_clean.shape, bool))
        near.append((~out[1:-1, 19]).mean())
        far.append((~out[1:-1, 20]).mean())
    for rate in (np.mean(near), np.mean(far)):
        assert 0.2 < rate < 0.6  # far above the 5 % wall rate, far below certain


def test_10cm_step_at_3m_with_a_dropout_is_rejected_on_both_sides():
    # What a ToF sensor does at an edge: the mixed pixel on the near side gets low confidence and
    # is unknown. The default neighbour rule then rejects both sides of the gap.
    z = _noisy(_step(60, 40, 3.0, 0.10), seed=31)
    known = np.ones(z.shape, bool)
    known[:, 19] = False
    out = mark_reliable(_grey(z.shape), z, known)
    assert not out[:, 18].any() and not out[:, 20].any()


# --------------------------------------------------------------------------------------------------
# Neighbours, borders, unknown pixels
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
def test_flat_plane_is_reliable_up_to_the_borders_and_corners(method):
    z = np.full((7, 9), 1.7)
    t = discontinuity_test(z, np.ones(z.shape, bool), method)
    assert t.passed.all() and t.testable.all()
    np.testing.assert_array_equal(t.n_neighbours, in_image_neighbours(z.shape))


def test_border_rule_requires_only_in_image_neighbours():
    z = np.full((6, 6), 2.0)
    known = np.ones(z.shape, bool)
    known[0, 2] = False  # an unknown pixel on the top border
    out = mark_reliable(_grey(z.shape), z, known)
    expected = np.ones(z.shape, bool)
    expected[0:2, 1:4] = False  # the unknown pixel and every pixel that has it as a neighbour
    np.testing.assert_array_equal(out, expected)
    # Asking for fewer known neighbours keeps its neighbours: with 7, the interior ones (7 of 8 known)
    # but not the border ones (4 of 5 in-image known, and min(7, 5) = 5 are required); with 4, all.
    out7 = mark_reliable(_grey(z.shape), z, known, min_neighbours=7)
    expected[1, 1:4] = True
    np.testing.assert_array_equal(out7, expected)
    out4 = mark_reliable(_grey(z.shape), z, known, min_neighbours=4)
    assert out4.sum() == z.size - 1 and not out4[0, 2]


def test_pixels_that_cannot_be_tested_are_unreliable():
    # The noise-model fit needs ≥ 3 known neighbours: a lone pair or a 1-pixel-wide strip cannot be
    # tested whatever min_neighbours says.
    z = np.full((5, 5), 1.0)
    known = np.zeros((5, 5), bool)
    known[2, 1:3] = True
    assert not mark_reliable(_grey(z.shape), z, known, min_neighbours=3).any()
    strip = np.full((1, 9), 1.0)
    assert not mark_reliable(_grey(strip.shape), strip, np.ones(strip.shape, bool)).any()
    assert mark_reliable(_grey(strip.shape), strip, np.ones(strip.shape, bool), "monroy2018").all()
    corner = np.full((2, 2), 1.0)  # 3 neighbours each, an exact plane through 4 points
    assert mark_reliable(_grey(corner.shape), corner, np.ones((2, 2), bool)).all()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), method=st.sampled_from(RELIABILITY_METHODS), min_nb=st.integers(3, 8))
def test_unknown_pixels_are_never_reliable_and_their_depth_is_never_used(seed, method, min_nb):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 12, 2)
    z = rng.uniform(0.2, 4.0, (h, w))
    known = rng.uniform(size=(h, w)) > rng.uniform(0, 0.6)
    rgb = rng.uniform(-0.1, 1.1, (h, w, 3))
    out = mark_reliable(rgb, z, known, method, min_neighbours=min_nb)
    assert not out[~known].any()
    assert not out[~exposure_ok(rgb)].any()
    garbage = z.copy()
    garbage[~known] = rng.choice([np.nan, np.inf, -1.0, 0.0, 1e300], size=int((~known).sum()))
    np.testing.assert_array_equal(mark_reliable(rgb, garbage, known, method, min_neighbours=min_nb), out)


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 0.0, -1.0])
def test_non_finite_or_non_positive_known_depth_is_treated_as_unknown(method, bad):
    z = np.full((6, 6), 2.0)
    z[2, 3] = bad
    known = np.ones(z.shape, bool)
    out = mark_reliable(_grey(z.shape), z, known, method, min_neighbours=7 if method == "noise_model" else 0)
    assert not out[2, 3]
    assert out.sum() == z.size - 1  # neighbours are not poisoned
    unknown = known.copy()
    unknown[2, 3] = False
    for mn in (3, 8):
        np.testing.assert_array_equal(
            mark_reliable(_grey(z.shape), z, known, "noise_model", min_neighbours=mn),
            mark_reliable(_grey(z.shape), z, unknown, "noise_model", min_neighbours=mn),
        )
    t = discontinuity_test(z, known, method)
    assert np.isfinite(t.statistic).all() and np.isfinite(t.threshold).all()


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
def test_absurd_depths_do_not_crash_or_give_nan(method):
    z = np.full((5, 5), 2.0)
    z[1, 1], z[3, 3], z[2, 2] = 1e300, 1e-300, np.finfo(np.float64).max
    t = discontinuity_test(z, np.ones(z.shape, bool), method)
    assert not np.isnan(t.statistic).any() and not np.isnan(t.threshold).any()
    out = mark_reliable(_grey(z.shape), z, np.ones(z.shape, bool), method)
    assert out.dtype == bool and not out[1, 1]


def test_nan_colour_at_known_pixel_is_unreliable_and_does_not_spread():
    rgb = _grey((5, 5))
    rgb[2, 2, 1] = np.nan
    out = mark_reliable(rgb, np.full((5, 5), 2.0), np.ones((5, 5), bool))
    assert not out[2, 2] and out.sum() == 24


# --------------------------------------------------------------------------------------------------
# Kernel paths: neighbour requirements, float32 exposure
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("min_nb", [3, 4, 5, 6, 7, 8])
def test_noise_model_verdict_for_every_neighbour_requirement(min_nb):
    # The kernel judges a row's interior with one neighbour requirement (and skips the threshold
    # lookup when only the 8-neighbour threshold can apply), then the first and last column with
    # their own: compare every pixel, borders and corners included, with the reference rule.
    rng = np.random.default_rng(min_nb)
    z = _noisy(_slanted_wall(9, 11, 2.0, 30.0), 12)
    z[2:6, 3:7] -= 0.2
    known = rng.uniform(size=z.shape) > 0.15
    ref, n_ref = noise_model_reference(z, known)
    need = np.minimum(min_nb, in_image_neighbours(z.shape))
    testable = known & (n_ref >= np.maximum(need, 3))
    thr = chi2.isf(0.05, np.maximum(n_ref - 2, 1))
    expected = testable & (np.nan_to_num(ref, nan=np.inf) <= thr)
    t = discontinuity_test(z, known, min_neighbours=min_nb)
    np.testing.assert_array_equal(t.testable, testable)
    np.testing.assert_array_equal(t.passed, expected)
    np.testing.assert_array_equal(mark_reliable(_grey(z.shape), z, known, min_neighbours=min_nb), expected)
    assert 0 < expected.sum() < testable.sum() or min_nb == 8


@pytest.mark.parametrize("min_nb", [0, 2, 5, 8])
def test_monroy2018_verdict_for_every_neighbour_requirement(min_nb):
    rng = np.random.default_rng(30 + min_nb)
    z = rng.uniform(20.0, 60.0, (8, 10))
    z[:, 5:] += 40.0
    known = rng.uniform(size=z.shape) > 0.2
    ref = monroy2018_reference(z, known)
    n_nb = np.array([[sum(1 for _ in known_offsets(known, r, c, False)) for c in range(10)] for r in range(8)])
    expected = known & (n_nb >= np.minimum(min_nb, in_image_neighbours(z.shape))) & (ref <= MONROY2018_THRESHOLD)
    np.testing.assert_array_equal(discontinuity_test(z, known, "monroy2018", min_neighbours=min_nb).passed, expected)


@pytest.mark.parametrize("dark, bright", [(0.05, 0.95), (1 / 3, 2 / 3), (0.0, 1.0), (-1e300, 1e300), (1e300, -1e300),
                                          (0.1, 0.1), (float(np.float32(0.25)), float(np.float32(0.75)))])
def test_float32_colour_is_judged_as_its_exact_value(dark, bright):
    # float32 colour is compared in float32 with thresholds rounded outwards; every float32 value next
    # to a threshold must be judged as the float64 comparison judges it.
    near = []
    for t in (dark, bright):
        with np.errstate(over="ignore"):
            c = np.float32(t)
        near += [np.nextafter(c, np.float32(-np.inf)), c, np.nextafter(c, np.float32(np.inf))]
    values = np.array(near + [0.0, 1.0, -0.0, 3e38, -3e38, np.inf, -np.inf, np.nan], np.float32)
    rng = np.random.default_rng(1)
    rgb = rng.choice(values, size=(40, 50, 3)).astype(np.float32)
    rgb[0, :3] = [3e38, 3e38, 0.5]  # the float32 sum overflows; the float64 one does not
    z = np.full((40, 50), 2.0)
    known = np.ones(z.shape, bool)
    expected = exposure_reference(rgb, dark, bright)
    assert not expected.all()
    got = mark_reliable(rgb, z, known, dark=dark, bright=bright, min_neighbours=3)
    np.testing.assert_array_equal(got, expected & discontinuity_test(z, known, min_neighbours=3).passed)
    np.testing.assert_array_equal(exposure_ok(rgb, dark=dark, bright=bright), expected)
    wide = rgb.astype(np.float64)  # the same values in float64: only the overflowing sums differ
    np.testing.assert_array_equal(mark_reliable(wide, z, known, dark=dark, bright=bright, min_neighbours=3),
                                  exposure_reference(wide, dark, bright) & discontinuity_test(z, known, min_neighbours=3).passed)


@pytest.mark.parametrize("method", RELIABILITY_METHODS)
def test_discontinuity_passed_is_the_tests_passed_mask(method):
    """The mask-only entry point: the same mask on steps, noise, holes, NaN and borders, the same errors."""
    rng = np.random.default_rng(21)
    z = 2.0 + 0.02 * rng.standard_normal((40, 50))
    z[:, 25:] += 0.4
    z[rng.random(z.shape) < 0.03] = np.nan
    known = rng.random(z.shape) > 0.05
    for depth in (z, z.astype(np.float32), z[:1], z[:, :2]):
        k = known[: depth.shape[0], : depth.shape[1]]
        np.testing.assert_array_equal(discontinuity_passed(depth, k, method), discontinuity_test(depth, k, method).passed)
    assert discontinuity_passed(np.zeros((0, 5)), np.zeros((0, 5), bool), method).shape == (0, 5)
    with pytest.raises(ShapeError):
        discontinuity_passed(z, known[:, :-1], method)
    with pytest.raises(RangeError):
        discontinuity_passed(z, known, method, p_value=0.0)
