"""Kinect-like sensor model against closed forms and ground truth re-derived independently (Nguyen's
formula written out here, fresh closest-hit casts from the projector, geometry of a box before a wall).

Small cameras (``with_resolution``) keep each capture to a few tens of milliseconds.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rgbd_envmap.colour import linear_to_srgb
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import look_at, pixel_rays
from rgbd_envmap.tum import read_tum_sequence, write_tum_sequence
from rgbd_envmap.types import Distortion, RigidTransform
from sim.kinect import (
    DROPOUT_BITS,
    KinectConfig,
    KinectSimulator,
    capture_kinect_depth,
    nguyen_axial_sigma_m,
    nguyen_lateral_sigma_px,
)
from sim.raycast import SceneRaycaster
from sim.scene import load_scene, scene_from_dict
from sim.trajectory import OrbitTrajectory, WaypointTrajectory
from tests.sim.helpers import box_room

FB = 580.0 * 0.075  # disparity focal length × baseline, px·m


def cam(eye, target) -> RigidTransform:
    return RigidTransform(look_at(eye, target).matrix, "world", "colour")


def bit(cap, name: str) -> np.ndarray:
    return (cap.dropout & DROPOUT_BITS[name]) != 0


def nguyen_sigma(z, theta):
    """Nguyen et al. 2012, eqs. 5–6, written out independently of sim.kinect."""
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    steep = theta > np.radians(60.0)
    t = np.minimum(theta, np.radians(89.0))
    return sigma + np.where(steep, 0.0001 / np.sqrt(z) * t**2 / (np.pi / 2 - t) ** 2, 0.0)


def incidence(cap, intr) -> np.ndarray:
    """Camera incidence angle per pixel from the true camera-frame normals."""
    rays = pixel_rays(intr)
    d = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    return np.arccos(np.clip(np.abs(np.sum(cap.true_normals_cam * d, axis=-1)), 0.0, 1.0))


def plane_scene(distance: float, yaw_deg: float, flags=()) -> dict:
    """A 12 m × 12 m quad through (0, distance, 0), turned ``yaw_deg`` about the vertical."""
    a = np.radians(yaw_deg)
    u = np.array([np.cos(a), np.sin(a), 0.0]) * 12.0
    v = np.array([0.0, 0.0, 12.0])
    corner = np.array([0.0, distance, 0.0]) - u / 2 - v / 2
    obj = {"name": "plane", "shape": "quad", "corner": corner.tolist(), "u": u.tolist(), "v": v.tolist(),
           "radiance": [0.4, 0.4, 0.4], "flags": list(flags)}
    return {"name": "plane", "objects": [obj]}


@pytest.fixture(scope="module")
def box_before_wall():
    """Camera at the origin looking along +y; a 30 cm cube 1.05–1.35 m away, centred; a wall at 2.5 m."""
    wall = {"name": "wall", "shape": "quad", "corner": [-5, 2.5, -5], "u": [10, 0, 0], "v": [0, 0, 10], "radiance": [0.5, 0.5, 0.5]}
    box = {"name": "box", "shape": "box", "centre": [0.0, 1.2, 0.0], "size": [0.3, 0.3, 0.3], "radiance": [0.3, 0.2, 0.1]}
    rc = SceneRaycaster(scene_from_dict({"name": "box_wall", "objects": [wall, box]}))
    cfg = KinectConfig(lateral_noise=False).with_resolution(320, 240)
    T = cam([0, 0, 0], [0, 1, 0])
    return rc, cfg, T, capture_kinect_depth(rc, T, 0.0, cfg, np.random.default_rng(0))


# --- depth noise -------------------------------------------------------------------------------------


@pytest.mark.parametrize("z0", [1.0, 3.0])
def test_axial_noise_matches_nguyen(z0):
    rc = SceneRaycaster(scene_from_dict(plane_scene(z0, 25.0)))
    cfg = KinectConfig().with_resolution(320, 240)
    T = cam([0, 0, 0], [0, 1, 0])
    residuals = []
    for seed in range(3):
        cap = capture_kinect_depth(rc, T, 0.0, cfg, np.random.default_rng(seed))
        z = cap.true_depth_m.astype(np.float64)
        sel = cap.known & (np.abs(z - z0) < 0.1 * z0)
        theta = incidence(cap, cfg.intrinsics)[sel]
        residuals.append((cap.depth_m[sel] - z[sel]) / nguyen_sigma(z[sel], theta))
    r = np.concatenate(residuals)
    assert r.size > 20_000
    # Noise + 1/8 px disparity quantisation + 1 mm rounding together have Nguyen's σ_z (see module doc).
    assert np.std(r) == pytest.approx(1.0, abs=0.05)
    assert abs(np.mean(r)) < 0.1  # a fixed pattern of the 1 mm rounding leaves ≈ 0.03 σ at 1 m
    # σ_z itself: 1.88 mm at 1 m, 14.0 mm at 3 m.
    assert nguyen_sigma(z0, 0.0) == pytest.approx({1.0: 0.001884, 3.0: 0.014044}[z0], rel=1e-6)


def test_depth_lies_on_the_disparity_grid():
    rc = SceneRaycaster(scene_from_dict(plane_scene(2.0, 30.0)))
    cfg = dataclasses.replace(KinectConfig(), depth_unit_m=None).with_resolution(160, 120)
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, 1, 0]), 0.0, cfg, np.random.default_rng(1))
    steps = 8.0 * FB / cap.depth_m[cap.known].astype(np.float64)  # disparity in 1/8 px
    assert np.max(np.abs(steps - np.rint(steps))) < 1e-3
    # Without noise a tilted plane is a staircase: every step between its nearest and farthest depth.
    quiet = dataclasses.replace(cfg, axial_noise=False)
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, 1, 0]), 0.0, quiet, np.random.default_rng(1))
    k = np.unique(np.rint(8.0 * FB / cap.depth_m[cap.known].astype(np.float64)))
    assert len(k) > 20 and np.all(np.diff(k) == 1)
    z = cap.true_depth_m.astype(np.float64)[cap.known]
    np.testing.assert_allclose(cap.depth_m[cap.known], FB / (np.rint(FB / z / 0.125) * 0.125), rtol=1e-6)


def test_fronto_parallel_wall_without_noise_is_one_quantised_value():
    rc = SceneRaycaster(scene_from_dict(plane_scene(2.01, 0.0)))
    cfg = dataclasses.replace(KinectConfig(), axial_noise=False).with_resolution(64, 48)
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, 1, 0]), 0.0, cfg, np.random.default_rng(0))
    # 43.5 / 2.01 = 21.642 px → 173 eighths → 21.625 px → 2.011561 m → 2.012 m after the 1 mm rounding.
    assert cap.known.all()
    assert np.all(cap.depth_m == np.float32(2.012))
    np.testing.assert_allclose(cap.true_depth_m, 2.01, rtol=1e-6)
    np.testing.assert_allclose(cap.true_normals_cam.reshape(-1, 3), [[0.0, 0.0, -1.0]] * cap.known.size, atol=1e-6)


# --- holes -------------------------------------------------------------------------------------------


def test_projector_shadow_falls_opposite_the_projector(box_before_wall):
    _, cfg, _, cap = box_before_wall
    intr = cfg.intrinsics
    shadow = bit(cap, "shadow")
    assert shadow.any()
    # Closed form on the wall (y = 2.5): the box's front-left edge (x = −0.15, y = 1.05) hides the wall
    # from the camera up to x = −0.15·2.5/1.05 and from the projector (x = +0.075) up to
    # x = 0.075 − 0.225·2.5/1.05. The visible shadow lies between, left of the box (opposite the projector).
    x_cam, x_proj = -0.15 * 2.5 / 1.05, 0.075 - 0.225 * 2.5 / 1.05
    u_lo, u_hi = intr.fx * x_proj / 2.5 + intr.cx, intr.fx * x_cam / 2.5 + intr.cx
    rows = slice(int(intr.cy) - 10, int(intr.cy) + 10)  # well inside the box's vertical extent
    cols = np.arange(intr.width)
    on_wall = cap.object_index[rows] == 0
    inside = (cols > u_lo + 1) & (cols < u_hi - 1)
    outside = (cols < u_lo - 1) | (cols > u_hi + 1)
    assert np.all(shadow[rows][on_wall & inside[None, :]])
    assert not np.any(shadow[rows][on_wall & outside[None, :]])
    assert not shadow[:, int(intr.cx):].any()  # nothing on the projector's side
    assert u_hi - u_lo > 8  # ~10.8 px at this resolution


def test_shadow_bit_equals_independent_visibility_from_projector(box_before_wall):
    rc, cfg, T, cap = box_before_wall
    rays = pixel_rays(cfg.intrinsics).reshape(-1, 3)
    valid = cap.true_valid.reshape(-1)
    p_world = T.apply(rays[valid] * cap.true_depth_m.reshape(-1)[valid, None].astype(np.float64))
    projector = T.apply(np.array([0.075, 0.0, 0.0]))
    to_p = p_world - projector
    dist = np.linalg.norm(to_p, axis=1)
    hits = rc.cast(projector, (to_p / dist[:, None]).astype(np.float32), 0.0)  # closest hit, not test_occlusions
    seen = hits.distance_m >= dist - 0.003
    shadow = bit(cap, "shadow").reshape(-1)[valid]
    disagree = np.flatnonzero(seen == shadow)
    assert len(disagree) <= 2, disagree  # at most a grazing pixel on the box's silhouette
    assert (~seen).sum() > 50


def test_edges_drop_both_sides_of_a_discontinuity(box_before_wall):
    cap = box_before_wall[3]
    z = np.where(cap.true_valid, cap.true_depth_m, np.inf).astype(np.float64)
    jump = np.zeros(z.shape, bool)
    for ax in (0, 1):
        a, b = np.moveaxis(z, ax, 0)[1:], np.moveaxis(z, ax, 0)[:-1]
        j = np.abs(a - b) > 0.05 * np.minimum(a, b)
        np.moveaxis(jump, ax, 0)[1:] |= j
        np.moveaxis(jump, ax, 0)[:-1] |= j
    edge = bit(cap, "edge")
    assert jump.sum() > 100 and np.array_equal(edge, jump)  # lateral noise off: exactly the 1-px rim
    clean = ~jump & ~bit(cap, "shadow") & cap.true_valid
    assert np.all(cap.known[clean])


def test_lateral_noise_jitters_edges_only(box_before_wall):
    rc, cfg, T, still = box_before_wall
    cfg = dataclasses.replace(cfg, lateral_noise=True)
    a, b = (capture_kinect_depth(rc, T, 0.0, cfg, np.random.default_rng(s)) for s in (0, 1))
    assert (bit(a, "edge") != bit(b, "edge")).sum() > 20  # the rim of the holes is ragged and differs per frame
    assert (bit(a, "edge") != bit(still, "edge")).sum() > 20
    # Away from edges (beyond the 2 px zone plus the 3 px largest offset) pixels keep their own surface.
    edge = bit(still, "edge")
    near = np.zeros_like(edge)
    for dv in range(-6, 7):
        for du in range(-6, 7):
            near |= np.roll(np.roll(edge, dv, axis=0), du, axis=1)
    far = a.known & ~near
    z = a.true_depth_m.astype(np.float64)[far]
    assert np.all(np.abs(a.depth_m[far] - z) < 6 * nguyen_sigma(z, 0.0) + 0.002)


def test_jittered_pixels_measure_their_source_surface():
    # A box turned 40° before a wall turned the other way: depth changes along every row, so a
    # measurement taken from any pixel other than the reported source would not match.
    wall = {"name": "wall", "shape": "box", "centre": [0, 2.6, 0], "size": [8, 0.1, 8], "yaw_deg": -25, "radiance": [0.5] * 3}
    box = {"name": "box", "shape": "box", "centre": [0.0, 1.2, 0.0], "size": [0.4, 0.4, 0.4], "yaw_deg": 40, "radiance": [0.3] * 3}
    rc = SceneRaycaster(scene_from_dict({"name": "bw", "objects": [wall, box]}))
    cfg = dataclasses.replace(KinectConfig(), axial_noise=False, depth_unit_m=None).with_resolution(320, 240)
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, 1, 0]), 0.0, cfg, np.random.default_rng(7))
    src = cap.source_index
    moved = src != np.arange(src.size).reshape(src.shape)
    assert moved.sum() > 200 and (cap.known & moved).sum() > 50
    z_src = cap.true_depth_m.reshape(-1)[src].astype(np.float64)
    want = FB / (np.rint(FB / z_src / 0.125) * 0.125)
    np.testing.assert_allclose(cap.depth_m[cap.known], want[cap.known], rtol=1e-6)
    rows, cols = np.divmod(src, src.shape[1])
    r0, c0 = np.indices(src.shape)
    assert np.abs(rows - r0).max() <= 3 and np.abs(cols - c0).max() <= 3


@pytest.mark.parametrize("flag", ["dark", "shiny", "emissive"])
def test_material_flags_drop_pixels(flag):
    panel = {"name": "panel", "shape": "quad", "corner": [-0.5, 1.9, -0.5], "u": [1.0, 0, 0], "v": [0, 0, 1.0],
             "radiance": [0.2] * 3, "flags": [flag]}
    rc = SceneRaycaster(scene_from_dict(box_room(extra=[panel])))
    T = cam([0, 0, 0], [0, 1, 0])
    base = KinectConfig(lateral_noise=False, specular_cone_deg=0.0).with_resolution(160, 120)
    on_panel = None
    for p in (0.0, 0.5, 1.0):
        cfg = dataclasses.replace(base, **{f"{flag}_dropout": p})
        cap = capture_kinect_depth(rc, T, 0.0, cfg, np.random.default_rng(3))
        if on_panel is None:
            on_panel = (cap.object_index == 6) & ~bit(cap, "edge") & ~bit(cap, "shadow")
            assert on_panel.sum() > 1000
        dropped = bit(cap, flag)[on_panel]
        assert dropped.mean() == pytest.approx(p, abs=0.05)
        assert not np.any(bit(cap, flag)[cap.object_index != 6])
        assert np.array_equal(cap.known[on_panel], ~dropped)


def test_specular_cone_on_shiny_surfaces():
    rc = SceneRaycaster(scene_from_dict(plane_scene(1.5, 0.0, flags=["shiny"])))
    cfg = KinectConfig(shiny_dropout=0.0, specular_cone_deg=5.0).with_resolution(160, 120)
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, 1, 0]), 0.0, cfg, np.random.default_rng(0))
    rays = pixel_rays(cfg.intrinsics)
    p = rays * cap.true_depth_m[..., None]
    to_cam = -p / np.linalg.norm(p, axis=-1, keepdims=True)
    to_proj = np.array([0.075, 0, 0]) - p
    to_proj /= np.linalg.norm(to_proj, axis=-1, keepdims=True)
    half = to_cam + to_proj
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(-half[..., 2], -1, 1)))  # the wall's normal is −z in the camera
    shiny = bit(cap, "shiny")
    assert np.all(shiny[angle < 4.9]) and not np.any(shiny[angle > 5.1])
    assert 50 < shiny.sum() < 0.5 * shiny.size


def test_grazing_dropout_follows_the_incidence_ramp(cube_scene):
    rc = SceneRaycaster(cube_scene)
    cfg = KinectConfig(lateral_noise=False).with_resolution(320, 240)
    T = cam([-1.9, 0.0, -1.8], [1.9, 0.0, -2.6])  # 20 cm above the floor, looking along it
    cap = capture_kinect_depth(rc, T, 0.0, cfg, np.random.default_rng(2))
    floor = (cap.object_index == 0) & cap.true_valid & ~bit(cap, "edge")
    theta_cam = np.degrees(incidence(cap, cfg.intrinsics))
    rays = pixel_rays(cfg.intrinsics)
    p = rays * cap.true_depth_m[..., None]
    to_proj = np.array([0.075, 0, 0]) - p
    cos_proj = np.abs(np.sum(cap.true_normals_cam * to_proj, axis=-1)) / np.linalg.norm(to_proj, axis=-1)
    theta = np.maximum(theta_cam, np.degrees(np.arccos(np.clip(cos_proj, 0, 1))))
    graze = bit(cap, "grazing")
    assert np.all(graze[floor & (theta > 85.0)]) and (floor & (theta > 85.0)).sum() > 100
    assert not np.any(graze[floor & (theta < 70.0)]) and (floor & (theta < 70.0)).sum() > 1000
    ramp = floor & (theta > 70.0) & (theta < 85.0)
    expected = np.sum((theta[ramp] - 70.0) / 15.0)
    n_sigma = np.sqrt(np.sum(((theta[ramp] - 70.0) / 15.0) * (1 - (theta[ramp] - 70.0) / 15.0)))
    assert abs(graze[ramp].sum() - expected) < 4 * n_sigma + 5


def test_range_limits(cube_scene):
    rc = SceneRaycaster(cube_scene)
    T = cam([0, 0, 0], [1, 0, 0])  # walls 2 m away
    cap = capture_kinect_depth(rc, T, 0.0, KinectConfig(max_depth_m=1.5).with_resolution(64, 48), np.random.default_rng(0))
    assert not cap.known.any() and bit(cap, "range").all() and not cap.true_valid.any()
    assert np.all(cap.depth_m == 0) and np.all(cap.true_depth_m == 0)
    near = cam([1.7, 0, 0], [2, 0, 0])  # 30 cm from the wall
    cap = capture_kinect_depth(rc, near, 0.0, KinectConfig().with_resolution(64, 48), np.random.default_rng(0))
    assert not cap.known.any() and bit(cap, "range").all()


def test_nothing_in_view():
    rc = SceneRaycaster(scene_from_dict(plane_scene(2.0, 0.0)))
    cap = capture_kinect_depth(rc, cam([0, 0, 0], [0, -1, 0]), 0.0, KinectConfig().with_resolution(32, 24), np.random.default_rng(0))
    assert not cap.known.any() and bit(cap, "no_surface").all()
    assert not cap.true_valid.any() and np.all(cap.true_normals_cam == 0) and np.all(cap.object_index == -1)


# --- the simulator -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_sim():
    cfg = KinectConfig().with_resolution(160, 120)
    traj = OrbitTrajectory(facing="inward", radius_m=1.2, height_m=0.4, period_s=4.0)
    return load_scene("office_unlit"), traj, cfg


def test_same_seed_same_frames_other_seed_other_noise(small_sim):
    scene, traj, cfg = small_sim
    a = list(KinectSimulator(scene, traj, cfg, seed=4).run(0.1))
    b = list(KinectSimulator(scene, traj, cfg, seed=4).run(0.1))
    c = list(KinectSimulator(scene, traj, cfg, seed=5).run(0.1))
    assert len(a) == 3
    for fa, fb in zip(a, b):
        for f in dataclasses.fields(fa):
            x, y = getattr(fa, f.name), getattr(fb, f.name)
            assert np.array_equal(x.matrix, y.matrix) if isinstance(x, RigidTransform) else np.array_equal(x, y), f.name
    assert not np.array_equal(a[1].depth_m, c[1].depth_m)
    assert np.array_equal(a[1].true_depth_m, c[1].true_depth_m)


def test_frames_timestamps_and_fields(small_sim):
    scene, traj, cfg = small_sim
    sim = KinectSimulator(scene, traj, cfg, seed=0, start_ns=5_000_000_000)
    assert sim.schedule(1.0)[:3] == [5_000_000_000, 5_033_333_000, 5_066_667_000] and len(sim.schedule(1.0)) == 30
    frames = list(sim.run(0.07))
    assert [f.index for f in frames] == [0, 1, 2]
    f = frames[1]
    h, w = 120, 160
    assert f.rgb.shape == (h, w, 3) and f.rgb.dtype == np.uint8
    assert f.depth_m.shape == (h, w) and f.depth_m.dtype == np.float32 and f.known.dtype == bool
    assert np.all(f.depth_m[~f.known] == 0) and np.all(f.depth_m[f.known] > 0)
    assert np.array_equal(f.known, f.dropout == 0)
    assert f.true_normals_cam.shape == (h, w, 3) and f.gains.shape == (3,)
    np.testing.assert_allclose(np.linalg.norm(f.true_normals_cam[f.true_valid], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(f.true_T_world_from_cam.matrix, traj.pose(f.t_s).matrix, atol=1e-12)
    assert f.T_world_from_cam == f.true_T_world_from_cam  # no tracking noise by default
    assert (f.T_world_from_cam.dst, f.T_world_from_cam.src) == ("world", "colour")
    err = np.abs(f.depth_m - f.true_depth_m)[f.known]
    assert np.median(err) < 0.01 and f.known.mean() > 0.5
    assert sim.calibration.sensor == "kinect" and sim.calibration.depth == cfg.intrinsics


def test_colour_is_the_exposed_radiance_of_the_same_pixels(small_sim):
    scene, traj, cfg = small_sim
    fixed = dataclasses.replace(cfg, colour=dataclasses.replace(cfg.colour, auto_exposure=False, auto_white_balance=False))
    f = next(iter(KinectSimulator(scene, traj, fixed).run(0.01)))
    np.testing.assert_array_equal(f.gains, [1.0, 1.0, 1.0])
    want = np.round(linear_to_srgb(np.clip(f.radiance, 0.0, 1.0).astype(np.float64)) * 255.0)
    diff = np.abs(f.rgb.astype(np.float64) - want)
    assert np.median(diff) <= 2.0 and np.mean(diff) < 3.0  # shot + read noise only
    frames = list(KinectSimulator(scene, traj, cfg).run(0.2))  # auto-exposure moves the gains
    assert not np.allclose(frames[0].gains, frames[-1].gains)


def test_tracking_noise_only_in_the_reported_pose(small_sim):
    scene, traj, cfg = small_sim
    noisy = dataclasses.replace(cfg, tracking_noise_m=0.01, tracking_noise_deg=0.5)
    f = next(iter(KinectSimulator(scene, traj, noisy).run(0.01)))
    d = np.linalg.norm(f.T_world_from_cam.translation - f.true_T_world_from_cam.translation)
    assert 1e-4 < d < 0.1


def test_simulated_run_replays_through_tum(small_sim, tmp_path):
    scene, traj, cfg = small_sim
    frames = list(KinectSimulator(scene, traj, cfg, seed=2).run(0.1))
    assert write_tum_sequence(tmp_path / "seq", frames, cfg.intrinsics) == 3
    seq = read_tum_sequence(tmp_path / "seq", max_dt_s=0.0)
    assert len(seq) == 3 and seq.intrinsics == cfg.intrinsics
    for a, b in zip(frames, seq):
        assert b.timestamp_ns == a.timestamp_ns and np.array_equal(b.rgb, a.rgb) and np.array_equal(b.known, a.known)
        np.testing.assert_allclose(b.depth_m, a.depth_m, rtol=0, atol=1e-7)  # millimetres fit 1/5000 m exactly
        np.testing.assert_allclose(b.T_world_from_cam.matrix, a.T_world_from_cam.matrix, atol=1e-12)


def test_waypoint_trajectory_moves_the_camera(cube_scene):
    traj = WaypointTrajectory((0.0, 1.0), ((0, 0, 0), (0.5, 0, 0)), ((0, 1, 0), (0.5, 1, 0)))
    frames = list(KinectSimulator(cube_scene, traj, KinectConfig().with_resolution(32, 24)).run(1.0))
    assert len(frames) == 30
    np.testing.assert_allclose(frames[15].true_T_world_from_cam.translation, [0.25, 0, 0], atol=1e-9)


def test_public_noise_formulas():
    z = np.linspace(0.4, 4.5, 50)[:, None]
    theta = np.radians(np.linspace(0.0, 88.0, 45))[None, :]
    np.testing.assert_allclose(nguyen_axial_sigma_m(z, theta), nguyen_sigma(z, theta), rtol=1e-12)
    np.testing.assert_allclose(nguyen_lateral_sigma_px(np.radians([0.0, 45.0])), [0.8, 0.835], rtol=1e-12)


def test_config_validation():
    cfg = KinectConfig()
    assert cfg.intrinsics.fx == 525.0 and (cfg.intrinsics.cx, cfg.intrinsics.cy) == (319.5, 239.5)
    assert cfg.colour.intrinsics.fx == pytest.approx(525.0, rel=1e-12) and cfg.colour.distortion.is_zero
    small = cfg.with_resolution(160, 120)
    assert small.intrinsics.fx == 131.25 and small.intrinsics.cx == 79.5 and small.colour.width == 160
    with pytest.raises(InvalidInputError, match="with_resolution"):
        dataclasses.replace(cfg, intrinsics=small.intrinsics)
    with pytest.raises(InvalidInputError, match="undistorted"):
        dataclasses.replace(cfg, intrinsics=dataclasses.replace(cfg.intrinsics, distortion=Distortion(0.1)))
    with pytest.raises(RangeError, match="projector_baseline_m"):
        KinectConfig(projector_baseline_m=0.0)
    with pytest.raises(RangeError, match="max_depth_m"):
        KinectConfig(min_depth_m=2.0, max_depth_m=1.0)
    with pytest.raises(RangeError, match="dropout"):
        KinectConfig(dark_dropout=1.5)
    with pytest.raises(RangeError, match="grazing"):
        KinectConfig(grazing_start_deg=80.0, grazing_stop_deg=70.0)
    with pytest.raises(InvalidInputError, match="start_ns"):
        KinectSimulator(load_scene("empty"), OrbitTrajectory(), cfg, start_ns=1)
