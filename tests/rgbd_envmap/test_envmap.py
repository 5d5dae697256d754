"""Environment map state, update rules, pairs and translation, against closed forms, an independent
pixel mapping (geometry.equirect_pixel_index) and ray-cast ground truth at displaced origins."""

import numpy as np
import pytest

from rgbd_envmap._kernels.envmap_update import EMPTY_Z
from rgbd_envmap.envmap import map_update as update_module
from rgbd_envmap.envmap import (
    ChangeLog,
    EnvironmentMap,
    SeenDepth,
    UpdateConfig,
    collect_pairs,
    is_backface,
    rule_closer,
    rule_empty,
    rule_removal,
    rule_trusted,
    translate,
    update,
)
from rgbd_envmap.reference.envmap import gardner_reference, pairs_reference, translate_reference, update_reference
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, ShapeError, UnknownMethodError
from rgbd_envmap.geometry import equirect_directions, equirect_pixel_index, look_at
from rgbd_envmap.types import Intrinsics
from sim.groundtruth import render_envmap
from sim.raycast import SceneRaycaster
from sim.scene import scene_from_dict
from tests.sim.helpers import box_room

H, W = 100, 200
POINT = UpdateConfig(splat=False)
FOCAL = 200.0


def _one(em, point, colour=(0.5, 0.25, 0.125), device=(0.0, 0.0, 0.0), config=POINT):
    return update(em, np.array([point], float), np.array([colour], np.float32), np.array(device, float), FOCAL, config)


def _pixel(point, origin=(0.0, 0.0, 0.0)):
    r, c, _ = equirect_pixel_index(np.asarray(point, float) - origin, H, W)
    return int(r), int(c)


def test_new_map_is_empty_and_planar():
    em = EnvironmentMap(H, W, (1.0, 2.0, 3.0))
    assert not em.valid.any() and em.radiance.shape == (H, W, 3) and em.radiance_planes.flags.c_contiguous
    em.radiance_planes[1, 5, 7] = 0.75
    assert em.radiance[5, 7, 1] == 0.75  # radiance is a view of the planar storage


def test_from_arrays_round_trip_and_copy_independence():
    rng = np.random.default_rng(0)
    rad, depth, valid = rng.random((H, W, 3), np.float32), rng.random((H, W), np.float32), rng.random((H, W)) > 0.5
    em = EnvironmentMap.from_arrays(rad, depth, valid, np.zeros(3))
    np.testing.assert_array_equal(em.radiance, rad)
    np.testing.assert_array_equal(em.depth_m, depth)
    np.testing.assert_array_equal(em.valid, valid)
    cp = em.copy()
    cp.depth_m[:] = 0
    assert em.depth_m.any()
    with pytest.raises(ShapeError):
        EnvironmentMap.from_arrays(rad, depth[:-1], valid, np.zeros(3))
    with pytest.raises(InvalidInputError):
        EnvironmentMap(H, W, (np.nan, 0, 0))


def test_rule_functions():
    assert rule_empty(False) and not rule_empty(True)
    assert rule_closer(1.0, 2.0) and not rule_closer(2.0, 1.0) and not rule_closer(1.0, 1.0)
    assert rule_trusted(0.05, 0.1) and not rule_trusted(0.1, 0.1)
    assert is_backface(3.0, 2.0, 4.0) and is_backface(3.0, 4.0, 2.0) and not is_backface(1.0, 2.0, 2.5)
    assert rule_removal(1.0, 0.01, 2.0, 2.5, 0.03)
    assert not rule_removal(1.0, 0.05, 2.0, 2.5, 0.03)  # too far from the ray
    assert not rule_removal(3.0, 0.01, 2.0, 2.5, 0.03)  # backface


def test_empty_pixel_takes_the_sample_in_the_right_place():
    em = EnvironmentMap(H, W)
    stats = _one(em, (1.0, 2.0, 0.5))
    r, c = _pixel((1.0, 2.0, 0.5))
    assert em.valid.sum() == 1 and em.valid[r, c] and stats.taken_empty == 1
    assert em.depth_m[r, c] == pytest.approx(np.linalg.norm([1.0, 2.0, 0.5]))
    np.testing.assert_allclose(em.radiance[r, c], [0.5, 0.25, 0.125])


def test_update_pixels_agree_with_the_geometry_mapping():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(5000, 3))
    em = EnvironmentMap(H, W)
    update(em, pts, np.ones((5000, 3), np.float32), np.zeros(3), FOCAL, POINT)
    rows, cols, _ = equirect_pixel_index(pts, H, W)
    expected = np.zeros((H, W), bool)
    expected[rows, cols] = True
    np.testing.assert_array_equal(em.valid, expected)


def test_closer_sample_moves_depth_to_the_mean_and_farther_is_ignored():
    em = EnvironmentMap(H, W)
    _one(em, (2.0, 0.0, 0.0), colour=(1, 0, 0), device=(0.5, 0.5, 0.5))
    r, c = _pixel((2.0, 0.0, 0.0))
    stats = _one(em, (3.0, 0.0, 0.0), colour=(0, 1, 0), device=(0.5, 0.5, 0.5))
    assert stats.taken == 0 and em.depth_m[r, c] == pytest.approx(2.0)
    stats = _one(em, (1.0, 0.0, 0.0), colour=(0, 0, 1), device=(0.5, 0.5, 0.5))
    assert stats.taken_closer == 1 and em.depth_m[r, c] == pytest.approx(1.5)
    np.testing.assert_allclose(em.radiance[r, c], [0, 0, 1])


def test_same_surface_samples_average_their_colours():
    """UpdateConfig.colour_average (here 4; default 8): samples of the stored surface (within the
    carving tolerance, 3 % + 2 cm) that take the pixel average its colour, a running mean over up to
    4, then each new one weighs 1/4; a farther one is still refused; a nearer surface beyond the
    tolerance replaces the colour and restarts the mean. colour_average=1 is the paper (replace)."""
    cfg = UpdateConfig(splat=False, colour_average=4)
    assert UpdateConfig().colour_average == 8
    em, paper = EnvironmentMap(H, W), EnvironmentMap(H, W)
    r, c = _pixel((2.0, 0.0, 0.0))
    dev = (0.5, 0.5, 0.5)
    colours = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 0.0), (0.0, 1.0, 1.0)]
    expected = np.zeros(3)
    for k, (dist, col) in enumerate(zip((2.0, 1.99, 1.98, 1.97, 1.96), colours)):  # each 1 cm nearer: "closer"
        st = _one(em, (dist, 0.0, 0.0), colour=col, device=dev, config=cfg)
        _one(paper, (dist, 0.0, 0.0), colour=col, device=dev, config=UpdateConfig(splat=False, colour_average=1))
        expected = np.asarray(col, float) if k == 0 else expected + (np.asarray(col) - expected) / min(k + 1, 4)
        np.testing.assert_allclose(em.radiance[r, c], expected, atol=1e-6)
        np.testing.assert_array_equal(paper.radiance[r, c], np.asarray(col, np.float32))
        assert st.averaged == (k > 0)
    np.testing.assert_array_equal(em.depth_m, paper.depth_m)  # depth follows the paper's rule either way
    before = em.radiance[r, c].copy()
    assert _one(em, (2.1, 0.0, 0.0), colour=(0.3, 0.3, 0.3), device=dev, config=cfg).taken == 0  # farther: refused
    np.testing.assert_array_equal(em.radiance[r, c], before)
    # A new surface 40 cm nearer: beyond the tolerance, the colour is replaced and the mean restarts.
    st = _one(em, (1.5, 0.0, 0.0), colour=(0.2, 0.4, 0.6), device=dev, config=cfg)
    assert st.taken_closer == 1 and st.averaged == 0
    np.testing.assert_allclose(em.radiance[r, c], [0.2, 0.4, 0.6])
    # (The paper's rule left the depth halfway, 1.73 m.) A sample at that depth now averages with the
    # new colour only.
    _one(em, (float(em.depth_m[r, c]) - 0.005, 0.0, 0.0), colour=(0.4, 0.6, 0.8), device=dev, config=cfg)
    np.testing.assert_allclose(em.radiance[r, c], [0.3, 0.5, 0.7], atol=1e-6)


