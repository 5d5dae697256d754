"""ToF sensor model against ground truth re-derived independently (fresh ray casts from each point's
own direction, projection through the depth intrinsics)."""

import numpy as np
import pytest

from rgbd_envmap.geometry import look_at, project_points
from rgbd_envmap.types import RigidTransform
from sim.raycast import SceneRaycaster
from sim.scene import FLAG_BITS, load_scene
from sim.tof import ToFConfig, capture_tof

CONFIDENT = 0.7


@pytest.fixture(scope="module")
def office_capture(office):
    rc = SceneRaycaster(office)
    # Towards the window (emissive) past the shelf and the plant (depth edges).
    T = RigidTransform(look_at([0.3, -0.3, 1.2], [-0.5, 2.0, 1.3]).matrix, "world", "depth")
    cfg = ToFConfig()
    return rc, T, cfg, capture_tof(rc, T, 0.0, cfg, np.random.default_rng(3))


def test_points_land_on_true_surfaces_within_noise(office_capture):
    rc, T, cfg, cap = office_capture
    sel = cap.confidence >= CONFIDENT
    pts = cap.points_m[sel].astype(np.float64)
    measured = np.linalg.norm(pts, axis=1)
    dirs_world = T.rotate(pts / measured[:, None])
    truth = rc.cast(T.translation, dirs_world, 0.0).distance_m.astype(np.float64)
    rel_err = np.abs(measured - truth) / truth
    # |N(0, σ)| has median 0.6745 σ; σ = noise_rel × range for clean surfaces.
    assert np.median(rel_err) < cfg.noise_rel
    assert np.median(rel_err) > 0.3 * cfg.noise_rel  # the noise is really there


def test_points_project_to_their_own_pixel(office_capture):
    _, _, cfg, cap = office_capture
    uv, ok = project_points(cap.points_m, cfg.intrinsics)
    assert ok.all()
    rows, cols = np.divmod(cap.pixel_index, cfg.intrinsics.width)
    np.testing.assert_allclose(uv[:, 0], cols, atol=1e-3)
    np.testing.assert_allclose(uv[:, 1], rows, atol=1e-3)


def test_confidence_drops_where_tof_fails(office_capture):
    _, _, _, cap = office_capture
    flags = cap.flags.reshape(-1)[cap.pixel_index]
    mixed = cap.mixed.reshape(-1)[cap.pixel_index]
    assert (flags & FLAG_BITS["emissive"]).any() and mixed.any()
    for bit in FLAG_BITS.values():
        assert np.all(cap.confidence[(flags & bit) != 0] < CONFIDENT)
    assert np.all(cap.confidence[mixed] < CONFIDENT)
    clean = (flags == 0) & ~mixed
    assert np.mean(cap.confidence[clean] >= CONFIDENT) > 0.8
    assert np.all((cap.confidence >= 0) & (cap.confidence <= 1))


def test_grazing_angles_lose_confidence(cube_scene):
    rc = SceneRaycaster(cube_scene)
    # Looking along the floor of the cube from just above it: the floor is seen at grazing angles.
    T = RigidTransform(look_at([-1.9, 0.0, -1.9], [1.9, 0.0, -1.7]).matrix, "world", "depth")
    cap = capture_tof(rc, T, 0.0, ToFConfig(), np.random.default_rng(0))
    on_floor = cap.object_index.reshape(-1)[cap.pixel_index] == 0
    far_floor = on_floor & (np.linalg.norm(cap.points_m, axis=1) > 1.5)
    assert far_floor.sum() > 50
    assert np.mean(cap.confidence[far_floor] < CONFIDENT) > 0.9


def test_range_limits_drop_points(cube_scene):
    rc = SceneRaycaster(cube_scene)
    T = RigidTransform(look_at([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]).matrix, "world", "depth")
    cfg = ToFConfig(max_range_m=1.0)
    cap = capture_tof(rc, T, 0.0, cfg, np.random.default_rng(0))
    assert len(cap.points_m) == 0  # every wall is ≥ 2 m away
    assert not cap.true_valid.any()


def test_empty_scene_and_device_inside_a_wall_give_valid_packets(office):
    rng = np.random.default_rng(0)
    cap = capture_tof(SceneRaycaster(load_scene("empty")), RigidTransform.identity(), 0.0, ToFConfig(), rng)
    assert cap.points_m.shape == (0, 3) and cap.confidence.shape == (0,)
    # Inside the dark cabinet (a closed box 0.6 m wide): every return is on its inner faces.
    cab = office.object("dark_cabinet").vertices.mean(axis=0)
    T = RigidTransform(look_at(cab, cab + [1.0, 0.0, 0.0]).matrix, "world", "depth")
    cap = capture_tof(SceneRaycaster(office), T, 0.0, ToFConfig(), rng)
    assert np.isfinite(cap.points_m).all()
    assert np.all(np.linalg.norm(cap.points_m, axis=1) < 1.0)
    assert np.all(cap.confidence < CONFIDENT)  # a very dark surface


def test_same_seed_same_capture(office_capture):
    rc, T, cfg, cap = office_capture
    again = capture_tof(rc, T, 0.0, cfg, np.random.default_rng(3))
    other = capture_tof(rc, T, 0.0, cfg, np.random.default_rng(4))
    np.testing.assert_array_equal(again.points_m, cap.points_m)
    assert not np.array_equal(other.points_m, cap.points_m)
