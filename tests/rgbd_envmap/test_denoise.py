"""Edge-aware plane-fit depth denoising, against closed forms (a plane's inverse depth is affine in
the normalised rays, so planes come back exactly) and an independent per-pixel least-squares
reference (numpy lstsq over the same inlier set,
:func:`rgbd_envmap.reference.denoise.plane_fit_reference`)."""

from types import SimpleNamespace

import numpy as np
import pytest

from rgbd_envmap.depth.denoise import _denoise, denoise_depth, denoise_frame
from rgbd_envmap.errors import InvalidInputError, RangeError, ShapeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.reference.denoise import plane_fit_reference
from rgbd_envmap.types import Distortion, Intrinsics, RGBDFrame, RigidTransform

INTR = Intrinsics(48, 36, 40.0, 41.0, 23.5, 17.5, Distortion.radial(-0.08, 0.02, 0.0))


def _plane_depth(intr, normal, d):
    """z-depth of the plane n·X = d along each pixel's ray (x, y, 1)."""
    rays = pixel_rays(intr)
    return d / (rays @ np.asarray(normal, float))


def test_a_plane_comes_back_exactly_and_noise_shrinks():
    z = _plane_depth(INTR, [0.2, -0.3, 1.0], 1.2)
    known = np.ones(z.shape, bool)
    np.testing.assert_allclose(denoise_depth(z, known, INTR), z, rtol=2e-6)
    rng = np.random.default_rng(0)
    noisy = z * (1.0 + 0.01 * rng.standard_normal(z.shape))
    out = denoise_depth(noisy, known, INTR)
    inner = (slice(2, -2), slice(2, -2))
    before = np.sqrt(np.mean((noisy / z - 1.0)[inner] ** 2))
    after = np.sqrt(np.mean((out / z - 1.0)[inner] ** 2))
    assert after < before / 3.0  # 25 inliers, 3 parameters: ~ √(3/25) of the noise


def test_matches_an_independent_least_squares_reference_with_holes_and_edges():
    rng = np.random.default_rng(1)
    z = _plane_depth(INTR, [0.1, 0.2, 1.0], 1.0)
    z[:, 30:] = _plane_depth(INTR, [-0.3, 0.0, 1.0], 2.0)[:, 30:]  # a step edge
    z *= 1.0 + 0.01 * rng.standard_normal(z.shape)
    known = rng.random(z.shape) > 0.2
    got = denoise_depth(z, known, INTR)
    want = plane_fit_reference(z, known, INTR)
    np.testing.assert_allclose(got, want, rtol=1e-5)
    assert np.array_equal(got[~known], z[~known].astype(np.float32))  # unknown pixels untouched


def test_edges_are_not_blended():
    z = np.where(np.arange(INTR.width)[None, :] < 24, 1.0, 1.5) * np.ones((INTR.height, INTR.width))
    z = z / (pixel_rays(INTR) @ np.array([0.0, 0.0, 1.0]))  # two fronto-parallel planes
    out = denoise_depth(z, np.ones(z.shape, bool), INTR)
    np.testing.assert_allclose(out, z, rtol=2e-6)


def test_hard_cases():
    z = np.full((INTR.height, INTR.width), 1.0)
    none = np.zeros(z.shape, bool)
    np.testing.assert_array_equal(denoise_depth(z, none, INTR), z.astype(np.float32))
    # NaN / zero / negative at "known" pixels are neither fitted nor used; neighbours stay exact
    bad = z.copy()
    bad[5, 5], bad[6, 6], bad[7, 7] = np.nan, 0.0, -1.0
    out = denoise_depth(bad, np.ones(z.shape, bool), INTR)
    assert np.isnan(out[5, 5]) and out[6, 6] == 0.0 and out[7, 7] == -1.0
    good = np.isfinite(bad) & (bad > 0)
    assert np.isfinite(out[good]).all()
    # a single measured row: collinear inliers, no plane, the measurement stays
    row = np.zeros(z.shape, bool)
    row[10] = True
    np.testing.assert_array_equal(denoise_depth(z * 1.01, row, INTR)[10], np.float32(1.01))
    with pytest.raises(RangeError):
        denoise_depth(z, none, INTR, min_inliers=2)
    with pytest.raises(RangeError):
        denoise_depth(z, none, INTR, tol_rel=0.0)
    with pytest.raises(RangeError):
        denoise_depth(z[:-1], none[:-1], INTR)
    with pytest.raises(ShapeError):
        denoise_depth(z, none[:-1], INTR)


