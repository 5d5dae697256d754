"""Virtual objects for relighting: the Stanford bunny (from Debian's CGAL data) and a procedural blob.

A :class:`VirtualObject` is a closed triangle mesh in its own **object frame**: z up, the base resting
on z = 0, the bounding box centred on x = y = 0, scaled to a given height in metres. It carries unit
area-weighted vertex normals and a linear RGB albedo, which is all the PRT stage (``rgbd_envmap.prt``)
and the renderer need. The world position of the object is the pipeline's business, not the asset's.

Objects:

- ``"bunny"``: the Stanford bunny as shipped by CGAL (``data/meshes/bunny00.off``: 37,706 vertices,
  75,408 triangles, closed). On Debian it is inside ``/usr/share/doc/libcgal-dev/data.tar.gz`` of the
  ``libcgal-demo`` package (``apt-get install --no-install-recommends libcgal-demo``). The file is
  extracted once into the cache directory; the cleaned mesh is cached beside it as ``.npz`` (keyed by a
  hash of the OFF file), so later loads take milliseconds. The OFF bunny is y-up; it is rotated
  +90° about x (x, y, z) → (x, −z, y) to stand on z = 0.
- ``"blob"``: a procedural star-shaped body (an icosphere with four radial horns and three dents, its
  bottom flattened into a base; its convex hull is 27 % larger than itself) with concave pockets and
  horns that shadow the body, so self-shadowing matters. It needs
  nothing on disk and is the fallback when the bunny is unavailable.

Cleaning (both objects): duplicate vertices merged, degenerate (zero-area) and duplicate faces dropped,
unreferenced vertices removed, and the winding flipped if the enclosed volume is negative (outward
normals). Normals are the normalised sum of the adjacent faces' cross products (area-weighted).

Cache directory: ``cache_dir`` if given, else ``$RGBD_ENVMAP_CACHE``, else ``~/.cache/rgbd-envmap``
(:func:`rgbd_envmap.cache.default_cache_dir`, re-exported here); files are written atomically
(:func:`rgbd_envmap.cache.atomic_write_bytes`).

References:
    - G. Turk and M. Levoy, "Zippered Polygon Meshes from Range Images", SIGGRAPH 1994 (the bunny scan;
      Stanford 3D Scanning Repository).
    - The CGAL Project, CGAL 5.5 data files (``data/meshes/bunny00.off``), Debian package libcgal-demo.
    - Paper 003 §7.1 (a virtual object rendered with PRT and a soft shadow plane).
"""

from __future__ import annotations

import hashlib
import io
import math
import tarfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd_envmap.cache import atomic_write_bytes, default_cache_dir
from rgbd_envmap.checks import check_array, check_method, check_positive_int
from rgbd_envmap.errors import (
    InvalidInputError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)

__all__ = [
    "BUNNY_ARCHIVES",
    "DEFAULT_ALBEDO",
    "OBJECT_NAMES",
    "AssetNotFoundError",
    "VirtualObject",
    "area_weighted_normals",
    "default_cache_dir",
    "load_virtual_object",
    "make_blob",
    "object_from_mesh",
]

OBJECT_NAMES = ("bunny", "blob")
"""Names accepted by :func:`load_virtual_object`."""

BUNNY_ARCHIVES = (
    Path("/usr/share/doc/libcgal-dev/data.tar.gz"),
    Path("/usr/share/doc/libcgal-demo/data.tar.gz"),
)
"""Where Debian's ``libcgal-demo`` puts the CGAL data archive (the second is a symlinked doc dir)."""

_BUNNY_MEMBER = "data/meshes/bunny00.off"
_CLEAN_VERSION = 1  # bump when the cleaning steps change: invalidates cached cleaned meshes

DEFAULT_ALBEDO = (0.60, 0.60, 0.60)
"""Linear RGB albedo of the objects: a light grey (sRGB ≈ 203/255), like unglazed white clay."""

_NORMAL_TOL = 1e-3


class AssetNotFoundError(RgbdEnvmapError, FileNotFoundError):
    """A mesh file the asset needs is not on this machine; the message says where it was looked for
    and how to install it."""


