"""Reference frames: Mitsuba's path tracer rendering a camera's view of the scene, with or without extra
meshes (the virtual object), in linear radiance before any camera processing.

The camera rays are the simulator's own (:func:`rgbd_envmap.geometry.pixel_rays`: through each pixel
centre, with the lens distortion), so a reference pixel and a simulated pixel see the same point; each
pixel averages ``spp`` independent paths. Rendering the frame with and without the virtual object
from the same random sequence makes their difference (the object's shadow and the light it bounces)
nearly free of noise where the object changes nothing.
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

__all__ = ["ReferenceFrame", "render_reference", "camera_rays"]


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