def test_mark_modified_restarts_the_colour_averages():
    """After the arrays are written from outside (``mark_modified``, as ``translate(out=...)`` does),
    the next same-surface sample averages with the written colour as with one sample."""
    cfg = UpdateConfig(splat=False, colour_average=4)
    em = EnvironmentMap(H, W)
    r, c = _pixel((2.0, 0.0, 0.0))
    for dist in (2.0, 1.99, 1.98):  # three samples averaged: the next one would weigh 1/4
        _one(em, (dist, 0.0, 0.0), colour=(0.0, 0.0, 0.0), device=(0.5, 0.5, 0.5), config=cfg)
    em.radiance_planes[:, r, c] = 0.5
    em.mark_modified()
    _one(em, (float(em.depth_m[r, c]) - 0.005, 0.0, 0.0), colour=(1.0, 1.0, 1.0), device=(0.5, 0.5, 0.5), config=cfg)
    np.testing.assert_allclose(em.radiance[r, c], 0.75)  # (0.5 + 1) / 2, not 0.5 + 0.5 / 4


def test_colour_average_two_is_an_even_blend_of_the_last_two_and_freed_pixels_replace():
    cfg = UpdateConfig(splat=False, colour_average=2)
    em = EnvironmentMap(H, W)
    r, c = _pixel((2.0, 0.0, 0.0))
    for k, dist in enumerate((2.0, 1.99, 1.98, 1.97)):
        _one(em, (dist, 0.0, 0.0), colour=(float(k), 0.0, 0.0), device=(0.5, 0.5, 0.5), config=cfg)
    # 0 → 0.5 → (0.5 + 2) / 2 → (1.25 + 3) / 2
    assert em.radiance[r, c, 0] == pytest.approx(2.125)


@pytest.mark.parametrize("bad", [0, -1, 256, 2.5])
def test_colour_average_must_be_from_1_to_255(bad):
    with pytest.raises((RangeError, DTypeError)):
        UpdateConfig(colour_average=bad)


def test_within_a_frame_the_closest_sample_wins():
    em = EnvironmentMap(H, W)
    pts = np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    cols = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    update(em, pts, cols, np.zeros(3), FOCAL, POINT)
    r, c = _pixel((1.0, 0, 0))
    assert em.valid.sum() == 1 and em.depth_m[r, c] == pytest.approx(1.0)
    np.testing.assert_allclose(em.radiance[r, c], [0, 1, 0])


def test_trusted_sphere_overrides():
    em = EnvironmentMap(H, W)
    _one(em, (2.0, 0, 0), device=(1.0, 1.0, 0.0))
    stats = _one(em, (4.0, 0, 0), colour=(0, 1, 0), device=(0.05, 0.0, 0.05))  # 7 cm from the origin
    r, c = _pixel((2.0, 0, 0))
    assert stats.taken_trusted == 1 and em.depth_m[r, c] == pytest.approx(3.0)


def test_removal_when_the_device_is_on_the_ray_and_not_a_backface():
    # A surface at 1 m along +x was removed; the wall behind it is at 3 m.
    em = EnvironmentMap(H, W)
    _one(em, (1.0, 0, 0), colour=(1, 0, 0), device=(0.5, 0.5, 0.0))
    r, c = _pixel((1.0, 0, 0))
    d = equirect_directions(H, W)[r, c].astype(float)
    # Device 1 cm off the pixel's ray, 0.5 m out: between the origin and the stored surface.
    side = np.cross(d, [0, 0, 1.0])
    side /= np.linalg.norm(side)
    on_ray = 0.5 * d + 0.01 * side
    stats = _one(em, 3.0 * d, colour=(0, 1, 0), device=on_ray)
    assert stats.taken_removal == 1 and em.depth_m[r, c] == pytest.approx(2.0)
    np.testing.assert_allclose(em.radiance[r, c], [0, 1, 0])
    # 5 cm off the ray: no removal.
    em2 = EnvironmentMap(H, W)
    _one(em2, (1.0, 0, 0), device=(0.5, 0.5, 0.0))
    assert _one(em2, 3.0 * d, device=0.5 * d + 0.05 * side).taken == 0
    # Device beyond the stored surface (1.5 m along the ray): a backface, no removal.
    em3 = EnvironmentMap(H, W)
    _one(em3, (1.0, 0, 0), device=(0.5, 0.5, 0.0))
    assert _one(em3, 3.0 * d, device=1.5 * d + 0.01 * side).taken == 0


def test_non_finite_samples_are_skipped():
    em = EnvironmentMap(H, W)
    pts = np.array([[np.nan, 0, 0], [1.0, np.inf, 0], [0.0, 0.0, 0.0], [1.0, 0, 0]])
    cols = np.array([[1, 1, 1], [1, 1, 1], [1, 1, 1], [np.nan, 0, 0]], np.float32)
    stats = update(em, pts, cols, np.zeros(3), FOCAL, POINT)
    assert stats.taken == 0 and not em.valid.any() and np.isfinite(em.radiance).all()


def test_a_sample_at_the_origin_is_skipped_and_a_bad_focal_length_rejected():
    from rgbd_envmap.errors import RangeError

    em = EnvironmentMap(H, W)
    stats = update(em, np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.ones((2, 3), np.float32), np.zeros(3), FOCAL,
                   UpdateConfig(splat=True))
    assert stats.taken == stats.touched > 0 and em.valid[_pixel((1.0, 0.0, 0.0))]
    for focal in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(RangeError, match="focal_px"):
            update(em, np.ones((1, 3)), np.ones((1, 3), np.float32), np.zeros(3), focal)


def test_poles_and_seam_samples_land_in_range():
    em = EnvironmentMap(H, W)
    pts = np.array([[0, 0, 1.0], [0, 0, -1.0], [-1.0, 1e-15, 0], [-1.0, -1e-15, 0]])
    update(em, pts, np.ones((4, 3), np.float32), np.zeros(3), FOCAL, UpdateConfig(splat=True))
    assert em.valid[0].any() and em.valid[-1].any() and em.valid[:, 0].any() and em.valid[:, -1].any()


@pytest.mark.parametrize("scale", [1.0, 1.25])
def test_splatting_closes_the_sieve_on_a_far_wall(scale):
    # A ToF-like 224×172 grid of samples on the wall x = 2.5 m, seen from 0.4 m behind the origin.
    em_point, em_splat = EnvironmentMap(1000, 2000), EnvironmentMap(1000, 2000)
    u, v = np.meshgrid(np.linspace(-1.6, 1.6, 224), np.linspace(-1.2, 1.2, 172))
    device = np.array([-0.4, 0.0, 0.0])
    pts = np.stack([np.full(u.size, 2.5), u.ravel(), v.ravel()], -1)
    cols = np.ones((len(pts), 3), np.float32)
    update(em_point, pts, cols, device, FOCAL, POINT)
    update(em_splat, pts, cols, device, FOCAL, UpdateConfig(splat=True, splat_scale=scale))
    # EM pixels whose ray from the origin meets the sampled rectangle, 2 cm inside its border.
    d = equirect_directions(1000, 2000).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = 2.5 / d[..., 0]
        y, z = t * d[..., 1], t * d[..., 2]
    inside = (d[..., 0] > 0) & (np.abs(y) < 1.58) & (np.abs(z) < 1.18)
    assert em_point.valid[inside].mean() < 0.9  # one pixel per sample leaves a sieve
    assert em_splat.valid[inside].all()
    # Splats stay on the wall: nothing beyond 4 cm outside the rectangle.
    outside = (d[..., 0] <= 0) | (np.abs(y) > 1.64) | (np.abs(z) > 1.24)
    assert not em_splat.valid[outside].any()


