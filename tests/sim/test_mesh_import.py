"""Mesh import (sim.mesh_import): files written here with trimesh (GLB, OBJ, PLY) with known colours,
loaded through a scene, against values computed here: the triangles and their placement, the albedo
(sRGB decoded with the IEC 61966-2-1 formula written out below) and the emission; bad files and specs
fail with typed errors naming the object and the key; and a bake of imported meshes against the same
scene built from primitives."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial

from rgbd_envmap.errors import InvalidInputError
from sim.scene import load_scene, scene_from_dict


def _srgb(c):
    """sRGB decoding, written out independently of sim.mesh_import."""
    c = np.asarray(c, dtype=np.float64)
    out = np.empty_like(c)
    low = c <= 0.04045
    out[low] = c[low] / 12.92
    out[~low] = ((c[~low] + 0.055) / 1.055) ** 2.4
    return out


_QUAD_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
_QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])


def _scene(tmp_path, **spec):
    return scene_from_dict({"objects": [{"name": "m", "shape": "mesh", **spec}]}, base_dir=tmp_path)


def _patch_glb(path, edit):
    """Rewrite a GLB's JSON chunk with ``edit(json_dict)`` (e.g. to add an extension trimesh drops)."""
    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    header = json.loads(data[20:20 + length])
    edit(header)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + length:]
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + len(rest))
                     + struct.pack("<I4s", len(text), b"JSON") + text + rest)


