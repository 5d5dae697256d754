"""Reference composites: the path-traced pair (with and without the virtual object) and the run
folder's ``reference/`` with the composite metrics."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from rgbd_envmap.geometry import look_at
from rgbd_envmap.types import Intrinsics
from sim.mitsuba_scene import ExtraMesh
from sim.raycast import SceneRaycaster
from sim.reference import render_reference_pair
from sim.scene import scene_from_dict

pytestmark = pytest.mark.slow

_ROOM = {
    "name": "reference_room",
    "virtual_object_position": [0.0, 0.0, 0.80],
    "default_trajectory": "orbit_inward",
    "objects": [
        {"name": "floor", "shape": "quad", "corner": [-1.6, -1.6, 0.0], "u": [3.2, 0, 0], "v": [0, 3.2, 0], "albedo": [0.5, 0.5, 0.5]},
        {"name": "ceiling", "shape": "quad", "corner": [-1.6, -1.6, 2.4], "u": [3.2, 0, 0], "v": [0, 3.2, 0], "albedo": [0.7, 0.7, 0.7]},
        {"name": "south", "shape": "quad", "corner": [-1.6, -1.6, 0.0], "u": [3.2, 0, 0], "v": [0, 0, 2.4], "albedo": [0.6, 0.5, 0.4]},
        {"name": "north", "shape": "quad", "corner": [-1.6, 1.6, 0.0], "u": [3.2, 0, 0], "v": [0, 0, 2.4], "albedo": [0.4, 0.5, 0.6]},
        {"name": "west", "shape": "quad", "corner": [-1.6, -1.6, 0.0], "u": [0, 3.2, 0], "v": [0, 0, 2.4], "albedo": [0.5, 0.6, 0.5]},
        {"name": "east", "shape": "quad", "corner": [1.6, -1.6, 0.0], "u": [0, 3.2, 0], "v": [0, 0, 2.4], "albedo": [0.6, 0.6, 0.6]},
        {"name": "table", "shape": "box", "centre": [0.0, 0.0, 0.375], "size": [1.0, 1.0, 0.75], "albedo": [0.7, 0.65, 0.6]},
        {"name": "lamp", "shape": "quad", "corner": [-0.3, -0.3, 2.39], "u": [0.6, 0, 0], "v": [0, 0.6, 0],
         "albedo": [0.5, 0.5, 0.5], "emission": [6.0, 6.0, 6.0]},
    ],
}


def _cube(centre, size):
    c = np.asarray(centre, float)
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float) - 0.5
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    return c + size * v, f


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    scene = scene_from_dict(_ROOM)
    caster = SceneRaycaster(scene, cache_dir=tmp_path_factory.mktemp("bake"))
    return scene, caster


def test_pair_shows_the_object_and_its_shadow_and_nothing_far_away(room):
    scene, caster = room
    verts, faces = _cube([0.0, 0.0, 0.85], 0.2)
    obj = ExtraMesh("cube", verts, faces, np.array([0.6, 0.6, 0.6]))
    intr = Intrinsics(96, 72, 70.0, 70.0, 47.5, 35.5)
    pose = look_at(np.array([0.0, -1.3, 1.6]), np.array([0.0, 0.0, 0.75]))
    pair = render_reference_pair(scene, pose, intr, 0.0, obj, spp=64, radius_m=0.6, raycaster=caster, method="path")
    hits = caster.cast(*_rays(pose, intr), 0.0, normals=False)
    # Outside the traced region both frames are the bake, exactly.
    out = ~pair.traced.ravel()
    assert out.any() and pair.traced.any()
    for frame in (pair.with_object, pair.without_object):
        assert np.array_equal(frame.reshape(-1, 3)[out], hits.radiance[out])
    # The object's pixels: where the cube is nearer than the scene (open3d on the cube alone, here by
    # the slab test of an axis-aligned box).
    origin, dirs = _rays(pose, intr)
    lo, hi = verts.min(0), verts.max(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - origin) / dirs, (hi - origin) / dirs
    tnear = np.minimum(t0, t1).max(1)
    tfar = np.maximum(t0, t1).min(1)
    inside = (tnear <= tfar) & (tfar > 0) & (tnear < hits.distance_m)
    assert np.array_equal(pair.object_mask.ravel(), inside)
    # The lamp is straight above: the table top right around the cube is darker with it.
    top = (hits.object_index == [o.name for o in scene.objects].index("table")) & ~inside
    point = origin + dirs * hits.distance_m[:, None]
    ring = top & (np.abs(point[:, 0]) < 0.16) & (point[:, 1] > -0.16) & (point[:, 1] < 0.0)
    far = top & (np.hypot(point[:, 0], point[:, 1]) > 0.4) & pair.traced.ravel()
    w, wo = pair.with_object.reshape(-1, 3), pair.without_object.reshape(-1, 3)
    assert ring.sum() > 20 and far.sum() > 20
    assert w[ring].mean() < 0.93 * wo[ring].mean()  # a penumbra 0–6 cm from the cube: about 14 % darker
    assert abs(w[far].mean() / wo[far].mean() - 1) < 0.02
    # The two halves' spread is a standard error: far smaller than the values, not zero.
    traced = pair.traced.ravel()
    rel = pair.noise_without.reshape(-1, 3)[traced].mean() / wo[traced].mean()
    assert 0.001 < rel < 0.5


def _rays(pose, intr):
    from sim.reference import camera_rays

    return camera_rays(pose, intr)


def test_simulate_writes_reference_frames_and_composite_metrics(tmp_path):
    scene_file = tmp_path / "room.yaml"
    scene_file.write_text(yaml.safe_dump(_ROOM))
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "apps.cli", "simulate", "--scene", str(scene_file), "--duration", "4.2",
           "--out", str(out), "--colour-size", "160x90", "--reference-every", "2", "--reference-spp", "8",
           "--no-video", "--quiet", "--cache-dir", str(tmp_path / "cache")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    accuracy = json.loads((out / "accuracy.json").read_text())
    assert accuracy["composite_reference_frames"] == 2
    for key in ("composite_rel_rmse", "composite_object_rel_rmse", "composite_shadow_rel_rmse"):
        assert accuracy[key] is not None and 0 <= accuracy[key] < 1.5, (key, accuracy[key])
    # the noise-corrected errors: the raw ones with the reference's own noise taken out, region by region
    for region in ("", "object_", "shadow_"):
        raw, noise = accuracy[f"composite_{region}rel_rmse"], accuracy[f"composite_{region}reference_noise_rel"]
        corrected = accuracy[f"composite_{region}rel_rmse_noise_corrected"]
        assert noise > 0 and 0 <= corrected <= raw
        assert corrected ** 2 == pytest.approx(max(raw ** 2 - noise ** 2, 0.0), rel=1e-9, abs=1e-12)
    frames = sorted((out / "reference").glob("*.npz"))
    assert len(frames) == 2 and len(list((out / "reference").glob("*.png"))) == 2
    times = []
    for path in frames:
        with np.load(path) as z:
            assert z["with_object"].shape == (90, 160, 3) and z["object_mask"].any()
            assert np.isfinite(z["ours"][z["valid"]].astype(np.float32)).all()
            times.append(float(z["t_s"]))
    # The first colour frame at or after 2 s and after 4 s (colour at 30 Hz).
    assert 2.0 <= times[0] < 2.0 + 1 / 29 and 4.0 <= times[1] < 4.0 + 1 / 29
    run = json.loads((out / "run.json").read_text())
    assert run["reference_frames"] == 2 and run["reference_spp"] == 8
    assert "composite_rel_rmse" in (out / "timing.md").read_text()


def _sphere_over_floor(scene, texel_m, sphere, centre, intr, eye, *, spp, radius_m):
    """The reference pair of a black ``sphere`` mesh at ``centre`` over ``scene``'s floor (object 0),
    seen from ``eye`` looking at the origin: (pair, each pixel's scene point (N, 3), the floor
    pixels the gather changed (N,) bool)."""
    from sim.bake import BakeConfig

    caster = SceneRaycaster(scene, bake_config=BakeConfig(texel_m=texel_m), cache_dir=None)
    obj = ExtraMesh("ball", sphere.vertices + centre, sphere.faces, np.zeros(3))
    pose = look_at(np.asarray(eye, float), np.zeros(3))
    pair = render_reference_pair(scene, pose, intr, 0.0, obj, spp=spp, radius_m=radius_m, raycaster=caster)
    origin, dirs = _rays(pose, intr)
    hits = caster.cast(origin, dirs, 0.0, normals=False)
    floor = (hits.object_index == 0) & pair.traced.ravel() & ~pair.object_mask.ravel()
    return pair, origin + dirs * hits.distance_m[:, None], floor


def test_gather_change_matches_the_view_factor_of_a_black_sphere():
    """A floor of albedo ρ under walls of fixed radiance L has radiance ρL; a black sphere (centre c,
    radius r, wholly above the floor) hides from a floor point x the cosine-weighted fraction
    cos θ · (r / d)² of its sky (the differential-area-to-sphere view factor; d = |c − x|, θ the angle
    between the floor normal and c − x), so the pixel's radiance drops by ρ L cos θ (r / d)²."""
    import trimesh

    rho, radiance = 0.5, 1.0
    s = 3.0
    walls = [
        {"name": "ceiling", "shape": "quad", "corner": [-s, -s, s], "u": [2 * s, 0, 0], "v": [0, 2 * s, 0]},
        {"name": "south", "shape": "quad", "corner": [-s, -s, 0], "u": [2 * s, 0, 0], "v": [0, 0, s]},
        {"name": "north", "shape": "quad", "corner": [-s, s, 0], "u": [2 * s, 0, 0], "v": [0, 0, s]},
        {"name": "west", "shape": "quad", "corner": [-s, -s, 0], "u": [0, 2 * s, 0], "v": [0, 0, s]},
        {"name": "east", "shape": "quad", "corner": [s, -s, 0], "u": [0, 2 * s, 0], "v": [0, 0, s]},
    ]
    scene = scene_from_dict({"name": "sky_room", "virtual_object_position": [0, 0, 0.3], "objects": [
        {"name": "floor", "shape": "quad", "corner": [-s, -s, 0], "u": [2 * s, 0, 0], "v": [0, 2 * s, 0],
         "albedo": [rho] * 3},
        *[{**w, "radiance": [radiance] * 3} for w in walls]]})
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.1)
    r_eff = float(np.cbrt(3 * sphere.volume / (4 * np.pi)))  # the inscribed mesh's equal-volume radius
    c = np.array([0.0, 0.0, 0.25])
    pair, x, floor = _sphere_over_floor(scene, 0.5, sphere, c, Intrinsics(64, 48, 40.0, 40.0, 31.5, 23.5),
                                        [0.0, -0.9, 0.9], spp=256, radius_m=0.8)
    to_c = c - x
    d = np.linalg.norm(to_c, axis=1)
    expect = -rho * radiance * (to_c[:, 2] / d) * (r_eff / d) ** 2
    got = (pair.with_object - pair.without_object).reshape(-1, 3).mean(axis=1)
    assert np.median(pair.without_object.reshape(-1, 3)[floor, 0]) == pytest.approx(rho * radiance, rel=0.02)
    strong = floor & (np.abs(expect) > 0.02)
    assert strong.sum() > 50
    rel = (got[strong] - expect[strong]) / np.abs(expect[strong])
    assert abs(np.median(rel)) < 0.02 and np.percentile(np.abs(rel), 90) < 0.1
    assert np.abs(got[floor & ~strong] - expect[floor & ~strong]).max() < 0.01


