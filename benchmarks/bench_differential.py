"""Benchmark: the differential composite's relight, piece by piece, on a recorded session.

    python benchmarks/bench_differential.py [--log runs/default/session] [--packets 450] [--repeats 15]
                                            [--tree PATH] [--json FILE]

Replays ``--packets`` packets of the log through the pipeline with its defaults (the differential
composite on), then times, on the map and lights it has reached, ``--repeats`` calls of each piece of
a relight:

- ``lights``: the direct / indirect split and the light sampler ("Lights from the map");
- ``receiver_mesh``: the real surfaces near the object from the map's depth (with the support plane
  merged in), and ``receiver_occlusion``: their SH occlusion by the object (together: "Receiver
  geometry", every ``render.geometry_every`` relights);
- ``shade_receivers``: the receivers' ratio E_with / E_without for the current lights, their terms
  reused (the same light set: what a frame that keeps its lights computes); ``shade_receivers_cold``: the same with every shadow ray cast anew (a
  relight right after a receiver rebuild);
- ``shade_object_lights``: ``render.object_shading = "lights"`` (the object's self-shadow rays too);
- ``shade_and_faces``: ``shade_receivers`` and the receiver triangles that change a pixel (what the
  stage "Shade receivers" runs when the lights are kept);
- ``light_irradiance``: the lights' irradiance at the receivers without and with shadows in the
  fused compiled pass, beside ``light_weights_and_products``: the same from the (R, n) weights and
  two matrix products (the form it replaced), for the current point lights (trees that have them).

``--tree PATH`` imports ``rgbd_envmap`` from another checkout (e.g. ``git worktree add /tmp/old REV``)
so that two versions can be timed alternately, in turns, by running the script once per tree per
turn. One BLAS and one OpenCV thread, as the apps run. Prints medians and p95 in ms; ``--json``
writes them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", default="runs/default/session")
    ap.add_argument("--packets", type=int, default=450)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--tree", default=None, help="import rgbd_envmap from this checkout")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root = Path(args.tree).resolve() if args.tree else Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root))
    from apps.process import configure_process

    configure_process()
    import numpy as np

    from rgbd_envmap.pipeline import Pipeline, PipelineConfig
    from rgbd_envmap.render.geometry import merge_receivers, receiver_mesh, support_plane
    from rgbd_envmap.sources.frames import as_source, feed

    src = as_source(args.log)
    pipe = Pipeline(PipelineConfig(), src.calibration, np.asarray(src.default_origin(), np.float64))
    for i, item in enumerate(src):
        if i >= args.packets:
            break
        feed(pipe, item)
    if pipe._diff_shader is None or pipe.lights is None:
        raise SystemExit("no differential relight with lights yet: raise --packets")
    em = pipe._lighting_map()
    rc = pipe.config.render
    shader = pipe._diff_shader
    n = pipe.bands * pipe.bands
    bands = pipe.sh_bands_computed

    def mesh():
        m = receiver_mesh(em.depth_m, em.valid, em.origin, shader.occluder.centre, rc.receiver_radius_m,
                          spacing_m=rc.receiver_spacing_m)
        plane = support_plane(pipe.object_base, rc.receiver_radius_m, rc.receiver_spacing_m)
        return merge_receivers(m, plane, 2 * rc.receiver_spacing_m)

    receivers = mesh()
    prt_mode = getattr(rc, "object_shading", None) == "prt"

    def shade(colours=None):
        if colours is None:
            return shader.shade(pipe.lights, pipe.coeffs_indirect[:n], pipe._transfer, pipe._object.albedo)
        return shader.shade(pipe.lights, pipe.coeffs_indirect[:n], pipe._transfer, pipe._object.albedo,
                            object_colours=colours, object_coeffs=pipe.coeffs[:n])  # as the pipeline calls it

    def shade_and_faces():
        _, ratio = shade(pipe.colours) if prt_mode else shade()
        return shader.active_faces(ratio)

    def cold():
        shader.set_receivers(receivers, bands)  # clears the kept shadow rays

    cases = {
        "lights": (lambda: pipe._split_lighting(em), None),
        "receiver_mesh": (mesh, None),
        "receiver_occlusion": (lambda: shader.set_receivers(receivers, bands), None),
        "shade_receivers": ((lambda: shade(pipe.colours)) if prt_mode else shade, None),
        "shade_object_lights": (lambda: shade(None), None),
        "shade_and_faces": (shade_and_faces, None),
    }
    from rgbd_envmap.render import differential as diff

    if hasattr(diff, "_light_irradiance"):
        pl = getattr(pipe.lights, "point_lights", pipe.lights)
        vis = np.ones((len(receivers), len(pl)), bool)
        vis[::7] = False  # some shadowed pairs

        def weights_and_products():
            w = diff._light_weights_unshadowed(pl, receivers.vertices, receivers.normals)
            return w @ pl.power, (w * vis) @ pl.power

        cases["light_irradiance"] = (lambda: diff._light_irradiance(pl, receivers.vertices, receivers.normals, vis),
                                     None)
        cases["light_weights_and_products"] = (weights_and_products, None)
    shader.set_receivers(receivers, bands)
    out = {"tree": str(root), "receivers": len(receivers), "n_lights": len(pipe.lights)}
    for name, (fn, _) in cases.items():
        fn()  # warm: kept shadow rays, caches, compiled code
        ts = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fn()
            ts.append((time.perf_counter() - t0) * 1e3)
        out[name] = {"median_ms": float(np.median(ts)), "p95_ms": float(np.percentile(ts, 95))}
    ts = []
    for _ in range(max(3, args.repeats // 3)):
        cold()
        t0 = time.perf_counter()
        shade(pipe.colours) if prt_mode else shade()
        ts.append((time.perf_counter() - t0) * 1e3)
    out["shade_receivers_cold"] = {"median_ms": float(np.median(ts)), "p95_ms": float(np.percentile(ts, 95))}
    print(f"tree {root}: {out['receivers']} receiver vertices, {out['n_lights']} lights")
    for k, v in out.items():
        if isinstance(v, dict):
            print(f"  {k:22s} median {v['median_ms']:8.2f} ms   p95 {v['p95_ms']:8.2f} ms")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