def test_pairs_need_data_within_one_centimetre():
    em = EnvironmentMap(H, W)
    _one(em, (2.0, 0, 0), colour=(0.2, 0.4, 0.6))
    pts = np.array([[2.005, 0, 0], [2.02, 0, 0], [0, 2.0, 0]])
    src, dst = collect_pairs(em, pts, np.array([[1, 1, 1], [2, 2, 2], [3, 3, 3]], np.float32))
    np.testing.assert_allclose(src, [[1, 1, 1]])
    np.testing.assert_allclose(dst, [[0.2, 0.4, 0.6]])
    src, dst = collect_pairs(EnvironmentMap(H, W), pts, np.ones((3, 3), np.float32))
    assert src.shape == (0, 3) and dst.shape == (0, 3)


@pytest.fixture(scope="module")
def room():
    return SceneRaycaster(scene_from_dict(box_room(radiance=(0.5, 0.4, 0.3), extra=[
        {"name": "post", "shape": "box", "centre": [0.8, 0.3, 0.0], "size": [0.2, 0.2, 3.9], "radiance": [0.9, 0.1, 0.1]},
        {"name": "poster", "shape": "quad", "corner": [-1.99, -1.0, -1.0], "u": [0, 2.0, 0], "v": [0, 0, 2.0],
         "radiance": {"texture": "checker", "colours": [[0.9, 0.9, 0.9], [0.1, 0.2, 0.3]], "cells": [4, 4]}},
    ])))


def _gt_map(room, origin, h=250, w=500):
    gt = render_envmap(room, origin, h, w, 0.0)
    return EnvironmentMap.from_arrays(gt.radiance, gt.distance_m, gt.valid, origin)


def test_zero_translation_is_the_identity(room):
    em = _gt_map(room, np.zeros(3))
    out = translate(em, np.zeros(3))
    np.testing.assert_array_equal(out.valid, em.valid)
    np.testing.assert_allclose(out.depth_m, em.depth_m, rtol=1e-5)
    np.testing.assert_array_equal(out.radiance, em.radiance)


def test_depth_translation_matches_ground_truth_at_the_new_origin(room):
    origin, offset = np.array([-0.3, 0.0, 0.0]), np.array([0.25, -0.15, 0.1])
    moved = translate(_gt_map(room, origin), offset)
    truth = _gt_map(room, origin + offset)
    both = moved.valid & truth.valid
    assert both.mean() > 0.95
    rel = np.abs(moved.depth_m[both] - truth.depth_m[both]) / truth.depth_m[both]
    assert np.median(rel) < 0.01
    assert np.mean(np.all(np.abs(moved.radiance[both] - truth.radiance[both]) < 1e-6, axis=-1)) > 0.95
    # The baseline assumes a sphere and gets the parallax of the near post wrong.
    gardner = translate(_gt_map(room, origin), offset, method="gardner", radius_m=2.0)
    ok_depth = np.mean(np.all(np.abs(moved.radiance[both] - truth.radiance[both]) < 1e-6, axis=-1))
    ok_gardner = np.mean(np.all(np.abs(gardner.radiance[both] - truth.radiance[both]) < 1e-6, axis=-1))
    assert ok_depth > ok_gardner


def test_gardner_is_exact_for_a_spherical_world():
    h, w = 64, 128
    dirs = equirect_directions(h, w)
    radiance = np.repeat(((dirs + 1) / 2)[..., :1], 3, axis=-1).astype(np.float32)  # varies with x
    em = EnvironmentMap.from_arrays(radiance, np.full((h, w), 2.0, np.float32), np.ones((h, w), bool), np.zeros(3))
    g = translate(em, np.array([0.3, 0.0, 0.0]), method="gardner", radius_m=2.0)
    d = translate(em, np.array([0.3, 0.0, 0.0]), method="depth")
    both = g.valid & d.valid
    assert both.mean() > 0.95
    np.testing.assert_allclose(g.depth_m[both], d.depth_m[both], rtol=2e-2)
    assert np.median(np.abs(g.radiance[both] - d.radiance[both])) < 0.02


@pytest.mark.parametrize("offset", [(0.3, -0.2, 0.1), (0.0, 0.0, -1.2), (1e-9, 0.0, 0.0)])
def test_gardner_kernel_equals_the_numpy_warp(offset):
    # The kernel's polynomial atan2 (error 1.2e-8 rad) may move a ray that lands within that of a
    # pixel edge to the next pixel; elsewhere it equals the reference's whole-map numpy warp.
    rng = np.random.default_rng(10)
    h, w = 90, 180
    em = _random_map(rng, h, w, 0.8)
    off, radius = np.array(offset), 1.5
    got = translate(em, off, "gardner", radius_m=radius)
    ref = gardner_reference(em, off, radius)
    same = (got.valid == ref.valid) & (~ref.valid | (got.radiance == ref.radiance).all(-1))
    assert same.mean() > 0.999, same.mean()
    ok = same & got.valid
    np.testing.assert_allclose(got.depth_m[ok], ref.depth_m[ok], rtol=1e-6)
    assert not got.depth_m[~got.valid].any() and not got.radiance[~got.valid].any()


def test_translate_errors():
    em = EnvironmentMap(H, W)
    with pytest.raises(UnknownMethodError):
        translate(em, np.zeros(3), method="warp")
    with pytest.raises(InvalidInputError):
        translate(em, np.array([3.0, 0, 0]), method="gardner", radius_m=2.0)
    with pytest.raises(InvalidInputError):
        translate(em, np.array([np.nan, 0, 0]))


def test_branchless_atan2_matches_libm_in_every_quadrant():
    import math

    from rgbd_envmap._kernels.envmap_common import ATAN_POLY, atan2_branchless

    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.normal(size=(20000, 2)), [[0, 1], [0, -1], [1, 0], [-1, 0], [-1, 1e-300], [1e-300, 1e-300]]])
    err = max(abs(atan2_branchless(y, x) - math.atan2(y, x)) for y, x in pts if not (x < 0 and y == 0))
    assert err < 2e-8
    # The written-out polynomial is the tuple's: atan(1) from the tuple equals the function's.
    assert abs(sum(ATAN_POLY) - atan2_branchless(1.0, 1.0)) < 1e-15


def test_frame_points_match_unprojection_and_the_pose():
    from rgbd_envmap.envmap import frame_points
    from rgbd_envmap.geometry import look_at, unproject_pixels
    from rgbd_envmap.types import Distortion, Intrinsics

    intr = Intrinsics(32, 24, 30.0, 31.0, 15.5, 11.5, Distortion.radial(-0.05, 0.01, 0.0))
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 3.0, intr.shape).astype(np.float32)
    mask = rng.random(intr.shape) > 0.3
    T = look_at([0.3, -0.2, 1.1], [2.0, 1.0, 0.5])
    rows, cols = np.nonzero(mask)
    cam = unproject_pixels(np.stack([cols, rows], -1).astype(float), depth[mask].astype(float), intr)
    np.testing.assert_allclose(frame_points(depth, mask, intr, T), T.apply(cam), atol=1e-9)


def test_fill_only_samples_do_not_win_by_the_closer_rule():
    em = EnvironmentMap(H, W)
    _one(em, (3.0, 0, 0), colour=(1, 0, 0), device=(0.5, 0.5, 0.0))
    r, c = _pixel((3.0, 0, 0))
    pts = np.array([[1.0, 0, 0], [0, 2.0, 0]])  # closer on the stored pixel; a new, empty pixel
    stats = update(em, pts, np.array([[0, 1, 0], [0, 0, 1]], np.float32), np.array([0.5, 0.5, 0.0]), FOCAL, POINT,
                   fill_only=np.array([True, True]))
    assert stats.taken == 1 and stats.taken_empty == 1
    np.testing.assert_allclose(em.radiance[r, c], [1, 0, 0])
    assert em.valid[_pixel((0, 2.0, 0))]


