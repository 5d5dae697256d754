"""Time the pipeline's "Denoise depth" stage (``denoise_frame``, 3×3 by default) on a recorded session.

    python benchmarks/bench_denoise.py [--session DIR] [--frames N] [--repeats N] [--json PATH]
                                       [--baseline PATH [--pipeline]]

Input: ``--frames`` depth frames spread over the recorded default session (``runs/default/session``,
written by ``rgbd-envmap simulate``), each turned into its RGB-D frame as the pipeline does
(``rgbd_frame_from_packets``); every call takes the next frame, so nothing is reused from the call
before. Rows: ``denoise_frame`` as ``Pipeline._depth_step`` calls it (``TangoIngestConfig``'s
``denoise_half_window``, 2: 5×5), ``denoise_depth`` alone, and the other specialised window (3×3).

``--baseline PATH`` loads another version of the denoiser, a module with ``denoise_frame`` and
``denoise_depth`` (e.g. the last commit's ``rgbd_envmap/depth/denoise.py``, ``git show
HEAD:rgbd_envmap/depth/denoise.py > /tmp/denoise_head.py``; its kernels come from the module it imports
them from, so to time a kernel change, load a file that holds the old kernels), checks that its output
is bit for bit the current one on every frame and window, and times both in the same loop,
alternating call by call (which goes first alternates too), so that both see the same load on the
shared machine.
Each row reports wall-clock median / p95 and the median *thread CPU time*, which other jobs disturb
much less. ``--pipeline`` also replays the whole session through ``Pipeline`` (rendering off), its
"Denoise depth" stage taking the current and the baseline ``denoise_frame`` in turn, depth frame by
depth frame (their outputs being bit for bit equal, the run is the same as with either): that stage's
times and the depth-frame totals per version, in the pipeline's own cache and load conditions.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table  # noqa: E402
from rgbd_envmap.depth import denoise as D  # noqa: E402
from rgbd_envmap.ingest.tango import TangoIngestConfig, decode_colour, rgbd_frame_from_packets  # noqa: E402
from rgbd_envmap.logs import SessionLog  # noqa: E402
from rgbd_envmap.timing import frame_totals, stage_stats  # noqa: E402
from rgbd_envmap.types import RGBDFrame  # noqa: E402

DEFAULT_SESSION = Path(__file__).resolve().parent.parent / "runs" / "default" / "session"


def load_baseline(path: Path):
    """Import another version of the denoise module under a private name."""
    spec = importlib.util.spec_from_file_location("_denoise_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # numba's cache looks the module up by name
    spec.loader.exec_module(module)
    return module


def session_rgbd_frames(root: Path, count: int) -> list[RGBDFrame] | None:
    """The RGB-D frames (point cloud → RGB-D, as the pipeline builds them) of ``count`` depth packets
    spread over the whole session, each with the colour frame nearest in time; None without one."""
    if not (Path(root) / "calibration.json").is_file():
        return None
    log = SessionLog.open(root)
    cfg = TangoIngestConfig()
    n = len(log.depth_timestamps_ns)
    frames = []
    for i in np.unique(np.linspace(0, n - 1, count).astype(int)):
        pk = log.read_depth(int(i))
        cp = log.read_colour(int(np.argmin(np.abs(log.colour_timestamps_ns - pk.timestamp_ns))))
        frame, _ = rgbd_frame_from_packets(pk, decode_colour(cp), cp.T_world_from_colour, log.calibration, cfg)
        frames.append(frame)
    return frames


def interleaved(fns: dict, frames: list, repeats: int) -> dict:
    """Wall and thread-CPU times of functions of a frame, called in turn on the next frame, round by
    round; the order within a round rotates."""
    names = list(fns)
    for fn in fns.values():
        fn(frames[0])
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for i in range(repeats):
        frame = frames[i % len(frames)]
        for k in names[i % len(names):] + names[:i % len(names)]:
            t0, c0 = time.perf_counter(), time.thread_time()
            fns[k](frame)
            cpu[k].append((time.thread_time() - c0) * 1e3)
            wall[k].append((time.perf_counter() - t0) * 1e3)
    return {k: {"median_ms": float(np.median(wall[k])), "p95_ms": float(np.percentile(wall[k], 95)),
                "min_ms": float(np.min(wall[k])), "n": repeats, "cpu_median_ms": float(np.median(cpu[k]))}
            for k in fns}


def identical(module, frames: list[RGBDFrame], half: int) -> tuple[int, float]:
    """(pixels whose bits differ, largest difference) between ``module``'s denoise_frame and ours."""
    bad, worst = 0, 0.0
    for f in frames:
        a = D.denoise_frame(f, half_window=half).depth_m
        b = module.denoise_frame(f, half_window=half).depth_m
        diff = a.view(np.uint32) != b.view(np.uint32)
        bad += int(diff.sum())
        if diff.any():
            worst = max(worst, float(np.nanmax(np.abs(a[diff].astype(np.float64) - b[diff]))))
    return bad, worst


