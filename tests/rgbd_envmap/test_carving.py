"""Free-space carving in the map update (rule "freed", envmap.update with ``seen``)."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd_envmap.envmap import EnvironmentMap, SeenDepth, UpdateConfig, update
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import equirect_directions, project_points
from rgbd_envmap.types import Distortion, Intrinsics, RigidTransform

DEVICE = np.array([-0.5, 0.5, 0.0])
STALE = (slice(49, 51), slice(99, 101))  # the 2×2 map pixels around +x at 100×200
ONE = (49, 99)  # one of them


def _pose(position=DEVICE) -> RigidTransform:
    """A camera at ``position`` looking along world +x (camera z = x, camera x = −y, camera y = −z)."""
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    T[:3, 3] = position
    return RigidTransform(T)


def _intr(distortion=Distortion()) -> Intrinsics:
    return Intrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, distortion=distortion)


def _stale_map() -> EnvironmentMap:
    """A 100×200 map whose pixels along +x hold a point 1 m out (grey), the rest empty."""
    em = EnvironmentMap(100, 200)
    em.valid[STALE] = True
    em.depth_m[STALE] = 1.0
    em.radiance_planes[(slice(None), *STALE)] = 0.5
    return em


def _update(em, depth, known=None, config=UpdateConfig(), intr=None, pose=None):
    """One red sample 3 m out along +x (farther than the stored 1 m: "closer" does not hold)."""
    intr = intr or _intr()
    known = np.ones(depth.shape, bool) if known is None else known
    seen = SeenDepth(depth.astype(np.float32), known, intr, pose or _pose())
    return update(em, np.array([[3.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), DEVICE, 50.0, config, seen=seen)


def _stored_z() -> np.ndarray:
    """The stale pixels' points' z-depths in the camera (its z is world x, from DEVICE)."""
    return equirect_directions(100, 200)[STALE][..., 0].ravel() * 1.0 - DEVICE[0]


def test_seen_through_point_is_freed_and_its_depth_replaced():
    em = _stale_map()
    em.record_changes()
    st = _update(em, np.full((48, 64), 3.0))
    assert st.taken == st.taken_freed == 4
    assert st.taken_closer == st.taken_removal == 0
    np.testing.assert_array_equal(em.depth_m[STALE], 3.0)  # replaced, not the mean 2.0
    np.testing.assert_array_equal(em.radiance_planes[0][STALE], 1.0)
    ch = em.take_changes()
    assert len(ch.index) == 4 and ch.was_valid.all()
    np.testing.assert_array_equal(ch.old_radiance, 0.5)


def test_tolerance_boundary():
    cfg = UpdateConfig()
    assert (cfg.carve_tol_rel, cfg.carve_tol_abs_m) == (0.03, 0.02)
    limit = _stored_z() * 1.03 + 0.02  # farther than this: seen through
    em = _stale_map()
    assert _update(em, np.full((48, 64), limit.min() - 1e-5)).taken == 0
    assert em.depth_m[STALE].max() == 1.0
    em = _stale_map()
    assert _update(em, np.full((48, 64), limit.max() + 1e-5)).taken_freed == 4
    cfg = UpdateConfig(carve_tol_rel=0.5, carve_tol_abs_m=0.0)
    assert _update(_stale_map(), np.full((48, 64), limit.max() + 1e-5), config=cfg).taken == 0


def _projected(intr: Intrinsics) -> np.ndarray:
    """(u, v) of map pixel ONE's stored point in the camera of :func:`_pose`."""
    X = _pose().inverse().apply(equirect_directions(100, 200)[ONE][None] * 1.0)
    return project_points(X, intr)[0][0]


@pytest.mark.parametrize("window", [1, 3, 5])
@pytest.mark.parametrize("distortion", [Distortion(), Distortion(k1=0.2, k2=-0.05, p1=0.01, p2=-0.02, k3=0.01)])
def test_the_window_is_where_the_point_projects(distortion, window):
    """A single near (or unmeasured) pixel inside the carving window around the point's projection
    (``UpdateConfig.carve_window``: by default the pixel itself) keeps the point; the same pixel just
    outside it does not. Also checks the kernel's projection (with Brown distortion) against
    geometry.project_points."""
    intr = _intr(distortion)
    u, v = _projected(intr)
    assert min(abs(u % 1 - 0.5), abs(v % 1 - 0.5)) > 0.05  # not on a pixel edge: the test is decisive
    row, col = int(round(v)), int(round(u))
    flat = 49 * 200 + 99
    cfg = UpdateConfig(carve_window=window)
    h = window // 2
    for dr, dc in ((0, 0), (h, -h), (-h, h), (0, h), (h + 1, 0), (0, -h - 1), (-h - 1, h + 1)):
        kept = max(abs(dr), abs(dc)) <= h
        depth = np.full((48, 64), 3.0)
        depth[row + dr, col + dc] = 0.5  # a surface in front of the stored point
        em = _stale_map()
        _update(em, depth, config=cfg, intr=intr)
        assert (em.depth_m.flat[flat] == 1.0) == kept, (dr, dc)
        known = np.ones((48, 64), bool)
        known[row + dr, col + dc] = False  # not measured: no evidence of free space
        em = _stale_map()
        _update(em, np.full((48, 64), 3.0), known, config=cfg, intr=intr)
        assert (em.depth_m.flat[flat] == 1.0) == kept, (dr, dc)