def test_fill_only_samples_still_obey_the_trusted_sphere():
    em = EnvironmentMap(H, W)
    _one(em, (3.0, 0, 0), colour=(1, 0, 0), device=(0.5, 0.5, 0.0))
    stats = update(em, np.array([[1.0, 0, 0]]), np.array([[0, 1, 0]], np.float32), np.array([0.05, 0.0, 0.0]),
                   FOCAL, POINT, fill_only=np.array([True]))
    assert stats.taken_trusted == 1


# --- the kernels against plain per-sample / per-pixel references ---------------------------------
# The kernels are restructured for speed (blocked coordinates, a band z-buffer of keys merged with
# min in any order, row-streamed translation with an integer-key z-buffer). These
# references follow the documented rules one sample and one pixel at a time, in plain Python, and
# share only the per-point coordinates with the library (its compiled coordinate function), so the
# comparisons are exact.


@pytest.mark.parametrize("splat", [True, False])
def test_update_kernel_equals_the_per_sample_reference(splat):
    # Samples near the origin (large footprints, some across the seam and near the poles), far
    # ones (one pixel), non-finite ones, fill-only ones, over three frames so every rule fires.
    rng = np.random.default_rng(7)
    h, w = 40, 80
    em_k, em_r = EnvironmentMap(h, w, (0.1, -0.2, 0.3)), EnvironmentMap(h, w, (0.1, -0.2, 0.3))
    cfg = UpdateConfig(splat=splat, max_splat_px=6)
    averaged = np.zeros((h, w), int)
    views = np.full((h, w), np.inf, np.float32)
    fired = np.zeros(6, int)
    for frame, device in enumerate(([1.0, 0.5, 0.2], [0.4, -0.1, 0.5], [0.12, -0.18, 0.31])):
        n = 400
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        dist = np.where(rng.random(n) < 0.2, rng.uniform(0.02, 0.2, n), rng.uniform(0.5, 4.0, n))
        pts = em_k.origin + dirs * dist[:, None]
        pts[rng.random(n) < 0.02] = np.nan
        cols = rng.random((n, 3)).astype(np.float32)
        cols[rng.random(n) < 0.02, 1] = np.inf
        fill_only = rng.random(n) < 0.3
        stats = update(em_k, pts, cols, np.array(device), FOCAL, cfg, fill_only=fill_only)
        touched, counts = update_reference(em_r, pts, cols, np.array(device), FOCAL, cfg, fill_only, averaged, views)
        assert stats.touched == touched
        assert (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal,
                stats.averaged, stats.kept_view, stats.kept_clipped) == tuple(counts.values())
        fired += (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal, stats.averaged,
                  stats.touched - stats.taken)
        np.testing.assert_array_equal(em_k.valid, em_r.valid)
        np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)
        np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
    # Every rule fired, and some pixels were refused (the last device is inside the trusted sphere).
    assert (fired > 0).all()
    # The scratch is clean again: the band z-buffer was cleared where touched, the tile flags reset.
    zband, tiles = update_module._update_scratch(em_k)[:2]
    assert (zband == EMPTY_Z).all() and not tiles.any()


@pytest.mark.parametrize("splat", [True, False])
def test_update_equal_float32_distances_keep_what_a_sequential_z_test_keeps(splat):
    # The kernel merges z-buffer keys with min in any order; a sequential test replaces the stored
    # sample when the new float64 distance is below the stored float32 one. On equal float32
    # distances that keeps the last sample rounded up (r < float32(r)) or else the first: every
    # order of such samples must give the reference's winner (its colour) and counts.
    import itertools

    d = np.array([0.8, 0.3, -0.52])
    d /= np.linalg.norm(d)
    g = 2.0  # a float32; ulp 2.4e-7
    # Within half an ulp of 2 (5.96e-8 below, 1.19e-7 above): all round to 2; the last is one float32 up.
    dist = [g - 5e-8, g + 9e-8, g, g - 2e-8, g + 4e-8, g + 5e-7]
    cfg = UpdateConfig(splat=splat, max_splat_px=4)
    for order in itertools.islice(itertools.permutations(range(len(dist))), 0, None, 37):
        pts = np.array([d * dist[i] for i in order])
        cols = np.array([[i / 8, 1 - i / 8, 0.5] for i in order], np.float32)
        fill_only = np.array([i % 2 == 1 for i in order])
        for pre in (None, 2.5):  # an empty map (rule "empty"), and one holding a farther surface
            em_k, em_r = EnvironmentMap(H, W), EnvironmentMap(H, W)
            if pre is not None:
                for em in (em_k, em_r):
                    em.valid[:] = True
                    em.depth_m[:] = pre
            stats = update(em_k, pts, cols, np.array([0.0, 0.0, 1.0]), FOCAL, cfg, fill_only)
            touched, counts = update_reference(em_r, pts, cols, np.array([0.0, 0.0, 1.0]), FOCAL, cfg, fill_only)
            assert stats.touched == touched
            assert (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal, stats.averaged, stats.kept_view, stats.kept_clipped) == tuple(counts.values())
            np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
            np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)


@pytest.mark.parametrize("h, w", [(3, 5), (20, 33), (24, 66), (30, 97), (16, 35)])
def test_update_kernel_equals_the_reference_on_odd_widths_across_the_seam_and_poles(h, w):
    # The merge takes footprints of up to 4 and up to 8 columns with fixed per-row tests at wrapped
    # columns and flags the tiles of a run's first and last column and of the map's last one; widths
    # whose last 32-column tile is partial (33, 66, 97: 1–2 columns; 35: 3) or tiny maps break that
    # first. Samples 0.05–0.6 m from the origin (a focal length scaled to the map: footprints of 1
    # to many columns, rows clipped at the poles), around the seam (azimuth ±π) and the poles, from
    # devices near and far; frames of 300 samples, then of one sample each (no other footprint
    # flags the tiles a footprint misses).
    rng = np.random.default_rng(h * 1000 + w)
    origin = (0.05, 0.02, -0.1)
    em_k, em_r = EnvironmentMap(h, w, origin), EnvironmentMap(h, w, origin)
    cfg = UpdateConfig(max_splat_px=6)
    averaged = np.zeros((h, w), int)
    views = np.full((h, w), np.inf, np.float32)
    focal = w / 4.0
    frames = [(d, 300) for d in ([0.9, -0.3, 0.2], [0.3, 0.1, -0.4], [0.06, 0.03, -0.08])]
    frames += [([0.9, -0.3, 0.2], 1)] * 150
    for device, n in frames:
        az = np.where(rng.random(n) < 0.6, np.pi + rng.normal(0, 0.15, n), rng.uniform(-np.pi, np.pi, n))
        pol = np.where(rng.random(n) < 0.3, rng.choice([0.02, np.pi - 0.02], n), rng.uniform(0, np.pi, n))
        dirs = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], -1)
        pts = em_k.origin + dirs * rng.uniform(0.05, 0.6, n)[:, None]
        pts[rng.random(n) < 0.03] = np.nan
        cols = rng.random((n, 3)).astype(np.float32)
        fill_only = rng.random(n) < 0.2
        stats = update(em_k, pts, cols, np.array(device), focal, cfg, fill_only=fill_only)
        touched, counts = update_reference(em_r, pts, cols, np.array(device), focal, cfg, fill_only, averaged, views)
        assert stats.touched == touched
        assert (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal, stats.averaged, stats.kept_view, stats.kept_clipped) == tuple(counts.values())
        np.testing.assert_array_equal(em_k.valid, em_r.valid)
        np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)
        np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
    zband, tiles = update_module._update_scratch(em_k)[:2]
    assert (zband == EMPTY_Z).all() and not tiles.any()


