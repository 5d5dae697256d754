"""Benchmark: the whole depth frame on a recorded session, for two versions side by side.

    python benchmarks/bench_depth_frame.py [--log runs/default/session] [--tree PATH] [--set KEY=VALUE ...]
                                           [--json FILE]

Replays the log through ``Pipeline`` with its defaults (``--set`` overrides config fields as the CLI's
``--set`` does) and prints, as ``timing.md`` forms them, the median and p95 over depth frames of the
per-frame sum of the depth stages (rendering excluded; also its 75th and 90th percentiles), with the
medians of the relight's stages, what every stage adds to the mean depth frame (its total over the
frames / the frames) and what it takes in the frames around the median (those ranked 40–60 % by
their total: where a typical frame's time goes).
``--tree PATH`` imports ``rgbd_envmap`` from another checkout (``git archive REV | tar -x -C DIR``):
run the script once per tree, in turns, to compare two versions under the same load. One BLAS and
one OpenCV thread, as the apps run.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

RELIGHT = ("Calculate SH coefficients*", "Lights from the map", "Receiver geometry", "Shade object (PRT)",
           "Shade receivers", "Project sample to EM*")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", default="runs/default/session")
    ap.add_argument("--tree", default=None, help="import rgbd_envmap from this checkout")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root = Path(args.tree).resolve() if args.tree else Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root))
    from apps.process import configure_process

    configure_process()
    import numpy as np

    from rgbd_envmap.pipeline import RENDER_STAGES, Pipeline, PipelineConfig
    from rgbd_envmap.sources.frames import as_source, feed

    config = PipelineConfig()
    if args.set:
        from rgbd_envmap.config import apply_overrides

        config = apply_overrides(config, args.set)
    src = as_source(args.log)
    with Pipeline(config, src.calibration, np.asarray(src.default_origin(), np.float64)) as pipe:
        for item in src:
            feed(pipe, item)
        records = list(pipe.timer.records)
    total: dict[int, float] = collections.defaultdict(float)
    stages: dict[str, list[float]] = collections.defaultdict(list)
    per_frame: dict[int, dict[str, float]] = collections.defaultdict(lambda: collections.defaultdict(float))
    for r in records:
        if r.kind == "depth" and r.stage not in RENDER_STAGES:
            total[r.frame] += r.ms
            stages[r.stage].append(r.ms)
            per_frame[r.frame][r.stage] += r.ms
    t = np.array(list(total.values()))
    # the frames around the median (ranked 40–60 % by their total): where a typical frame's time goes
    ranked = sorted(total, key=total.get)
    middle = ranked[int(0.4 * len(ranked)):max(int(0.6 * len(ranked)), int(0.4 * len(ranked)) + 1)]
    out = {"tree": str(root), "depth_frames": len(t), "depth_frame_median_ms": float(np.median(t)),
           "depth_frame_p75_ms": float(np.percentile(t, 75)), "depth_frame_p90_ms": float(np.percentile(t, 90)),
           "depth_frame_p95_ms": float(np.percentile(t, 95)),
           **{f"{k} median ms": float(np.median(v)) for k, v in stages.items() if k in RELIGHT},
           # what each stage adds to the mean depth frame (its sum over the frames / their count)
           **{f"{k} ms a frame": float(np.sum(v)) / max(len(t), 1) for k, v in stages.items()},
           **{f"{k} ms in the median frames": float(np.mean([per_frame[f][k] for f in middle])) for k in stages}}
    print(f"tree {root}: {len(t)} depth frames")
    for k, v in out.items():
        if isinstance(v, float):
            print(f"  {k:40s} {v:8.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
