"""The differential composite: the real geometry from the map's depth, shadow rays, the object's
occlusion of the indirect light, the energy of lights + SH, and the composite kernel against its
numpy reference. Every expected value is independent of the code under test (closed forms, brute
force, or the other implementation)."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd_envmap import sh
from rgbd_envmap.errors import RgbdEnvmapError
from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles
from rgbd_envmap.lights import LightSet, irradiance, sample_lights, split_direct_indirect
from rgbd_envmap.reference.render_differential import composite_differential as composite_ref
from rgbd_envmap.render import Layer, composite, composite_differential
from rgbd_envmap.render.differential import (DifferentialShader, ObjectOccluder, cone_directions, direct_irradiance,
                                             light_visibility, receiver_occlusion)
from rgbd_envmap.render.geometry import ReceiverMesh, merge_receivers, receiver_mesh, support_plane, surface_radiance


def icosphere(radius: float, centre, subdiv: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle sphere (vertices on the sphere, faces outward)."""
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    verts = list(v / np.linalg.norm(v, axis=1, keepdims=True))
    faces = f
    for _ in range(subdiv):
        cache: dict = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        nf = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = nf
    return np.asarray(verts) * radius + np.asarray(centre, float), np.asarray(faces, np.int32)


def plane_map(H: int, W: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the plane z = −h seen from the origin: h / (−d_z) below the horizon, invalid above."""
    d = equirect_directions(H, W).astype(np.float64)
    valid = d[..., 2] < -1e-3
    depth = np.where(valid, h / np.maximum(-d[..., 2], 1e-3), 0.0)
    return depth.astype(np.float32), valid


# --- the real geometry -----------------------------------------------------------------------------

def test_receiver_mesh_of_a_plane_lies_on_it_faces_up_and_stays_in_range():
    depth, valid = plane_map(400, 800, 0.1)
    origin = np.array([0.3, -0.2, 1.0])
    centre = origin + [0.05, 0.0, -0.05]
    mesh = receiver_mesh(depth, valid, origin, centre, 0.3, spacing_m=0.005, stride=1)
    assert len(mesh) > 2000 and len(mesh.faces) > 2000
    np.testing.assert_allclose(mesh.vertices[:, 2], origin[2] - 0.1, atol=1e-6)
    np.testing.assert_allclose(mesh.normals, np.tile([0, 0, 1.0], (len(mesh), 1)), atol=1e-5)  # float32 depth
    assert np.linalg.norm(mesh.vertices - centre, axis=1).max() <= 0.3 + 1e-9
    # the disc of the plane within the radius is covered, without overlaps: its area to 3 %
    tri = mesh.vertices[mesh.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(np.pi * (0.3 ** 2 - 0.05 ** 2), rel=0.03)
    # about one vertex per spacing² of area
    assert 0.5 < len(mesh) * 0.005 ** 2 / area < 1.5


def test_receiver_mesh_cuts_at_a_depth_discontinuity_and_has_no_seam():
    H, W = 400, 800
    d = equirect_directions(H, W).astype(np.float64)
    depth, valid = plane_map(H, W, 0.1)
    # a floating board z = −0.05 over 0.1 ≤ x ≤ 0.2 in front of the floor
    t_board = 0.05 / np.maximum(-d[..., 2], 1e-9)
    xb = d[..., 0] * t_board
    board = (d[..., 2] < 0) & (xb >= 0.1) & (xb <= 0.2)
    depth = np.where(board, t_board, depth).astype(np.float32)
    mesh = receiver_mesh(depth, valid, np.zeros(3), np.zeros(3), 0.5, spacing_m=0.005, stride=1)
    z = mesh.vertices[:, 2]
    on_floor = np.abs(z + 0.1) < 1e-5
    on_board = np.abs(z + 0.05) < 1e-5
    assert (on_floor | on_board).all() and on_board.sum() > 100
    f = mesh.faces
    assert not (on_floor[f].any(1) & on_board[f].any(1)).any()
    np.testing.assert_allclose(mesh.normals[:, 2], 1.0, atol=1e-5)
    # no seam at φ = ±180°: some triangle joins both sides
    phi = np.degrees(np.arctan2(mesh.vertices[:, 1], mesh.vertices[:, 0]))
    assert ((phi[f] > 175).any(1) & (phi[f] < -175).any(1)).any()


def test_support_plane_fills_in_where_the_map_has_no_surface():
    plane = support_plane(np.array([1.0, 2.0, 0.7]), 0.2, 0.01)
    assert len(plane) == 41 * 41
    np.testing.assert_allclose(plane.vertices[:, 2], 0.7)
    tri = plane.vertices[plane.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(0.4 * 0.4, rel=1e-9)
    # a map mesh covering x > 1.05: the plane keeps only triangles farther than 0.02 from it
    g = np.linspace(1.05, 1.2, 16)
    xy = np.stack(np.meshgrid(g, np.linspace(1.8, 2.2, 41), indexing="ij"), -1).reshape(-1, 2)
    first = ReceiverMesh(np.concatenate([xy, np.full((len(xy), 1), 0.7)], 1), np.tile([0, 0, 1.0], (len(xy), 1)),
                         np.array([[0, 1, 41]], np.int32))
    merged = merge_receivers(first, plane, 0.02)
    assert len(merged.faces) > 1 and (merged.faces[:1] == first.faces).all()
    added = merged.vertices[np.unique(merged.faces[1:])]
    assert added[:, 0].max() < 1.05 - 0.02 + 1e-9 and added[:, 0].min() == pytest.approx(0.8)
    assert merge_receivers(ReceiverMesh.empty(), plane, 0.02) is plane


def test_receiver_mesh_empty_and_bad_inputs():
    depth, valid = plane_map(50, 100, 0.1)
    assert len(receiver_mesh(depth, np.zeros_like(valid), np.zeros(3), np.zeros(3), 0.3)) == 0
    assert len(receiver_mesh(depth, valid, np.zeros(3), np.array([5.0, 0, 0]), 0.3)) == 0
    with pytest.raises(RgbdEnvmapError, match="radius_m"):
        receiver_mesh(depth, valid, np.zeros(3), np.zeros(3), 0.0)
    with pytest.raises(RgbdEnvmapError, match="valid"):
        receiver_mesh(depth, valid[:10], np.zeros(3), np.zeros(3), 0.3)


# --- rays and occlusion ----------------------------------------------------------------------------

def test_cone_directions_inside_the_cone_with_its_solid_angle():
    rng = np.random.default_rng(1)
    axis = rng.normal(size=(5, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    cos_max = np.array([0.0, 0.5, 0.9, 0.99, -1.0])
    d, omega = cone_directions(axis, cos_max, 64)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=1e-12)
    assert (np.einsum("ck,cmk->cm", axis, d) >= cos_max[:, None] - 1e-12).all()
    np.testing.assert_allclose(omega, 2 * np.pi * (1 - cos_max))
    # uniform in the cone: the mean of cos θ is (1 + cos_max) / 2
    np.testing.assert_allclose(np.einsum("ck,cmk->cm", axis, d).mean(1), (1 + cos_max) / 2, atol=1e-3)


def test_cone_ray_kernel_is_its_reference_bit_for_bit_and_the_cones_directions():
    """The occlusion rays: kernel against the plain-Python reference bit for bit, and against
    cone_directions (the numpy form) with the front-facing selection, to rounding; axes along x
    (the other helper axis), a full hemisphere (cos_max 0) and a receiver facing away."""
    from rgbd_envmap._kernels.occlusion_rays import cone_rays_kernel
    from rgbd_envmap.reference.render_differential import cone_rays
    from rgbd_envmap.render.differential import _fib_pattern

    rng = np.random.default_rng(4)
    N, m = 40, 16
    axis = rng.normal(size=(N, 3))
    axis[:3] = [[1, 0, 0], [-0.95, 0.3, 0.1], [0, 0, 1]]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    nrm = rng.normal(size=(N, 3))
    nrm[5] = -axis[5]  # faces away: no ray
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pts = rng.uniform(-1, 1, (N, 3))
    cos_max = rng.uniform(0.0, 0.999, N)
    cos_max[2] = 0.0
    idx = np.array([0, 1, 2, 5, 7, 11, 39])
    pattern = _fib_pattern(m)
    out = [np.empty((len(idx) * m, 3)), np.empty((len(idx) * m, 3)), np.empty(len(idx) * m, np.int64), np.empty(len(idx) * m)]
    k = cone_rays_kernel(pts, nrm, axis, cos_max, pattern, 1e-4, idx, *out)
    want = cone_rays(pts, nrm, axis, cos_max, pattern, 1e-4, idx)
    assert k == len(want[0])
    for got, w in zip(out, want):
        np.testing.assert_array_equal(got[:k], w)
    assert 5 not in idx[out[2][:k]]
    d, _ = cone_directions(axis[idx], cos_max[idx], m)
    cos = np.einsum("ck,cmk->cm", nrm[idx], d)
    ci, mi = np.nonzero(cos > 0)
    np.testing.assert_array_equal(out[2][:k], ci)
    np.testing.assert_allclose(out[1][:k], d[ci, mi], atol=1e-14)
    np.testing.assert_allclose(out[0][:k], pts[idx][ci] + 1e-4 * nrm[idx][ci], atol=1e-15)
    np.testing.assert_allclose(out[3][:k], cos[ci, mi], atol=1e-14)


@pytest.mark.parametrize("bands", [1, 3, 5, 8])
def test_ray_sh_sums_kernel_is_its_reference_bit_for_bit_and_the_sh_basis(bands):
    """Weight × SH basis summed per receiver: kernel against the plain-Python reference bit for bit,
    and against sh.basis summed with numpy to rounding; rays at the poles and on the seam."""
    from rgbd_envmap._kernels.occlusion_rays import ray_sh_sums_kernel
    from rgbd_envmap.reference.render_differential import ray_sh_sums

    rng = np.random.default_rng(8)
    d = rng.normal(size=(300, 3))
    d[:4] = [[0, 0, 1], [0, 0, -1], [-1, 0, 0], [1, 0, 0]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w = rng.uniform(0, 0.2, 300)
    owner = np.sort(rng.integers(0, 25, 300))
    sh_out, w_out = np.zeros((30, bands * bands)), np.zeros(30)
    ray_sh_sums_kernel(d, w, owner, bands, sh_out, w_out)
    want_sh, want_w = ray_sh_sums(d, w, owner, bands, 30)
    np.testing.assert_array_equal(sh_out, want_sh)
    np.testing.assert_array_equal(w_out, want_w)
    brute = np.zeros((30, bands * bands))
    np.add.at(brute, owner, w[:, None] * sh.basis(d, bands))
    np.testing.assert_allclose(sh_out, brute, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(w_out, np.bincount(owner, w, minlength=30), rtol=1e-13)
    assert (sh_out[25:] == 0).all()


def test_shadow_of_a_sphere_from_a_point_light_matches_the_closed_form():
    r, c = 0.05, np.array([0.0, 0.0, 0.08])
    v, f = icosphere(r, c)
    occ = ObjectOccluder(v, f)
    light = np.array([0.1, 0.05, 1.0])
    g = np.linspace(-0.3, 0.3, 121)
    pts = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([pts, np.zeros((len(pts), 1))], 1)
    nrm = np.tile([0, 0, 1.0], (len(pts), 1))
    lights = LightSet(((light) / np.linalg.norm(light))[None], np.ones((1, 3)), "test",
                      positions=light[None], origin=np.zeros(3))
    vis = light_visibility(lights, pts, nrm, occ)[:, 0]
    # closed form: the segment x → light meets the sphere
    w = c - pts
    u = light - pts
    t = np.clip(np.sum(w * u, 1) / np.sum(u * u, 1), 0, 1)
    dist = np.linalg.norm(w - t[:, None] * u, axis=1)
    sure = np.abs(dist - r) > 2e-3  # away from the penumbra-free edge (the mesh's facets)
    assert (vis[sure] == (dist[sure] > r)).all()
    assert (~vis).sum() > 100
    # without culling the same answer
    np.testing.assert_array_equal(vis, light_visibility(lights, pts, nrm, occ, cull=False)[:, 0])



def test_visibility_of_many_lights_is_that_of_each_alone():
    """One batch of shadow rays for every light gives each light's own answer (positioned lights on
    both sides of the object, a distant one, one below the receivers)."""
    r, c = 0.05, np.array([0.0, 0.0, 0.08])
    v, f = icosphere(r, c)
    occ = ObjectOccluder(v, f)
    g = np.linspace(-0.3, 0.3, 41)
    pts = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([pts, np.zeros((len(pts), 1))], 1)
    nrm = np.tile([0, 0, 1.0], (len(pts), 1))
    pos = np.array([[0.1, 0.05, 1.0], [-0.3, 0.2, 0.5], [0.0, 0.0, 0.3], [np.nan, np.nan, np.nan], [0.0, 0.1, -1.0]])
    dirs = np.array([[0.1, 0.05, 1.0], [-0.3, 0.2, 0.5], [0, 0, 1.0], [0.2, -0.1, 1.0], [0, 0.1, -1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lights = LightSet(dirs, np.ones((5, 3)), "test", positions=pos, origin=np.zeros(3))
    for cull in (True, False):
        vis = light_visibility(lights, pts, nrm, occ, cull=cull)
        for i in range(5):
            one = LightSet(dirs[i:i + 1], np.ones((1, 3)), "test", positions=pos[i:i + 1], origin=np.zeros(3))
            np.testing.assert_array_equal(vis[:, i], light_visibility(one, pts, nrm, occ, cull=cull)[:, 0])
        assert (~vis[:, :4]).any(axis=0).all() and vis[:, 4].all()  # light below the receivers: the object is not between


def test_shadow_ray_kernel_is_its_reference_bit_for_bit():
    from rgbd_envmap._kernels.shadow_rays import shadow_ray_candidates_kernel
    from rgbd_envmap.reference.render_differential import shadow_ray_candidates

    rng = np.random.default_rng(5)
    org = rng.uniform(-0.4, 0.4, (300, 3)) * [1, 1, 0.1]
    pos = np.concatenate([rng.uniform(-2, 2, (6, 3)) + [0, 0, 2], [[0, 0, 0.08]], [[0, 0, 0]]])  # one at the centre
    org[0] = pos[-1]  # a zero-length segment
    has = np.array([True] * 7 + [False])
    dirs = rng.normal(size=(8, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for cull in (True, False):
        size = len(org) * len(has)
        rows, cols, vec = np.empty(size, np.int64), np.empty(size, np.int64), np.empty((size, 3))
        k = shadow_ray_candidates_kernel(org, pos, has, dirs, np.array([0, 0, 0.08]), 0.05, cull, rows, cols, vec)
        r, c, v = shadow_ray_candidates(org, pos, has, dirs, [0, 0, 0.08], 0.05, cull)
        assert k == len(r) and (0 < k < size if cull else k == size)
        np.testing.assert_array_equal(rows[:k], r)
        np.testing.assert_array_equal(cols[:k], c)
        np.testing.assert_array_equal(vec[:k], v)

def test_occlusion_of_a_sphere_over_a_plane_is_its_view_factor():
    r, c = 0.05, np.array([0.0, 0.0, 0.1])
    v, f = icosphere(r, c)
    occ = ObjectOccluder(v, f)
    x = np.linspace(0.0, 0.3, 16)
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    nrm = np.tile([0, 0, 1.0], (len(pts), 1))
    rec = ReceiverMesh(pts, nrm, np.zeros((0, 3), np.int32))
    o = receiver_occlusion(rec, occ, 3, samples=256)
    d = np.linalg.norm(c - pts, axis=1)
    cos_t = (c - pts)[:, 2] / d
    expect = np.pi * (r / d) ** 2 * cos_t  # ∫ cos dω over a sphere wholly above the horizon
    np.testing.assert_allclose(o.blocked_cos, expect, rtol=0.04)
    # B_0 = Y_0 · F (Y_0 constant)
    np.testing.assert_allclose(o.blocked_sh[:, 0], o.blocked_cos * 0.5 / np.sqrt(np.pi), rtol=1e-9)


def test_first_hits_give_the_hit_triangle_and_its_barycentric_weights():
    v, f = icosphere(0.05, [0.0, 0.0, 0.1], subdiv=2)
    occ = ObjectOccluder(v, f)
    rng = np.random.default_rng(5)
    org = rng.normal(scale=0.02, size=(400, 3)) + [0.0, 0.0, -0.5]
    tgt = v[rng.integers(len(v), size=400)] * 0.9 + 0.1 * np.array([0.0, 0.0, 0.1])  # inside the sphere
    vec = np.concatenate([tgt - org, [[1.0, 0.0, 0.0]]])  # and one that misses
    org = np.concatenate([org, [[0.0, 0.0, -0.5]]])
    hit, tri, bary = occ.first_hits(org, vec)
    assert hit[:-1].all() and not hit[-1] and not bary[-1].any()
    np.testing.assert_allclose(bary[hit].sum(axis=1), 1.0, atol=1e-6)
    assert (bary[hit] >= -1e-6).all()
    # the barycentric point lies on the ray, and is the nearest of all the triangles' hits
    p = np.einsum("nk,nkd->nd", bary[hit], v[f[tri[hit]]])
    d = vec[hit] / np.linalg.norm(vec[hit], axis=1, keepdims=True)
    off = p - org[hit]
    np.testing.assert_allclose(np.linalg.norm(np.cross(off, d), axis=1), 0.0, atol=2e-6)
    assert (np.einsum("nd,nd->n", off, d) > 0).all()
    np.testing.assert_array_equal(occ.blocked(org, vec), hit)


def test_bounce_weights_sum_to_the_view_factor_and_see_the_side_facing_the_receiver():
    """The object's light onto a receiver comes from its side that faces it: a sphere whose upper
    half has radiance 10 and lower half 1, over points straight below it (which see only a cap
    below the equator) gives them F · 1, not F times the mean radiance (5.5); a point far to the
    side sees part of the upper half. Each weight row sums to F."""
    r, c = 0.05, np.array([0.0, 0.0, 0.1])
    v, f = icosphere(r, c)
    occ = ObjectOccluder(v, f)
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.03], [0.0, 0.0, -0.2], [0.4, 0.0, 0.0]])
    nrm = np.tile([0, 0, 1.0], (len(pts), 1))
    o = receiver_occlusion(ReceiverMesh(pts, nrm, np.zeros((0, 3), np.int32)), occ, 3, samples=256)
    assert o.bounce.shape == (len(pts), len(v))
    np.testing.assert_allclose(np.asarray(o.bounce.sum(axis=1)).ravel(), o.blocked_cos, rtol=1e-12)
    colours = np.where(v[:, 2:] > c[2], 10.0, 1.0) * np.ones((1, 3))
    got = o.bounced(colours)
    np.testing.assert_allclose(got[:3], np.repeat(o.blocked_cos[:3, None], 3, axis=1), rtol=1e-9)
    assert o.blocked_cos[3] > 0 and 1.05 < got[3, 0] / o.blocked_cos[3] < 5.5
    # uniform colours: the mean radiance's answer
    np.testing.assert_allclose(o.bounced(np.full((len(v), 3), 2.0)), 2.0 * o.blocked_cos[:, None] * np.ones((1, 3)),
                               rtol=1e-9)
    # an occlusion without weights falls back to the mean radiance
    from rgbd_envmap.render.differential import ReceiverOcclusion

    mean = ReceiverOcclusion(o.blocked_sh, o.blocked_cos).bounced(colours)
    np.testing.assert_allclose(mean, o.blocked_cos[:, None] * colours.mean(axis=0)[None], rtol=1e-12)


def _lights_and_receivers(seed: int, n: int, m: int, distant: list[int]):
    """Random unit directions (n, 3), an origin, positions along them 0.3–3 m out (NaN rows: the
    ``distant`` lights), and m receiver points around the origin with random unit normals."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origin = np.array([0.2, -0.1, 1.0])
    pos = origin + d * rng.uniform(0.3, 3.0, (n, 1))
    pos[distant] = np.nan
    pts = origin + rng.normal(scale=0.5, size=(m, 3))
    nrm = rng.normal(size=(m, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return rng, d, origin, pos, pts, nrm


def test_light_weights_kernel_is_its_reference_bit_for_bit():
    """The compiled weights against the pair-by-pair reference: positioned and distant lights mixed
    (a NaN position is a distant light), points on a light (the 1e-12 floor), back-facing normals."""
    from rgbd_envmap.reference.render_differential import light_weights
    from rgbd_envmap.render.differential import _light_weights_unshadowed

    n = 9
    _, d, origin, pos, pts, nrm = _lights_and_receivers(11, n, 300, [2, 5])
    pts[7] = pos[0]  # on a light
    for lights in (LightSet(d, np.ones((n, 3)), "t", positions=pos, origin=origin), LightSet(d, np.ones((n, 3)), "t")):
        got = _light_weights_unshadowed(lights, pts, nrm)
        want = light_weights(pts, nrm, lights.positions, lights.directions, lights.origin)
        np.testing.assert_array_equal(got, want)
        assert (got >= 0).all() and np.isfinite(got).all()
    assert _light_weights_unshadowed(lights, pts[:0], nrm[:0]).shape == (0, n)


def test_light_irradiance_kernel_is_its_reference_bit_for_bit():
    """The fused irradiance (without / with shadows) against the reference's weights summed light
    by light: mixed light kinds, coloured powers, random visibility; and against the weights'
    matrix product to rounding."""
    from rgbd_envmap.reference.render_differential import light_irradiance
    from rgbd_envmap.render.differential import _light_irradiance, _light_weights_unshadowed

    n = 11
    rng, d, origin, pos, pts, nrm = _lights_and_receivers(12, n, 250, [1, 6])
    power = rng.uniform(0.0, 2.0, (n, 3))
    vis = rng.random((250, n)) < 0.7
    lights = LightSet(d, power, "t", positions=pos, origin=origin)
    got_all, got_vis = _light_irradiance(lights, pts, nrm, vis)
    want_all, want_vis = light_irradiance(pts, nrm, lights.positions, lights.directions, lights.origin, power, vis)
    np.testing.assert_array_equal(got_all, want_all)
    np.testing.assert_array_equal(got_vis, want_vis)
    w = _light_weights_unshadowed(lights, pts, nrm)
    np.testing.assert_allclose(got_all, w @ power, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(got_vis, (w * vis) @ power, rtol=1e-12, atol=1e-300)
    assert (got_vis <= got_all + 1e-15).all()
    none = _light_irradiance(LightSet(d[:0], power[:0], "t"), pts, nrm, vis[:, :0])
    assert (none[0] == 0).all() and (none[1] == 0).all()

def test_direct_irradiance_equals_the_light_sets_own():
    rng = np.random.default_rng(3)
    n = 7
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    power = rng.uniform(0, 2, (n, 3))
    origin = np.array([0.1, 0.2, 0.9])
    pos = origin + d * rng.uniform(0.5, 3, (n, 1))
    pts = origin + rng.normal(scale=0.2, size=(50, 3))
    nrm = rng.normal(size=(50, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    point = LightSet(d, power, "t", positions=pos, origin=origin)
    np.testing.assert_allclose(direct_irradiance(point, pts, nrm), irradiance(point, nrm, pts), rtol=1e-9, atol=1e-12)
    distant = LightSet(d, power, "t")
    np.testing.assert_allclose(direct_irradiance(distant, pts, nrm), irradiance(distant, nrm), rtol=1e-9, atol=1e-12)
    vis = rng.random((50, n)) > 0.5
    brute = np.einsum("pl,plc->pc", vis * np.maximum(nrm @ d.T, 0), np.broadcast_to(power, (50, n, 3)))
    np.testing.assert_allclose(direct_irradiance(distant, pts, nrm, vis), brute, rtol=1e-9, atol=1e-12)


def test_lights_plus_indirect_sh_count_the_energy_once():
    H, W = 64, 128
    d = equirect_directions(H, W).astype(np.float64)
    omega = equirect_solid_angles(H, W)
    rad = 0.2 + 0.1 * np.maximum(d[..., :1], 0) * np.array([1.0, 0.8, 0.6])
    lamp = d @ np.array([0.3, 0.2, 0.93]) > 0.985
    rad[lamp] = [9.0, 8.5, 8.0]
    rad = rad.astype(np.float32)
    split = split_direct_indirect(rad, 0.5)
    lights = sample_lights(rad, 200, "q2tree", valid=split.direct)
    coeffs = sh.project_equirect(split.indirect, bands=5)
    rng = np.random.default_rng(0)
    nrm = rng.normal(size=(40, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    e = irradiance(lights, nrm) + sh.irradiance(coeffs, nrm)
    brute = np.einsum("hwc,nhw->nc", rad * omega[..., None], np.maximum(np.einsum("nk,hwk->nhw", nrm, d), 0))
    np.testing.assert_allclose(e, brute, rtol=0.03)


def _receiver_terms(R: int, K: int, Kb: int, seed: int = 5):
    """Random receivers' transfers and terms for the ratio kernel: float32 transfers (K, R), some
    rows with no light at all (E0 = 0), bright object light (ratios clipped at 4), a floor above
    E0 at a third of the rows."""
    rng = np.random.default_rng(seed)
    t0 = rng.normal(0.3, 0.5, (K, R)).astype(np.float32)
    t1 = (t0 - np.abs(rng.normal(0, 0.2, (K, R)))).astype(np.float32)
    bt = np.abs(rng.normal(0, 0.1, (Kb, R))).astype(np.float32)
    coeffs = rng.normal(0.5, 0.3, (K, 3))
    bc = np.abs(rng.normal(0, 2.0, (Kb, 3)))
    add0 = np.abs(rng.normal(0, 1, (R, 3)))
    add1 = add0 * rng.uniform(0, 1, (R, 3))
    t0[:, :5] = t1[:, :5] = 0.0
    add0[:5] = add1[:5] = 0.0
    bt[:, :3] = 0.0
    floor = np.where(rng.random((R, 1)) < 0.3, 3.0 * add0 + 1.0, 0.0)
    floor[:5] = 0.0
    keep = rng.uniform(0, 1, R)
    return t0, t1, coeffs, bt, bc, add0, add1, floor, keep


@pytest.mark.parametrize("R,K,nk,Kb,use_floor", [(1300, 25, 25, 25, True), (1300, 25, 9, 16, False),
                                                 (7, 9, 4, 0, True), (0, 9, 9, 9, True)])
def test_receiver_ratio_kernel_is_its_reference_bit_for_bit(R, K, nk, Kb, use_floor):
    """The fused receiver shading (three blocked SH products, the floor, the ratio, the far flags)
    against the reference's plain numpy sums; across a block boundary (R > 512), with fewer
    coefficients than the transfers hold, no object light, no receivers."""
    from rgbd_envmap._kernels.receiver_shading import receiver_ratio_kernel
    from rgbd_envmap.render.composite import RATIO_EPS
    from rgbd_envmap.reference.render_differential import receiver_ratio_terms

    t0, t1, coeffs, bt, bc, add0, add1, floor, keep = _receiver_terms(R, K, Kb)
    ratio, far = np.empty((R, 3), np.float32), np.empty(R, bool)
    s = np.empty((3, 3, R))
    n_far = receiver_ratio_kernel(t0, t1, nk, coeffs, bt, Kb, bc, add0, add1, floor, use_floor, keep, 1e-6, 4.0,
                                  RATIO_EPS, s[0], s[1], s[2], ratio, far)
    want_ratio, want_far = receiver_ratio_terms(t0, t1, coeffs[:nk], bt, bc[:Kb], add0, add1,
                                                floor if use_floor else None, keep)
    np.testing.assert_array_equal(ratio, want_ratio)
    np.testing.assert_array_equal(far, want_far)
    assert n_far == int(want_far.sum())
    if R:
        assert (ratio[:5] == 1).all() and not far[:5].any()  # no light: left as it is
        assert ratio.max() <= 4.0 and ratio.min() >= 0.0
        # the products themselves against numpy's matrix products, to rounding
        e0 = np.maximum(t0[:nk].T.astype(np.float64) @ coeffs[:nk], 0) + add0
        if use_floor:
            e0 = np.maximum(e0, floor)
        np.testing.assert_allclose(s[0].T, e0, rtol=1e-12, atol=1e-12)


def test_faces_touching_kernel_is_its_reference():
    from rgbd_envmap._kernels.receiver_shading import faces_touching_kernel
    from rgbd_envmap.reference.render_differential import faces_touching

    rng = np.random.default_rng(2)
    faces = rng.integers(0, 200, (600, 3)).astype(np.int32)
    for far in (rng.random(200) < 0.1, np.zeros(200, bool), np.ones(200, bool)):
        out = np.empty_like(faces)
        n = faces_touching_kernel(faces, far, out)
        np.testing.assert_array_equal(out[:n], faces_touching(faces, far))
    assert faces_touching_kernel(faces[:0], far, out) == 0


def test_receiver_ratio_floor_and_clip():
    """E_with / E_without given directly (no SH part): 1 where E_without is 0 (no light to change),
    clipped at 4, and only the vertex whose ratio differs from 1 flagged."""
    from rgbd_envmap._kernels.receiver_shading import receiver_ratio_kernel
    from rgbd_envmap.render.composite import RATIO_EPS

    e0, e1 = np.array([[1.0, 2, 0], [0, 0, 0]]), np.array([[0.5, 10, 3], [1, 1, 1]])
    none, t = np.zeros((0, 3)), np.zeros((0, 2), np.float32)
    ratio, far, s = np.empty((2, 3), np.float32), np.empty(2, bool), np.empty((3, 3, 2))
    n = receiver_ratio_kernel(t, t, 0, none, t, 0, none, e0, e1, np.zeros((2, 3)), False, np.ones(2), 1e-6, 4.0,
                              RATIO_EPS, s[0], s[1], s[2], ratio, far)
    np.testing.assert_allclose(ratio, [[0.5, 4.0, 1.0], [1, 1, 1]])
    assert n == 1 and far.tolist() == [True, False]


def test_shader_darkens_the_shadow_and_leaves_far_points():
    r, c = 0.04, np.array([0.0, 0.0, 0.05])
    v, f = icosphere(r, c, 3)
    nv = (v - c) / r
    shader = DifferentialShader(v, f, nv, samples=64)
    g = np.linspace(-0.4, 0.4, 41)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    shader.set_receivers(ReceiverMesh(pts, np.tile([0, 0, 1.0], (len(pts), 1)), np.zeros((0, 3), np.int32)), 3)
    light = np.array([0.0, 0.0, 2.0])
    lights = LightSet(np.array([[0, 0, 1.0]]), np.full((1, 3), 1.0), "t", positions=light[None], origin=np.zeros(3))
    coeffs = np.zeros((9, 3))
    coeffs[0] = 0.1 * 2 * np.sqrt(np.pi)  # uniform radiance 0.1
    transfer = np.zeros((len(v), 9))
    colours, ratio = shader.shade(lights, coeffs, transfer, np.full(3, 0.5))
    below = np.argmin(np.linalg.norm(pts, axis=1))
    far = np.argmax(np.linalg.norm(pts, axis=1))
    assert ratio[below].max() < 0.2
    np.testing.assert_allclose(ratio[far], 1.0, atol=0.01)
    # object radiance: albedo / π · the light's irradiance on the top vertex (I = power · |p − o|² = 4)
    top = np.argmax(v[:, 2])
    e_top = 4.0 / (light[2] - v[top, 2]) ** 2
    np.testing.assert_allclose(colours[top], 0.5 / np.pi * e_top, rtol=1e-3)
    bottom = np.argmin(v[:, 2])
    np.testing.assert_allclose(colours[bottom], 0.0, atol=1e-9)  # faces away from the light


def _sphere_over_grid(n: int = 21):
    """An icosphere (r 4 cm, centre 5 cm up) and a flat grid of receivers under it (±0.3 m, normals up)."""
    r, c = 0.04, np.array([0.0, 0.0, 0.05])
    v, f = icosphere(r, c, 3)
    g = np.linspace(-0.3, 0.3, n)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    return v, f, (v - c) / r, ReceiverMesh(pts, np.tile([0, 0, 1.0], (len(pts), 1)), np.zeros((0, 3), np.int32))


def test_receivers_with_an_occlusion_computed_elsewhere_shade_the_same():
    """set_receivers(occlusion=...) with receiver_occlusion of the same mesh (against another occluder
    of the same object, as a rebuild on another thread does) shades as computing it there; an
    occlusion of another mesh or band count is refused."""
    v, f, nv, mesh = _sphere_over_grid()
    pts = mesh.vertices
    lights = LightSet(np.array([[0, 0, 1.0]]), np.ones((1, 3)), "t", positions=np.array([[0.1, 0, 2.0]]), origin=np.zeros(3))
    coeffs = np.zeros((9, 3))
    coeffs[0] = 0.3
    args = (lights, coeffs, np.zeros((len(v), 9)), np.full(3, 0.5))
    a, b = DifferentialShader(v, f, nv, samples=16), DifferentialShader(v, f, nv, samples=16)
    a.set_receivers(mesh, 3)
    b.set_receivers(mesh, 3, occlusion=receiver_occlusion(mesh, ObjectOccluder(v, f), 3, samples=16))
    for x, y in zip(a.shade(*args), b.shade(*args)):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(RgbdEnvmapError, match="occlusion"):
        b.set_receivers(mesh, 3, occlusion=receiver_occlusion(mesh, ObjectOccluder(v, f), 2, samples=16))
    with pytest.raises(RgbdEnvmapError, match="occlusion"):
        b.set_receivers(ReceiverMesh(pts[:5], mesh.normals[:5], np.zeros((0, 3), np.int32)), 3,
                        occlusion=a._occlusion)


def test_albedo_floor_adds_the_light_the_map_missed():
    """With the map's radiance of the receivers, E_without ≥ π L / max_albedo: where the lights and
    SH give less, the missing light M is added to E_without and M (1 − F/π) to E_with, so each ratio
    moves from the unfloored one towards 1 − F/π (a convex combination of the two)."""
    r, c = 0.04, np.array([0.0, 0.0, 0.05])
    v, f = icosphere(r, c, 3)
    shader = DifferentialShader(v, f, (v - c) / r, samples=64)
    g = np.linspace(-0.3, 0.3, 25)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    mesh = ReceiverMesh(np.concatenate([xy, np.zeros((len(xy), 1))], 1), np.tile([0, 0, 1.0], (len(xy), 1)),
                        np.zeros((0, 3), np.int32))
    lights = LightSet(np.array([[0, 0, 1.0]]), np.full((1, 3), 1.0), "t", positions=[[0.0, 0.0, 2.0]],
                      origin=np.zeros(3))
    coeffs = np.zeros((9, 3))
    coeffs[0] = 0.1 * 2 * np.sqrt(np.pi)
    args = (lights, coeffs, np.zeros((len(v), 9)), np.full(3, 0.5))
    shader.set_receivers(mesh, 3)
    plain = shader.shade(*args)[1].astype(np.float64)
    F = shader._occlusion.blocked_cos
    # a dark surface (radiance below what it receives × albedo): no change, bit for bit
    shader.set_receivers(mesh, 3, radiance=np.zeros((len(xy), 3)))
    np.testing.assert_array_equal(shader.shade(*args)[1], plain)
    shader.set_receivers(mesh, 3, radiance=np.full((len(xy), 3), np.nan))  # unseen: NaN counts as dark
    np.testing.assert_array_equal(shader.shade(*args)[1], plain)
    # far too bright for the light the map has: the ratio is the uniform missing light's, 1 − F/π
    shader.set_receivers(mesh, 3, radiance=np.full((len(xy), 3), 1e6))
    np.testing.assert_allclose(shader.shade(*args)[1], np.repeat(1 - F[:, None] / np.pi, 3, 1), atol=1e-5)
    # in between: between the two, and the same with half the radiance and half the largest albedo
    shader.set_receivers(mesh, 3, radiance=np.full((len(xy), 3), 1.0))
    mid = shader.shade(*args)[1].astype(np.float64)
    lo, hi = np.minimum(plain, 1 - F[:, None] / np.pi), np.maximum(plain, 1 - F[:, None] / np.pi)
    assert (mid >= lo - 1e-6).all() and (mid <= hi + 1e-6).all()
    assert (np.abs(mid - plain) > 1e-3).any()
    shader.set_receivers(mesh, 3, radiance=np.full((len(xy), 3), 0.5), max_albedo=0.5)
    np.testing.assert_allclose(shader.shade(*args)[1], mid, rtol=1e-6)
    with pytest.raises(RgbdEnvmapError):
        shader.set_receivers(mesh, 3, radiance=np.ones((3, 3)))
    with pytest.raises(RgbdEnvmapError):
        shader.set_receivers(mesh, 3, radiance=np.ones((len(xy), 3)), max_albedo=0.0)


def test_surface_radiance_reads_the_pixel_of_each_points_direction():
    H, W = 16, 32
    rad = np.arange(H * W * 3, dtype=np.float32).reshape(H, W, 3)
    valid = np.ones((H, W), bool)
    valid[3, 7] = False
    origin = np.array([0.5, -1.0, 1.2])
    d = equirect_directions(H, W).astype(np.float64)
    rng = np.random.default_rng(2)
    rows, cols = np.divmod(np.arange(H * W), W)
    pts = origin + d[rows, cols] * rng.uniform(0.1, 5.0, (H * W, 1))
    got = surface_radiance(rad, valid, origin, pts)
    want = rad[rows, cols].astype(np.float64)
    want[~valid[rows, cols]] = np.nan
    np.testing.assert_array_equal(got, want)
    # across the seam and at the poles: the nearest pixel centre
    seam = np.array([[np.cos(np.pi - 1e-9), np.sin(np.pi - 1e-9), 0.0], [np.cos(-np.pi + 1e-9), np.sin(-np.pi + 1e-9), 0.0]])
    poles = np.array([[0, 0, 1.0], [0, 0, -1.0], [1e-12, 0, 1.0]])
    out = surface_radiance(rad, valid, origin, origin + np.concatenate([seam, poles]))
    assert {tuple(x) for x in out[:2]} <= {tuple(rad[7, 0]), tuple(rad[7, W - 1]), tuple(rad[8, 0]), tuple(rad[8, W - 1])}
    assert np.isin(out[2], rad[0]).all() and np.isin(out[4], rad[0]).all()
    assert np.isin(out[3], rad[H - 1]).all()
    # the origin itself, and no points
    assert np.isnan(surface_radiance(rad, valid, origin, origin[None])).all()
    assert surface_radiance(rad, valid, origin, np.zeros((0, 3))).shape == (0, 3)
    with pytest.raises(RgbdEnvmapError):
        surface_radiance(rad, valid[:-1], origin, pts)
    with pytest.raises(RgbdEnvmapError):
        surface_radiance(rad, valid, origin, np.full((1, 3), np.nan))


def test_shader_bounce_from_prt_coefficients_equals_the_vertex_form():
    """With ``object_coeffs`` the receivers' bounce light is (bounce @ transfer) @ coeffs: the same
    ratio as the sparse product with the PRT colours themselves, to their float32 rounding; a new
    transfer (another object shading) is not served from the cached product."""
    from rgbd_envmap import prt

    v, f, nv, rec = _sphere_over_grid()
    pts = rec.vertices
    rng = np.random.default_rng(2)
    transfer = prt.unoccluded_transfer(nv, 3).astype(np.float32)
    coeffs = rng.normal(0, 0.2, (9, 3))
    coeffs[0] = 3.0
    albedo = np.array([0.6, 0.5, 0.4])
    colours = prt.shade(transfer, coeffs, albedo)
    ind = 0.5 * coeffs
    a, b = DifferentialShader(v, f, nv, samples=32), DifferentialShader(v, f, nv, samples=32)
    a.set_receivers(rec, 3)
    b.set_receivers(rec, 3)
    _, ra = a.shade(None, ind, transfer, albedo, object_colours=colours, object_coeffs=coeffs)
    _, rb = b.shade(None, ind, transfer, albedo, object_colours=colours)
    assert (np.abs(ra - 1) > 1e-3).any()  # the object changes the receivers at all
    np.testing.assert_allclose(ra, rb, rtol=1e-5, atol=1e-6)
    # a lit top and a dark bottom: the receivers below see the dark side
    other = transfer.copy()
    other[v[:, 2] < 0.05] *= 0.1  # below the centre
    _, r2 = a.shade(None, ind, other, albedo, object_colours=prt.shade(other, coeffs, albedo), object_coeffs=coeffs)
    _, r3 = b.shade(None, ind, other, albedo, object_colours=prt.shade(other, coeffs, albedo))
    np.testing.assert_allclose(r2, r3, rtol=1e-5, atol=1e-6)
    below = np.argmin(np.linalg.norm(pts, axis=1))
    assert r2[below].mean() < ra[below].mean()


# --- the composite ---------------------------------------------------------------------------------

def random_layers(rng, H=40, W=60):
    colour = rng.uniform(0, 1.2, (H, W, 3)).astype(np.float32)
    mask = rng.random((H, W)) < 0.3
    alpha = np.where(rng.random((H, W)) < 0.5, rng.uniform(0, 1, (H, W)), 0).astype(np.float32)
    obj = Layer(np.where(mask[..., None], colour, 0).astype(np.float32), mask, np.where(mask, 0, alpha).astype(np.float32),
                (0, H, 0, W))
    ratio = rng.uniform(0, 2, (H, W, 3)).astype(np.float32)
    ratio[rng.random((H, W)) < 0.2] = np.float32(1.0005)  # within RATIO_EPS of 1: left as it is
    rmask = rng.random((H, W)) < 0.6
    rec = Layer(np.where(rmask[..., None], ratio, 0).astype(np.float32), rmask, np.zeros((H, W), np.float32), (0, H, 0, W))
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return frame, obj, rec


def test_kernel_and_reference_share_the_ratio_tolerance():
    from rgbd_envmap._kernels.differential import RATIO_EPS as kernel_eps
    from rgbd_envmap.reference.render_differential import RATIO_EPS as ref_eps
    assert kernel_eps == ref_eps


@pytest.mark.parametrize("with_m", [False, True])
def test_composite_differential_matches_its_reference_bit_for_bit(with_m):
    rng = np.random.default_rng(5)
    frame, obj, rec = random_layers(rng)
    m = np.array([[1.1, 0.05, -0.02], [0.03, 0.95, 0.01], [-0.01, 0.04, 1.05]]) if with_m else None
    got = composite_differential(frame, obj, rec, ccm_inverse=m, shadow_grey=0.2)
    np.testing.assert_array_equal(got, composite_ref(frame, obj, rec, ccm_inverse=m, shadow_grey=0.2))


def test_composite_differential_reduces_to_paper003_without_receivers_and_to_the_frame_at_ratio_one():
    rng = np.random.default_rng(6)
    frame, obj, rec = random_layers(rng)
    empty = Layer.empty(*frame.shape[:2])
    np.testing.assert_array_equal(composite_differential(frame, obj, empty, shadow_grey=0.2),
                                  composite(frame, obj, shadow_grey=0.2))
    ones = Layer(np.ones(frame.shape, np.float32), np.ones(frame.shape[:2], bool), np.zeros(frame.shape[:2], np.float32),
                 (0, frame.shape[0], 0, frame.shape[1]))
    np.testing.assert_array_equal(composite_differential(frame, Layer.empty(*frame.shape[:2]), ones), frame)
    np.testing.assert_array_equal(composite_differential(frame, empty, empty), frame)
    # half the light: the linear frame halves
    half = Layer(np.full(frame.shape, 0.5, np.float32), ones.mask, ones.plane_alpha, ones.bbox)
    from rgbd_envmap.reference.render_composite import decode_srgb8, encode_srgb8
    # (within one code: the library decodes through a float32 table)
    diff = composite_differential(frame, empty, half).astype(int) - encode_srgb8(0.5 * decode_srgb8(frame))
    assert np.abs(diff).max() <= 1 and (diff != 0).mean() < 0.02


def test_shader_reuses_the_rays_of_a_light_that_moved_less_than_cache_deg():
    v, f = icosphere(0.04, [0.0, 0.0, 0.05], 2)
    shader = DifferentialShader(v, f, (v - [0, 0, 0.05]) / 0.04, samples=8, cache_deg=0.5)
    pts = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    shader.set_receivers(ReceiverMesh(pts, np.tile([0, 0, 1.0], (2, 1)), np.zeros((0, 3), np.int32)), 2)
    coeffs = np.zeros((4, 3))

    def lights_at(p):
        p = np.asarray(p, float)
        return LightSet((p / np.linalg.norm(p))[None], np.ones((1, 3)), "t", positions=p[None], origin=np.zeros(3))

    _, r1 = shader.shade(lights_at([0, 0, 2.0]), coeffs, np.zeros((len(v), 4)), np.full(3, 0.5))
    first = shader.cached_lights
    _, r2 = shader.shade(lights_at([0.005, 0, 2.0]), coeffs, np.zeros((len(v), 4)), np.full(3, 0.5))
    assert shader.cached_lights == first  # 0.14° from the object's centre: its rays reused
    np.testing.assert_allclose(r1, r2, atol=1e-5)  # the receiver under the object stays in shadow
    assert r1[0].max() < 0.2 and np.abs(r1[1] - 1).max() < 1e-3  # (the lit object reflects onto both)
    shader.shade(lights_at([0.05, 0, 2.0]), coeffs, np.zeros((len(v), 4)), np.full(3, 0.5))
    assert shader.cached_lights != first  # 1.4°: cast anew


def test_shader_called_again_with_the_same_lights_reuses_their_terms_exactly():
    """The same LightSet object again (a pipeline that kept its lights): only the SH part is recomputed,
    and the result is what a fresh shader computes for those lights and the new coefficients."""
    c = np.array([0.0, 0.0, 0.05])
    v, f = icosphere(0.04, c, 2)
    nv = (v - c) / 0.04
    g = np.linspace(-0.3, 0.3, 9)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pts = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    rec = ReceiverMesh(pts, np.tile([0, 0, 1.0], (len(pts), 1)), np.zeros((0, 3), np.int32))
    p = np.array([[0.1, 0.0, 2.0], [-1.0, 0.5, 1.5]])
    lights = LightSet(p / np.linalg.norm(p, axis=1, keepdims=True), np.array([[1.0, 0.9, 0.8], [0.2, 0.2, 0.3]]), "t",
                      positions=p, origin=np.zeros(3))
    transfer = np.random.default_rng(0).uniform(0, 0.1, (len(v), 9))
    c1, c2 = np.zeros((9, 3)), np.zeros((9, 3))
    c1[0], c2[0] = 0.3, 0.5
    c2[2] = 0.1
    def fresh_shade(light_set, obj):
        fresh = DifferentialShader(v, f, nv, samples=16)
        fresh.set_receivers(rec, 3)
        return fresh.shade(light_set, c2, transfer, np.full(3, 0.5), object_colours=obj)

    for obj in (None, np.full((len(v), 3), 0.2, np.float32)):
        shader = DifferentialShader(v, f, nv, samples=16)
        shader.set_receivers(rec, 3)
        shader.shade(lights, c1, transfer, np.full(3, 0.5), object_colours=obj)
        got = shader.shade(lights, c2, transfer, np.full(3, 0.5), object_colours=obj)
        want = fresh_shade(lights, obj)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        # another light set, equal or not, is computed anew
        moved = LightSet(lights.directions, 2 * lights.power, "t", positions=p, origin=np.zeros(3))
        twice = shader.shade(moved, c2, transfer, np.full(3, 0.5), object_colours=obj)
        assert not np.array_equal(twice[1], got[1])
        # a new set with one light where it was and one moved: the kept light's shadow rays are
        # reused, and the result is a fresh shader's
        q = p.copy()
        q[1] += [0.3, 0.0, 0.0]
        shifted = LightSet(q / np.linalg.norm(q, axis=1, keepdims=True), lights.power, "t", positions=q, origin=np.zeros(3))
        again = shader.shade(shifted, c2, transfer, np.full(3, 0.5), object_colours=obj)
        want = fresh_shade(shifted, obj)
        np.testing.assert_array_equal(again[0], want[0])
        np.testing.assert_array_equal(again[1], want[1])
        assert not np.array_equal(again[1], twice[1])
