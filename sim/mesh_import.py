"""Scene objects from mesh files (glTF / GLB, OBJ, PLY), read with trimesh.

A scene object with ``shape: mesh`` names a file (``file:``, relative to the scene's YAML file) and an
optional placement; :func:`mesh_parts` reads it and returns its triangles in world coordinates, cut
into parts of one constant albedo and emission each, which :mod:`sim.scene` turns into ordinary
:class:`sim.scene.SceneObject` s. Everything downstream (the ray caster, the bake, the Mitsuba scene)
sees only triangles with a constant material, as for a box or a quad.

**Placement.** ``x_world = translation + R · (scale · A(x_file))``, where ``A`` takes the file's up
axis to +z (``up_axis``: glTF is y-up by its specification, so ``y`` is the default for .glb / .gltf;
``z`` for OBJ and PLY, which have no convention), ``scale`` is a uniform factor > 0, ``R`` is a
rotation about z by ``yaw_deg`` degrees or a ``rotation`` given as a 3×3 rotation matrix or a 4×4
rigid transform (whose translation is added to ``translation``), and ``translation`` is metres.

**Colour.** Linear RGB throughout; what each format stores:

=======================  ==================================================  ====================
source                   meaning                                              decoded as
=======================  ==================================================  ====================
glTF baseColorFactor     base colour (the JSON's exact floats)                linear
glTF baseColorTexture    base colour, multiplied by the factor                sRGB → linear
glTF COLOR_0             vertex colour, multiplied by the above               linear (the spec's)
glTF emissiveFactor      emitted radiance, × KHR_materials_emissive_strength  linear
glTF emissiveTexture     emitted radiance, multiplied by the factor           sRGB → linear
OBJ (MTL) Kd             diffuse colour (trimesh keeps 8 bits)                linear
OBJ (MTL) map_Kd         diffuse texture, multiplied by Kd                    sRGB → linear
OBJ / PLY vertex colour  8-bit vertex (or PLY face) colours                   sRGB → linear
=======================  ==================================================  ====================

sRGB decoding is IEC 61966-2-1's: c / 12.92 for c ≤ 0.04045, else ((c + 0.055) / 1.055)^2.4. Alpha is
ignored (every surface is opaque).

**Per-face colour.** The world's materials are constant per object (procedural textures exist only
on quads), so a texture or vertex colours are reduced to one colour per triangle: the mean, in linear
RGB, of the colour at four points of the triangle (its centroid and the midpoints between it and each
corner; textures read nearest-texel, wrapping). Triangles of equal colour form one part; when there are
more than ``max_colours`` distinct colours (default 16), they are clustered (k-means in linear RGB of
albedo and emission, fixed seed) and each cluster takes its members' area-weighted mean colour. A
texture finer than the triangles is therefore blurred to the triangle size; a finely tessellated mesh
keeps more of it. This keeps the bake, the ray caster and the Mitsuba scene unchanged.

**Checks** (each a typed error naming the object and the key): the file exists and has a supported
suffix, it parses, it has triangles of non-zero area, its vertices are finite, the transform is a
rotation and a positive scale, every albedo is in [0, 1) (``albedo_scale`` < 1 scales a file's base
colour down; ``albedo:`` in the scene replaces it) and every emission is finite and ≥ 0.

References:
    Khronos, *glTF 2.0 specification* (2021), §3.9 materials and §3.7.2.1 (COLOR_0 is linear); the
    ``KHR_materials_emissive_strength`` extension. IEC 61966-2-1:1999, the sRGB transfer function.
    Lloyd, *Least squares quantization in PCM* (1982), k-means.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError

__all__ = ["MESH_SUFFIXES", "MeshPart", "srgb_to_linear", "placement_from_spec", "read_mesh", "mesh_parts"]

#: File suffixes :func:`read_mesh` reads (lower case).
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")

#: Default bound on the parts (distinct colours) one mesh is cut into.
DEFAULT_MAX_COLOURS = 16

#: Tolerance of the rotation check (RᵀR = I, det R = 1).
_ROTATION_TOL = 1e-6

#: Barycentric weights of the four points at which a triangle's colour is averaged.
_FACE_POINTS = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """Linear values of sRGB-encoded ``c`` in [0, 1] (any shape; IEC 61966-2-1), float64."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class MeshPart:
    """Triangles of one constant material, in world coordinates.

    Attributes:
        vertices: (V, 3) float64 metres. faces: (F, 3) int64.
        albedo: (3,) float64 linear base colour (None when the file has none).
        emission: (3,) float64 linear emitted radiance (zeros when the file has none).
    """

    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray | None
    emission: np.ndarray


