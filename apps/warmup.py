"""Compile the pipeline's largest numba kernels into numba's on-disk cache, for a first run.

On a fresh machine the main job spent about 60 s compiling numba kernels one after the other on one
core (map update 12 s, SH tracker 9.5 s, colour pairs 4.6 s, ...; numba's compile events), while the
other core idled. ``scripts/main.sh`` starts this module in the background when the cache is cold, so
that these kernels compile on the other core while the main process builds the simulator and compiles
its own; when the main process reaches a kernel already compiled here, numba loads it from the cache.
The inputs are tiny but have the pipeline's dtypes and layouts, so the same specialisations are cached.
Nothing else is written; a failure here only means the main process compiles the kernel itself.

    python -m apps.warmup
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.capture import CaptureConfig
from rgbd_envmap.envmap import EnvironmentMap, SeenDepth, UpdateConfig, _frame_pair_sums, _frame_samples, update
from rgbd_envmap.geometry import look_at
from rgbd_envmap.sh import IncrementalProjection
from rgbd_envmap.types import Intrinsics, RGBDFrame


def main() -> int:
    """Run each kernel on a 16×12 frame and a 40×20 map, in the order that leaves the main process
    the least to compile itself: the kernels it reaches last first (the SH tracker follows the map
    update; the ingest kernels, which it reaches first, are left to it: 78.6 → 64.8 s for a fresh
    2 s session with the first version of this module, which compiled those too)."""
    rng = np.random.default_rng(0)
    intr = Intrinsics(16, 12, 14.0, 14.0, 7.5, 5.5)
    em = EnvironmentMap(20, 40)
    tracker = IncrementalProjection(5)
    frames = []
    for step, target in enumerate(([1.0, 0.2, 0.0], [1.0, -0.3, 0.1])):
        T = look_at([0.01 * step, 0.0, 0.0], target)
        frames.append(RGBDFrame(rng.random((12, 16, 3)).astype(np.float32),
                                rng.uniform(1.0, 2.0, (12, 16)).astype(np.float32), np.ones((12, 16), bool), T, intr, step))
    for frame in frames:
        T = frame.T_world_from_cam
        flags = np.zeros((12, 16), np.uint8)  # the edge margin's dilated mask
        pts, colours, fill_only = _frame_samples(frame.depth_m, frame.known, intr, T, frame.rgb, flags, np.eye(3))
        update(em, pts, colours, T.translation, 14.0, UpdateConfig(), fill_only,
               SeenDepth(frame.depth_m, frame.known, intr, T))
        tracker.coefficients(em)  # the first call projects the whole map, the second follows the changes
    _frame_pair_sums(em, frames[0].depth_m, frames[0].known, intr, frames[0].T_world_from_cam, frames[0].rgb, 0.01,
                     threads=CaptureConfig().pair_threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
