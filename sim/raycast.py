"""Ray casting against a scene at a time t with open3d's RaycastingScene.

One BVH is built per set of visible objects and cached, so a scene change (an object removed) costs
one rebuild and a lamp dimming none.
"""

from __future__ import annotations

from dataclasses import dataclass

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
        rays = np.empty((n, 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        ans = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))
        dist = ans["t_hit"].numpy()
        hit = np.isfinite(dist)
        # Misses carry open3d's INVALID_ID (2^32 − 1); clipping sends them to the final −1 entry.
        geom = np.minimum(ans["geometry_ids"].numpy(), len(geometry_to_object) - 1)
        obj = geometry_to_object[geom]
        if normals:
            normal = ans["primitive_normals"].numpy()
            flip = np.einsum("ij,ij->i", normal, directions) > 0
            normal[flip] *= -1.0
        else:
            normal = np.zeros((n, 3), np.float32)
        radiance = self._radiance(obj, origins, directions, dist, t_s)
        return RayHits(hit, dist.astype(np.float32), obj, normal, radiance, self._flag_bits[obj])

    def _radiance(self, obj, origins, directions, dist, t_s) -> np.ndarray:
        table = np.zeros((len(self.scene.objects) + 1, 3), dtype=np.float32)
        textured = []
        for i, o in enumerate(self.scene.objects):
            scale = o.scale_at(t_s)
            if o.texture is None:
                table[i] = o.radiance * scale
            else:
                textured.append((i, o, scale))
        out = table[obj]
        for i, o, scale in textured:
            sel = np.flatnonzero(obj == i)
            if sel.size == 0:
                continue
            p = origins[sel].astype(np.float64) + directions[sel] * dist[sel, None].astype(np.float64)
            corner, u, v = o.quad_frame
            s = (p - corner) @ u / (u @ u)
            t = (p - corner) @ v / (v @ v)
            out[sel] = o.texture.sample(s, t) * scale
        return out