def test_gather_change_of_a_small_lamp_matches_brute_force_and_stays_non_negative():
    """A floor of albedo ρ lit only by a small bright lamp (0.2 m square, radiance 200, 2 m up); a
    sphere 0.25 m above the floor hides part of the lamp from the floor points in its shadow. Brute
    force: ΔL(x) = −ρ/π Σ over a 48 × 48 grid on the lamp of L cos θ_x cos θ_y / r² ΔA where the ray
    x → y meets the sphere mesh (open3d). The gather must match it (the lamp found by its area
    samples, not by the cone's uniform directions: the old estimator's heavy tail) and never give
    the floor a negative radiance."""
    import open3d as o3d
    import trimesh

    rho, big = 0.5, 200.0
    lamp = {"name": "lamp", "shape": "quad", "corner": [-0.1, -0.1, 2.0], "u": [0.2, 0, 0], "v": [0, 0.2, 0],
            "radiance": [big] * 3}
    scene = scene_from_dict({"name": "lamp_room", "virtual_object_position": [0, 0, 0.3], "objects": [
        {"name": "floor", "shape": "quad", "corner": [-3, -3, 0], "u": [6, 0, 0], "v": [0, 6, 0], "albedo": [rho] * 3},
        lamp]})
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    c = np.array([0.05, 0.0, 0.25])
    pair, x, floor = _sphere_over_floor(scene, 0.25, sphere, c, Intrinsics(48, 36, 40.0, 40.0, 23.5, 17.5),
                                        [0.0, -0.6, 0.9], spp=64, radius_m=0.6)
    g = (np.arange(48) + 0.5) / 48
    ys = np.array([-0.1, -0.1, 2.0]) + g[:, None, None] * np.array([0.2, 0, 0]) + g[None, :, None] * np.array([0, 0.2, 0])
    ys = ys.reshape(-1, 3)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor((sphere.vertices + c).astype(np.float32)), o3d.core.Tensor(sphere.faces.astype(np.uint32)))
    idx = np.flatnonzero(floor)
    d = ys[None] - x[idx, None]  # (P, G, 3)
    r = np.linalg.norm(d, axis=2)
    w = d / r[..., None]
    rays = np.concatenate([np.repeat(x[idx], len(ys), axis=0), w.reshape(-1, 3)], axis=1).astype(np.float32)
    t = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(r.shape)
    blocked = t < r
    cos_x, cos_y = w[..., 2], w[..., 2]  # floor normal +z, lamp normal −z
    term = rho / np.pi * big * cos_x * cos_y / r ** 2 * (0.04 / len(ys))
    expect = -np.sum(blocked * term, axis=1)
    lit = np.sum(term, axis=1)  # the lamp's light at x without the object (the coarse bake is not compared)
    got = (pair.with_object - pair.without_object).reshape(-1, 3).mean(axis=1)[idx]
    strong = np.abs(expect) > 0.2 * lit.max()
    assert strong.sum() > 20 and (expect == 0).sum() > 50
    rel = (got[strong] - expect[strong]) / np.abs(expect[strong])
    assert abs(np.median(rel)) < 0.03 and np.percentile(np.abs(rel), 90) < 0.1
    assert np.abs(got - expect).max() < 0.15 * lit.max()
    assert (got >= -1.1 * lit).all()  # never more hidden than the lamp gives (cone sampling alone: −4.8×)


