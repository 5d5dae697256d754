"""Precomputed radiance transfer (PRT): per-vertex transfer vectors with self-visibility, Lambertian
shading with SH lighting, and the soft-shadow plane (paper 003 §7.1; docs/design/overview.md, stage 9).

What is computed. For a vertex x with unit normal n, the transfer vector of a diffuse receiver is

    T_k(x) = ∫_S² V(x, ω) max(n·ω, 0) Y_k(ω) dω,        k = l(l + 1) + m,  l < bands,

with V = 1 where the ray x + tω (t > 0) escapes the mesh (and any extra occluders) and 0 where it hits.
With the environment's SH radiance coefficients L_k (``sh.project_equirect``), the outgoing radiance
is (albedo / π) Σ_k L_k T_k (:func:`shade`). Without occlusion T_k = Â_l Y_k(n) exactly
(:func:`unoccluded_transfer`; Â_l are the clamped-cosine band factors), so :func:`shade` then equals
``(albedo / π) · sh.irradiance(coeffs, n)``.

Quadrature. One set of ``n_dirs`` directions covers the sphere: a spherical Fibonacci lattice (equal
area, low discrepancy), rotated by a fixed random rotation drawn from ``seed`` (deterministic: the same
seed gives bit-identical results). Each direction has weight 4π / n_dirs; about half of them are above a
given vertex's horizon, and only those are cast (open3d's Embree ``RaycastingScene.test_occlusions``).
Because every vertex uses the same directions, the SH part is a single float32 matrix product
(vertices × directions) @ (directions × bands²).

Two estimators (``estimator=``):

- ``"occluded"`` (default): T = Â_l Y_k(n) − Σ_j w (1 − V_j) max(n·ω_j, 0) Y_k(ω_j). The unoccluded part
  is integrated in closed form and only the *blocked* part by quadrature (a control variate), so a
  vertex that sees the whole hemisphere is exact and the quadrature error scales with the blocked
  fraction. A fully enclosed vertex gets the quadrature error of the whole hemisphere instead of 0.
- ``"direct"``: T = Σ_j w V_j max(n·ω_j, 0) Y_k(ω_j), the plain estimator; its error with no occlusion
  (the kink of max(n·ω, 0) at the horizon) is what the control variate removes. Kept as an
  independent check and for the documentation's error-vs-n_dirs figure.

Ray origins are offset by ``offset_m`` along the vertex normal (default 1e-5 × the diagonal of the
bounding box of all geometry: 1.95 µm for the 12 cm bunny) so that a ray does not hit the faces around
its own vertex; docs/design/prt.md shows the transfer unchanged over 1e-7 … 1e-4 × the diagonal, brighter
from 1e-3 on (origins leave the creases).

Cache. :func:`load_or_compute` and :func:`shadow_plane` keep results in ``<cache>/prt/*.npz`` keyed by a
SHA-256 of the mesh arrays (bytes, dtype and shape) and every setting, so a changed mesh or setting
computes anew (``cache`` is ``cache_dir``, else ``$RGBD_ENVMAP_CACHE``, else ``~/.cache/rgbd-envmap``).

Shadow plane. :func:`shadow_plane` lays a grid on z = 0 around the object (object frame) and stores two
transfer vectors per grid vertex, normal +z: with the object as occluder and without (closed form
Â_l Y_k(+z)). :func:`shadow_alpha` turns them into alpha = clip(1 − E_with / E_without, 0, 1) with E the
luminance (Rec. 709 weights) of the irradiance Σ_k L_k T_k.

Invalid input: wrong shapes raise :class:`ShapeError`; NaN or infinity in vertices, normals or
coefficients raise :class:`NonFiniteError`; a zero-length normal raises :class:`InvalidInputError`
(its transfer would be undefined); face indices out of range raise :class:`RangeError`. An empty vertex
array gives an empty (0, bands²) result; an empty face array means "no self-occlusion". Any
``n_dirs`` ≥ 1 is accepted (a tiny one is just a coarse quadrature; with the default estimator the
unoccluded part stays exact). ``shade`` does not scan the transfer for NaN (it runs per colour frame
and must stay well under a millisecond); a NaN row gives a NaN colour.

The compiled loops are in :mod:`rgbd_envmap._kernels.prt`; what they compute, in plain numpy, in
:mod:`rgbd_envmap.reference.prt`.

References:
    - P.-P. Sloan, J. Kautz, J. Snyder, "Precomputed Radiance Transfer for Real-Time Rendering in
      Dynamic, Low-Frequency Lighting Environments", SIGGRAPH 2002 (transfer vectors, shadowed
      diffuse transfer).
    - R. Ramamoorthi and P. Hanrahan, "An Efficient Representation for Irradiance Environment Maps",
      SIGGRAPH 2001 (Â_l).
    - Á. González, "Measurement of Areas on a Sphere Using Fibonacci and Latitude–Longitude
      Lattices", Math. Geosci. 2010 (spherical Fibonacci lattice).
    - Paper 003 §7.1 (25 coefficients, PRT with a shadow plane, alpha from the irradiance ratio).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd_envmap import sh
from rgbd_envmap._kernels import prt as kernels
from rgbd_envmap.assets import VirtualObject
from rgbd_envmap.cache import atomic_write_bytes, default_cache_dir
from rgbd_envmap.checks import check_array, check_method, check_number, check_positive_int, check_range
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, ShapeError

__all__ = [
    "ESTIMATORS",
    "LUMINANCE_WEIGHTS",
    "ShadowPlane",
    "compute_transfer",
    "load_or_compute",
    "plane_grid",
    "shade",
    "shadow_alpha",
    "shadow_plane",
    "sphere_directions",
    "transfer_cache_path",
    "unoccluded_transfer",
    "MAX_PRT_DIRS",
]

ESTIMATORS = ("occluded", "direct")
"""Quadrature estimators of :func:`compute_transfer` (see the module docstring)."""

LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 / sRGB luminance of linear RGB, used for the shadow alpha."""

