"""The virtual camera of a render call: its checked inputs and their per-frame projection.

Conventions: ``T_world_from_cam`` is an OpenCV camera pose (x right, y down, z forward); pixel
(column u, row v) has its centre at integer (u, v). The camera is the colour camera's undistorted
pinhole (its distortion is ignored). Both backends project the meshes here first: the screen-space
bounds of everything in front of the near plane give the rectangle that they clear, rasterise and
read back (the layer's ``bbox``), and the numba rasteriser uses the fixed-point vertex positions.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels import raster_camera as kernels
from rgbd_envmap.checks import check_array, check_range
from rgbd_envmap.errors import RangeError
from rgbd_envmap.types import Intrinsics, RigidTransform, check_transform

__all__ = ["ProjectedMesh", "as_pose", "check_inputs", "project_meshes", "to_camera"]

#: Plane alphas this far outside [0, 1] (rounding in the PRT ratio) are clipped rather than rejected.
_ALPHA_SLACK = 1e-6


def as_pose(T_world_from_cam: object) -> RigidTransform:
    """The camera pose as a :class:`RigidTransform`: given as one, or as a finite (4, 4) matrix."""
    if isinstance(T_world_from_cam, RigidTransform):
        return check_transform(T_world_from_cam, "T_world_from_cam", "world")
    m = check_array(T_world_from_cam, "T_world_from_cam", shape=(4, 4), dtype=("float", "int"), finite=True)
    return RigidTransform(m.astype(np.float64), "world", "cam")


def _check_mesh(vertices: object, faces: object, prefix: str) -> tuple[np.ndarray, np.ndarray]:
    v = check_array(vertices, f"{prefix}_vertices_world", shape=("N", 3), dtype=("float", "int"), finite=True)
    f = check_array(faces, f"{prefix}_faces", shape=("F", 3), dtype="int")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise RangeError(
            f"{prefix}_faces: expected vertex indices in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    # Faces as a read-only view either way: numba compiles one specialisation of the rasteriser
    # per array flag (seconds on a first run), and the object's faces are read-only, the plane's not.
    f = np.ascontiguousarray(f, dtype=np.int32).view()
    f.flags.writeable = False
    return v.astype(np.float64, copy=False), f


def check_inputs(T_world_from_cam, object_vertices_world, object_faces, object_colours,
                 plane_vertices_world, plane_faces, plane_alpha):
    """The arguments of :meth:`rgbd_envmap.render.raster.Renderer.render`, checked and converted:
    (pose, object vertices float64, object faces int32 read-only, object colours float32 clamped at
    0, plane vertices, plane faces, plane alpha float32 clipped to [0, 1])."""
    pose = as_pose(T_world_from_cam)
    ov, of = _check_mesh(object_vertices_world, object_faces, "object")
    oc = check_array(object_colours, "object_colours", shape=(len(ov), 3), dtype="float", finite=True)
    pv, pf = _check_mesh(plane_vertices_world, plane_faces, "plane")
    pa = check_array(plane_alpha, "plane_alpha", shape=(len(pv),), dtype="float", finite=True)
    check_range(pa, "plane_alpha", -_ALPHA_SLACK, 1.0 + _ALPHA_SLACK)
    oc = np.maximum(oc, 0.0).astype(np.float32)
    return pose, ov, of, oc, pv, pf, np.clip(pa, 0.0, 1.0).astype(np.float32)


def to_camera(pose: RigidTransform, points_world: np.ndarray) -> np.ndarray:
    """(N, 3) world points → camera frame, float64 (p_cam = Rᵀ (p_world − t))."""
    r = pose.rotation
    return (points_world - pose.translation) @ r


class ProjectedMesh:
    """A mesh's per-frame vertex data: camera-frame positions and their projection."""

    def __init__(self, pc: np.ndarray, faces: np.ndarray, intr: Intrinsics, near: float, bounds: np.ndarray):
        n = len(pc)
        self.pc, self.faces = pc, faces
        self.xy = np.empty((n, 2), np.int32)
        self.iz = np.empty(n, np.float64)
        self.any_front = bool(len(faces)) and kernels.prepare_vertices(
            pc, faces, near, intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height, self.xy, self.iz, bounds)


def project_meshes(pose, meshes, intr: Intrinsics, near: float):
    """Transform and project each (vertices_world, faces); returns the :class:`ProjectedMesh` meshes
    and the half-open (row0, row1, col0, col1) bounding the pixel centres the visible geometry can
    cover (clipped to the image, one pixel of margin for vertex snapping), or None when nothing can
    be."""
    bounds = np.array([np.inf, -np.inf, np.inf, -np.inf])
    projected = [ProjectedMesh(to_camera(pose, v), f, intr, near, bounds) for v, f in meshes]
    if not any(p.any_front for p in projected) or not np.isfinite(bounds).all():
        return projected, None
    big = 1e9  # projections of points near the near plane can be huge; clamp before int conversion
    umin, umax, vmin, vmax = np.clip(bounds, -big, big)
    c0 = max(int(np.floor(umin)) - 1, 0)
    c1 = min(int(np.floor(umax)) + 2, intr.width)
    r0 = max(int(np.floor(vmin)) - 1, 0)
    r1 = min(int(np.floor(vmax)) + 2, intr.height)
    if c0 >= c1 or r0 >= r1:
        return projected, None
    return projected, (r0, r1, c0, c1)
