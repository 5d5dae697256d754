"""The real geometry near the virtual object, from the map's own depth (docs/design/differential.md).

An environment map stores, per equirect pixel, the distance ``depth_m`` from its origin to the surface
seen in that direction. :func:`receiver_mesh` turns that into a triangle mesh of the surfaces around
the object (the table it stands on, a wall behind it), the *receivers* of its shadow and of its
reflected light:

- vertices: the valid map pixels of a sub-grid (every ``stride``-th row and column, pixel centres)
  at ``origin + direction · depth`` within ``radius_m`` of ``centre`` (the object's centre), thinned
  to one per cube of side ``spacing_m`` in the world. An equirect grid is dense in the world where
  the map looks steeply down on the table and sparse where it grazes it; the thinning makes the
  spacing even (about 10 000 vertices for a 0.4 m radius at 8 mm instead of 65 000 on a 4-pixel grid);
- triangles: the Delaunay triangulation of the vertices' directions from the origin (in the
  stereographic projection from the zenith, which keeps circles circles, so it is the spherical
  Delaunay triangulation: neighbours as the map sees them, no seam), cut at a depth discontinuity or
  a hole: a triangle with an edge longer than ``max_edge · spacing_m``, or seen from the origin at a
  grazing angle (|cos| between its normal and the ray from the origin below ``min_cos``), which is
  what a triangle spanning a foreground and a background surface looks like;
- normals: area-weighted means of the kept triangles' normals at each vertex, turned to face the
  origin (the origin saw the surface, so its front faces the origin).

Vertices that no kept triangle uses are dropped.

Where the map has no geometry near the object, a horizontal grid through the object's base stands in
(:func:`support_plane`, merged by :func:`merge_receivers`): a map updated only from viewpoints near
its origin holds the table far from the object but rarely right next to it, where a camera looking
down at the object sees the table at a steep angle from the origin's point of view.

References:
    - Rohmer, Büschel, Dachselt, Grosch (paper 000) §5 (the reconstructed real geometry in the
      G-buffer with the virtual objects).
    - Knecht et al., Differential instant radiosity (paper 001) §3.1, §4 (real geometry from the
      RGB-D sensor for differential rendering).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.errors import ShapeError
from rgbd_envmap.geometry import directions_to_equirect, equirect_directions

__all__ = ["ReceiverMesh", "merge_receivers", "receiver_mesh", "support_plane", "surface_radiance"]


@dataclass(frozen=True, eq=False)
class ReceiverMesh:
    """Real surfaces near the object (read-only arrays, world frame).

    Attributes:
        vertices: (V, 3) float64 metres.
        normals: (V, 3) float64 unit, facing the map's origin.
        faces: (F, 3) int32 vertex indices.
    """

    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        v = check_array(self.vertices, "vertices", shape=("V", 3), dtype="float", finite=True)
        n = check_array(self.normals, "normals", shape=(len(v), 3), dtype="float", finite=True)
        f = check_array(self.faces, "faces", shape=("F", 3), dtype="int")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ShapeError(f"faces: expected indices in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
        for name, a, dt in (("vertices", v, np.float64), ("normals", n, np.float64), ("faces", f, np.int32)):
            a = np.array(a, dt, copy=True)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return int(self.vertices.shape[0])

    @classmethod
    def empty(cls) -> "ReceiverMesh":
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.int32))


def receiver_mesh(depth_m: object, valid: object, origin: object, centre: object, radius_m: float, *,
                  spacing_m: float = 0.008, stride: int = 2, max_edge: float = 4.0,
                  min_cos: float = 0.03) -> ReceiverMesh:
    """The map's surfaces within ``radius_m`` of ``centre`` as a triangle mesh (module docstring).

    Args:
        depth_m: (H, W) float distances from ``origin`` (metres), meaningful where ``valid``.
        valid: (H, W) bool.
        origin: (3,) the map's world origin; centre: (3,) world point the receivers surround.
        radius_m: > 0, the largest distance of a vertex from ``centre``.
        spacing_m: > 0, the world spacing of the vertices: one map point per cube of this side.
        stride: ≥ 1, the candidate sub-grid step in map pixels (rows and columns).
        max_edge: > 0, triangles with an edge longer than ``max_edge · spacing_m`` are cut (a depth
            discontinuity, or a hole in the map).
        min_cos: in [0, 1), the grazing cut (see the module docstring).

    Returns:
        A :class:`ReceiverMesh` (empty when fewer than three points are in range).
    """
    from scipy.spatial import Delaunay, QhullError

    dep = check_array(depth_m, "depth_m", shape=("H", "W"), dtype=("float", "int"))
    ok = check_array(valid, "valid", shape=dep.shape, dtype=np.bool_)
    o = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    c = check_array(centre, "centre", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    radius = check_number(radius_m, "radius_m", low=0.0, low_open=True)
    spacing = check_number(spacing_m, "spacing_m", low=0.0, low_open=True)
    stride = check_number(stride, "stride", low=1, integer=True)
    max_edge = check_number(max_edge, "max_edge", low=0.0, low_open=True)
    min_cos = check_number(min_cos, "min_cos", low=0.0, high=1.0, high_open=True)
    H, W = dep.shape
    rows = np.arange(stride // 2, H, stride)
    cols = np.arange(stride // 2, W, stride)
    good = ok[np.ix_(rows, cols)]
    d = dep[np.ix_(rows, cols)]
    # A point within radius of the centre is within radius of the centre's distance along its own
    # direction (the triangle inequality): that cuts the candidates before any direction is formed.
    dc = float(np.linalg.norm(c - o))
    with np.errstate(invalid="ignore"):
        cand = good & np.isfinite(d) & (d > 0) & (np.abs(d - dc) <= radius * (1 + 1e-6) + 1e-9)
    ri, ci = np.nonzero(cand)
    dirs = equirect_directions(H, W)[rows[ri], cols[ci]].astype(np.float64)
    pts = o + dirs * d[ri, ci].astype(np.float64)[:, None]
    near = np.sum((pts - c) ** 2, axis=1) <= radius * radius
    pts, dirs = pts[near], dirs[near]
    if len(pts) < 3:
        return ReceiverMesh.empty()
    # one point per cube of side spacing (the first in map order: deterministic), the cube's three
    # indices packed into one int64 key (a 1-D sort; rows of three sort ten times slower)
    cell = np.floor((pts - c) / spacing).astype(np.int64)
    off = int(np.abs(cell).max()) + 1
    base = 2 * off + 1
    if base < 2 ** 20:
        key = ((cell[:, 0] + off) * base + (cell[:, 1] + off)) * base + (cell[:, 2] + off)
        _, first = np.unique(key, return_index=True)
    else:  # radius / spacing too large to pack
        _, first = np.unique(cell, axis=0, return_index=True)
    first.sort()
    pts, dirs = pts[first], dirs[first]
    if len(pts) < 3:
        return ReceiverMesh.empty()
    # triangulate by direction: stereographic projection from the zenith (circles stay circles, so
    # this is the spherical Delaunay triangulation of the directions; no seam)
    q = dirs[:, :2] / np.maximum(1.0 - dirs[:, 2:], 1e-9)
    try:
        tris = Delaunay(q).simplices.astype(np.int64)
    except QhullError:  # all points on a line in direction space
        return ReceiverMesh.empty()
    p = pts
    e = [np.linalg.norm(p[tris[:, a]] - p[tris[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))]
    short = np.maximum(np.maximum(e[0], e[1]), e[2]) <= max_edge * spacing
    tris = tris[short]
    if len(tris) == 0:
        return ReceiverMesh.empty()
    e1 = p[tris[:, 1]] - p[tris[:, 0]]
    e2 = p[tris[:, 2]] - p[tris[:, 0]]
    fn = np.cross(e1, e2)  # |fn| = 2 · area
    centroid = (p[tris[:, 0]] + p[tris[:, 1]] + p[tris[:, 2]]) / 3.0
    ray = centroid - o
    area2 = np.linalg.norm(fn, axis=1)
    rlen = np.linalg.norm(ray, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosang = np.abs(np.sum(fn * ray, axis=1)) / (area2 * rlen)
    keep = (area2 > 0) & (rlen > 0) & (cosang >= max(min_cos, 1e-12))
    tris, fn, centroid = tris[keep], fn[keep], centroid[keep]
    if len(tris) == 0:
        return ReceiverMesh.empty()
    # orient each face normal towards the origin, then accumulate at the vertices (area weights)
    flip = np.sum(fn * (o - centroid), axis=1) < 0
    fn[flip] *= -1.0
    vn = np.zeros_like(p)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    used = np.unique(tris)
    remap = np.full(len(p), -1, np.int64)
    remap[used] = np.arange(len(used))
    vn = vn[used]
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    return ReceiverMesh(p[used], vn, remap[tris].astype(np.int32))


def support_plane(base: object, half_size_m: float, spacing_m: float = 0.008) -> ReceiverMesh:
    """The fallback receiver where the map has no geometry: a square grid on the horizontal plane
    through ``base`` (the object's base, world), ``half_size_m`` each way, vertices ``spacing_m``
    apart, normals +z."""
    b = check_array(base, "base", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    half = check_number(half_size_m, "half_size_m", low=0.0, low_open=True, high=100.0)
    spacing = check_number(spacing_m, "spacing_m", low=1e-4, high=half * 2)
    n = int(np.ceil(2 * half / spacing)) + 1
    g = np.linspace(-half, half, n)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([b[0] + x.ravel(), b[1] + y.ravel(), np.full(n * n, b[2])], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, bb, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    f = np.concatenate([np.stack([a, bb, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return ReceiverMesh(v, np.tile([0.0, 0.0, 1.0], (n * n, 1)), f.astype(np.int32))


def merge_receivers(first: ReceiverMesh, fallback: ReceiverMesh, exclude_m: float) -> ReceiverMesh:
    """``first`` and the triangles of ``fallback`` none of whose vertices lies within ``exclude_m`` of
    a vertex of ``first`` (the fallback fills in where the first mesh has no surface)."""
    exclude = check_number(exclude_m, "exclude_m", low=0.0)
    if len(first) == 0:
        return fallback
    if len(fallback) == 0:
        return first
    from scipy.spatial import cKDTree

    d, _ = cKDTree(first.vertices).query(fallback.vertices, distance_upper_bound=exclude)
    free = ~np.isfinite(d)  # no first-mesh vertex within the distance
    f = fallback.faces[free[fallback.faces].all(axis=1)]
    used = np.unique(f)
    remap = np.full(len(fallback), -1, np.int64)
    remap[used] = np.arange(len(used)) + len(first)
    return ReceiverMesh(np.concatenate([first.vertices, fallback.vertices[used]]),
                        np.concatenate([first.normals, fallback.normals[used]]),
                        np.concatenate([first.faces, remap[f].astype(np.int32)]))


def surface_radiance(radiance: object, valid: object, origin: object, points: object) -> np.ndarray:
    """(N, 3) float64 the map's radiance of world ``points`` (N, 3): the map's pixel (nearest centre)
    in each point's direction from ``origin``; NaN where that pixel is not ``valid`` or the point is
    the origin itself. The map's depth is not checked: a receiver vertex comes from that pixel's
    depth, or (the support plane) lies under the object where the map sees the table."""
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    ok = check_array(valid, "valid", shape=rad.shape[:2], dtype=np.bool_)
    o = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    p = check_array(points, "points", shape=("N", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    H, W = rad.shape[:2]
    out = np.full((len(p), 3), np.nan)
    if not len(p):
        return out
    uv = directions_to_equirect(p - o, H, W)
    good = np.isfinite(uv).all(axis=1)
    u = np.mod(np.rint(uv[good, 0]).astype(np.int64), W)
    v = np.clip(np.rint(uv[good, 1]).astype(np.int64), 0, H - 1)
    idx = np.flatnonzero(good)
    seen = ok[v, u]
    out[idx[seen]] = rad[v[seen], u[seen]]
    return out
