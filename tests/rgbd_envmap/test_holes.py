"""Tests for rgbd_envmap.depth.holes: hole filling of the depth image (paper 003 §4.2, eq. 1).

The reference for "monroy2018" is :func:`rgbd_envmap.reference.holes.eq1_reference`: a deliberately
slow, obvious pure-Python transcription of eq. (1) that marches outward pixel by pixel from every
unknown pixel in each of the 8 directions. The library's numba kernel shares no code with it (it
sweeps the image twice, keeping the nearest source of every ray).
:func:`~rgbd_envmap.reference.holes.eq1_kernel_order_reference` marches the same way with the
kernel's float64 order of operations, and pins the kernel bit for bit. Closed-form
cases check the weights against the formula by hand.
The baselines ("telea", "ip_basic") are checked on planar ramps and for their contracts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rgbd_envmap import depth
from rgbd_envmap.depth import holes
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
    UnknownMethodError,
)
from rgbd_envmap.reference.holes import (
    DIRECTIONS,
    eq1_kernel_order_reference,
    eq1_reference,
    source_range_reference,
)

fill_holes = holes.fill_holes
FILL_METHODS = holes.FILL_METHODS


@dataclass(frozen=True)
class _Tolerances:
    reference_m: float = 1e-5  #: monroy2018 vs the pure-Python eq. (1), float32 output (brief: 1e-5)
    closed_form_rel: float = 1e-6  #: hand-computed weighted means (float64 sums, float32 output)
    ramp_telea_m: float = 0.005  #: telea on a gentle planar ramp (1 mm/px, 0.5 mm/px): 3.3 mm seen
    #: ip_basic on the same ramp: its dilations pick the nearest depth within up to 5 px (by design,
    #: favouring foreground), 1 mm/px × 5 px, plus the blurs: 5.9 mm seen.
    ramp_ip_basic_m: float = 0.008
    #: telea from one source: OpenCV's bounded gradient term, scaled down to ~10 µm per step (holes.py).
    telea_constant_m: float = 1e-4


TOL = _Tolerances()

def _random_case(rng: np.random.Generator, h: int, w: int, hole_fraction: float):
    depth = rng.uniform(0.2, 4.0, (h, w)).astype(np.float32)
    known = rng.random((h, w)) >= hole_fraction
    depth[~known] = np.nan  # must be ignored
    return depth, known


def _assert_matches_reference(depth: np.ndarray, known: np.ndarray) -> None:
    out, after = fill_holes(depth, known)
    ref, ref_after = eq1_reference(depth, known)
    np.testing.assert_array_equal(after, ref_after)
    np.testing.assert_allclose(out[after], ref[after], rtol=0, atol=TOL.reference_m)
    assert np.all(out[~after] == 0.0)


# ---------------------------------------------------------------------------------------------------
# smoke / shape
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", FILL_METHODS)
def test_smoke_shapes_and_dtypes(method):
    depth, known = _random_case(np.random.default_rng(0), 20, 30, 0.3)
    out, after = fill_holes(depth, known, method=method)
    assert out.shape == (20, 30) and out.dtype == np.float32
    assert after.shape == (20, 30) and after.dtype == bool
    assert after[known].all()


def test_methods_registered():
    assert FILL_METHODS == ("monroy2018", "telea", "ip_basic")


def test_package_reexports_fill_holes():
    assert depth.fill_holes is fill_holes and depth.FILL_METHODS == FILL_METHODS


# ---------------------------------------------------------------------------------------------------
# monroy2018 against the pure-Python reference
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (11, 1), (5, 5), (17, 23), (31, 12), (40, 9), (24, 48)])
@pytest.mark.parametrize("hole_fraction", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_monroy2018_matches_reference_on_random_masks(shape, hole_fraction):
    rng = np.random.default_rng([shape[0], shape[1], int(hole_fraction * 10)])
    for _ in range(3):
        _assert_matches_reference(*_random_case(rng, *shape, hole_fraction))


def test_monroy2018_matches_reference_on_blob_holes():
    """Large holes (discs) make the rays long: the sweep must still find the nearest source."""
    rng = np.random.default_rng(7)
    h, w = 36, 44
    yy, xx = np.mgrid[:h, :w]
    for _ in range(4):
        depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
        known = np.ones((h, w), bool)
        for _ in range(3):
            cy, cx, r = rng.integers(0, h), rng.integers(0, w), rng.integers(4, 14)
            known &= (yy - cy) ** 2 + (xx - cx) ** 2 > r * r
        _assert_matches_reference(depth, known)


@settings(max_examples=150, deadline=None)
@given(
    known=hnp.arrays(bool, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12)),
    seed=st.integers(0, 2**32 - 1),
)
def test_monroy2018_matches_reference_property(known, seed):
    depth = np.random.default_rng(seed).uniform(0.1, 5.0, known.shape).astype(np.float32)
    _assert_matches_reference(depth, known)


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (11, 1), (17, 23), (60, 7), (7, 60), (45, 45)])
@pytest.mark.parametrize("hole_fraction", [0.05, 0.5, 0.95])
def test_monroy2018_is_bit_identical_to_the_kernel_order_reference(shape, hole_fraction):
    """Tall frames (rays longer than the width), sparse and dense holes, and discs."""
    rng = np.random.default_rng([shape[0], shape[1], int(hole_fraction * 100)])
    depth, known = _random_case(rng, *shape, hole_fraction)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    disc = known & ((yy - shape[0] // 3) ** 2 + (xx - shape[1] // 2) ** 2 > (min(shape) // 3) ** 2)
    for k in (known, disc):
        out, _ = fill_holes(depth, k)
        np.testing.assert_array_equal(out.view(np.uint32), eq1_kernel_order_reference(depth, k).view(np.uint32))


def test_monroy2018_all_unknown_stays_unknown():
    depth = np.full((6, 7), np.nan, np.float32)
    out, after = fill_holes(depth, np.zeros((6, 7), bool))
    assert not after.any() and np.all(out == 0.0)


def test_monroy2018_all_known_unchanged():
    depth, _ = _random_case(np.random.default_rng(1), 9, 13, 0.0)
    out, after = fill_holes(depth, np.ones(depth.shape, bool))
    assert after.all() and np.array_equal(out, depth)


def test_monroy2018_single_known_pixel_fills_exactly_its_eight_rays():
    h, w, y0, x0, value = 15, 20, 7, 9, np.float32(1.2345)
    depth = np.zeros((h, w), np.float32)
    known = np.zeros((h, w), bool)
    depth[y0, x0], known[y0, x0] = value, True
    out, after = fill_holes(depth, known)
    on_ray = np.zeros((h, w), bool)
    for dy, dx in DIRECTIONS:
        y, x = y0, x0
        while 0 <= y < h and 0 <= x < w:
            on_ray[y, x] = True
            y, x = y + dy, x + dx
    # Every ray here is shorter than the width (≤ 14 axis steps, ≤ 9·√2 diagonal), so every weight > 0.
    np.testing.assert_array_equal(after, on_ray)
    np.testing.assert_allclose(out[on_ray], value, rtol=TOL.closed_form_rel)
    assert np.all(out[~on_ray] == 0.0)


def test_monroy2018_filled_pixels_are_not_sources():
    """(2, 1) is a knight's move from the only known pixel: no ray of its reaches a known pixel, though
    its neighbours (1, 1), (2, 0), (2, 2) get filled. If filled pixels were sources it would be filled."""
    depth = np.zeros((3, 3), np.float32)
    known = np.zeros((3, 3), bool)
    depth[0, 0], known[0, 0] = 2.0, True
    out, after = fill_holes(depth, known)
    assert after[1, 1] and after[2, 0] and after[2, 2]
    assert not after[2, 1] and not after[1, 2]
    assert out[2, 1] == 0.0


def test_monroy2018_holes_along_the_border():
    rng = np.random.default_rng(3)
    depth, known = _random_case(rng, 14, 19, 0.2)
    known[0, :] = known[-1, :] = known[:, 0] = known[:, -1] = False
    known[:3, :4] = False  # a corner block
    _assert_matches_reference(depth, known)


@pytest.mark.parametrize("shape", [(1, 1), (1, 6), (6, 1)])
def test_monroy2018_degenerate_frames(shape):
    depth = np.arange(1, np.prod(shape) + 1, dtype=np.float32).reshape(shape)
    out, after = fill_holes(depth, np.ones(shape, bool))
    assert np.array_equal(out, depth) and after.all()
    out, after = fill_holes(depth, np.zeros(shape, bool))
    assert not after.any()


def test_monroy2018_one_pixel_frame_unknown_stays_unknown():
    out, after = fill_holes(np.array([[np.nan]], np.float32), np.array([[False]]))
    assert not after[0, 0] and out[0, 0] == 0.0


def test_monroy2018_column_frame_weights_vanish_beyond_the_width():
    """N×1: only vertical rays, w = 1, so any source at distance ≥ 1 has weight 0: nothing fills."""
    depth = np.linspace(1.0, 2.0, 8, dtype=np.float32)[:, None]
    known = np.array([True, False, True, False, False, True, False, True])[:, None]
    out, after = fill_holes(depth, known)
    np.testing.assert_array_equal(after, known)


def test_monroy2018_tall_frame_distance_limit():
    """In a frame 5 px wide the diagonal from (0, 0) reaches (3, 3) at x_r = 3√2 ≈ 4.24 < 5 (weight
    > 0) and (4, 4) at 4√2 ≈ 5.66 ≥ 5 (weight 0); straight down, (4, 0) at 4 < 5 fills and (5, 0)
    and below, at ≥ 5, do not."""
    h, w = 12, 5
    depth = np.zeros((h, w), np.float32)
    known = np.zeros((h, w), bool)
    depth[0, 0], known[0, 0] = 3.0, True
    out, after = fill_holes(depth, known)
    assert after[3, 3] and not after[4, 4]
    assert after[4, 0] and not after[5:, 0].any()
    assert after[0, 4]  # 4 steps along the row
    np.testing.assert_allclose(out[after], 3.0, rtol=TOL.closed_form_rel)
    _assert_matches_reference(depth, known)


def test_monroy2018_tall_frame_mixed_sources():
    """A tall frame (60×7) with sparse sources: many pixels have only far (zero-weight) sources."""
    rng = np.random.default_rng(11)
    for _ in range(5):
        depth, known = _random_case(rng, 60, 7, 0.93)
        _assert_matches_reference(depth, known)


# ---------------------------------------------------------------------------------------------------
# monroy2018 closed forms
# ---------------------------------------------------------------------------------------------------


def test_monroy2018_ramp_row_hole_gives_mean_of_equidistant_sources():
    w = 21
    ramp = (1.0 + 0.05 * np.arange(w)).astype(np.float32)[None, :]
    known = np.ones((1, w), bool)
    known[0, 7:14] = False  # centre 10; nearest sources at 6 and 14, both 4 away
    out, after = fill_holes(ramp, known)
    assert after.all()
    assert out[0, 10] == pytest.approx((ramp[0, 6] + ramp[0, 14]) / 2.0, rel=TOL.closed_form_rel)


def test_monroy2018_ramp_in_x_is_exact_where_sources_are_symmetric():
    """A ramp in x with a hole spanning part of one row, rows above and below known: the centre pixel's
    sources pair up symmetrically (up/down equal, left/right and diagonals mirror), so eq. (1) returns
    the ramp value there."""
    h, w = 9, 30
    ramp = np.tile((0.8 + 0.01 * np.arange(w)).astype(np.float32), (h, 1))
    known = np.ones((h, w), bool)
    known[4, 10:21] = False  # centre column 15
    out, _ = fill_holes(ramp, known)
    assert out[4, 15] == pytest.approx(ramp[4, 15], rel=TOL.closed_form_rel)


def test_monroy2018_axis_weights_follow_the_formula():
    w, p = 10, 3
    a, b = 1.0, 3.0
    depth = np.zeros((1, w), np.float32)
    known = np.zeros((1, w), bool)
    depth[0, 0], depth[0, w - 1] = a, b
    known[0, 0] = known[0, w - 1] = True
    w_a, w_b = (w - p) / w, (w - (w - 1 - p)) / w
    out, _ = fill_holes(depth, known)
    assert out[0, p] == pytest.approx((w_a * a + w_b * b) / (w_a + w_b), rel=TOL.closed_form_rel)


def test_monroy2018_diagonal_weight_uses_sqrt2_per_step():
    """Pixel (5, 4) sees exactly two sources: (2, 1) three diagonal steps up-left (x_r = 3√2) and
    (5, 9) five steps right (x_r = 5)."""
    h, w = 8, 12
    depth = np.zeros((h, w), np.float32)
    known = np.zeros((h, w), bool)
    depth[2, 1], depth[5, 9] = 1.5, 2.5
    known[2, 1] = known[5, 9] = True
    w_diag, w_axis = (w - 3 * math.sqrt(2.0)) / w, (w - 5.0) / w
    out, after = fill_holes(depth, known)
    assert after[5, 4]
    assert out[5, 4] == pytest.approx((w_diag * 1.5 + w_axis * 2.5) / (w_diag + w_axis), rel=TOL.closed_form_rel)


def test_monroy2018_mirror_symmetry():
    """Flipping the frame left-right (or up-down) flips the result: no direction is favoured."""
    depth, known = _random_case(np.random.default_rng(5), 23, 31, 0.6)
    out, after = fill_holes(depth, known)
    for axis in (0, 1):
        out_f, after_f = fill_holes(np.flip(depth, axis), np.flip(known, axis))
        np.testing.assert_array_equal(np.flip(after_f, axis), after)
        np.testing.assert_allclose(np.flip(out_f, axis), out, rtol=1e-6, atol=0)


# ---------------------------------------------------------------------------------------------------
# monroy2018 with max_source_ratio: holes across a depth edge stay unknown
# ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 9), (17, 23), (60, 7), (45, 45)])
@pytest.mark.parametrize("hole_fraction", [0.05, 0.5, 0.95])
@pytest.mark.parametrize("ratio", [1.0, 1.5, 4.0])
def test_monroy2018_max_source_ratio_matches_the_reference(shape, hole_fraction, ratio):
    """Exactly the holes whose sources span more than the ratio stay unknown; the others keep the
    unguarded eq. (1) value bit for bit."""
    rng = np.random.default_rng([shape[0], shape[1], int(hole_fraction * 100), int(ratio * 10)])
    depth, known = _random_case(rng, *shape, hole_fraction)
    out, after = fill_holes(depth, known, max_source_ratio=ratio)
    plain, plain_after = fill_holes(depth, known)
    lo, hi = source_range_reference(np.nan_to_num(depth), known)
    expected = plain_after & (known | (hi <= lo * ratio))
    np.testing.assert_array_equal(after, expected)
    np.testing.assert_array_equal(out[after].view(np.uint32), plain[after].view(np.uint32))
    assert np.all(out[~after] == 0.0)
    if hole_fraction == 0.05 and shape == (45, 45) and ratio == 4.0:
        assert 0 < (plain_after & ~after).sum() < (~known).sum()  # the case discriminates


def test_monroy2018_max_source_ratio_keeps_holes_within_a_surface_and_drops_them_across_an_edge():
    """A foreground plane at 1 m beside a background at 3 m with a gap of dropped (mixed) pixels
    between them, and a hole inside each plane: the gap stays unknown, the in-surface holes fill as
    without the option, and no filled depth lies between the two planes."""
    h, w = 30, 40
    depth = np.where(np.arange(w)[None, :] < 20, 1.0, 3.0).astype(np.float32) * np.ones((h, 1), np.float32)
    depth += np.float32(0.001) * np.arange(h, dtype=np.float32)[:, None]  # a gentle slope
    known = np.ones((h, w), bool)
    known[:, 18:22] = False  # the edge's mixed pixels
    known[5:8, 5:9] = False  # a dark spot on the foreground
    known[20:24, 30:35] = False  # one on the background
    plain, plain_after = fill_holes(depth, known)
    assert plain_after.all() and np.any((plain > 1.1) & (plain < 2.9))  # eq. (1) invents a surface
    out, after = fill_holes(depth, known, max_source_ratio=1.5)
    assert not after[:, 18:22].any()
    assert after[5:8, 5:9].all() and after[20:24, 30:35].all()
    np.testing.assert_array_equal(out[after], plain[after])
    assert not np.any((out > 1.1) & (out < 2.9))


def test_monroy2018_max_source_ratio_ignores_sources_of_zero_weight():
    """A 12×3 frame whose middle column is unknown but for a far 10 m pixel at the bottom: at row 2
    that source is 9 steps away (≥ the width 3, weight 0) and does not count, so the hole fills from
    its 1 m neighbours; at row 9, 2 steps away, it counts and the hole stays unknown."""
    depth = np.ones((12, 3), np.float32)
    known = np.ones((12, 3), bool)
    known[:, 1] = False
    known[11, 1], depth[11, 1] = True, 10.0
    out, after = fill_holes(depth, known, max_source_ratio=1.5)
    assert after[2, 1] and out[2, 1] == np.float32(1.0)
    assert not after[9, 1] and not after[10, 1]


def test_monroy2018_max_source_ratio_none_and_inf_are_eq1():
    depth, known = _random_case(np.random.default_rng(5), 23, 31, 0.4)
    plain = fill_holes(depth, known)
    for ratio in (None, float("inf")):
        out, after = fill_holes(depth, known, max_source_ratio=ratio)
        np.testing.assert_array_equal(after, plain[1])
        np.testing.assert_array_equal(out.view(np.uint32), plain[0].view(np.uint32))


@pytest.mark.parametrize("bad", [0.5, 0.0, -1.0, float("nan"), True, "1.5"])
def test_monroy2018_max_source_ratio_must_be_at_least_one(bad):
    depth, known = _random_case(np.random.default_rng(6), 5, 5, 0.3)
    with pytest.raises(RangeError, match="max_source_ratio"):
        fill_holes(depth, known, max_source_ratio=bad)


@pytest.mark.parametrize("shape", [(1, 9), (17, 23), (45, 45)])
@pytest.mark.parametrize("ratio", [1.0, 1.5, 4.0, float("inf")])
def test_fill_holes_flagged_is_eq1_with_the_guard_as_flags(shape, ratio):
    """Depth and known_after of plain eq. (1) bit for bit; the flags are exactly the holes the guard
    (``max_source_ratio``) leaves unknown."""
    rng = np.random.default_rng([shape[0], shape[1], int(min(ratio, 99) * 10)])
    depth, known = _random_case(rng, *shape, 0.3)
    out, after, across = holes.fill_holes_flagged(depth, known, ratio)
    plain, plain_after = fill_holes(depth, known)
    _, guarded_after = fill_holes(depth, known, max_source_ratio=ratio)
    np.testing.assert_array_equal(out.view(np.uint32), plain.view(np.uint32))
    np.testing.assert_array_equal(after, plain_after)
    np.testing.assert_array_equal(across, plain_after & ~guarded_after)
    assert across.dtype == bool and not (across & known).any()


def test_fill_holes_flagged_edge_and_surface_holes():
    """The two-plane frame of the test above: the gap between the planes is flagged, the holes
    inside each plane are not; an empty frame gives empty outputs."""
    h, w = 30, 40
    z = np.where(np.arange(w)[None, :] < 20, 1.0, 3.0).astype(np.float32) * np.ones((h, 1), np.float32)
    known = np.ones((h, w), bool)
    known[:, 18:22] = False
    known[5:8, 5:9] = False
    _, after, across = depth.fill_holes_flagged(z, known, 1.5)  # the package's re-export
    assert after.all() and across[:, 18:22].all() and across.sum() == h * 4
    out, after, across = depth.fill_holes_flagged(np.zeros((0, 5), np.float32), np.zeros((0, 5), bool), 1.5)
    assert out.shape == after.shape == across.shape == (0, 5)


@pytest.mark.parametrize("bad", [0.5, float("nan"), True, "2"])
def test_fill_holes_flagged_needs_a_ratio_of_at_least_one(bad):
    d, k = _random_case(np.random.default_rng(8), 5, 5, 0.3)
    with pytest.raises(RangeError, match="max_source_ratio"):
        holes.fill_holes_flagged(d, k, bad)


def test_fill_holes_flagged_checks_its_input_as_fill_holes_does():
    d, k = _random_case(np.random.default_rng(9), 5, 5, 0.3)
    with pytest.raises(ShapeError):
        holes.fill_holes_flagged(d, k[:4], 1.5)
    bad = d.copy()
    bad[k] = -1.0
    with pytest.raises(RangeError, match="depth > 0"):
        holes.fill_holes_flagged(bad, k, 1.5)


@pytest.mark.parametrize("method", ["telea", "ip_basic"])
def test_max_source_ratio_is_an_option_of_monroy2018_only(method):
    depth, known = _random_case(np.random.default_rng(7), 5, 5, 0.3)
    with pytest.raises(InvalidInputError, match="max_source_ratio"):
        fill_holes(depth, known, method=method, max_source_ratio=1.5)


# ---------------------------------------------------------------------------------------------------
# baselines
# ---------------------------------------------------------------------------------------------------


def _planar_ramp_with_hole(h=48, w=64, radius=6):
    yy, xx = np.mgrid[:h, :w]
    depth = (2.0 + 0.001 * xx + 0.0005 * yy).astype(np.float32)
    known = (yy - h // 2) ** 2 + (xx - w // 2) ** 2 > radius**2
    holed = depth.copy()
    holed[~known] = np.nan
    return depth, holed, known


@pytest.mark.parametrize("method, tol", [("telea", TOL.ramp_telea_m), ("ip_basic", TOL.ramp_ip_basic_m),
                                         ("monroy2018", TOL.ramp_telea_m)])
def test_planar_ramp_hole_is_filled_closely(method, tol):
    truth, holed, known = _planar_ramp_with_hole()
    out, after = fill_holes(holed, known, method=method)
    assert after.all()
    np.testing.assert_allclose(out[~known], truth[~known], rtol=0, atol=tol)
    assert np.array_equal(out[known], truth[known])


@pytest.mark.parametrize("method", ["telea", "ip_basic"])
def test_baseline_all_unknown_stays_unknown(method):
    out, after = fill_holes(np.full((8, 9), np.nan, np.float32), np.zeros((8, 9), bool), method=method)
    assert not after.any() and np.all(out == 0.0)


@pytest.mark.parametrize("method", ["telea", "ip_basic"])
@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (3, 3)])
def test_baseline_degenerate_frames(method, shape):
    depth = np.arange(1, np.prod(shape) + 1, dtype=np.float32).reshape(shape)
    known = np.ones(shape, bool)
    known.flat[0] = shape == (1, 1)
    out, after = fill_holes(depth, known, method=method)
    assert np.array_equal(out[known], depth[known])
    assert np.isfinite(out).all() and np.all(out[after] > 0)


def test_telea_reaches_every_pixel_from_one_source():
    depth = np.zeros((10, 12), np.float32)
    known = np.zeros((10, 12), bool)
    depth[3, 4], known[3, 4] = 1.7, True
    out, after = fill_holes(depth, known, method="telea")
    assert after.all()
    np.testing.assert_allclose(out, 1.7, rtol=0, atol=TOL.telea_constant_m)


def test_telea_ignores_values_under_the_mask():
    _, holed, known = _planar_ramp_with_hole()
    a = fill_holes(np.where(known, holed, 0.0).astype(np.float32), known, method="telea")[0]
    b = fill_holes(np.where(known, holed, 1e6).astype(np.float32), known, method="telea")[0]
    assert np.array_equal(a, b)


def test_telea_radius_option():
    _, holed, known = _planar_ramp_with_hole()
    out, _ = fill_holes(holed, known, method="telea", radius_px=2)
    assert np.isfinite(out).all()
    with pytest.raises(RangeError, match="radius_px"):
        fill_holes(holed, known, method="telea", radius_px=0)


def test_ip_basic_prefers_the_nearer_surface_at_an_edge():
    """Grey dilation of inverted depth picks the closest depth in the kernel: a hole straddling a
    step edge fills with the foreground (the paper's stated intent)."""
    depth = np.full((20, 20), 3.0, np.float32)
    depth[:, :10] = 1.0
    known = np.ones((20, 20), bool)
    known[8:12, 9:11] = False
    out, after = fill_holes(depth, known, method="ip_basic", blur="none")
    assert after.all()
    np.testing.assert_allclose(out[8:12, 9:11], 1.0)


def test_ip_basic_large_fill_option():
    """The first fills reach about 5 px into a hole (diamond 2 + 7×7 3), the 31×31 large fill 15 px
    more. The centre of a 30 px wide hole is 15 px in: filled only with the large fill. A 70 px hole's
    centre (35 px in) stays unknown either way."""
    h, w = 80, 80
    depth = np.full((h, w), 2.0, np.float32)
    known = np.ones((h, w), bool)
    known[25:55, 25:55] = False
    _, after_small = fill_holes(depth, known, method="ip_basic", large_fill=False)
    _, after_large = fill_holes(depth, known, method="ip_basic")
    assert not after_small[40, 40] and after_large[40, 40]
    known[5:75, 5:75] = False
    for blur in ("bilateral", "gaussian", "none"):
        out, after = fill_holes(depth, known, method="ip_basic", blur=blur)
        assert not after[40, 40] and out[40, 40] == 0.0
        # Rims of the pixels left empty: the Gaussian is normalised, so empty (0) neighbours do not
        # drag depths towards max_depth_m.
        np.testing.assert_allclose(out[after], 2.0, rtol=1e-5)


@pytest.mark.parametrize("blur", ["bilateral", "gaussian", "none"])
def test_ip_basic_blur_options(blur):
    truth, holed, known = _planar_ramp_with_hole()
    out, after = fill_holes(holed, known, method="ip_basic", blur=blur)
    assert after.all() and np.isfinite(out).all()
    assert np.array_equal(out[known], truth[known])


def test_ip_basic_option_errors():
    truth, holed, known = _planar_ramp_with_hole()
    with pytest.raises(UnknownMethodError, match="median"):
        fill_holes(holed, known, method="ip_basic", blur="median")
    with pytest.raises(RangeError, match="max_depth_m"):
        fill_holes(holed, known, method="ip_basic", max_depth_m=2.0)
    with pytest.raises(RangeError, match="bilateral_sigma_m"):
        fill_holes(holed, known, method="ip_basic", bilateral_sigma_m=-1.0)


# ---------------------------------------------------------------------------------------------------
# invariants for every method
# ---------------------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    method=st.sampled_from(FILL_METHODS),
    known=hnp.arrays(bool, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=24)),
    depth=st.floats(0.0625, 10.0, width=32),
    seed=st.integers(0, 2**32 - 1),
)
def test_known_pixels_are_kept_bit_for_bit(method, known, depth, seed):
    rng = np.random.default_rng(seed)
    values = (depth * rng.uniform(0.5, 1.5, known.shape)).astype(np.float32)
    values[~known] = np.nan
    out, after = fill_holes(values, known, method=method)
    assert np.array_equal(out.view(np.uint32)[known], values.view(np.uint32)[known])
    assert after[known].all()
    assert np.isfinite(out).all() and np.all(out[after] > 0) and np.all(out[~after] == 0)


