"""Reference frames: Mitsuba's path tracer rendering a camera's view of the scene, with or without extra
meshes (the virtual object), in linear radiance before any camera processing.

The camera rays are the simulator's own (:func:`rgbd_envmap.geometry.pixel_rays`: through each pixel
centre, with the lens distortion), so a reference pixel and a simulated pixel see the same point; each
pixel averages ``spp`` independent paths. Rendering the frame with and without the virtual object
from the same random sequence makes their difference (the object's shadow and the light it bounces)
nearly free of noise where the object changes nothing.

:func:`render_reference_pair` renders that pair for a virtual object, the ground truth of a composite:
both are rendered only in a region of interest (the pixels that see the object or a surface within
``radius_m`` of it, where its shadow and its bounce light fall); elsewhere the object
changes the scene by less than the comparison resolves, and both frames hold the bake's radiance
(the simulated camera's own truth, within 2 % of path tracing: tests/sim/test_lit_world.py).
``radius_m=None`` renders every pixel. The function's docstring describes the two methods.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_number
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics, RigidTransform
from sim.mitsuba_scene import ExtraMesh, build_scene, trace
from sim.scene import Scene

__all__ = ["ReferenceFrame", "ReferencePair", "EmitterQuad", "emitter_quads", "render_reference", "render_reference_pair",
           "camera_rays"]


@dataclass(frozen=True)
class ReferenceFrame:
    """A path-traced view.

    Attributes:
        radiance: (H, W, 3) float32 linear radiance arriving at the camera through each pixel centre.
        hit: (H, W) bool, the pixel's ray meets a surface.
        spp: paths per pixel. t_s: the scene time rendered. seconds: wall time of the render.
    """

    radiance: np.ndarray
    hit: np.ndarray
    spp: int
    t_s: float
    seconds: float


@dataclass(frozen=True)
class ReferencePair:
    """A view path-traced with and without a virtual object (see :func:`render_reference_pair`).

    Attributes:
        with_object, without_object: (H, W, 3) float32 linear radiance through each pixel centre.
        object_mask: (H, W) bool, the pixel's ray meets the object first.
        traced: (H, W) bool, the pixel was rendered (the region of interest); elsewhere both
            frames hold the bake's radiance.
        hit: (H, W) bool, the ray meets a surface (the object or the scene).
        noise_with, noise_without: (H, W, 3) float32 standard error of each pixel's mean (from the
            spread of its two halves of paths; 0 outside ``traced``).
        spp, t_s, seconds: paths per traced pixel (each frame), the scene time, wall time.
    """

    with_object: np.ndarray
    without_object: np.ndarray
    object_mask: np.ndarray
    traced: np.ndarray
    hit: np.ndarray
    noise_with: np.ndarray
    noise_without: np.ndarray
    spp: int
    t_s: float
    seconds: float


def camera_rays(T_world_from_cam: RigidTransform, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """World origin (3,) and unit directions (H·W, 3) of every pixel centre (row-major)."""
    rays = pixel_rays(intrinsics).reshape(-1, 3)
    rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    return np.asarray(T_world_from_cam.translation, np.float64), T_world_from_cam.rotate(rays)


def render_reference(scene: Scene, T_world_from_cam: RigidTransform, intrinsics: Intrinsics, t_s: float,
                     *, spp: int = 64, extra: Sequence[ExtraMesh] = (), seed: int = 0) -> ReferenceFrame:
    """Path-trace the camera's view of ``scene`` at time ``t_s`` (visible objects, emitters at their
    scale), with ``extra`` meshes added."""
    import time

    spp = int(check_number(spp, "spp", low=1, high=1 << 16, integer=True))
    start = time.perf_counter()
    visible = frozenset(i for i, o in enumerate(scene.objects) if o.visible_at(t_s))
    scale = [o.scale_at(t_s) for o in scene.objects]
    mi_scene = build_scene(scene, visible, scale, extra=extra)
    origin, dirs = camera_rays(T_world_from_cam, intrinsics)
    origins = np.broadcast_to(origin, dirs.shape)
    acc = np.zeros((len(dirs), 3), np.float64)
    for k in range(spp):
        acc += trace(mi_scene, origins, dirs, seed=seed * 100_003 + k)
    hit = _hits(mi_scene, origin, dirs)
    h, w = intrinsics.height, intrinsics.width
    return ReferenceFrame((acc / spp).astype(np.float32).reshape(h, w, 3), hit.reshape(h, w), spp, float(t_s),
                          time.perf_counter() - start)


def _hits(mi_scene, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    from sim.mitsuba_scene import mitsuba

    mi = mitsuba()
    d = np.asarray(dirs, np.float32)
    ray = mi.Ray3f(mi.Point3f(*[float(x) for x in origin]),
                   mi.Vector3f(mi.Float(np.ascontiguousarray(d[:, 0])), mi.Float(np.ascontiguousarray(d[:, 1])),
                               mi.Float(np.ascontiguousarray(d[:, 2]))))
    return np.asarray(mi_scene.ray_test(ray)).astype(bool)


def _object_caster(vertices: np.ndarray, faces: np.ndarray):
    """An open3d ray caster of the object alone (built once per reference pair)."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(faces, np.uint32)))
    return rc


