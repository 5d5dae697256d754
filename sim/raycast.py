"""Ray casting against a scene at a time t with open3d's RaycastingScene.

One BVH is built per set of visible objects and cached, so a scene change (an object removed) costs
one rebuild and a lamp dimming none. A hit's radiance is its fixed radiance, or for a lit surface
Le + ρ · S with S read from the scene's bake (:mod:`sim.bake`) at the hit point, for the visibility
state at t and each emitter group's scale at t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import open3d as o3d

from sim.bake import BakeConfig, SceneLighting, bake_scene, gather_kernel
from sim.scene import Scene, Texture

__all__ = ["RayHits", "SceneRaycaster", "SurfaceHits"]


@dataclass(frozen=True)
class RayHits:
    """Per-ray results; misses have ``hit`` False, distance inf, object −1 and zero radiance.

    Attributes:
        hit: (N,) bool.
        distance_m: (N,) float32 distance along the (unit) ray.
        object_index: (N,) int32 index into ``scene.objects``, −1 for a miss.
        normal: (N, 3) float32 unit world normal, flipped to face the ray origin.
        radiance: (N, 3) float32 linear outgoing radiance at time t.
        flags: (N,) uint8 OR of :data:`sim.scene.FLAG_BITS` of the hit object.
    """

    hit: np.ndarray
    distance_m: np.ndarray
    object_index: np.ndarray
    normal: np.ndarray
    radiance: np.ndarray
    flags: np.ndarray


@dataclass(frozen=True)
class SurfaceHits:
    """First hits with what the bake needs (see :meth:`SceneRaycaster.surface_hits`).

    Attributes:
        hit, distance_m, object_index: as in :class:`RayHits`.
        triangle: (N,) int64 triangle index within the object. bary: (N, 2) float32 barycentric
            weights of the triangle's vertices 1 and 2. face_normal: (N, 3) float32 unit normal of
            the winding (not flipped). albedo: (N, 3) float32 (zero for fixed-radiance surfaces).
        emission: (N, 3) float32 emitted (or fixed) radiance at scale 1.
    """

    hit: np.ndarray
    distance_m: np.ndarray
    object_index: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    face_normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray


class SceneRaycaster:
    """Casts rays into ``scene`` as it is at a given time.

    A scene with lit surfaces needs its bake: pass ``lighting``, or it is loaded from the cache (or
    computed) with ``bake_config`` under ``cache_dir`` on construction. ``bake=False`` leaves a lit
    scene unbaked (its surfaces show only their emission): the bake itself uses :meth:`surface_hits`.
    """

    def __init__(self, scene: Scene, lighting: SceneLighting | None = None, *,
                 bake_config: BakeConfig | None = None, cache_dir=None, bake: bool = True) -> None:
        self.scene = scene
        self._cache: dict[frozenset[int], tuple[o3d.t.geometry.RaycastingScene, np.ndarray]] = {}
        self._flag_bits = np.array([o.flag_bits for o in scene.objects] + [0], dtype=np.uint8)
        self._texture_arrays: tuple[np.ndarray, ...] | None = None
        self._albedo_arrays: tuple[np.ndarray, ...] | None = None
        if lighting is None and scene.is_lit and bake:
            lighting = bake_scene(scene, bake_config or BakeConfig(), cache_dir)
        self.lighting = lighting

    def _bvh(self, t_s: float):
        visible = frozenset(i for i, o in enumerate(self.scene.objects) if o.visible_at(t_s))
        if visible not in self._cache:
            rc = o3d.t.geometry.RaycastingScene()
            geometry_to_object = []
            for i in sorted(visible):
                o = self.scene.objects[i]
                rc.add_triangles(
                    o3d.core.Tensor(o.vertices.astype(np.float32)), o3d.core.Tensor(o.faces.astype(np.uint32))
                )
                geometry_to_object.append(i)
            # open3d's INVALID_ID maps to the last entry, −1.
            self._cache[visible] = (rc, np.array(geometry_to_object + [-1], dtype=np.int32))
        return self._cache[visible]

    def cast(self, origins: np.ndarray, directions: np.ndarray, t_s: float, *, normals: bool = True) -> RayHits:
        """Cast rays from (N, 3) or (3,) ``origins`` along (N, 3) unit ``directions`` at time ``t_s``.

        ``normals=False`` skips the normals (left as zeros), which the colour camera does not need.
        """
        directions = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        n = len(directions)
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float32), (n, 3))
        rc, geometry_to_object = self._bvh(t_s)
        if len(geometry_to_object) == 1:  # nothing visible
            return RayHits(
                np.zeros(n, bool), np.full(n, np.inf, np.float32), np.full(n, -1, np.int32),
                np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.zeros(n, np.uint8),
            )
        rays = _rays(origins, directions)
        ans = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))
        dist = ans["t_hit"].numpy()
        geometry_ids = ans["geometry_ids"].numpy()
        if normals:
            normal = ans["primitive_normals"].numpy()
            flip = np.einsum("ij,ij->i", normal, directions) > 0
            normal[flip] *= -1.0
        else:
            normal = np.zeros((n, 3), np.float32)
        # Misses carry open3d's INVALID_ID (2^32 − 1): they go to the final −1 entry.
        hit, obj, radiance, flags = _shade_hits(rays, dist, geometry_ids, geometry_to_object,
                                                self._radiance_table(t_s), *self._textures, self._flag_bits)
        if self.lighting is not None:
            radiance = self._lit(rays, dist, geometry_ids, geometry_to_object, obj, ans, directions, t_s, radiance)
        return RayHits(hit, dist, obj, normal, radiance, flags)

    def surface_hits(self, origins: np.ndarray, directions: np.ndarray, t_s: float) -> SurfaceHits:
        """What the bake needs at each ray's first hit: the object, triangle and barycentrics, the
        albedo, and the emitted (or fixed) radiance at scale 1."""
        directions = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        n = len(directions)
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float32), (n, 3))
        rc, geometry_to_object = self._bvh(t_s)
        rays = _rays(origins, directions)
        ans = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))
        dist = ans["t_hit"].numpy()
        geometry_ids = ans["geometry_ids"].numpy()
        hit, obj, emission, _ = _shade_hits(rays, dist, geometry_ids, geometry_to_object, self._emission_table,
                                            *self._textures, self._flag_bits)
        _, _, albedo, _ = _shade_hits(rays, dist, geometry_ids, geometry_to_object, self._albedo_table,
                                      *self._albedo_textures, self._flag_bits)
        return SurfaceHits(hit, dist, obj, ans["primitive_ids"].numpy().astype(np.int64), ans["primitive_uvs"].numpy(),
                           ans["primitive_normals"].numpy(), albedo, emission)

    @property
    def _emission_table(self) -> np.ndarray:
        """(objects + 1, 4) float32: each object's constant emission or fixed radiance, scale 1."""
        table = np.zeros((len(self.scene.objects) + 1, 4), dtype=np.float32)
        for i, o in enumerate(self.scene.objects):
            if o.radiance is not None:
                table[i, :3] = o.radiance
            elif o.emission is not None:
                table[i, :3] = o.emission
            table[i, 3] = 1.0
        return table

    def _lit(self, rays, dist, geometry_ids, geometry_to_object, obj, ans, directions, t_s, radiance):
        """Add ρ · S at every hit on a lit surface (S from the bake, at t_s's state and scales)."""
        lighting = self.lighting
        visible = frozenset(i for i, o in enumerate(self.scene.objects) if o.visible_at(t_s))
        scales = tuple(float(self.scene.objects[g[0]].scale_at(t_s)) for g in lighting.groups)
        state = lighting.state_index(visible)
        combined = lighting.combined(state, scales)
        lat = lighting.lattice
        s = gather_kernel(obj, ans["primitive_ids"].numpy().astype(np.int64), ans["primitive_uvs"].numpy(),
                          directions, lat.tri_base, lat.tri_n, lat.tri_offset, lat.tri_normal, combined,
                          lighting.valid[state])
        _, _, albedo, _ = _shade_hits(rays, dist, geometry_ids, geometry_to_object, self._albedo_table,
                                      *self._albedo_textures, self._flag_bits)
        return radiance + albedo * s

    @property
    def _albedo_table(self) -> np.ndarray:
        """(objects + 1, 4) float32: each lit object's constant albedo (zero otherwise), scale 1."""
        table = np.zeros((len(self.scene.objects) + 1, 4), dtype=np.float32)
        for i, o in enumerate(self.scene.objects):
            if o.albedo is not None:
                table[i, :3] = o.albedo
            table[i, 3] = 1.0
        return table

    @property
    def _albedo_textures(self) -> tuple[np.ndarray, ...]:
        if self._albedo_arrays is None:
            self._albedo_arrays = _texture_tables(self.scene, [o.albedo_texture for o in self.scene.objects])
        return self._albedo_arrays

    def _radiance_table(self, t_s: float) -> np.ndarray:
        """(objects + 1, 4) float32: each constant object's radiance at t_s (zero for textured ones and
        the miss row), then its radiance scale at t_s."""
        table = np.zeros((len(self.scene.objects) + 1, 4), dtype=np.float32)
        for i, o in enumerate(self.scene.objects):
            scale = o.scale_at(t_s)
            if o.radiance is not None:
                table[i, :3] = o.radiance * scale  # float32 × a Python float: float32, as before
            elif o.emission is not None:
                table[i, :3] = o.emission * scale
            table[i, 3] = scale
        return table

    @property
    def _textures(self) -> tuple[np.ndarray, ...]:
        """Texture tables of the radiance (fixed surfaces) or emission (lit ones): see _texture_tables."""
        if self._texture_arrays is None:
            objs = self.scene.objects
            self._texture_arrays = _texture_tables(self.scene, [o.texture if o.texture is not None else o.emission_texture
                                                                for o in objs])
        return self._texture_arrays