@pytest.mark.parametrize("capacity", [None, 300])
def test_two_thread_update_equals_one_thread(capacity):
    # The update kernel lists each half of the samples at once and splits the map's bands in two
    # parts updated at once, each with its own z-buffer band and change log: on two threads and on
    # one (the parts in turn) the maps, the counts and the change log (raster order; with a log too
    # short for the frame, the same first entries and the same overflow) must be the same after
    # every frame, with carving on.
    import dataclasses

    rng = np.random.default_rng(5)
    h, w = 64, 128
    origin = (0.1, 0.0, -0.05)
    maps = {t: EnvironmentMap(h, w, origin) for t in (1, 2)}
    for em in maps.values():
        em.record_changes()
        if capacity is not None:
            em.change_log = ChangeLog(capacity)
    intr = Intrinsics(32, 24, 24.0, 24.0, 15.5, 11.5)
    overflowed = 0
    frames = [([1.0, 0.5, 0.2], 900), ([0.4, -0.1, 0.5], 900), ([0.12, -0.04, -0.03], 900), ([0.5, 0.0, 0.0], 0),
              ([-0.6, 0.3, -0.2], 1)]
    for device, n in frames:
        dirs = rng.normal(size=(n, 3))
        dirs[: n // 3, 2] -= 2.0  # a third towards the floor: bands below the equator with large footprints
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        dist = np.where(rng.random(n) < 0.2, rng.uniform(0.03, 0.3, n), rng.uniform(0.5, 4.0, n))
        pts = np.asarray(origin) + dirs * dist[:, None]
        pts[rng.random(n) < 0.02] = np.nan
        cols = rng.random((n, 3)).astype(np.float32)
        fill_only = rng.random(n) < 0.3
        T = look_at(device, [0.0, 0.0, 0.0])
        seen = SeenDepth(rng.uniform(0.5, 5.0, (24, 32)).astype(np.float32), rng.random((24, 32)) < 0.9, intr, T)
        stats, changes = {}, {}
        cap = maps[2].change_log.capacity  # grown by take_changes after an overflow
        for t, em in maps.items():
            cfg = UpdateConfig(max_splat_px=8)
            stats[t] = update(em, pts, cols, np.array(device), 40.0, cfg, fill_only, seen, threads=t)
            changes[t] = em.take_changes()
        assert dataclasses.astuple(stats[1]) == dataclasses.astuple(stats[2])
        a, b = maps[1], maps[2]
        np.testing.assert_array_equal(a.valid, b.valid)
        np.testing.assert_array_equal(a.depth_m.view(np.uint32), b.depth_m.view(np.uint32))
        np.testing.assert_array_equal(a.radiance_planes.view(np.uint32), b.radiance_planes.view(np.uint32))
        ca, cb = changes[1], changes[2]
        assert (ca.complete, ca.updates) == (cb.complete, cb.updates)
        np.testing.assert_array_equal(ca.index, cb.index)
        np.testing.assert_array_equal(ca.was_valid, cb.was_valid)
        np.testing.assert_array_equal(ca.old_radiance.view(np.uint32), cb.old_radiance.view(np.uint32))
        assert cb.complete == (stats[1].taken <= cap)
        overflowed += not cb.complete
        if not cb.complete:
            assert len(cb.index) == cap
    assert overflowed == (capacity is not None)
    assert maps[2].valid.mean() > 0.3 and stats[2].samples == 1
    for zband, tiles in (update_module._update_scratch(maps[2])[:2], maps[2].scratch["update_2t"][:2]):
        assert (zband == EMPTY_Z).all() and not tiles.any()


def test_update_threads_must_be_positive():
    with pytest.raises(RangeError, match="threads"):
        update(EnvironmentMap(H, W), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(3), FOCAL, threads=0)


def test_update_without_usable_samples_changes_nothing():
    for pts in (np.empty((0, 3)), np.full((5, 3), np.nan), np.zeros((3, 3))):  # none, NaN, at the origin
        em = EnvironmentMap(H, W)
        em.record_changes()
        stats = update(em, pts, np.ones((len(pts), 3), np.float32), np.array([0.5, 0.0, 0.0]), FOCAL)
        assert (stats.samples, stats.touched, stats.taken) == (len(pts), 0, 0)
        assert not em.valid.any()
        changes = em.take_changes()
        assert len(changes.index) == 0 and changes.complete and changes.updates == 1


def test_removal_rule_near_the_edge_of_its_cone():
    # The kernel evaluates the removal rule only in rows within asin(removal_r / |device|) (plus two
    # rows) of the device's direction. Samples on rays at angles around that bound, behind stored
    # surfaces (so only removal can take them), from devices in several directions.
    rng = np.random.default_rng(11)
    h, w = 120, 240
    cfg = UpdateConfig(splat=False, removal_radius_m=0.05)
    fired = 0
    for device in ([0.3, 0.1, 0.25], [0.0, 0.05, -0.4], [-0.2, -0.3, 0.02], [0.0, 0.0, 0.35]):
        device = np.array(device)
        dev_dir = device / np.linalg.norm(device)
        cone = np.arcsin(0.05 / np.linalg.norm(device))
        axis = np.cross(dev_dir, [0.3, 0.5, 0.8])
        axis /= np.linalg.norm(axis)
        pts = []
        for angle in np.linspace(0.0, 1.6 * cone, 40):
            for turn in np.linspace(0.0, 2 * np.pi, 24, endpoint=False):
                # rotate dev_dir by `angle` about an axis turned by `turn` around dev_dir
                a = np.cos(turn) * axis + np.sin(turn) * np.cross(dev_dir, axis)
                ray = dev_dir * np.cos(angle) + np.cross(a, dev_dir) * np.sin(angle)
                pts.append(ray * rng.uniform(1.2, 2.0))
        pts = np.array(pts)
        cols = rng.random((len(pts), 3)).astype(np.float32)
        em_k, em_r = EnvironmentMap(h, w), EnvironmentMap(h, w)
        for em in (em_k, em_r):
            em.valid[:] = True
            em.depth_m[:] = 1.0  # every sample is farther: only the removal rule can take it
        stats = update(em_k, pts, cols, device, FOCAL, cfg)
        touched, counts = update_reference(em_r, pts, cols, device, FOCAL, cfg)
        assert stats.touched == touched and stats.taken_removal == counts["removal"]
        assert 0 < counts["removal"] < touched
        fired += counts["removal"]
        np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
        np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)
    assert fired > 0


@pytest.mark.parametrize("ratio", [1.0, 1.5, 3.0, np.inf])
def test_viewpoint_rule_kernel_equals_the_reference(ratio):
    # One room-like surface (1–3 m per direction) sampled with 1 % distance noise from devices
    # near and far, in an order that makes far frames follow near ones and the reverse, plus a
    # nearer object that appears (a different surface: always taken) and the trusted sphere (never
    # refused). Maps, counts and the view distances must equal the per-pixel reference's.
    rng = np.random.default_rng(11)
    h, w = 30, 60
    origin = (0.0, 0.0, 0.0)
    n = 600
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wall = rng.uniform(1.0, 3.0, n)
    em_k, em_r = EnvironmentMap(h, w, origin), EnvironmentMap(h, w, origin)
    cfg = UpdateConfig(max_splat_px=4, view_ratio=ratio, carve=False)
    averaged = np.zeros((h, w), int)
    views = np.full((h, w), np.inf, np.float32)
    kept = 0
    devices = [0.3, 1.2, 0.5, 2.0, 0.05, 1.0, 0.6, 2.5]
    for k, dev_r in enumerate(devices):
        dist = wall * (1.0 + 0.01 * rng.normal(size=n))
        if k == 5:  # an object appears in front of part of the room
            dist = np.where(dirs[:, 2] > 0.5, 0.6 * wall, dist)
        pts = dirs * dist[:, None]
        cols = rng.random((n, 3)).astype(np.float32)
        device = dev_r * np.array([0.6, 0.0, 0.8])
        stats = update(em_k, pts, cols, device, 30.0, cfg)
        touched, counts = update_reference(em_r, pts, cols, device, 30.0, cfg, None, averaged, views)
        assert stats.touched == touched
        assert (stats.taken_empty, stats.taken_closer, stats.taken_trusted, stats.taken_removal, stats.averaged,
                stats.kept_view, stats.kept_clipped) == tuple(counts.values())
        assert stats.taken == sum(counts[r] for r in ("empty", "closer", "trusted", "removal"))
        if dev_r < cfg.trusted_radius_m:
            assert stats.kept_view == 0  # the trusted sphere is never refused
        kept += stats.kept_view
        np.testing.assert_array_equal(em_k.valid, em_r.valid)
        np.testing.assert_array_equal(em_k.depth_m, em_r.depth_m)
        np.testing.assert_array_equal(em_k.radiance_planes, em_r.radiance_planes)
        if ratio < np.inf:
            np.testing.assert_array_equal(update_module.view_distances(em_k), views)
    if ratio == np.inf:
        assert kept == 0
    else:
        assert kept > 0


