"""The bake: outgoing radiance of every lit surface, computed once per scene by Mitsuba's path tracer.

A lit surface point x with normal n (on either side) has outgoing radiance

    L(x) = Le(x) + ρ(x) · S(x),    S(x) = (1/π) ∫ L_in(x, ω) cos θ dω = E(x) / π,

where E is the irradiance. The bake stores S (not L) on a lattice over each triangle and each side:
S is smooth where the albedo texture is not (a checker floor), so the ray caster multiplies the
interpolated S by ρ and adds Le, both looked up exactly at the hit point, and textures stay sharp.

- **Lattice.** Triangle k is cut into n_k² similar sub-triangles (n_k = ⌈middle edge length / texel_m⌉); S is
  baked at the (n_k + 1)(n_k + 2) / 2 lattice points of each side and interpolated linearly inside each
  sub-triangle (:func:`gather_kernel`). Lattice points are pulled a hair towards the centroid so that a
  point on an edge belongs to its own triangle.
- **Estimator.** S = S_direct + S_indirect. S_direct, the light arriving straight from the emitters,
  by emitter area sampling (``direct_samples`` points per lattice side, chosen by area × mean emitted
  luminance, stratified) with shadow rays cast by open3d. S_indirect, everything else, by ``spp``
  cosine-distributed directions (a 2-D Halton sequence with a random shift per side) from x + δn, each
  traced by Mitsuba's path integrator less the emission of the surface it meets first (the direct
  part already counts it); every later bounce is Mitsuba's, with its own emitter sampling and MIS. Unbiased (Russian roulette ends paths) with ``max_depth = −1``.
- **Dead sides.** A side whose probe rays (16, cosine-distributed) all leave the scene, or all meet a
  closed object from inside (the outside of the room's walls, the inside of a box, the floor under a
  box standing on it) is dead: nothing sees it and it receives no light. It is not traced, and the
  lookup interpolates only between live lattice points, so the dark under a box does not bleed into
  the floor around it.
- **Final gather.** With ``final_gather`` M > 0 the above is a first pass S¹, and the bake is S_direct
  plus the mean over M cosine-distributed rays of ρ S¹ + w_cos Le at the surface each meets: every
  ray reads S¹ at a different lattice cell, so the first pass's noise is averaged M-fold, and ``spp``
  can stay small (8: the white furnace's p99 texel error is 0.9 % at 8 and 0.8 % at 16).
- **Linearity.** Emitters are grouped by their timeline (equal ``scale`` steps share a group; fixed
  radiance surfaces emit too); each group is baked alone, once per set of visible objects (a box
  removed at 6 s changes the transport), and the ray caster sums S_g × scale_g(t), so a lamp dimming at
  8 s is exact.
- **Shared rays.** Visibility states are put in families whose first state sees every object the
  others see (the state after the box goes joins the one before). A family's states share their
  emitter samples, shadow rays (against the objects all of them see; only the rays that pass are
  tested again against a state's other objects) and final-gather rays (cast in the first state; a
  ray that meets an object a state lacks is cast again there). This is exact for each state; only
  the Mitsuba paths of the first pass, which depend on the whole scene, are traced per state.
  docs/design/bake.md has the timings.
- **Cache.** A bake is keyed by the scene's content, the settings and this module's format version,
  and written atomically under the cache directory (``lightmaps/<key>.npz``).

References:
    Kajiya, *The rendering equation* (1986); lightmaps as in Quake / Abrash (1997) and every game
    engine since: irradiance stored over surfaces, multiplied by albedo at lookup.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import io
import time
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from rgbd_envmap.cache import atomic_write_bytes, default_cache_dir
from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError
from sim.scene import Scene

__all__ = ["BakeConfig", "Lattice", "SceneLighting", "bake_scene", "build_lattice", "emitter_groups",
           "visibility_states", "gather_kernel", "BAKE_FORMAT"]

#: Bumped when the bake's meaning or layout changes: old cache entries are then ignored.
BAKE_FORMAT = 3

#: Ray origins sit this far in front of the surface (metres): well clear of float32 rounding at room
#: scale and of the emitters' back copies (0.1 mm), well below any feature of the scenes.
ORIGIN_OFFSET_M = 1e-3

#: Lattice points are moved this fraction of the way to their triangle's centroid.
_SHRINK = 1e-3

#: Bound on lattice points (both sides), so a tiny texel size fails before allocating.
MAX_LATTICE_POINTS = 20_000_000


@dataclass(frozen=True)
class BakeConfig:
    """Settings of the bake.

    Attributes:
        texel_m: lattice spacing along a triangle's longest edge, metres.
        spp: cosine-distributed directions per lattice point and side (the indirect light).
        direct_samples: emitter points per lattice point and side (the direct light).
        final_gather: cosine-distributed rays per lattice point and side of the final gather through
            the first pass (0: no final gather, the first pass is the bake).
        max_depth: Mitsuba path integrator's maximum path length (−1: unbounded, Russian roulette).
        rr_depth: path length from which Russian roulette may end a path. At Mitsuba's default (5)
            roulette kills low-throughput paths and weights a survivor by up to 1/throughput, which
            in a bright closed room gives rare large samples: with the final gather the white
            furnace's p99 texel error is 1.3 % at 5 and 0.9 % at 10 (spp 8), for about a quarter more
            Mitsuba time at 10.
        seed: random sequence of the bake.
    """

    texel_m: float = 0.05
    spp: int = 8
    direct_samples: int = 128
    final_gather: int = 128
    max_depth: int = -1
    rr_depth: int = 10
    seed: int = 0

    def __post_init__(self) -> None:
        check_number(self.texel_m, "BakeConfig.texel_m", low=1e-3, high=10.0)
        check_number(self.spp, "BakeConfig.spp", low=1, high=1 << 16, integer=True)
        check_number(self.direct_samples, "BakeConfig.direct_samples", low=1, high=1 << 16, integer=True)
        check_number(self.final_gather, "BakeConfig.final_gather", low=0, high=1 << 16, integer=True)
        check_number(self.max_depth, "BakeConfig.max_depth", low=-1, high=1024, integer=True)
        if self.max_depth == 0:
            raise InvalidInputError("BakeConfig.max_depth: expected −1 or ≥ 1, got 0")
        check_number(self.rr_depth, "BakeConfig.rr_depth", low=1, high=1024, integer=True)
        check_number(self.seed, "BakeConfig.seed", low=0, high=2**31 - 1, integer=True)


@dataclass(frozen=True)
class Lattice:
    """Lattice points of every lit triangle of a scene.

    Attributes:
        tri_base: (objects + 1,) int64 index of each object's first triangle in the lattice tables,
            −1 for an object that is not lit (and for the miss row).
        tri_n: (T,) int64 subdivisions per triangle. tri_offset: (T,) int64 first point of each.
        tri_normal: (T, 3) float64 unit geometric normal (the winding's: the "front" side).
        points: (P, 3) float64 lattice points. point_normal: (P, 3) their triangle's normal.
        point_object: (P,) int64 object index of each point.
    """

    tri_base: np.ndarray
    tri_n: np.ndarray
    tri_offset: np.ndarray
    tri_normal: np.ndarray
    points: np.ndarray
    point_normal: np.ndarray
    point_object: np.ndarray

    @property
    def size(self) -> int:
        return len(self.points)


def build_lattice(scene: Scene, texel_m: float) -> Lattice:
    """The lattice of every lit object's triangles at spacing ``texel_m``."""
    tri_base = np.full(len(scene.objects) + 1, -1, np.int64)
    tris, objs = [], []
    for i, o in enumerate(scene.objects):
        if o.lit:
            tri_base[i] = sum(len(t) for t in tris)
            tris.append(o.vertices[o.faces])
            objs.append(np.full(len(o.faces), i, np.int64))
    if not tris:
        empty = np.zeros((0, 3))
        return Lattice(tri_base, np.zeros(0, np.int64), np.zeros(0, np.int64), empty, empty, empty, np.zeros(0, np.int64))
    tri = np.concatenate(tris)  # (T, 3, 3)
    tri_obj = np.concatenate(objs)
    e = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], axis=1)
    # Subdivisions from the middle edge length: a quad's halves (right triangles) get a lattice as fine
    # as texel_m along both of the quad's sides; the diagonal, longer, is the one edge spaced wider.
    middle = np.sort(np.linalg.norm(e, axis=2), axis=1)[:, 1]
    n = np.maximum(1, np.ceil(middle / texel_m - 1e-9)).astype(np.int64)
    counts = (n + 1) * (n + 2) // 2
    total = int(counts.sum())
    if 2 * total > MAX_LATTICE_POINTS:
        raise InvalidInputError(
            f"bake texel_m: {texel_m} m gives {2 * total:,} lattice points (bound {MAX_LATTICE_POINTS:,}, "
            f"{2 * total * 12 / 2**30:.1f} GiB per bake); use a larger texel_m")
    offset = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    points = np.empty((total, 3))
    point_obj = np.empty(total, np.int64)
    point_normal = np.empty((total, 3))
    for k in np.unique(n):
        sel = np.flatnonzero(n == k)
        j, i = np.divmod(np.arange((k + 1) ** 2), k + 1)
        keep = i + j <= k
        b1, b2 = i[keep] / k, j[keep] / k  # row-major in j, as lattice_index counts them
        b1 = 1 / 3 + (1 - _SHRINK) * (b1 - 1 / 3)
        b2 = 1 / 3 + (1 - _SHRINK) * (b2 - 1 / 3)
        t = tri[sel]  # (S, 3, 3)
        p = t[:, None, 0] + b1[None, :, None] * (t[:, None, 1] - t[:, None, 0]) + b2[None, :, None] * (t[:, None, 2] - t[:, None, 0])
        idx = offset[sel][:, None] + np.arange(len(b1))[None, :]
        points[idx] = p
        point_obj[idx] = tri_obj[sel][:, None]
        point_normal[idx] = normal[sel][:, None, :]
    return Lattice(tri_base, n, offset, normal, points, point_normal, point_obj)


