import numpy as np

from rgbd_envmap.geometry import equirect_directions
from sim.groundtruth import render_envmap
from sim.raycast import SceneRaycaster
from sim.scene import FLAG_BITS, load_scene, scene_from_dict
from tests.sim.helpers import box_room

DIST_TOL_M = 1e-4


def test_cube_room_distances_match_closed_form(cube_scene):
    # From the centre of a cube of half-size a, the wall along unit d is at a / max|d_i|.
    em = render_envmap(SceneRaycaster(cube_scene), np.zeros(3), 32, 64, 0.0)
    d = equirect_directions(32, 64).astype(np.float64)
    expected = 2.0 / np.abs(d).max(axis=-1)
    assert em.valid.all()
    np.testing.assert_allclose(em.distance_m, expected, atol=DIST_TOL_M)
    np.testing.assert_allclose(em.radiance, np.broadcast_to([0.5, 0.4, 0.3], em.radiance.shape), atol=1e-6)


def test_off_centre_origin_and_normals_face_the_ray(cube_scene):
    rc = SceneRaycaster(cube_scene)
    origin = np.array([0.5, -0.25, 1.0])
    dirs = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0]], np.float32)
    hits = rc.cast(origin, dirs, 0.0)
    np.testing.assert_allclose(hits.distance_m, [1.5, 2.5, 1.0, 3.0], atol=DIST_TOL_M)
    assert np.all(np.sum(hits.normal * dirs, axis=1) < -0.999)


def test_textured_quad_and_flags():
    extra = [{
        "name": "poster", "shape": "quad", "corner": [1.9, -1.0, -1.0], "u": [0, 2.0, 0], "v": [0, 0, 2.0],
        "radiance": {"texture": "checker", "colours": [[3, 3, 3], [0.1, 0.2, 0.3]], "cells": [2, 2]}, "flags": ["emissive"],
    }]
    rc = SceneRaycaster(scene_from_dict(box_room(extra=extra)))
    # (y, z) = (−0.5, −0.5) is cell (0, 0) → colour 0; (0.5, −0.5) is cell (1, 0) → colour 1.
    targets = np.array([[1.9, -0.5, -0.5], [1.9, 0.5, -0.5]])
    dirs = (targets / np.linalg.norm(targets, axis=1, keepdims=True)).astype(np.float32)
    hits = rc.cast(np.zeros(3), dirs, 0.0)
    np.testing.assert_allclose(hits.radiance, [[3, 3, 3], [0.1, 0.2, 0.3]], atol=1e-6)
    assert np.all(hits.flags == FLAG_BITS["emissive"])


def test_empty_scene_misses_everything():
    rc = SceneRaycaster(load_scene("empty"))
    hits = rc.cast(np.zeros(3), equirect_directions(4, 8).reshape(-1, 3), 0.0)
    assert not hits.hit.any() and np.all(hits.object_index == -1) and np.all(np.isinf(hits.distance_m))
    assert np.all(hits.radiance == 0)


def test_scene_changes_over_time(office):
    rc = SceneRaycaster(office)
    box = office.object("removed_box")
    centre = box.vertices.mean(axis=0)
    origin = centre + np.array([0.0, 0.0, 0.5])
    down = np.array([[0.0, 0.0, -1.0]], np.float32)
    before, after = rc.cast(origin, down, 5.0), rc.cast(origin, down, 6.5)
    assert office.objects[before.object_index[0]].name == "removed_box"
    assert office.objects[after.object_index[0]].name == "table_top"
    lamp = office.object("ceiling_lamp")
    up_origin = lamp.vertices.mean(axis=0) - [0, 0, 1.0]
    up = np.array([[0.0, 0.0, 1.0]], np.float32)
    np.testing.assert_allclose(rc.cast(up_origin, up, 9.0).radiance, rc.cast(up_origin, up, 1.0).radiance * 0.4, rtol=1e-6)


def test_radiance_kernel_matches_the_array_version(office):
    """The one-pass kernel against the per-object numpy formulas (Texture.sample at the float64 hit
    point, constant radiance × the time's scale) on every object of the office, lamp dimmed or not."""
    rc = SceneRaycaster(office)
    origin = office.virtual_object_position + np.array([0.1, -0.2, 0.3])
    dirs = equirect_directions(200, 400).reshape(-1, 3).astype(np.float32)
    for t_s in (0.0, 7.0, 30.0):
        hits = rc.cast(origin, dirs, t_s)
        expected = np.zeros((len(dirs), 3), np.float32)
        for i, o in enumerate(office.objects):
            sel = hits.object_index == i
            if not sel.any():
                continue
            if o.texture is None:
                expected[sel] = o.radiance * o.scale_at(t_s)
                continue
            p = origin.astype(np.float32).astype(np.float64) + dirs[sel] * hits.distance_m[sel, None].astype(np.float64)
            corner, u, v = o.quad_frame
            s = (p - corner) @ u / (u @ u)
            t = (p - corner) @ v / (v @ v)
            expected[sel] = o.texture.sample(s, t) * o.scale_at(t_s)
        # A texel edge may fall either side under a different summation order: allow a handful.
        mismatch = np.any(np.abs(hits.radiance - expected) > 1e-6 * np.maximum(1.0, np.abs(expected)), axis=1)
        assert mismatch.sum() <= 5, mismatch.sum()
        assert hits.hit.sum() == (hits.object_index >= 0).sum() > 0.9 * len(dirs)
        np.testing.assert_array_equal(hits.flags, [office.objects[k].flag_bits if k >= 0 else 0 for k in hits.object_index])
