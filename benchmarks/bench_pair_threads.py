"""The colour pairs' sums on one thread against two, on the recorded session's frames.

Every "Collect paired samples" call of ``capture.process`` on the recorded session (``bash
scripts/main.sh`` writes ``runs/default/session``) runs :func:`rgbd_envmap.envmap.frame_pair_sums`
with ``threads=1`` and ``threads=2``, alternating which goes first; the results must be identical
bit for bit. Prints median / p95 ms of each over the calls (the first left out). Two threads need
two numba threads (numba's default is one per core); with one, ``threads=2`` runs the one-thread
kernel (``bench_envmap.py --one-thread-kernels`` times the two-thread kernel on one thread).

    python benchmarks/bench_pair_threads.py [--recorded DIR] [--rounds N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_envmap import capture_inputs  # noqa: E402
from rgbd_envmap._kernels.parallel import usable_threads  # noqa: E402
from rgbd_envmap.pipeline import capture as capture_module  # noqa: E402
from rgbd_envmap.pipeline.capture import EnvironmentCapture  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recorded", type=Path, default=Path("runs/default/session"))
    parser.add_argument("--rounds", type=int, default=1, help="replays of the session")
    args = parser.parse_args()
    if usable_threads(2) < 2:
        print("numba has one thread: threads=2 runs the one-thread kernel here")
    data = capture_inputs(args.recorded)
    if data is None:
        raise SystemExit(f"no recorded session at {args.recorded} (bash scripts/main.sh writes it)")
    origin, cfg, calls = data
    sums = capture_module.frame_pair_sums
    ms: dict[int, list[float]] = {1: [], 2: []}
    count = [0]

    def both(*a, threads=1, **k):
        count[0] += 1
        out = {}
        for t in ((1, 2) if count[0] % 2 else (2, 1)):
            t0 = time.perf_counter()
            out[t] = sums(*a, threads=t, **k)
            if count[0] > 1:
                ms[t].append((time.perf_counter() - t0) * 1e3)
        if not all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(out[1], out[2])):
            raise SystemExit(f"call {count[0]}: the sums on one and two threads differ")
        return out[1]

    capture_module.frame_pair_sums = both
    try:
        for _ in range(args.rounds):
            capture = EnvironmentCapture(origin, cfg)
            for raw, reliable, filled, across in calls:
                capture.process(raw, reliable, filled, across_edges=across)
    finally:
        capture_module.frame_pair_sums = sums
    print(f"{len(ms[1])} pair passes, sums identical on one and two threads")
    for t in (1, 2):
        a = np.array(ms[t])
        print(f"threads={t}: median {np.median(a):.3f} ms, p95 {np.percentile(a, 95):.3f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