def emitter_groups(scene: Scene) -> list[tuple[int, ...]]:
    """Emitting objects grouped by their timeline (equal scale steps), in a fixed order."""
    groups: dict[tuple, list[int]] = {}
    for i, o in enumerate(scene.objects):
        if o.emits:
            groups.setdefault(o.scale_steps, []).append(i)
    return [tuple(v) for _, v in sorted(groups.items(), key=lambda kv: kv[1][0])]


def visibility_states(scene: Scene) -> list[frozenset[int]]:
    """The distinct sets of visible objects over time, in time order."""
    times = scene.change_times()
    probes = [times[0] - 1.0] if times else [0.0]
    probes += [t for t in times]
    states: list[frozenset[int]] = []
    for t in probes:
        v = frozenset(i for i, o in enumerate(scene.objects) if o.visible_at(t))
        if v not in states:
            states.append(v)
    return states


@dataclass(frozen=True)
class SceneLighting:
    """A scene's bake: S per (visibility state, emitter group, side, lattice point).

    Attributes:
        lattice: the lattice the values live on.
        states: the visible-object sets, each with its values. groups: emitter groups (object indices).
        values: (states, groups, 2, P, 3) float32 S = E / π; side 0 is the front (the winding's normal).
        valid: (states, 2, P) bool, the side is live (baked); dead sides hold zero.
        config: the settings it was baked with. key: the cache key.
        bake_seconds: wall time of the bake (0 when loaded). from_cache: loaded from the cache.
    """

    lattice: Lattice
    states: tuple[frozenset[int], ...]
    groups: tuple[tuple[int, ...], ...]
    values: np.ndarray
    valid: np.ndarray
    config: BakeConfig
    key: str
    bake_seconds: float = 0.0
    from_cache: bool = False
    _combined: dict = field(default_factory=dict, compare=False, repr=False)

    def state_index(self, visible: frozenset[int]) -> int:
        try:
            return self.states.index(visible)
        except ValueError:
            raise InvalidInputError(f"bake: no state with visible objects {sorted(visible)}") from None

    def combined(self, state: int, group_scales: tuple[float, ...]) -> np.ndarray:
        """(2, P, 3) float32 Σ_g scale_g × S_g for one state (cached: scales change only at steps)."""
        key = (state, group_scales)
        if key not in self._combined:
            if len(self._combined) > 8:
                self._combined.clear()
            acc = np.zeros(self.values.shape[2:], np.float32)
            for g, s in enumerate(group_scales):
                if s != 0:
                    acc += np.float32(s) * self.values[state, g]
            self._combined[key] = acc
        return self._combined[key]