def _hard_depth(shape, seed):
    """Two noisy planes with a step edge, 25 % holes, and NaN / ±inf / 0 / negative depths at
    "known" pixels: every branch of the inlier test and of the solve."""
    rng = np.random.default_rng(seed)
    h, w = shape
    z = 1.0 + 0.3 * rng.random((h, w))
    z[:, w // 2:] += 1.0
    z *= 1.0 + 0.01 * rng.standard_normal((h, w))
    known = rng.random((h, w)) > 0.25
    bad = rng.random((h, w))
    z[bad < 0.02] = np.nan
    z[(bad >= 0.02) & (bad < 0.03)] = np.inf
    z[(bad >= 0.03) & (bad < 0.04)] = -np.inf
    z[(bad >= 0.04) & (bad < 0.05)] = 0.0
    z[(bad >= 0.05) & (bad < 0.06)] = -1.0
    return z.astype(np.float32), known


@pytest.mark.parametrize("shape", [(36, 48), (120, 160), (1, 1), (1, 7), (7, 1), (2, 2), (3, 40), (17, 33), (4, 3)])
@pytest.mark.parametrize(("tol", "min_in"), [(0.04, 6), (0.5, 3), (0.02, 9)])
@pytest.mark.parametrize("half", [1, 2])
def test_3x3_and_5x5_kernels_equal_the_general_kernel_bit_for_bit(shape, tol, min_in, half):
    """The 3×3 and 5×5 specialisations (float32 depth, half window 1 or 2) against the general kernel
    (float64 depth takes it), bit for bit, on holes, NaN, ±inf, zero and negative depths, image
    borders and images narrower than the window. Both outputs, and denoise_frame's zeroed copy."""
    h, w = shape
    intr = Intrinsics(w, h, 40.0, 41.0, (w - 1) / 2, (h - 1) / 2, Distortion.radial(-0.08, 0.02, 0.0))
    for seed in range(3):
        z, known = _hard_depth(shape, seed)
        fast = denoise_depth(z, known, intr, half_window=half, tol_rel=tol, min_inliers=min_in)
        general = denoise_depth(z.astype(np.float64), known, intr, half_window=half, tol_rel=tol, min_inliers=min_in)
        assert fast.dtype == np.float32 and fast.shape == shape
        np.testing.assert_array_equal(fast.view(np.uint32), general.view(np.uint32))
        if shape == (120, 160) and seed == 0 and min_in < 9:
            assert np.count_nonzero(fast[known] != z[known]) > 1000  # the fit changes most measured pixels
        zeroed = _denoise(z, known, intr, half, tol, float(min_in), True)
        general[~known] = 0.0
        np.testing.assert_array_equal(zeroed.view(np.uint32), general.view(np.uint32))


@pytest.mark.parametrize("half", [1, 2])
def test_3x3_and_5x5_kernels_take_non_contiguous_views(half):
    z, known = _hard_depth((72, 96), 4)
    view, kview = z[::2, ::2], known[::2, ::2]
    got = denoise_depth(view, kview, INTR, half_window=half)
    np.testing.assert_array_equal(got, denoise_depth(view.copy(), kview.copy(), INTR, half_window=half))


@pytest.mark.parametrize("half", [1, 2])
def test_denoise_frame_equals_the_frame_the_constructor_builds(half):
    """denoise_frame builds its frame without RGBDFrame's copies; the same frame as the plain
    construction (values, dtypes, read-only arrays), and the input frame untouched."""
    rng = np.random.default_rng(5)
    z, known = _hard_depth((INTR.height, INTR.width), 5)
    rgb = rng.random((INTR.height, INTR.width, 3)).astype(np.float32)
    frame = RGBDFrame(rgb, np.where(known, z, 0.0), known, RigidTransform.identity("world", "cam"), INTR, 7)
    before = frame.depth_m.copy()
    got = denoise_frame(frame, half_window=half)
    depth = denoise_depth(frame.depth_m, frame.known, INTR, half_window=half)
    depth[~frame.known] = 0.0
    want = RGBDFrame(frame.rgb, depth, frame.known, frame.T_world_from_cam, INTR, frame.timestamp_ns)
    assert type(got) is RGBDFrame
    for name in ("rgb", "depth_m", "known"):  # bit for bit (NaN depths at known pixels included)
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
    assert (got.T_world_from_cam, got.intrinsics, got.timestamp_ns) == (want.T_world_from_cam, INTR, 7)
    assert got.depth_m.dtype == np.float32 and not got.depth_m.flags.writeable
    assert not got.rgb.flags.writeable and not got.known.flags.writeable
    np.testing.assert_array_equal(frame.depth_m, before)
    # a frame-like object is refused by name
    duck = SimpleNamespace(rgb=rgb, depth_m=frame.depth_m.copy(), known=known.copy(),
                           T_world_from_cam=frame.T_world_from_cam, intrinsics=INTR, timestamp_ns=7)
    with pytest.raises(InvalidInputError, match="RGBDFrame"):
        denoise_frame(duck, half_window=half)