def _recorder_run(visible_from_s: float, every_s: float = 2.0, duration_s: float = 7.0):
    """A recorder fed 10 Hz colour frames whose camera looks away from the object before
    ``visible_from_s`` and at it after; returns the kept frames' times."""
    from types import SimpleNamespace

    from apps.reference_frames import ReferenceOptions, ReferenceRecorder
    from rgbd_envmap.geometry import look_at
    from rgbd_envmap.types import Intrinsics

    intr = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)
    obj = SimpleNamespace(vertices=np.array([[-0.05, -0.05, 0.0], [0.05, 0.05, 0.1]]))
    pipeline = SimpleNamespace(virtual_object=obj, object_base=np.array([0.0, 0.0, 0.8]))
    rec = ReferenceRecorder(None, None, intr, ReferenceOptions(every_s=every_s))
    for k in range(int(duration_s * 10) + 1):
        t = k / 10
        target = [0.0, 0.0, 0.85] if t >= visible_from_s else [0.0, 0.0, 3.0]  # at the object, or at the ceiling
        pose = look_at([1.0, 0.0, 0.85], target)
        rec.on_colour(k, {"t_s": t, "true_pose": pose, "gains": [1.0, 1.0, 1.0]})
        rec.on_step(SimpleNamespace(timestamp_ns=k, image=np.zeros((48, 64, 3), np.uint8)), pipeline)
    return [f.t_s for f in rec.frames]


