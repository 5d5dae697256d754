"""SH stage on a real capture: the incremental projection beside the full one, frame by frame.

    python benchmarks/bench_sh_session.py [--session runs/default/session] [--every 1]

Replays a recorded session (``bash main.sh`` writes ``runs/default/session``) through the pipeline
(rendering off). After every depth frame that changed the map, the pipeline's own stage "Calculate
SH coefficients*" ran :class:`rgbd_envmap.sh.IncrementalProjection`; beside it, on the same map
state in the same run, this script times the full ``sh.project_planar`` (plan the fill of every
missing pixel, project every row) and checks that both give the same coefficients. Prints median /
p95 of both, the pixels written per frame and the largest relative difference.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apps.replay import default_origin
from rgbd_envmap import sh
from rgbd_envmap.logs import SessionLog
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from rgbd_envmap.timing import summarise


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--session", type=Path, default=Path("runs/default/session"))
    ap.add_argument("--every", type=int, default=1, help="time the full projection every N depth frames")
    args = ap.parse_args()
    log = SessionLog.open(args.session)
    cfg = PipelineConfig()
    cfg = dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, enabled=False))
    p = Pipeline(cfg, log.calibration, default_origin(log))
    full_ms, diffs, steps = [], [], 0
    for packet in log:
        for result in p.feed(packet):
            if not getattr(result, "sh_updated", False):
                continue
            steps += 1
            if steps % args.every:
                continue
            em = p.capture.em
            t = time.perf_counter()
            ref = sh.project_planar(em.radiance_planes, em.valid, p.sh_bands_computed)
            full_ms.append((time.perf_counter() - t) * 1e3)
            diffs.append(float(np.abs(p.coeffs - ref).max() / np.abs(ref).max()))
    inc = summarise(p.timer.records)["Calculate SH coefficients*"]
    proj = p._projection
    print(f"{args.session}: {steps} SH updates ({proj.incremental_updates} incremental, {proj.full_projections} full)")
    print(f"  incremental (pipeline stage): median {inc['median_ms']:.2f} ms, p95 {inc['p95_ms']:.2f} ms")
    print(f"  full project_planar, same maps: median {np.median(full_ms):.2f} ms, p95 {np.percentile(full_ms, 95):.2f} ms")
    print(f"  largest relative difference of the coefficients: {max(diffs):.2e}")


if __name__ == "__main__":
    main()
