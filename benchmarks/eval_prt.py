"""PRT shading of the virtual object against a Monte Carlo reference with visibility (paper 003 §7.1;
docs/design/overview.md, stage 9).

    python benchmarks/eval_prt.py [--object bunny] [--n-vertices 600] [--ref-rays 16384] [--n-dirs 1024]
                                  [--em-height 1000] [--no-precompute-timing] [--figures] [--json PATH]

Lighting: the complete ground-truth EM of the default scene ("office", origin (0, 0, 0.80), t = 0,
2000×1000), projected with ``sh.project_equirect`` to 8 bands; n-band shading uses the first n²
coefficients and the first n² transfer columns (``prt.shade``).

Reference per vertex, independent of the SH path: (albedo / π) ∫ V(ω) max(n·ω, 0) L(ω) dω by cosine-
weighted Monte Carlo: ``--ref-rays`` rays per vertex, stratified (a √M × √M jittered grid mapped to
the disk by Shirley–Chiu's concentric map and lifted to the hemisphere), a random rotation about the
normal per vertex, visibility by open3d ray casting against the object, L(ω) the EM pixel containing
ω (nearest, via ``geometry.equirect_pixel_index``). The same without visibility gives the reference of
the unshadowed case. Two references with different seeds estimate the reference's own noise.

Error: relative RMSE = ‖shaded − reference‖₂ / ‖reference‖₂ over the vertex subset and RGB. Columns:
the PRT shading (n_dirs of the pipeline and 16× more, which separates quadrature noise), and the
unshadowed SH irradiance against the unshadowed reference (SH truncation alone). The shadow plane:
alpha from ``prt.shadow_alpha`` against 1 − E_with / E_without from the same Monte Carlo.

Timing: transfer precompute of the whole object per band count (one run each; the ray casting does not
depend on the band count), ``prt.shade`` of the whole object (median / p95 of 200), the cached load
(miss and hit). BLAS is held to one thread; open3d's ray casting uses both cores.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import open3d as o3d

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from benchmarks.common import time_it
from rgbd_envmap import assets, prt, sh
from rgbd_envmap.geometry import equirect_pixel_index
from sim.groundtruth import render_envmap
from sim.raycast import SceneRaycaster
from sim.scene import load_scene

ORIGIN = (0.0, 0.0, 0.80)
MAX_BANDS = 8


# --- the independent Monte Carlo reference ------------------------------------------------------------

def concentric_disk(u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley & Chiu 1997: [0, 1)² → unit disk, area preserving."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    first = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(first, a, b)
        phi = np.where(first, (math.pi / 4) * (b / a), math.pi / 2 - (math.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def cosine_samples(n_vertices: int, m: int, rng: np.random.Generator) -> np.ndarray:
    """(n_vertices, m², 3) jittered-stratified cosine-weighted directions in the local frame (z = normal)."""
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    u1 = (i.ravel()[None] + rng.random((n_vertices, m * m))) / m
    u2 = (j.ravel()[None] + rng.random((n_vertices, m * m))) / m
    x, y = concentric_disk(u1, u2)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], axis=-1)


def tangent_frames(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(V, 3, 3) rotations whose third column is the normal, randomly spun about it."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(helper, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    ang = rng.uniform(0, 2 * math.pi, len(n))[:, None]
    t, b = np.cos(ang) * t + np.sin(ang) * b, -np.sin(ang) * t + np.cos(ang) * b
    return np.stack([t, b, n], axis=-1)


def mc_irradiance(points, normals, radiance, occluders, *, rays: int, seed: int, offset_m: float,
                  chunk_rays: int = 1 << 20) -> np.ndarray:
    """(V, 3) float64 E = ∫ V max(n·ω, 0) L dω (π × the mean of V·L over cosine samples); ``occluders``
    a list of (vertices, faces) or empty for no visibility."""
    H, W = radiance.shape[:2]
    m = round(math.sqrt(rays))
    rng = np.random.default_rng(seed)
    scene = None
    if occluders:
        scene = o3d.t.geometry.RaycastingScene()
        for v, f in occluders:
            scene.add_triangles(o3d.core.Tensor(np.asarray(v, np.float32)), o3d.core.Tensor(np.asarray(f, np.uint32)))
    out = np.zeros((len(points), 3))
    step = max(1, chunk_rays // (m * m))
    for s in range(0, len(points), step):
        e = min(len(points), s + step)
        R = tangent_frames(normals[s:e].astype(np.float64), rng)
        local = cosine_samples(e - s, m, rng)
        dirs = np.einsum("vij,vsj->vsi", R, local)
        rows, cols, _ = equirect_pixel_index(dirs, H, W)
        L = radiance[rows, cols].astype(np.float64)
        if scene is not None:
            org = np.repeat(points[s:e] + offset_m * normals[s:e], m * m, axis=0)
            r = np.concatenate([org, dirs.reshape(-1, 3)], axis=1).astype(np.float32)
            vis = ~scene.test_occlusions(o3d.core.Tensor(r)).numpy().astype(bool)
            L *= vis.reshape(e - s, m * m, 1)
        out[s:e] = math.pi * L.mean(axis=1)
    return out


def rel_rmse(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(((a - ref) ** 2).sum() / (ref ** 2).sum()))


# --- figures --------------------------------------------------------------------------------------------

def draw_mesh(ax, vertices, faces, colours, azim_deg=-60.0, elev_deg=20.0, alpha=None, cmap=None):
    """Painter's-algorithm orthographic render of a mesh with per-vertex linear colours (shown sRGB
    encoded), or per-vertex scalars in [0, 1] through ``cmap``."""
    from matplotlib.collections import PolyCollection

    from rgbd_envmap.colour import linear_to_srgb

    az, el = math.radians(azim_deg), math.radians(elev_deg)
    right = np.array([-math.sin(az), math.cos(az), 0.0])
    fwd = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])  # towards viewer
    up = np.cross(fwd, right)
    p2 = np.stack([vertices @ right, vertices @ up], axis=1)
    depth = (vertices @ fwd)[faces].mean(axis=1)
    facing = np.einsum("fi,i->f", np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                           vertices[faces[:, 2]] - vertices[faces[:, 0]]), fwd) > 0
    order = np.argsort(depth)
    order = order[facing[order]] if alpha is None else order
    if cmap is not None:
        import matplotlib

        cols = matplotlib.colormaps[cmap](np.clip(colours[faces[order]].mean(axis=1), 0, 1))[:, :3]
    else:
        cols = np.clip(linear_to_srgb(np.clip(colours[faces[order]].mean(axis=1), 0, 1)), 0, 1)
    if alpha is not None:
        cols = np.concatenate([cols, alpha[faces[order]].mean(axis=1, keepdims=True)], axis=1)
    pc = PolyCollection(p2[faces[order]], facecolors=cols, edgecolors="none", antialiased=False)
    ax.add_collection(pc)
    ax.set_xlim(p2[:, 0].min(), p2[:, 0].max())
    ax.set_ylim(p2[:, 1].min(), p2[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")


def make_figures(obj, transfer, coeffs, plane, rows, quad_rows, scatter, out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    # 1. the object: unshadowed SH irradiance, PRT (5 bands), their ratio (self-shadowing), plane alpha
    L5 = coeffs[:25]
    shaded = prt.shade(transfer[:, :25], L5, obj.albedo)
    unshadowed = prt.shade(prt.unoccluded_transfer(obj.normals, 5).astype(np.float32), L5, obj.albedo)
    scale = 0.8 / np.percentile(unshadowed.mean(axis=1), 99)
    ratio = np.clip(shaded.mean(axis=1) / np.maximum(unshadowed.mean(axis=1), 1e-9), 0, 1)
    alpha = prt.shadow_alpha(plane, L5)
    fig, axes = plt.subplots(1, 4, figsize=(16, 4.4))
    draw_mesh(axes[0], obj.vertices, obj.faces, unshadowed * scale)
    axes[0].set_title("SH irradiance, no visibility (5 bands)")
    draw_mesh(axes[1], obj.vertices, obj.faces, shaded * scale)
    axes[1].set_title("PRT with self-shadowing (5 bands)")
    draw_mesh(axes[2], obj.vertices, obj.faces, ratio, cmap="magma")
    axes[2].set_title("self-shadowing: PRT / unshadowed")
    fig.colorbar(matplotlib.cm.ScalarMappable(cmap="magma", norm=matplotlib.colors.Normalize(0, 1)), ax=axes[2],
                 fraction=0.046)
    r = plane.resolution
    ext = plane.size_m / 2
    im = axes[3].imshow(alpha.reshape(r, r), origin="lower", extent=(-ext, ext, -ext, ext), cmap="gray_r",
                        vmin=0, vmax=1)
    from scipy.spatial import ConvexHull

    foot = obj.vertices[obj.vertices[:, 2] < 0.002, :2]
    axes[3].plot(foot[:, 0], foot[:, 1], ",", color="tab:red")
    hull = ConvexHull(obj.vertices[:, :2])
    loop = obj.vertices[np.r_[hull.vertices, hull.vertices[:1]], :2]
    axes[3].plot(loop[:, 0], loop[:, 1], "--", color="tab:blue", lw=0.8)
    axes[3].set_title("shadow-plane alpha (base red, outline blue)", fontsize=10)
    axes[3].set_xlabel("x (m)")
    axes[3].set_ylabel("y (m)")
    fig.colorbar(im, ax=axes[3], fraction=0.046)
    fig.tight_layout()
    p = out_dir / "prt_bunny.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    # 2. error against the Monte Carlo reference per band count, and the per-vertex scatter at 5 bands
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11.5, 4.2), gridspec_kw={"width_ratios": [1.4, 1]})
    b = [r["bands"] for r in rows]
    ax.semilogy(b, [100 * r["prt_rel_rmse"] for r in rows], "o-", label="PRT vs MC reference (with visibility)")
    ax.semilogy(b, [100 * r["prt_hi_rel_rmse"] for r in rows], "s--", label="PRT, 16× transfer directions")
    ax.semilogy(b, [100 * r["unshadowed_rel_rmse"] for r in rows], "^-", label="SH irradiance vs MC, no visibility")
    ax.axhline(100 * rows[0]["reference_noise"], color="grey", ls=":", label="reference noise")
    ax.axhline(3.0, color="tab:red", lw=0.8, label="3 % requirement")
    ax.set_xlabel("SH bands")
    ax.set_ylabel("relative RMSE (%)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    shaded5, reference = scatter
    lum = prt.LUMINANCE_WEIGHTS
    x, y = reference @ lum, shaded5 @ lum
    ax2.plot(x, y, ".", ms=3, alpha=0.6)
    lim = [0, 1.05 * max(x.max(), y.max())]
    ax2.plot(lim, lim, "k-", lw=0.8)
    ax2.set_xlim(lim)
    ax2.set_ylim(lim)
    ax2.set_aspect("equal")
    ax2.set_xlabel("Monte Carlo reference (luminance)")
    ax2.set_ylabel("PRT, 5 bands (luminance)")
    ax2.set_title(f"{len(x)} bunny vertices", fontsize=9)
    fig.tight_layout()
    p = out_dir / "prt_error_vs_bands.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    # 3. quadrature error against n_dirs
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    quad_rows = [q for q in quad_rows if "n_dirs" in q]
    nd = [q["n_dirs"] for q in quad_rows]
    ax.loglog(nd, [q["sphere_direct"] for q in quad_rows], "o-", label="sphere (no occlusion), direct")
    ax.loglog(nd, [q["bunny_direct"] for q in quad_rows], "s-", label="bunny, direct")
    ax.loglog(nd, [q["bunny_occluded"] for q in quad_rows], "^--", label="bunny, occluded-part estimator")
    ax.set_xlabel("n_dirs (directions on the sphere)")
    ax.set_ylabel("relative RMS error of T (5 bands)")
    ax.set_title("sphere: vs the closed form (the occluded-part estimator is exact there);\n"
                 "bunny: vs 65,536 directions", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    p = out_dir / "prt_quadrature.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def quadrature_study(obj, n_vertices: int, seed: int) -> list[dict]:
    """Relative RMS error of the transfer vectors (5 bands) against 65,536 directions."""
    import trimesh

    sphere = trimesh.creation.icosphere(3)
    s_obj = assets.object_from_mesh(sphere.vertices, sphere.faces, height_m=0.12)
    s_ref = prt.unoccluded_transfer(s_obj.normals, 5)
    rng = np.random.default_rng(seed)
    sub = rng.choice(len(obj.vertices), n_vertices, replace=False)
    v, n = obj.vertices[sub], obj.normals[sub]
    empty = np.zeros((0, 3), np.int32)
    ref = prt.compute_transfer(v, n, empty, 5, n_dirs=65536, occluder_meshes=[obj], seed=99)
    out = []
    for nd in (64, 256, 1024, 4096, 16384):
        s_dir = prt.compute_transfer(s_obj.vertices, s_obj.normals, s_obj.faces, 5, n_dirs=nd, estimator="direct")
        b_dir = prt.compute_transfer(v, n, empty, 5, n_dirs=nd, occluder_meshes=[obj], estimator="direct")
        b_occ = prt.compute_transfer(v, n, empty, 5, n_dirs=nd, occluder_meshes=[obj])
        out.append({"n_dirs": nd, "sphere_direct": rel_rmse(s_dir, s_ref), "bunny_direct": rel_rmse(b_dir, ref),
                    "bunny_occluded": rel_rmse(b_occ, ref)})
        print(f"  n_dirs {nd:>6}: sphere direct {out[-1]['sphere_direct']:.2e}  bunny direct "
              f"{out[-1]['bunny_direct']:.2e}  bunny occluded {out[-1]['bunny_occluded']:.2e}", flush=True)
    # The ray-origin offset: too small risks hitting the vertex's own faces, too large lifts the
    # origin out of creases. Same vertices, 1024 directions, offsets as fractions of the diagonal.
    diag = float(np.linalg.norm(obj.vertices.max(0) - obj.vertices.min(0)))
    for frac in (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2):
        T = prt.compute_transfer(v, n, empty, 5, n_dirs=1024, occluder_meshes=[obj], offset_m=frac * diag)
        out.append({"offset_fraction": frac, "rel_rmse": rel_rmse(T, ref),
                    "t00_mean_change": float(T[:, 0].mean() / ref[:, 0].mean() - 1)})
        print(f"  offset {frac:g} x diagonal ({1e6 * frac * diag:.3g} um): rel. RMS error of T "
              f"{out[-1]['rel_rmse']:.2e}, mean T_00 {100 * out[-1]['t00_mean_change']:+.2f} %", flush=True)
    return out


# --- main ---------------------------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="bunny", choices=assets.OBJECT_NAMES)
    parser.add_argument("--n-vertices", type=int, default=600)
    parser.add_argument("--ref-rays", type=int, default=16384)
    parser.add_argument("--n-dirs", type=int, default=1024)
    parser.add_argument("--em-height", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-precompute-timing", action="store_true")
    parser.add_argument("--figures", action="store_true", help="write docs/figures/prt_*.png")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    obj = assets.load_virtual_object(args.object)
    print(f"object: {obj}")
    H, W = args.em_height, 2 * args.em_height
    gt = render_envmap(SceneRaycaster(load_scene("office")), origin=ORIGIN, height=H, width=W, t_s=0.0)
    print(f"EM {W}x{H}: {100 * gt.valid.mean():.2f} % of pixels hit a surface")
    coeffs = sh.project_equirect(gt.radiance, gt.valid, bands=MAX_BANDS)
    albedo = obj.albedo.astype(np.float64)
    diag = float(np.linalg.norm(obj.vertices.max(0) - obj.vertices.min(0)))
    offset = prt.DEFAULT_OFFSET_FRACTION * diag
    result: dict = {"object": repr(obj), "em": [H, W], "n_dirs": args.n_dirs, "n_vertices": args.n_vertices,
                    "ref_rays": args.ref_rays}

    # Cache miss then hit (fresh directory), 5 bands.
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        transfer5 = prt.load_or_compute(obj, 5, n_dirs=args.n_dirs, cache_dir=tmp)
        miss = time.perf_counter() - t0
        t0 = time.perf_counter()
        again = prt.load_or_compute(obj, 5, n_dirs=args.n_dirs, cache_dir=tmp)
        hit = time.perf_counter() - t0
        assert np.array_equal(transfer5, again)
    result["cache"] = {"miss_s": miss, "hit_ms": 1e3 * hit}
    print(f"load_or_compute 5 bands, n_dirs {args.n_dirs}: miss {miss:.2f} s, hit {1e3 * hit:.1f} ms")

    precompute_s = {}
    if not args.no_precompute_timing:
        for b in range(1, MAX_BANDS + 1):
            t0 = time.perf_counter()
            prt.compute_transfer(obj.vertices, obj.normals, obj.faces, b, n_dirs=args.n_dirs)
            precompute_s[b] = time.perf_counter() - t0
            print(f"  precompute {b} bands: {precompute_s[b]:.2f} s", flush=True)
    transfer = prt.compute_transfer(obj.vertices, obj.normals, obj.faces, MAX_BANDS, n_dirs=args.n_dirs)

    rng = np.random.default_rng(args.seed)
    sub = np.sort(rng.choice(len(obj.vertices), args.n_vertices, replace=False))
    pts, nrm = obj.vertices[sub].astype(np.float64), obj.normals[sub].astype(np.float64)
    occ = [(obj.vertices, obj.faces)]
    t0 = time.perf_counter()
    ref = albedo / math.pi * mc_irradiance(pts, nrm, gt.radiance, occ, rays=args.ref_rays, seed=1, offset_m=offset)
    ref_b = albedo / math.pi * mc_irradiance(pts, nrm, gt.radiance, occ, rays=args.ref_rays, seed=2, offset_m=offset)
    ref_free = albedo / math.pi * mc_irradiance(pts, nrm, gt.radiance, [], rays=args.ref_rays, seed=3, offset_m=offset)
    print(f"Monte Carlo references: {time.perf_counter() - t0:.1f} s")
    # Two independent references: ‖a − b‖ / √2 estimates the noise of one.
    noise = rel_rmse(ref, ref_b) / math.sqrt(2)
    result["reference_noise"] = noise
    hi = prt.compute_transfer(pts, nrm, np.zeros((0, 3), np.int32), MAX_BANDS, n_dirs=16 * args.n_dirs,
                              occluder_meshes=[obj], seed=5)

    # Where the error sits: vertices grouped by how much of the cosine-weighted hemisphere is blocked.
    openness = transfer[sub, 0] / prt.unoccluded_transfer(nrm, 1)[:, 0]
    groups = {"open (T00 >= 0.95 of unoccluded)": openness >= 0.95,
              "partly occluded (0.8-0.95)": (openness >= 0.8) & (openness < 0.95),
              "occluded (< 0.8)": openness < 0.8}
    rows = []
    for b in range(1, MAX_BANDS + 1):
        K = b * b
        shaded = prt.shade(transfer[sub, :K], coeffs[:K], albedo).astype(np.float64)
        shaded_hi = prt.shade(hi[:, :K], coeffs[:K], albedo).astype(np.float64)
        free = albedo / math.pi * sh.irradiance(coeffs[:K], nrm)
        T_full, L_K = np.ascontiguousarray(transfer[:, :K]), coeffs[:K]
        t_shade = time_it(lambda T_full=T_full, L_K=L_K: prt.shade(T_full, L_K, albedo), 200)
        rows.append({
            "bands": b,
            "prt_rel_rmse": rel_rmse(shaded, ref),
            "prt_hi_rel_rmse": rel_rmse(shaded_hi, ref),
            "unshadowed_rel_rmse": rel_rmse(free, ref_free),
            "reference_noise": noise,
            "shade_median_ms": t_shade["median_ms"],
            "shade_p95_ms": t_shade["p95_ms"],
            "precompute_s": precompute_s.get(b),
            "by_occlusion": {name: [int(m.sum()), rel_rmse(shaded[m], ref[m])] for name, m in groups.items()},
        })
    result["rows"] = rows

    # Shadow plane: alpha against the Monte Carlo irradiance ratio on the plane (points near the object).
    plane = prt.shadow_plane(obj, size_m=0.5, resolution=48, bands=5, n_dirs=args.n_dirs, use_cache=False)
    alpha = prt.shadow_alpha(plane, coeffs[:25])
    near = np.flatnonzero(np.linalg.norm(plane.vertices[:, :2], axis=1) < 0.15)
    up = np.tile([0.0, 0.0, 1.0], (len(near), 1))
    pv = plane.vertices[near].astype(np.float64)
    e_with = mc_irradiance(pv, up, gt.radiance, occ, rays=args.ref_rays, seed=4, offset_m=offset)
    e_free = mc_irradiance(pv, up, gt.radiance, [], rays=args.ref_rays, seed=6, offset_m=offset)
    lum = prt.LUMINANCE_WEIGHTS
    alpha_ref = np.clip(1 - (e_with @ lum) / (e_free @ lum), 0, 1)
    far = np.linalg.norm(plane.vertices[:, :2], axis=1) > 0.2
    result["plane"] = {
        "alpha_mae": float(np.abs(alpha[near] - alpha_ref).mean()),
        "alpha_max_err": float(np.abs(alpha[near] - alpha_ref).max()),
        "alpha_max_ref": float(alpha_ref.max()),
        "alpha_far_max": float(alpha[far].max()),
        "n_points": len(near),
    }

    print()
    print(f"relative RMSE over {args.n_vertices} vertices × RGB, reference {args.ref_rays} rays/vertex "
          f"(noise {100 * noise:.2f} %), transfer n_dirs {args.n_dirs}")
    print("| bands | coeffs | PRT rel. RMSE | PRT, 16× dirs | unshadowed SH vs MC | precompute (s) | shade median / p95 (ms) |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        pre = f"{r['precompute_s']:.1f}" if r["precompute_s"] is not None else "–"
        print(f"| {r['bands']} | {r['bands'] ** 2} | {100 * r['prt_rel_rmse']:.2f} % | {100 * r['prt_hi_rel_rmse']:.2f} % "
              f"| {100 * r['unshadowed_rel_rmse']:.2f} % | {pre} | {r['shade_median_ms']:.3f} / {r['shade_p95_ms']:.3f} |")
    print("\nPRT error by occlusion of the vertex (relative RMSE within each group):")
    print("| bands | " + " | ".join(f"{k} [{rows[0]['by_occlusion'][k][0]} vertices]" for k in groups) + " |")
    print("|---:|" + "---:|" * len(groups))
    for r in rows:
        print(f"| {r['bands']} | " + " | ".join(f"{100 * r['by_occlusion'][k][1]:.2f} %" for k in groups) + " |")
    pl = result["plane"]
    print(f"\nshadow plane (48×48 on 0.5 m, 5 bands, {pl['n_points']} points within 15 cm): alpha MAE "
          f"{pl['alpha_mae']:.4f}, max |err| {pl['alpha_max_err']:.4f}, max alpha (MC) {pl['alpha_max_ref']:.3f}, "
          f"max alpha beyond 20 cm {pl['alpha_far_max']:.4f}")

    if args.figures:
        print("\nquadrature study (5 bands, 300 bunny vertices):")
        quad = quadrature_study(obj, 300, args.seed)
        result["quadrature"] = quad
        shaded5 = prt.shade(transfer[sub, :25], coeffs[:25], albedo).astype(np.float64)
        paths = make_figures(obj, transfer, coeffs, plane, rows, quad, (shaded5, ref), REPO / "docs" / "figures")
        print("wrote", ", ".join(str(p.relative_to(REPO)) for p in paths))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