@pytest.mark.parametrize("value,error", [(0.99, RangeError), (0.0, RangeError), (-np.inf, RangeError),
                                         (np.nan, RangeError), ("1.5", DTypeError), (True, DTypeError), (None, DTypeError)])
def test_view_ratio_is_validated(value, error):
    with pytest.raises(error, match="UpdateConfig.view_ratio"):
        UpdateConfig(view_ratio=value)
    assert UpdateConfig(view_ratio=1.0).view_ratio == 1.0 and UpdateConfig(view_ratio=np.inf).view_ratio == np.inf
    assert UpdateConfig().view_ratio == 1.5


def test_viewpoint_rule_keeps_near_views_and_lets_other_surfaces_in():
    # A closed-form case: every map pixel holds a surface at 2 m seen from 0.4 m out. A same-surface
    # (nearer) sample from 1.0 m out (> 1.5 × 0.4) is refused, one from 0.5 m is averaged in and lowers
    # nothing; a nearer object (1 m: a different surface) is taken from 1.0 m, and then a 1.0 m
    # view of the same surface, from no farther than 1.5 × 1.0, is taken.
    h, w = 20, 40
    em = EnvironmentMap(h, w)
    dirs = equirect_directions(h, w).reshape(-1, 3)
    grey = np.full((len(dirs), 3), 0.5, np.float32)
    cfg = UpdateConfig(splat=False, carve=False)
    dev = lambda r: np.array([0.0, r, 0.0])  # noqa: E731
    s0 = update(em, dirs * 2.0, grey, dev(0.4), FOCAL, cfg)
    assert s0.taken_empty == h * w
    np.testing.assert_array_equal(update_module.view_distances(em), np.float32(0.4))
    before = em.radiance_planes.copy(), em.depth_m.copy()
    s1 = update(em, dirs * 1.99, np.ones_like(grey), dev(1.0), FOCAL, cfg)
    assert s1.taken == 0 and s1.kept_view == h * w and s1.touched == h * w
    np.testing.assert_array_equal(em.radiance_planes, before[0])
    np.testing.assert_array_equal(em.depth_m, before[1])
    # Off, the same frame averages into every pixel (the closer rule does not apply: farther).
    em_off = EnvironmentMap(h, w)
    update(em_off, dirs * 2.0, grey, dev(0.4), FOCAL, cfg)
    s_off = update(em_off, dirs * 1.99, np.ones_like(grey), dev(1.0), FOCAL, UpdateConfig(splat=False, carve=False, view_ratio=np.inf))
    assert s_off.kept_view == 0 and s_off.averaged == h * w
    s2 = update(em, dirs * 1.99, np.ones_like(grey), dev(0.5), FOCAL, cfg)
    assert s2.taken_closer == h * w and s2.averaged == h * w and s2.kept_view == 0
    np.testing.assert_allclose(em.radiance_planes, 0.75)
    np.testing.assert_array_equal(update_module.view_distances(em), np.float32(0.4))  # the minimum stays
    s3 = update(em, dirs * 1.0, grey, dev(1.0), FOCAL, cfg)
    assert s3.taken_closer == h * w and s3.averaged == 0 and s3.kept_view == 0
    np.testing.assert_array_equal(update_module.view_distances(em), np.float32(1.0))
    # The depth is now the mean 0.5 · (1.995 + 1.0) (the paper's rule); a sample just nearer, of that
    # surface, from 1.0 m (within 1.5 × 1.0): averaged in.
    np.testing.assert_allclose(em.depth_m, 0.5 * (0.5 * (2.0 + 1.99) + 1.0), rtol=1e-6)
    s4 = update(em, dirs * 1.49, np.ones_like(grey), dev(1.0), FOCAL, cfg)
    assert s4.kept_view == 0 and s4.averaged == h * w
    # The view distances restart with the colour counts (a modified map: any viewpoint again).
    em.mark_modified()
    assert np.isinf(update_module.view_distances(em)).all()


def _random_rgbd(seed, width, height, focal):
    """A random RGB-D frame: depth 0.5–3 m with 5 % NaN, 80 % of pixels masked in, float32 colours."""
    from rgbd_envmap.geometry import look_at
    from rgbd_envmap.types import Intrinsics

    rng = np.random.default_rng(seed)
    intr = Intrinsics(width, height, focal, focal + 1.0, (width - 1) / 2, (height - 1) / 2)
    T = look_at([0.1, -0.2, 0.05], [2.0, 0.5, 0.3])
    depth = rng.uniform(0.5, 3.0, intr.shape).astype(np.float32)
    depth[rng.random(intr.shape) < 0.05] = np.nan
    mask = rng.random(intr.shape) < 0.8
    rgb = rng.random((*intr.shape, 3)).astype(np.float32)
    return rng, intr, T, depth, mask, rgb


def test_fused_frame_samples_and_pairs_equal_the_separate_calls():
    from rgbd_envmap.envmap import frame_pairs, frame_points, frame_samples

    rng, intr, T, depth, mask, rgb = _random_rgbd(12, 40, 30, 35.0)
    flag = rng.random(intr.shape) < 0.3
    pts, col, fo = frame_samples(depth, mask, intr, T, rgb, flag)
    np.testing.assert_array_equal(pts, frame_points(depth, mask, intr, T))
    np.testing.assert_array_equal(col, rgb[mask])
    np.testing.assert_array_equal(fo, flag[mask])
    assert not frame_samples(depth, mask, intr, T, rgb)[2].any()
    # Colours corrected in the same pass: apply_ccm's values up to float32 rounding; points unchanged.
    from rgbd_envmap.colour import apply_ccm

    m = np.array([[1.3, 0.1, -0.05], [0.02, 0.9, 0.1], [-0.1, 0.05, 1.7]])
    pts_m, col_m, _ = frame_samples(depth, mask, intr, T, rgb, flag, m)
    np.testing.assert_array_equal(pts_m, pts)
    assert col_m.dtype == np.float32
    np.testing.assert_allclose(col_m, apply_ccm(rgb[mask], m), rtol=2e-6, atol=1e-7)
    from rgbd_envmap.errors import NonFiniteError

    with pytest.raises(NonFiniteError):
        frame_samples(depth, mask, intr, T, rgb, flag, np.full((3, 3), np.nan))
    em = EnvironmentMap(H, W)
    update(em, frame_points(depth, np.ones(intr.shape, bool), intr, T), rgb.reshape(-1, 3), np.zeros(3), FOCAL)
    src, dst = frame_pairs(em, depth, mask, intr, T, rgb, 0.05)
    ref_src, ref_dst = collect_pairs(em, pts, rgb[mask], 0.05)
    assert len(src) > 100
    np.testing.assert_array_equal(src, ref_src)
    np.testing.assert_array_equal(dst, ref_dst)



