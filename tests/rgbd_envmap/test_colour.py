"""Tests for rgbd_envmap.colour: the sRGB transfer functions and NV21 decode / encode.

References: colour-science's IEC 61966-2-1 implementation for the transfer functions, and an ITU-R
BT.601 limited-range YCbCr formula written out (from Kr = 0.299, Kb = 0.114) for NV21
(:mod:`rgbd_envmap.reference.colour`).

How close OpenCV's ``COLOR_YUV2RGB_NV21`` gets to the exact formula was measured exhaustively over all
2^24 (Y, U, V) triples: its 20-bit fixed-point coefficients stay within 0.69 of a level of the
real-valued result, so ±1 level of the rounded exact value. One deliberate deviation: OpenCV clamps
Y − 16 at 0, decoding footroom luma (Y < 16) as black luma instead of extrapolating to negative values
before the final clip; the reference below does the same and says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import colour as colour_science  # colour-science; not to be confused with rgbd_envmap.colour
import numpy as np
import pytest

from rgbd_envmap import colour
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, RgbdEnvmapError, ShapeError
from rgbd_envmap.reference.colour import bt601_decode, bt601_encode, nv21_planes


@dataclass(frozen=True)
class _Tolerances:
    transfer: float = 1e-6  #: sRGB transfer vs colour-science (float32 or float64)
    #: linear_to_srgb(srgb_to_linear(x)) in float64. Not 1e-15: IEC 61966-2-1's rounded constants
    #: (break at 0.04045 encoded, 0.0031308 linear) make the two segments miss by ~3e-8 at the break.
    round_trip_f64: float = 1e-7
    round_trip_f32: float = 1e-6  #: the same in float32
    nv21_decode_levels: int = 1  #: OpenCV's fixed-point decode vs the exact BT.601 formula, rounded
    nv21_round_trip_levels: int = 2  #: decode(encode(flat colour)) vs the colour
    nv21_encode_levels: int = 1  #: encode vs the exact BT.601 forward formula, rounded


TOL = _Tolerances()

# --------------------------------------------------------------------------------------------------
# sRGB transfer functions
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_srgb_to_linear_matches_colour_science(dtype):
    x = np.linspace(0.0, 1.0, 10001).astype(dtype)
    got = colour.srgb_to_linear(x)
    assert got.dtype == dtype and got.shape == x.shape
    np.testing.assert_allclose(got, colour_science.models.eotf_sRGB(x.astype(np.float64)), rtol=0, atol=TOL.transfer)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_linear_to_srgb_matches_colour_science(dtype):
    x = np.linspace(0.0, 1.0, 10001).astype(dtype)
    got = colour.linear_to_srgb(x)
    assert got.dtype == dtype and got.shape == x.shape
    np.testing.assert_allclose(got, colour_science.models.eotf_inverse_sRGB(x.astype(np.float64)), rtol=0, atol=TOL.transfer)


def test_transfer_reference_values():
    # IEC 61966-2-1 values: 0.5 encoded is 0.214041 linear; 0.5 linear is 0.735357 encoded; the
    # linear segment below the break points.
    np.testing.assert_allclose(colour.srgb_to_linear(np.array([0.0, 0.04, 0.5, 1.0])),
                               [0.0, 0.04 / 12.92, 0.2140411405, 1.0], rtol=0, atol=TOL.transfer)
    np.testing.assert_allclose(colour.linear_to_srgb(np.array([0.0, 0.003, 0.5, 1.0])),
                               [0.0, 0.003 * 12.92, 0.7353569831, 1.0], rtol=0, atol=TOL.transfer)


def test_transfer_round_trip():
    x = np.linspace(0.0, 1.0, 100001)
    np.testing.assert_allclose(colour.linear_to_srgb(colour.srgb_to_linear(x)), x, rtol=0, atol=TOL.round_trip_f64)
    np.testing.assert_allclose(colour.srgb_to_linear(colour.linear_to_srgb(x)), x, rtol=0, atol=TOL.round_trip_f64)
    x32 = x.astype(np.float32)
    np.testing.assert_allclose(colour.linear_to_srgb(colour.srgb_to_linear(x32)), x32, rtol=0, atol=TOL.round_trip_f32)


def test_transfer_is_monotonic_and_continuous_at_the_break():
    x = np.linspace(0.0, 1.0, 100001)
    assert (np.diff(colour.srgb_to_linear(x)) > 0).all()
    assert (np.diff(colour.linear_to_srgb(x)) > 0).all()
    for f, brk in ((colour.srgb_to_linear, 0.04045), (colour.linear_to_srgb, 0.0031308)):
        lo, hi = f(np.array([np.nextafter(brk, 0.0), np.nextafter(brk, 1.0)]))
        assert abs(hi - lo) < TOL.transfer


@pytest.mark.parametrize("f", [colour.srgb_to_linear, colour.linear_to_srgb])
def test_transfer_clips_outside_unit_interval(f):
    # 1.055 · 1 − 0.055 is 1 − 1 ulp in float64, hence a tolerance rather than exact equality at 1.
    np.testing.assert_allclose(f(np.array([-0.5, -1e-9, 1.0 + 1e-9, 3.0])), [0.0, 0.0, 1.0, 1.0],
                               rtol=0, atol=TOL.transfer)


@pytest.mark.parametrize("f", [colour.srgb_to_linear, colour.linear_to_srgb])
def test_transfer_nan_and_inf_do_not_crash(f):
    x = np.array([np.nan, np.inf, -np.inf, 0.5])
    with np.errstate(all="raise"):
        got = f(x)
    assert np.isnan(got[0])
    np.testing.assert_allclose(got[1:3], [1.0, 0.0], rtol=0, atol=TOL.transfer)
    assert got[3] == pytest.approx(f(np.array([0.5]))[0])


@pytest.mark.parametrize("f", [colour.srgb_to_linear, colour.linear_to_srgb])
def test_transfer_is_shape_agnostic(f):
    values = np.linspace(0.0, 1.0, 18)
    flat = f(values)
    np.testing.assert_array_equal(f(values.reshape(6, 3)), flat.reshape(6, 3))
    np.testing.assert_array_equal(f(values.reshape(2, 3, 3)), flat.reshape(2, 3, 3))
    # A scalar row and a single value agree with the batch.
    np.testing.assert_array_equal(f(values[3:6]), flat[3:6])
    assert float(f(values[7])) == flat[7]


def test_transfer_does_not_mutate_input():
    x = np.array([[-0.5, 0.2, 1.5]])
    for f in (colour.srgb_to_linear, colour.linear_to_srgb):
        f(x)
        np.testing.assert_array_equal(x, [[-0.5, 0.2, 1.5]])


# --------------------------------------------------------------------------------------------------
# NV21
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [(48, 64), (2, 2), (172, 224)])
def test_decode_nv21_matches_bt601_limited_range(size):
    h, w = size
    buf = np.random.default_rng(h).integers(0, 256, size=(h * 3 // 2, w), dtype=np.uint8)
    got = colour.decode_nv21(buf, h, w)
    assert got.shape == (h, w, 3) and got.dtype == np.uint8
    expected = np.round(bt601_decode(*nv21_planes(buf, h, w)))
    assert np.abs(got.astype(np.int64) - expected).max() <= TOL.nv21_decode_levels


def test_decode_nv21_known_values():
    # Flat 2×2 images: black, white, mid grey at legal-range luma and neutral chroma, and a pure red.
    cases = {(16, 128, 128): (0, 0, 0), (235, 128, 128): (255, 255, 255), (126, 128, 128): (128, 128, 128),
             (81, 90, 240): (255, 0, 0)}  # (Y, U, V) → RGB
    for (y, u, v), rgb in cases.items():
        buf = np.array([[y, y], [y, y], [v, u]], dtype=np.uint8)  # NV21: V first
        got = colour.decode_nv21(buf, 2, 2).astype(np.int64)
        assert np.abs(got - rgb).max() <= TOL.nv21_decode_levels, ((y, u, v), got[0, 0])


def test_decode_nv21_accepts_flat_buffers():
    h, w = 6, 8
    buf = np.random.default_rng(7).integers(0, 256, size=(h * 3 // 2, w), dtype=np.uint8)
    np.testing.assert_array_equal(colour.decode_nv21(buf.ravel(), h, w), colour.decode_nv21(buf, h, w))


@pytest.mark.parametrize("rgb", [
    (0, 0, 0), (255, 255, 255), (128, 128, 128), (255, 0, 0), (0, 255, 0), (0, 0, 255),
    (255, 255, 0), (0, 255, 255), (255, 0, 255), (12, 200, 99), (240, 30, 170), (90, 90, 10),
])
def test_encode_then_decode_flat_colour(rgb):
    img = np.empty((6, 10, 3), dtype=np.uint8)
    img[...] = rgb
    nv21 = colour.encode_nv21(img)
    assert nv21.shape == (9, 10) and nv21.dtype == np.uint8
    got = colour.decode_nv21(nv21, 6, 10).astype(np.int64)
    assert np.abs(got - np.array(rgb)).max() <= TOL.nv21_round_trip_levels, got[0, 0]


def test_encode_then_decode_many_random_flat_colours():
    for rgb in np.random.default_rng(11).integers(0, 256, size=(200, 3)):
        img = np.broadcast_to(rgb.astype(np.uint8), (4, 4, 3))
        got = colour.decode_nv21(colour.encode_nv21(img), 4, 4).astype(np.int64)
        assert np.abs(got - rgb).max() <= TOL.nv21_round_trip_levels, (rgb, got[0, 0])


def test_encode_nv21_matches_bt601_and_puts_v_first():
    for rgb in np.random.default_rng(12).integers(0, 256, size=(50, 3)):
        img = np.broadcast_to(rgb.astype(np.uint8), (2, 4, 3))
        buf = colour.encode_nv21(img).reshape(-1).astype(np.int64)
        y, cb, cr = bt601_encode(rgb)
        assert np.abs(buf[:8] - np.round(y)).max() <= TOL.nv21_encode_levels
        assert np.abs(buf[8::2] - np.round(cr)).max() <= TOL.nv21_encode_levels  # V (Cr) first
        assert np.abs(buf[9::2] - np.round(cb)).max() <= TOL.nv21_encode_levels


def test_encode_nv21_keeps_spatial_layout():
    # Left half red, right half blue: each 2×2 chroma block is uniform, so decode recovers both.
    img = np.zeros((4, 8, 3), dtype=np.uint8)
    img[:, :4] = (255, 0, 0)
    img[:, 4:] = (0, 0, 255)
    got = colour.decode_nv21(colour.encode_nv21(img), 4, 8).astype(np.int64)
    assert np.abs(got - img).max() <= TOL.nv21_round_trip_levels


@pytest.mark.parametrize("buf_shape", [(8, 8), (12, 7), (95,), (97,), (9, 8, 2)])
def test_decode_nv21_wrong_size_raises_shape_error(buf_shape):
    with pytest.raises(ShapeError) as info:
        colour.decode_nv21(np.zeros(buf_shape, dtype=np.uint8), 6, 8)
    assert isinstance(info.value, ValueError)
    assert "nv21" in str(info.value)


@pytest.mark.parametrize("buf_shape,size", [((12, 6), (6, 8)), ((9, 8), (8, 6)), ((9, 8, 1), (6, 8))],
                         ids=["other_2d_shape", "swapped_height_width", "extra_axis"])
def test_decode_nv21_rejects_a_buffer_of_another_shape_with_the_same_byte_count(buf_shape, size):
    """The docstring accepts (H * 3 // 2, W) or the same bytes flat; any other shape (here: one with
    the right number of bytes, as when height and width are swapped) must raise, not be reinterpreted."""
    with pytest.raises(ShapeError):
        colour.decode_nv21(np.zeros(buf_shape, dtype=np.uint8), *size)


@pytest.mark.parametrize("size", [(5, 8), (6, 7), (1, 1)])
def test_decode_nv21_odd_size_raises_invalid_input(size):
    h, w = size
    with pytest.raises(InvalidInputError):
        colour.decode_nv21(np.zeros(h * 3 // 2 * w + 8, dtype=np.uint8), h, w)


@pytest.mark.parametrize("size", [(0, 8), (6, 0), (-2, 8)])
def test_decode_nv21_non_positive_size_raises_range_error(size):
    with pytest.raises(RangeError):
        colour.decode_nv21(np.zeros(72, dtype=np.uint8), *size)


def test_decode_nv21_wrong_dtype_raises():
    with pytest.raises(DTypeError):
        colour.decode_nv21(np.zeros((9, 8), dtype=np.uint16), 6, 8)
    with pytest.raises(DTypeError):
        colour.decode_nv21(np.zeros((9, 8), dtype=np.float32), 6, 8)


@pytest.mark.parametrize("shape,dtype,error", [
    ((5, 8, 3), np.uint8, InvalidInputError),
    ((6, 7, 3), np.uint8, InvalidInputError),
    ((0, 8, 3), np.uint8, InvalidInputError),
    ((6, 8), np.uint8, ShapeError),
    ((6, 8, 4), np.uint8, ShapeError),
    ((6, 8, 3), np.float32, DTypeError),
])
def test_encode_nv21_bad_input(shape, dtype, error):
    with pytest.raises(error) as info:
        colour.encode_nv21(np.zeros(shape, dtype=dtype))
    assert isinstance(info.value, RgbdEnvmapError)