@dataclass(frozen=True)
class _Mesh:
    """A whole file: triangles (file coordinates) with one colour per face."""

    vertices: np.ndarray  # (V, 3)
    faces: np.ndarray  # (F, 3)
    albedo: np.ndarray | None  # (F, 3) linear, or None: no base colour in the file
    emission: np.ndarray  # (F, 3) linear


def _error(name: str, key: str, message: str) -> InvalidInputError:
    return InvalidInputError(f"object {name}: {key}: {message}")


# --- placement ---------------------------------------------------------------------------------------

def _rotation(value, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(3×3 rotation, translation) from a 3×3 rotation or a 4×4 rigid transform."""
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _error(name, "rotation", f"expected a 3×3 or 4×4 matrix, got {value!r}") from None
    if m.shape not in ((3, 3), (4, 4)) or not np.isfinite(m).all():
        raise _error(name, "rotation", f"expected a finite 3×3 or 4×4 matrix, got {value!r}")
    t = np.zeros(3)
    if m.shape == (4, 4):
        if not np.allclose(m[3], [0, 0, 0, 1], atol=_ROTATION_TOL):
            raise _error(name, "rotation", f"a 4×4 transform's last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        m, t = m[:3, :3], m[:3, 3]
    if not np.allclose(m.T @ m, np.eye(3), atol=_ROTATION_TOL) or np.linalg.det(m) <= 0:
        raise _error(name, "rotation", f"expected a rotation (orthonormal, det +1; use scale: for size), got {m.tolist()}")
    return m, t


def placement_from_spec(spec: dict, name: str, suffix: str) -> np.ndarray:
    """The 4×4 ``T_world_from_file`` of a mesh object's spec (see the module docstring)."""
    up = spec.get("up_axis", "y" if suffix in (".glb", ".gltf") else "z")
    if up not in ("y", "z"):
        raise _error(name, "up_axis", f"expected 'y' or 'z', got {up!r}")
    a = np.eye(3) if up == "z" else np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # y-up → z-up
    scale = check_number(spec.get("scale", 1.0), f"object {name}: scale", low=0.0, low_open=True)
    if "yaw_deg" in spec and "rotation" in spec:
        raise _error(name, "rotation", "give yaw_deg or rotation, not both")
    r, t = np.eye(3), np.zeros(3)
    if "rotation" in spec:
        r, t = _rotation(spec["rotation"], name)
    elif "yaw_deg" in spec:
        yaw = np.radians(check_number(spec["yaw_deg"], f"object {name}: yaw_deg"))
        c, s = np.cos(yaw), np.sin(yaw)
        r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    try:
        translation = np.asarray(spec.get("translation", [0.0, 0.0, 0.0]), dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise _error(name, "translation", f"expected [x, y, z], got {spec.get('translation')!r}") from None
    if not np.isfinite(translation).all():
        raise _error(name, "translation", f"must be finite, got {translation.tolist()}")
    m = np.eye(4)
    m[:3, :3] = scale * r @ a
    m[:3, 3] = translation + t
    return m


# --- reading -----------------------------------------------------------------------------------------

def _gltf_json(path: Path) -> dict:
    """The JSON of a .gltf file, or of a .glb's first chunk."""
    if path.suffix.lower() == ".gltf":
        return json.loads(path.read_text())
    data = path.read_bytes()
    if len(data) < 20 or data[:4] != b"glTF":
        raise ValueError("not a GLB file (bad magic)")
    length, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON":
        raise ValueError("GLB's first chunk is not JSON")
    return json.loads(data[20:20 + length])


def _gltf_materials(header: dict) -> list[dict]:
    """Each material of a glTF's JSON: name, exact base colour factor, emissive factor and strength."""
    out = []
    for mat in header.get("materials", []) or []:
        pbr = mat.get("pbrMetallicRoughness", {}) or {}
        ext = (mat.get("extensions", {}) or {}).get("KHR_materials_emissive_strength", {}) or {}
        out.append({"name": mat.get("name"),
                    "base": np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), np.float64).reshape(4)[:3],
                    "emissive": np.asarray(mat.get("emissiveFactor", [0, 0, 0]), np.float64).reshape(3),
                    "strength": float(ext.get("emissiveStrength", 1.0))})
    return out