@pytest.mark.parametrize("threads", [1, 2])
def test_fused_pair_sums_equal_summing_the_collected_pairs_bit_for_bit(threads):
    """The pairs reduced to normal-equation sums give exactly what collecting them and summing
    gives (same values, same order), NaN and saturated colours included, on one thread and two."""
    from rgbd_envmap.colour import ccm_sums
    from rgbd_envmap.envmap import frame_pair_sums, frame_pairs, frame_points

    def _frame_pair_sums(*args, **kwargs):
        return frame_pair_sums(*args, **kwargs, threads=threads)

    rng, intr, T, depth, mask, rgb = _random_rgbd(13, 64, 48, 50.0)
    rgb *= 1.1  # some channels ≥ 1: saturated
    rgb[rng.random(intr.shape) < 0.02, 1] = np.nan
    em = EnvironmentMap(H, W)
    update(em, frame_points(depth, np.ones(intr.shape, bool), intr, T), rng.random((intr.shape[0] * intr.shape[1], 3)),
           np.zeros(3), FOCAL)
    src, dst = frame_pairs(em, depth, mask, intr, T, rgb, 0.05)
    ata, atb, bb, n, n_nonfinite, n_saturated = ccm_sums(src, dst, 1.0)
    got = _frame_pair_sums(em, depth, mask, intr, T, rgb, 0.05, saturation=1.0)
    assert n > 100 and n_nonfinite > 0 and n_saturated > 0
    np.testing.assert_array_equal(got[0], ata)
    np.testing.assert_array_equal(got[1], atb)
    assert got[2:] == (bb, n, n_nonfinite, n_saturated, len(src))
    # An empty map: no pairs, zero sums.
    empty = _frame_pair_sums(EnvironmentMap(H, W), depth, mask, intr, T, rgb)
    assert empty[3:] == (0, 0, 0, 0) and not empty[0].any() and not empty[1].any()
    # No pixel in the mask, one pixel, one row.
    one = np.zeros_like(mask)
    one[5, 5] = True
    for m in (np.zeros_like(mask), one, mask & (np.arange(mask.shape[0]) == 20)[:, None]):
        src, dst = frame_pairs(em, depth, m, intr, T, rgb, 0.05)
        ata, atb, bb, n, n_nonfinite, n_saturated = ccm_sums(src, dst, 1.0)
        got = _frame_pair_sums(em, depth, m, intr, T, rgb, 0.05, saturation=1.0)
        np.testing.assert_array_equal(got[0], ata)
        assert got[2:] == (bb, n, n_nonfinite, n_saturated, len(src))

@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("offset", [(0.3, -0.2, 0.1), (-0.05, 0.0, 0.6), (0.0, 0.0, 0.0)])
def test_translate_kernel_equals_the_per_pixel_reference(offset, threads):
    # Random depths with depth jumps, holes and empty rows (the kernel skips them), a far move
    # (magnified footprints, the seam, the poles) and ties: whole constant-depth rows.
    rng = np.random.default_rng(3)
    h, w = 24, 48
    depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    depth[:, 10:20] = 0.6  # a near block: depth jumps at its sides
    depth[5] = 1.5
    valid = rng.random((h, w)) < 0.8
    valid[8:11] = False  # empty rows
    rad = rng.random((h, w, 3)).astype(np.float32)
    em = EnvironmentMap.from_arrays(rad, depth, valid, np.zeros(3))
    off = np.array(offset)
    got, ref = translate(em, off, threads=threads), translate_reference(em, off)
    np.testing.assert_array_equal(got.valid, ref.valid)
    np.testing.assert_array_equal(got.depth_m, ref.depth_m)
    np.testing.assert_array_equal(got.radiance_planes, ref.radiance_planes)
    # The source map is intact and the key buffers clean for the next call (the spare keys past
    # the map's end take the updates of pixels that are not one-pixel footprints).
    from rgbd_envmap._kernels.translate import NO_KEY
    from rgbd_envmap.envmap.translation import _translate_buffers

    np.testing.assert_array_equal(em.depth_m, depth)
    for part in range(threads):
        assert (_translate_buffers(h, w, part)[0][: h * w] == NO_KEY).all()


def test_float32_atan2_matches_libm():
    import math

    from rgbd_envmap._kernels.translate import atan2_f32

    rng = np.random.default_rng(4)
    pts = np.concatenate([rng.normal(size=(5000, 2)), [[0, 1], [0, -1], [1, 0], [-1, 1e-30], [1e-30, 1e-30]]])
    pts = pts.astype(np.float32)
    err = max(abs(atan2_f32(y, x) - math.atan2(y, x)) for y, x in pts)
    assert err < 3e-7  # 1e-4 of a 2000×1000 pixel (3.1e-3 rad)


def test_pairs_equal_a_numpy_reference():
    rng = np.random.default_rng(5)
    for origin in (np.zeros(3), np.array([0.3, -0.2, 0.1])):
        em = EnvironmentMap(H, W, origin)
        update(em, origin + rng.normal(size=(3000, 3)) * 2, rng.random((3000, 3)).astype(np.float32), origin, FOCAL)
        pts = origin + rng.normal(size=(4000, 3)) * 2
        pts[::97] = np.nan
        cols = rng.random((4000, 3))  # float64 colours come back as float32
        src, dst = collect_pairs(em, pts, cols, max_depth_diff_m=0.3)
        ref_src, ref_dst = pairs_reference(em, pts, cols, max_depth_diff_m=0.3)
        assert 0 < len(ref_src) < len(pts)
        assert src.dtype == dst.dtype == np.float32
        np.testing.assert_array_equal(src, ref_src)
        np.testing.assert_array_equal(dst, ref_dst)


def test_translate_kernel_on_tiny_and_empty_maps():
    # Rows of one or two pixels (the seam neighbours are the pixel itself or each other), one row.
    rng = np.random.default_rng(6)
    for h, w in ((1, 1), (1, 2), (2, 1), (2, 3), (5, 2)):
        em = EnvironmentMap.from_arrays(rng.random((h, w, 3)).astype(np.float32),
                                        rng.uniform(0.5, 3, (h, w)).astype(np.float32), rng.random((h, w)) < 0.8, np.zeros(3))
        for off in (np.array([0.3, -0.2, 0.1]), np.zeros(3)):
            got, ref = translate(em, off), translate_reference(em, off)
            np.testing.assert_array_equal(got.valid, ref.valid)
            np.testing.assert_array_equal(got.depth_m, ref.depth_m)
            np.testing.assert_array_equal(got.radiance_planes, ref.radiance_planes)
    out = translate(EnvironmentMap(H, W), np.array([0.1, 0.0, 0.0]))
    assert not out.valid.any() and not out.depth_m.any() and not out.radiance_planes.any()


