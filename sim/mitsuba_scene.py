"""The simulator's scene as a Mitsuba 3 scene, and Mitsuba's path tracer on rays we choose.

Mitsuba is the physically based renderer behind the lit world: the bake (:mod:`sim.bake`) asks it for
the radiance arriving along rays leaving each surface point, and the reference frames
(:mod:`sim.reference`) for the radiance arriving at a camera through each pixel. Both go through
:func:`trace`, which hands arrays of rays to Mitsuba's ``path`` integrator (unidirectional path tracing
with next-event estimation and multiple importance sampling, Russian roulette after a few bounces) in
the vectorised ``llvm_ad_rgb`` variant: millions of rays per call, no Python per ray.

How a :class:`sim.scene.Scene` maps onto Mitsuba:

- every object is a triangle mesh with a two-sided diffuse BSDF (``twosided`` over ``diffuse``): its
  albedo for a lit surface, black for a fixed-radiance one;
- an emitting object of an *active* emitter group carries an ``area`` emitter (its emission, or its
  fixed radiance, times the group's scale). Mitsuba's area emitters emit on the front side only; our
  surfaces emit on both, so each emitter gets a second, face-reversed copy 0.1 mm behind it;
- procedural textures become bitmaps over the quad's (s, t) (nearest-neighbour for checkers and patches,
  bilinear for gradients);
- extra meshes (the virtual object of a reference frame) are lit diffuse surfaces.

References:
    Jakob, Speierer, Roussel et al., *Mitsuba 3 renderer* (2022), the ``path`` integrator and the
    ``area`` emitter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rgbd_envmap.errors import InvalidInputError
from sim.scene import Scene, SceneObject, Texture

__all__ = ["ExtraMesh", "mitsuba", "build_scene", "trace", "EMITTER_BACK_OFFSET_M"]

#: Distance behind an emitter of its face-reversed copy (the back side's emitter).
EMITTER_BACK_OFFSET_M = 1e-4

#: Texels per texture cell in the bitmaps made from procedural textures (checker, patches), and the
#: bitmap size of a gradient.
_CELL_TEXELS = 16
_GRADIENT_TEXELS = 256

#: Rays per call to Mitsuba: bounds the memory of one wavefront (~0.4 KB a ray in flight).
_WAVEFRONT = 1 << 20


@lru_cache(maxsize=1)
def mitsuba():
    """Mitsuba 3 in its ``llvm_ad_rgb`` variant (imported on first use; the variant is process-wide).

    The variant needs LLVM's shared library (Debian: ``apt-get install libllvm19``, which
    ``scripts/bootstrap.sh`` installs); without it this raises with that instruction.
    """
    import mitsuba as mi

    try:
        mi.set_variant("llvm_ad_rgb")
    except (ImportError, AttributeError, RuntimeError) as e:
        raise InvalidInputError(
            "the lit world needs Mitsuba's llvm_ad_rgb variant, which needs libLLVM "
            f"(apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH): {e}"
        ) from None
    return mi


@dataclass(frozen=True)
class ExtraMesh:
    """A lit diffuse mesh added to the scene (e.g. the virtual object of a reference frame)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray


def _texture_bitmap(texture: Texture) -> tuple[np.ndarray, str]:
    """(rows, cols, 3) float32 bitmap of a procedural texture and Mitsuba's filter for it: row r holds
    t = (r + ½) / rows and column c holds s = (c + ½) / cols (Mitsuba reads texture coordinate (u, v)
    at column u·cols, row v·rows; tests/sim/test_mitsuba_scene.py pins this)."""
    if texture.kind == "gradient":
        rows, cols = _GRADIENT_TEXELS, 2
    else:
        cols, rows = texture.cells[0] * _CELL_TEXELS, texture.cells[1] * _CELL_TEXELS
    s = (np.arange(cols) + 0.5) / cols
    t = (np.arange(rows) + 0.5) / rows
    ss, tt = np.meshgrid(s, t)
    image = texture.sample(ss.ravel(), tt.ravel()).reshape(rows, cols, 3)
    return np.ascontiguousarray(image, dtype=np.float32), ("bilinear" if texture.kind == "gradient" else "nearest")


def _value(mi, rgb: np.ndarray | None, texture: Texture | None, scale: float = 1.0) -> dict:
    if texture is not None:
        image, filt = _texture_bitmap(texture)
        return {"type": "bitmap", "bitmap": mi.Bitmap(image * np.float32(scale)), "raw": True,
                "filter_type": filt, "wrap_mode": "clamp"}
    return {"type": "rgb", "value": (np.asarray(rgb, np.float64) * scale).tolist()}


def _uv(obj: SceneObject) -> np.ndarray | None:
    """Per-vertex (s, t) of a quad (the texture coordinates of :class:`sim.scene.Texture`)."""
    if obj.quad_frame is None:
        return None
    corner, u, v = obj.quad_frame
    p = obj.vertices - corner
    return np.stack([p @ u / (u @ u), p @ v / (v @ v)], axis=1)


def _mesh(mi, name: str, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None, bsdf: dict,
          emitter: dict | None):
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    mesh = mi.Mesh(name, len(vertices), len(faces), props=props, has_vertex_normals=False,
                   has_vertex_texcoords=uv is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(faces, np.uint32).ravel())
    if uv is not None:
        params["vertex_texcoords"] = mi.Float(np.asarray(uv, np.float32).ravel())
    params.update()
    return mesh


