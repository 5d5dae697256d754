"""The helpers of benchmarks/study_composite.py against closed forms."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.study_composite import (barycentric, brute_irradiance, cone_directions, exact_irradiance,
                                        fibonacci_sphere, plane_alpha_at_rays, random_rotations, shadow_change)
from rgbd_envmap.geometry import equirect_directions


def test_exact_irradiance_of_a_constant_map_is_pi_l_for_every_normal_poles_included():
    radiance = np.full((64, 128, 3), [0.5, 1.0, 2.0], np.float32)
    normals = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0], [0.6, 0, 0.8]], np.float64)
    e = exact_irradiance(radiance, normals)
    np.testing.assert_allclose(e, np.pi * np.array([[0.5, 1.0, 2.0]] * 5), rtol=2e-3)


def test_exact_irradiance_of_an_upper_hemisphere():
    h, w = 128, 256
    d = equirect_directions(h, w)
    radiance = np.repeat((d[..., 2:3] > 0).astype(np.float32), 3, axis=2)
    e = exact_irradiance(radiance, np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]]))[:, 0]
    # up: π; down: 0; horizontal: half the cosine lobe, π / 2
    np.testing.assert_allclose(e, [np.pi, 0.0, np.pi / 2], atol=5e-3)


def test_fibonacci_lattice_is_unit_and_integrates_the_cosine_lobe():
    d = fibonacci_sphere(4096)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert abs(float(np.maximum(d[:, 2], 0).sum() * 4 * np.pi / len(d)) - np.pi) < 1e-3


def test_random_rotations_are_proper_rotations():
    r = random_rotations(50, np.random.default_rng(1))
    np.testing.assert_allclose(np.einsum("kij,kil->kjl", r, r), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)


def test_plane_alpha_at_rays_hits_vertices_interpolates_and_misses():
    res, size = 5, 1.0
    alpha = np.arange(res * res, dtype=np.float64).reshape(res, res) / 100.0  # row j: y, column i: x
    base = np.array([2.0, -1.0, 0.5])
    origin = np.array([2.0, -1.0, 1.5])
    # grid vertex (j=1, i=3): x = -0.5 + 3 * 0.25 = 0.25, y = -0.5 + 1 * 0.25 = -0.25
    targets = np.array([[2.25, -1.25, 0.5], [2.125, -1.25, 0.5], [2.0 + 0.8, -1.0, 0.5], [2.0, -1.0, 2.0]])
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    a = plane_alpha_at_rays(origin, dirs, base, size, alpha)
    assert a[0] == pytest.approx(alpha[1, 3])
    assert a[1] == pytest.approx(0.5 * (alpha[1, 2] + alpha[1, 3]))
    assert a[2] == 0.0  # outside the square
    assert a[3] == 0.0  # upwards: the plane is behind


def test_barycentric_matches_open3d_hit_points():
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(3)
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.3]], np.float64)
    faces = np.array([[0, 1, 2], [1, 3, 2]], np.int64)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    target = np.column_stack([rng.random(200), rng.random(200), np.zeros(200)])
    origin = np.array([0.3, 0.4, 2.0])
    d = target - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([np.broadcast_to(origin, d.shape), d], 1).astype(np.float32)))
    t = ans["t_hit"].numpy()
    ok = np.isfinite(t)
    assert ok.sum() > 150
    p = barycentric(verts, faces, ans["primitive_ids"].numpy()[ok].astype(np.int64),
                    ans["primitive_uvs"].numpy()[ok].astype(np.float64))
    np.testing.assert_allclose(p, origin + d[ok] * t[ok, None], atol=1e-5)


def test_cone_directions_stay_in_the_cone_with_the_uniform_mean_cosine():
    axis = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    cos_max = np.array([0.8, -1.0])
    d = cone_directions(axis, cos_max, np.random.default_rng(0).random((2, 20000, 2)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=1e-12)
    c = np.einsum("pmk,pk->pm", d, axis)
    assert c[0].min() >= 0.8 - 1e-12
    # uniform in solid angle: the mean cosine is (1 + cos_max) / 2
    np.testing.assert_allclose(c.mean(axis=1), (1 + cos_max) / 2, atol=0.01)


class _Occluder:
    def __init__(self, everything: bool) -> None:
        self.everything = everything

    def occluded(self, origins, dirs):
        return np.full(len(dirs), self.everything)

    def cast(self, origins, dirs):
        return {"t": np.full(len(dirs), 0.5 if self.everything else np.inf)}


class _Room:
    """A raycaster stub: radiance ``l`` everywhere, ``l_near`` when cast from anywhere but the origin."""

    def __init__(self, l, l_near=None, distance=1.0) -> None:
        self.l, self.l_near, self.distance = np.asarray(l, np.float32), l_near, distance

    def cast(self, origins, dirs, t_s, normals=False):
        n = len(dirs)
        near = self.l_near is not None and np.asarray(origins).ndim == 2
        rad = np.broadcast_to(np.asarray(self.l_near if near else self.l, np.float32), (n, 3))
        return SimpleNamespace(radiance=np.array(rad), hit=np.ones(n, bool), distance_m=np.full(n, self.distance))


def test_brute_irradiance_control_variate_open_and_enclosed_points():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(7, 3))
    nrm = rng.normal(size=(7, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    l = np.array([1.0, 2.0, 3.0])
    e0 = np.tile(np.pi * l, (7, 1))
    rot = random_rotations(7, rng)
    common = dict(em_origin=np.zeros(3), t_s=0.0, e0=e0, n_dirs=4096, rotations=rot, local=True)
    open_ = brute_irradiance(pts, nrm, object_caster=_Occluder(False), raycaster=_Room(l, l_near=2 * l), **common)
    np.testing.assert_allclose(open_["distant"], e0)  # nothing blocked: exactly the closed form
    np.testing.assert_allclose(open_["local"], 2 * e0, rtol=2e-3)  # the near light is twice as bright
    shut = brute_irradiance(pts, nrm, object_caster=_Occluder(True), raycaster=_Room(l), **common)
    np.testing.assert_allclose(shut["distant"], 0.0, atol=2e-3 * math.pi * 3)
    np.testing.assert_allclose(shut["local"], shut["distant"])


def test_shadow_change_of_a_point_enclosed_by_the_object():
    # inside the bounding sphere: the cone is the whole sphere, and what the object hides is the upper
    # hemisphere's cosine-weighted radiance, π L
    l = np.array([0.5, 1.0, 1.5])
    out = shadow_change(np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)), object_caster=_Occluder(True),
                        raycaster=_Room(l, distance=1.0), em_origin=np.zeros(3), centre=np.zeros(3), radius=1.0,
                        t_s=0.0, uniforms=np.random.default_rng(2).random((3, 40000, 2)), local=True)
    np.testing.assert_allclose(out["distant"], np.tile(np.pi * l, (3, 1)), rtol=0.02)
    np.testing.assert_allclose(out["local"], out["distant"])  # the object (0.5 m) is nearer than the room