def _match_gltf_material(material, table: list[dict]) -> tuple[np.ndarray, np.ndarray] | None:
    """Exact (base colour, emission) of a trimesh PBRMaterial from the glTF's JSON. trimesh keeps the
    base colour factor as 8 bits and drops the emissive strength, so the JSON entries with the same
    name, 8-bit base colour and emissive factor are looked up; None if there is none or they differ."""
    base8 = np.asarray(material.baseColorFactor if material.baseColorFactor is not None else [255] * 4)[:3]
    emissive = np.asarray(material.emissiveFactor if material.emissiveFactor is not None else [0, 0, 0], np.float64)
    found = []
    for m in table:
        if m["name"] is not None and material.name is not None and m["name"] != material.name:
            continue
        if np.array_equal(trimesh.visual.color.to_rgba(np.append(m["base"], 1.0))[:3], base8) and \
                np.allclose(m["emissive"], emissive, rtol=1e-6, atol=1e-12):
            found.append((m["base"], m["emissive"] * m["strength"]))
    if not found or any(not (np.array_equal(b, found[0][0]) and np.array_equal(e, found[0][1])) for b, e in found):
        return None
    return found[0]


def _image_rgb(image) -> np.ndarray | None:
    """(H, W, 3) float64 sRGB-encoded values in [0, 1] of a PIL image (None for no image)."""
    if image is None:
        return None
    arr = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    return arr if arr.ndim == 3 and arr.size else None


def _sample_faces(values_at, faces: np.ndarray) -> np.ndarray:
    """(F, 3) mean over :data:`_FACE_POINTS` of ``values_at(face, barycentrics (F, 3))``."""
    return np.mean([values_at(faces, np.broadcast_to(w, (len(faces), 3))) for w in _FACE_POINTS], axis=0)


def _texture_lookup(image: np.ndarray, uv: np.ndarray):
    """values_at for a texture read nearest-texel (wrapping), linearised: uv (V, 2), v up."""
    h, w = image.shape[:2]
    linear = srgb_to_linear(image)

    def at(faces, bary):
        p = np.einsum("fk,fkc->fc", bary, uv[faces])
        col = np.minimum((np.mod(p[:, 0], 1.0) * w).astype(np.int64), w - 1)
        row = np.minimum(((1.0 - np.mod(p[:, 1], 1.0)) * h).astype(np.int64), h - 1)
        return linear[row, col]

    return at


def _vertex_lookup(colours: np.ndarray):
    def at(faces, bary):
        return np.einsum("fk,fkc->fc", bary, colours[faces])

    return at


