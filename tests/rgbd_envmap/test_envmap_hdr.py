"""HDR capture in the map update: clipped samples are lower bounds and never overwrite an unclipped
colour of the same surface (closed forms on one pixel, and the kernel against the per-sample
reference), and the frame-level helpers of rgbd_envmap.colour.hdr."""

import numpy as np
import pytest

from rgbd_envmap.colour import HDRConfig, clipped_pixels, exposure_scale, hdr_frame, low_confidence_pixels
from rgbd_envmap.envmap import EnvironmentMap, UpdateConfig, clip_flags, update
from rgbd_envmap.errors import DTypeError, RangeError, ShapeError
from rgbd_envmap.geometry import equirect_pixel_index
from rgbd_envmap.reference.envmap import update_reference
from rgbd_envmap.types import Intrinsics, RGBDFrame, RigidTransform

H, W = 60, 120
FOCAL = 200.0
POINT = UpdateConfig(splat=False)
WALL = np.array([[2.0, 0.3, 0.1]])  # one surface point, seen from inside the trusted sphere


def _put(em, colour, clipped, point=WALL, config=POINT):
    return update(em, point, np.array([colour], np.float32), np.zeros(3), FOCAL, config,
                  clipped=None if clipped is None else np.array([clipped]))


def _px(point=WALL):
    r, c, _ = equirect_pixel_index(point, H, W)
    return int(r[0]), int(c[0])


def test_clipped_sample_never_overwrites_an_unclipped_colour_of_the_same_surface():
    em = EnvironmentMap(H, W)
    _put(em, (9.0, 8.5, 7.5), False)  # the lamp seen unclipped at low exposure
    s = _put(em, (1.0, 1.0, 1.0), True)  # then clipped at the live exposure
    assert s.kept_clipped == 1 and s.taken == 0 and s.averaged == 0
    np.testing.assert_array_equal(em.radiance[_px()], np.float32([9.0, 8.5, 7.5]))
    assert clip_flags(em)[_px()] == 0


def test_unclipped_samples_still_average_and_clipped_ones_keep_the_larger_bound():
    em = EnvironmentMap(H, W)
    _put(em, (1.0, 1.0, 0.5), True)
    assert clip_flags(em)[_px()] == 1
    s = _put(em, (0.5, 2.0, 0.25), True)  # two lower bounds: the larger per channel, not their mean
    assert s.taken == 1 and s.averaged == 0 and s.kept_clipped == 0
    np.testing.assert_array_equal(em.radiance[_px()], np.float32([1.0, 2.0, 0.5]))
    _put(em, (6.0, 6.0, 6.0), False)  # an unclipped sample replaces a clipped colour outright
    np.testing.assert_array_equal(em.radiance[_px()], np.float32([6.0, 6.0, 6.0]))
    assert clip_flags(em)[_px()] == 0
    s = _put(em, (8.0, 8.0, 8.0), False)  # unclipped over unclipped: the running mean, (6 + 8) / 2
    assert s.averaged == 1
    np.testing.assert_array_equal(em.radiance[_px()], np.float32([7.0, 7.0, 7.0]))


def test_clipped_sample_takes_empty_pixels_and_other_surfaces():
    em = EnvironmentMap(H, W)
    s = _put(em, (1.0, 1.0, 1.0), True)
    assert s.taken_empty == 1 and clip_flags(em)[_px()] == 1
    em2 = EnvironmentMap(H, W)
    _put(em2, (0.2, 0.2, 0.2), False)
    s = _put(em2, (1.0, 0.9, 0.8), True, point=WALL * 0.5)  # a nearer surface, clipped: it takes over
    assert s.taken_closer == 1 and s.kept_clipped == 0
    np.testing.assert_array_equal(em2.radiance[_px()], np.float32([1.0, 0.9, 0.8]))
    assert clip_flags(em2)[_px()] == 1


