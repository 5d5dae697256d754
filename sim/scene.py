"""Scene description: triangle meshes whose surfaces are either lit or carry a fixed radiance.

A scene is a list of :class:`SceneObject`; each has a shape (quad, box, cylinder, sphere, or a mesh
file), a material, sensor flags (``emissive``, ``shiny``, ``dark``) that drive the ToF confidence
model, and a timeline (visible interval, scale steps such as a lamp dimming). Two materials:

- **lit** (``albedo:`` and optionally ``emission:``): a two-sided Lambertian surface with diffuse
  reflectance ρ ∈ [0, 1) and emitted radiance Le ≥ 0, lit by global illumination from every emitter in
  the scene. Its outgoing radiance comes from a bake (:mod:`sim.bake`, Mitsuba 3's path tracer) stored
  per surface and read by the ray caster; the timeline's ``scale`` steps multiply the emission.
- **fixed radiance** (``radiance:``): the outgoing radiance *is* what a camera sees, lit by nothing.
  In a scene with lit surfaces such a surface also lights them (it is an emitter of its radiance that
  reflects nothing).

Albedo, emission and radiance are constant RGB or a procedural texture over a quad's (s, t) ∈ [0, 1]².
A ``shape: mesh`` object reads a glTF / GLB, OBJ or PLY file (:mod:`sim.mesh_import`): its base
colour becomes the albedo and its emissive colour the emission, one constant per part, so a file
with several colours becomes several objects, ``NAME.0``, ``NAME.1``, ... (docs/design/scenes.md).

Scenes are written in YAML under ``sim/data/scenes/`` (package data, installed with the package);
:func:`load_scene` reads one by name or path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
import yaml

from rgbd_envmap.errors import InvalidInputError
from sim.mesh_import import mesh_parts

__all__ = ["Texture", "SceneObject", "Scene", "load_scene", "SCENES_DIR", "FLAG_BITS"]

#: The packaged scenes (``sim/data/scenes/*.yaml``, shipped as package data; see pyproject.toml).
SCENES_DIR = Path(__file__).resolve().parent / "data" / "scenes"

#: Bit of each sensor flag in the per-hit flag mask.
FLAG_BITS = {"emissive": 1, "shiny": 2, "dark": 4}


@dataclass(frozen=True)
class Texture:
    """Procedural radiance over a quad's (s, t) ∈ [0, 1]² (s along ``u``, t along ``v``).

    kinds: ``checker`` (``colours`` = 2 RGB, ``cells`` = (ns, nt)), ``gradient`` (``colours`` = RGB at
    t = 0 and t = 1), ``patches`` (``cells`` = (ns, nt) grid of ``colours`` in row-major order of t).
    """

    kind: str
    colours: np.ndarray
    cells: tuple[int, int] = (1, 1)

    def __post_init__(self) -> None:
        colours = np.asarray(self.colours, dtype=np.float32).reshape(-1, 3)
        object.__setattr__(self, "colours", colours)
        need = {"checker": 2, "gradient": 2, "patches": self.cells[0] * self.cells[1]}
        if self.kind not in need:
            raise InvalidInputError(f"texture kind: unknown {self.kind!r}; valid kinds are {sorted(need)}")
        if len(colours) != need[self.kind]:
            raise InvalidInputError(f"texture {self.kind}: expected {need[self.kind]} colours, got {len(colours)}")
        if not np.isfinite(colours).all() or (colours < 0).any():
            raise InvalidInputError("texture colours must be finite and ≥ 0")

    def sample(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) float32 at (N,) texture coordinates (clipped to [0, 1])."""
        s = np.clip(s, 0.0, 1.0)
        t = np.clip(t, 0.0, 1.0)
        if self.kind == "gradient":
            return (self.colours[0] * (1.0 - t)[:, None] + self.colours[1] * t[:, None]).astype(np.float32)
        i = np.minimum((s * self.cells[0]).astype(np.int64), self.cells[0] - 1)
        j = np.minimum((t * self.cells[1]).astype(np.int64), self.cells[1] - 1)
        if self.kind == "checker":
            return self.colours[(i + j) % 2]
        return self.colours[j * self.cells[0] + i]


