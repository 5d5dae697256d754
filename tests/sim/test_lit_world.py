"""The lit world: the bake's light transport against closed forms and against Mitsuba rendering directly.

- the white furnace: a closed room whose every surface has albedo ρ and emission Le has radiance
  Le / (1 − ρ) everywhere;
- direct light from one square emitter onto a floor under black walls, against the point-to-polygon
  form factor (Lambert's formula) computed here;
- the baked radiance seen by a pinhole camera against Mitsuba path-tracing the same rays.
"""

from __future__ import annotations

import numpy as np
import pytest

from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import look_at
from rgbd_envmap.types import Intrinsics
from sim.bake import BakeConfig, bake_scene, build_lattice, gather_kernel
from sim.raycast import SceneRaycaster
from sim.reference import camera_rays, render_reference
from sim.scene import scene_from_dict

pytestmark = pytest.mark.slow


def _quad(name, corner, u, v, **material):
    return {"name": name, "shape": "quad", "corner": corner, "u": u, "v": v, **material}


def _box_room(size, **material):
    """Six quads of a closed axis-aligned room [−s/2, s/2]² × [0, s] with one material."""
    h = size / 2
    s = size
    return [
        _quad("floor", [-h, -h, 0], [s, 0, 0], [0, s, 0], **material),
        _quad("ceiling", [-h, -h, s], [s, 0, 0], [0, s, 0], **material),
        _quad("south", [-h, -h, 0], [s, 0, 0], [0, 0, s], **material),
        _quad("north", [-h, h, 0], [s, 0, 0], [0, 0, s], **material),
        _quad("west", [-h, -h, 0], [0, s, 0], [0, 0, s], **material),
        _quad("east", [h, -h, 0], [0, s, 0], [0, 0, s], **material),
    ]


def _live_values(lighting, state=0, group=0):
    """S at every lattice side that receives light (the inside of the room)."""
    v = lighting.values[state, group]  # (2, P, 3)
    return v.reshape(-1, 3)[v.reshape(-1, 3).max(axis=1) > 0]