def _pbr_quad(path, base, emissive=None, *, vertices=_QUAD_V, faces=_QUAD_F, strength=None):
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(baseColorFactor=base, emissiveFactor=emissive))
    mesh.export(path)
    if strength is not None:
        def edit(h):
            h.setdefault("extensionsUsed", []).append("KHR_materials_emissive_strength")
            h["materials"][0]["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
        _patch_glb(path, edit)
    return path


# --- geometry and placement ---------------------------------------------------------------------------

def test_glb_factors_are_linear_and_emissive_strength_multiplies(tmp_path):
    base = np.array([51, 102, 153, 255]) / 255.0  # 8-bit exact: trimesh keeps the factor as 8 bits
    _pbr_quad(tmp_path / "q.glb", base, [0.9, 0.8, 0.7], strength=5.0)
    (o,) = _scene(tmp_path, file="q.glb", up_axis="z").objects
    np.testing.assert_allclose(o.albedo, base[:3], rtol=1e-6)  # linear: no decoding
    np.testing.assert_allclose(o.emission, [4.5, 4.0, 3.5], rtol=1e-6)
    np.testing.assert_array_equal(o.faces, _QUAD_F)
    np.testing.assert_allclose(o.vertices, _QUAD_V)
    assert o.lit and o.emits and o.quad_frame is None


def test_gltf_is_y_up_and_the_placement_composes_scale_rotation_translation(tmp_path):
    _pbr_quad(tmp_path / "q.glb", [0.2, 0.2, 0.2, 1.0])
    yaw = 30.0
    scene = _scene(tmp_path, file="q.glb", scale=2.0, yaw_deg=yaw, translation=[1.0, -2.0, 0.5])
    (o,) = scene.objects
    # y-up → z-up: (x, y, z) ↦ (x, −z, y); then ×2, then the yaw about z, then the translation
    up = np.stack([_QUAD_V[:, 0], -_QUAD_V[:, 2], _QUAD_V[:, 1]], axis=1) * 2.0
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    expected = up @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + [1.0, -2.0, 0.5]
    np.testing.assert_allclose(o.vertices, expected, atol=1e-12)
    # a 4×4 rigid transform: rotation 90° about x and its translation, added to translation:
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    m[:3, 3] = [0.0, 0.0, 1.0]
    (o2,) = _scene(tmp_path, file="q.glb", up_axis="z", rotation=m.tolist(), translation=[0.5, 0, 0]).objects
    np.testing.assert_allclose(o2.vertices, _QUAD_V @ m[:3, :3].T + [0.5, 0.0, 1.0], atol=1e-12)


def test_relative_paths_are_from_the_scene_file(tmp_path):
    (tmp_path / "meshes").mkdir()
    _pbr_quad(tmp_path / "meshes" / "q.glb", [0.2, 0.4, 0.6, 1.0])
    (tmp_path / "s.yaml").write_text(
        "name: s\nobjects:\n  - {name: m, shape: mesh, file: meshes/q.glb, up_axis: z, flags: [shiny],"
        " timeline: [{t: 2.0, scale: 0.5}], visible: {until: 3.0}}\n")
    (o,) = load_scene(tmp_path / "s.yaml").objects
    assert o.flags == {"shiny"} and o.scale_steps == ((2.0, 0.5),) and o.visible_until_s == 3.0
    np.testing.assert_allclose(o.albedo, np.round(np.array([0.2, 0.4, 0.6]) * 255) / 255, rtol=1e-6)


# --- colours --------------------------------------------------------------------------------------------

_VC = np.array([[200, 30, 10, 255], [10, 180, 40, 255], [5, 20, 230, 255], [128, 128, 128, 255]], np.uint8)


@pytest.mark.parametrize("suffix, srgb", [(".ply", True), (".obj", True), (".glb", False)])
def test_vertex_colours_become_the_mean_per_face(tmp_path, suffix, srgb):
    trimesh.Trimesh(_QUAD_V, _QUAD_F, vertex_colors=_VC, process=False).export(tmp_path / f"v{suffix}")
    scene = _scene(tmp_path, file=f"v{suffix}", up_axis="z")
    assert [o.name for o in scene.objects] == ["m.0", "m.1"] or [o.name for o in scene.objects] == ["m.1", "m.0"]
    lin = _srgb(_VC[:, :3] / 255.0) if srgb else _VC[:, :3] / 255.0  # glTF's COLOR_0 is linear
    expected = {tuple(np.round(lin[f].mean(axis=0), 5)) for f in _QUAD_F}
    assert {tuple(np.round(o.albedo.astype(np.float64), 5)) for o in scene.objects} == expected
    assert all(o.emission is None for o in scene.objects)
    assert sum(len(o.faces) for o in scene.objects) == 2


def test_ply_face_colours_are_srgb(tmp_path):
    fc = np.array([[250, 128, 3, 255], [250, 128, 3, 255]], np.uint8)
    trimesh.Trimesh(_QUAD_V, _QUAD_F, face_colors=fc, process=False).export(tmp_path / "f.ply")
    (o,) = _scene(tmp_path, file="f.ply").objects
    np.testing.assert_allclose(o.albedo, _srgb(fc[0, :3] / 255.0), rtol=1e-6)


def test_base_colour_texture_is_srgb_times_the_factor(tmp_path):
    pil = pytest.importorskip("PIL.Image")
    texels = np.array([[[250, 10, 10], [10, 200, 10]], [[10, 10, 180], [120, 120, 120]]], np.uint8)  # rows top→bottom
    # two small triangles, each inside one texel: (u, v) with v up, so row = 1 − v
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [2, 1, 0]], float)
    uv = np.array([[0.05, 0.55], [0.2, 0.55], [0.05, 0.7], [0.8, 0.05], [0.95, 0.05], [0.8, 0.2]])
    mesh = trimesh.Trimesh(verts, [[0, 1, 2], [3, 4, 5]], process=False)
    factor = np.array([204, 153, 255, 255]) / 255.0
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=PBRMaterial(
        baseColorTexture=pil.fromarray(texels), baseColorFactor=factor))
    mesh.export(tmp_path / "t.glb")
    scene = _scene(tmp_path, file="t.glb", up_axis="z", albedo_scale=0.9)
    by_x = {round(float(o.vertices[:, 0].min())): o for o in scene.objects}
    # triangle 0: u < ½, v > ½ → top-left texel; triangle 1: u > ½, v < ½ → bottom-right
    np.testing.assert_allclose(by_x[0].albedo, 0.9 * factor[:3] * _srgb(texels[0, 0] / 255.0), rtol=1e-5)
    np.testing.assert_allclose(by_x[2].albedo, 0.9 * factor[:3] * _srgb(texels[1, 1] / 255.0), rtol=1e-5)