def test_reference_frames_are_the_first_in_each_window_that_show_the_object():
    # In view throughout: the first frame at or after 2, 4 and 6 s.
    assert _recorder_run(0.0) == [2.0, 4.0, 6.0]
    # Out of view until 4.5 s: the window from 2 s has none, the one from 4 s takes 4.5 s.
    assert _recorder_run(4.5) == [4.5, 6.0]
    # Never in view: no frame.
    assert _recorder_run(99.0) == []


def test_object_in_view_against_the_camera_geometry():
    from apps.reference_frames import object_in_view
    from rgbd_envmap.geometry import look_at
    from rgbd_envmap.types import Intrinsics

    intr = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)
    box = np.array([[-0.05, -0.05, 0.8], [0.05, 0.05, 0.9]])
    assert object_in_view(box, look_at([1.0, 0.0, 0.85], [0.0, 0.0, 0.85]), intr)  # straight ahead
    assert not object_in_view(box, look_at([1.0, 0.0, 0.85], [2.0, 0.0, 0.85]), intr)  # behind the camera
    # Beside the optical axis at 1 m depth: the image's half width there is 31.5 / 50 × 1 m = 0.63 m, so
    # a box 0.5 m off the axis is in view and one 1.2 m off is not.
    assert object_in_view(box, look_at([1.0, 0.5, 0.85], [0.0, 0.5, 0.85]), intr)
    assert not object_in_view(box, look_at([1.0, 1.2, 0.85], [0.0, 1.2, 0.85]), intr)
