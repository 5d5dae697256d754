"""Time the map update with HDR clip flags against the update without them and against a git ref.

    python benchmarks/bench_hdr_update.py [--recorded PATH] [--rounds R] [--threads T] [--baseline REF]

Every ``update`` call of the recorded session (``runs/default/session``) is replayed on four maps of
their own, frame by frame, in an order that rotates every frame: the library at ``--baseline`` (default
HEAD: the update before HDR capture), the library without ``clipped`` (its flags off), with
``clipped`` all False (the HDR path, nothing clipped: the map must equal the other two bit for bit)
and with ``clipped`` set where a corrected colour has a channel at or above 0.95 (the HDR path as it
runs on the lit office; a different map). Median / p95 ms per call, the first frame (into an empty
map) left out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.bench_envmap import Baseline, _maps_differ, load_baseline, recorded_update_calls  # noqa: E402
from rgbd_envmap._kernels.parallel import configure_threading_layer  # noqa: E402
from rgbd_envmap.envmap import EnvironmentMap, update  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recorded", type=Path, default=REPO / "runs/default/session")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--baseline", default="HEAD")
    args = parser.parse_args()
    configure_threading_layer()
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    base = Baseline(load_baseline(args.baseline))
    data = recorded_update_calls(args.recorded)
    if data is None:
        raise SystemExit(f"no recorded session at {args.recorded}")
    origin, h, w, calls, _ = data
    kinds = ("baseline", "flags off", "hdr, none clipped", "hdr, clipped ≥ 0.95")
    ms = {k: [] for k in kinds}
    converted = [base.update_args(c[4], c[6], args.threads) for c in calls]
    for r in range(args.rounds):
        maps = {k: EnvironmentMap(h, w, origin) for k in kinds[1:]}
        maps["baseline"] = base.envmap.EnvironmentMap(h, w, origin)
        for j, ((pts, col, dev, focal, config, fill_only, seen), (b_cfg, b_seen, b_kw)) in enumerate(zip(calls, converted)):
            none = np.zeros(len(pts), bool)
            flagged = (col >= 0.95).any(axis=1)
            fns = {
                "baseline": lambda: base.envmap.update(maps["baseline"], pts, col, dev, focal, b_cfg, fill_only, b_seen, **b_kw),
                "flags off": lambda: update(maps["flags off"], pts, col, dev, focal, config, fill_only, seen,
                                            threads=args.threads),
                "hdr, none clipped": lambda: update(maps["hdr, none clipped"], pts, col, dev, focal, config, fill_only,
                                                    seen, clipped=none, threads=args.threads),
                "hdr, clipped ≥ 0.95": lambda: update(maps["hdr, clipped ≥ 0.95"], pts, col, dev, focal, config,
                                                      fill_only, seen, clipped=flagged, threads=args.threads),
            }
            k0 = (j + r) % len(kinds)
            for k in kinds[k0:] + kinds[:k0]:
                t0 = time.perf_counter()
                fns[k]()
                if j > 0:
                    ms[k].append((time.perf_counter() - t0) * 1e3)
            ref = maps["baseline"]
            for k in ("flags off", "hdr, none clipped"):
                if _maps_differ(maps[k], ref):
                    raise SystemExit(f"{k}: the map differs from the baseline at frame {j} of round {r}")
    print(f"update() on {len(calls)} recorded frames × {args.rounds} rounds, {args.threads} thread(s); "
          f"'flags off' and 'hdr, none clipped' identical to the baseline after every frame")
    print(f"{'':24s} {'median ms':>10s} {'p95 ms':>8s}")
    for k in kinds:
        a = np.asarray(ms[k])
        print(f"{k:24s} {np.median(a):10.3f} {np.percentile(a, 95):8.3f}")


if __name__ == "__main__":
    main()
