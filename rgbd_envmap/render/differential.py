"""Differential rendering: the virtual object's change to the real surfaces around it, lit by lights
from the map and SH (papers 000 §4.2–5 and 001 §3.1; docs/design/differential.md).

The map is split into a direct part (the brightest pixels holding a fraction τ of its energy,
:func:`rgbd_envmap.lights.split_direct_indirect`) sampled into a few lights with world positions (from
the map's depth), and an indirect rest kept as SH coefficients, so every pixel's energy counts once.
On each real surface point x with normal n near the object (a vertex of the
:class:`~rgbd_envmap.render.geometry.ReceiverMesh` built from the map's depth):

    E_without(x) = Σ_i I_i max(0, n·ℓ_i) / r_i²  +  Σ_k L_k Â_l Y_k(n)
    E_with(x)    = Σ_i I_i max(0, n·ℓ_i) / r_i² V_i(x)  +  Σ_k L_k (Â_l Y_k(n) − B_k(x))  +  ∫_blocked L_obj(ω) max(0, n·ω) dω

with I_i = power_i · |p_i − origin|² the light's intensity (a distant light, without a position, gives
power_i max(0, n·d_i); a virtual area light is the sum of its points, each with its part of the
power: :attr:`rgbd_envmap.lights.LightSet.point_lights`), V_i the visibility of light i through the
virtual object (a shadow ray from x to the light's position against the object's mesh),
B_k(x) = ∫_blocked max(0, n·ω) Y_k(ω) dω the SH projection of the directions in which x sees the object, F(x) = ∫_blocked max(0, n·ω) dω their
cosine-weighted solid angle and L_obj(ω) the object's outgoing radiance where the ray x + tω meets it
(the light it reflects onto x, paper 001's colour bleeding from virtual to real: the object's side that
faces x, so a lamp-lit top does not light the table under it). B, F and the last integral's weights
are estimated once per receiver mesh by casting ``samples`` stratified rays per vertex into the cone
of the object's bounding sphere: each ray that meets the object adds its weight to the three
vertices of the triangle it hits, by the hit's barycentric coordinates (``ReceiverOcclusion.bounce``,
a sparse receivers × object-vertices matrix), so the integral is one sparse product with the
object's vertex radiance on every relight (or, for PRT colours, that matrix times the object's
transfer, kept per mesh, times the SH coefficients).

The composite is then camera · E_with / E_without per channel in the reference colour space
(:func:`rgbd_envmap.render.composite.composite_differential`): with the real surface's albedo
ρ = π · camera / E_without (radiance over irradiance), final = camera + ρ (E_with − E_without) / π,
paper 000 eq. 14 / paper 001's L_rv − L_r added to the frame. The object's own vertices are shaded
with the same lights, each with a self-shadow ray, plus the PRT of the indirect coefficients
(:func:`object_radiance`).

With ``object_colours`` (the pipeline's default, ``render.object_shading = "prt"``) the object keeps
its PRT shading from the whole map and the lights only shadow the receivers. Shadow rays use open3d's
Embree ray caster (no numba kernel); a light's rays are reused by the next relight's light seen from
the object's centre within 0.5° of it (the cosine and distance terms are recomputed exactly), since the
lamp of a captured map stays put from one depth frame to the next.

References:
    - Rohmer, Büschel, Dachselt, Grosch (paper 000) §4.2 (direct / indirect split), §4.3 (lights with
      positions), §5 (shadows from the lights, differential rendering).
    - Knecht, Traxler, Mattausch, Purgathofer, Wimmer, Differential Instant Radiosity for Mixed Reality
      (paper 001) §3.1 (L_rv − L_r added to the camera image), §3.7 (light from virtual onto real).
    - Debevec (1998), Rendering synthetic objects into real scenes (differential rendering).
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels.light_weights import light_irradiance_kernel, light_weights_kernel
from rgbd_envmap._kernels.occlusion_rays import cone_rays_kernel, ray_sh_sums_kernel
from rgbd_envmap._kernels.receiver_shading import faces_touching_kernel, receiver_ratio_kernel
from rgbd_envmap._kernels.shadow_rays import shadow_ray_candidates_kernel
from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.lights import LightSet
from rgbd_envmap.render.composite import RATIO_EPS
from rgbd_envmap.render.geometry import ReceiverMesh

__all__ = ["ObjectOccluder", "ReceiverOcclusion", "cone_directions", "direct_irradiance", "object_radiance",
           "receiver_occlusion"]

#: rays per open3d call (bounded memory).
_CHUNK = 1 << 18


def _fib_pattern(m: int) -> np.ndarray:
    """(m, 2) stratified points in [0, 1)²: the Fibonacci lattice ((i + ½)/m, frac(i φ⁻¹))."""
    i = np.arange(m, dtype=np.float64)
    return np.stack([(i + 0.5) / m, np.mod(i * 0.6180339887498949, 1.0)], axis=1)


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) completing unit ``axis`` (N, 3) to an orthonormal frame."""
    helper = np.where(np.abs(axis[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(axis, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(axis, t)


def cone_directions(axis: np.ndarray, cos_max: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Stratified directions (N, m, 3) uniform in the cones around unit ``axis`` (N, 3) of half-angle
    acos(cos_max) (N,), and each cone's solid angle (N,) = 2π (1 − cos_max)."""
    u = _fib_pattern(m)
    cos_t = 1.0 - u[None, :, 0] * (1.0 - cos_max[:, None])
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2 * np.pi * u[None, :, 1]
    t, b = _frame(axis)
    d = (cos_t[..., None] * axis[:, None, :] + (sin_t * np.cos(phi))[..., None] * t[:, None, :]
         + (sin_t * np.sin(phi))[..., None] * b[:, None, :])
    return d, 2 * np.pi * (1.0 - cos_max)


class ObjectOccluder:
    """The virtual object's mesh in the world, ready for shadow rays (open3d RaycastingScene), with
    its bounding sphere (centre of the bounding box, radius to the farthest vertex)."""

    def __init__(self, vertices_world: object, faces: object) -> None:
        import open3d as o3d  # local: importing open3d is slow

        v = check_array(vertices_world, "vertices_world", shape=("V", 3), dtype=("float", "int"), finite=True)
        f = check_array(faces, "faces", shape=("F", 3), dtype="int")
        self.vertices = np.asarray(v, np.float64)
        self.centre = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        self.radius = float(np.linalg.norm(self.vertices - self.centre, axis=1).max()) if len(v) else 0.0
        self._o3d = o3d
        self.faces = np.asarray(f, np.int64)
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(f):
            self._scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                                      o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)))

    def first_hits(self, origins: np.ndarray, vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where the rays origins + t · vectors, t > 0, first meet the object: (hit (N,) bool,
        triangle index (N,) int64, barycentric weights (N, 3) float64 of its three vertices, rows
        summing to 1; zeros where the ray misses)."""
        n = len(origins)
        hit = np.zeros(n, bool)
        tri = np.zeros(n, np.int64)
        bary = np.zeros((n, 3))
        for s in range(0, n, _CHUNK):
            rays = np.concatenate([origins[s:s + _CHUNK], vectors[s:s + _CHUNK]], axis=1).astype(np.float32)
            ans = self._scene.cast_rays(self._o3d.core.Tensor(rays))
            h = np.isfinite(ans["t_hit"].numpy())
            uv = ans["primitive_uvs"].numpy().astype(np.float64)
            sl = slice(s, s + len(rays))
            hit[sl] = h
            tri[sl] = np.where(h, ans["primitive_ids"].numpy().astype(np.int64), 0)
            # open3d's uv: the hit is (1 − u − v) · v0 + u · v1 + v · v2
            bary[sl] = np.where(h[:, None], np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1), 0.0)
        return hit, tri, bary

    def blocked(self, origins: np.ndarray, vectors: np.ndarray, t_far: float = np.inf) -> np.ndarray:
        """(N,) bool: the ray origins + t · vectors, 0 < t < ``t_far``, meets the object (t in units of
        |vectors|: with t_far = 1 and vectors = target − origin the segment to the target)."""
        out = np.zeros(len(origins), bool)
        for s in range(0, len(origins), _CHUNK):
            rays = np.concatenate([origins[s:s + _CHUNK], vectors[s:s + _CHUNK]], axis=1).astype(np.float32)
            hit = self._scene.test_occlusions(self._o3d.core.Tensor(rays), tnear=0.0, tfar=float(t_far))
            out[s:s + _CHUNK] = hit.numpy().astype(bool)
        return out


class ReceiverOcclusion:
    """What the object hides from each receiver vertex: ``blocked_sh`` (R, n²) float64 B_k,
    ``blocked_cos`` (R,) float64 F, and ``bounce`` (R, V) sparse (CSR) float64 the weights of the
    object's V vertex radiances in ∫_blocked L_obj max(0, n·ω) dω (module docstring; each row sums to
    F). Without ``bounce`` (None) the object's mean radiance stands for L_obj."""

    def __init__(self, blocked_sh: np.ndarray, blocked_cos: np.ndarray, bounce=None) -> None:
        self.blocked_sh = blocked_sh
        self.blocked_cos = blocked_cos
        self.bounce = bounce

    def bounced(self, colours: np.ndarray) -> np.ndarray:
        """(R, 3) float64 the light the object reflects onto each receiver, ∫_blocked L_obj cos dω,
        for the object's vertex radiance ``colours`` (V, 3)."""
        c = np.asarray(colours, np.float64)
        if self.bounce is not None:
            return np.asarray(self.bounce @ c)
        l_obj = (np.ones(len(c)) @ c) / max(len(c), 1)  # a product with ones: a column mean is ~10× slower
        return self.blocked_cos[:, None] * l_obj[None]


def receiver_occlusion(receivers: ReceiverMesh, occluder: ObjectOccluder, bands: int, *, samples: int = 32,
                       offset_m: float = 1e-4) -> ReceiverOcclusion:
    """B_k, F and the bounce weights of every receiver vertex by ``samples`` stratified rays in the
    cone of the object's bounding sphere (the hemisphere around the normal when the vertex is inside
    the sphere)."""
    from scipy.sparse import coo_matrix, csr_matrix

    bands = check_number(bands, "bands", low=1, integer=True)
    samples = check_number(samples, "samples", low=1, integer=True)
    V = len(receivers)
    nv = len(occluder.vertices)
    out_sh = np.zeros((V, bands * bands))
    out_cos = np.zeros(V)
    rows, cols, vals = [], [], []
    if V == 0 or occluder.radius <= 0:
        return ReceiverOcclusion(out_sh, out_cos, csr_matrix((V, nv)))
    p, n = receivers.vertices, receivers.normals
    to_c = occluder.centre - p
    d = np.linalg.norm(to_c, axis=1)
    r = occluder.radius
    inside = d <= r * 1.0001
    sin_a = np.where(inside, 1.0, r / np.maximum(d, 1e-12))
    cos_a = np.sqrt(np.maximum(0.0, 1.0 - sin_a ** 2))
    axis = np.where(inside[:, None], n, to_c / np.maximum(d, 1e-12)[:, None])
    cos_max = np.where(inside, 0.0, cos_a)
    # the cone can be seen from the front of the surface at all
    above = inside | (np.sum(n * axis, axis=1) > -sin_a)
    idx = np.flatnonzero(above)
    pattern = _fib_pattern(samples)
    omega = 2 * np.pi * (1.0 - cos_max)  # each cone's solid angle
    step = max(1, _CHUNK // samples)
    cap = min(len(idx), step) * samples
    org, dirs = np.empty((cap, 3)), np.empty((cap, 3))
    owner, cos = np.empty(cap, np.int64), np.empty(cap)
    for s in range(0, len(idx), step):
        ii = idx[s:s + step]
        # the rays that leave the front of the surface, receiver by receiver (owner: index into ii)
        k = cone_rays_kernel(p, n, axis, cos_max, pattern, offset_m, ii, org, dirs, owner, cos)
        hit = occluder.blocked(org[:k], dirs[:k])  # the occlusion test first: cheaper than a full cast
        ho, hd = org[:k][hit], dirs[:k][hit]
        if not len(ho):
            continue
        ci = ii[owner[:k][hit]]  # ascending: each vertex's blocked rays are one run
        _, tri, bary = occluder.first_hits(ho, hd)
        w = (omega[ci] / samples) * cos[:k][hit]
        rows.append(np.repeat(ci, 3))
        cols.append(occluder.faces[tri].ravel())
        vals.append((w[:, None] * bary).ravel())
        ray_sh_sums_kernel(hd, w, ci, bands, out_sh, out_cos)
    if rows:  # duplicates (a vertex hit by several rays of one receiver) are summed by the conversion
        bounce = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(V, nv)).tocsr()
    else:
        bounce = csr_matrix((V, nv))
    return ReceiverOcclusion(out_sh, out_cos, bounce)


def direct_irradiance(lights: LightSet, points: object, normals: object, visible: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) float64 irradiance of ``lights`` at world ``points`` (N, 3) with unit ``normals`` (N, 3):
    point lights where a light has a position (intensity power · |p − origin|², inverse square law),
    directional ones where not; ``visible`` (N, n) bool multiplies each light's term."""
    if not isinstance(lights, LightSet):
        raise InvalidInputError(f"lights: expected a LightSet, got {type(lights).__name__}")
    pts = check_array(points, "points", shape=("N", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    nrm = check_array(normals, "normals", shape=(len(pts), 3), dtype=("float", "int"), finite=True).astype(np.float64)
    if len(lights) == 0 or len(pts) == 0:
        return np.zeros((len(pts), 3))
    w = _light_weights_unshadowed(lights, pts, nrm)
    if visible is not None:
        w = w * visible
    return w @ lights.power


def _light_terms(lights: LightSet) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kernels' view of ``lights``: (has a position (n,) bool, positions (n, 3) with 0 where
    none, directions (n, 3), intensity I = |p − origin|² (n,), 0 without an origin)."""
    has_pos = np.zeros(len(lights), bool) if lights.positions is None else np.isfinite(lights.positions).all(axis=1)
    pos = np.zeros((len(lights), 3)) if lights.positions is None else np.where(has_pos[:, None], lights.positions, 0.0)
    intensity = np.zeros(len(lights)) if lights.origin is None else np.sum((pos - lights.origin) ** 2, axis=1)
    return has_pos, np.ascontiguousarray(pos, np.float64), np.ascontiguousarray(lights.directions, np.float64), intensity


def _light_irradiance(lights: LightSet, points: np.ndarray, normals: np.ndarray,
                      visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 each: the lights' irradiance at ``points`` without and with their shadows
    (``visible`` (N, n) bool), Σ_j w_ij power_j and Σ_j w_ij v_ij power_j with the weights of
    :func:`_light_weights_unshadowed`, in one compiled pass that forms no (N, n) weights
    (:func:`rgbd_envmap._kernels.light_weights.light_irradiance_kernel`)."""
    pts = np.asarray(points, np.float64)
    out_all, out_visible = np.zeros((3, len(pts))), np.zeros((3, len(pts)))
    if len(lights) and len(pts):
        has_pos, pos, dirs, intensity = _light_terms(lights)
        # one row per coordinate (the kernel's inner loop then reads consecutive values)
        light_irradiance_kernel(np.ascontiguousarray(pts.T), np.ascontiguousarray(np.asarray(normals, np.float64).T),
                                pos, has_pos, dirs, intensity, np.ascontiguousarray(lights.power, np.float64),
                                np.ascontiguousarray(np.asarray(visible, np.bool_).T), out_all, out_visible)
    return np.ascontiguousarray(out_all.T), np.ascontiguousarray(out_visible.T)


def _light_weights_unshadowed(lights: LightSet, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, n) float64: the irradiance each light gives per unit power at ``points`` with ``normals``
    (the weights :func:`direct_irradiance` multiplies by the lights' power): I max(0, n·Δ) / |Δ|³ with
    Δ = p_i − x and I = |p_i − origin|² for a light with a position, max(0, n·d_i) for a distant one.
    One compiled pass (:mod:`rgbd_envmap._kernels.light_weights`)."""
    pts = np.ascontiguousarray(points, np.float64)
    nrm = np.ascontiguousarray(normals, np.float64)
    w = np.zeros((len(pts), len(lights)))
    if len(lights) == 0 or len(pts) == 0:
        return w
    has_pos, pos, dirs, intensity = _light_terms(lights)
    light_weights_kernel(pts, nrm, pos, has_pos, dirs, intensity, w)
    return w


def light_visibility(lights: LightSet, points: np.ndarray, normals: np.ndarray, occluder: ObjectOccluder, *,
                     offset_m: float = 1e-4, cull: bool = True) -> np.ndarray:
    """(N, n) bool: light i seen from point x past the object (a shadow ray from x + offset · n to
    the light's position, or 1 km along a distant light's direction). With ``cull`` only rays that
    pass within the object's bounding sphere are cast (the others cannot meet it)."""
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    vis = np.ones((len(pts), len(lights)), bool)
    if len(pts) == 0 or len(lights) == 0 or occluder.radius <= 0:
        return vis
    org = np.ascontiguousarray(pts + offset_m * nrm)
    has_pos = np.zeros(len(lights), bool) if lights.positions is None else np.isfinite(lights.positions).all(axis=1)
    pos = np.zeros((len(lights), 3)) if lights.positions is None else np.where(has_pos[:, None], lights.positions, 0.0)
    size = len(pts) * len(lights)
    rows, cols, vec = np.empty(size, np.int64), np.empty(size, np.int64), np.empty((size, 3))
    # the rays that pass the object's bounding sphere, in one compiled pass (_kernels/shadow_rays.py)
    count = shadow_ray_candidates_kernel(org, np.ascontiguousarray(pos, np.float64), has_pos,
                                         np.ascontiguousarray(lights.directions, np.float64),
                                         np.asarray(occluder.centre, np.float64), float(occluder.radius), bool(cull),
                                         rows, cols, vec)
    if count:  # every (point, light) ray in one batch
        rows, cols = rows[:count], cols[:count]
        vis[rows, cols] = ~occluder.blocked(org[rows], vec[:count], 1.0)
    return vis


def object_radiance(albedo: object, transfer: np.ndarray, coeffs_indirect: np.ndarray, direct: np.ndarray) -> np.ndarray:
    """(V, 3) float32 outgoing radiance of the object's vertices: albedo / π · (direct irradiance
    (V, 3) from the lights, self-shadowed + Σ_k L_k T_k of the indirect coefficients)."""
    a = np.asarray(albedo, np.float64).reshape(1, 3)
    e = np.asarray(transfer, np.float64) @ np.asarray(coeffs_indirect, np.float64) + direct
    return (a / np.pi * np.maximum(e, 0.0)).astype(np.float32)


class DifferentialShader:
    """The per-relight state of the differential composite: the object in the world (its shadow-ray
    scene), the receiver mesh with its :class:`ReceiverOcclusion`, and, per light, the weights that
    turn its power into irradiance at every receiver and object vertex (cosine, distance and shadow
    ray). The shadow rays are kept from one call to the next and reused for a light seen from the
    object's centre within ``cache_deg`` (0.5°) of a kept one: the lamp of a captured map stays put
    from one depth frame to the next, up to the jitter of its power-weighted mean position as the map
    is updated. Called again with the same :class:`LightSet` object (a caller that kept its lights),
    the lights' irradiance terms themselves are reused and only the SH part is recomputed.

    :meth:`shade` returns the object's vertex radiance and the receivers' per-vertex ratio
    E_with / E_without (module docstring)."""

    def __init__(self, object_vertices_world: object, object_faces: object, object_normals: object, *,
                 samples: int = 32, cache_deg: float = 0.5) -> None:
        self.occluder = ObjectOccluder(object_vertices_world, object_faces)
        self.object_normals = np.asarray(object_normals, np.float64)
        self.samples = check_number(samples, "samples", low=1, integer=True)
        self.cache_deg = check_number(cache_deg, "cache_deg", low=0.0, high=180.0)
        self.receivers = ReceiverMesh.empty()
        self._occlusion: ReceiverOcclusion | None = None
        self._floor: np.ndarray | None = None
        self._bands = 0
        # the receivers' SH transfer without / with the object, (K, R) float32 (the kernel's layout),
        # the share of missed light the object leaves each receiver, and the kernel's scratch
        self._t0 = self._t1 = np.zeros((0, 0), np.float32)
        self._keep = np.zeros(0)
        self._scratch = np.zeros((3, 3, 0))
        self._far: tuple | None = None  # (the last ratio returned, its far flags)
        # the shadow rays of recent lights: (kind, unit direction from the object's centre,
        # receiver visibility (R,) bool, object visibility (V,) bool or None)
        self._visibility: list[tuple[str, np.ndarray, np.ndarray, np.ndarray | None]] = []
        # the last light set (a LightSet is frozen: the same object is the same lights) with its
        # direct irradiance at the receivers without / with the object and at the object's vertices
        self._direct: tuple | None = None
        # (key, bounce weights @ the object's transfer (R, K), the transfer itself: keeps its id valid)
        self._bounce_t: tuple | None = None

    @property
    def cached_lights(self) -> tuple[tuple, ...]:
        """What the cached shadow rays were cast for: (kind, direction from the object's centre rounded
        to 1e-6) per light, "p" for a positioned light and "d" for a distant one."""
        return tuple((k, *np.round(d, 6).tolist()) for k, d, _, _ in self._visibility)

    def set_receivers(self, receivers: ReceiverMesh, bands: int, radiance: object = None, max_albedo: float = 1.0,
                      occlusion: ReceiverOcclusion | None = None) -> None:
        """A new receiver mesh (the map's geometry changed): its occlusion is estimated anew (or taken
        from ``occlusion``, :func:`receiver_occlusion` of this mesh and object at ``bands`` and
        ``self.samples``, computed elsewhere), and its SH transfer without (Â_l Y_k(n)) and with the
        object (minus B_k) kept.

        ``radiance`` (R, 3): the map's radiance of each receiver vertex (what the camera saw there).
        With it the receivers' irradiance without the object is kept at least π · radiance /
        ``max_albedo``: a surface cannot reflect more than it receives, so where the map's lights
        and SH give less, the map has missed light (parts of the room it did not see). That missing
        light M is taken as uniform over the hemisphere, of which the object hides F / π, so E_with
        gains M (1 − F / π). Without the floor a poorly covered map gives a well-observed table a
        small E_without, and the object's changes, divided by it, are magnified."""
        self.receivers = receivers
        self._floor = None
        if radiance is not None:
            rad = check_array(radiance, "radiance", shape=(len(receivers), 3), dtype="float")
            max_albedo = check_number(max_albedo, "max_albedo", low=0.0, low_open=True)
            self._floor = np.pi * np.maximum(np.nan_to_num(np.asarray(rad, np.float64)), 0.0) / max_albedo
        self._bands = check_number(bands, "bands", low=1, integer=True)
        if occlusion is None:
            occlusion = receiver_occlusion(receivers, self.occluder, bands, samples=self.samples)
        elif not isinstance(occlusion, ReceiverOcclusion) or occlusion.blocked_sh.shape != (len(receivers), bands * bands) \
                or (occlusion.bounce is not None
                    and occlusion.bounce.shape != (len(receivers), len(self.occluder.vertices))):
            raise InvalidInputError(f"occlusion: expected the ReceiverOcclusion of these {len(receivers)} receivers "
                                    f"at {bands} bands and this object's {len(self.occluder.vertices)} vertices")
        self._occlusion = occlusion
        from rgbd_envmap.prt import unoccluded_transfer

        t0 = unoccluded_transfer(receivers.normals, bands).astype(np.float64) if len(receivers) else \
            np.zeros((0, bands * bands))
        self._t0 = np.ascontiguousarray(t0.T, np.float32)
        self._t1 = np.ascontiguousarray((t0 - self._occlusion.blocked_sh).T, np.float32)
        self._keep = np.maximum(1.0 - self._occlusion.blocked_cos / np.pi, 0.0)
        self._scratch = np.empty((3, 3, len(receivers)))
        self._far = None
        self._visibility = []
        self._direct = None
        self._bounce_t = None

    def _seen_from_object(self, lights: LightSet) -> tuple[list[str], np.ndarray]:
        """Each light's kind ("p" positioned, "d" distant: no position, or at the object's centre)
        and unit direction from the object's centre (a distant light's own)."""
        dirs = np.array(lights.directions, np.float64)
        positioned = np.zeros(len(lights), bool)
        if lights.positions is not None and len(lights):
            v = np.where(np.isfinite(lights.positions), lights.positions, 0.0) - self.occluder.centre
            nv = np.linalg.norm(v, axis=1)
            positioned = np.isfinite(lights.positions).all(axis=1) & (nv > 0)
            dirs[positioned] = v[positioned] / nv[positioned, None]
        return ["p" if q else "d" for q in positioned.tolist()], dirs

    def _shadows(self, lights: LightSet, with_object: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """(R, n) receiver and (V, n) object visibility of each light (None without ``with_object``:
        the object's self-shadow rays are neither cast nor kept).

        The shadow rays are reused from a light of the last call seen from the object's centre
        within ``cache_deg`` of this one (a lamp's power-weighted mean position jitters as the map is
        updated; 0.5° moves a shadow cast from 10 cm above a surface by under 1 mm, an eighth of the
        receivers' spacing); the cosine and distance terms (:func:`_light_irradiance`) are exact for
        every light on every call."""
        p, n = self.receivers.vertices, self.receivers.normals
        kinds, dirs = self._seen_from_object(lights)
        cos_tol = np.cos(np.radians(self.cache_deg))
        # each light's kept entry: the one of its kind (with object rays if they are needed) seen
        # within cache_deg, the nearest, the last of equals
        old = self._visibility
        match = np.full(len(lights), -1)
        if old and len(lights):
            c = dirs @ np.array([e[1] for e in old]).T
            old_kind = np.array([e[0] for e in old])
            has_object_rays = np.array([e[3] is not None or not with_object for e in old])
            usable = (np.array(kinds)[:, None] == old_kind[None, :]) & has_object_rays[None, :]
            c = np.where(usable, c, -np.inf)
            last = c.shape[1] - 1 - np.argmax(c[:, ::-1], axis=1)
            ok = c[np.arange(len(lights)), last] >= cos_tol
            match[ok] = last[ok]
        miss = np.flatnonzero(match < 0)
        if len(miss):  # the shadow rays of every light without a kept entry, in one batch
            fresh = LightSet(lights.directions[miss], np.ones((len(miss), 3)), lights.method,
                             positions=None if lights.positions is None else lights.positions[miss],
                             origin=lights.origin)
            r = light_visibility(fresh, p, n, self.occluder)
            o = light_visibility(fresh, self.occluder.vertices, self.object_normals, self.occluder,
                                 cull=False) if with_object else None
        entries = [None] * len(lights)
        for j, i in enumerate(miss):
            entries[i] = (kinds[i], dirs[i], r[:, j], None if o is None else o[:, j])
        keep, kept = [], set()
        for i in range(len(lights)):
            if entries[i] is None:
                entries[i] = old[match[i]]
            if id(entries[i]) not in kept:
                kept.add(id(entries[i]))
                keep.append(entries[i])
        # one row per light, returned transposed ((R, n) views): the irradiance kernel reads them by light
        rv = (np.stack([e[2] for e in entries]) if entries else np.ones((0, len(p)), bool)).T
        ov = None
        if with_object:
            ov = (np.stack([e[3] for e in entries]) if entries else np.ones((0, len(self.occluder.vertices)), bool)).T
        self._visibility = keep
        return rv, ov

    def shade(self, lights: LightSet | None, coeffs_indirect: np.ndarray, transfer: np.ndarray,
              albedo: object, object_colours: np.ndarray | None = None,
              object_coeffs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(object vertex radiance (V, 3) float32, receiver ratio (R, 3) float32) for the lights (None:
        no direct part; area lights, with ``points``, as a point light per point, so that the shadow
        rays to a light's points give its penumbra) and the indirect SH coefficients (n², 3);
        ``transfer`` (V, ≥ n²) the object's PRT transfer (its first n² columns are used). ``object_colours`` (V, 3): the object's radiance
        as shaded elsewhere (PRT of the whole map): returned as it is and used for the light it
        reflects onto the receivers; the lights' self-shadow rays are then not cast.
        ``object_coeffs`` (m², 3): the coefficients ``object_colours`` were shaded with by PRT
        (albedo / π · transfer[:, :m²] @ object_coeffs); the light the object reflects onto the
        receivers is then formed from them through the bounce weights times the transfer (kept per
        receiver mesh: an (R, m²) product instead of a sparse (R, V) one per call; equal up to the
        colours' float32 rounding)."""
        from rgbd_envmap.prt import shade as prt_shade

        c = np.asarray(coeffs_indirect, np.float64)
        nk = c.shape[0]
        if self._occlusion is not None and nk > self._bands ** 2:
            raise InvalidInputError(f"coeffs_indirect: expected at most {self._bands}² rows (the receivers' bands), got {nk}")
        V = len(self.occluder.vertices)
        if object_colours is not None:
            object_colours = check_array(object_colours, "object_colours", shape=(V, 3), dtype="float")
        if lights is not None:
            lights = lights.point_lights  # area lights: a shadow ray to each of their points
        has = lights is not None and len(lights) > 0
        with_object = object_colours is None
        if has:
            kept = self._direct
            if kept is not None and kept[0] is lights and kept[1] == with_object:
                d0, d1, do = kept[2:]  # the same light set as last call: its terms are unchanged
            else:
                rv, ov = self._shadows(lights, with_object=with_object)
                d0, d1 = _light_irradiance(lights, self.receivers.vertices, self.receivers.normals, rv)
                do = None if ov is None else _light_irradiance(lights, self.occluder.vertices, self.object_normals, ov)[1]
                self._direct = (lights, with_object, d0, d1, do)
        a = np.asarray(albedo, np.float64).reshape(3)
        if object_colours is not None:
            colours = object_colours
        else:
            colours = prt_shade(np.asarray(transfer)[:, :nk], c, a)
            if has:
                colours = (colours + (a / np.pi) * do).astype(np.float32)
        R = len(self.receivers)
        if R == 0:
            return colours, np.ones((0, 3), np.float32)
        zeros = np.zeros((R, 3))
        add0, add1 = (d0, d1) if has else (zeros, zeros)
        # the object's light onto each receiver, from its side that faces it: from the coefficients
        # through the bounce weights × transfer, or from the shaded colours through the weights
        if object_coeffs is not None and object_colours is not None and self._occlusion.bounce is not None:
            bt = self._bounced_sh(transfer)
            bc = np.ascontiguousarray(np.asarray(object_coeffs, np.float64)[:bt.shape[0]] * (a / np.pi)[None])
        else:
            bt, bc = np.zeros((0, R), np.float32), np.zeros((0, 3))
            add1 = add1 + self._occlusion.bounced(colours)
        ratio = np.empty((R, 3), np.float32)
        far = np.empty(R, bool)
        use_floor = self._floor is not None  # light the map missed (set_receivers)
        s0, s1, sb = self._scratch
        receiver_ratio_kernel(self._t0, self._t1, nk, c, bt, bc.shape[0], bc, np.ascontiguousarray(add0, np.float64),
                              np.ascontiguousarray(add1, np.float64), self._floor if use_floor else zeros, use_floor,
                              self._keep, 1e-6, 4.0, RATIO_EPS, s0, s1, sb, ratio, far)
        self._far = (ratio, far)
        return colours, ratio

    def _bounced_sh(self, transfer: np.ndarray) -> np.ndarray:
        """(K, R) float32 the bounce weights × the object's transfer, transposed: with the object's
        coefficients × albedo / π, the object's PRT light onto the receivers. Computed once per
        receiver mesh and transfer array (an array changed in place is not seen: the pipeline's
        transfer is fixed per object)."""
        t = np.asarray(transfer)
        key = (id(transfer), t.shape)
        if self._bounce_t is None or self._bounce_t[0] != key:
            bt = np.asarray(self._occlusion.bounce @ t.astype(np.float64))
            self._bounce_t = (key, np.ascontiguousarray(bt.T, np.float32), transfer)
        return self._bounce_t[1]

    def active_faces(self, ratio: np.ndarray, eps: float = RATIO_EPS) -> np.ndarray:
        """(F', 3) int32 the receiver triangles with a vertex whose ratio is farther than ``eps`` from 1
        in some channel: the others change no pixel (the composite leaves a pixel within 1e-3 of a
        ratio of 1 as it is), so they need not be rasterised. The flags of the ratio :meth:`shade`
        returned last are reused."""
        r = np.asarray(ratio)
        if self._far is not None and self._far[0] is ratio and eps == RATIO_EPS:
            far = self._far[1]
        else:
            far = (np.abs(r.astype(np.float64) - 1.0) > eps).any(axis=1)
        f = np.ascontiguousarray(self.receivers.faces)
        out = np.empty_like(f)
        n = faces_touching_kernel(f, far, out)
        return out[:n].copy()