def _back_copy(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None):
    """Each triangle face-reversed and moved EMITTER_BACK_OFFSET_M behind itself (a triangle soup)."""
    tri = vertices[faces]  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    tri = tri[:, ::-1] - EMITTER_BACK_OFFSET_M * n[:, None, :]
    soup_faces = np.arange(3 * len(faces)).reshape(-1, 3)
    soup_uv = None if uv is None else uv[faces][:, ::-1].reshape(-1, 2)
    return tri.reshape(-1, 3), soup_faces, soup_uv


def build_scene(scene: Scene, visible: frozenset[int], emitter_scale: Sequence[float],
                extra: Sequence[ExtraMesh] = (), max_depth: int = -1, rr_depth: int = 5):
    """The Mitsuba scene of the objects ``visible`` (indices into ``scene.objects``).

    ``emitter_scale[i]`` multiplies object i's emission (or fixed radiance); 0 leaves it dark (only its
    BSDF). ``max_depth`` is the path integrator's (−1: unbounded, ended by Russian roulette), and
    ``rr_depth`` the path length from which Russian roulette may end a path (Mitsuba's default, 5).
    """
    mi = mitsuba()
    d: dict = {"type": "scene", "integrator": {"type": "path", "max_depth": int(max_depth),
                                               "rr_depth": int(rr_depth)}}
    for i in sorted(visible):
        o = scene.objects[i]
        uv = _uv(o)
        if o.lit:
            reflect = _value(mi, o.albedo, o.albedo_texture)
            emit_rgb, emit_tex = o.emission, o.emission_texture
        else:
            reflect = {"type": "rgb", "value": [0.0, 0.0, 0.0]}
            emit_rgb, emit_tex = o.radiance, o.texture
        bsdf = {"type": "twosided", "material": {"type": "diffuse", "reflectance": reflect}}
        scale = float(emitter_scale[i])
        emitter = None
        if scale > 0 and o.emits:
            emitter = {"type": "area", "radiance": _value(mi, emit_rgb, emit_tex, scale)}
        d[f"o{i}"] = _mesh(mi, o.name, o.vertices, o.faces, uv, bsdf, emitter)
        if emitter is not None:
            bv, bf, buv = _back_copy(o.vertices, o.faces, uv)
            d[f"o{i}_back"] = _mesh(mi, o.name + "_back", bv, bf, buv, bsdf,
                                    {"type": "area", "radiance": _value(mi, emit_rgb, emit_tex, scale)})
    for k, m in enumerate(extra):
        bsdf = {"type": "twosided", "material": {"type": "diffuse", "reflectance": {
            "type": "rgb", "value": np.asarray(m.albedo, np.float64).reshape(3).tolist()}}}
        d[f"extra{k}"] = _mesh(mi, m.name, m.vertices, m.faces, None, bsdf, None)
    return mi.load_dict(d)


def trace(mi_scene, origins: np.ndarray, directions: np.ndarray, seed: int = 0, *,
          first_emission_weight: np.ndarray | None = None) -> np.ndarray:
    """Radiance (N, 3) float32 arriving at ``origins`` (N, 3) from unit ``directions`` (N, 3), one path
    each, through Mitsuba's path integrator; ``seed`` picks the random sequence (equal seeds on equal
    rays give equal results).

    ``first_emission_weight`` (N,): count the emission of the first surface each ray meets (which the
    integrator adds with weight one) with this weight instead, e.g. a multiple-importance weight when
    the caller samples the emitters itself. (The integrator's ``hide_emitters`` is not the same: it
    drops the reflection off a directly seen emitter too.)
    """
    mi = mitsuba()
    import drjit as dr

    origins = np.asarray(origins, np.float32).reshape(-1, 3)
    directions = np.asarray(directions, np.float32).reshape(-1, 3)
    n = len(directions)
    out = np.empty((n, 3), np.float32)
    integrator = mi_scene.integrator()
    sampler = mi.load_dict({"type": "independent"})
    for k, start in enumerate(range(0, n, _WAVEFRONT)):
        stop = min(start + _WAVEFRONT, n)
        o, dd = origins[start:stop], directions[start:stop]
        # An opaque seed: a literal one would make drjit compile a new kernel for every call.
        sampler.seed(dr.opaque(mi.UInt32, (int(seed) * 7919 + k) & 0xFFFFFFFF), stop - start)
        ray = mi.Ray3f(mi.Point3f(mi.Float(o[:, 0]), mi.Float(o[:, 1]), mi.Float(o[:, 2])),
                       mi.Vector3f(mi.Float(dd[:, 0]), mi.Float(dd[:, 1]), mi.Float(dd[:, 2])))
        radiance, _, _ = integrator.sample(mi_scene, sampler, ray)
        if first_emission_weight is not None:
            si = mi_scene.ray_intersect(ray)
            emitter = si.emitter(mi_scene)
            drop = mi.Float(np.ascontiguousarray(1.0 - first_emission_weight[start:stop], np.float32))
            radiance = radiance - drop * emitter.eval(si, si.is_valid())  # a null emitter evaluates to zero
        out[start:stop] = np.asarray(dr.ravel(radiance)).reshape(-1, 3)
    return out