def _random_map(rng, h, w, coverage):
    depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    depth[:, : w // 4] = 0.6  # a near block: magnified footprints and depth jumps
    return EnvironmentMap.from_arrays(rng.random((h, w, 3)).astype(np.float32), depth, rng.random((h, w)) < coverage,
                                      np.zeros(3))


def _assert_same_map(got, ref):
    np.testing.assert_array_equal(got.valid, ref.valid)
    np.testing.assert_array_equal(got.depth_m.view(np.uint32), ref.depth_m.view(np.uint32))
    np.testing.assert_array_equal(got.radiance_planes.view(np.uint32), ref.radiance_planes.view(np.uint32))


def test_translate_keys_of_earlier_calls_never_show():
    # The key buffer is kept between calls: a dense map, then a sparse one of the same size must
    # give the sparse map's own result (and back).
    rng = np.random.default_rng(7)
    h, w = 20, 40
    dense, sparse = _random_map(rng, h, w, 0.95), _random_map(rng, h, w, 0.3)
    off = np.array([0.2, -0.1, 0.05])
    ref_dense, ref_sparse = translate_reference(dense, off), translate_reference(sparse, off)
    for threads in (2, 1, 2):
        _assert_same_map(translate(dense, off, threads=threads), ref_dense)
        _assert_same_map(translate(sparse, off, threads=threads), ref_sparse)


@pytest.mark.parametrize("h, w", [(1, 1), (2, 3), (3, 8), (40, 80)])
def test_translate_on_two_threads_is_the_one_thread_map(h, w):
    # The rows split where half the valid pixels lie (all in one half, none, or one row apart),
    # the output pass at half the rows; a far move, so footprints cross the split both ways.
    rng = np.random.default_rng(9)
    for coverage in (0.0, 0.5, 1.0):
        em = _random_map(rng, h, w, coverage)
        em.valid[: h // 2] &= coverage < 1.0  # top half empty in the dense case: the split moves down
        for off in (np.array([0.4, 0.1, -0.3]), np.array([0.0, 0.0, 0.9]), np.zeros(3)):
            _assert_same_map(translate(em, off, threads=2), translate(em, off, threads=1))


def test_translate_threads_must_be_positive():
    for bad in (0, -1, 1.5):
        with pytest.raises((InvalidInputError, RangeError, DTypeError)):
            translate(EnvironmentMap(H, W), np.array([0.1, 0.0, 0.0]), threads=bad)


def test_translate_out_gives_the_same_map_in_place():

    rng = np.random.default_rng(8)
    em = _random_map(rng, 24, 48, 0.8)
    em.origin = np.array([0.1, 0.2, 0.3])
    out = EnvironmentMap(24, 48)
    out.record_changes()
    for method, off in (("depth", np.array([0.3, -0.2, 0.1])), ("depth", np.array([-0.05, 0.0, 0.4])), ("gardner", np.array([0.2, 0, 0]))):
        ref = translate(em, off, method)
        got = translate(em, off, method, out=out)
        assert got is out
        _assert_same_map(got, ref)
        np.testing.assert_array_equal(got.origin, em.origin + off)
        assert not out.take_changes().complete  # the whole map was rewritten outside update()


def test_translate_out_errors():
    em = EnvironmentMap(H, W)
    off = np.array([0.1, 0.0, 0.0])
    for bad in (EnvironmentMap(H, W + 2), EnvironmentMap(H + 1, W), em):
        with pytest.raises(InvalidInputError, match="out"):
            translate(em, off, out=bad)
    with pytest.raises(DTypeError, match="out: expected an EnvironmentMap"):
        translate(em, off, out=np.zeros((3, H, W), np.float32))
    read_only = EnvironmentMap(H, W)
    read_only.radiance_planes.setflags(write=False)
    with pytest.raises(InvalidInputError, match="out.radiance_planes: expected a writable array"):
        translate(em, off, out=read_only)
    shares = EnvironmentMap(H, W)
    shares.depth_m = em.depth_m  # the kernel would read what it writes
    with pytest.raises(InvalidInputError, match="out"):
        translate(em, off, out=shares)
    # Nothing is touched when the call is rejected.
    out = EnvironmentMap(H, W)
    with pytest.raises(InvalidInputError):
        translate(em, np.array([3.0, 0, 0]), "gardner", radius_m=2.0, out=out)
    np.testing.assert_array_equal(out.origin, np.zeros(3))


def test_masked_run_update_touches_only_its_lanes():
    import numba

    from rgbd_envmap._kernels.intrinsics import min_run8

    @numba.njit
    def run(a, q, m, k):
        min_run8(a, q, m, k)

    for q, m in ((0, 0), (3, 1), (2, 5), (4, 8), (1, 11), (14, 2)):  # (14, 2): lanes past the end stay off
        a = np.arange(16, dtype=np.int64) * 10
        expect = a.copy()
        expect[q : q + min(m, 8)] = np.minimum(expect[q : q + min(m, 8)], 45)
        run(a, q, m, 45)
        np.testing.assert_array_equal(a, expect)


def _random_frame(rng, n=400, spread=1.0):
    pts = rng.normal(size=(n, 3)) * spread
    return pts, rng.random((n, 3)).astype(np.float32)


def test_change_log_lists_exactly_the_written_pixels_with_their_old_state():
    rng = np.random.default_rng(3)
    em = EnvironmentMap(H, W)
    assert em.take_changes() is None  # not recording
    update(em, *_random_frame(rng), np.array([0.0, 0.0, 2.0]), FOCAL)
    em.record_changes()
    before = (em.radiance_planes.copy(), em.depth_m.copy(), em.valid.copy())
    stats = update(em, *_random_frame(rng), np.array([0.0, 0.0, 2.0]), FOCAL)
    ch = em.take_changes()
    assert ch.complete and ch.updates == 1 and len(ch.index) == stats.taken > 0
    changed = (em.depth_m != before[1]) | (em.valid != before[2]) | (em.radiance_planes != before[0]).any(0)
    assert set(np.flatnonzero(changed)) <= set(ch.index.tolist())  # every changed pixel is listed
    assert (np.diff(ch.index) > 0).all()  # each once, in raster order
    np.testing.assert_array_equal(ch.was_valid, before[2].ravel()[ch.index])
    old = before[0].reshape(3, -1)[:, ch.index].T
    np.testing.assert_array_equal(ch.old_radiance[ch.was_valid], old[ch.was_valid])
    again = em.take_changes()  # the log restarts empty
    assert again.complete and len(again.index) == 0 and again.updates == 0


def test_change_log_over_several_updates_keeps_each_pixel_once_with_its_first_old_state():
    rng = np.random.default_rng(4)
    em = EnvironmentMap(H, W)
    em.record_changes()
    before = (em.radiance_planes.copy(), em.valid.copy())
    for _ in range(3):
        update(em, *_random_frame(rng), np.array([0.0, 0.0, 0.05]), FOCAL)  # trusted sphere: rewrites
    ch = em.take_changes()
    assert ch.updates == 3 and ch.complete and (np.diff(ch.index) > 0).all()
    assert not ch.was_valid.any()  # all were empty before the first update
    assert set(ch.index.tolist()) == set(np.flatnonzero(em.valid & ~before[1]).tolist())


def test_change_log_overflow_and_mark_modified_say_incomplete():
    rng = np.random.default_rng(5)
    em = EnvironmentMap(H, W)
    em.record_changes()
    em.change_log = ChangeLog(8)  # a tiny log
    stats = update(em, *_random_frame(rng), np.zeros(3) + 2.0, FOCAL)
    ch = em.take_changes()
    assert stats.taken > 8 and not ch.complete and len(ch.index) == 8
    update(em, *_random_frame(rng), np.zeros(3) + 2.0, FOCAL)  # the log grew to fit
    assert em.take_changes().complete
    em.mark_modified()
    assert not em.take_changes().complete
    assert translate(em, np.zeros(3)).take_changes() is None  # a new map does not record


@pytest.mark.parametrize("avx512", [True, False])
def test_compress16_lists_the_flagged_columns_in_order(monkeypatch, avx512):
    # Both code paths of the intrinsic (AVX-512's register compress, LLVM's portable
    # compress-store), each in a freshly compiled function: the flagged columns of each 16, in
    # order, appended after what the list holds; 16 flags past the end read as zero padding.
    import numba

    from rgbd_envmap._kernels import intrinsics as _intrinsics

    if avx512 and not _intrinsics.host_has_avx512():
        pytest.skip("no AVX-512 here")
    monkeypatch.setattr(_intrinsics, "AVX512", avx512)
    compress16 = _intrinsics.compress16

    @numba.njit(cache=False)
    def listed(flags, width, out, n):
        for c0 in range(0, width, 16):
            n = compress16(flags, c0, out, n)
        return n

    rng = np.random.default_rng(11)
    for width, p in ((1, 1.0), (16, 0.0), (37, 0.5), (200, 0.1), (200, 1.0)):
        flags = np.zeros(width + 16, np.uint8)
        flags[:width] = rng.random(width) < p
        out = np.full(width + 16 + 5, -7, np.int32)
        n = listed(flags, width, out, 5)
        expect = np.flatnonzero(flags[:width])
        assert n == 5 + len(expect)
        np.testing.assert_array_equal(out[5:n], expect)
        assert (out[:5] == -7).all()  # what the list held before is untouched