def _scene_digest(scene: Scene, config: BakeConfig) -> str:
    h = hashlib.sha256()
    h.update(f"bake{BAKE_FORMAT}|{config}".encode())
    for o in scene.objects:
        h.update(o.name.encode())
        for a in (o.vertices, o.faces, o.radiance, o.albedo, o.emission):
            h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
        for tex in (o.texture, o.albedo_texture, o.emission_texture):
            h.update(b"-" if tex is None else f"{tex.kind}{tex.cells}".encode() + tex.colours.tobytes())
        h.update(repr((o.visible_from_s, o.visible_until_s, o.scale_steps)).encode())
    try:
        import mitsuba

        h.update(mitsuba.__version__.encode())
    except ImportError:
        pass
    return h.hexdigest()[:32]


@contextlib.contextmanager
def _timed(timings: dict | None, phase: str):
    """Add the wall time of the block to ``timings[phase]`` (seconds), when timings is a dict."""
    start = time.perf_counter()
    try:
        yield
    finally:
        if timings is not None:
            timings[phase] = timings.get(phase, 0.0) + time.perf_counter() - start


def _halton(index: np.ndarray, base: int) -> np.ndarray:
    result = np.zeros(len(index))
    f = 1.0
    i = index.astype(np.int64).copy()
    while (i > 0).any():
        f /= base
        result += f * (i % base)
        i //= base
    return result