@pytest.mark.parametrize("method", FILL_METHODS)
def test_float64_input_is_rounded_once_to_float32(method):
    depth, known = _random_case(np.random.default_rng(2), 12, 16, 0.3)
    depth64 = depth.astype(np.float64) + 1e-9  # not representable in float32
    depth64[~known] = np.nan
    out, _ = fill_holes(depth64, known, method=method)
    assert out.dtype == np.float32
    assert np.array_equal(out[known], depth64[known].astype(np.float32))


@pytest.mark.parametrize("method", FILL_METHODS)
def test_inputs_are_not_mutated(method):
    depth, known = _random_case(np.random.default_rng(4), 10, 10, 0.4)
    depth_copy, known_copy = depth.copy(), known.copy()
    fill_holes(depth, known, method=method)
    np.testing.assert_array_equal(depth, depth_copy)
    np.testing.assert_array_equal(known, known_copy)


@pytest.mark.parametrize("method", FILL_METHODS)
def test_non_contiguous_inputs(method):
    depth, known = _random_case(np.random.default_rng(6), 20, 30, 0.4)
    a = fill_holes(depth[::2, ::3], known[::2, ::3], method=method)
    b = fill_holes(depth[::2, ::3].copy(), known[::2, ::3].copy(), method=method)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


# ---------------------------------------------------------------------------------------------------
# hard cases: bad input
# ---------------------------------------------------------------------------------------------------


