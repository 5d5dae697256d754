"""Time offscreen rasterisation and compositing (paper 003 §7.2; docs/design/overview.md, stage 10; paper Table 1
"Render frame" 20.7 ms; this project's target ≤ 15 ms median for rasterise + composite at 960×540).

    python benchmarks/bench_render.py [--repeats N] [--json PATH] [--backends numba,pyrender]

Scene: a 960×540 colour camera (78° horizontal field of view, like the simulator's), a deformed
icosphere about 12 cm across standing on a 0.5 m shadow-plane grid of 64×64 vertices (7,938 triangles),
seen from table distance (about 0.9 m; the inward orbit of the default capture) and close up (about
0.45 m). Objects: icosphere(subdivisions=5) (10,242 vertices, 20,480 triangles) and subdivisions=6
(40,962 vertices, 81,920 triangles), and the Stanford bunny (37,706 vertices, 75,408 triangles; 12 cm
tall) when rgbd_envmap.assets finds it (Debian's libcgal-demo). Each timed call moves the
camera to the next of 8 poses around the object and uploads new colours and alphas, as the pipeline
does per colour frame.

Rows per case and backend: ``render`` (Renderer.render: checks, bounds, rasterise, read back),
``composite`` (composite with a correction matrix), ``total`` (both, timed together). All rows of a
case are timed interleaved (one call of each per round), so they share the machine's load. Ablations:
``crop=False`` (whole frame cleared, rasterised and read back) and, for pyrender, its stock
OffscreenRenderer (4× MSAA RGBA8 framebuffer, full-frame colour + depth readback, colours fixed).
Everything runs on the CPU (Mesa llvmpipe for OpenGL, which uses its own worker threads; numba is
single-threaded).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"
# pyrender's stock renderer below imports OpenGL itself: a headless platform (as render.gl chooses it)
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap import geometry, render
from rgbd_envmap.types import Intrinsics

W, H = 960, 540
HFOV_DEG = 78.0
CENTRE = np.array([0.0, 0.0, 0.81])
PLANE_Z = 0.75
PLANE_SIZE_M = 0.5
PLANE_N = 64
N_POSES = 8


def intrinsics() -> Intrinsics:
    fx = (W / 2.0) / np.tan(np.radians(HFOV_DEG) / 2.0)
    return Intrinsics(W, H, fx, fx, (W - 1) / 2.0, (H - 1) / 2.0)


def deformed_icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lumpy ellipsoid (~14 × 10 × 12 cm) resting on the plane; smooth linear colours up to ~1.3."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    d = np.asarray(m.vertices)
    r = 1.0 + 0.12 * np.sin(5 * d[:, 0] + 1) * np.cos(4 * d[:, 1]) + 0.08 * np.sin(7 * d[:, 2])
    v = d * r[:, None] * np.array([0.07, 0.05, 0.06])
    v += CENTRE - [0.0, 0.0, v[:, 2].min() + CENTRE[2] - PLANE_Z]
    colours = (0.5 + 0.5 * d) * np.array([1.3, 0.9, 0.6]) * (0.6 + 0.4 * r[:, None])
    return v, np.asarray(m.faces), colours


def bunny() -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The Stanford bunny (12 cm tall, base on the plane) via rgbd_envmap.assets, or None when the mesh
    is not on this machine (Debian's libcgal-demo)."""
    try:
        from rgbd_envmap import assets

        obj = assets.load_virtual_object("bunny", fallback=None)
    except Exception as exc:  # noqa: BLE001 - optional case
        print(f"bunny case skipped: {exc}")
        return None
    v = np.asarray(obj.vertices, np.float64) + [CENTRE[0], CENTRE[1], PLANE_Z]
    n = np.asarray(obj.normals, np.float64)
    colours = (0.5 + 0.45 * n) * np.array([1.2, 0.9, 0.7])
    return v, np.asarray(obj.faces), colours


def plane_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    g = np.linspace(-PLANE_SIZE_M / 2, PLANE_SIZE_M / 2, PLANE_N)
    x, y = np.meshgrid(g, g)
    v = np.c_[x.ravel(), y.ravel(), np.full(x.size, PLANE_Z)]
    idx = np.arange(PLANE_N * PLANE_N).reshape(PLANE_N, PLANE_N)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    rho = np.hypot(x, y).ravel()
    alpha = 0.7 * np.exp(-((rho / 0.09) ** 2))  # a soft contact shadow
    return v, faces, alpha


def poses(distance_m: float) -> list:
    out = []
    for k in range(N_POSES):
        phi = 2 * np.pi * k / N_POSES + 0.3
        eye = CENTRE + distance_m * np.array([0.85 * np.cos(phi), 0.85 * np.sin(phi), 0.53])
        out.append(geometry.look_at(eye, CENTRE))
    return out