# --- the object type ----------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class VirtualObject:
    """A closed triangle mesh in the object frame, ready for PRT.

    Attributes:
        vertices: (V, 3) float32 positions in metres, object frame (z up, base on z = 0, centred on
            x = y = 0).
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside.
        normals: (V, 3) float32 unit area-weighted vertex normals, pointing outwards.
        albedo: (3,) float32 linear RGB diffuse albedo in [0, 1].
        name: the object's name (``"bunny"``, ``"blob"`` or a caller's name).
        source: where the mesh came from (a file path and member, or "procedural ...").

    Arrays are copied and made read-only on construction. Validation: finite vertices, at least one
    face, indices in range, unit normals (to 1e-3), albedo in [0, 1].
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    name: str
    source: str

    def __post_init__(self) -> None:
        v = check_array(self.vertices, "vertices", shape=("V", 3), dtype=("float", "int"), finite=True)
        f = check_array(self.faces, "faces", shape=("F", 3), dtype="int")
        n = check_array(self.normals, "normals", shape=(v.shape[0], 3), dtype="float", finite=True)
        a = check_array(self.albedo, "albedo", shape=(3,), dtype=("float", "int"), finite=True)
        if v.shape[0] == 0 or f.shape[0] == 0:
            raise ShapeError(f"vertices/faces: expected a non-empty mesh, got {v.shape[0]} vertices and "
                             f"{f.shape[0]} faces")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise RangeError(f"faces: expected indices in [0, {v.shape[0] - 1}], got [{f.min()}, {f.max()}]")
        lengths = np.linalg.norm(n.astype(np.float64), axis=1)
        if np.abs(lengths - 1.0).max() > _NORMAL_TOL:
            raise InvalidInputError(f"normals: expected unit vectors (to {_NORMAL_TOL}), got lengths in "
                                    f"[{lengths.min():.4g}, {lengths.max():.4g}]")
        if a.min() < 0.0 or a.max() > 1.0:
            raise RangeError(f"albedo: expected values in [0, 1], got {a.tolist()}")
        for field, arr, dtype in (("vertices", v, np.float32), ("faces", f, np.int32),
                                  ("normals", n, np.float32), ("albedo", a, np.float32)):
            arr = np.array(arr, dtype=dtype, copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, field, arr)

    @property
    def height_m(self) -> float:
        """Extent along z in metres."""
        return float(self.vertices[:, 2].max() - self.vertices[:, 2].min())

    def __repr__(self) -> str:
        return (f"VirtualObject(name={self.name!r}, {self.vertices.shape[0]} vertices, {self.faces.shape[0]} "
                f"faces, height {self.height_m:.4g} m, source={self.source!r})")


def area_weighted_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals: the normalised sum of the adjacent faces' cross products (so each face
    counts with its area), counter-clockwise faces giving outward normals.

    Args:
        vertices: (V, 3) float positions. faces: (F, 3) int indices.

    Returns:
        (V, 3) float64; a vertex whose face normals cancel or that no face uses gets a zero row.
    """
    v = check_array(vertices, "vertices", shape=("V", 3), dtype=("float", "int")).astype(np.float64)
    f = check_array(faces, "faces", shape=("F", 3), dtype="int")
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    acc = np.zeros_like(v)
    for c in range(3):
        for axis in range(3):
            acc[:, axis] += np.bincount(f[:, c], weights=cross[:, axis], minlength=len(v))
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    # Relative to the local face size so that tiny meshes still get normals.
    scale = max(float(np.abs(cross).max(initial=0.0)), np.finfo(np.float64).tiny)
    return np.where(norm > 1e-12 * scale, acc / np.where(norm > 0, norm, 1.0), 0.0)


