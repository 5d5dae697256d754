"""SH stage on a real capture: the incremental projection beside the full one, frame by frame.

    python benchmarks/bench_sh_session.py [--session runs/default/session] [--every 1]
    python benchmarks/bench_sh_session.py --baseline OLD_SH.py [--passes 3]

Replays a recorded session (``bash main.sh`` writes ``runs/default/session``) through the pipeline
(rendering off). After every depth frame that changed the map, the pipeline's own stage "Calculate
SH coefficients*" ran :class:`rgbd_envmap.sh.IncrementalProjection`; beside it, on the same map
state in the same run, this script times the full ``sh.project_planar`` (plan the fill of every
missing pixel, project every row) and checks that both give the same coefficients. Prints median /
p95 of both, the pixels written per frame and the largest relative difference.

``--baseline`` compares two versions of the tracker instead: the file is a module that defines an
``IncrementalProjection`` (e.g. ``git show REV:rgbd_envmap/sh/incremental.py > /tmp/sh_old.py``,
with its kernels import pointed at a copy of that revision's ``rgbd_envmap/_kernels/sh_incremental.py``
to compare kernels too), whose ``IncrementalProjection`` follows the same map beside the current one, both fed the same change log each frame, in alternating order
(the machine is shared and noisy: side by side in one process is the only fair comparison), over
``--passes`` replays of the session; also prints on how many frames the two gave bit-identical
coefficients and their largest relative difference.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import dataclasses
import importlib.util
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


def _pipeline(log: SessionLog) -> Pipeline:
    cfg = PipelineConfig()
    cfg = dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, enabled=False))
    return Pipeline(cfg, log.calibration, default_origin(log))


class _View:
    """The map as one of two trackers sees it: the change set both get this frame."""

    def __init__(self, em) -> None:
        self.em, self.changes = em, None

    def __getattr__(self, name):
        return getattr(self.em, name)

    def take_changes(self):
        return self.changes


class _SideBySide:
    """Stands in for the pipeline's tracker: runs the baseline's and the current one on each frame."""

    def __init__(self, trackers: dict, times: dict, diffs: list) -> None:
        self.trackers, self.times, self.diffs = trackers, times, diffs
        self.views: dict = {}
        self.calls = 0

    def coefficients(self, em) -> np.ndarray:
        views = self.views.setdefault(id(em), (em, {k: _View(em) for k in self.trackers}))[1]
        changes = em.take_changes()
        names = list(self.trackers) if self.calls % 2 == 0 else list(self.trackers)[::-1]
        self.calls += 1
        out = {}
        for name in names:
            views[name].changes = changes
            t = time.perf_counter()
            out[name] = self.trackers[name].coefficients(views[name])
            self.times[name].append((time.perf_counter() - t) * 1e3)
        ref = sh.project_planar(em.radiance_planes, em.valid, self.trackers["current"].bands)
        self.diffs.append({k: float(np.abs(c - ref).max() / np.abs(ref).max()) for k, c in out.items()})
        base, cur = out["baseline"], out["current"]
        self.diffs[-1]["identical"] = bool(np.array_equal(base, cur))
        self.diffs[-1]["versus"] = float(np.abs(cur - base).max() / max(np.abs(base).max(), 1e-300))
        return out["current"]


def compare(log: SessionLog, baseline: Path, passes: int) -> None:
    # named after the file, as an import would be: numba's cache of its kernels records that name
    spec = importlib.util.spec_from_file_location(baseline.stem, baseline)
    old = importlib.util.module_from_spec(spec)
    sys.modules[baseline.stem] = old  # (dataclasses look their module up)
    spec.loader.exec_module(old)
    times: dict = {"baseline": [], "current": []}
    diffs: list = []
    for i in range(passes):
        p = _pipeline(log)
        trackers = {"baseline": old.IncrementalProjection(p.sh_bands_computed),
                    "current": sh.IncrementalProjection(p.sh_bands_computed)}
        p._projection = _SideBySide(trackers, times, diffs)
        for packet in log:
            p.feed(packet)
        counts = ", ".join(f"{k} {t.incremental_updates} incremental / {t.full_projections} full" for k, t in trackers.items())
        print(f"pass {i + 1}: {counts}", flush=True)
    for name in ("baseline", "current"):
        t = np.array(times[name])
        d = max(x[name] for x in diffs)
        print(f"  {name:8s} ({baseline if name == 'baseline' else 'rgbd_envmap.sh'}): median {np.median(t):.2f} ms, "
              f"p95 {np.percentile(t, 95):.2f} ms over {len(t)} frames; "
              f"largest relative difference from project_planar {d:.2e}")
    same = sum(x["identical"] for x in diffs)
    print(f"  current vs baseline: identical coefficients on {same} of {len(diffs)} frames, "
          f"largest relative difference {max(x['versus'] for x in diffs):.2e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--session", type=Path, default=Path("runs/default/session"))
    ap.add_argument("--every", type=int, default=1, help="time the full projection every N depth frames")
    ap.add_argument("--baseline", type=Path, help="a module defining IncrementalProjection, timed beside the current one")
    ap.add_argument("--passes", type=int, default=3, help="replays of the session with --baseline")
    args = ap.parse_args()
    log = SessionLog.open(args.session)
    if args.baseline is not None:
        compare(log, args.baseline, args.passes)
        return
    p = _pipeline(log)
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
