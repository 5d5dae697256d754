"""Time one reference composite (sim/reference.py ``render_reference_pair``) of a lit scene.

    python benchmarks/bench_reference.py [--scene office] [--size 960x540] [--times 5,10,15]
                                         [--runs 3] [--method gather] [--json PATH]

The views are the default trajectory's true colour-camera poses at ``--times`` (the frames the main
job's ``--reference-every 5`` picks), with the pipeline's default virtual object at the scene's object
position, as ``simulate`` renders them. Each view is rendered ``--runs`` times (the first run of the
process also compiles and builds the ray casters: it is reported apart as "first"). Printed per view:
median / p95 wall seconds, the process CPU seconds per render (user + system: on an otherwise idle
2-core machine the wall time is about CPU / 2 for the parallel parts), and the traced fraction of
the frame.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apps.process import configure_process  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="office")
    ap.add_argument("--size", default="960x540", help="WIDTHxHEIGHT of the colour camera")
    ap.add_argument("--times", default="5,10,15", help="session seconds of the views (comma-separated)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--method", default="gather", choices=("gather", "path"))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    configure_process()

    from rgbd_envmap import assets
    from rgbd_envmap.pipeline import PipelineConfig
    from sim.colour_camera import ColourCameraConfig
    from sim.device import TangoDeviceConfig
    from sim.mitsuba_scene import ExtraMesh
    from sim.reference import render_reference_pair
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    w, h = (int(v) for v in args.size.lower().split("x"))
    scene = load_scene(args.scene)
    sim = Simulator(scene, load_trajectory(scene.default_trajectory),
                    TangoDeviceConfig(colour=ColourCameraConfig(width=w, height=h)), seed=0)
    oc = PipelineConfig().object
    obj = assets.load_virtual_object(oc.name, height_m=oc.height_m)
    base = np.asarray(scene.virtual_object_position, np.float64)
    mesh = ExtraMesh(obj.name, np.asarray(obj.vertices, np.float64) + base, obj.faces, obj.albedo)
    results = {}
    first = True
    for t in (float(v) for v in args.times.split(",")):
        pose = sim.true_pose_colour(t)
        walls, cpus, traced = [], [], 0.0
        for run in range(args.runs + (1 if first else 0)):
            c0, t0 = time.process_time(), time.perf_counter()
            pair = render_reference_pair(scene, pose, sim.calibration.colour, t, mesh, raycaster=sim.raycaster,
                                         method=args.method, seed=run)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            traced = float(pair.traced.mean())
            if first:
                results["first"] = {"wall_s": wall, "cpu_s": cpu}
                print(f"first render (compiles, builds casters): {wall:.1f} s wall, {cpu:.1f} s CPU")
                first = False
                continue
            walls.append(wall)
            cpus.append(cpu)
        row = {"wall_median_s": float(np.median(walls)), "wall_p95_s": float(np.percentile(walls, 95)),
               "cpu_median_s": float(np.median(cpus)), "traced_fraction": traced, "runs": len(walls)}
        results[f"t={t:g}s"] = row
        print(f"t = {t:5.1f} s  wall median {row['wall_median_s']:6.1f} s  p95 {row['wall_p95_s']:6.1f} s  "
              f"CPU {row['cpu_median_s']:6.1f} s  traced {100 * traced:5.1f} % of {w}×{h}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
