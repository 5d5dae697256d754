"""Tests for rgbd_envmap.prt: transfer vectors with self-visibility, shading, shadow plane, cache.

Independent references:
    - Unoccluded transfer of a normal +z: T_l0 = 2π √((2l+1)/4π) ∫_0^1 P_l(μ) μ dμ (scipy quad and
      eval_legendre), m ≠ 0 zero; any other normal by brute-force quadrature on a fine equirect grid.
    - A point at the bottom of an open tube of radius r and depth h sees a cone of half-angle
      α = atan(r / h): T_l0 = 2π √((2l+1)/4π) ∫_cos α^1 P_l(μ) μ dμ, m ≠ 0 zero by symmetry.
    - Shading against ``sh.irradiance`` (a separate implementation of E = Σ Â_l L_lm Y_lm).
    - rgbd_envmap.reference.prt: the quadrature's rays and weights and the shading weights (exact),
      shading and the shadow alpha in float64 (float32 rounding: 1e-5).

Tolerances (measured, see docs/design/prt.md):
    - the occluded-part estimator on a convex mesh is exact up to float32: 1e-6.
    - the direct estimator with 1024 directions on a convex mesh: max |ΔT| 5.6e-4 → 2e-3.
    - the tube with 65,536 directions: max |ΔT| 8.3e-4 → 2e-3 (256-sided tube: the cap is 1.5e-4 off).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.integrate import quad
from scipy.special import eval_legendre

from rgbd_envmap import assets, prt, sh
from rgbd_envmap._kernels import prt as prt_kernels
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    ShapeError,
    UnknownMethodError,
)
from rgbd_envmap.reference import prt as prt_ref

EMPTY = np.zeros((0, 3), np.int32)
UP = np.array([[0.0, 0.0, 1.0]])


# --- references and fixtures --------------------------------------------------------------------------

def zonal_cap_transfer(bands: int, cos_alpha: float) -> np.ndarray:
    """Transfer of normal +z seeing only the cap θ < α (cos_alpha = 0: the whole hemisphere)."""
    out = np.zeros(bands * bands)
    for l in range(bands):
        norm = math.sqrt((2 * l + 1) / (4 * math.pi))
        out[l * (l + 1)] = 2 * math.pi * norm * quad(lambda mu, l=l: eval_legendre(l, mu) * mu, cos_alpha, 1.0)[0]
    return out


def open_tube(radius: float, depth: float, segments: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """The wall of an open cylinder from z = 0 to z = depth (no caps)."""
    a = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    v = np.concatenate([np.c_[ring, np.zeros(segments)], np.c_[ring, np.full(segments, depth)]])
    i = np.arange(segments)
    j = (i + 1) % segments
    f = np.concatenate([np.stack([i, j, segments + j], 1), np.stack([i, segments + j, segments + i], 1)])
    return v, f


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(2)
    return assets.object_from_mesh(s.vertices, s.faces, height_m=0.1, name="sphere")


@pytest.fixture(scope="module")
def blob():
    return assets.make_blob(3)


@pytest.fixture(scope="module")
def blob_transfer(blob):
    return prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 5, n_dirs=512)


# --- closed forms ---------------------------------------------------------------------------------------

def test_unoccluded_transfer_of_up_normal_matches_legendre_integrals():
    np.testing.assert_allclose(prt.unoccluded_transfer(UP, 7)[0], zonal_cap_transfer(7, 0.0), atol=1e-12)


def test_unoccluded_transfer_matches_brute_force_quadrature():
    H, W = 200, 400  # midpoint rule on the equirect grid: max error 3.9e-5 here
    theta = np.pi * (np.arange(H) + 0.5) / H
    phi = 2 * np.pi * (np.arange(W) + 0.5) / W - np.pi
    d = np.stack(np.broadcast_arrays(np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                                     np.cos(theta)[:, None]), axis=-1).reshape(-1, 3)
    omega = np.repeat((2 * np.pi / W) * (np.cos(np.pi * np.arange(H) / H) - np.cos(np.pi * np.arange(1, H + 1) / H)), W)
    Y = sh.basis(d, 4)
    normals = np.array([[0.3, -0.5, 0.8], [-1.0, 0.2, -0.1]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    brute = (np.maximum(normals @ d.T, 0.0) * omega) @ Y
    np.testing.assert_allclose(prt.unoccluded_transfer(normals, 4), brute, atol=1e-4)


def test_sphere_directions_are_unit_deterministic_and_equal_area():
    d = prt.sphere_directions(2048, seed=3)
    assert d.shape == (2048, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(d, prt.sphere_directions(2048, seed=3))
    assert not np.allclose(d, prt.sphere_directions(2048, seed=4))
    # Equal weights integrate the low-order SH to their exact values (√(4π) for Y_00, else 0).
    integ = sh.basis(d, 4).sum(axis=0) * (4 * np.pi / len(d))
    np.testing.assert_allclose(integ, np.r_[math.sqrt(4 * math.pi), np.zeros(15)], atol=2e-3)


def test_convex_mesh_occluded_estimator_is_exact(sphere):
    T = prt.compute_transfer(sphere.vertices, sphere.normals, sphere.faces, 5, n_dirs=256)
    np.testing.assert_allclose(T, prt.unoccluded_transfer(sphere.normals, 5), atol=1e-6)


def test_convex_mesh_direct_estimator_within_quadrature_error(sphere):
    T = prt.compute_transfer(sphere.vertices, sphere.normals, sphere.faces, 5, n_dirs=1024, estimator="direct")
    err = np.abs(T - prt.unoccluded_transfer(sphere.normals, 5))
    assert err.max() < 2e-3
    assert err.max() > 1e-6  # it is a quadrature, not the closed form


@pytest.mark.parametrize("estimator", prt.ESTIMATORS)
def test_bottom_of_tube_sees_a_cone(estimator):
    r, depth = 0.05, 0.1
    T = prt.compute_transfer(np.zeros((1, 3)), UP, EMPTY, 5, n_dirs=65536, occluder_meshes=[open_tube(r, depth)],
                             estimator=estimator)[0]
    ref = zonal_cap_transfer(5, math.cos(math.atan(r / depth)))
    np.testing.assert_allclose(T, ref, atol=2e-3)
    assert abs(T[0] - ref[0]) / ref[0] < 3e-3
    assert T[0] < 0.25 * prt.unoccluded_transfer(UP, 1)[0, 0]  # the occluded vertex sees much less


def test_point_under_a_box_lid_is_darker():
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.02))
    box.apply_translation((0, 0, 0.06))
    pts = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])  # the second sees the box 0.2 m wide 5 m away
    T = prt.compute_transfer(pts, np.repeat(UP, 2, 0), EMPTY, 3, n_dirs=4096, occluder_meshes=[box])
    free = prt.unoccluded_transfer(UP, 3)[0, 0]
    # Under the lid (half-width 0.1 m, 5 cm up) only directions below 27° elevation get through:
    # T_00 = π Y_00 (1 − sin² 63°) in the limit of an infinitely wide lid, about 0.21 π Y_00 here.
    assert T[0, 0] < 0.3 * free
    np.testing.assert_allclose(T[1], prt.unoccluded_transfer(UP, 3)[0], atol=2e-3)


def test_self_shadowing_only_removes_light(blob, blob_transfer):
    free = prt.unoccluded_transfer(blob.normals, 5)[:, 0]
    assert np.all(blob_transfer[:, 0] <= free + 1e-6)
    assert np.mean(blob_transfer[:, 0] < 0.95 * free) > 0.05  # the blob has concavities
    assert np.mean(np.isclose(blob_transfer[:, 0], free, atol=1e-6)) > 0.15  # and open parts (exact)


def test_estimators_agree_on_an_occluded_mesh(blob, blob_transfer):
    direct = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 5, n_dirs=512, estimator="direct")
    scale = np.sqrt((blob_transfer ** 2).sum(1).mean())
    assert np.sqrt(((direct - blob_transfer) ** 2).sum(1).mean()) / scale < 0.01


def test_more_directions_converge(blob):
    v, n = blob.vertices[::7], blob.normals[::7]
    ref = prt.compute_transfer(v, n, EMPTY, 3, n_dirs=16384, occluder_meshes=[blob], seed=11)
    errs = [np.sqrt(((prt.compute_transfer(v, n, EMPTY, 3, n_dirs=nd, occluder_meshes=[blob]) - ref) ** 2).mean())
            for nd in (64, 1024)]
    assert errs[1] < 0.5 * errs[0]


def test_deterministic_and_chunking_invariant(blob, blob_transfer, monkeypatch):
    again = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 5, n_dirs=512)
    np.testing.assert_array_equal(again, blob_transfer)
    monkeypatch.setattr(prt, "_CHUNK_ENTRIES", 3000)
    chunked = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 5, n_dirs=512)
    np.testing.assert_allclose(chunked, blob_transfer, atol=1e-6)


def test_fewer_bands_are_the_leading_columns(blob, blob_transfer):
    T3 = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 3, n_dirs=512)
    np.testing.assert_allclose(T3, blob_transfer[:, :9], atol=1e-6)


def test_translation_invariant(blob, blob_transfer):
    moved = prt.compute_transfer(blob.vertices + np.float32([1.0, -2.0, 0.5]), blob.normals, blob.faces, 5,
                                 n_dirs=512, offset_m=2e-6)
    assert np.abs(moved - blob_transfer).max() < 0.02  # float32 positions far from the origin: a few rays flip


def test_self_occlusion_off_gives_closed_form(blob):
    T = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 3, n_dirs=64, self_occlusion=False)
    np.testing.assert_allclose(T, prt.unoccluded_transfer(blob.normals, 3), atol=1e-6)


# --- hard cases -----------------------------------------------------------------------------------------

def test_empty_vertices_give_empty_transfer():
    out = prt.compute_transfer(np.zeros((0, 3)), np.zeros((0, 3)), EMPTY, 4)
    assert out.shape == (0, 16) and out.dtype == np.float32


def test_bands_one_and_tiny_n_dirs(blob):
    T = prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 1, n_dirs=1)
    assert T.shape == (len(blob.vertices), 1) and np.isfinite(T).all()
    T = prt.compute_transfer(UP * 0, UP, EMPTY, 1, n_dirs=1, estimator="direct")
    assert np.isfinite(T).all()


def test_invalid_inputs(blob):
    v, n, f = blob.vertices, blob.normals, blob.faces
    bad_v = v.copy()
    bad_v[3, 1] = np.nan
    with pytest.raises(NonFiniteError, match="vertices"):
        prt.compute_transfer(bad_v, n, f)
    zero_n = n.copy()
    zero_n[5] = 0.0
    with pytest.raises(InvalidInputError, match="normals.*1 zero"):
        prt.compute_transfer(v, zero_n, f)
    with pytest.raises(ShapeError, match="normals"):
        prt.compute_transfer(v, n[:-1], f)
    with pytest.raises(RangeError, match="faces"):
        prt.compute_transfer(v, n, f + len(v))
    with pytest.raises(RangeError, match="bands"):
        prt.compute_transfer(v, n, f, 0)
    with pytest.raises(RangeError, match="n_dirs"):
        prt.compute_transfer(v, n, f, n_dirs=0)
    with pytest.raises(UnknownMethodError, match="estimator"):
        prt.compute_transfer(v, n, f, estimator="mc")
    with pytest.raises(DTypeError, match="occluder_meshes"):
        prt.compute_transfer(v, n, f, occluder_meshes=[42])
    with pytest.raises(RangeError, match="offset_m"):
        prt.compute_transfer(v, n, f, offset_m=-1.0)


# --- shading --------------------------------------------------------------------------------------------

def test_white_furnace():
    normals = np.random.default_rng(0).normal(size=(50, 3))
    T = prt.unoccluded_transfer(normals, 5).astype(np.float32)
    L = np.zeros((25, 3))
    L[0] = np.array([1.0, 2.0, 3.0]) * math.sqrt(4 * math.pi)  # uniform radiance (1, 2, 3)
    out = prt.shade(T, L, [0.5, 0.25, 1.0])
    assert out.dtype == np.float32 and out.shape == (50, 3)
    np.testing.assert_allclose(out, np.tile([0.5, 0.5, 3.0], (50, 1)), rtol=1e-5)


def test_unoccluded_shading_matches_sh_irradiance():
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(100, 3))
    L = rng.normal(size=(25, 3))
    T = prt.unoccluded_transfer(normals, 5)
    albedo = np.array([0.2, 0.5, 0.8])
    np.testing.assert_allclose(prt.shade(T, L, albedo), albedo / math.pi * sh.irradiance(L, normals),
                               rtol=1e-4, atol=1e-5)


def test_shade_uses_the_smaller_band_count(blob_transfer):
    rng = np.random.default_rng(2)
    L9, L36 = rng.normal(size=(9, 3)), rng.normal(size=(36, 3))
    np.testing.assert_allclose(prt.shade(blob_transfer, L9, 1.0), blob_transfer[:, :9] @ L9 / math.pi,
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(prt.shade(blob_transfer, L36, 1.0), blob_transfer @ L36[:25] / math.pi,
                               rtol=1e-4, atol=1e-5)
    # Column slices and float64 transfers take the same path (up to float32 summation order: the
    # kernel vectorises a contiguous row and a strided slice differently).
    np.testing.assert_allclose(prt.shade(blob_transfer[:, :9], L36, 1.0), prt.shade(blob_transfer, L36[:9], 1.0),
                               rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(prt.shade(blob_transfer.astype(np.float64), L9, 1.0),
                               prt.shade(blob_transfer, L9, 1.0), rtol=1e-6)


@pytest.mark.parametrize("coeff_dtype", [np.float64, np.float32])
@pytest.mark.parametrize("albedo", [np.array([0.6, 0.6, 0.6], np.float32), np.array([0.2, 0.5, 0.9]), 0.7,
                                    np.float32(0.3)])
def test_shade_weights_round_as_numpy_does(blob_transfer, coeff_dtype, albedo):
    # The weights L_k · albedo / π are formed inside the kernel call; they must round exactly as the
    # numpy expression does (a float32 albedo is divided by π in float32, as numpy's promotion does).
    L = np.random.default_rng(2).normal(size=(25, 3)).astype(coeff_dtype)
    weights = prt_ref.shade_weights(L, albedo, 25)
    numpy_weights = (L * (np.broadcast_to(np.asarray(albedo), (3,)) / math.pi)).astype(np.float32)
    np.testing.assert_array_equal(weights, numpy_weights)
    a = np.asarray(albedo)
    np.testing.assert_array_equal(prt_kernels.shade_weights(L, np.broadcast_to(a, (3,)), a.dtype.type(math.pi), 25),
                                  weights.T)
    expected = np.empty((len(blob_transfer), 3), np.float32)
    prt_kernels.shade_with_weights(blob_transfer, np.ascontiguousarray(weights.T), 25, expected)
    np.testing.assert_array_equal(prt.shade(blob_transfer, L, albedo), expected)


def test_shade_matches_the_float64_reference(blob_transfer):
    rng = np.random.default_rng(8)
    for L, albedo in ((rng.normal(size=(25, 3)), np.array([0.2, 0.5, 0.9])), (rng.normal(size=(9, 3)), 0.6),
                      (rng.normal(size=(36, 3)).astype(np.float32), np.float32(0.3))):
        ref = prt_ref.shade(blob_transfer, L, albedo)
        np.testing.assert_allclose(prt.shade(blob_transfer, L, albedo), ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_quadrature_rays_and_weights_match_the_reference(blob):
    """The rays cast per (vertex, direction) pair above the horizon and the weights taken from their
    hits, bit for bit (integer indices and copied float32 values)."""
    rng = np.random.default_rng(9)
    dirs = prt.sphere_directions(64, seed=1).astype(np.float32)
    origins = blob.vertices[:200] + np.float32(1e-5) * blob.normals[:200]
    cos = blob.normals[:200] @ dirs.T
    rays, flat = prt_kernels.upper_rays(origins, dirs, cos)
    want_rays, want_flat = prt_ref.upper_rays(origins, dirs, cos)
    np.testing.assert_array_equal(rays, want_rays)
    np.testing.assert_array_equal(flat, want_flat)
    hit = (rng.uniform(size=len(flat)) < 0.3).astype(np.uint8)
    for blocked_part in (True, False):
        np.testing.assert_array_equal(prt_kernels.blocked_weights(cos, flat, hit, blocked_part),
                                      prt_ref.blocked_weights(cos, flat, hit, blocked_part))


def test_shade_out_parameter_and_empty(blob_transfer):
    L = np.ones((25, 3))
    out = np.empty((len(blob_transfer), 3), np.float32)
    res = prt.shade(blob_transfer, L, 0.6, out=out)
    assert res is out
    np.testing.assert_allclose(out, prt.shade(blob_transfer, L, 0.6))
    assert prt.shade(np.zeros((0, 25), np.float32), L, 0.6).shape == (0, 3)


def test_shade_invalid_inputs(blob_transfer):
    L = np.ones((25, 3))
    with pytest.raises(ShapeError, match="transfer"):
        prt.shade(blob_transfer[:, :10], L, 0.5)
    with pytest.raises(ShapeError, match="coeffs"):
        prt.shade(blob_transfer, np.ones((24, 3)), 0.5)
    with pytest.raises(NonFiniteError, match="coeffs"):
        prt.shade(blob_transfer, np.full((25, 3), np.nan), 0.5)
    with pytest.raises(ShapeError, match="albedo"):
        prt.shade(blob_transfer, L, [0.5, 0.5])
    with pytest.raises(NonFiniteError, match="albedo"):
        prt.shade(blob_transfer, L, np.nan)
    with pytest.raises(DTypeError, match="transfer"):
        prt.shade(blob_transfer.astype(np.int32), L, 0.5)


# --- shadow plane ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def plane(blob):
    return prt.shadow_plane(blob, size_m=0.6, resolution=25, bands=5, n_dirs=1024, use_cache=False)


def light_from_above() -> np.ndarray:
    """SH coefficients (5 bands) of radiance 1 in the cap within 30° of +z, 0 elsewhere."""
    H, W = 180, 360
    theta = np.pi * (np.arange(H) + 0.5) / H
    rad = np.zeros((H, W, 3), np.float32)
    rad[theta < np.radians(30)] = 1.0
    return sh.project_equirect(rad, bands=5)


def test_plane_geometry(plane):
    assert plane.vertices.shape == (625, 3) and plane.faces.shape == (2 * 24 * 24, 3)
    assert np.all(plane.vertices[:, 2] == 0)
    np.testing.assert_allclose(plane.vertices[:, :2].min(0), -0.3, atol=1e-7)
    v = plane.vertices[plane.faces]
    normal_z = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]
    assert np.all(normal_z > 0)  # counter-clockwise seen from +z
    with pytest.raises(ValueError):
        plane.vertices[0, 0] = 1.0


def test_plane_without_is_closed_form_and_agrees_with_quadrature(plane):
    np.testing.assert_allclose(plane.transfer_without, np.repeat(prt.unoccluded_transfer(UP, 5), 625, 0), atol=1e-6)
    direct = prt.compute_transfer(plane.vertices, np.repeat(UP, 625, 0), EMPTY, 5, n_dirs=4096, estimator="direct")
    np.testing.assert_allclose(direct, plane.transfer_without, atol=5e-4)


@pytest.mark.parametrize("lighting", ["uniform", "above"])
def test_alpha_far_is_zero_and_under_is_one(plane, blob, lighting):
    if lighting == "uniform":
        L = np.zeros((25, 3))
        L[0] = math.sqrt(4 * math.pi)
    else:
        L = light_from_above()
    alpha = prt.shadow_alpha(plane, L)
    assert alpha.shape == (625,) and alpha.dtype == np.float32
    assert alpha.min() >= 0 and alpha.max() <= 1
    r = np.linalg.norm(plane.vertices[:, :2], axis=1)
    corner = np.argmax(r)
    assert alpha[corner] < 0.05
    centre = np.argmin(r)  # inside the blob's base
    assert alpha[centre] > 0.95


def test_alpha_without_light_is_zero(plane):
    assert np.all(prt.shadow_alpha(plane, np.zeros((25, 3))) == 0)
    # Light only from below the plane: E_without ≤ 0 → alpha 0, not a division by ~0.
    L = np.zeros((4, 3))
    L[0] = 1.0
    L[2] = -2.0  # Y_10 ∝ z: radiance negative above, positive below
    assert np.all(prt.shadow_alpha(plane, L) == 0)


def test_alpha_matches_a_float64_reference(plane):
    # One float32 pass instead of two BLAS products: the same values up to float32 rounding.
    rng = np.random.default_rng(12)
    for n in (1, 4, 9, 25, 36):
        L = rng.normal(size=(n, 3))
        L[0] = np.abs(L[0]) + 1.0
        ref = prt_ref.shadow_alpha(plane.transfer_with, plane.transfer_without, L)
        np.testing.assert_allclose(prt.shadow_alpha(plane, L), ref, rtol=0, atol=1e-5)


def test_shadow_plane_invalid(blob):
    with pytest.raises(RangeError, match="resolution"):
        prt.shadow_plane(blob, resolution=1, use_cache=False)
    with pytest.raises(RangeError, match="size_m"):
        prt.shadow_plane(blob, size_m=-1, use_cache=False)
    with pytest.raises(DTypeError, match="obj"):
        prt.shadow_plane((blob.vertices, blob.faces), use_cache=False)
    with pytest.raises(DTypeError, match="plane"):
        prt.shadow_alpha(None, np.ones((25, 3)))


# --- cache ----------------------------------------------------------------------------------------------

def test_load_or_compute_caches(blob, tmp_path, monkeypatch):
    T = prt.load_or_compute(blob, 3, n_dirs=128, cache_dir=tmp_path)
    path = prt.transfer_cache_path(blob, 3, n_dirs=128, cache_dir=tmp_path)
    assert path.is_file() and path.parent == tmp_path / "prt"
    np.testing.assert_array_equal(T, prt.compute_transfer(blob.vertices, blob.normals, blob.faces, 3, n_dirs=128))

    def boom(*a, **k):
        raise AssertionError("recomputed")

    monkeypatch.setattr(prt, "compute_transfer", boom)
    hit = prt.load_or_compute(blob, 3, n_dirs=128, cache_dir=tmp_path)
    np.testing.assert_array_equal(hit, T)
    assert not hit.flags.writeable
    for changed in ({"n_dirs": 64}, {"seed": 1}, {"estimator": "direct"}):
        args = {"n_dirs": 128, **changed}
        assert prt.transfer_cache_path(blob, 3, cache_dir=tmp_path, **args) != path
        with pytest.raises(AssertionError, match="recomputed"):
            prt.load_or_compute(blob, 3, cache_dir=tmp_path, **args)
    with pytest.raises(AssertionError, match="recomputed"):
        prt.load_or_compute(blob, 4, n_dirs=128, cache_dir=tmp_path)


def test_cache_key_follows_the_mesh(blob, tmp_path):
    moved = assets.VirtualObject(vertices=blob.vertices * 1.01, faces=blob.faces, normals=blob.normals,
                                 albedo=blob.albedo, name=blob.name, source=blob.source)
    assert prt.transfer_cache_path(moved, cache_dir=tmp_path) != prt.transfer_cache_path(blob, cache_dir=tmp_path)
    grey = assets.VirtualObject(vertices=blob.vertices, faces=blob.faces, normals=blob.normals,
                                albedo=np.array([0.1, 0.2, 0.3]), name=blob.name, source=blob.source)
    # The albedo does not enter the transfer, so it does not enter the key.
    assert prt.transfer_cache_path(grey, cache_dir=tmp_path) == prt.transfer_cache_path(blob, cache_dir=tmp_path)


def test_damaged_cache_file_is_recomputed(blob, tmp_path):
    path = prt.transfer_cache_path(blob, 2, n_dirs=64, cache_dir=tmp_path)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not an npz")
    T = prt.load_or_compute(blob, 2, n_dirs=64, cache_dir=tmp_path)
    assert T.shape == (len(blob.vertices), 4)
    with np.load(path) as z:
        np.testing.assert_array_equal(z["transfer"], T)


def test_cache_dir_from_environment_and_use_cache_false(blob, tmp_path, monkeypatch):
    monkeypatch.setenv("RGBD_ENVMAP_CACHE", str(tmp_path / "env"))
    prt.load_or_compute(blob, 1, n_dirs=16, use_cache=False)
    assert not (tmp_path / "env").exists()
    prt.load_or_compute(blob, 1, n_dirs=16)
    assert len(list((tmp_path / "env" / "prt").glob("transfer_*.npz"))) == 1


def test_shadow_plane_cache(blob, plane, tmp_path, monkeypatch):
    first = prt.shadow_plane(blob, size_m=0.6, resolution=25, n_dirs=1024, cache_dir=tmp_path)
    np.testing.assert_array_equal(first.transfer_with, plane.transfer_with)
    monkeypatch.setattr(prt, "compute_transfer", lambda *a, **k: (_ for _ in ()).throw(AssertionError("again")))
    second = prt.shadow_plane(blob, size_m=0.6, resolution=25, n_dirs=1024, cache_dir=tmp_path)
    np.testing.assert_array_equal(second.transfer_with, first.transfer_with)
    with pytest.raises(AssertionError, match="again"):
        prt.shadow_plane(blob, size_m=0.5, resolution=25, n_dirs=1024, cache_dir=tmp_path)
