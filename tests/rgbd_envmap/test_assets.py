"""Tests for rgbd_envmap.assets: the virtual objects (CGAL bunny, procedural blob) in the object frame.

References: hand-computed normals of small meshes, trimesh's watertightness and volume, the bunny's
known size (37,706 vertices, 75,408 faces in CGAL's bunny00.off) and its flat base (y-up in the file).
The bunny tests are skipped where Debian's libcgal-demo is not installed.
"""

from __future__ import annotations

import dataclasses
import tarfile
import warnings

import numpy as np
import pytest
import trimesh

from rgbd_envmap import assets
from rgbd_envmap.cache import atomic_write_bytes, default_cache_dir
from rgbd_envmap.errors import (
    InvalidInputError,
    NonFiniteError,
    RangeError,
    ShapeError,
    UnknownMethodError,
)

HAVE_BUNNY = any(p.is_file() for p in assets.BUNNY_ARCHIVES)
needs_bunny = pytest.mark.skipif(not HAVE_BUNNY, reason="libcgal-demo (CGAL data.tar.gz) is not installed")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("asset-cache")


@pytest.fixture(scope="module")
def bunny(cache):
    return assets.load_virtual_object("bunny", cache_dir=cache, fallback=None)


def check_object_frame(obj: assets.VirtualObject, height_m: float) -> None:
    v = obj.vertices.astype(np.float64)
    assert obj.vertices.dtype == np.float32 and obj.normals.dtype == np.float32 and obj.faces.dtype == np.int32
    assert v[:, 2].min() == 0.0
    np.testing.assert_allclose(v[:, 2].max(), height_m, rtol=1e-6)
    np.testing.assert_allclose((v[:, :2].min(0) + v[:, :2].max(0)) / 2, 0.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(obj.normals, axis=1), 1.0, atol=1e-5)
    mesh = trimesh.Trimesh(obj.vertices, obj.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward winding
    # Outward normals: the area-weighted normal agrees with trimesh's face normals around each vertex.
    agree = np.einsum("ij,ij->i", obj.normals, mesh.vertex_normals)
    assert np.mean(agree > 0.5) > 0.99
    for arr in (obj.vertices, obj.faces, obj.normals, obj.albedo):
        assert not arr.flags.writeable


# --- blob ---------------------------------------------------------------------------------------------

def test_blob_object_frame_and_size():
    obj = assets.load_virtual_object("blob", height_m=0.2, subdivisions=3)
    assert obj.name == "blob" and "procedural" in obj.source
    assert obj.vertices.shape == (642, 3)
    check_object_frame(obj, 0.2)
    # The flattened base: many vertices exactly on z = 0 with normals −z.
    base = obj.vertices[:, 2] == 0
    assert base.sum() > 20
    assert np.mean(obj.normals[base, 2] < -0.99) > 0.5


def test_blob_default_size_and_determinism():
    a = assets.make_blob()
    b = assets.make_blob()
    assert a.vertices.shape == (10242, 3)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_blob_is_not_convex():
    obj = assets.make_blob(3)
    hull = trimesh.Trimesh(obj.vertices, obj.faces, process=False).convex_hull
    assert hull.volume > 1.2 * trimesh.Trimesh(obj.vertices, obj.faces, process=False).volume


def test_default_albedo_is_light_grey():
    obj = assets.make_blob(1)
    np.testing.assert_allclose(obj.albedo, assets.DEFAULT_ALBEDO)
    assert np.all(obj.albedo == obj.albedo[0]) and 0.4 < obj.albedo[0] < 0.8


# --- normals and frame conversion ---------------------------------------------------------------------

def test_area_weighted_normals_of_a_fold():
    # Two triangles sharing the edge (0, 1): a big one in the plane z = 0 (normal +z) and a small one
    # in the plane x = 0 (normal +x). The shared vertices lean towards the big face by its area.
    v = np.array([[0, 0, 0], [0, 1, 0], [2, 0, 0], [0, 0, 0.5]], float)
    f = np.array([[0, 2, 1], [0, 1, 3]])
    n = assets.area_weighted_normals(v, f)
    big, small = np.array([0, 0, 1.0]) * 1.0, np.array([1.0, 0, 0]) * 0.25  # area of each face
    expect = (big + small) / np.linalg.norm(big + small)
    np.testing.assert_allclose(n[0], expect, atol=1e-12)
    np.testing.assert_allclose(n[1], expect, atol=1e-12)
    np.testing.assert_allclose(n[2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(n[3], [1, 0, 0], atol=1e-12)


def test_area_weighted_normals_of_a_sphere_are_radial():
    s = trimesh.creation.icosphere(3)
    n = assets.area_weighted_normals(s.vertices, s.faces)
    radial = s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", n, radial).min() > 0.999


def test_unused_vertex_gets_zero_normal():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    n = assets.area_weighted_normals(v, np.array([[0, 1, 2]]))
    np.testing.assert_array_equal(n[3], 0.0)


def test_y_up_mesh_stands_on_z():
    # A tall box along y (y-up file), off-centre: it becomes tall along z, centred, on z = 0.
    box = trimesh.creation.box(extents=(0.2, 1.0, 0.4))
    box.apply_translation((3.0, 2.0, -1.0))
    obj = assets.object_from_mesh(box.vertices, box.faces, height_m=0.5, up_axis="y")
    ext = obj.vertices.max(0) - obj.vertices.min(0)
    np.testing.assert_allclose(ext, [0.1, 0.2, 0.5], rtol=1e-6)
    check_object_frame(obj, 0.5)


def test_cleaning_merges_duplicates_and_drops_degenerate_faces():
    box = trimesh.creation.box()
    v = np.asarray(box.vertices)
    f = np.asarray(box.faces)
    # Duplicate every vertex (each face uses its own copy) and add a zero-area face and a repeat.
    v2 = v[f.ravel()]
    f2 = np.arange(len(v2)).reshape(-1, 3)
    f2 = np.vstack([f2, [[0, 0, 1]], f2[:1]])
    obj = assets.object_from_mesh(v2, f2, height_m=1.0)
    assert obj.vertices.shape == (8, 3) and obj.faces.shape == (12, 3)
    check_object_frame(obj, 1.0)


def test_inverted_winding_is_fixed():
    s = trimesh.creation.icosphere(2)
    obj = assets.object_from_mesh(s.vertices, s.faces[:, ::-1], height_m=1.0)
    check_object_frame(obj, 1.0)


def test_object_from_mesh_invalid():
    s = trimesh.creation.icosphere(1)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    with pytest.raises(ShapeError, match="non-empty"):
        assets.object_from_mesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    bad = v.copy()
    bad[2, 0] = np.nan
    with pytest.raises(NonFiniteError, match="vertices"):
        assets.object_from_mesh(bad, f)
    with pytest.raises(RangeError, match="height_m"):
        assets.object_from_mesh(v, f, height_m=0.0)
    with pytest.raises(RangeError, match="faces"):
        assets.object_from_mesh(v, f + 100)
    with pytest.raises(UnknownMethodError, match="up_axis"):
        assets.object_from_mesh(v, f, up_axis="x")
    flat = v.copy()
    flat[:, 2] = 0.0
    with pytest.raises(RangeError, match="extent"):
        assets.object_from_mesh(flat, f)  # no height to scale
    with pytest.raises(ShapeError, match="non-degenerate"):
        assets.object_from_mesh(np.zeros((3, 3)), np.array([[0, 1, 2]]))


def test_virtual_object_validation_and_immutability():
    obj = assets.make_blob(1)
    fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    with pytest.raises(InvalidInputError, match="normals"):
        assets.VirtualObject(**{**fields, "normals": obj.normals * 2})
    with pytest.raises(RangeError, match="faces"):
        assets.VirtualObject(**{**fields, "faces": obj.faces + 1000})
    with pytest.raises(RangeError, match="albedo"):
        assets.VirtualObject(**{**fields, "albedo": np.array([0.5, 1.5, 0.5])})
    with pytest.raises(ShapeError, match="albedo"):
        assets.VirtualObject(**{**fields, "albedo": np.array([0.5, 0.5])})
    with pytest.raises(ShapeError, match="non-empty"):
        assets.VirtualObject(**{**fields, "faces": np.zeros((0, 3), np.int32)})
    with pytest.raises(dataclasses.FrozenInstanceError):
        obj.name = "x"
    with pytest.raises(ValueError):
        obj.vertices[0, 0] = 1.0
    assert "blob" in repr(obj) and "vertices" in repr(obj)


# --- loading, cache, fallback -------------------------------------------------------------------------

def test_unknown_name():
    with pytest.raises(UnknownMethodError, match="name"):
        assets.load_virtual_object("teapot")


def test_missing_bunny_falls_back_to_blob(tmp_path):
    with pytest.warns(RuntimeWarning, match="libcgal-demo"):
        obj = assets.load_virtual_object("bunny", cache_dir=tmp_path, archive=tmp_path / "nope.tar.gz",
                                         subdivisions=2)
    assert obj.name == "blob" and "fallback" in obj.source
    with pytest.raises(assets.AssetNotFoundError, match="libcgal-demo") as info:
        assets.load_virtual_object("bunny", cache_dir=tmp_path, archive=tmp_path / "nope.tar.gz", fallback=None)
    assert isinstance(info.value, FileNotFoundError)


def test_archive_without_the_member_is_not_found(tmp_path):
    archive = tmp_path / "data.tar.gz"
    other = tmp_path / "readme.txt"
    other.write_text("x")
    with tarfile.open(archive, "w:gz") as tf:
        tf.add(other, arcname="data/readme.txt")
    with pytest.raises(assets.AssetNotFoundError):
        assets.load_virtual_object("bunny", cache_dir=tmp_path, archive=archive, fallback=None)


def test_off_file_as_archive(tmp_path):
    box = trimesh.creation.box(extents=(1.0, 2.0, 1.0))
    path = tmp_path / "box.off"
    box.export(path)
    obj = assets.load_virtual_object("bunny", cache_dir=tmp_path, archive=path, height_m=0.1)
    assert obj.source == str(path)
    check_object_frame(obj, 0.1)
    np.testing.assert_allclose(obj.vertices.max(0) - obj.vertices.min(0), [0.05, 0.05, 0.1], rtol=1e-6)


def test_default_cache_dir(monkeypatch, tmp_path):
    monkeypatch.setenv("RGBD_ENVMAP_CACHE", str(tmp_path))
    assert assets.default_cache_dir() == tmp_path
    monkeypatch.setenv("RGBD_ENVMAP_CACHE", "")
    assert assets.default_cache_dir().name == "rgbd-envmap"
    assert assets.default_cache_dir is default_cache_dir


def test_atomic_write_replaces_the_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "entry.npz"
    atomic_write_bytes(path, b"first")
    atomic_write_bytes(path, b"second")
    assert path.read_bytes() == b"second"
    assert path.stat().st_mode & 0o777 == 0o644  # readable by other users of a shared cache
    assert sorted(p.name for p in path.parent.iterdir()) == ["entry.npz"]


@needs_bunny
def test_bunny_shape_and_frame(bunny):
    assert bunny.name == "bunny" and "bunny00.off" in bunny.source
    assert bunny.vertices.shape == (37706, 3) and bunny.faces.shape == (75408, 3)
    check_object_frame(bunny, 0.12)
    # Upright: the scan's flat base (y-min in the file) is now on z = 0 with normals pointing down.
    base = bunny.vertices[:, 2] < 0.002
    assert base.sum() > 1000
    assert np.mean(bunny.normals[base, 2] < -0.9) > 0.5


@needs_bunny
def test_bunny_is_the_file_rotated_y_up_to_z_up(bunny, cache):
    raw = trimesh.load(cache / "meshes" / "bunny00.off", process=False)
    v = np.asarray(raw.vertices)
    assert len(v) == len(bunny.vertices)  # the CGAL file has no duplicates or degenerate faces
    # (x, y, z)_file → (x, −z, y) then a uniform scale and a shift: each object axis is an affine
    # function of one file axis with the same positive scale.
    s = 0.12 / np.ptp(v[:, 1])
    for obj_axis, file_axis, sign in ((0, 0, 1), (1, 2, -1), (2, 1, 1)):
        got = bunny.vertices[:, obj_axis].astype(np.float64)
        want = sign * s * v[:, file_axis]
        np.testing.assert_allclose(got - got.mean(), want - want.mean(), atol=2e-7)
    # Right-handed: the volume keeps its sign (positive, outward winding).
    assert trimesh.Trimesh(bunny.vertices, bunny.faces, process=False).volume > 0


@needs_bunny
def test_bunny_cache_is_used(bunny, cache, monkeypatch):
    assert (cache / "meshes" / "bunny00.off").is_file()
    assert len(list((cache / "meshes").glob("bunny00_clean_*.npz"))) == 1

    def boom(*a, **k):
        raise AssertionError("parsed again")

    monkeypatch.setattr(assets, "_parse_off", boom)
    again = assets.load_virtual_object("bunny", cache_dir=cache, height_m=0.24)
    np.testing.assert_allclose(again.vertices, 2 * bunny.vertices, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(again.faces, bunny.faces)


def test_no_warnings_for_blob():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assets.load_virtual_object("blob", subdivisions=1)
