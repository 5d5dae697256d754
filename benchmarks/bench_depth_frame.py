"""Benchmark: the whole depth frame on a recorded session, for two versions side by side.

    python benchmarks/bench_depth_frame.py [--log runs/default/session] [--tree PATH] [--set KEY=VALUE ...]
                                           [--versus KEY=VALUE ...] [--json FILE]

Replays the log through ``Pipeline`` with its defaults (``--set`` overrides config fields as the CLI's
``--set`` does) and prints, as ``timing.md`` forms them, the median and p95 over depth frames of the
per-frame sum of the depth stages (rendering excluded; also its 75th and 90th percentiles), with the
medians of the relight's stages, what every stage adds to the mean depth frame (its total over the
frames / the frames) and what it takes in the frames around the median (those ranked 40–60 % by
their total: where a typical frame's time goes).
``--tree PATH`` imports ``rgbd_envmap`` from another checkout (``git archive REV | tar -x -C DIR``):
run the script once per tree, in turns, to compare two versions under the same load. One BLAS and
one OpenCV thread, as the apps run.

``--versus KEY=VALUE`` (repeatable) compares two settings of one tree in one process: a second
pipeline with those overrides (on top of ``--set``) is fed the same packets in lockstep, the two
taking turns to go first, so that both see the same load from moment to moment. Beside each one's
figures it prints the median and the 25th–75th percentiles of the per-frame difference (second
minus first) over the depth frames both processed: on a shared machine that difference is far
steadier than two medians taken minutes apart.
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
    ap.add_argument("--versus", action="append", default=[], metavar="KEY=VALUE",
                    help="also run these overrides in lockstep and report the per-frame difference")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root = Path(args.tree).resolve() if args.tree else Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root))
    from apps.process import configure_process

    configure_process()
    import numpy as np

    from rgbd_envmap.config import apply_overrides
    from rgbd_envmap.pipeline import RENDER_STAGES, Pipeline, PipelineConfig
    from rgbd_envmap.sources.frames import as_source, feed

    configs = [apply_overrides(PipelineConfig(), args.set) if args.set else PipelineConfig()]
    if args.versus:
        configs.append(apply_overrides(configs[0], args.versus))
    src = as_source(args.log)
    origin = np.asarray(src.default_origin(), np.float64)
    pipes = [Pipeline(c, src.calibration, origin) for c in configs]
    try:
        for i, item in enumerate(src):
            for pipe in (pipes if i % 2 == 0 else pipes[::-1]):  # each goes first every other packet
                feed(pipe, item)
        records = [list(p.timer.records) for p in pipes]
    finally:
        for p in pipes:
            p.close()
    outs, totals = [], []
    for recs in records:
        out, total = _summary(recs, RENDER_STAGES, np)
        outs.append(out)
        totals.append(total)
    labels = ["defaults" + (f" + {' '.join(args.set)}" if args.set else "")]
    if args.versus:
        labels.append(f"{labels[0]} + {' '.join(args.versus)}")
    result = {"tree": str(root), "runs": [dict(label=lab, **o) for lab, o in zip(labels, outs)]}
    for lab, out in zip(labels, outs):
        print(f"tree {root} [{lab}]: {out['depth_frames']} depth frames")
        for k, v in out.items():
            if isinstance(v, float):
                print(f"  {k:40s} {v:8.2f}")
    if args.versus:
        both = sorted(set(totals[0]) & set(totals[1]))
        diff = np.array([totals[1][f] - totals[0][f] for f in both])
        if len(diff):
            q25, q50, q75 = np.percentile(diff, [25, 50, 75])
            result["paired_difference_ms"] = {"frames": len(diff), "median": float(q50), "p25": float(q25),
                                              "p75": float(q75)}
            print(f"per-frame difference (second − first) over {len(diff)} depth frames: median {q50:+.2f} ms "
                  f"(25th–75th percentile {q25:+.2f} … {q75:+.2f})")
    if args.json:
        Path(args.json).write_text(json.dumps(result if args.versus else result["runs"][0] | {"tree": str(root)},
                                              indent=1))
    return 0


def _summary(records, render_stages, np) -> tuple[dict, dict]:
    """The figures of one run's records, and its per-frame totals {frame: ms}."""
    total: dict[int, float] = collections.defaultdict(float)
    stages: dict[str, list[float]] = collections.defaultdict(list)
    per_frame: dict[int, dict[str, float]] = collections.defaultdict(lambda: collections.defaultdict(float))
    for r in records:
        if r.kind == "depth" and r.stage not in render_stages:
            total[r.frame] += r.ms
            stages[r.stage].append(r.ms)
            per_frame[r.frame][r.stage] += r.ms
    t = np.array(list(total.values()))
    # the frames around the median (ranked 40–60 % by their total): where a typical frame's time goes
    ranked = sorted(total, key=total.get)
    middle = ranked[int(0.4 * len(ranked)):max(int(0.6 * len(ranked)), int(0.4 * len(ranked)) + 1)]
    out = {"depth_frames": len(t), "depth_frame_median_ms": float(np.median(t)),
           "depth_frame_p75_ms": float(np.percentile(t, 75)), "depth_frame_p90_ms": float(np.percentile(t, 90)),
           "depth_frame_p95_ms": float(np.percentile(t, 95)),
           **{f"{k} median ms": float(np.median(v)) for k, v in stages.items() if k in RELIGHT},
           # what each stage adds to the mean depth frame (its sum over the frames / their count)
           **{f"{k} ms a frame": float(np.sum(v)) / max(len(t), 1) for k, v in stages.items()},
           **{f"{k} ms in the median frames": float(np.mean([per_frame[f][k] for f in middle])) for k in stages}}
    return out, dict(total)


if __name__ == "__main__":
    raise SystemExit(main())