def _rgb(value, what: str, *, below_one: bool = False) -> np.ndarray:
    """(3,) float32 from a scene value, finite and ≥ 0 (and < 1 with ``below_one``), else a typed error."""
    try:
        rgb = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what}: expected [r, g, b], got {value!r}") from None
    if not np.isfinite(rgb).all() or (rgb < 0).any() or (below_one and (rgb >= 1).any()):
        rng = "in [0, 1)" if below_one else "finite and ≥ 0"
        raise InvalidInputError(f"{what}: each channel must be {rng}, got {rgb.tolist()}")
    return rgb.astype(np.float32)


@dataclass(frozen=True)
class SceneObject:
    """One mesh with its material.

    Attributes:
        name: unique within the scene.
        vertices: (V, 3) float64 world coordinates, metres. faces: (F, 3) int.
        radiance: (3,) linear RGB fixed outgoing radiance, or None (``texture`` or a lit material).
        texture: procedural fixed radiance; only for quads (``quad_frame`` set).
        albedo: (3,) diffuse reflectance in [0, 1) of a lit surface, or None (``albedo_texture``, or a
            fixed-radiance surface).
        albedo_texture: procedural albedo (quads only; colours in [0, 1)).
        emission: (3,) emitted radiance of a lit surface (zero when None and no ``emission_texture``).
        emission_texture: procedural emission (quads only).
        quad_frame: (corner, u, v) of a quad, for texture lookup.
        flags: subset of ``emissive``, ``shiny``, ``dark``.
        visible_from_s, visible_until_s: the object exists for t in [from, until).
        scale_steps: ((t_s, scale), ...) multiplier of the radiance or emission from each time on (1
            before the first).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    radiance: np.ndarray | None = None
    texture: Texture | None = None
    quad_frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    flags: frozenset[str] = frozenset()
    visible_from_s: float = -np.inf
    visible_until_s: float = np.inf
    scale_steps: tuple[tuple[float, float], ...] = ()
    albedo: np.ndarray | None = None
    albedo_texture: Texture | None = None
    emission: np.ndarray | None = None
    emission_texture: Texture | None = None

    def __post_init__(self) -> None:
        unknown = set(self.flags) - set(FLAG_BITS)
        if unknown:
            raise InvalidInputError(f"{self.name}: unknown flags {sorted(unknown)}; valid are {sorted(FLAG_BITS)}")
        fixed = self.radiance is not None or self.texture is not None
        lit = self.albedo is not None or self.albedo_texture is not None
        if fixed and lit:
            raise InvalidInputError(f"{self.name}: give either radiance or albedo, not both")
        if not fixed and not lit:
            raise InvalidInputError(f"{self.name}: give radiance (fixed) or albedo (lit)")
        if self.radiance is not None and self.texture is not None:
            raise InvalidInputError(f"{self.name}: give exactly one of radiance or texture")
        if self.albedo is not None and self.albedo_texture is not None:
            raise InvalidInputError(f"{self.name}: give exactly one of albedo or albedo_texture")
        if self.emission is not None and self.emission_texture is not None:
            raise InvalidInputError(f"{self.name}: give exactly one of emission or emission_texture")
        if fixed and (self.emission is not None or self.emission_texture is not None):
            raise InvalidInputError(f"{self.name}: emission needs a lit surface (albedo); radiance is already fixed")
        textures = [t for t in (self.texture, self.albedo_texture, self.emission_texture) if t is not None]
        if textures and self.quad_frame is None:
            raise InvalidInputError(f"{self.name}: textures are supported on quads only")
        if self.radiance is not None:
            object.__setattr__(self, "radiance", _rgb(self.radiance, f"{self.name}: radiance"))
        if self.albedo is not None:
            object.__setattr__(self, "albedo", _rgb(self.albedo, f"{self.name}: albedo", below_one=True))
        if self.albedo_texture is not None and (self.albedo_texture.colours >= 1).any():
            raise InvalidInputError(f"{self.name}: albedo: texture colours must be in [0, 1)")
        if self.emission is not None:
            object.__setattr__(self, "emission", _rgb(self.emission, f"{self.name}: emission"))

    @property
    def lit(self) -> bool:
        """A lit (albedo) surface, as opposed to a fixed-radiance one."""
        return self.albedo is not None or self.albedo_texture is not None

    @property
    def emits(self) -> bool:
        """Emits light into the scene: a fixed-radiance surface, or a lit one with non-zero emission."""
        if not self.lit:
            return True
        if self.emission_texture is not None:
            return bool((self.emission_texture.colours > 0).any())
        return self.emission is not None and bool((self.emission > 0).any())

    def visible_at(self, t_s: float) -> bool:
        return self.visible_from_s <= t_s < self.visible_until_s

    def scale_at(self, t_s: float) -> float:
        scale = 1.0
        for t_step, s in self.scale_steps:
            if t_s >= t_step:
                scale = s
        return scale

    @property
    def flag_bits(self) -> int:
        return sum(FLAG_BITS[f] for f in self.flags)


@dataclass(frozen=True)
class Scene:
    """A named set of objects and the virtual object's position (the default EM origin)."""

    name: str
    objects: tuple[SceneObject, ...]
    virtual_object_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    default_trajectory: str = "orbit"

    def __post_init__(self) -> None:
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise InvalidInputError(f"scene {self.name}: object names must be unique, got {names}")
        object.__setattr__(self, "virtual_object_position", np.asarray(self.virtual_object_position, dtype=np.float64))

    def object(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    @property
    def is_lit(self) -> bool:
        """Any lit surface: the scene needs a bake (:func:`sim.bake.bake_scene`)."""
        return any(o.lit for o in self.objects)

    def change_times(self) -> list[float]:
        """Times at which the set of visible objects changes."""
        times = {o.visible_from_s for o in self.objects} | {o.visible_until_s for o in self.objects}
        return sorted(t for t in times if np.isfinite(t))


def _quad(corner, u, v):
    corner, u, v = (np.asarray(x, dtype=np.float64) for x in (corner, u, v))
    verts = np.stack([corner, corner + u, corner + u + v, corner + v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]]), (corner, u, v)