def _frames(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents orthogonal to each (N, 3) unit normal (Duff et al. 2017)."""
    sign = np.where(normal[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + normal[:, 2])
    b = normal[:, 0] * normal[:, 1] * a
    t1 = np.stack([1 + sign * normal[:, 0] ** 2 * a, sign * b, -sign * normal[:, 0]], axis=1)
    t2 = np.stack([b, sign + normal[:, 1] ** 2 * a, -normal[:, 1]], axis=1)
    return t1, t2


#: Probe rays per lattice side for finding dead sides.
_PROBES = 16


def _solid(obj) -> bool:
    """A closed mesh with outward faces (a box, cylinder, sphere, a watertight mesh file): a point
    whose every probe meets its faces from behind is inside it. Quads never enclose anything."""
    if obj.quad_frame is not None:
        return False
    import trimesh

    return bool(trimesh.Trimesh(obj.vertices, obj.faces, process=False).is_watertight)


def _live_sides(scene: Scene, visible: frozenset[int], origins: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N,) bool: the side at each origin can receive light and is seen from the room (see "Dead
    sides" above): some probe ray meets a surface other than a solid object from behind."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    solid, tri_normals = [], []
    for i in sorted(visible):
        o = scene.objects[i]
        rc.add_triangles(o3d.core.Tensor(o.vertices.astype(np.float32)), o3d.core.Tensor(o.faces.astype(np.uint32)))
        solid.append(_solid(o))
        t = o.vertices[o.faces]
        nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        tri_normals.append(nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30))
    t1, t2 = _frames(normals)
    rng = np.random.default_rng(12345)
    live = np.zeros(len(origins), bool)
    for _ in range(_PROBES):
        u1, u2 = rng.random(len(origins)), rng.random(len(origins))
        # Only the sides not yet known to be live are probed again (the same draws as probing all).
        todo = np.flatnonzero(~live)
        if len(todo) == 0:
            break
        u1, u2 = u1[todo], u2[todo]
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        d = (t1[todo] * (r * np.cos(phi))[:, None] + t2[todo] * (r * np.sin(phi))[:, None]
             + normals[todo] * np.sqrt(1 - u1)[:, None])
        ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([origins[todo], d], axis=1).astype(np.float32)))
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(ans["t_hit"].numpy())
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        buried = np.zeros(len(todo), bool)
        for g in range(len(solid)):
            m = hit & (gid == g)
            if m.any() and solid[g]:
                buried[m] = np.einsum("ij,ij->i", tri_normals[g][prim[m]], d[m]) > 0
        live[todo] = hit & ~buried
    return live


@dataclass(frozen=True)
class _EmitterTriangles:
    """The emitting triangles of one group in one state, for area sampling."""

    corners: np.ndarray  # (T, 3, 3)
    normal: np.ndarray  # (T, 3) unit
    cdf: np.ndarray  # (T,) selection CDF ∝ area × weight
    density: np.ndarray  # (T,) pdf per unit area of a point on each triangle
    owner: np.ndarray  # (T,) object index
    constant: np.ndarray  # (T, 3) emitted radiance of an untextured owner (zero for textured ones)
    textured: np.ndarray  # (T,) bool the owner's emission is a texture


def _emitter_triangles(scene: Scene, visible: frozenset[int], members: tuple[int, ...]) -> _EmitterTriangles | None:
    corners, owner, weight = [], [], []
    for i in members:
        o = scene.objects[i]
        if i not in visible or not o.emits:
            continue
        tex = o.texture if o.texture is not None else o.emission_texture
        rgb = o.radiance if o.radiance is not None else o.emission
        mean = tex.colours.mean(axis=0) if tex is not None else rgb
        corners.append(o.vertices[o.faces])
        owner.append(np.full(len(o.faces), i))
        weight.append(np.full(len(o.faces), max(float(np.mean(mean)), 1e-12)))
    if not corners:
        return None
    c = np.concatenate(corners)
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    keep = area > 0
    c, cross, area = c[keep], cross[keep], area[keep]
    w = area * np.concatenate(weight)[keep]
    cdf = np.cumsum(w) / w.sum()
    density = (w / w.sum()) / area
    owner = np.concatenate(owner)[keep]
    constant = np.zeros((len(owner), 3))
    textured = np.zeros(len(owner), bool)
    for i in np.unique(owner):
        o = scene.objects[i]
        if o.texture is not None or o.emission_texture is not None:
            textured[owner == i] = True
        else:
            constant[owner == i] = o.radiance if o.radiance is not None else o.emission
    return _EmitterTriangles(c, cross / (2 * area[:, None]), cdf, density, owner, constant, textured)


def _emitted(scene: Scene, owner: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Emitted (or fixed) radiance (N, 3) at points on emitting objects, at scale 1."""
    out = np.zeros((len(points), 3))
    for i in np.unique(owner):
        o = scene.objects[i]
        m = owner == i
        tex = o.texture if o.texture is not None else o.emission_texture
        if tex is None:
            out[m] = o.radiance if o.radiance is not None else o.emission
        else:
            corner, u, v = o.quad_frame
            p = points[m] - corner
            out[m] = tex.sample(p @ u / (u @ u), p @ v / (v @ v))
    return out


def _occluders(scene: Scene, visible: frozenset[int]):
    """open3d scene of the visible objects and the object index of each of its geometries (−1 last)."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    ids = []
    for i in sorted(visible):
        o = scene.objects[i]
        rc.add_triangles(o3d.core.Tensor(o.vertices.astype(np.float32)), o3d.core.Tensor(o.faces.astype(np.uint32)))
        ids.append(i)
    return rc, np.array(ids + [-1], np.int64)


def _cast(rc, origins: np.ndarray, directions: np.ndarray):
    import open3d as o3d

    ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([origins, directions], axis=1).astype(np.float32)))
    return ans["t_hit"].numpy(), ans["geometry_ids"].numpy().astype(np.int64), ans["primitive_normals"].numpy()


def _occluded(rc, origins: np.ndarray, directions: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(N,) bool: a surface lies on each ray within ``length`` (open3d's occlusion test, cheaper than
    finding the first hit: the direction is scaled to the length and the ray ends at t = 1)."""
    import open3d as o3d

    rays = np.concatenate([origins, directions * np.maximum(length, 0.0)[:, None]], axis=1).astype(np.float32)
    return rc.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=1.0).numpy().astype(bool)


def _cosine_directions(t1, t2, normals, k, shift):
    """Direction k of a 2-D Halton sequence, shifted per row, cosine-distributed about each normal;
    and its cos θ."""
    return _cosine_kernel(t1, t2, normals, _halton(np.array([k + 1]), 2)[0], _halton(np.array([k + 1]), 3)[0],
                          shift)


@numba.njit(cache=True)
def _cosine_kernel(t1, t2, normals, h2, h3, shift):  # pragma: no cover - compiled
    n = normals.shape[0]
    d = np.empty((n, 3))
    cos_x = np.empty(n)
    for i in range(n):
        u1 = (h2 + shift[i, 0]) % 1.0
        u2 = (h3 + shift[i, 1]) % 1.0
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        c = np.sqrt(max(1.0 - u1, 0.0))
        a, b = r * np.cos(phi), r * np.sin(phi)
        for j in range(3):
            d[i, j] = t1[i, j] * a + t2[i, j] * b + normals[i, j] * c
        cos_x[i] = c
    return d, cos_x


def _cosine_weight(p_cos, p_area, n_cos, n_area):
    """Balance-heuristic weight of the cosine strategy against emitter area sampling (Veach 1997);
    the area sampler's weight is one minus it."""
    a, b = p_cos * n_cos, p_area * n_area
    return np.where(a + b > 0, a / np.maximum(a + b, 1e-300), 1.0)