def test_scene_albedo_and_emission_replace_the_files(tmp_path):
    trimesh.Trimesh(_QUAD_V, _QUAD_F, vertex_colors=_VC, process=False).export(tmp_path / "v.ply")
    (o,) = _scene(tmp_path, file="v.ply", albedo=[0.3, 0.2, 0.1], emission=[2.0, 2.0, 2.0]).objects
    np.testing.assert_allclose(o.albedo, [0.3, 0.2, 0.1], rtol=1e-6)
    np.testing.assert_allclose(o.emission, [2.0, 2.0, 2.0])
    (f,) = _scene(tmp_path, file="v.ply", radiance=[1.0, 0.5, 0.25]).objects
    assert not f.lit and f.emits
    np.testing.assert_allclose(f.radiance, [1.0, 0.5, 0.25])


def test_many_colours_are_clustered_keeping_the_area_weighted_mean(tmp_path):
    rng = np.random.default_rng(3)
    grid = trimesh.creation.box(extents=[1.0, 2.0, 0.5]).subdivide().subdivide()  # 192 faces, two areas
    fc = np.concatenate([rng.integers(20, 230, (len(grid.faces), 3)), np.full((len(grid.faces), 1), 255)], axis=1)
    trimesh.Trimesh(grid.vertices, grid.faces, face_colors=fc.astype(np.uint8), process=False).export(tmp_path / "g.ply")
    scene = _scene(tmp_path, file="g.ply", max_colours=5)
    assert 1 < len(scene.objects) <= 5
    area = trimesh.Trimesh(grid.vertices, grid.faces).area_faces
    expected = (area[:, None] * _srgb(fc[:, :3] / 255.0)).sum(axis=0)
    got = sum(trimesh.Trimesh(o.vertices, o.faces, process=False).area * o.albedo.astype(np.float64) for o in scene.objects)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert sum(len(o.faces) for o in scene.objects) == len(grid.faces)


# --- bad inputs -----------------------------------------------------------------------------------------

def _ascii_ply(path, vertices, faces, colours=True):
    head = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y",
            "property float z"]
    if colours:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    rows = [" ".join(str(x) for x in v) + (" 100 100 100" if colours else "") for v in vertices]
    rows += ["3 " + " ".join(str(i) for i in f) for f in faces]
    path.write_text("\n".join(head + rows) + "\n")


def _bad_file(tmp_path, kind):
    if kind == "missing":
        return "nowhere.glb"
    if kind == "format":
        trimesh.Trimesh(_QUAD_V, _QUAD_F).export(tmp_path / "q.stl")
        return "q.stl"
    if kind == "nan":
        _ascii_ply(tmp_path / "n.ply", [[0, 0, 0], [1, 0, 0], [float("nan"), 1, 0]], [[0, 1, 2]])
        return "n.ply"
    if kind == "empty":
        _ascii_ply(tmp_path / "e.ply", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [])
        return "e.ply"
    if kind == "degenerate":
        _ascii_ply(tmp_path / "d.ply", [[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]])
        return "d.ply"
    if kind == "white":
        _pbr_quad(tmp_path / "w.glb", [1.0, 1.0, 1.0, 1.0])
        return "w.glb"
    if kind == "uncoloured":
        _ascii_ply(tmp_path / "u.ply", _QUAD_V.tolist(), _QUAD_F.tolist(), colours=False)
        return "u.ply"
    if kind == "corrupt":
        (tmp_path / "c.glb").write_bytes(b"glTF not really")
        return "c.glb"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind, match", [
    ("missing", "object m: file: no such file"),
    ("format", "object m: file: unknown mesh format '.stl'"),
    ("nan", "object m: file: 1 of 3 vertices are not finite"),
    ("empty", "object m: file: no triangles"),
    ("degenerate", "object m: file: no triangles of non-zero area"),
    ("white", r"object m: albedo: .*\[0, 1\).*\[1.0, 1.0, 1.0\]"),
    ("uncoloured", "object m: albedo: the file u.ply has no base colour"),
    ("corrupt", "object m: file: cannot read"),
])
def test_bad_files_fail_naming_the_object_and_key(tmp_path, kind, match):
    with pytest.raises(InvalidInputError, match=match):
        _scene(tmp_path, file=_bad_file(tmp_path, kind))