def _distance(rc, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance (N,) along rays (N origins or one, N directions) to the object (inf where they miss)."""
    import open3d as o3d

    rays = np.concatenate([np.broadcast_to(np.asarray(origins, np.float32), dirs.shape), np.asarray(dirs, np.float32)],
                          axis=1)
    return rc.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)))["t_hit"].numpy()


def _cone_directions(axis: np.ndarray, cos_max: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """(N, m, 3) unit directions uniform in the cone of half-angle acos(cos_max) (N,) about ``axis`` (N, 3)."""
    n = len(axis)
    u1, u2 = rng.random((n, m)), rng.random((n, m))
    cos_t = 1.0 - u1 * (1.0 - cos_max[:, None])
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u2
    helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(axis, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(axis, t1)
    return (sin_t * np.cos(phi))[..., None] * t1[:, None] + (sin_t * np.sin(phi))[..., None] * t2[:, None] \
        + cos_t[..., None] * axis[:, None]


def render_reference_pair(scene: Scene, T_world_from_cam: RigidTransform, intrinsics: Intrinsics, t_s: float,
                          virtual_object: ExtraMesh, *, spp: int = 64, radius_m: float | None = 0.75,
                          raycaster=None, seed: int = 0, method: str = "gather",
                          object_spp: int = 256) -> ReferencePair:
    """Render the camera's view of ``scene`` at ``t_s`` with ``virtual_object`` inserted and without it.

    ``method="path"``: both frames path-traced by Mitsuba in the region of interest, ``spp`` paths a
    pixel, from the same random sequences.

    ``method="gather"`` (the default; far less noise for the time): the frame without the object is
    the bake (Mitsuba's global illumination stored in the lightmaps); the object's pixels are
    path-traced by Mitsuba with the object in the scene, ``object_spp`` paths each; and each other
    pixel of the region, a diffuse point x of albedo ρ, gets the change the object makes to its
    irradiance, ΔL = ρ/π ∫ (L_object − L_behind) cos θ dω over the directions in which x sees the
    object: ``spp`` directions uniform in the cone around the object's bounding sphere, each cast
    against the scene and the object; where the object is nearer, L_object is one Mitsuba path along
    that ray and L_behind the baked radiance the object now hides. Left out: the second-order change
    (light that the changed surfaces pass on to others), below the comparison's resolution.

    Args:
        virtual_object: the object in world coordinates, a diffuse mesh.
        spp: paths (``path``) or object directions (``gather``) per pixel, in each frame (even: two
            halves give the noise).
        radius_m: the region of interest: pixels that see the object, or a surface whose hit point is
            within this distance of the object's bounding-box centre. None: every pixel.
        raycaster: a :class:`sim.raycast.SceneRaycaster` of ``scene`` (with its bake), for the pixels
            outside the region; built (and baked, through the cache) when None.
        method: "gather" or "path". object_spp: paths per object pixel (``gather``).
    """
    import time

    from rgbd_envmap.checks import check_method
    from sim.raycast import SceneRaycaster

    spp = int(check_number(spp, "spp", low=2, high=1 << 16, integer=True))
    spp += spp % 2
    object_spp = int(check_number(object_spp, "object_spp", low=2, high=1 << 16, integer=True))
    object_spp += object_spp % 2
    check_method(method, ("gather", "path"), "method")
    if radius_m is not None:
        radius_m = float(check_number(radius_m, "radius_m", low=0.0, low_open=True))
    start = time.perf_counter()
    h, w = intrinsics.height, intrinsics.width
    origin, dirs = camera_rays(T_world_from_cam, intrinsics)
    raycaster = raycaster if raycaster is not None else SceneRaycaster(scene)
    hits = raycaster.cast(origin, dirs, t_s, normals=False)
    verts = np.asarray(virtual_object.vertices, np.float64)
    object_rc = _object_caster(verts, virtual_object.faces)
    t_obj = _distance(object_rc, origin, dirs)
    object_mask = np.isfinite(t_obj) & (~hits.hit | (t_obj < hits.distance_m))
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    point = origin + dirs * np.where(hits.hit, hits.distance_m, 0.0)[:, None]
    if radius_m is None:
        traced = hits.hit | object_mask
    else:
        traced = object_mask | (hits.hit & (np.linalg.norm(point - centre, axis=1) <= radius_m))
    with_obj = np.array(hits.radiance, np.float32)
    without = with_obj.copy()
    noise = [np.zeros((len(dirs), 3), np.float32), np.zeros((len(dirs), 3), np.float32)]
    visible = frozenset(i for i, o in enumerate(scene.objects) if o.visible_at(t_s))
    scale = [o.scale_at(t_s) for o in scene.objects]

    def traced_mean(mi_scene, o, d, n_paths, seed0):
        halves = np.zeros((2, len(d), 3), np.float64)
        for j in range(n_paths):
            halves[j % 2] += trace(mi_scene, o, d, seed=seed0 + j)
        halves /= n_paths // 2
        return halves.mean(axis=0), np.abs(halves[0] - halves[1]) / 2.0

    if method == "path":
        idx = np.flatnonzero(traced)
        if len(idx):
            sub = dirs[idx]
            origins = np.broadcast_to(origin, sub.shape)
            for k, extra in enumerate(((virtual_object,), ())):
                mi_scene = build_scene(scene, visible, scale, extra=extra)
                mean, err = traced_mean(mi_scene, origins, sub, spp, seed * 100_003)
                (with_obj if k == 0 else without)[idx] = mean
                noise[k][idx] = err
    else:
        mi_scene = build_scene(scene, visible, scale, extra=(virtual_object,))
        idx = np.flatnonzero(object_mask)
        if len(idx):
            mean, err = traced_mean(mi_scene, np.broadcast_to(origin, (len(idx), 3)), dirs[idx], object_spp,
                                    seed * 100_003)
            with_obj[idx], noise[0][idx] = mean, err
        _gather_change(raycaster, object_rc, mi_scene, t_s, origin, dirs,
                       np.flatnonzero(traced & ~object_mask), centre, verts, spp, seed, with_obj, noise[0])
    hit = hits.hit | object_mask
    shape3 = (h, w, 3)
    return ReferencePair(with_obj.reshape(shape3), without.reshape(shape3), object_mask.reshape(h, w),
                         traced.reshape(h, w), hit.reshape(h, w), noise[0].reshape(shape3), noise[1].reshape(shape3),
                         spp, float(t_s), time.perf_counter() - start)


#: pixels per batch of :func:`_gather_change` (each casts ``spp`` rays).
_GATHER_BATCH = 1 << 14


def _gather_change(raycaster, object_rc, mi_scene, t_s, origin, dirs, idx, centre, verts, m, seed, out, noise):
    """Add to ``out[idx]`` the radiance change the object makes at each pixel's scene point (see
    :func:`render_reference_pair`, ``gather``); its standard error to ``noise[idx]``.

    A point sees the object in a solid angle Ω ≤ that of its bounding sphere, and its change is at
    most ρ L Ω / π: a far point gets fewer directions, ``m`` · Ω / Ω(2 r) rounded down to a power of
    two (at least 4), which keeps every point's absolute noise at most that of the nearest ones."""
    radius = float(np.max(np.linalg.norm(verts - centre, axis=1)))
    omega_near = 2.0 * np.pi * (1.0 - np.sqrt(0.75))  # the bounding sphere seen from 2 r
    rng = np.random.default_rng([int(seed), 0x9E3779B9])
    emitters = emitter_quads(raycaster.scene, t_s)
    for b in range(0, len(idx), _GATHER_BATCH):
        pix = idx[b:b + _GATHER_BATCH]
        sh = raycaster.surface_hits(origin, dirs[pix], t_s)
        keep = sh.hit & (sh.albedo.max(axis=1) > 0)
        pix = pix[keep]
        if not len(pix):
            continue
        dist = sh.distance_m[keep].astype(np.float64)
        x = origin + dirs[pix] * dist[:, None]
        n = sh.face_normal[keep].astype(np.float64)
        n *= np.where(np.einsum("ij,ij->i", n, dirs[pix]) > 0, -1.0, 1.0)[:, None]
        albedo = sh.albedo[keep].astype(np.float64)
        to_c = centre - x
        d_c = np.linalg.norm(to_c, axis=1)
        inside = d_c <= radius * 1.0001
        cos_max = np.where(inside, -1.0, np.sqrt(np.maximum(0.0, 1.0 - (radius / np.maximum(d_c, 1e-12)) ** 2)))
        axis = to_c / np.maximum(d_c, 1e-12)[:, None]
        solid = 2.0 * np.pi * (1.0 - cos_max)
        # Below the point's horizon altogether: nothing changes.
        above = np.einsum("ij,ij->i", to_c, n) > -radius
        share = np.minimum(1.0, solid / omega_near)
        count = np.where(above, np.maximum(4, 2 ** np.floor(np.log2(np.maximum(m * share, 1.0)))), 0).astype(int)
        count = np.minimum(count, m - m % 2)
        for mk in np.unique(count[count > 0]):
            g = np.flatnonzero(count == mk)
            _gather_group(raycaster, object_rc, mi_scene, t_s, x[g], n[g], axis[g], cos_max[g], solid[g], albedo[g],
                          int(mk), rng, int(seed) * 7_919 + b * 64 + int(mk), out, noise, pix[g],
                          emitters=emitters, centre=centre, radius=radius)


@dataclass(frozen=True)
class EmitterQuad:
    """An emitting quad of the scene, sampled by area in the gather (index into ``scene.objects``;
    corner + s·u + t·v, s, t ∈ [0, 1]; unit normal; area; centre and bounding radius)."""

    index: int
    corner: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    area: float
    centre: np.ndarray
    radius: float


def emitter_quads(scene: Scene, t_s: float) -> tuple[EmitterQuad, ...]:
    """The scene's emitting quads visible at ``t_s`` (lamps, windows, screens: every emitter with a
    quad frame)."""
    out = []
    for i, o in enumerate(scene.objects):
        if not (o.emits and o.quad_frame is not None and o.visible_at(t_s)):
            continue
        corner, u, v = (np.asarray(a, np.float64) for a in o.quad_frame)
        nrm = np.cross(u, v)
        area = float(np.linalg.norm(nrm))
        if area <= 0:
            continue
        c = corner + 0.5 * (u + v)
        r = 0.5 * max(float(np.linalg.norm(u + v)), float(np.linalg.norm(u - v)))
        out.append(EmitterQuad(i, corner, u, v, nrm / area, area, c, r))
    return tuple(out)


def _cone_overlap(x: np.ndarray, c1: np.ndarray, r1: float, c2: np.ndarray, r2: float) -> np.ndarray:
    """(P,) bool: from points ``x`` (P, 3), the cones around the spheres (c1, r1) and (c2, r2) share a
    direction (conservatively: the angle between the axes ≤ the sum of the half-angles; a point
    inside a sphere sees it all round)."""
    a, b = c1 - x, c2 - x
    da, db = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ha = np.where(da > r1, np.arcsin(np.clip(r1 / np.maximum(da, 1e-12), 0.0, 1.0)), np.pi)
    hb = np.where(db > r2, np.arcsin(np.clip(r2 / np.maximum(db, 1e-12), 0.0, 1.0)), np.pi)
    cos_ab = np.einsum("ij,ij->i", a, b) / np.maximum(da * db, 1e-300)
    return np.arccos(np.clip(cos_ab, -1.0, 1.0)) <= ha + hb + 1e-9


def _mis_area_weight(r: np.ndarray, cos_y: np.ndarray, area: float, solid: np.ndarray) -> np.ndarray:
    """The balance heuristic's weight of the area sample (one cone direction and one area sample per
    term): p_area / (p_area + p_cone) in solid-angle measure, p_area = r² / (A cos θ_y), p_cone = 1 / Ω."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p_area = r * r / (area * cos_y)
    p_cone = 1.0 / solid
    return np.where(np.isfinite(p_area), p_area / (p_area + p_cone), 1.0)


def _emitter_blocked(raycaster, object_rc, t_s, org, n, solid, em: EmitterQuad, m, rng) -> np.ndarray:
    """(P, m, 3) per point and area sample y_j of emitter ``em`` (m jittered Fibonacci points on the
    quad, a random rotation per point): the radiance the object now hides from the point through y_j,
    as an estimate of ∫_quad L(y) cos θ_x cos θ_y / r² dA (each sample's term × area / m): L(y) the
    bake's radiance where the scene ray from the point meets the quad itself (nothing of the scene in
    between), counted only where the object is hit before it; each term weighted by the balance
    heuristic against the cone's directions (``solid`` (P,) the points' cone solid angles)."""
    P = len(org)
    i = np.arange(m)
    base = np.stack([(i + 0.5) / m, np.mod(i * 0.6180339887498949, 1.0)], axis=1)  # (m, 2)
    st = np.mod(base[None] + rng.random((P, 1, 2)), 1.0)  # (P, m, 2)
    y = em.corner + st[..., :1] * em.u + st[..., 1:] * em.v  # (P, m, 3)
    d = y - org[:, None]
    r = np.linalg.norm(d, axis=2)
    w = d / np.maximum(r, 1e-12)[..., None]
    cos_x = np.einsum("pmk,pk->pm", w, n)
    cos_y = np.abs(w @ em.normal)
    ok = (cos_x > 0) & (r > 1e-6)
    out = np.zeros((P, m, 3))
    k = np.flatnonzero(ok.ravel())
    if not len(k):
        return out
    o_rep = np.repeat(org, m, axis=0)[k]
    w_flat = w.reshape(-1, 3)[k]
    r_flat = r.ravel()[k]
    t_o = _distance(object_rc, o_rep, w_flat)
    blocked = np.isfinite(t_o) & (t_o < r_flat)
    k, o_rep, w_flat, r_flat = k[blocked], o_rep[blocked], w_flat[blocked], r_flat[blocked]
    if not len(k):
        return out
    hits = raycaster.cast(o_rep, w_flat.astype(np.float32), t_s, normals=False)
    seen = hits.hit & (hits.object_index == em.index) & (hits.distance_m >= r_flat * (1.0 - 1e-4) - 1e-4)
    k, rad = k[seen], hits.radiance[seen].astype(np.float64)
    rk, cyk = r.ravel()[k], cos_y.ravel()[k]
    g = (cos_x.ravel()[k] * cyk / rk ** 2) * (em.area / m)
    g *= _mis_area_weight(rk, cyk, em.area, solid[k // m])
    out.reshape(-1, 3)[k] = rad * g[:, None]
    return out


def _gather_group(raycaster, object_rc, mi_scene, t_s, x, n, axis, cos_max, solid, albedo, m, rng, seed, out, noise,
                  pix, *, emitters: Sequence[EmitterQuad] = (), centre=None, radius: float = 0.0):
    """:func:`_gather_change` for points that all take ``m`` directions.

    The light the object hides from the scene's emitting quads (``emitters``) is estimated twice and
    combined by multiple importance sampling (the balance heuristic): by the cone's ``m`` directions
    and by ``m`` samples on each quad's area (next-event estimation). A small lamp covers a tiny part
    of the cone, so uniform directions alone found it in a few of their ``m`` only, a heavy-tailed
    estimate that left black and negative pixels at the object's foot; a large emitter (a wall that
    fills the cone) is better sampled by the cone, and the weights pick each where it is better.
    Everything else the object hides, and the light it reflects, comes from the cone alone."""
    d = _cone_directions(axis, cos_max, m, rng)  # (P, m, 3)
    cos_n = np.einsum("pmk,pk->pm", d, n)
    o_rep = np.repeat(x + 1e-4 * n, m, axis=0)
    d_flat = d.reshape(-1, 3)
    t_o = _distance(object_rc, o_rep, d_flat)
    towards = np.isfinite(t_o) & (cos_n.ravel() > 0)
    delta = np.zeros((len(d_flat), 3))
    k = np.flatnonzero(towards)
    if len(k):
        behind = raycaster.cast(o_rep[k], d_flat[k].astype(np.float32), t_s, normals=False)
        front = ~behind.hit | (t_o[k] < behind.distance_m)
        k, behind_radiance = k[front], behind.radiance[front].astype(np.float64)
        hit_index = behind.object_index[front]
        for em in emitters:  # the cone's share of an emitter's hidden light (balance heuristic)
            on = np.flatnonzero(hit_index == em.index)
            if len(on):
                cos_y = np.abs(d_flat[k[on]] @ em.normal)
                r = behind.distance_m[front][on].astype(np.float64)
                behind_radiance[on] *= 1.0 - _mis_area_weight(r, cos_y, em.area, solid[k[on] // m])[:, None]
        if len(k):
            delta[k] = trace(mi_scene, o_rep[k], d_flat[k], seed=seed) - behind_radiance
    # ΔE/π = (1/π) ∫ ΔL cos dω ≈ (Ω / π) · mean(ΔL cos), uniform in the cone.
    w = (delta * np.maximum(cos_n, 0.0).reshape(-1, 1)).reshape(len(x), m, 3)
    halves = np.stack([w[:, 0::2].mean(axis=1), w[:, 1::2].mean(axis=1)]) * (solid / np.pi)[None, :, None]
    for em in emitters:  # minus what the object hides of each emitting quad, in E / π units
        near = np.flatnonzero(_cone_overlap(x, centre, radius, em.centre, em.radius))
        if not len(near):
            continue
        hidden = _emitter_blocked(raycaster, object_rc, t_s, x[near] + 1e-4 * n[near], n[near], solid[near], em, m, rng)
        halves[0, near] -= hidden[:, 0::2].sum(axis=1) * (2.0 / np.pi)
        halves[1, near] -= hidden[:, 1::2].sum(axis=1) * (2.0 / np.pi)
    out[pix] += (albedo * halves.mean(axis=0)).astype(np.float32)
    noise[pix] = (albedo * np.abs(halves[0] - halves[1]) / 2.0).astype(np.float32)