def _geometry_colours(geom, suffix: str, gltf_table: list[dict] | None, name: str) -> tuple[np.ndarray | None, np.ndarray]:
    """(F, 3) linear albedo (None: no colour) and (F, 3) linear emission of one trimesh geometry."""
    faces = np.asarray(geom.faces, dtype=np.int64)
    n = len(faces)
    emission = np.zeros((n, 3))
    vis = geom.visual
    gltf = suffix in (".glb", ".gltf")
    if isinstance(vis, trimesh.visual.ColorVisuals):
        if vis.kind is None:
            return None, emission
        decode = (lambda c: c) if gltf else srgb_to_linear  # glTF COLOR_0 is linear, 8-bit OBJ/PLY sRGB
        if vis.kind == "face":
            return decode(np.asarray(vis.face_colors, np.float64)[:, :3] / 255.0), emission
        vc = decode(np.asarray(vis.vertex_colors, np.float64)[:, :3] / 255.0)
        return _sample_faces(_vertex_lookup(vc), faces), emission
    material = getattr(vis, "material", None)
    if material is None:
        return None, emission
    uv = None if getattr(vis, "uv", None) is None else np.asarray(vis.uv, np.float64)
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        exact = _match_gltf_material(material, gltf_table or []) if gltf else None
        if exact is not None:
            base, emissive = exact
        else:
            base = np.asarray(material.baseColorFactor if material.baseColorFactor is not None else [255] * 4,
                              np.float64)[:3] / 255.0
            emissive = np.asarray(material.emissiveFactor if material.emissiveFactor is not None else [0, 0, 0], np.float64)
        base_image, emissive_image = _image_rgb(material.baseColorTexture), _image_rgb(material.emissiveTexture)
    else:  # SimpleMaterial (OBJ's MTL): Kd (8 bits, linear) and map_Kd
        diffuse = getattr(material, "diffuse", None)
        base = np.ones(3) if diffuse is None else np.asarray(diffuse, np.float64)[:3] / 255.0
        emissive, base_image, emissive_image = np.zeros(3), _image_rgb(getattr(material, "image", None)), None
    albedo = np.broadcast_to(base, (n, 3)).astype(np.float64)
    if base_image is not None:
        if uv is None or len(uv) != len(geom.vertices):
            raise _error(name, "file", "a base colour texture without texture coordinates")
        albedo = albedo * _sample_faces(_texture_lookup(base_image, uv), faces)
    vc = getattr(vis, "vertex_attributes", {}).get("color") if hasattr(vis, "vertex_attributes") else None
    if vc is not None and len(vc) == len(geom.vertices):
        c = np.asarray(vc, np.float64)[:, :3]
        c = c / 255.0 if c.max() > 1.0 or np.issubdtype(np.asarray(vc).dtype, np.integer) else c
        albedo = albedo * _sample_faces(_vertex_lookup(c if gltf else srgb_to_linear(c)), faces)
    emission = np.broadcast_to(emissive, (n, 3)).astype(np.float64)
    if emissive_image is not None and uv is not None and len(uv) == len(geom.vertices) and emissive.any():
        emission = emission * _sample_faces(_texture_lookup(emissive_image, uv), faces)
    return albedo, emission


def read_mesh(path: Path, name: str) -> _Mesh:
    """Every triangle of a mesh file (in the file's coordinates, glTF node transforms applied) with
    its linear albedo and emission; typed errors name ``object NAME: file``."""
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise _error(name, "file", f"unknown mesh format {path.suffix!r} ({path}); supported are {list(MESH_SUFFIXES)}")
    if not path.is_file():
        raise _error(name, "file", f"no such file {path}")
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
        geometries = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        table = _gltf_materials(_gltf_json(path)) if suffix in (".glb", ".gltf") else None
    except InvalidInputError:
        raise
    except Exception as e:  # trimesh raises many kinds on a corrupt file
        raise _error(name, "file", f"cannot read {path}: {type(e).__name__}: {e}") from None
    verts, faces, albedo, emission = [], [], [], []
    has_albedo = []
    offset = 0
    for g in geometries:
        v = np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        if not len(f):
            continue
        if not np.isfinite(v).all():
            bad = int((~np.isfinite(v).all(axis=1)).sum())
            raise _error(name, "file", f"{bad} of {len(v)} vertices are not finite in {path}")
        a, e = _geometry_colours(g, suffix, table, name)
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
        has_albedo.append(a is not None)
        albedo.append(a if a is not None else np.zeros((len(f), 3)))
        emission.append(e)
    if not faces:
        raise _error(name, "file", f"no triangles in {path}")
    v, f = np.concatenate(verts), np.concatenate(faces)
    a, e = np.concatenate(albedo), np.concatenate(emission)
    if any(has_albedo) and not all(has_albedo):
        raise _error(name, "albedo", f"some of {path}'s meshes have a base colour and some not; give albedo:")
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    keep = area > 0
    if not keep.any():
        raise _error(name, "file", f"no triangles of non-zero area in {path}")
    return _Mesh(v, f[keep], a[keep] if any(has_albedo) else None, e[keep])