def _texture_tables(scene: Scene, textures: list[Texture | None]) -> tuple[np.ndarray, ...]:
    """Per object (and the miss row): texture kind (−1 none; :data:`_TEXTURE_KINDS`), cells (ns, nt),
    colours (padded to the most any texture has), and the quad frame (corner, u, v) as float64 rows,
    with u·u and v·v."""
    objs = scene.objects
    k = max([len(t.colours) for t in textures if t is not None], default=1)
    kind = np.full(len(objs) + 1, -1, np.int64)
    cells = np.ones((len(objs) + 1, 2), np.int64)
    colours = np.zeros((len(objs) + 1, k, 3), np.float32)
    frame = np.zeros((len(objs) + 1, 5, 3), np.float64)
    for i, (o, tex) in enumerate(zip(objs, textures)):
        if tex is None:
            continue
        kind[i] = _TEXTURE_KINDS.index(tex.kind)
        cells[i] = tex.cells
        colours[i, : len(tex.colours)] = tex.colours
        corner, u, v = (np.asarray(a, np.float64) for a in o.quad_frame)
        frame[i, :3] = corner, u, v
        frame[i, 3, 0], frame[i, 4, 0] = u @ u, v @ v
    return kind, cells, colours, frame


#: Texture kinds in the order :func:`_shade_hits` numbers them.
_TEXTURE_KINDS = ("gradient", "checker", "patches")