@numba.njit(cache=True)
def _direct_sample_kernel(origins, normals, shift, h, cdf, corners, em_normal, density, n_cos, n_area):  # pragma: no cover - compiled
    """One emitter area sample per origin (the 3-D Halton point ``h`` shifted per row): the point y,
    the unit direction d to it, its distance r, the triangle, and the MIS-weighted estimator factor
    w = w_area cos θx / p(ω) (zero where the sample is below either surface)."""
    n = origins.shape[0]
    y = np.empty((n, 3))
    d = np.empty((n, 3))
    r = np.empty(n)
    w = np.zeros(n)
    tri = np.empty(n, np.int64)
    last = cdf.shape[0] - 1
    for i in range(n):
        u0 = (h[0] + shift[i, 0]) % 1.0
        u1 = (h[1] + shift[i, 1]) % 1.0
        u2 = (h[2] + shift[i, 2]) % 1.0
        t = min(np.searchsorted(cdf, u0, side="right"), last)
        tri[i] = t
        su = np.sqrt(u1)
        b1, b2 = su * (1 - u2), su * u2
        r2 = 0.0
        for c in range(3):
            y[i, c] = (corners[t, 0, c] + b1 * (corners[t, 1, c] - corners[t, 0, c])
                       + b2 * (corners[t, 2, c] - corners[t, 0, c]))
            d[i, c] = y[i, c] - origins[i, c]
            r2 += d[i, c] * d[i, c]
        ri = np.sqrt(r2)
        r[i] = ri
        inv = 1.0 / max(ri, 1e-12)
        cos_x = 0.0
        cos_y = 0.0
        for c in range(3):
            d[i, c] *= inv
            cos_x += normals[i, c] * d[i, c]
            cos_y += em_normal[t, c] * d[i, c]
        cos_y = abs(cos_y)
        if cos_x > 0 and cos_y > 0 and ri > 1e-6:
            p_area = density[t] * r2 / max(cos_y, 1e-12)  # per steradian
            a, b = cos_x / np.pi * n_cos, p_area * n_area
            w_cos = a / max(a + b, 1e-300) if a + b > 0 else 1.0
            w[i] = (1.0 - w_cos) * cos_x / max(p_area, 1e-300)
    return y, d, r, w, tri


def _direct(scene: Scene, em: _EmitterTriangles, rc, origins: np.ndarray, normals: np.ndarray,
            n_area: int, n_cos: int, rng, extra=(None,)) -> list[np.ndarray]:
    """The area-sampled, MIS-weighted part of S_direct (N, 3): (1/π) ∫ w_area Le cos θ dω over the
    group's emitters, stratified by a 3-D Halton point shifted per side, shadow rays by open3d (only
    for the samples above both surfaces).

    One result per entry of ``extra``: the occluders are those of ``rc`` and, where the entry is not
    None, those of that second open3d scene too (the objects a visibility state has beyond ``rc``'s):
    the samples and the main shadow rays are shared between the results."""
    n = len(origins)
    shift = rng.random((n, 3))
    direct = [np.zeros((n, 3)) for _ in extra]
    origins = np.ascontiguousarray(origins, np.float64)
    normals = np.ascontiguousarray(normals, np.float64)
    for k in range(n_area):
        h = np.array([_halton(np.array([k + 1]), b)[0] for b in (2, 3, 5)])
        y, d, r, w, tri = _direct_sample_kernel(origins, normals, shift, h, em.cdf, em.corners, em.normal,
                                                em.density, float(n_cos), float(n_area))
        reach = r * (1 - 1e-4) - 1e-4  # the shadow ray stops just short of the emitter
        ok = np.flatnonzero(w > 0)
        ok = ok[~_occluded(rc, origins[ok], d[ok], reach[ok])]
        value = _emitted_at(scene, em, tri[ok], y[ok]) * w[ok, None]
        for j, rc_extra in enumerate(extra):
            if rc_extra is None:
                direct[j][ok] += value
            else:
                free = ~_occluded(rc_extra, origins[ok], d[ok], reach[ok])
                direct[j][ok[free]] += value[free]
    return [x / (n_area * np.pi) for x in direct]