def test_carve_window_must_be_odd_and_small():
    assert UpdateConfig().carve_window == 1
    for bad in (0, -1, 2, 4, 17):
        with pytest.raises((RangeError, InvalidInputError)):
            UpdateConfig(carve_window=bad)


def test_unusable_evidence_frees_nothing():
    depth = np.full((48, 64), 3.0)
    bad = depth.copy()
    bad[:, :] = np.nan
    assert _update(_stale_map(), bad).taken == 0  # NaN depth counts as unmeasured
    assert _update(_stale_map(), depth, np.zeros((48, 64), bool)).taken == 0
    behind = _pose(np.array([2.0, 0.5, 0.0]))  # the stored point is behind this camera
    assert _update(_stale_map(), depth, pose=behind).taken == 0
    aside = _pose().matrix.copy()
    aside[:3, :3] = aside[:3, :3] @ np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # looks 90° sideways
    assert _update(_stale_map(), depth, pose=RigidTransform(aside)).taken == 0  # outside the image


def test_off_or_without_evidence_is_the_paper_update():
    depth = np.full((48, 64), 3.0)
    assert _update(_stale_map(), depth, config=UpdateConfig(carve=False)).taken == 0
    em = _stale_map()
    st = update(em, np.array([[3.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), DEVICE, 50.0)
    assert st.taken == 0 and st.taken_freed == 0


def test_carving_never_empties_or_touches_unhit_pixels():
    em = _stale_map()
    em.valid[10, 10] = True  # a stored pixel no sample reaches
    em.depth_m[10, 10] = 1.0
    before = em.copy()
    _update(em, np.full((48, 64), 3.0))
    assert em.valid[before.valid].all()
    assert em.depth_m[10, 10] == 1.0


def test_bad_evidence_is_refused():
    em = _stale_map()
    with pytest.raises(InvalidInputError):
        _update(em, np.full((47, 64), 3.0), np.ones((47, 64), bool))
    with pytest.raises(RangeError, match="carve_tol_rel"):
        _update(em, np.full((48, 64), 3.0), config=UpdateConfig(carve_tol_rel=-1.0))
    with pytest.raises(RangeError, match="carve_tol_abs_m"):
        _update(em, np.full((48, 64), 3.0), config=UpdateConfig(carve_tol_abs_m=float("nan")))
    np.testing.assert_array_equal(em.depth_m[STALE], 1.0)  # nothing was written


@pytest.mark.parametrize("distortion", [Distortion(), Distortion(k1=0.2, k2=-0.05, p1=0.01, p2=-0.02, k3=0.01)])
def test_row_carving_tests_equal_the_per_pixel_test(distortion):
    """The update tests a row's candidates together (the kernels' _carve_tests: gather, a vectorised
    projection, lookups); it must decide exactly as _is_free does pixel by pixel, for stored points
    in the image, outside it, behind the camera, at the poles and across the seam, and with depths
    that are 0, NaN or huge."""
    from rgbd_envmap._kernels.envmap_update import _carve_tests, _is_free
    from rgbd_envmap.envmap.map_update import _seen_arrays
    from rgbd_envmap.envmap.tables import trig_tables

    rng = np.random.default_rng(3)
    h, w = 90, 180
    rows, cols = trig_tables(h, w)
    origin = np.array([0.1, -0.05, 0.02])
    depth = rng.uniform(1.2, 3.0, (48, 64))  # nearer and farther than the stored points
    depth[rng.random((48, 64)) < 0.02] = np.nan
    seen = SeenDepth(depth.astype(np.float32), rng.random((48, 64)) > 0.02, _intr(distortion), _pose())
    cam, seen_depth = _seen_arrays(seen, UpdateConfig())
    df = rng.uniform(0.1, 1.5, h * w).astype(np.float32)
    df[rng.random(h * w) < 0.02] = 0.0
    df[rng.random(h * w) < 0.02] = np.nan
    df[rng.random(h * w) < 0.01] = 1e30
    buf, flags = np.empty((4, w)), np.zeros(w, np.uint8)
    n_free = n_tested = 0
    for rr in (0, 1, 30, 38, 41, 44, 45, 48, 52, 60, 88, 89):  # the camera sees rows ≈ 33–57, columns ≈ 70–110
        base = rr * w
        pick = np.union1d(rng.choice(w, size=rng.integers(1, w), replace=False), [0, w - 1, *range(70, 110)]).astype(np.int64)
        pick = np.concatenate([pick, [0]])  # a spare slot past the last, as the kernel's list has
        flags[:] = 7
        _carve_tests(len(pick) - 1, pick, flags, rows[rr, 0], rows[rr, 1], cols, df, base, origin, cam, seen_depth, buf)
        expect = [_is_free(rows[rr, 0] * cols[c, 1], rows[rr, 0] * cols[c, 0], rows[rr, 1], df[base + c], origin, cam, seen_depth)
                  for c in pick[:-1]]
        np.testing.assert_array_equal(flags[pick[:-1]], np.where(expect, 3, 0))
        untouched = np.ones(w, bool)
        untouched[pick[:-1]] = False
        assert (flags[untouched] == 7).all()
        n_free += sum(expect)
        n_tested += len(expect) if rr in (38, 41, 44, 45, 48, 52) else 0
    assert n_free > 50 and n_tested - n_free > 50, (n_free, n_tested)  # not vacuous: both decisions, often


def test_seen_arrays_keep_only_measured_finite_positive_depths():
    """_seen_arrays: the frame's depth where known, finite and > 0 (float32, a float64 value beyond
    float32's range becoming inf as numpy's cast makes it), then each pixel's minimum over the
    carving window (numpy's sliding windows, not cv2's erode); the camera rows are T_cam_from_world's."""
    from rgbd_envmap.envmap.map_update import _seen_arrays

    rng = np.random.default_rng(5)
    depth = rng.uniform(0.3, 5.0, (48, 64))
    depth[rng.random((48, 64)) < 0.05] = np.nan
    depth[rng.random((48, 64)) < 0.03] = np.inf
    depth[rng.random((48, 64)) < 0.03] = -1.0
    depth[rng.random((48, 64)) < 0.03] = 0.0
    depth[rng.random((48, 64)) < 0.01] = 1e300
    known = rng.random((48, 64)) > 0.1
    pose = RigidTransform.from_rt(_pose().rotation @ np.array([[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1]]), [0.3, -0.2, 1.1])
    with np.errstate(over="ignore"):
        as_f32 = depth.astype(np.float32)
    for d in (depth, as_f32):
        with np.errstate(invalid="ignore", over="ignore"):
            measured = np.where(known & np.isfinite(d) & (d > 0), d, 0).astype(np.float32)
        for window in (1, 3, 5):
            ref = measured
            if window > 1:  # the window's minimum, 0 where it leaves the image
                ref = np.pad(measured, window // 2)
                ref = np.lib.stride_tricks.sliding_window_view(ref, (window, window)).min(axis=(-2, -1))
            cam, seen_depth = _seen_arrays(SeenDepth(d, known, _intr(), pose), UpdateConfig(carve_window=window))
            assert seen_depth.dtype == np.float32
            np.testing.assert_array_equal(seen_depth, ref)
            np.testing.assert_array_equal(cam[:12], pose.inverse().matrix[:3].reshape(-1))
    huge = SeenDepth(np.full((48, 64), 1e300), np.ones((48, 64), bool), _intr(), pose)
    assert (_seen_arrays(huge, UpdateConfig())[1] == np.inf).all()
    assert (_seen_arrays(huge, UpdateConfig(carve_window=3))[1][1:-1, 1:-1] == np.inf).all()


def test_rule_freed_on_its_own():
    from rgbd_envmap.envmap import rule_freed

    z = 2.0
    limit = np.float32(z * 1.05 + 0.02)  # 2.12
    assert rule_freed(z, float(np.nextafter(limit, np.float32(np.inf))), 0.05, 0.02)
    assert not rule_freed(z, float(limit), 0.05, 0.02)  # strictly beyond the tolerance
    assert not rule_freed(z, 0.0, 0.05, 0.02)  # an unmeasured neighbour
    assert not rule_freed(z, float("nan"), 0.05, 0.02)
    assert rule_freed(z, float("inf"), 0.05, 0.02)
    assert rule_freed(0.5, 0.6, 0.0, 0.0) and not rule_freed(0.5, 0.6, 0.2, 0.0)