@numba.njit(cache=True)
def _rays(origins, directions):  # pragma: no cover - compiled
    """(N, 6) float32 rays for open3d from (N, 3) origins and directions."""
    n = directions.shape[0]
    rays = np.empty((n, 6), np.float32)
    for i in range(n):
        for k in range(3):
            rays[i, k] = origins[i, k]
            rays[i, 3 + k] = directions[i, k]
    return rays


@numba.njit(cache=True)
def _shade_hits(rays, dist, geometry_ids, geometry_to_object, table, kind, cells, colours, frame, flag_bits):  # pragma: no cover - compiled
    """Per ray: hit, object index (−1 for a miss), radiance (N, 3) float32 and flag bits, in one pass.
    A textured quad's (s, t) = ((p − corner)·u / u·u, (p − corner)·v / v·v) at the float64 hit point,
    clipped to [0, 1]; :meth:`sim.scene.Texture.sample` is the array version (tested against it)."""
    n = dist.shape[0]
    last = geometry_to_object.shape[0] - 1
    hit = np.empty(n, np.bool_)
    obj = np.empty(n, np.int32)
    radiance = np.empty((n, 3), np.float32)
    flags = np.empty(n, np.uint8)
    for i in range(n):
        g = geometry_ids[i]
        o = geometry_to_object[g if g < last else last]
        hit[i] = np.isfinite(dist[i])
        obj[i] = o
        flags[i] = flag_bits[o]
        row = o if o >= 0 else table.shape[0] - 1
        tk = kind[row]
        if tk < 0:
            radiance[i, 0], radiance[i, 1], radiance[i, 2] = table[row, 0], table[row, 1], table[row, 2]
            continue
        d = np.float64(dist[i])
        px = np.float64(rays[i, 0]) + np.float64(rays[i, 3]) * d - frame[row, 0, 0]
        py = np.float64(rays[i, 1]) + np.float64(rays[i, 4]) * d - frame[row, 0, 1]
        pz = np.float64(rays[i, 2]) + np.float64(rays[i, 5]) * d - frame[row, 0, 2]
        s = (px * frame[row, 1, 0] + py * frame[row, 1, 1] + pz * frame[row, 1, 2]) / frame[row, 3, 0]
        t = (px * frame[row, 2, 0] + py * frame[row, 2, 1] + pz * frame[row, 2, 2]) / frame[row, 4, 0]
        s = min(max(s, 0.0), 1.0)
        t = min(max(t, 0.0), 1.0)
        scale = table[row, 3]
        if tk == 0:  # gradient, in float64 and then float32, as the array version
            for k in range(3):
                c = np.float32(np.float64(colours[row, 0, k]) * (1.0 - t) + np.float64(colours[row, 1, k]) * t)
                radiance[i, k] = c * scale
            continue
        ns, nt = cells[row, 0], cells[row, 1]
        a = min(np.int64(s * ns), ns - 1)
        b = min(np.int64(t * nt), nt - 1)
        j = (a + b) % 2 if tk == 1 else b * ns + a
        for k in range(3):
            radiance[i, k] = colours[row, j, k] * scale
    return hit, obj, radiance, flags