DEFAULT_OFFSET_FRACTION = 1e-5
"""Ray-origin offset along the normal, as a fraction of the bounding-box diagonal of all geometry."""

_VERSION = 1  # bump when the numbers a cached file holds would change: part of every cache key
_CHUNK_ENTRIES = 1 << 21  # vertices × directions per chunk (≈ 8 MB of float32)
_ALPHA_TINY = 1e-6  # E_without below this fraction of π × the mean environment luminance → alpha 0


# --- directions and closed forms ----------------------------------------------------------------------

#: The most directions a transfer is computed with: 2**20 (the lattice alone is 24 MiB of float64;
#: the default is 1,024).
MAX_PRT_DIRS = 2**20


def _check_dirs(n_dirs: object) -> int:
    n_dirs = check_positive_int(n_dirs, "n_dirs")
    if n_dirs > MAX_PRT_DIRS:
        raise RangeError(f"n_dirs: expected at most {MAX_PRT_DIRS:,} directions, got {n_dirs:,}; the lattice "
                         f"alone would take about {n_dirs * 24 / 2**30:.3g} GiB")
    return n_dirs


def sphere_directions(n_dirs: int, seed: int | None = 0) -> np.ndarray:
    """(n_dirs, 3) float64 unit directions: a spherical Fibonacci lattice (equal-area points,
    z_i = 1 − (2i + 1)/N, φ_i = 2π i / golden ratio), rotated by a random rotation drawn from ``seed``
    (None: not rotated). Each direction stands for 4π / n_dirs steradians. ``n_dirs`` is at most
    :data:`MAX_PRT_DIRS`; ``seed`` is an integer ≥ 0 or None."""
    n_dirs = _check_dirs(n_dirs)
    seed = check_number(seed, "seed", low=0, integer=True, optional=True)
    i = np.arange(n_dirs, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n_dirs
    phi = 2.0 * math.pi * np.mod(i * (2.0 / (1.0 + math.sqrt(5.0))), 1.0)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    if seed is not None:
        from scipy.spatial.transform import Rotation

        d = d @ Rotation.random(random_state=np.random.default_rng(int(seed))).as_matrix().T
    return d


def _l_of_k(bands: int) -> np.ndarray:
    return np.repeat(np.arange(bands), 2 * np.arange(bands) + 1)


def unoccluded_transfer(normals: np.ndarray, bands: int = 5) -> np.ndarray:
    """Closed-form transfer with no occlusion, T_k = Â_l Y_k(n).

    Args:
        normals: (..., 3) float, need not be unit (normalised here; zero / non-finite → NaN row).
        bands: number of bands ≥ 1.

    Returns:
        (..., bands²) float64.
    """
    bands = check_positive_int(bands, "bands")
    normals = check_array(normals, "normals", shape=("*", 3), dtype=("float", "int"))
    a = sh.lambertian_band_factors(bands)[_l_of_k(bands)]
    return sh.basis(normals, bands) * a


# --- ray casting --------------------------------------------------------------------------------------

def _as_mesh(item: object, index: int) -> tuple[np.ndarray, np.ndarray]:
    """An occluder given as an object with .vertices/.faces or as a (vertices, faces) pair."""
    if hasattr(item, "vertices") and hasattr(item, "faces"):
        v, f = item.vertices, item.faces
    elif isinstance(item, (tuple, list)) and len(item) == 2:
        v, f = item
    else:
        raise DTypeError(f"occluder_meshes[{index}]: expected (vertices, faces) or an object with .vertices "
                         f"and .faces, got {type(item).__name__}")
    name = f"occluder_meshes[{index}]"
    v = check_array(v, f"{name}.vertices", shape=("V", 3), dtype=("float", "int"), finite=True)
    f = check_array(f, f"{name}.faces", shape=("F", 3), dtype="int")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise RangeError(f"{name}.faces: expected indices in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    return v, f


def _validate_mesh(vertices, normals, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v = check_array(vertices, "vertices", shape=("V", 3), dtype=("float", "int"), finite=True)
    n = check_array(normals, "normals", shape=(v.shape[0], 3), dtype=("float", "int"), finite=True)
    f = check_array(faces, "faces", shape=("F", 3), dtype="int")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise RangeError(f"faces: expected indices in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    n = n.astype(np.float64)
    length = np.linalg.norm(n, axis=1)
    if (length == 0.0).any():
        raise InvalidInputError(f"normals: expected non-zero vectors, got {int((length == 0.0).sum())} zero "
                                f"of {len(n)} (a vertex no face uses, or faces that cancel)")
    return v.astype(np.float64), n / length[:, None], f


def compute_transfer(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, bands: int = 5, *,
                     n_dirs: int = 1024, seed: int | None = 0, occluder_meshes: Sequence = (),
                     estimator: str = "occluded", offset_m: float | None = None, self_occlusion: bool = True,
                     n_threads: int = 0) -> np.ndarray:
    """Diffuse shadowed transfer vectors T_k(x) = ∫ V(x, ω) max(n·ω, 0) Y_k(ω) dω at every vertex.

    Args:
        vertices: (V, 3) float positions, metres (any frame; the result is in the same frame).
        normals: (V, 3) float outward normals (normalised here; zero → error).
        faces: (F, 3) int triangles of the mesh itself; they occlude when ``self_occlusion``.
            F = 0 means no self-occlusion (e.g. points on a plane).
        bands: number of SH bands n ≥ 1; the result has n² columns.
        n_dirs: directions on the whole sphere (about half are cast per vertex).
        seed: rotation of the direction lattice (deterministic); None: unrotated.
        occluder_meshes: extra occluders, each (vertices, faces) or an object with ``.vertices`` and
            ``.faces`` (e.g. a :class:`VirtualObject`), in the same frame.
        estimator: "occluded" (closed form minus the blocked part; default) or "direct".
        offset_m: ray-origin offset along the normal; None: 1e-5 × the bounding-box diagonal.
        self_occlusion: False ignores ``faces`` as occluders.
        n_threads: open3d ray-casting threads (0: open3d's default, all cores).

    Returns:
        (V, n²) float32 transfer vectors, column k = l(l + 1) + m.

    Raises:
        ShapeError / NonFiniteError / RangeError / InvalidInputError: see the module docstring.

    Example:
        >>> up = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
        >>> round(float(compute_transfer(*up, np.zeros((0, 3), int), bands=1)[0, 0]), 5)  # π · Y_00
        0.88623
    """
    bands = check_positive_int(bands, "bands")
    n_dirs = _check_dirs(n_dirs)
    check_method(estimator, ESTIMATORS, "estimator")
    v, n, f = _validate_mesh(vertices, normals, faces)
    occluders = [_as_mesh(item, i) for i, item in enumerate(occluder_meshes)]
    K = bands * bands
    if len(v) == 0:
        return np.zeros((0, K), np.float32)

    geometry = ([(v, f)] if self_occlusion and len(f) else []) + [(ov, of) for ov, of in occluders if len(of)]
    if offset_m is None:
        pts = np.concatenate([v] + [np.asarray(ov, np.float64) for ov, _ in occluders])
        diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        offset_m = DEFAULT_OFFSET_FRACTION * (diag if diag > 0 else 1.0)
    offset_m = float(offset_m)
    if not (math.isfinite(offset_m) and offset_m >= 0.0):
        raise RangeError(f"offset_m: expected a finite value ≥ 0, got {offset_m}")

    dirs = sphere_directions(n_dirs, seed)
    y_w = (sh.basis(dirs, bands) * (4.0 * math.pi / n_dirs)).astype(np.float32)  # (N, K)
    dirs32 = dirs.astype(np.float32)
    out = (unoccluded_transfer(n, bands).astype(np.float32) if estimator == "occluded"
           else np.zeros((len(v), K), np.float32))

    scene = None
    if geometry:
        import open3d as o3d  # local: importing open3d is slow and only this function needs it

        scene = o3d.t.geometry.RaycastingScene()
        for gv, gf in geometry:
            scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(gv, np.float32)),
                                o3d.core.Tensor(np.ascontiguousarray(gf, np.uint32)))
    if scene is None and estimator == "occluded":
        return out

    origins = (v + offset_m * n).astype(np.float32)
    n32 = n.astype(np.float32)
    step = max(1, _CHUNK_ENTRIES // n_dirs)
    for s in range(0, len(v), step):
        e = min(len(v), s + step)
        cos = n32[s:e] @ dirs32.T  # (c, N)
        if scene is None:  # "direct" without any occluder
            np.maximum(cos, 0.0, out=cos)
            out[s:e] = cos @ y_w
            continue
        rays, flat = kernels.upper_rays(origins[s:e], dirs32, cos)
        hit = scene.test_occlusions(o3d.core.Tensor(rays), nthreads=n_threads).numpy()
        hit8 = hit.view(np.uint8) if hit.dtype == np.bool_ else hit.astype(np.uint8)
        weight = kernels.blocked_weights(cos, flat, hit8, estimator == "occluded")
        part = weight @ y_w
        if estimator == "occluded":
            out[s:e] -= part
        else:
            out[s:e] = part
    return out


# --- cache ----------------------------------------------------------------------------------------------

def _hash_arrays(h, *arrays: np.ndarray) -> None:
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())


def _cache_key(kind: str, arrays: Sequence[np.ndarray], settings: dict) -> str:
    h = hashlib.sha256(f"{kind}-v{_VERSION}".encode())
    _hash_arrays(h, *arrays)
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()[:24]


def _cache_root(cache_dir: str | Path | None) -> Path:
    return (Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()) / "prt"


def _read_npz(path: Path, names: Sequence[str]) -> dict | None:
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            return {k: z[k] for k in names}
    except (OSError, KeyError, ValueError, EOFError):
        return None  # damaged or partial: recompute and overwrite


def _write_npz(path: Path, **arrays: np.ndarray) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _transfer_settings(bands: int, n_dirs: int, seed, estimator: str, offset_m) -> dict:
    return {"bands": bands, "n_dirs": n_dirs, "seed": seed, "estimator": estimator,
            "offset_m": None if offset_m is None else float(offset_m)}


def transfer_cache_path(obj: VirtualObject, bands: int = 5, *, n_dirs: int = 1024, seed: int | None = 0,
                        estimator: str = "occluded", offset_m: float | None = None,
                        cache_dir: str | Path | None = None) -> Path:
    """The ``.npz`` file :func:`load_or_compute` reads or writes for these arguments."""
    key = _cache_key("transfer", (obj.vertices, obj.faces, obj.normals),
                     _transfer_settings(bands, n_dirs, seed, estimator, offset_m))
    return _cache_root(cache_dir) / f"transfer_{obj.name}_{len(obj.vertices)}v_{bands}b_{key}.npz"


def load_or_compute(obj: VirtualObject, bands: int = 5, *, n_dirs: int = 1024, seed: int | None = 0,
                    estimator: str = "occluded", offset_m: float | None = None,
                    cache_dir: str | Path | None = None, use_cache: bool = True) -> np.ndarray:
    """The object's transfer vectors (:func:`compute_transfer` with self-occlusion), cached on disk.

    Args:
        obj: the virtual object (object frame). bands, n_dirs, seed, estimator, offset_m: as in
            :func:`compute_transfer`.
        cache_dir: cache root (``<cache_dir>/prt/``); None: ``$RGBD_ENVMAP_CACHE`` or
            ``~/.cache/rgbd-envmap``.
        use_cache: False computes without reading or writing the cache.

    Returns:
        (V, bands²) float32, read-only when it came from or went to the cache. The cache key hashes
        the vertices, faces and normals and every setting; a damaged file is recomputed.
    """
    if not isinstance(obj, VirtualObject):
        raise DTypeError(f"obj: expected a VirtualObject, got {type(obj).__name__}")
    bands = check_positive_int(bands, "bands")
    n_dirs = _check_dirs(n_dirs)
    check_method(estimator, ESTIMATORS, "estimator")

    def compute() -> np.ndarray:
        return compute_transfer(obj.vertices, obj.normals, obj.faces, bands, n_dirs=n_dirs, seed=seed,
                                estimator=estimator, offset_m=offset_m)

    if not use_cache:
        return compute()
    path = transfer_cache_path(obj, bands, n_dirs=n_dirs, seed=seed, estimator=estimator, offset_m=offset_m,
                               cache_dir=cache_dir)
    got = _read_npz(path, ("transfer",))
    if got is not None and got["transfer"].shape == (len(obj.vertices), bands * bands) \
            and got["transfer"].dtype == np.float32:
        t = got["transfer"]
    else:
        t = compute()
        _write_npz(path, transfer=t)
    t.setflags(write=False)
    return t


# --- the shadow plane ---------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ShadowPlane:
    """A square grid on z = 0 around the object (object frame) with transfer vectors per grid vertex.

    Attributes:
        vertices: (P, 3) float32 grid vertices, P = resolution², row-major from (−s/2, −s/2); z = 0.
        faces: (2 (resolution − 1)², 3) int32 triangles, counter-clockwise seen from +z.
        transfer_with: (P, bands²) float32, the object occluding (normal +z).
        transfer_without: (P, bands²) float32, no occluder: Â_l Y_k(+z) (the same in every row).
        size_m: side length in metres. resolution: vertices per side. bands, n_dirs: the settings.
    """

    vertices: np.ndarray
    faces: np.ndarray
    transfer_with: np.ndarray
    transfer_without: np.ndarray
    size_m: float
    resolution: int
    bands: int
    n_dirs: int

    def __post_init__(self) -> None:
        for name in ("vertices", "faces", "transfer_with", "transfer_without"):
            arr = np.array(getattr(self, name), copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        P, K = len(self.vertices), self.bands * self.bands
        if self.transfer_with.shape != (P, K) or self.transfer_without.shape != (P, K):
            raise ShapeError(f"transfer_with/transfer_without: expected ({P}, {K}), got "
                             f"{self.transfer_with.shape} and {self.transfer_without.shape}")


def plane_grid(size_m: float, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """The shadow plane's grid: ``resolution`` × ``resolution`` vertices on z = 0 spanning
    [−size_m / 2, size_m / 2]² (row-major from (−s/2, −s/2): row j has y = t[j], column i x = t[i]),
    as (P, 3) float32 vertices and (2 (resolution − 1)², 3) int32 faces, counter-clockwise seen from
    +z. ``size_m`` in (0, 1e6] metres, ``resolution`` an integer in [2, 4096]."""
    size_m = check_number(size_m, "size_m", low=0.0, low_open=True, high=1e6)
    resolution = check_number(resolution, "resolution", low=2, high=4096, integer=True)
    t = np.linspace(-size_m / 2, size_m / 2, resolution)
    gx, gy = np.meshgrid(t, t)  # row j: y = t[j]; column i: x = t[i]
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(resolution * resolution)], axis=1).astype(np.float32)
    idx = np.arange(resolution * resolution).reshape(resolution, resolution)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()  # (j, i), (j, i + 1)
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()  # (j + 1, i + 1), (j + 1, i)
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return vertices, faces


def shadow_plane(obj: VirtualObject, *, size_m: float | None = None, resolution: int = 48, bands: int = 5,
                 n_dirs: int = 1024, seed: int | None = 0, offset_m: float | None = None,
                 cache_dir: str | Path | None = None, use_cache: bool = True) -> ShadowPlane:
    """Transfer vectors of a ground plane under the object, with the object as occluder and without.

    Args:
        obj: the virtual object (object frame: its base rests on z = 0).
        size_m: side of the square plane, centred on x = y = 0; None: 4 × the larger of the object's
            height and horizontal extent.
        resolution: grid vertices per side (≥ 2).
        bands, n_dirs, seed, offset_m: as in :func:`compute_transfer` (``estimator="occluded"``).
        cache_dir, use_cache: as in :func:`load_or_compute`.

    Returns:
        :class:`ShadowPlane`. Grid vertices inside the object's footprint are covered by its base:
        their transfer is ≈ 0 (alpha ≈ 1).
    """
    if not isinstance(obj, VirtualObject):
        raise DTypeError(f"obj: expected a VirtualObject, got {type(obj).__name__}")
    bands = check_positive_int(bands, "bands")
    n_dirs = _check_dirs(n_dirs)
    resolution = check_positive_int(resolution, "resolution")
    if resolution < 2:
        raise RangeError(f"resolution: expected at least 2 vertices per side, got {resolution}")
    if size_m is None:
        ext = obj.vertices.max(axis=0) - obj.vertices.min(axis=0)
        size_m = 4.0 * float(max(ext.max(), 1e-6))
    size_m = float(size_m)
    if not (math.isfinite(size_m) and size_m > 0.0):
        raise RangeError(f"size_m: expected a finite value > 0, got {size_m}")

    vertices, faces = plane_grid(size_m, resolution)
    up = np.zeros_like(vertices)
    up[:, 2] = 1.0
    without = np.repeat(unoccluded_transfer(up[:1], bands).astype(np.float32), len(vertices), axis=0)

    def compute() -> np.ndarray:
        return compute_transfer(vertices, up, np.zeros((0, 3), np.int32), bands, n_dirs=n_dirs, seed=seed,
                                occluder_meshes=[obj], offset_m=offset_m)

    if use_cache:
        settings = _transfer_settings(bands, n_dirs, seed, "occluded", offset_m)
        settings.update(size_m=size_m, resolution=resolution)
        key = _cache_key("plane", (obj.vertices, obj.faces), settings)
        path = _cache_root(cache_dir) / f"plane_{obj.name}_{resolution}r_{bands}b_{key}.npz"
        got = _read_npz(path, ("transfer_with",))
        if got is not None and got["transfer_with"].shape == without.shape:
            with_ = got["transfer_with"].astype(np.float32)
        else:
            with_ = compute()
            _write_npz(path, transfer_with=with_)
    else:
        with_ = compute()
    return ShadowPlane(vertices=vertices, faces=faces, transfer_with=with_, transfer_without=without,
                       size_m=size_m, resolution=resolution, bands=bands, n_dirs=n_dirs)


# --- shading --------------------------------------------------------------------------------------------

def _coeffs(coeffs: np.ndarray) -> np.ndarray:
    L = check_array(coeffs, "coeffs", shape=("K", 3), dtype=("float", "int"), finite=True)
    sh.n_bands(L.shape[0])
    return L


def shade(transfer: np.ndarray, coeffs: np.ndarray, albedo, *, out: np.ndarray | None = None) -> np.ndarray:
    """Diffuse PRT shading: outgoing radiance = (albedo / π) Σ_k L_k T_k per vertex.

    Args:
        transfer: (V, m²) float transfer vectors (float32 C-contiguous is the fast path; a column
            slice such as ``transfer[:, :16]`` works too).
        coeffs: (n², 3) linear RGB SH radiance coefficients, finite.
        albedo: (3,) linear RGB or a scalar, in [0, 1e6] (1 is white; larger values only scale).
        out: optional (V, 3) float32 C-contiguous array to write into.

    Returns:
        (V, 3) float32 linear radiance. ``transfer`` is not checked for NaN (it is the cached PRT, a
        (V, m²) read per frame): a vertex with a NaN transfer gets NaN radiance, only that vertex. Only the first min(m², n²) coefficients are used, so a 5-band
        transfer shades with 3-band lighting (and vice versa) as a truncation to the smaller band count.

    Example:
        >>> T = unoccluded_transfer(np.array([[0.0, 0.0, 1.0]]), 3).astype(np.float32)
        >>> L = np.zeros((9, 3)); L[0] = 2.0 * math.sqrt(4 * math.pi)   # uniform radiance 2
        >>> shade(T, L, 0.5).round(5)   # a white furnace: albedo × radiance
        array([[1., 1., 1.]], dtype=float32)
    """
    T = check_array(transfer, "transfer", shape=("V", "K"), dtype="float")
    if T.shape[1] < 1 or math.isqrt(T.shape[1]) ** 2 != T.shape[1]:
        raise ShapeError(f"transfer: expected n² columns (1, 4, 9, 16, 25, ...), got {T.shape[1]}")
    L = _coeffs(coeffs)
    a = check_array(albedo, "albedo", dtype=("float", "int"), finite=True)
    if a.shape not in ((), (3,)):
        raise ShapeError(f"albedo: expected shape () or (3,), got {a.shape}")
    check_range(a, "albedo", 0.0, 1e6)
    K = min(T.shape[1], L.shape[0])
    if T.dtype != np.float32:
        T = T.astype(np.float32)
    if out is None:
        out = np.empty((T.shape[0], 3), np.float32)
    else:
        check_array(out, "out", shape=(T.shape[0], 3), dtype=np.float32)
        if not out.flags.writeable:
            raise InvalidInputError("out: expected a writable array, got a read-only one")
    # A single-threaded kernel, not BLAS: a (V, 25) × (25, 3) product is too small for threads, and
    # on a busy machine BLAS's thread wake-ups cost many times the product (benchmarks/bench_prt.py
    # times both). The weights L_k · albedo / π are formed inside the compiled call too, not as numpy
    # temporaries, whose allocations would cost a good part of the product.
    if L.dtype in _FLOATS and a.dtype in _FLOATS:
        kernels.shade(T, L, np.broadcast_to(a, (3,)), a.dtype.type(math.pi), K, out)
    else:  # integer coefficients or albedo: numpy's promotion rules decide the weights' rounding
        weights = (L[:K] * (np.broadcast_to(a, (3,)) / math.pi)).astype(np.float32)
        kernels.shade_with_weights(T, np.ascontiguousarray(weights.T), K, out)
    return out


_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))