def test_an_update_without_flags_on_an_hdr_map_has_no_clipped_sample():
    em = EnvironmentMap(H, W)
    _put(em, (1.0, 1.0, 1.0), True)
    s = _put(em, (3.0, 3.0, 3.0), None)
    assert s.taken == 1 and s.averaged == 0  # replaces the clipped colour
    assert clip_flags(em)[_px()] == 0
    em2 = EnvironmentMap(H, W)  # a map that never saw flags keeps no flag array
    _put(em2, (1.0, 1.0, 1.0), None)
    assert "clip_flags" not in em2.scratch


def test_flags_restart_with_the_colour_counts():
    em = EnvironmentMap(H, W)
    _put(em, (1.0, 1.0, 1.0), True)
    assert clip_flags(em.copy()).sum() == 0
    em.mark_modified()
    assert clip_flags(em).sum() == 0


def test_bad_clip_flags_are_refused():
    em = EnvironmentMap(H, W)
    with pytest.raises(ShapeError, match="clipped"):
        update(em, WALL, np.ones((1, 3), np.float32), np.zeros(3), FOCAL, POINT, clipped=np.zeros(2, bool))
    with pytest.raises(DTypeError, match="clipped"):
        update(em, WALL, np.ones((1, 3), np.float32), np.zeros(3), FOCAL, POINT, clipped=np.zeros(1))


@pytest.mark.parametrize("threads", [1, 2])
def test_update_kernel_with_clip_flags_equals_the_per_sample_reference(threads):
    # A room seen again and again from devices inside and outside the trusted sphere: samples of the
    # same surfaces with random clip flags and colours, so every HDR branch fires (refused, max of
    # bounds, replacement, averaging), bit for bit against the reference.
    rng = np.random.default_rng(20)
    h, w = 40, 80
    origin = np.array([0.05, -0.02, 0.1])
    em_k, em_r = EnvironmentMap(h, w, origin), EnvironmentMap(h, w, origin)
    cfg = UpdateConfig(max_splat_px=4, carve=False)
    averaged = np.zeros((h, w), int)
    views = np.full((h, w), np.inf, np.float32)
    flags_r = np.zeros((h, w), np.uint8)
    n = 1500
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wall = rng.uniform(1.5, 3.0, n)
    totals = {"kept_clipped": 0, "averaged": 0}
    for k, device in enumerate(([0.0, 0.0, 0.0], [0.3, 0.1, 0.0], [0.02, 0.0, 0.03], [0.5, -0.2, 0.1])):
        dist = wall * (1.0 + 0.002 * rng.normal(size=n))
        pts = origin + dirs * dist[:, None]
        cols = (rng.random((n, 3)) * 4).astype(np.float32)
        clipped = rng.random(n) < (0.5 if k % 2 else 0.2)
        dev = origin + np.array(device)
        stats = update(em_k, pts, cols, dev, 30.0, cfg, clipped=clipped, threads=threads)
        touched, counts = update_reference(em_r, pts, cols, dev, 30.0, cfg, None, averaged, views, clipped, flags_r)
        assert stats.touched == touched
        assert (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal, stats.averaged,
                stats.kept_view, stats.kept_clipped) == tuple(counts.values())
        for key in totals:
            totals[key] += counts[key]
        np.testing.assert_array_equal(em_k.valid, em_r.valid)
        np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)
        np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
        np.testing.assert_array_equal(clip_flags(em_k), flags_r)
    assert totals["kept_clipped"] > 50 and totals["averaged"] > 50
    assert 0 < flags_r.sum() < flags_r.size


# --- frame-level helpers ---------------------------------------------------------------------------


def _frame(rgb):
    h, w = rgb.shape[:2]
    intr = Intrinsics(w, h, 10.0, 10.0, (w - 1) / 2, (h - 1) / 2)
    return RGBDFrame(rgb, np.ones((h, w)), np.ones((h, w), bool), RigidTransform.identity("world", "depth"), intr, 0)


def test_clipped_pixels_flag_any_channel_above_the_level():
    rgb = np.array([[[0.2, 0.3, 0.4], [0.96, 0.1, 0.1], [0.95, 0.95, 0.95], [np.nan, 0.2, 1.0]]], np.float32)
    np.testing.assert_array_equal(clipped_pixels(rgb), [[False, True, False, True]])
    with pytest.raises(RangeError, match="clip_level"):
        clipped_pixels(rgb, 1.5)


