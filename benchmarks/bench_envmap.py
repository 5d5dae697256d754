"""Time the colour-correction and environment-map stages on realistic data (paper Table 1 rows
"Collect paired samples", "Compute colour correction matrix", "Calculate MSE", "Project sample to EM"
and the §6.2 translation).

    python benchmarks/bench_envmap.py [--repeats N] [--json PATH]

A 4 s capture of the default scene warms the map up; the timed frame is the next one. Single thread
(every kernel is serial numba).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it  # noqa: E402
from benchmarks.eval_envmap import ingested_frames  # noqa: E402
from rgbd_envmap.capture import CaptureConfig, EnvironmentCapture  # noqa: E402
from rgbd_envmap.colour import apply_ccm, estimate_ccm  # noqa: E402
from rgbd_envmap.envmap import UpdateConfig, collect_pairs, frame_points, translate, update  # noqa: E402
from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), TangoDeviceConfig(colour=ColourCameraConfig(width=640, height=360)), seed=0)
    frames = [res for _, res in ingested_frames(sim, 4.2)]
    cap = EnvironmentCapture(sim.scene.virtual_object_position, CaptureConfig())
    for res in frames[:-1]:
        cap.process(res.frame, res.reliable, res.filled)
    res = frames[-1]
    raw, filled = res.frame, res.filled
    em = cap.em
    # Pairs over the whole cloud (every known pixel, as the paper's 38,528-point figure), and over
    # the reliable pixels the pipeline actually uses.
    pts_all = frame_points(raw.depth_m, raw.known, raw.intrinsics, raw.T_world_from_cam)
    col_all = raw.rgb[raw.known]
    pts_rel = frame_points(raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam)
    col_rel = raw.rgb[res.reliable]
    src, dst = collect_pairs(em, pts_all, col_all)
    mask = cap.projected_mask(raw, filled)
    pts_proj = frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam)
    col_proj = apply_ccm(filled.rgb[mask], cap.matrix)
    dev = filled.T_world_from_cam.translation
    r = args.repeats
    work = em.copy()

    def pairs_matrix_mse(p, c):
        s, d = collect_pairs(em, p, c)
        return estimate_ccm(s, d, method="ridge")

    rows = {
        f"pairs+matrix+mse, all {len(pts_all)} known pts ({len(src)} pairs)": time_it(lambda: pairs_matrix_mse(pts_all, col_all), r),
        f"pairs+matrix+mse, {len(pts_rel)} reliable pts": time_it(lambda: pairs_matrix_mse(pts_rel, col_rel), r),
        "  of which collect_pairs (all pts)": time_it(lambda: collect_pairs(em, pts_all, col_all), r),
        "  of which estimate_ccm ridge": time_it(lambda: estimate_ccm(src, dst, method="ridge"), r),
        "world points of a frame (frame_points)": time_it(lambda: frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam), r),
        f"EM update 2000x1000, {len(pts_proj)} samples, splat": time_it(lambda: update(work, pts_proj, col_proj, dev, 200.0), r),
        f"EM update 2000x1000, {len(pts_proj)} samples, one pixel each": time_it(lambda: update(work, pts_proj, col_proj, dev, 200.0, UpdateConfig(splat=False)), r),
        "projected mask (plane test on filled depth)": time_it(lambda: cap.projected_mask(raw, filled), r),
        "translate 2000x1000 by 10 cm (depth)": time_it(lambda: translate(em, np.array([0.1, 0.0, 0.0])), max(5, r // 5)),
        "translate 2000x1000 by 10 cm (gardner)": time_it(lambda: translate(em, np.array([0.1, 0.0, 0.0]), "gardner"), max(5, r // 5)),
    }
    print(f"map coverage before the timed frame: {em.valid.mean():.3f}")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
