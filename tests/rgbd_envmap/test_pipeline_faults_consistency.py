"""The map check (rgbd_envmap/pipeline/consistency.py) and the pipeline's use of it after pose jumps.

The probe is compared with a brute-force lookup through :func:`rgbd_envmap.geometry.equirect_pixel_index`
on a map whose surfaces are known in closed form (a sphere around the origin), and the pose
extrapolation with scipy's rotation vectors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rgbd_envmap.envmap.map import EnvironmentMap
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError
from rgbd_envmap.geometry import equirect_pixel_index
from rgbd_envmap.pipeline.config import PoseCheckConfig
from rgbd_envmap.pipeline.consistency import extrapolated_pose, map_consistency, map_residuals
from rgbd_envmap.types import RigidTransform

ORIGIN = np.array([0.5, -0.2, 0.8])


def sphere_map(radius: float = 2.0, h: int = 90, w: int = 180) -> EnvironmentMap:
    """Every pixel valid at ``radius``, except the upper hemisphere's first 10 rows (no data)."""
    depth = np.full((h, w), radius, np.float32)
    valid = np.ones((h, w), bool)
    valid[:10] = False
    return EnvironmentMap.from_arrays(np.full((h, w, 3), 0.5, np.float32), depth, valid, ORIGIN)


def camera(yaw_deg: float = 30.0, at=(0.3, 0.1, -0.1)) -> RigidTransform:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zx", [yaw_deg, -80.0], degrees=True).as_matrix()
    T[:3, 3] = ORIGIN + np.asarray(at)
    return RigidTransform(T, "world", "depth")