def _clean(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge duplicate vertices, drop degenerate and duplicate faces and unreferenced vertices, make
    the winding outward for a closed mesh. Returns float64 vertices and int64 faces."""
    import trimesh  # local: only the asset loader needs it

    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                           process=True, validate=False)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise ShapeError("mesh: expected at least one non-degenerate face after cleaning, got none")
    if mesh.is_watertight and mesh.volume < 0.0:
        mesh.invert()
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def object_from_mesh(vertices: np.ndarray, faces: np.ndarray, *, height_m: float = 0.12, name: str = "mesh",
                     source: str = "caller", albedo: tuple[float, float, float] | np.ndarray = DEFAULT_ALBEDO,
                     up_axis: str = "z", clean: bool = True) -> VirtualObject:
    """Put any triangle mesh into the object frame: clean it, rotate ``up_axis`` to +z, rest the base
    on z = 0, centre the bounding box on x = y = 0, scale to ``height_m``, compute normals.

    Args:
        vertices: (V, 3) float, any units. faces: (F, 3) int.
        height_m: extent along z after scaling, metres (> 0).
        up_axis: "z" (no rotation) or "y" (a y-up mesh such as the bunny: (x, y, z) → (x, −z, y)).
        clean: run the cleaning steps of the module docstring.

    Raises:
        ShapeError / NonFiniteError / RangeError: empty mesh, NaN vertices, a flat mesh (zero height),
        bad ``height_m``. Vertices with zero normals after cleaning (isolated or cancelling faces)
        raise :class:`InvalidInputError`.
    """
    v = check_array(vertices, "vertices", shape=("V", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    f = check_array(faces, "faces", shape=("F", 3), dtype="int").astype(np.int64)
    if v.shape[0] == 0 or f.shape[0] == 0:
        raise ShapeError(f"vertices/faces: expected a non-empty mesh, got {v.shape[0]} vertices and "
                         f"{f.shape[0]} faces")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise RangeError(f"faces: expected indices in [0, {v.shape[0] - 1}], got [{f.min()}, {f.max()}]")
    height_m = float(height_m)
    if not (math.isfinite(height_m) and height_m > 0.0):
        raise RangeError(f"height_m: expected a finite value > 0, got {height_m}")
    check_method(up_axis, ("z", "y"), "up_axis")
    if clean:
        v, f = _clean(v, f)
    if up_axis == "y":
        v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)
    lo, hi = v.min(axis=0), v.max(axis=0)
    if hi[2] - lo[2] <= 0.0:
        raise RangeError("vertices: expected a mesh with a non-zero extent along the up axis, got a flat one")
    v = (v - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])) * (height_m / (hi[2] - lo[2]))
    n = area_weighted_normals(v, f)
    bad = np.count_nonzero(~np.any(n != 0.0, axis=1))
    if bad:
        raise InvalidInputError(f"mesh: expected every vertex to have a normal, got {bad} vertices whose "
                                f"faces cancel or that no face uses")
    return VirtualObject(vertices=v.astype(np.float32), faces=f.astype(np.int32), normals=n.astype(np.float32),
                         albedo=np.asarray(albedo, np.float32), name=name, source=source)


# --- the procedural blob ------------------------------------------------------------------------------

# (direction, amplitude, sharpness κ) of radial lobes a·exp(κ (d·c − 1)); negative amplitudes are dents.
_BLOB_LOBES = (
    ((0.0, 0.0, 1.0), 0.70, 10.0),      # a horn on top
    ((1.0, 0.0, 0.35), 0.75, 12.0),     # three horns around the shoulders: they shadow each other
    ((-0.5, 0.87, 0.35), 0.75, 12.0),   # and the body between them
    ((-0.5, -0.87, 0.35), 0.75, 12.0),
    ((0.5, 0.87, 0.1), -0.45, 6.0),     # three dents: concave pockets
    ((-1.0, 0.0, 0.0), -0.40, 6.0),
    ((0.5, -0.87, -0.1), -0.40, 7.0),
)


def make_blob(subdivisions: int = 5, *, height_m: float = 0.12,
              albedo: tuple[float, float, float] | np.ndarray = DEFAULT_ALBEDO) -> VirtualObject:
    """The procedural fallback object: an icosphere of ``subdivisions`` (10·4^s + 2 vertices: 5 →
    10,242; 6 → 40,962) displaced radially by lumps and dents, its lowest 15 % flattened into a base,
    in the object frame. Deterministic (no randomness)."""
    import trimesh

    subdivisions = check_positive_int(subdivisions, "subdivisions")
    if subdivisions > 7:
        raise RangeError(f"subdivisions: expected at most 7 (≈ 164k vertices), got {subdivisions}")
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sphere.vertices, np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = np.ones(len(d))
    for c, amp, kappa in _BLOB_LOBES:
        c = np.asarray(c) / np.linalg.norm(c)
        r += amp * np.exp(kappa * (d @ c - 1.0))
    r += 0.05 * np.sin(5.0 * np.arctan2(d[:, 1], d[:, 0])) * (1.0 - d[:, 2] ** 2)  # gentle ribs
    v = d * r[:, None]
    z_cut = v[:, 2].min() + 0.15 * (v[:, 2].max() - v[:, 2].min())
    v[:, 2] = np.maximum(v[:, 2], z_cut)
    obj = object_from_mesh(v, np.asarray(sphere.faces), height_m=height_m, name="blob",
                           source=f"procedural blob (icosphere, {subdivisions} subdivisions)", albedo=albedo)
    return obj


# --- the bunny ----------------------------------------------------------------------------------------

def _bunny_off_bytes(cache_dir: Path, archive: Path | None) -> tuple[bytes, str]:
    """The OFF file's bytes, extracted into ``cache_dir/meshes`` on first use; and a source string."""
    cached = cache_dir / "meshes" / "bunny00.off"
    candidates = [Path(archive)] if archive is not None else list(BUNNY_ARCHIVES)
    source = f"CGAL data.tar.gz:{_BUNNY_MEMBER} (Debian libcgal-demo)"
    if archive is None and cached.is_file():
        return cached.read_bytes(), source
    for path in candidates:
        if not path.is_file():
            continue
        if path.suffix.lower() == ".off":
            return path.read_bytes(), str(path)
        try:
            with tarfile.open(path, "r:*") as tf:
                member = tf.extractfile(_BUNNY_MEMBER)
                data = member.read() if member is not None else None
        except (tarfile.TarError, KeyError, OSError):
            continue
        if data:
            atomic_write_bytes(cached, data)
            return data, source if archive is None else f"{path}:{_BUNNY_MEMBER}"
    raise AssetNotFoundError(
        f"bunny: expected the CGAL bunny ({_BUNNY_MEMBER}) in one of {[str(p) for p in candidates]} or "
        f"{cached}, found none; install it with 'apt-get install --no-install-recommends libcgal-demo'")


def _parse_off(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Minimal OFF reader (triangles only); faces with more than 3 corners raise ShapeError."""
    import trimesh

    mesh = trimesh.load(io.BytesIO(data), file_type="off", process=False)
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    if v.ndim != 2 or f.ndim != 2 or f.shape[1] != 3 or len(v) == 0:
        raise ShapeError(f"bunny: expected a triangle mesh in the OFF file, got vertices {v.shape}, faces {f.shape}")
    return v, f


def _load_bunny_clean(cache_dir: Path, archive: Path | None) -> tuple[np.ndarray, np.ndarray, str]:
    """Cleaned bunny vertices (y-up, file units) and faces, via an npz cache keyed by the OFF's hash."""
    data, source = _bunny_off_bytes(cache_dir, archive)
    digest = hashlib.sha256(data + f"clean-v{_CLEAN_VERSION}".encode()).hexdigest()[:16]
    npz_path = cache_dir / "meshes" / f"bunny00_clean_{digest}.npz"
    if npz_path.is_file():
        try:
            with np.load(npz_path) as z:
                return z["vertices"], z["faces"], source
        except (OSError, KeyError, ValueError):
            pass  # a damaged cache file is rebuilt below
    v, f = _clean(*_parse_off(data))
    buf = io.BytesIO()
    np.savez(buf, vertices=v, faces=f)
    atomic_write_bytes(npz_path, buf.getvalue())
    return v, f, source


def load_virtual_object(name: str = "bunny", *, height_m: float = 0.12, cache_dir: str | Path | None = None,
                        albedo: tuple[float, float, float] | np.ndarray = DEFAULT_ALBEDO,
                        fallback: str | None = "blob", archive: str | Path | None = None,
                        subdivisions: int = 5) -> VirtualObject:
    """Load a virtual object in the object frame (z up, base on z = 0, centred on x = y = 0).

    Args:
        name: "bunny" (the CGAL Stanford bunny, 37,706 vertices) or "blob" (procedural,
            ``subdivisions`` 5 → 10,242 vertices).
        height_m: the object's height in metres (default 12 cm).
        cache_dir: where the extracted OFF and the cleaned mesh are kept (default
            :func:`default_cache_dir`).
        albedo: (3,) linear RGB in [0, 1] (default :data:`DEFAULT_ALBEDO`, a light grey).
        fallback: object to return, with a ``RuntimeWarning``, when the bunny is not on this machine
            (``source`` then says so); None raises :class:`AssetNotFoundError` instead.
        archive: a CGAL ``data.tar.gz`` or an ``.off`` file to read the bunny from instead of the
            Debian locations :data:`BUNNY_ARCHIVES` (the extracted copy in the cache is used only when
            ``archive`` is None).
        subdivisions: icosphere subdivisions of the blob.

    Returns:
        :class:`VirtualObject` with float32 vertices / normals, int32 faces.

    Raises:
        UnknownMethodError: unknown ``name``. RangeError: bad ``height_m``. AssetNotFoundError: the
        bunny is missing and ``fallback`` is None.

    Example:
        >>> obj = load_virtual_object("blob", height_m=0.1)
        >>> round(obj.height_m, 6), obj.vertices.shape
        (0.1, (10242, 3))
    """
    check_method(name, OBJECT_NAMES, "name")
    if fallback is not None:
        check_method(fallback, tuple(n for n in OBJECT_NAMES if n != "bunny"), "fallback")
    cache = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    if name == "blob":
        return make_blob(subdivisions, height_m=height_m, albedo=albedo)
    try:
        v, f, source = _load_bunny_clean(cache, None if archive is None else Path(archive))
    except AssetNotFoundError as exc:
        if fallback is None:
            raise
        warnings.warn(f"{exc}; using the procedural {fallback!r} instead", RuntimeWarning, stacklevel=2)
        obj = load_virtual_object(fallback, height_m=height_m, cache_dir=cache, albedo=albedo, fallback=None,
                                  subdivisions=subdivisions)
        return VirtualObject(vertices=obj.vertices, faces=obj.faces, normals=obj.normals, albedo=obj.albedo,
                             name=obj.name, source=f"{obj.source} (fallback: the bunny is not installed)")
    return object_from_mesh(v, f, height_m=height_m, name="bunny", source=source, albedo=albedo, up_axis="y",
                            clean=False)