def _edge_cases(dtype):
    """Random colours with every hard value a decoded frame can hold: both levels exactly, their
    neighbouring floats, 0, negatives, NaN and ±inf, in every channel."""
    rng = np.random.default_rng(7)
    rgb = rng.uniform(-0.1, 1.2, (37, 29, 3)).astype(dtype)
    specials = np.array([0.95, 0.01, np.nextafter(dtype(0.95), dtype(2)), np.nextafter(dtype(0.01), dtype(0)),
                         0.0, -1.0, np.nan, np.inf, -np.inf, 1.0], dtype)
    pick = rng.random(rgb.shape) < 0.3
    rgb[pick] = rng.choice(specials, int(pick.sum()))
    return rgb


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("dark", [None, 0.01, 0.0, 0.95])
def test_low_confidence_pixels_equal_the_reference(dtype, dark):
    from rgbd_envmap.reference.colour import low_confidence_reference

    rgb = _edge_cases(dtype)
    want = low_confidence_reference(rgb, 0.95, dark)
    got = low_confidence_pixels(rgb, 0.95, dark)
    assert got.dtype == bool and got.shape == rgb.shape[:2]
    np.testing.assert_array_equal(got, want)
    # the numpy forms the pipeline used before the kernel
    old = (rgb > dtype(0.95)).any(axis=-1)
    if dark is not None:
        old |= ~(rgb >= dtype(dark)).any(axis=-1)
    np.testing.assert_array_equal(got, old)
    # a strided view (a crop of a larger frame) gives the same flags
    np.testing.assert_array_equal(low_confidence_pixels(rgb[::2, 1::3], 0.95, dark), want[::2, 1::3])


def test_low_confidence_pixels_hard_cases():
    empty = np.zeros((0, 5, 3), np.float32)
    assert low_confidence_pixels(empty).shape == (0, 5)
    one = np.array([[[np.nan, np.nan, np.nan]]], np.float32)
    assert not low_confidence_pixels(one)[0, 0]  # NaN does not clip ...
    assert low_confidence_pixels(one, dark=0.01)[0, 0]  # ... nor reach the dark level
    assert low_confidence_pixels(np.full((1, 1, 3), 0.5), 1.0, 0.5).sum() == 0  # float64; the levels inclusive as stated
    with pytest.raises(RangeError, match="dark"):
        low_confidence_pixels(one, 0.5, 0.6)  # a dark level above the clip level
    with pytest.raises(ShapeError, match="rgb"):
        low_confidence_pixels(np.zeros((4, 4), np.float32))
    with pytest.raises(DTypeError, match="rgb"):
        low_confidence_pixels(np.zeros((2, 2, 3), np.uint8))


def test_exposure_scale_and_hdr_frame():
    assert exposure_scale(1.0, 1.0 / 16) == 16.0
    assert exposure_scale(None, 2.0) == 1.0 and exposure_scale(2.0, None) == 1.0
    with pytest.raises(RangeError, match="exposure"):
        exposure_scale(1.0, 0.0)
    rgb = np.full((2, 3, 3), 0.5, np.float32)
    rgb[0, 0] = 1.0
    f = hdr_frame(_frame(rgb), 4.0, clipped_pixels(rgb))
    np.testing.assert_array_equal(f.rgb[1, 1], np.float32([2.0, 2.0, 2.0]))
    assert f.clipped[0, 0] and f.clipped.sum() == 1
    assert f.rgb.flags.writeable is False and f.clipped.flags.writeable is False
    with pytest.raises(ShapeError, match="clipped"):
        hdr_frame(_frame(rgb), 1.0, np.zeros((3, 2), bool))


def test_hdr_config_checks():
    assert HDRConfig().enabled and HDRConfig().clip_level == 0.95
    with pytest.raises(RangeError, match="clip_level"):
        HDRConfig(clip_level=0.0)
    with pytest.raises(DTypeError, match="enabled"):
        HDRConfig(enabled="yes")