def points_at(T: RigidTransform, distances: np.ndarray, rng) -> np.ndarray:
    """Camera-frame points whose world positions lie at ``distances`` from ORIGIN, in random
    directions of the camera's forward hemisphere."""
    dirs = rng.normal(size=(len(distances), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    world = ORIGIN + dirs * distances[:, None]
    cam = (world - T.translation) @ T.rotation  # R^T (p - t), row-wise
    return cam.astype(np.float32)


def test_residuals_match_a_brute_force_lookup():
    rng = np.random.default_rng(0)
    em = sphere_map()
    em.depth_m[:] = rng.uniform(0.5, 4.0, em.depth_m.shape).astype(np.float32)  # every pixel its own distance
    T = camera()
    pts = points_at(T, rng.uniform(0.3, 4.0, 3000), rng)
    pts[5] = np.nan  # not probed
    sampled, d, m = map_residuals(em, pts, T)
    world = pts.astype(np.float64) @ T.rotation.T + T.translation
    finite = np.isfinite(world).all(axis=1)
    rel = world[finite] - ORIGIN
    rows, cols, ok = equirect_pixel_index(rel, em.height, em.width)
    keep = ok & em.valid[rows, cols]
    assert sampled == 2999
    np.testing.assert_allclose(d, np.linalg.norm(rel, axis=1)[keep], rtol=1e-12)
    np.testing.assert_array_equal(m, em.depth_m[rows[keep], cols[keep]].astype(np.float64))
    assert 0 < len(d) < sampled  # the rows without data are not compared


def test_consistent_in_front_and_behind_are_counted_by_closed_form():
    rng = np.random.default_rng(1)
    em = sphere_map(2.0)
    T = camera()
    # On the sphere (within 2 cm + 2 % of 2 m = 6 cm), 20 cm inside, 30 cm outside.
    dist = np.concatenate([np.full(600, 2.0) + rng.uniform(-0.05, 0.05, 600), np.full(300, 1.8), np.full(100, 2.3)])
    pts = points_at(T, dist, rng)
    c = map_consistency(em, pts, T, tol_m=0.02, tol_rel=0.02)
    _, d, _ = map_residuals(em, pts, T)
    lab = np.where(np.abs(d - 2.0) <= 0.06, 0, np.where(d < 2.0, 1, 2))
    assert c.sampled == 1000 and c.compared == len(d)
    assert (c.consistent, c.in_front) == (int((lab == 0).sum()), int((lab == 1).sum()))
    assert c.judged == c.consistent + c.in_front
    assert c.fraction == pytest.approx(c.consistent / c.judged)
    # Every second point: the probe takes a subsample.
    assert map_consistency(em, pts, T, step=2).sampled == 500


def test_a_shifted_pose_misses_the_map_and_the_true_one_fits():
    rng = np.random.default_rng(2)
    em = sphere_map(2.0)
    T = camera()
    pts = points_at(T, np.full(2000, 2.0), rng)
    shifted = T.matrix.copy()
    shifted[:3, 3] += [0.10, -0.05, 0.0]
    right = map_consistency(em, pts, T)
    wrong = map_consistency(em, pts, RigidTransform(shifted, "world", "depth"))
    assert right.consistent == right.compared > 1000
    assert wrong.consistent < 0.6 * right.consistent


def test_empty_and_all_nan_clouds_probe_nothing():
    em = sphere_map()
    for pts in (np.zeros((0, 3), np.float32), np.full((10, 3), np.nan, np.float32)):
        c = map_consistency(em, pts, camera())
        assert (c.sampled, c.compared, c.consistent, c.in_front) == (0, 0, 0, 0) and math.isnan(c.fraction)


@pytest.mark.parametrize("call, error, name", [
    (lambda em, T: map_consistency("map", np.zeros((3, 3)), T), DTypeError, "em"),
    (lambda em, T: map_consistency(em, np.zeros((3, 2)), T), InvalidInputError, "points_m"),
    (lambda em, T: map_consistency(em, np.zeros((3, 3)), np.eye(4)), DTypeError, "T_world_from_cam"),
    (lambda em, T: map_consistency(em, np.zeros((3, 3)), RigidTransform(np.eye(4), "depth", "world")), InvalidInputError,
     "T_world_from_cam"),
    (lambda em, T: map_consistency(em, np.zeros((3, 3)), T, step=0), RangeError, "step"),
    (lambda em, T: map_consistency(em, np.zeros((3, 3)), T, tol_m=-1.0), RangeError, "tol_m"),
    (lambda em, T: map_consistency(em, np.zeros((3, 3)), T, tol_rel=math.nan), RangeError, "tol_rel"),
])
def test_bad_inputs_raise_typed_errors_naming_the_argument(call, error, name):
    with pytest.raises(error, match=name):
        call(sphere_map(), camera())


def test_extrapolation_continues_a_constant_screw_motion():
    step = Rotation.from_rotvec([0.05, -0.02, 0.3])
    a = np.eye(4)
    a[:3, :3] = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    a[:3, 3] = [1.0, 2.0, 0.5]
    b = np.eye(4)
    b[:3, :3] = step.as_matrix() @ a[:3, :3]
    b[:3, 3] = a[:3, 3] + [0.03, -0.01, 0.0]
    for s in (0.0, 0.5, 1.0, 2.5):
        p = extrapolated_pose(a, b, s)
        want = Rotation.from_rotvec(s * step.as_rotvec()).as_matrix() @ b[:3, :3]
        np.testing.assert_allclose(p[:3, :3], want, atol=1e-12)
        np.testing.assert_allclose(p[:3, 3], b[:3, 3] + s * np.array([0.03, -0.01, 0.0]), atol=1e-12)
    np.testing.assert_allclose(extrapolated_pose(b, b, 3.0), b, atol=1e-12)  # at rest: stays
    half_turn = np.eye(4)
    half_turn[:3, :3] = Rotation.from_rotvec([0.0, math.pi, 0.0]).as_matrix()
    np.testing.assert_allclose(extrapolated_pose(np.eye(4), half_turn, 1.0)[:3, :3], np.eye(3), atol=1e-7)
    with pytest.raises(InvalidInputError, match="earlier"):
        extrapolated_pose(np.full((4, 4), np.nan), b, 1.0)


@pytest.mark.parametrize("field, value, error", [
    ("map_check", 1, DTypeError), ("map_check_points", 0, RangeError), ("map_check_points", 2.5, DTypeError),
    ("map_tol_m", -0.01, RangeError), ("map_tol_rel", math.inf, RangeError), ("map_min_compared", 0, RangeError),
    ("map_margin", 1.5, RangeError), ("map_margin", math.nan, RangeError), ("map_accept_after_s", -1.0, RangeError),
    ("map_accept_after_s", "10", DTypeError),
])
def test_map_check_settings_are_checked(field, value, error):
    with pytest.raises(error, match=f"pose_check.{field}"):
        PoseCheckConfig(**{field: value})


def test_map_check_defaults_are_valid_and_none_never_accepts():
    pc = PoseCheckConfig(map_accept_after_s=None)
    assert pc.map_check and pc.map_margin == 0.1 and pc.map_accept_after_s is None


@pytest.mark.parametrize("value, error", [(-1.0, RangeError), (1001.0, RangeError), (math.nan, RangeError), ("50", DTypeError)])
def test_colour_fallback_lag_is_checked(value, error):
    from rgbd_envmap.pipeline.config import PipelineConfig

    with pytest.raises(error, match="colour_fallback_lag_ms"):
        PipelineConfig(colour_fallback_lag_ms=value)
    assert PipelineConfig(colour_fallback_lag_ms=None).colour_fallback_lag_ms is None