def _rot_z(yaw_deg: float) -> np.ndarray:
    m = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _build_shape(spec: dict, name: str):
    shape = spec.get("shape")
    if shape == "quad":
        return _quad(spec["corner"], spec["u"], spec["v"])
    if shape == "box":
        m = _rot_z(spec.get("yaw_deg", 0.0))
        m[:3, 3] = spec["centre"]
        mesh = trimesh.creation.box(extents=spec["size"], transform=m)
    elif shape == "cylinder":
        m = np.eye(4)
        m[:3, 3] = spec["centre"]
        mesh = trimesh.creation.cylinder(radius=spec["radius"], height=spec["height"], sections=24, transform=m)
    elif shape == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=spec["radius"])
        mesh.apply_translation(spec["centre"])
    else:
        raise InvalidInputError(f"object {name}: unknown shape {shape!r}; valid shapes are box, cylinder, mesh, quad, sphere")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64), None


def _material_value(spec: dict, key: str, name: str) -> tuple[np.ndarray | None, Texture | None]:
    """A constant RGB or a procedural texture from ``spec[key]`` (both None when absent)."""
    value = spec.get(key)
    if value is None:
        return None, None
    if isinstance(value, dict):
        try:
            return None, Texture(value["texture"], np.asarray(value["colours"], dtype=np.float32),
                                 tuple(value.get("cells", (1, 1))))
        except KeyError as e:
            raise InvalidInputError(f"object {name}: {key}: a texture needs {e.args[0]!r}") from None
        except InvalidInputError as e:
            raise InvalidInputError(f"object {name}: {key}: {e}") from None
    return _rgb(value, f"object {name}: {key}", below_one=key == "albedo"), None