def test_unknown_method_lists_valid_names():
    depth, known = _random_case(np.random.default_rng(0), 4, 4, 0.5)
    with pytest.raises(UnknownMethodError) as info:
        fill_holes(depth, known, method="navier_stokes")
    for name in FILL_METHODS:
        assert name in str(info.value)
    assert isinstance(info.value, ValueError) and isinstance(info.value, RgbdEnvmapError)


def test_unknown_option_is_rejected():
    depth, known = _random_case(np.random.default_rng(0), 4, 4, 0.5)
    with pytest.raises(InvalidInputError, match="radius_px"):
        fill_holes(depth, known, method="monroy2018", radius_px=3)


@pytest.mark.parametrize("method", FILL_METHODS)
@pytest.mark.parametrize("bad, error", [(np.nan, NonFiniteError), (np.inf, NonFiniteError),
                                        (0.0, RangeError), (-1.0, RangeError)])
def test_bad_depth_at_known_pixels_is_rejected_with_a_count(method, bad, error):
    depth, known = _random_case(np.random.default_rng(0), 6, 6, 0.3)
    idx = np.flatnonzero(known)[:3]
    depth.flat[idx] = bad
    with pytest.raises(error, match=r"got 3 "):
        fill_holes(depth, known, method=method)


@pytest.mark.parametrize("method", FILL_METHODS)
@pytest.mark.parametrize("garbage", [np.nan, np.inf, -5.0, 0.0, 1e30])
def test_garbage_at_unknown_pixels_is_ignored(method, garbage):
    depth, known = _random_case(np.random.default_rng(8), 16, 20, 0.4)
    clean = fill_holes(np.where(known, depth, 1.0).astype(np.float32), known, method=method)
    dirty = fill_holes(np.where(known, depth, garbage).astype(np.float32), known, method=method)
    assert np.isfinite(dirty[0]).all()
    assert np.array_equal(clean[0], dirty[0]) and np.array_equal(clean[1], dirty[1])