def pipeline_rows(root: Path, baseline) -> dict[str, dict]:
    """Replay the session with "Denoise depth" alternating between ours and ``baseline``'s
    ``denoise_frame`` per depth frame: that stage and the depth-frame totals, per version."""
    import dataclasses

    from apps.replay import default_origin
    from rgbd_envmap.pipeline import Pipeline, PipelineConfig

    log = SessionLog.open(root)
    cfg = PipelineConfig()
    pipe = Pipeline(dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, enabled=False)), log.calibration,
                    default_origin(log))
    calls = [0]
    ours = D.denoise_frame

    def alternate(frame, **kwargs):  # Pipeline._depth_step looks denoise_frame up on every call
        calls[0] += 1
        return (baseline.denoise_frame if calls[0] % 2 == 0 else ours)(frame, **kwargs)

    D.denoise_frame = alternate
    try:
        for packet in log:
            pipe.feed(packet)
        pipe.finish()
    finally:
        D.denoise_frame = ours
    # the n-th "Denoise depth" record is the n-th call: odd calls ours, even ones the baseline's
    stage_frames = [r.frame for r in pipe.timer.records if r.stage == "Denoise depth"]
    which = {f: ("" if n % 2 == 0 else "baseline: ") for n, f in enumerate(stage_frames)}
    rows = {}
    for name in ("", "baseline: "):
        mine = [r for r in pipe.timer.records if which.get(r.frame) == name]
        rows[f"{name}pipeline: 'Denoise depth'"] = stage_stats(r.ms for r in mine if r.stage == "Denoise depth")
        rows[f"{name}pipeline: depth frame total"] = stage_stats(frame_totals(mine, "depth"))
    return {k: {"median_ms": v["median_ms"], "p95_ms": v["p95_ms"], "n": v["count"]} for k, v in rows.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--session", type=Path, default=DEFAULT_SESSION, help="a recorded session (rgbd-envmap simulate)")
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--baseline", type=Path, default=None, help="another denoise.py, timed alternately")
    parser.add_argument("--pipeline", action="store_true", help="with --baseline: also replay the session (about 1 min)")
    args = parser.parse_args()
    frames = session_rgbd_frames(args.session, args.frames)
    if frames is None:
        print(f"no session at {args.session}: nothing to time (rgbd-envmap simulate writes one)")
        return
    half = TangoIngestConfig().denoise_half_window
    other = 1 if half == 2 else 2  # the other specialised window
    modules = {"": D}
    if args.baseline:
        modules["baseline: "] = load_baseline(args.baseline)
        for h in (half, other):
            bad, worst = identical(modules["baseline: "], frames, h)
            print(f"{2 * h + 1}×{2 * h + 1} on {len(frames)} frames: {bad} pixels differ from the baseline"
                  + (f" (largest difference {worst:.3g} m)" if bad else " (bit for bit)"))
    known = 100 * np.mean([f.known.mean() for f in frames])
    cases = {
        f"denoise_frame {2 * half + 1}×{2 * half + 1} (the pipeline stage; {known:.0f} % known)":
            lambda m: lambda f: m.denoise_frame(f, half_window=half),
        f"denoise_depth {2 * half + 1}×{2 * half + 1}":
            lambda m: lambda f: m.denoise_depth(f.depth_m, f.known, f.intrinsics, half_window=half),
        f"denoise_frame {2 * other + 1}×{2 * other + 1}": lambda m: lambda f: m.denoise_frame(f, half_window=other),
    }
    rows = {}
    for name, make in cases.items():
        both = interleaved({prefix: make(m) for prefix, m in modules.items()}, frames, args.repeats)
        for prefix, row in both.items():
            rows[prefix + name] = row
    if args.pipeline and args.baseline:
        rows.update(pipeline_rows(args.session, modules["baseline: "]))
    print_table(rows)
    width = max(len(k) for k in rows)
    print(f"\n{'case':<{width}}  {'thread CPU median ms':>20}")
    for name, r in rows.items():
        if "cpu_median_ms" in r:
            print(f"{name:<{width}}  {r['cpu_median_ms']:>20.3f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