def _mesh_objects(spec: dict, name: str, base_dir: Path | None, common: dict) -> list[SceneObject]:
    """The objects of a ``shape: mesh`` spec: one per part of constant material (sim.mesh_import)."""
    rad, texture = _material_value(spec, "radiance", name)
    albedo, albedo_texture = _material_value(spec, "albedo", name)
    emission, emission_texture = _material_value(spec, "emission", name)
    if any(t is not None for t in (texture, albedo_texture, emission_texture)):
        raise InvalidInputError(f"object {name}: textures are supported on quads only (a mesh takes its file's colours)")
    if rad is not None:  # fixed radiance: the file's colours do not matter
        if emission is not None:
            raise InvalidInputError(f"object {name}: emission needs a lit surface (albedo); radiance is already fixed")
        parts = mesh_parts(spec, name, base_dir, albedo=np.zeros(3), emission=np.zeros(3))
    else:
        parts = mesh_parts(spec, name, base_dir, albedo=albedo, emission=emission)
    objects = []
    for k, part in enumerate(parts):
        if rad is None and part.albedo is None:
            raise InvalidInputError(f"object {name}: albedo: the file {spec['file']} has no base colour; "
                                    "give albedo: [r, g, b] (or radiance:)")
        objects.append(SceneObject(
            name=name if len(parts) == 1 else f"{name}.{k}", vertices=part.vertices, faces=part.faces,
            radiance=rad, albedo=None if rad is not None else part.albedo,
            emission=None if rad is not None or not (part.emission > 0).any() else part.emission, **common))
    return objects


def _objects_from_spec(spec: dict, base_dir: Path | None = None) -> list[SceneObject]:
    name = spec.get("name")
    if not name:
        raise InvalidInputError(f"scene object without a name: {spec}")
    if "radiance" in spec and "albedo" in spec:
        raise InvalidInputError(f"object {name}: give either radiance or albedo, not both")
    vis = spec.get("visible", {}) or {}
    steps = tuple((float(s["t"]), float(s["scale"])) for s in spec.get("timeline", []) or [])
    common = dict(flags=frozenset(spec.get("flags", []) or []),
                  visible_from_s=float(vis.get("from", -np.inf)), visible_until_s=float(vis.get("until", np.inf)),
                  scale_steps=tuple(sorted(steps)))
    if spec.get("shape") == "mesh":
        return _mesh_objects(spec, name, base_dir, common)
    verts, faces, frame = _build_shape(spec, name)
    rad, texture = _material_value(spec, "radiance", name)
    albedo, albedo_texture = _material_value(spec, "albedo", name)
    emission, emission_texture = _material_value(spec, "emission", name)
    return [SceneObject(
        name=name, vertices=verts, faces=faces, radiance=rad, texture=texture, quad_frame=frame,
        albedo=albedo, albedo_texture=albedo_texture, emission=emission, emission_texture=emission_texture,
        **common,
    )]


def scene_from_dict(d: dict, base_dir: str | Path | None = None) -> Scene:
    """Build a :class:`Scene` from its YAML mapping; mesh files' relative paths are resolved against
    ``base_dir`` (the YAML file's folder; the working directory when None)."""
    base = None if base_dir is None else Path(base_dir)
    return Scene(
        name=d.get("name", "unnamed"),
        objects=tuple(o for spec in d.get("objects", []) or [] for o in _objects_from_spec(spec, base)),
        virtual_object_position=np.asarray(d.get("virtual_object_position", [0.0, 0.0, 0.0]), dtype=np.float64),
        default_trajectory=d.get("default_trajectory", "orbit"),
    )


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a scene by name (the packaged ``sim/data/scenes/NAME.yaml``) or by path (anything with a suffix)."""
    path = Path(name_or_path)
    if not path.suffix:
        path = SCENES_DIR / f"{name_or_path}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in SCENES_DIR.glob("*.yaml"))
        raise InvalidInputError(f"scene {name_or_path!r}: no file {path}; known scenes are {known}")
    with open(path) as f:
        return scene_from_dict(yaml.safe_load(f) or {}, base_dir=path.resolve().parent)