@pytest.mark.parametrize("extra, match", [
    ({"rotation": [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}, "object m: rotation: expected a rotation"),
    ({"rotation": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}, "object m: rotation: expected a rotation"),  # a mirror
    ({"rotation": [[1, 0], [0, 1]]}, "object m: rotation: expected a finite 3×3 or 4×4"),
    ({"rotation": np.eye(3).tolist(), "yaw_deg": 3}, "object m: rotation: give yaw_deg or rotation"),
    ({"scale": 0.0}, "object m: scale"),
    ({"scale": float("nan")}, "object m: scale"),
    ({"translation": [0, float("inf"), 0]}, "object m: translation"),
    ({"up_axis": "x"}, "object m: up_axis"),
    ({"max_colours": 0}, "object m: max_colours"),
    ({"albedo": [0.5, 1.0, 0.5]}, "object m: albedo"),
    ({"albedo": {"texture": "checker", "colours": [[0.1] * 3, [0.2] * 3]}}, "object m: textures are supported on quads only"),
    ({"emission": [1.0, -1.0, 0.0]}, "object m: emission"),
    ({"file": None}, "object m: file: a mesh object needs file"),
])
def test_bad_specs_fail_naming_the_object_and_key(tmp_path, extra, match):
    _pbr_quad(tmp_path / "q.glb", [0.2, 0.2, 0.2, 1.0])
    with pytest.raises(InvalidInputError, match=match):
        _scene(tmp_path, **{"file": "q.glb", **extra})


# --- downstream: ray casting and the bake -----------------------------------------------------------------

def _primitive_and_imported(tmp_path):
    """A 2 m floor (albedo 0.6, 0.5, 0.4) under a 0.6 m emitting square 1.2 m up, in a dark 1.5 m high
    room: from primitives, and from files (the floor as a y-up GLB at half size with the other diagonal,
    the emitter as a GLB whose emission is its emissive factor × strength)."""
    floor_albedo = np.array([153, 128, 102]) / 255.0
    # dark walls and ceiling close the room (a side that sees nothing is not baked: sim/bake.py)
    dark = {"shape": "quad", "albedo": [0.05, 0.05, 0.05]}
    shell = [{"name": "ceiling", "corner": [-1, -1, 1.5], "u": [2, 0, 0], "v": [0, 2, 0], **dark},
             {"name": "south", "corner": [-1, -1, 0], "u": [2, 0, 0], "v": [0, 0, 1.5], **dark},
             {"name": "north", "corner": [-1, 1, 0], "u": [2, 0, 0], "v": [0, 0, 1.5], **dark},
             {"name": "west", "corner": [-1, -1, 0], "u": [0, 2, 0], "v": [0, 0, 1.5], **dark},
             {"name": "east", "corner": [1, -1, 0], "u": [0, 2, 0], "v": [0, 0, 1.5], **dark}]
    prim = scene_from_dict({"objects": [
        {"name": "floor", "shape": "quad", "corner": [-1, -1, 0], "u": [2, 0, 0], "v": [0, 2, 0], "albedo": floor_albedo.tolist()},
        {"name": "lamp", "shape": "quad", "corner": [-0.3, -0.3, 1.2], "u": [0.6, 0, 0], "v": [0, 0.6, 0],
         "albedo": [128 / 255] * 3, "emission": [4.0, 4.0, 4.0]},  # trimesh keeps base colours as 8 bits
        *shell,
    ]})
    # floor in glTF's y-up frame: z_world = y_file, y_world = −z_file
    fv = np.array([[-0.5, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, -0.5], [-0.5, 0, -0.5]])
    _pbr_quad(tmp_path / "floor.glb", np.append(floor_albedo, 1.0), vertices=fv, faces=np.array([[0, 1, 3], [1, 2, 3]]))
    # the lamp: emissiveFactor 0.8 × KHR_materials_emissive_strength 5 = 4, wound the other way
    lv = np.array([[0, 0, 0], [0.6, 0, 0], [0.6, 0.6, 0], [0, 0.6, 0]])
    _pbr_quad(tmp_path / "lamp.glb", [0.5, 0.5, 0.5, 1.0], [0.8, 0.8, 0.8], vertices=lv, faces=_QUAD_F[:, ::-1], strength=5.0)
    imported = scene_from_dict({"objects": [
        {"name": "floor", "shape": "mesh", "file": "floor.glb", "scale": 2.0},
        {"name": "lamp", "shape": "mesh", "file": "lamp.glb", "up_axis": "z", "translation": [-0.3, -0.3, 1.2]},
        *shell,
    ]}, base_dir=tmp_path)
    return prim, imported


def test_imported_meshes_ray_cast_like_primitives(tmp_path):
    from sim.raycast import SceneRaycaster

    prim, imported = _primitive_and_imported(tmp_path)
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(5000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    a = SceneRaycaster(prim, bake=False).cast(np.array([0.1, 0.2, 0.6]), dirs, 0.0)
    b = SceneRaycaster(imported, bake=False).cast(np.array([0.1, 0.2, 0.6]), dirs, 0.0)
    np.testing.assert_array_equal(a.hit, b.hit)
    np.testing.assert_array_equal(a.object_index, b.object_index)
    np.testing.assert_allclose(a.distance_m[a.hit], b.distance_m[b.hit], rtol=1e-5)
    np.testing.assert_allclose(a.radiance, b.radiance)  # the lamp's emission; the floor unbaked: black


@pytest.mark.slow
def test_a_bake_of_imported_meshes_matches_the_same_scene_from_primitives(tmp_path):
    from sim.bake import BakeConfig, bake_scene
    from sim.raycast import SceneRaycaster

    prim, imported = _primitive_and_imported(tmp_path)
    config = BakeConfig(texel_m=0.1, spp=8, direct_samples=64, final_gather=16)
    # camera rays from above the lamp's edge down onto a grid of floor points
    g = np.linspace(-0.9, 0.9, 24)
    target = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    target = np.concatenate([target, np.zeros((len(target), 1))], axis=1)
    origin = np.array([0.0, -0.6, 1.0])
    dirs = target - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    out = []
    for scene in (prim, imported):
        rc = SceneRaycaster(scene, bake_scene(scene, config, tmp_path / "cache"))
        h = rc.cast(origin, dirs, 0.0)
        assert (h.object_index == 0).all()  # every ray meets the floor (object 0 in both)
        out.append(h.radiance.astype(np.float64))
    a, b = out
    assert a.min() > 0
    np.testing.assert_allclose(b.mean(axis=0), a.mean(axis=0), rtol=0.02)
    # 4 × 4 blocks of the grid: the light falls off from under the lamp the same way
    blocks = lambda x: x[:, 1].reshape(4, 6, 4, 6).mean(axis=(1, 3))  # noqa: E731
    np.testing.assert_allclose(blocks(b), blocks(a), rtol=0.05)
    assert blocks(a).max() > 2 * blocks(a).min()  # the comparison sees the falloff


def test_a_closed_mesh_split_at_seams_is_merged_watertight(tmp_path):
    box = trimesh.creation.box(extents=[0.3, 0.2, 0.1])
    soup = trimesh.Trimesh(box.vertices[box.faces].reshape(-1, 3), np.arange(3 * len(box.faces)).reshape(-1, 3), process=False)
    assert not soup.is_watertight
    soup.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(baseColorFactor=[0.4, 0.4, 0.4, 1.0]))
    soup.export(tmp_path / "box.glb")
    (o,) = _scene(tmp_path, file="box.glb").objects
    assert len(o.vertices) == 8 and len(o.faces) == 12
    assert trimesh.Trimesh(o.vertices, o.faces, process=False).is_watertight


def test_obj_mtl_kd_is_linear(tmp_path):
    mesh = trimesh.Trimesh(_QUAD_V, _QUAD_F, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.SimpleMaterial(diffuse=[51, 102, 153, 255]))
    (tmp_path / "obj").mkdir()
    mesh.export(tmp_path / "obj" / "k.obj")
    assert "Kd 0.2" in "".join(p.read_text() for p in (tmp_path / "obj").glob("*.mtl"))
    (o,) = _scene(tmp_path, file="obj/k.obj").objects
    np.testing.assert_allclose(o.albedo, [0.2, 0.4, 0.6], rtol=1e-6)
