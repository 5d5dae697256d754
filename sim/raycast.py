"""Ray casting against a scene at a time t with open3d's RaycastingScene.

One BVH is built per set of visible objects and cached, so a scene change (an object removed) costs
one rebuild and a lamp dimming none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import open3d as o3d

from sim.scene import Scene

__all__ = ["RayHits", "SceneRaycaster"]


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


class SceneRaycaster:
    """Casts rays into ``scene`` as it is at a given time."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self._cache: dict[frozenset[int], tuple[o3d.t.geometry.RaycastingScene, np.ndarray]] = {}
        self._flag_bits = np.array([o.flag_bits for o in scene.objects] + [0], dtype=np.uint8)
        self._texture_arrays: tuple[np.ndarray, ...] | None = None

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
        if normals:
            normal = ans["primitive_normals"].numpy()
            flip = np.einsum("ij,ij->i", normal, directions) > 0
            normal[flip] *= -1.0
        else:
            normal = np.zeros((n, 3), np.float32)
        # Misses carry open3d's INVALID_ID (2^32 − 1): they go to the final −1 entry.
        hit, obj, radiance, flags = _shade_hits(rays, dist, ans["geometry_ids"].numpy(), geometry_to_object,
                                                self._radiance_table(t_s), *self._textures, self._flag_bits)
        return RayHits(hit, dist, obj, normal, radiance, flags)

    def _radiance_table(self, t_s: float) -> np.ndarray:
        """(objects + 1, 4) float32: each constant object's radiance at t_s (zero for textured ones and
        the miss row), then its radiance scale at t_s."""
        table = np.zeros((len(self.scene.objects) + 1, 4), dtype=np.float32)
        for i, o in enumerate(self.scene.objects):
            scale = o.scale_at(t_s)
            if o.texture is None:
                table[i, :3] = o.radiance * scale  # float32 × a Python float: float32, as before
            table[i, 3] = scale
        return table

    @property
    def _textures(self) -> tuple[np.ndarray, ...]:
        """Per object (and the miss row): texture kind (−1 none; :data:`_TEXTURE_KINDS`), cells (ns,
        nt), colours (padded to the most any texture has), and the quad frame (corner, u, v) as
        float64 rows, with u·u and v·v."""
        if self._texture_arrays is None:
            objs = self.scene.objects
            k = max([len(o.texture.colours) for o in objs if o.texture is not None], default=1)
            kind = np.full(len(objs) + 1, -1, np.int64)
            cells = np.ones((len(objs) + 1, 2), np.int64)
            colours = np.zeros((len(objs) + 1, k, 3), np.float32)
            frame = np.zeros((len(objs) + 1, 5, 3), np.float64)
            for i, o in enumerate(objs):
                if o.texture is None:
                    continue
                kind[i] = _TEXTURE_KINDS.index(o.texture.kind)
                cells[i] = o.texture.cells
                colours[i, : len(o.texture.colours)] = o.texture.colours
                corner, u, v = (np.asarray(a, np.float64) for a in o.quad_frame)
                frame[i, :3] = corner, u, v
                frame[i, 3, 0], frame[i, 4, 0] = u @ u, v @ v
            self._texture_arrays = (kind, cells, colours, frame)
        return self._texture_arrays


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