def _emitted_at(scene: Scene, em: _EmitterTriangles, tri: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Emitted radiance (N, 3) at points on the group's emitting triangles ``tri``, at scale 1:
    a table lookup for untextured emitters, the texture only for the others."""
    out = em.constant[tri]
    textured = em.textured[tri]
    if textured.any():
        m = np.flatnonzero(textured)
        out[m] = _emitted(scene, em.owner[tri[m]], points[m])
    return out


#: Rays per batch of the first pass (open3d cast and Mitsuba trace of several directions at once).
_BATCH_RAYS = 1 << 20


def _first_pass(scene: Scene, visible: frozenset[int], members: tuple[int, ...], mi_scene, origins: np.ndarray,
                normals: np.ndarray, config: BakeConfig, seed: int, *, n_area: int, n_cos: int,
                direct: np.ndarray | None = None, timings: dict | None = None,
                label: str = "") -> tuple[np.ndarray, np.ndarray]:
    """(S_direct, S) at each origin (a lattice side), both (N, 3) float64: direct light by ``n_area``
    emitter area samples, everything else by ``spp`` cosine-distributed rays through Mitsuba, the
    emitters seen by both strategies weighted by the balance heuristic (as if ``n_cos`` cosine rays
    met ``n_area`` area samples), so neither a small lamp (area sampling wins) nor a wall meeting the
    surface at a corner (cosine sampling wins) is noisy. ``direct``: S_direct when computed already
    (shared between visibility states, :func:`_shared_direct`).

    The spp directions of many origins go to open3d and Mitsuba together, in batches of about
    ``_BATCH_RAYS`` rays (one wavefront each)."""
    from sim.mitsuba_scene import trace

    n = len(origins)
    em = _emitter_triangles(scene, visible, members)
    rc, geometry_to_object = _occluders(scene, visible)
    density_of = np.zeros(len(scene.objects) + 1)  # area sampler's pdf per unit area, per object
    if em is not None:
        density_of[em.owner] = em.density
    t1, t2 = _frames(normals)
    rng = np.random.default_rng(seed)
    acc = np.zeros((n, 3), np.float64)
    shift = rng.random((n, 2))
    per_batch = max(1, _BATCH_RAYS // max(n, 1))
    for k0 in range(0, config.spp, per_batch):
        ks = range(k0, min(k0 + per_batch, config.spp))
        d = np.empty((len(ks), n, 3))
        cos_x = np.empty((len(ks), n))
        for j, k in enumerate(ks):
            d[j], cos_x[j] = _cosine_directions(t1, t2, normals, k, shift)
        d, cos_x = d.reshape(-1, 3), cos_x.ravel()
        o = np.broadcast_to(origins, (len(ks), n, 3)).reshape(-1, 3)
        weight = None
        if em is not None:
            dist, gid, prim_n = _cast(rc, o, d)
            hit = np.isfinite(dist)
            miss_row = len(geometry_to_object) - 1
            obj = geometry_to_object[np.where(hit, np.minimum(gid, miss_row), miss_row)]
            cos_y = np.abs(np.einsum("ij,ij->i", prim_n, d))
            dens = density_of[obj]
            p_area = np.where(hit & (dens > 0), dens * np.where(hit, dist, 0.0) ** 2 / np.maximum(cos_y, 1e-12), 0.0)
            weight = _cosine_weight(cos_x / np.pi, p_area, n_cos, n_area)
        with _timed(timings, f"indirect (Mitsuba){label}"):
            out = trace(mi_scene, o, d, seed=seed * 65537 + k0,
                        first_emission_weight=np.ones(len(d)) if weight is None else weight)
        acc += out.reshape(len(ks), n, 3).sum(axis=0)
    acc /= config.spp
    if em is None:
        return np.zeros((n, 3)), acc
    if direct is None:
        with _timed(timings, f"direct{label}"):
            direct = _direct(scene, em, rc, origins, normals, n_area, n_cos, rng)[0]
    return direct, acc + direct


def _families(states: list[frozenset[int]]) -> list[list[int]]:
    """The visibility states in families that share rays: the first state of each (its base) sees
    every object that the others see (a box removed at 6 s: the state after it joins the one before)."""
    families: list[list[int]] = []
    for s in sorted(range(len(states)), key=lambda i: (-len(states[i]), i)):
        for f in families:
            if states[s] <= states[f[0]]:
                f.append(s)
                break
        else:
            families.append([s])
    return families


def _shared_direct(scene: Scene, states: list[frozenset[int]], family: list[int], members: tuple[int, ...],
                   origins: np.ndarray, normals: np.ndarray, n_area: int, n_cos: int, seed: int) -> dict:
    """S_direct (N, 3) of one emitter group at the family's sides, per state of the family ({state:
    array}): states whose emitters of the group are the same share the samples and the shadow rays
    against the objects all of them see; only the rays that pass those are tested again against each
    state's other objects."""
    out: dict[int, np.ndarray] = {}
    by_emitters: dict[tuple, list[int]] = {}
    for s in family:
        key = tuple(i for i in members if i in states[s] and scene.objects[i].emits)
        by_emitters.setdefault(key, []).append(s)
    for same in by_emitters.values():
        em = _emitter_triangles(scene, states[same[0]], members)
        if em is None:
            out.update({s: np.zeros((len(origins), 3)) for s in same})
            continue
        common = frozenset.intersection(*(states[s] for s in same))
        rc, _ = _occluders(scene, common)
        extra = [_occluders(scene, states[s] - common)[0] if states[s] - common else None for s in same]
        rng = np.random.default_rng(seed)
        rng.random((len(origins), 2))  # the first pass's shifts come first in this stream
        for s, d in zip(same, _direct(scene, em, rc, origins, normals, n_area, n_cos, rng, extra)):
            out[s] = d
    return out


def _take_hits(h, rows) -> dict:
    """The rows ``rows`` of a :class:`sim.raycast.SurfaceHits`, as a dict of arrays."""
    return {f.name: getattr(h, f.name)[rows] for f in dataclasses.fields(h)}


def _final_gather(scene: Scene, states: list[frozenset[int]], family: list[int], groups, lattice: Lattice,
                  values: np.ndarray, valid: np.ndarray, direct: dict, rows: dict, origins: np.ndarray,
                  normals: np.ndarray, config: BakeConfig, seed: int) -> dict:
    """S per state of the family and group ({state: [(N_s, 3) per group]}): the direct part plus
    (1/M) Σ_k [ρ(z_k) S¹(z_k) + w_cos Le(z_k)] over ``final_gather`` cosine-distributed rays, with
    z_k the first surface met and S¹ the state's first pass (``values[s]``, live where ``valid[s]``)
    read from the lattice. The rays leave the family's sides (``origins``; state s uses rows
    ``rows[s]``) and are cast once (open3d) in the family's base state for every state and group:
    a ray whose first hit is an object that a state lacks is cast again in that state. Each ray
    averages the first pass's noise over many lattice points."""
    from sim.raycast import SceneRaycaster

    rc = SceneRaycaster(scene, bake=False)
    base_t = _state_time(scene, states[family[0]])
    n = len(origins)
    member_of = np.full(len(scene.objects) + 1, -1)
    for g, m in enumerate(groups):
        member_of[list(m)] = g
    density_of, shown = {}, {}
    for s in family:
        density_of[s] = np.zeros(len(scene.objects) + 1)
        for m in groups:
            em = _emitter_triangles(scene, states[s], m)
            if em is not None:
                density_of[s][em.owner] = em.density
        shown[s] = np.zeros(len(scene.objects) + 1, bool)
        shown[s][sorted(states[s])] = True
    in_state = {}
    for s in family:
        in_state[s] = np.zeros(n, bool)
        in_state[s][rows[s]] = True
    t1, t2 = _frames(normals)
    shift = np.random.default_rng(seed).random((n, 2))
    # Sums over all the family's sides for every state (a side a state lacks is summed and dropped).
    acc = {s: [np.zeros((n, 3)) for _ in groups] for s in family}
    for k in range(config.final_gather):
        d, cos_x = _cosine_directions(t1, t2, normals, k, shift)
        h_all = _take_hits(rc.surface_hits(origins, d, base_t), slice(None))
        for s in family:
            h = h_all
            again = np.flatnonzero(in_state[s] & h_all["hit"] & ~shown[s][h_all["object_index"]])
            if len(again):
                h = {name: v.copy() for name, v in h_all.items()}
                redo = rc.surface_hits(origins[again], d[again], _state_time(scene, states[s]))
                for name, v in _take_hits(redo, slice(None)).items():
                    h[name][again] = v
            cos_y = np.abs(np.einsum("ij,ij->i", h["face_normal"], d))
            dens = density_of[s][h["object_index"]]
            p_area = np.where(h["hit"] & (dens > 0),
                              dens * np.where(h["hit"], h["distance_m"], 0.0) ** 2 / np.maximum(cos_y, 1e-12), 0.0)
            w_cos = _cosine_weight(cos_x / np.pi, p_area, config.final_gather, config.direct_samples)
            group_of_hit = member_of[h["object_index"]]
            for g in range(len(groups)):
                s1 = gather_kernel(h["object_index"], h["triangle"], h["bary"], d, lattice.tri_base, lattice.tri_n,
                                   lattice.tri_offset, lattice.tri_normal, values[s, g], valid[s])
                acc[s][g] += h["albedo"] * s1 + np.where(group_of_hit == g, w_cos, 0.0)[:, None] * h["emission"]
    return {s: [direct[s][g] + acc[s][g][rows[s]] / config.final_gather for g in range(len(groups))] for s in family}