def test_float64_garbage_beyond_float32_range_at_unknown_pixels_is_ignored():
    depth = np.array([[1.0, 1e300, 2.0]])
    out, after = fill_holes(depth, np.array([[True, False, True]]))
    assert after.all() and np.isfinite(out).all()


@pytest.mark.parametrize(
    "depth_shape, known_shape",
    [((4, 5), (5, 4)), ((4, 5), (4, 5, 1)), ((4, 5, 1), (4, 5, 1)), ((20,), (20,)), ((), ())],
)
def test_shape_errors(depth_shape, known_shape):
    with pytest.raises(ShapeError):
        fill_holes(np.ones(depth_shape, np.float32), np.ones(known_shape, bool))


@pytest.mark.parametrize("known", [np.ones((3, 3), np.uint8), np.ones((3, 3), np.float32),
                                   np.ones((3, 3), np.int64)])
def test_known_must_be_bool(known):
    with pytest.raises(DTypeError, match="known"):
        fill_holes(np.ones((3, 3), np.float32), known)


def test_depth_must_be_float():
    with pytest.raises(DTypeError, match="depth_m"):
        fill_holes(np.ones((3, 3), np.uint16), np.ones((3, 3), bool))


@pytest.mark.parametrize("method", FILL_METHODS)
@pytest.mark.parametrize("shape", [(0, 5), (5, 0), (0, 0)])
def test_empty_frames_give_empty_outputs(method, shape):
    out, after = fill_holes(np.zeros(shape, np.float32), np.zeros(shape, bool), method=method)
    assert out.shape == shape and out.dtype == np.float32
    assert after.shape == shape and after.dtype == bool