def shadow_alpha(plane: ShadowPlane, coeffs: np.ndarray) -> np.ndarray:
    """Shadow opacity of each plane vertex: alpha = clip(1 − E_with / E_without, 0, 1).

    E is the luminance (:data:`LUMINANCE_WEIGHTS`) of the irradiance Σ_k L_k T_k with the first
    min(plane bands², n²) coefficients. Where E_without ≤ 1e-6 · π · L̄ (L̄ the environment's mean
    luminance, |L_00| Y_00, with an absolute floor of 1e-12) the ratio means nothing (no light from
    above, or SH ringing below zero) and alpha is 0.

    One single-threaded pass (float32 sums of float32 transfer × float32 luminance weights): for a
    product this small, a BLAS call's overhead would dominate. Its sums associate differently, so
    alpha differs from a BLAS or float64 product by float32 rounding (≤ 1e-6;
    :func:`rgbd_envmap.reference.prt.shadow_alpha` is the float64 statement).

    Args:
        plane: :class:`ShadowPlane`. coeffs: (n², 3) finite SH radiance coefficients.

    Returns:
        (P,) float32 in [0, 1].
    """
    if not isinstance(plane, ShadowPlane):
        raise DTypeError(f"plane: expected a ShadowPlane, got {type(plane).__name__}")
    L = _coeffs(coeffs)
    return kernels.shadow_alpha(plane.transfer_with, plane.transfer_without, L.astype(np.float64, copy=False),
                                LUMINANCE_WEIGHTS, _ALPHA_TINY)