def test_white_furnace_radiance_is_le_over_one_minus_rho(tmp_path):
    rho, le = 0.5, 1.0
    scene = scene_from_dict({"objects": _box_room(2.0, albedo=[rho] * 3, emission=[le] * 3)})
    lighting = bake_scene(scene, BakeConfig(), tmp_path)
    expected = le / (1 - rho)
    radiance = le + rho * _live_values(lighting)
    rel = np.abs(radiance / expected - 1)
    assert abs(radiance.mean() / expected - 1) < 0.01
    assert np.percentile(rel, 99) < 0.03
    # and as the ray caster sees it, from inside, in every direction
    dirs = np.random.default_rng(0).normal(size=(20000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = SceneRaycaster(scene, lighting).cast(np.array([0.2, -0.3, 0.9]), dirs, 0.0)
    assert hits.hit.all()
    assert abs(hits.radiance.mean() / expected - 1) < 0.01


def _polygon_form_factor(x, n, vertices):
    """Point-to-polygon form factor F = (1/2π) Σ γ_i n·(R_i × R_{i+1}) / |R_i × R_{i+1}| (Lambert),
    for a polygon fully above the point's tangent plane; the fraction of a Lambertian emitter's
    radiance that arrives as irradiance / π."""
    r = vertices - x
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        gamma = np.arccos(np.clip(a @ b, -1, 1))
        total += gamma * (n @ c) / np.linalg.norm(c)
    return abs(total) / (2 * np.pi)


def test_direct_light_from_a_square_emitter_matches_the_form_factor(tmp_path):
    rho, le = 0.6, 2.0
    black = {"albedo": [0, 0, 0]}
    lamp = [[-0.25, -0.25, 1.0], [0.25, -0.25, 1.0], [0.25, 0.25, 1.0], [-0.25, 0.25, 1.0]]
    objects = [
        _quad("floor", [-1, -1, 0], [2, 0, 0], [0, 2, 0], albedo=[rho] * 3),
        _quad("lamp", lamp[0], [0.5, 0, 0], [0, 0.5, 0], albedo=[0, 0, 0], emission=[le] * 3),
        _quad("wall_s", [-1, -1, 0], [2, 0, 0], [0, 0, 1.5], **black),
        _quad("wall_n", [-1, 1, 0], [2, 0, 0], [0, 0, 1.5], **black),
        _quad("wall_w", [-1, -1, 0], [0, 2, 0], [0, 0, 1.5], **black),
        _quad("wall_e", [1, -1, 0], [0, 2, 0], [0, 0, 1.5], **black),
    ]
    scene = scene_from_dict({"objects": objects})
    lighting = bake_scene(scene, BakeConfig(), tmp_path)
    lat = lighting.lattice
    floor = np.flatnonzero(lat.point_object == 0)
    up = lat.point_normal[floor, 2] > 0  # the winding's side: +z for this quad
    side = 0 if up.all() else 1
    s = lighting.values[0, 0, side, floor, 1]
    expected = np.array([le * _polygon_form_factor(p, np.array([0, 0, 1.0]), np.array(lamp)) for p in lat.points[floor]])
    rel = np.abs(s / expected - 1)
    assert np.median(rel) < 0.01
    assert np.percentile(rel, 99) < 0.03
    # the floor's underside and the black walls' light stay out of it: nothing else lights the floor
    assert np.abs(s.mean() / expected.mean() - 1) < 0.005


def _small_room():
    """A room with a ceiling lamp, a checker floor, a coloured panel and a box: colour bleeding,
    shadows and textures."""
    objects = [
        _quad("floor", [-1.5, -1.5, 0], [3, 0, 0], [0, 3, 0],
              albedo={"texture": "checker", "colours": [[0.6, 0.5, 0.4], [0.2, 0.2, 0.25]], "cells": [6, 6]}),
        _quad("ceiling", [-1.5, -1.5, 2.5], [3, 0, 0], [0, 3, 0], albedo=[0.8, 0.8, 0.8]),
        _quad("south", [-1.5, -1.5, 0], [3, 0, 0], [0, 0, 2.5], albedo=[0.7, 0.7, 0.7]),
        _quad("north", [-1.5, 1.5, 0], [3, 0, 0], [0, 0, 2.5], albedo=[0.7, 0.6, 0.5]),
        _quad("west", [-1.5, -1.5, 0], [0, 3, 0], [0, 0, 2.5],
              albedo={"texture": "gradient", "colours": [[0.2, 0.3, 0.5], [0.6, 0.7, 0.8]]}),
        _quad("east", [1.5, -1.5, 0], [0, 3, 0], [0, 0, 2.5], albedo=[0.7, 0.7, 0.7]),
        _quad("lamp", [-0.3, -0.3, 2.2], [0.6, 0, 0], [0, 0.6, 0], albedo=[0.5, 0.5, 0.5], emission=[6.0, 5.5, 5.0]),
        {"name": "panel", "shape": "box", "centre": [0.6, 0.0, 0.4], "size": [0.05, 0.8, 0.8], "albedo": [0.85, 0.1, 0.08]},
        {"name": "cube", "shape": "box", "centre": [0.1, 0.0, 0.25], "size": [0.5, 0.5, 0.5], "albedo": [0.6, 0.6, 0.6]},
    ]
    return scene_from_dict({"objects": objects})


def _blocks(x, k=8):
    h, w = x.shape[:2]
    return x[: h // k * k, : w // k * k].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))


def test_baked_radiance_matches_mitsuba_rendering_the_same_view(tmp_path):
    scene = _small_room()
    lighting = bake_scene(scene, BakeConfig(), tmp_path)
    intr = Intrinsics(96, 72, 60.0, 60.0, 47.5, 35.5)
    pose = look_at(np.array([-1.2, -1.1, 1.4]), np.array([0.4, 0.3, 0.4]))
    origin, dirs = camera_rays(pose, intr)
    ours = SceneRaycaster(scene, lighting).cast(origin, dirs, 0.0).radiance.reshape(72, 96, 3).astype(np.float64)
    ref = render_reference(scene, pose, intr, 0.0, spp=512)
    assert ref.hit.all()
    a, b = _blocks(ours), _blocks(ref.radiance.astype(np.float64))
    rel = np.abs(a - b).sum(axis=-1) / b.sum(axis=-1)
    assert rel.mean() <= 0.02, rel.mean()
    assert abs(ours.mean() / ref.radiance.mean() - 1) < 0.01


def test_lamp_dimming_is_exact_by_linearity(tmp_path):
    """An emitter group's light scales with its timeline exactly: the lamp at 0.4 from t = 1 s."""
    d = {"objects": [
        _quad("floor", [-1, -1, 0], [2, 0, 0], [0, 2, 0], albedo=[0.5, 0.5, 0.5]),
        {**_quad("lamp", [-0.2, -0.2, 1.0], [0.4, 0, 0], [0, 0.4, 0], albedo=[0, 0, 0], emission=[3, 3, 3]),
         "timeline": [{"t": 1.0, "scale": 0.4}]},
        _quad("window", [-1, 1, 0.2], [0.8, 0, 0], [0, 0, 0.6], albedo=[0, 0, 0], emission=[1, 1, 1]),
    ]}
    scene = scene_from_dict(d)
    lighting = bake_scene(scene, BakeConfig(spp=8, direct_samples=8, texel_m=0.1), tmp_path)
    assert len(lighting.groups) == 2
    rc = SceneRaycaster(scene, lighting)
    dirs = np.array([[0.1, 0.05, -1.0], [-0.3, 0.2, -1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = np.array([0.0, 0.0, 0.5])
    before = rc.cast(origin, dirs, 0.5).radiance.astype(np.float64)
    after = rc.cast(origin, dirs, 1.5).radiance.astype(np.float64)
    lamp_group = [g for g, members in enumerate(lighting.groups) if 1 in members][0]
    only_lamp = lighting.combined(0, tuple(1.0 if g == lamp_group else 0.0 for g in range(2)))
    # the difference is exactly 0.6 of the lamp's own contribution
    lamp_part = gather_kernel(np.zeros(2, np.int32), *_hit_triangles(rc, origin, dirs), dirs,
                              lighting.lattice.tri_base, lighting.lattice.tri_n, lighting.lattice.tri_offset,
                              lighting.lattice.tri_normal, only_lamp, lighting.valid[0]) * 0.5
    np.testing.assert_allclose(before - after, 0.6 * lamp_part, rtol=1e-5, atol=1e-7)


def test_state_after_a_box_goes_matches_the_scene_without_it(tmp_path):
    """The bake shares rays between visibility states (the state after a box goes reuses the state
    before it, casting again only what met the box): the later state must match a bake of the scene
    that never had the box (its shadow and the dark floor under it gone), and the earlier one must
    still show them."""
    objects = [
        _quad("floor", [-1, -1, 0], [2, 0, 0], [0, 2, 0], albedo=[0.5, 0.5, 0.5]),
        _quad("wall", [-1, 1, 0], [2, 0, 0], [0, 0, 1.2], albedo=[0.7, 0.7, 0.7]),
        _quad("lamp", [-0.2, -0.2, 1.0], [0.4, 0, 0], [0, 0.4, 0], albedo=[0, 0, 0], emission=[3, 3, 3]),
    ]
    box = {"name": "box", "shape": "box", "centre": [0.3, 0.0, 0.15], "size": [0.3, 0.3, 0.3],
           "albedo": [0.6, 0.6, 0.6], "visible": {"until": 1.0}}
    config = BakeConfig(spp=8, direct_samples=64, final_gather=64, texel_m=0.1)
    with_box = bake_scene(scene_from_dict({"objects": objects + [box]}), config, tmp_path)
    without = bake_scene(scene_from_dict({"objects": objects}), config, tmp_path)
    assert len(with_box.states) == 2 and 3 in with_box.states[0] and 3 not in with_box.states[1]
    lat = with_box.lattice
    floor = np.flatnonzero(lat.point_object == 0)
    np.testing.assert_array_equal(lat.points[floor], without.lattice.points[floor])
    up = 0 if (lat.point_normal[floor, 2] > 0).all() else 1
    p = lat.points[floor]
    under = (np.abs(p[:, 0] - 0.3) < 0.13) & (np.abs(p[:, 1]) < 0.13)
    near = (np.abs(p[:, 0] - 0.3) < 0.6) & (np.abs(p[:, 1]) < 0.6) & ~under
    assert under.sum() >= 4 and near.sum() > 50
    assert not with_box.valid[0, up, floor[under]].any() and with_box.valid[1, up, floor[under]].all()
    after = with_box.values[1, 0, up, floor].sum(axis=1)
    before = with_box.values[0, 0, up, floor].sum(axis=1)
    alone = without.values[0, 0, up, floor].sum(axis=1)
    assert abs(after.mean() / alone.mean() - 1) < 0.01
    assert abs(after[near].mean() / alone[near].mean() - 1) < 0.01
    assert abs(after[under].mean() / alone[under].mean() - 1) < 0.03
    lit = alone > 0  # (an open scene: floor points whose probes all escape are dead, zero)
    assert lit.sum() > 0.5 * len(floor)
    assert np.median(np.abs(after[lit] / alone[lit] - 1)) < 0.03
    assert before[near].mean() < 0.95 * alone[near].mean()  # the box's shadow, while it is there


def _hit_triangles(rc, origin, dirs):
    import open3d as o3d

    rcs, _ = rc._bvh(0.0)
    rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=1).astype(np.float32)
    ans = rcs.cast_rays(o3d.core.Tensor(rays))
    assert (ans["geometry_ids"].numpy() == 0).all()
    return ans["primitive_ids"].numpy().astype(np.int64), ans["primitive_uvs"].numpy()


def test_gather_kernel_interpolates_the_lattice_linearly():
    """A lattice holding a linear function of position gives that function back anywhere on the
    triangle (linear interpolation is exact for it), on either side."""
    scene = scene_from_dict({"objects": [_quad("q", [0, 0, 0], [1.0, 0, 0], [0, 0.7, 0], albedo=[0.5] * 3)]})
    lat = build_lattice(scene, 0.1)
    f = lat.points @ np.array([0.3, -0.2, 0.0]) + 1.0
    combined = np.stack([np.repeat(f[:, None], 3, 1), 2 * np.repeat(f[:, None], 3, 1)]).astype(np.float32)
    rng = np.random.default_rng(3)
    uv = rng.random((500, 2))
    uv = np.where(uv.sum(1, keepdims=True) > 1, 1 - uv, uv)
    prim = rng.integers(0, 2, 500)
    tri = scene.objects[0].vertices[scene.objects[0].faces[prim]]
    p = tri[:, 0] + uv[:, :1] * (tri[:, 1] - tri[:, 0]) + uv[:, 1:] * (tri[:, 2] - tri[:, 0])
    expected = p @ np.array([0.3, -0.2, 0.0]) + 1.0
    for sign, factor in ((-1.0, 1.0), (1.0, 2.0)):  # against the normal (+z): the front; along it: the back
        dirs = np.tile([0.0, 0.0, sign], (500, 1))
        s = gather_kernel(np.zeros(500, np.int32), prim, uv.astype(np.float32), dirs, lat.tri_base, lat.tri_n,
                          lat.tri_offset, lat.tri_normal, combined, np.ones((2, lat.size), bool))
        # the lattice points sit a hair inside the triangle: exact to that shrink
        np.testing.assert_allclose(s[:, 0], factor * expected, rtol=2e-3)


def test_bake_is_cached_by_content(tmp_path):
    scene = scene_from_dict({"objects": _box_room(1.0, albedo=[0.3] * 3, emission=[1.0] * 3)})
    config = BakeConfig(spp=2, direct_samples=2, texel_m=0.25)
    first = bake_scene(scene, config, tmp_path)
    again = bake_scene(scene, config, tmp_path)
    assert not first.from_cache and again.from_cache
    np.testing.assert_array_equal(first.values, again.values)
    other = scene_from_dict({"objects": _box_room(1.0, albedo=[0.31] * 3, emission=[1.0] * 3)})
    assert bake_scene(other, config, tmp_path).key != first.key
    assert len(list((tmp_path / "lightmaps").glob("*.npz"))) == 2
    assert not list((tmp_path / "lightmaps").glob("*.tmp"))


_BAKE_IN_A_PROCESS = """
import json, sys
from sim.bake import BakeConfig, bake_scene
from sim.scene import scene_from_dict
spec = json.loads(sys.argv[1])
lighting = bake_scene(scene_from_dict(spec), BakeConfig(spp=2, direct_samples=2, texel_m=0.25), sys.argv[2])
print(json.dumps({"from_cache": lighting.from_cache, "sum": float(lighting.values.sum())}))
"""


def test_two_processes_baking_one_scene_bake_it_once(tmp_path):
    """The second process waits on the cache entry's lock and loads the first one's bake."""
    import json
    import subprocess
    import sys

    spec = {"objects": _box_room(1.0, albedo=[0.4] * 3, emission=[1.0] * 3)}
    procs = [subprocess.Popen([sys.executable, "-c", _BAKE_IN_A_PROCESS, json.dumps(spec), str(tmp_path)],
                              stdout=subprocess.PIPE, text=True) for _ in range(2)]
    results = [json.loads(p.communicate(timeout=600)[0].splitlines()[-1]) for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sorted(r["from_cache"] for r in results) == [False, True]
    assert results[0]["sum"] == results[1]["sum"]
    assert len(list((tmp_path / "lightmaps").glob("*.npz"))) == 1


@pytest.mark.parametrize(("spec", "match"), [
    ({"albedo": [1.0, 0.5, 0.5]}, "albedo"),
    ({"albedo": [-0.1, 0.5, 0.5]}, "albedo"),
    ({"albedo": [float("nan"), 0.5, 0.5]}, "albedo"),
    ({"albedo": [0.5, 0.5, 0.5], "radiance": [1, 1, 1]}, "radiance or albedo"),
    ({"albedo": [0.5, 0.5, 0.5], "emission": [-1, 0, 0]}, "emission"),
    ({"albedo": [0.5, 0.5, 0.5], "emission": [float("inf"), 0, 0]}, "emission"),
    ({"radiance": [1, 1, 1], "emission": [1, 1, 1]}, "emission needs a lit surface"),
    ({"albedo": {"texture": "checker", "colours": [[0.2, 0.2, 0.2], [1.2, 0.2, 0.2]], "cells": [2, 2]}}, "albedo"),
    ({"albedo": {"texture": "checker", "cells": [2, 2]}}, "colours"),
    ({"albedo": "white"}, "albedo"),
])
def test_bad_materials_fail_at_load_naming_the_object_and_key(spec, match):
    with pytest.raises(InvalidInputError, match=match) as info:
        scene_from_dict({"objects": [_quad("desk_top", [0, 0, 0], [1, 0, 0], [0, 1, 0], **spec)]})
    assert "desk_top" in str(info.value)


def test_bake_settings_are_checked():
    for bad in ({"texel_m": 0.0}, {"spp": 0}, {"direct_samples": -1}, {"max_depth": 0}, {"texel_m": float("nan")}):
        with pytest.raises(InvalidInputError):
            BakeConfig(**bad)
    scene = scene_from_dict({"objects": _box_room(50.0, albedo=[0.3] * 3)})
    with pytest.raises(InvalidInputError, match="lattice points"):
        build_lattice(scene, 0.002)


def test_fixed_radiance_scenes_need_no_bake():
    scene = scene_from_dict({"objects": [_quad("q", [0, 0, 0], [1, 0, 0], [0, 1, 0], radiance=[0.5, 0.5, 0.5])]})
    assert not scene.is_lit
    assert SceneRaycaster(scene).lighting is None