# --- parts -------------------------------------------------------------------------------------------

def _group(colours: np.ndarray, area: np.ndarray, max_colours: int) -> tuple[np.ndarray, np.ndarray]:
    """(labels (F,), colours (K, C)): faces grouped by equal colour, or clustered to ``max_colours``."""
    unique, labels = np.unique(colours.astype(np.float32), axis=0, return_inverse=True)
    labels = labels.reshape(-1)
    if len(unique) <= max_colours:
        return labels, unique.astype(np.float64)
    from scipy.cluster.vq import kmeans2

    _, labels = kmeans2(colours, max_colours, minit="++", seed=np.random.default_rng(0))
    used = np.unique(labels)
    labels = np.searchsorted(used, labels)
    w = np.bincount(labels, weights=area)
    means = np.stack([np.bincount(labels, weights=area * colours[:, c]) / w for c in range(colours.shape[1])], axis=1)
    return labels, means


def mesh_parts(spec: dict, name: str, base_dir: Path | None, *, albedo: np.ndarray | None = None,
               emission: np.ndarray | None = None) -> list[MeshPart]:
    """The parts of a ``shape: mesh`` object (``spec`` its YAML mapping), in world coordinates.

    ``albedo`` / ``emission`` (3,) from the scene replace the file's; otherwise the file's base colour
    (times ``albedo_scale``) must lie in [0, 1) and its emission be finite and ≥ 0.
    """
    if not spec.get("file"):
        raise _error(name, "file", "a mesh object needs file: PATH (relative to the scene file)")
    path = Path(spec["file"])
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    mesh = read_mesh(path, name)
    transform = placement_from_spec(spec, name, path.suffix.lower())
    max_colours = check_number(spec.get("max_colours", DEFAULT_MAX_COLOURS), f"object {name}: max_colours",
                               low=1, high=256, integer=True)
    albedo_scale = check_number(spec.get("albedo_scale", 1.0), f"object {name}: albedo_scale", low=0.0)
    n = len(mesh.faces)
    if albedo is not None:
        face_albedo = np.broadcast_to(np.asarray(albedo, np.float64), (n, 3))
    elif mesh.albedo is not None:
        face_albedo = mesh.albedo * albedo_scale
        if not np.isfinite(face_albedo).all() or (face_albedo < 0).any() or (face_albedo >= 1).any():
            worst = face_albedo[np.argmax(np.where(np.isfinite(face_albedo), face_albedo, np.inf).max(axis=1))]
            raise _error(name, "albedo", f"the base colour of {path.name} must be in [0, 1) in every channel "
                         f"(linear, × albedo_scale {albedo_scale:g}), got {worst.tolist()}; "
                         "give albedo_scale: < 1 or albedo: [r, g, b]")
    else:
        face_albedo = None
    face_emission = np.broadcast_to(np.asarray(emission, np.float64), (n, 3)) if emission is not None else mesh.emission
    if not np.isfinite(face_emission).all() or (face_emission < 0).any():
        raise _error(name, "emission", f"the emission of {path.name} must be finite and ≥ 0")
    v = mesh.vertices @ transform[:3, :3].T + transform[:3, 3]
    tri = v[mesh.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    colours = np.concatenate([face_albedo if face_albedo is not None else np.zeros((n, 3)), face_emission], axis=1)
    labels, means = _group(colours, area, max_colours)
    parts = []
    for k in range(len(means)):
        # vertices at equal positions merged (files split them at texture seams), so that a closed
        # part is watertight for the bake's test of which surfaces are enclosed
        corners = v[mesh.faces[labels == k]].reshape(-1, 3)
        unique, first, inverse = np.unique(corners, axis=0, return_index=True, return_inverse=True)
        order = np.argsort(first)  # vertices in the order the faces first use them
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        parts.append(MeshPart(unique[order], rank[inverse.reshape(-1)].reshape(-1, 3),
                              None if face_albedo is None else np.minimum(means[k, :3], np.nextafter(1.0, 0.0)),
                              means[k, 3:]))
    return parts