def _live_mask(scene: Scene, visible: frozenset[int], lattice: Lattice) -> np.ndarray:
    """(2, P) bool: which sides of ``lattice``'s points on the visible objects are live."""
    sel = np.flatnonzero(np.isin(lattice.point_object, sorted(visible)))
    normals = np.concatenate([lattice.point_normal[sel], -lattice.point_normal[sel]])
    origins = np.concatenate([lattice.points[sel], lattice.points[sel]]) + ORIGIN_OFFSET_M * normals
    live = _live_sides(scene, visible, origins, normals)
    valid = np.zeros((2, lattice.size), bool)
    valid[np.repeat([0, 1], len(sel))[live], np.concatenate([sel, sel])[live]] = True
    return valid


def _state_time(scene: Scene, visible: frozenset[int]) -> float:
    """A time at which exactly ``visible`` is visible (for the ray caster)."""
    times = scene.change_times()
    for t in ([times[0] - 1.0] if times else [0.0]) + list(times):
        if frozenset(i for i, o in enumerate(scene.objects) if o.visible_at(t)) == visible:
            return t
    raise InvalidInputError(f"bake: no time with visible objects {sorted(visible)}")


def bake_scene(scene: Scene, config: BakeConfig = BakeConfig(), cache_dir: Path | None = None,
               *, use_cache: bool = True, progress=None, timings: dict | None = None) -> SceneLighting:
    """The bake of ``scene`` (loaded from the cache when there, else computed and cached).

    ``progress``: an optional callable(done, total) called after each (state, group) bake.
    ``timings``: an optional dict that receives the wall seconds of each phase of a computed bake
    ("lattice", "live sides s0", "direct g1 s0 s1" (emitter sampling shared by a family of states),
    "first pass s0 g1" and its "indirect (Mitsuba) s0 g1" part, "final gather s0 s1", ...;
    benchmarks/bench_bake.py prints them).
    """
    start = time.perf_counter()
    with _timed(timings, "lattice"):
        lattice = build_lattice(scene, config.texel_m)
    groups = emitter_groups(scene)
    states = visibility_states(scene)
    key = _scene_digest(scene, config)
    path = Path(cache_dir if cache_dir is not None else default_cache_dir()) / "lightmaps" / f"{key}.npz"
    shape = (len(states), len(groups), 2, lattice.size, 3)
    if not use_cache:
        return _bake(scene, config, lattice, groups, states, key, start, progress, timings, None)
    cached = _load_bake(path, lattice, states, groups, config, key, shape)
    if cached is not None:
        return cached
    # Another process (a second test worker, a warm-up, a second user of a shared cache) may be baking
    # the same scene: wait for it and load its result rather than bake twice.
    with _cache_lock(path):
        cached = _load_bake(path, lattice, states, groups, config, key, shape)
        if cached is not None:
            return cached
        return _bake(scene, config, lattice, groups, states, key, start, progress, timings, path)


@contextlib.contextmanager
def _cache_lock(path: Path):
    """An exclusive ``flock`` on ``<path>.lock`` (released by the kernel if the process dies)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _load_bake(path: Path, lattice, states, groups, config: BakeConfig, key: str, shape) -> SceneLighting | None:
    """The cached bake at ``path`` if it is there, readable and of the expected shape, else None."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            values, valid = z["values"], z["valid"]
            seconds = float(z["bake_seconds"])
    except (OSError, ValueError, KeyError):
        return None  # unreadable entry: bake again and replace it
    if values.shape != shape or valid.shape != (len(states), 2, lattice.size):
        return None
    return SceneLighting(lattice, tuple(states), tuple(groups), values, valid, config, key, seconds, True)


