"""Tests for rgbd_envmap.ingest.kinect: warp + merge + normals of the Kinect path (paper 001 §4.2).

References are independent of the library: scenes are ray-cast analytically here (planes, a box in
front of a wall, a sphere) with known depth and normals; OpenCV's ``warpFrame`` (a point forward
warp) and ``RgbdNormals``, and kornia's ``warp_frame_depth`` (a backward warp) and
``depth_to_normals`` serve as second implementations. The warp is also compared with its float64
loop transcription, :func:`rgbd_envmap.reference.kinect.warp_reference`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial.transform import Rotation

from rgbd_envmap.colour import srgb_to_linear
from rgbd_envmap.depth import mark_reliable
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, ShapeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.ingest.kinect import (
    KinectMergeConfig,
    KinectMerger,
    kinect_rgbd_frame,
    merge_depth,
    normals_from_depth,
    warp_depth,
)
from rgbd_envmap.reference.kinect import warp_reference
from rgbd_envmap.types import Distortion, Intrinsics, RGBDFrame, RigidTransform


@dataclass(frozen=True)
class _Tol:
    plane_rel: float = 2e-6  #: warped depth of a plane vs ray–plane intersection (float32 output)
    plane_normal_deg: float = 0.05  #: normals of a noise-free plane (float32 depth and positions)
    sphere_normal_deg: float = 1.5  #: normals on a sphere (finite differences of a curved surface)
    reference_normal_deg: float = 2.0  #: our normals vs OpenCV / kornia on a sphere (median)
    kernel_rel: float = 5e-7  #: warped depth vs the float64 reference warp (float32 interpolation, ≤ 4 ulp)


TOL = _Tol()
INTR = Intrinsics(160, 120, 130.0, 130.0, 79.5, 59.5)


# ------------------------------------------------------------------------------------------- scenes


def _rays(intr: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)


def _render(intr, T_world_from_cam, planes=(), rects=(), spheres=()):
    """Analytic ray cast in the camera frame. planes: (n_world, c) with n·p = c; rects: (n, c, lo, hi)
    bounded by the world box [lo, hi]; spheres: (centre_world, radius). Returns float32 z-depth
    (0: no hit), float32 camera-frame unit normals facing the camera, and the hit mask."""
    rays = _rays(intr)  # z = 1, so the ray parameter is the z-depth
    R, t = T_world_from_cam.rotation, T_world_from_cam.translation
    dirs_w = rays @ R.T
    best = np.full(rays.shape[:2], np.inf)
    normal_w = np.zeros(rays.shape)
    for n, c, *box in [(np.asarray(n, float), c) for n, c in planes] + [
        (np.asarray(n, float), c, np.asarray(lo, float), np.asarray(hi, float)) for n, c, lo, hi in rects
    ]:
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (c - n @ t) / (dirs_w @ n)
        hit = z > 1e-6
        if box:
            p = t + dirs_w * z[..., None]
            hit &= np.all((p >= box[0] - 1e-9) & (p <= box[1] + 1e-9), axis=-1)
        take = hit & (z < best)
        best[take] = z[take]
        normal_w[take] = n / np.linalg.norm(n)
    for centre, radius in spheres:
        oc = t - np.asarray(centre, float)
        a = np.einsum("ijk,ijk->ij", dirs_w, dirs_w)
        b = 2 * dirs_w @ oc
        disc = b * b - 4 * a * (oc @ oc - radius**2)
        with np.errstate(invalid="ignore"):
            z = (-b - np.sqrt(disc)) / (2 * a)
        take = (disc > 0) & (z > 1e-6) & (z < best)
        best[take] = z[take]
        p = t + dirs_w[take] * z[take, None]
        normal_w[take] = (p - centre) / radius
    valid = np.isfinite(best)
    n_cam = normal_w @ R  # world → camera
    flip = np.einsum("ijk,ijk->ij", n_cam, rays) > 0
    n_cam[flip] *= -1
    depth = np.where(valid, best, 0.0).astype(np.float32)
    return depth, n_cam.astype(np.float32), valid


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a.astype(np.float64) * b, axis=-1), -1.0, 1.0)))


def _pose(rotvec_deg=(0.0, 0.0, 0.0), t=(0.0, 0.0, 0.0)):
    return RigidTransform.from_rt(Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix(), np.asarray(t, float))


BOX_SCENE = {
    "planes": [((0.0, 0.0, -1.0), -3.0)],  # wall z = 3
    "rects": [((0.0, 0.0, -1.0), -1.2, (-0.3, -0.25, 1.2), (0.3, 0.25, 1.2))],  # box face at z = 1.2
}
SPHERE_SCENE = {"planes": [((0.0, 0.0, -1.0), -3.0)], "spheres": [((0.1, 0.0, 1.6), 0.45)]}


def _ones(shape=INTR.shape):
    return np.ones(shape, np.float32)


# --------------------------------------------------------------------------------------- identity


def test_identity_pose_leaves_depth_bit_for_bit():
    rng = np.random.default_rng(1)
    depth, _, valid = _render(INTR, RigidTransform.identity(), **SPHERE_SCENE)
    depth = (depth * (1 + 0.003 * rng.standard_normal(depth.shape))).astype(np.float32)
    known = valid & (rng.random(depth.shape) > 0.05)  # speckled holes
    known[40:60, 30:50] = False  # and a block
    merger = KinectMerger(INTR)
    first = merger.step(depth, known, _pose((1, 2, 3), (0.1, 0.2, 0.3)))
    np.testing.assert_array_equal(first.depth_m, np.where(known, depth, 0))
    for k in range(2, 5):
        out = merger.step(depth, known, _pose((1, 2, 3), (0.1, 0.2, 0.3)))
        np.testing.assert_array_equal(out.known, known)
        np.testing.assert_array_equal(out.depth_m, np.where(known, depth, 0))
        assert out.n_replaced == 0 and out.n_occluded == 0 and out.n_held == 0
    assert out.weight.max() == 4.0 and np.all(out.weight[known] >= 1)


def test_identity_warp_is_exact_and_keeps_rims():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **BOX_SCENE)
    weight = np.random.default_rng(0).integers(1, 9, depth.shape).astype(np.float32)
    d, w, k = warp_depth(depth, weight, valid, INTR, RigidTransform.identity())
    # every pixel is on a surviving triangle (no holes, each surface wider than a pixel)
    np.testing.assert_array_equal(k, valid)
    np.testing.assert_array_equal(d, depth)
    np.testing.assert_array_equal(w, weight)


def test_identity_warp_with_distortion_is_exact():
    intr = Intrinsics(96, 72, 80.0, 82.0, 47.2, 35.9, Distortion(-0.2, 0.05, 0.001, -0.002, 0.0))
    depth = np.linspace(1.0, 2.0, 96 * 72, dtype=np.float32).reshape(72, 96)
    known = np.ones(depth.shape, bool)
    d, _, k = warp_depth(depth, _ones(depth.shape), known, intr, RigidTransform.identity())
    assert k.all()
    np.testing.assert_allclose(d, depth, rtol=1e-7)


# ------------------------------------------------------------------------------------ exact warps


@pytest.mark.parametrize("t", [(0.05, -0.03, 0.0), (0.0, 0.0, -0.4), (0.021, 0.013, 0.25)])
def test_translated_fronto_parallel_plane_warps_to_exact_depth(t):
    z0 = 2.0
    depth = np.full(INTR.shape, z0, np.float32)
    known = np.ones(INTR.shape, bool)
    T = RigidTransform.from_rt(np.eye(3), t)  # p_cur = p_prev + t
    d, _, k = warp_depth(depth, _ones(), known, INTR, T)
    z1 = z0 + t[2]
    np.testing.assert_allclose(d[k], z1, rtol=1e-7)
    # coverage: a current pixel is covered iff its point, moved back, projects inside the source grid
    rays = _rays(INTR)
    p_prev = rays * z1 - np.asarray(t)
    u = INTR.fx * p_prev[..., 0] / p_prev[..., 2] + INTR.cx
    v = INTR.fy * p_prev[..., 1] / p_prev[..., 2] + INTR.cy
    inside = (u >= 1e-6) & (u <= INTR.width - 1 - 1e-6) & (v >= 1e-6) & (v <= INTR.height - 1 - 1e-6)
    margin = (u >= -0.6) & (u <= INTR.width - 0.4) & (v >= -0.6) & (v <= INTR.height - 0.4)  # rim splats
    assert np.all(k[inside]) and not np.any(k[~margin])


def test_tilted_plane_under_rotation_and_translation_is_exact():
    # perspective-correct interpolation of 1/z is exact for a planar triangle
    plane = ((0.3, -0.2, -1.0), -2.2)
    T_w_prev = RigidTransform.identity()
    T_w_cur = _pose((4.0, -6.0, 3.0), (0.08, -0.05, 0.1))
    prev, _, valid = _render(INTR, T_w_prev, planes=[plane])
    cur, _, _ = _render(INTR, T_w_cur, planes=[plane])
    T_cur_from_prev = RigidTransform(T_w_cur.inverse().matrix @ T_w_prev.matrix)
    d, _, k = warp_depth(prev, _ones(), valid, INTR, T_cur_from_prev)
    assert k.mean() > 0.7
    np.testing.assert_allclose(d[k], cur[k], rtol=TOL.plane_rel)


def test_warp_agrees_with_opencv_point_warp_on_a_plane():
    depth = np.full(INTR.shape, 1.5, np.float32)
    T = RigidTransform.from_rt(np.eye(3), (0.04, 0.02, -0.1))
    d, _, k = warp_depth(depth, _ones(), np.ones(INTR.shape, bool), INTR, T)
    # An image and a mask are passed explicitly: OpenCV 5.1's warpFrame crashes on None for them.
    ref, _, ref_mask = cv2.warpFrame(depth, np.zeros((*INTR.shape, 3), np.uint8), np.full(INTR.shape, 255, np.uint8),
                                     T.matrix, INTR.K)
    both = k & (ref_mask > 0) & (ref > 0)
    assert both.sum() > 0.5 * k.sum()
    np.testing.assert_allclose(d[both], ref[both], rtol=1e-6)
    # the point warp leaves cracks where the triangles do not (magnification by moving closer)
    assert k.sum() > 1.05 * ((ref_mask > 0) & (ref > 0)).sum()


def _torch_and_kornia():
    """torch and kornia, the second implementations of some tests (the dev extra; not run-time
    dependencies): skip the test without them."""
    torch = pytest.importorskip("torch", reason="torch (dev extra) is only a test reference here")
    kornia = pytest.importorskip("kornia", reason="kornia (dev extra) is only a test reference here")
    return torch, kornia


def test_warp_is_consistent_with_kornia_backward_warp_on_a_sphere():
    torch, kornia = _torch_and_kornia()

    T_w_prev, T_w_cur = RigidTransform.identity(), _pose((0.0, 3.0, 0.0), (0.04, 0.0, 0.02))
    prev, _, valid = _render(INTR, T_w_prev, **SPHERE_SCENE)
    T_cur_from_prev = RigidTransform(T_w_cur.inverse().matrix @ T_w_prev.matrix)
    d, _, k = warp_depth(prev, _ones(), valid, INTR, T_cur_from_prev)
    # kornia samples the previous depth at the projection of each warped point into the previous view;
    # the sample must equal that point's own z in the previous frame (bilinear error only)
    src = torch.from_numpy(prev)[None, None].double()
    dst = torch.from_numpy(np.where(k, d, 0).astype(np.float64))[None, None]
    K = torch.from_numpy(INTR.K)[None]
    T_prev_from_cur = torch.from_numpy(T_cur_from_prev.inverse().matrix.copy())[None]
    sampled = kornia.geometry.depth.warp_frame_depth(src, dst, T_prev_from_cur, K)[0, 0].numpy()
    pts = _rays(INTR) * d[..., None].astype(np.float64)
    z_prev = pts @ T_cur_from_prev.inverse().rotation[2] + T_cur_from_prev.inverse().translation[2]
    inner = k & (cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)
    _, _, sphere = _render(INTR, T_w_cur, spheres=SPHERE_SCENE["spheres"])
    check = inner & cv2.erode(sphere.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert check.sum() > 1000
    err = np.abs(sampled[check] - z_prev[check]) / z_prev[check]
    assert np.median(err) < 1e-4 and err.max() < 2e-3


# ------------------------------------------------------------------- straightforward reference warp

INTR_SMALL = Intrinsics(80, 60, 65.0, 66.0, 39.3, 29.6)
def _noisy_scene(intr, scene, seed):
    rng = np.random.default_rng(seed)
    depth, _, valid = _render(intr, RigidTransform.identity(), **scene)
    depth = (depth * (1 + 0.002 * rng.standard_normal(depth.shape))).astype(np.float32)
    known = valid & (rng.random(depth.shape) > 0.03)
    known[20:26, 10:17] = False
    weight = rng.integers(1, 9, depth.shape).astype(np.float32)
    return depth, weight, known


@pytest.mark.slow
@pytest.mark.parametrize(
    "scene, pose, distortion",
    [
        (BOX_SCENE, ((0.4, -0.7, 0.3), (0.012, -0.006, 0.01)), None),  # frame-to-frame motion, depth edges
        (SPHERE_SCENE, ((1.5, 2.0, -1.0), (-0.03, 0.02, -0.05)), None),
        (BOX_SCENE, ((-4.0, 9.0, 2.0), (0.2, -0.1, 0.15)), None),  # large motion: ~20 px, folds, occlusion
        (SPHERE_SCENE, ((0.6, -0.4, 0.8), (0.01, 0.015, 0.02)), (-0.2, 0.05, 0.001, -0.002, 0.01)),
    ],
)
def test_warp_matches_a_straightforward_float64_reference(scene, pose, distortion):
    # the kernel works in float32 relative to pixel centres, one row at a time; the reference in
    # float64 on absolute positions: same coverage, same weights, depth within float32 rounding
    intr = INTR_SMALL if distortion is None else Intrinsics(80, 60, 65.0, 66.0, 39.3, 29.6, Distortion(*distortion))
    depth, weight, known = _noisy_scene(intr, scene, seed=3)
    T = _pose(*pose)
    d, w, k = warp_depth(depth, weight, known, intr, T)
    rd, rw, rk = warp_reference(depth, weight, known, intr, T)
    assert rk.sum() > 0.5 * k.size
    np.testing.assert_array_equal(k, rk)
    np.testing.assert_allclose(d[k], rd[k], rtol=TOL.kernel_rel)
    np.testing.assert_array_equal(w, rw)


def test_quads_with_every_triangle_dropped_draw_nothing():
    # a vertical depth step: the quads across it lose all four triangles (every one has a stretched
    # edge). The one-pixel pass used to interpolate such a quad anyway when its diagonal's box held a
    # single pixel centre, leaving about one flying pixel per row between the two surfaces.
    depth = np.full(INTR_SMALL.shape, 1.6, np.float32)
    depth[:, :40] = 1.0
    known = np.ones(INTR_SMALL.shape, bool)
    rng = np.random.default_rng(0)
    for _ in range(8):
        T = _pose(rng.normal(0.0, 0.3, 3), rng.normal(0.0, 0.005, 3))  # sub-pixel parallax
        d, _, k = warp_depth(depth, _ones(INTR_SMALL.shape), known, INTR_SMALL, T)
        z = d[k]
        assert k.mean() > 0.9 and not np.any((z > 1.03) & (z < 1.6 * 0.97))


# ------------------------------------------------------------------------------ discontinuities


def test_stretched_triangles_at_a_depth_edge_are_dropped():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **BOX_SCENE)
    T = RigidTransform.from_rt(np.eye(3), (0.06, 0.02, 0.0))  # parallax opens a gap beside the box
    d, _, k = warp_depth(depth, _ones(), valid, INTR, T)
    z = d[k]
    assert np.any(np.isclose(z, 1.2)) and np.any(np.isclose(z, 3.0))
    assert not np.any((z > 1.2 + 1e-3) & (z < 3.0 - 1e-3))  # nothing interpolated across the edge
    # without the stretch test the warp does smear (so the assertion above has teeth)
    d2, _, k2 = warp_depth(depth, _ones(), valid, INTR, T, max_stretch=np.inf)
    z2 = d2[k2]
    assert np.sum((z2 > 1.2 + 1e-3) & (z2 < 3.0 - 1e-3)) > 50


def test_closest_surface_wins_the_z_buffer():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **BOX_SCENE)
    T_w_cur = _pose((0.0, -8.0, 0.0), (0.25, 0.0, 0.0))
    T_cur_from_prev = T_w_cur.inverse()
    d, _, k = warp_depth(depth, _ones(), valid, INTR, T_cur_from_prev)
    truth, _, tv = _render(INTR, T_w_cur, **BOX_SCENE)
    both = k & tv
    assert both.sum() > 10000
    rel = np.abs(d[both] - truth[both]) / truth[both]
    # wrong only on a thin band along edges (where a vertex' nearest-pixel rim splat lands)
    assert np.mean(rel > 1e-4) < 0.02 and np.median(rel) < 1e-6


def test_near_plane_drops_points_behind_or_too_close():
    depth = np.full(INTR.shape, 1.0, np.float32)
    T = RigidTransform.from_rt(np.eye(3), (0.0, 0.0, -0.99))  # the plane ends up 1 cm in front
    d, _, k = warp_depth(depth, _ones(), np.ones(INTR.shape, bool), INTR, T, near_m=0.05)
    assert not k.any()
    T = RigidTransform.from_rt(np.eye(3), (0.0, 0.0, -2.0))  # behind the camera
    assert not warp_depth(depth, _ones(), np.ones(INTR.shape, bool), INTR, T)[2].any()


# --------------------------------------------------------------------------------------- merging


def test_merge_closed_form_cases():
    wd = np.array([[2.0, 2.0, 2.0, 0.0, 5.0, 2.0]], np.float32)
    ww = np.array([[3.0, 3.0, 40.0, 0.0, 2.0, 7.0]], np.float32)
    wk = np.array([[True, True, True, False, True, False]])
    nd = np.array([[2.02, 2.5, 2.01, 1.0, 0.0, 0.0]], np.float32)
    nk = np.array([[True, True, True, True, False, False]])
    d, w, k = merge_depth(wd, ww, wk, nd, nk, max_weight=16.0, threshold=0.03, occlusion_radius_px=0)
    np.testing.assert_allclose(d[0, 0], 2.0 + (np.float32(2.02) - 2.0) / 4.0, rtol=1e-7)  # average
    assert w[0, 0] == 4.0
    assert d[0, 1] == np.float32(2.5) and w[0, 1] == 1.0  # |Δ| = 0.5 > 3 % → new wins
    np.testing.assert_allclose(d[0, 2], 2.0 + (np.float32(2.01) - 2.0) / 17.0, rtol=1e-7)  # capped at 16
    assert w[0, 2] == 16.0
    assert d[0, 3] == 1.0 and w[0, 3] == 1.0  # new only
    assert d[0, 4] == 5.0 and w[0, 4] == 2.0  # held from the warp
    assert not k[0, 5] and d[0, 5] == 0 and w[0, 5] == 0  # neither
    np.testing.assert_array_equal(k, [[True, True, True, True, True, False]])


def test_merge_of_equal_values_is_exact_for_any_weight():
    rng = np.random.default_rng(3)
    d = rng.uniform(0.4, 8.0, (50, 60)).astype(np.float32)
    w = rng.uniform(0.0, 100.0, d.shape).astype(np.float32)
    k = np.ones(d.shape, bool)
    out, wt, _ = merge_depth(d, w, k, d, k, max_weight=32.0)
    np.testing.assert_array_equal(out, d)
    np.testing.assert_array_equal(wt, np.minimum(np.minimum(w, 32.0) + 1.0, 32.0))


def test_threshold_is_relative_to_depth():
    wd = np.array([[1.0, 4.0]], np.float32)
    nd = np.array([[1.1, 4.1]], np.float32)  # 10 cm apart at 1 m (10 %) and at 4 m (2.5 %)
    k = np.ones((1, 2), bool)
    _, w, _ = merge_depth(wd, np.full((1, 2), 5.0, np.float32), k, nd, k, threshold=0.03)
    np.testing.assert_array_equal(w, [[1.0, 6.0]])  # replaced near, averaged far
    _, w, _ = merge_depth(wd, np.full((1, 2), 5.0, np.float32), k, nd, k, threshold=0.0, threshold_abs_m=0.2)
    np.testing.assert_array_equal(w, [[6.0, 6.0]])


@settings(max_examples=40, deadline=None)
@given(
    hnp.arrays(np.float32, (6, 7), elements=st.floats(0.0, 10.0, width=32)),
    hnp.arrays(np.float32, (6, 7), elements=st.floats(0.0, 10.0, width=32)),
    hnp.arrays(np.float32, (6, 7), elements=st.floats(0.0, 100.0, width=32)),
    hnp.arrays(bool, (6, 7)),
    hnp.arrays(bool, (6, 7)),
    st.floats(1.0, 50.0),
)
def test_merge_invariants(wd, nd, ww, wk, nk, max_weight):
    d, w, k = merge_depth(wd, ww, wk, nd, nk, max_weight=max_weight)
    assert np.all((w >= 0) & (w <= max_weight)) and np.all(np.isfinite(d))
    np.testing.assert_array_equal(k, d > 0)
    a_ok, b_ok = wk & (wd > 0), nk & (nd > 0)
    # where the new frame measured, the result is never farther from it than τ (no smearing)
    assert np.all(np.abs(d[b_ok] - nd[b_ok]) <= 0.03 * nd[b_ok] * (1 + 1e-6))
    assert not np.any(k & ~a_ok & ~b_ok)
    lo, hi = np.minimum(wd, nd), np.maximum(wd, nd)
    both = a_ok & b_ok
    assert np.all((d[both] >= lo[both] * (1 - 1e-6)) & (d[both] <= hi[both] * (1 + 1e-6)))


def test_occlusion_test_drops_background_held_next_to_a_closer_measurement():
    wd = np.full((5, 7), 3.0, np.float32)  # the warp holds background everywhere
    nd = np.zeros((5, 7), np.float32)
    nd[:, :2] = 1.0  # foreground measured on the left, its edge pixels dropped
    nk = nd > 0
    ones = np.ones((5, 7), bool)
    d, _, k = merge_depth(wd, np.full((5, 7), 9.0, np.float32), ones, nd, nk, occlusion_radius_px=2)
    np.testing.assert_array_equal(k[0], [True, True, False, False, True, True, True])
    np.testing.assert_array_equal(d[:, 4:], 3.0)
    d, _, k = merge_depth(wd, np.full((5, 7), 9.0, np.float32), ones, nd, nk, occlusion_radius_px=0)
    assert k.all()


def test_pose_jump_to_a_different_scene_leaves_no_smear():
    rng = np.random.default_rng(5)
    merger = KinectMerger(INTR)
    T0 = RigidTransform.identity()
    old, _, valid = _render(INTR, T0, **BOX_SCENE)
    for _ in range(5):
        merger.step((old * (1 + 0.002 * rng.standard_normal(old.shape))).astype(np.float32), valid, T0)
    T1 = _pose((0.0, 30.0, 0.0), (0.5, 0.0, 0.0))  # 0.5 m and 30°
    new, _, new_valid = _render(INTR, T1, spheres=[((1.0, 0.2, 1.8), 0.5)], planes=[((0.0, 0.0, -1.0), -2.6)])
    known = new_valid & (rng.random(new.shape) > 0.1)
    out = merger.step(new, known, T1)
    # wherever the new frame measured, the output is the new value or agrees with it within τ
    assert np.all(np.abs(out.depth_m[known] - new[known]) <= 0.03 * new[known] * (1 + 1e-6))
    assert out.n_replaced > 0
    replaced = known & (out.weight == 1) & (np.abs(out.depth_m - new) == 0)
    assert replaced.sum() >= out.n_replaced
    # and the output is the rendering of the new scene up to the truth's own τ wherever known
    truth, _, _ = _render(INTR, T1, spheres=[((1.0, 0.2, 1.8), 0.5)], planes=[((0.0, 0.0, -1.0), -2.6)])
    both = out.known & new_valid
    assert np.mean(np.abs(out.depth_m[both] - truth[both]) > 0.03 * truth[both]) < 0.01


def test_weight_cap_is_respected_over_many_frames():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **SPHERE_SCENE)
    merger = KinectMerger(INTR, KinectMergeConfig(max_weight=5.0))
    for i in range(9):
        out = merger.step(depth, valid, _pose((0.0, 0.05 * i, 0.0), (0.002 * i, 0.0, 0.0)))
        assert out.weight.max() <= 5.0
    assert out.weight.max() == 5.0 and np.median(out.weight[out.known]) == 5.0


def test_merging_reduces_noise_on_a_moving_camera():
    rng = np.random.default_rng(7)
    merger = KinectMerger(INTR)
    errs_raw, errs_merged = [], []
    for i in range(12):
        T = _pose((0.0, 0.4 * i, 0.0), (0.01 * i, 0.0, 0.0))
        truth, _, valid = _render(INTR, T, **SPHERE_SCENE)
        noisy = (truth + 0.01 * rng.standard_normal(truth.shape)).astype(np.float32)
        out = merger.step(noisy, valid, T)
        m = out.known & valid
        errs_raw.append(np.sqrt(np.mean((noisy[valid] - truth[valid]) ** 2)))
        errs_merged.append(np.sqrt(np.mean((out.depth_m[m] - truth[m]) ** 2)))
    assert errs_merged[-1] < 0.45 * errs_raw[-1]


# --------------------------------------------------------------------------------------- normals


def test_normals_of_a_tilted_plane_match_the_analytic_normal():
    T = _pose((10.0, -20.0, 5.0), (0.1, 0.0, 0.0))
    depth, truth, valid = _render(INTR, T, planes=[((0.2, 0.1, -1.0), -2.0)])
    n, ok = normals_from_depth(depth, valid, INTR)
    assert ok[valid].mean() > 0.99
    assert _angle_deg(n[ok], truth[ok]).max() < TOL.plane_normal_deg
    assert np.all(np.sum(n[ok] * _rays(INTR)[ok], axis=-1) < 0)  # facing the camera


def test_normals_of_a_sphere_match_analytic_and_reference_normals():
    depth, truth, valid = _render(INTR, RigidTransform.identity(), spheres=[((0.0, 0.0, 1.5), 0.5)])
    n, ok = normals_from_depth(depth, valid, INTR)
    interior = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert ok[interior].all()
    err = _angle_deg(n[interior], truth[interior])
    assert np.median(err) < 0.2 and np.percentile(err, 99) < TOL.sphere_normal_deg
    # OpenCV's cross-product normals (camera frame, facing the camera)
    rn = cv2.RgbdNormals.create(INTR.height, INTR.width, cv2.CV_32F, INTR.K, 5, 50.0,
                                cv2.RgbdNormals_RGBD_NORMALS_METHOD_FALS)
    ref = np.asarray(rn.apply(cv2.depthTo3d(depth, INTR.K)))[..., :3]
    assert np.median(_angle_deg(n[interior], ref[interior])) < TOL.reference_normal_deg


def test_normals_of_a_sphere_match_kornia_normals():
    torch, kornia = _torch_and_kornia()
    depth, _, valid = _render(INTR, RigidTransform.identity(), spheres=[((0.0, 0.0, 1.5), 0.5)])
    n, _ = normals_from_depth(depth, valid, INTR)
    interior = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    # kornia's normals point away from the camera: flip
    kn = kornia.geometry.depth.depth_to_normals(torch.from_numpy(depth)[None, None].double(),
                                                torch.from_numpy(INTR.K)[None])[0].permute(1, 2, 0).numpy()
    assert np.median(_angle_deg(n[interior], -kn[interior])) < TOL.reference_normal_deg


def test_normals_do_not_straddle_a_depth_edge():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **BOX_SCENE)
    n, ok = normals_from_depth(depth, valid, INTR)
    assert ok[valid].all()  # one-sided differences at the edge
    np.testing.assert_allclose(n[ok], np.broadcast_to([0.0, 0.0, -1.0], n[ok].shape), atol=1e-6)


def test_merged_normals_beat_raw_normals():
    rng = np.random.default_rng(11)
    merger = KinectMerger(INTR)
    for i in range(10):
        T = _pose((0.0, 0.3 * i, 0.0), (0.005 * i, 0.0, 0.0))
        truth, tn, valid = _render(INTR, T, **SPHERE_SCENE)
        noisy = (truth * (1 + 0.003 * rng.standard_normal(truth.shape))).astype(np.float32)
        out = merger.step(noisy, valid, T)
    raw_n, raw_ok = normals_from_depth(noisy, valid, INTR)
    both = raw_ok & out.normals_valid & valid
    assert np.median(_angle_deg(out.normals[both], tn[both])) < 0.5 * np.median(_angle_deg(raw_n[both], tn[both]))


# ------------------------------------------------------------------------------ hard / bad inputs


def test_nan_inf_and_nonpositive_depth_at_known_pixels_count_as_unknown():
    depth = np.full(INTR.shape, 2.0, np.float32)
    depth[10, 10], depth[20, 20], depth[30, 30], depth[40, 40] = np.nan, np.inf, 0.0, -1.0
    known = np.ones(INTR.shape, bool)
    out = KinectMerger(INTR).step(depth, known, RigidTransform.identity())
    bad = ~np.isfinite(depth) | (depth <= 0)
    assert not out.known[bad].any() and out.known[~bad].all() and np.all(np.isfinite(out.depth_m))
    d, _, k = warp_depth(depth, _ones(), known, INTR, RigidTransform.identity())
    assert np.all(np.isfinite(d)) and not k[bad].any()
    n, ok = normals_from_depth(depth, known, INTR)
    assert np.all(np.isfinite(n)) and not ok[bad].any()


def test_all_unknown_and_tiny_inputs():
    unknown = np.zeros(INTR.shape, bool)
    garbage = np.full(INTR.shape, np.nan, np.float32)
    merger = KinectMerger(INTR)
    for _ in range(2):
        out = merger.step(garbage, unknown, RigidTransform.identity())
        assert not out.known.any() and not out.normals_valid.any() and np.all(out.depth_m == 0)
    d, w, k = warp_depth(garbage, garbage, unknown, INTR, RigidTransform.identity())
    assert not k.any() and np.all(d == 0) and np.all(w == 0)
    for shape in [(1, 1), (1, 5), (4, 1)]:
        intr = Intrinsics(shape[1], shape[0], 10.0, 10.0, 0.0, 0.0)
        z, kk = np.ones(shape, np.float32), np.ones(shape, bool)
        out = KinectMerger(intr).step(z, kk, RigidTransform.identity())
        assert out.known.all() and not out.normals_valid.any() if 1 in shape else True
        assert warp_depth(z, z, kk, intr, RigidTransform.identity())[0].shape == shape
    e = np.zeros((0, 4), np.float32)
    d, w, k = merge_depth(e, e, e.astype(bool), e, e.astype(bool))
    assert d.shape == w.shape == k.shape == (0, 4)


def test_bad_inputs_raise_with_the_argument_name():
    z, k = np.ones(INTR.shape, np.float32), np.ones(INTR.shape, bool)
    I = RigidTransform.identity()
    with pytest.raises(ShapeError, match="depth_m"):
        warp_depth(z[:-1], z, k, INTR, I)
    with pytest.raises(DTypeError, match="known"):
        warp_depth(z, z, k.astype(np.uint8), INTR, I)
    with pytest.raises(DTypeError, match="depth_m"):
        warp_depth(z.astype(np.int32), z, k, INTR, I)
    with pytest.raises(RangeError, match="weight"):
        warp_depth(z, -z, k, INTR, I)
    with pytest.raises(RangeError, match="weight"):
        warp_depth(z, np.full_like(z, np.nan), k, INTR, I)
    with pytest.raises(InvalidInputError, match="T_cur_from_prev"):
        warp_depth(z, z, k, INTR, np.eye(4))
    with pytest.raises(RangeError, match="max_stretch"):
        warp_depth(z, z, k, INTR, I, max_stretch=0.5)
    with pytest.raises(ShapeError, match="new_depth"):
        merge_depth(z, z, k, z[:, :-1], k)
    with pytest.raises(RangeError, match="max_weight"):
        merge_depth(z, z, k, z, k, max_weight=0.5)
    with pytest.raises(RangeError, match="threshold"):
        merge_depth(z, z, k, z, k, threshold=-0.1)
    with pytest.raises(RangeError, match="occlusion_radius_px"):
        KinectMergeConfig(occlusion_radius_px=-1)
    with pytest.raises(RangeError, match="near_m"):
        KinectMergeConfig(near_m=0.0)
    with pytest.raises(InvalidInputError, match="config"):
        KinectMerger(INTR, config={"max_weight": 3})
    with pytest.raises(InvalidInputError, match="T_world_from_cam"):
        KinectMerger(INTR).step(z, k, "pose")
    with pytest.raises(ShapeError, match="rgb_uint8"):
        kinect_rgbd_frame(z, k, np.zeros((2, 2, 3), np.uint8), I, INTR, 0)


# ------------------------------------------------------------------------------------ RGB-D frame


def test_kinect_rgbd_frame_decodes_srgb_and_enters_reliability_marking():
    rng = np.random.default_rng(2)
    rgb8 = rng.integers(0, 256, (*INTR.shape, 3), dtype=np.uint8)
    depth, _, valid = _render(INTR, RigidTransform.identity(), **SPHERE_SCENE)
    depth[5, 5] = np.nan
    frame = kinect_rgbd_frame(depth, valid, rgb8, _pose(t=(1, 2, 3)), INTR, 123_456)
    assert isinstance(frame, RGBDFrame) and frame.timestamp_ns == 123_456
    np.testing.assert_allclose(frame.rgb, srgb_to_linear(rgb8 / 255.0), atol=1e-6)
    assert not frame.known[5, 5] and frame.depth_m[5, 5] == 0
    np.testing.assert_array_equal(frame.depth_m[frame.known], depth[frame.known])
    reliable = mark_reliable(frame.rgb, frame.depth_m, frame.known)
    assert reliable.shape == INTR.shape and not reliable[~frame.known].any()


def test_merger_outputs_are_independent_of_later_steps():
    depth, _, valid = _render(INTR, RigidTransform.identity(), **SPHERE_SCENE)
    merger = KinectMerger(INTR)
    a = merger.step(depth, valid, RigidTransform.identity())
    keep = a.depth_m.copy(), a.normals.copy()
    for i in range(3):
        merger.step(depth * 1.5, valid, _pose(t=(0.01 * i, 0, 0)))
    np.testing.assert_array_equal(a.depth_m, keep[0])
    np.testing.assert_array_equal(a.normals, keep[1])
    assert not a.depth_m.flags.writeable
    merger.reset()
    assert not merger.has_history