def stock_pyrender(intr, ov, of, oc, pv, pf, pa, cams):
    """pyrender's own OffscreenRenderer, for comparison: MSAA RGBA8, colour + depth readback."""
    import pyrender

    scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0))
    mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0), doubleSided=True)
    rgba = np.c_[np.clip(oc, 0, 1), np.ones(len(oc))]
    scene.add(pyrender.Mesh([pyrender.Primitive(positions=ov, indices=of, color_0=rgba, material=mat)]))
    prgba = np.c_[pa, np.zeros((len(pa), 2)), np.full(len(pa), 0.5)]
    scene.add(pyrender.Mesh([pyrender.Primitive(positions=pv, indices=pf, color_0=prgba, material=mat)]))
    cam = scene.add(pyrender.IntrinsicsCamera(intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5, znear=0.05, zfar=20.0))
    off = pyrender.OffscreenRenderer(W, H)
    flags = pyrender.RenderFlags.FLAT | pyrender.RenderFlags.RGBA | pyrender.RenderFlags.SKIP_CULL_FACES
    it = itertools.cycle(cams)

    def fn():
        scene.set_pose(cam, geometry.opengl_from_opencv(next(it)).matrix)
        return off.render(scene, flags)

    return off, fn


def stats(ms: list[float]) -> dict:
    """The same summary as benchmarks.common.time_it (median / p95 / min in ms)."""
    a = np.asarray(ms)
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "min_ms": float(a.min()),
            "n": len(a)}


def interleaved(fns: dict[str, object], repeats: int) -> dict[str, dict]:
    """Time every function once per round, round after round, so that all of them see the same load on
    a shared machine (one warm-up call each first)."""
    for fn in fns.values():
        fn()
    ms: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            ms[name].append((time.perf_counter() - t0) * 1e3)
    return {name: stats(v) for name, v in ms.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=40)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--backends", default="numba,pyrender")
    parser.add_argument("--no-ablations", action="store_true", help="skip crop=False and stock pyrender")
    args = parser.parse_args()
    backends = args.backends.split(",")
    intr = intrinsics()
    pv, pf, pa = plane_grid()
    rng = np.random.default_rng(0)
    ccm_inverse = np.array([[1.1, 0.03, -0.02], [0.02, 0.95, 0.01], [-0.01, 0.04, 0.85]])
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    rows: dict[str, dict] = {}
    meshes = [deformed_icosphere(5), bunny(), deformed_icosphere(6)]
    for mesh in meshes:
        if mesh is None:
            continue
        ov, of, oc = mesh
        for dist_name, dist in (("table 0.9 m", 0.9), ("close 0.45 m", 0.45)):
            cams = poses(dist)
            case = f"{'bunny ' if mesh is meshes[1] else 'blob '}{len(ov) / 1000:.0f}k verts, {dist_name}"
            # per-frame colour changes (the pipeline reshades when a depth frame arrives)
            colour_sets = [oc * (0.9 + 0.2 * k / N_POSES) for k in range(N_POSES)]
            fns, renderers, covered = {}, [], None
            for backend in backends:
                variants = [(backend, True)] + ([] if args.no_ablations else [(backend + " crop=False", False)])
                for label, crop in variants:
                    renderer = render.Renderer(intr, backend=backend, crop=crop)
                    renderers.append(renderer)
                    counter = itertools.count()

                    def do_render(renderer=renderer, counter=counter, cams=cams, ov=ov, of=of, colours=colour_sets):
                        k = next(counter) % N_POSES
                        return renderer.render(cams[k], ov, of, colours[k], pv, pf, pa)

                    fns[f"{case} | {label} | render"] = do_render
                    if crop:
                        layers = [do_render() for _ in range(N_POSES)]
                        lit = itertools.cycle(layers)
                        fns[f"{case} | {label} | composite"] = (
                            lambda lit=lit: render.composite(frame, next(lit), ccm_inverse=ccm_inverse))
                        fns[f"{case} | {label} | total"] = (
                            lambda do_render=do_render: render.composite(frame, do_render(), ccm_inverse=ccm_inverse))
                        covered = (np.mean([lay.mask.sum() for lay in layers]),
                                   np.mean([(lay.plane_alpha > 0).sum() for lay in layers]))
            off = None
            if "pyrender" in backends and not args.no_ablations:
                off, fns[f"{case} | pyrender stock OffscreenRenderer | render"] = stock_pyrender(
                    intr, ov, of, oc, pv, pf, pa, cams)
            rows.update(interleaved(fns, args.repeats))
            for renderer in renderers:
                renderer.close()
            if off is not None:  # last: its delete() terminates the process's shared EGL display
                off.delete()
            print(f"{case}: {len(of)} object + {len(pf)} plane triangles; object covers {covered[0]:.0f} px, "
                  f"plane {covered[1]:.0f} px (mean over poses)", flush=True)
    print(f"\n{W}x{H}; {args.repeats} interleaved rounds after 1 warm-up; each call the next of {N_POSES} poses; "
          f"load average {os.getloadavg()[0]:.1f}")
    width = max(len(k) for k in rows)
    print(f"{'case':<{width}}  {'median ms':>10}  {'p95 ms':>10}  {'min ms':>8}  {'n':>4}")
    for name, r in rows.items():
        print(f"{name:<{width}}  {r['median_ms']:>10.2f}  {r['p95_ms']:>10.2f}  {r['min_ms']:>8.2f}  {r['n']:>4}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