def _bake(scene: Scene, config: BakeConfig, lattice, groups, states, key: str, start: float, progress, timings,
          path: Path | None) -> SceneLighting:
    """Compute the bake (and write it to ``path`` unless None)."""
    from sim.mitsuba_scene import build_scene

    shape = (len(states), len(groups), 2, lattice.size, 3)
    values = np.zeros(shape, np.float32)
    valid = np.zeros((len(states), 2, lattice.size), bool)
    done, total = 0, len(states) * len(groups)
    n_points = lattice.size
    for family in _families(states):
        # The family's sides: every side live in any of its states (state s uses rows[s] of them).
        keys = {}
        for s in family:
            with _timed(timings, f"live sides s{s}"):
                valid[s] = _live_mask(scene, states[s], lattice)
            keys[s] = np.flatnonzero(valid[s].ravel())  # side × P + point, ascending
        union = np.unique(np.concatenate([keys[s] for s in family]))
        rows = {s: np.searchsorted(union, keys[s]) for s in family}
        side_u, point_u = np.divmod(union, n_points)
        normals_u = lattice.point_normal[point_u] * (1.0 - 2.0 * side_u)[:, None]
        origins_u = lattice.points[point_u] + ORIGIN_OFFSET_M * normals_u
        directs: dict[int, list[np.ndarray]] = {s: [] for s in family}
        for g, members in enumerate(groups):
            base_seed = config.seed * 1009 + family[0] * 31 + g
            with _timed(timings, f"direct g{g}" + "".join(f" s{s}" for s in family)):
                shared = _shared_direct(scene, states, family, members, origins_u, normals_u, config.direct_samples,
                                        config.final_gather or config.spp, base_seed)
            for s in family:
                r = rows[s]
                scale = np.zeros(len(scene.objects))
                scale[list(members)] = 1.0
                with _timed(timings, f"first pass s{s} g{g}"):
                    mi_scene = build_scene(scene, states[s], scale, max_depth=config.max_depth,
                                           rr_depth=config.rr_depth)
                    direct, first = _first_pass(scene, states[s], members, mi_scene, origins_u[r], normals_u[r],
                                                config, seed=config.seed * 1009 + s * 31 + g,
                                                n_area=config.direct_samples, n_cos=config.final_gather or config.spp,
                                                direct=shared[s][r], timings=timings, label=f" s{s} g{g}")
                side, point = np.divmod(keys[s], n_points)
                values[s, g, side, point] = first
                directs[s].append(direct)
                done += 1
                if progress is not None:
                    progress(done, total)
        if config.final_gather:
            with _timed(timings, "final gather" + "".join(f" s{s}" for s in family)):
                final = _final_gather(scene, states, family, groups, lattice, values, valid, directs, rows,
                                      origins_u, normals_u, config, seed=config.seed * 1013 + family[0] * 37)
            for s in family:
                side, point = np.divmod(keys[s], n_points)
                for g in range(len(groups)):
                    values[s, g, side, point] = final[s][g]
    seconds = time.perf_counter() - start
    if path is not None:
        buf = io.BytesIO()
        np.savez(buf, values=values, valid=valid, bake_seconds=np.float64(seconds))
        atomic_write_bytes(path, buf.getvalue())
    return SceneLighting(lattice, tuple(states), tuple(groups), values, valid, config, key, seconds, False)


@numba.njit(cache=True)
def gather_kernel(obj, prim, bary, directions, tri_base, tri_n, tri_offset, tri_normal, combined, valid):  # pragma: no cover - compiled
    """Per ray: S at the hit, linearly interpolated on its triangle's lattice (zero for a miss or a
    surface that is not lit). ``bary`` (N, 2) are the hit's barycentric weights of vertices 1 and 2;
    the side is the front when the ray meets the triangle against its normal. Only live corners
    (``valid`` (2, P)) count: the weights of the others go to them in proportion; with none, zero."""
    n = obj.shape[0]
    out = np.zeros((n, 3), np.float32)
    for r in range(n):
        o = obj[r]
        if o < 0 or tri_base[o] < 0:
            continue
        t = tri_base[o] + prim[r]
        k = tri_n[t]
        dot = (tri_normal[t, 0] * directions[r, 0] + tri_normal[t, 1] * directions[r, 1]
               + tri_normal[t, 2] * directions[r, 2])
        side = 0 if dot < 0 else 1
        x = min(max(np.float64(bary[r, 0]), 0.0), 1.0) * k
        y = min(max(np.float64(bary[r, 1]), 0.0), 1.0) * k
        i = min(np.int64(x), k - 1)
        j = min(np.int64(y), k - 1)
        if i + j > k - 1:  # rounding past the far edge
            if i > j:
                i = k - 1 - j
            else:
                j = k - 1 - i
        fx = x - i
        fy = y - j
        base = tri_offset[t]
        # point (i, j) of the lattice: row j starts at j (k + 1) − j (j − 1) / 2
        p00 = base + j * (k + 1) - (j * (j - 1)) // 2 + i
        p10 = p00 + 1
        p01 = base + (j + 1) * (k + 1) - ((j + 1) * j) // 2 + i
        if fx + fy <= 1.0 or i + j == k - 1:
            w0, w1, w2 = 1.0 - fx - fy, fx, fy
            a, b, c = p00, p10, p01
        else:
            gx, gy = 1.0 - fx, 1.0 - fy
            w0, w1, w2 = 1.0 - gx - gy, gx, gy
            a, b, c = p01 + 1, p01, p10  # (i+1, j+1), (i, j+1), (i+1, j)
        if not valid[side, a]:
            w0 = 0.0
        if not valid[side, b]:
            w1 = 0.0
        if not valid[side, c]:
            w2 = 0.0
        total = w0 + w1 + w2
        if total <= 1e-9:
            continue
        for ch in range(3):
            out[r, ch] = np.float32((w0 * combined[side, a, ch] + w1 * combined[side, b, ch] + w2 * combined[side, c, ch]) / total)
    return out
