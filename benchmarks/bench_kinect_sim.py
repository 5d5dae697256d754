"""Time the Kinect-like simulator per frame and the TUM RGB-D reader / writer per frame.

    python benchmarks/bench_kinect_sim.py [--repeats N] [--json PATH]

Rows: a whole simulated frame (depth + colour, as ``KinectSimulator.run`` yields it) on the office scene
along the default orbit, then its parts (the camera ray cast through ``SceneRaycaster.cast``, the
projector occlusion test, the noise / dropout kernel, the colour exposure), the depth alone at 320×240,
and the TUM layout: writing one 640×480 frame (two PNGs and three index lines) and loading one
(two PNG decodes, checks, depth → metres), plus opening and associating a 30-frame sequence. It
also prints a whole frame's CPU time (all threads), which other jobs on the shared box disturb less
than the wall time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.tum import read_tum_sequence, write_tum_sequence  # noqa: E402
from sim import kinect  # noqa: E402
from sim.colour_camera import AutoExposureState  # noqa: E402
from sim.kinect import KinectConfig, KinectSimulator, capture_kinect_depth  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    r = args.repeats

    scene, traj = load_scene("office"), load_trajectory("orbit")
    cfg = KinectConfig()
    sim = KinectSimulator(scene, traj, cfg, seed=0)
    frames = sim.run(30.0)
    rows = {"kinect frame 640x480 (depth + colour)": time_it(lambda: next(frames), r, warmup=2)}
    # CPU time of all threads per frame: less sensitive than wall time to other jobs on a shared box.
    cpu0 = time.process_time()
    for _ in range(r):
        next(frames)
    cpu_ms = (time.process_time() - cpu0) * 1e3 / r

    times = iter(np.linspace(0.0, 20.0, 100_000))
    rng = np.random.default_rng(0)

    def depth(config=cfg):
        t = next(times)
        capture_kinect_depth(sim.raycaster, sim.true_pose(t), t, config, rng)

    rows["  depth only 640x480"] = time_it(depth, r)
    t0 = 3.0
    T = sim.true_pose(t0)
    dirs_cam, _ = kinect._rays(cfg.intrinsics)
    dirs_world = kinect._rotate_rows(T.rotation, dirs_cam)
    rows["  camera ray cast 640x480 (SceneRaycaster.cast)"] = time_it(lambda: sim.raycaster.cast(T.translation, dirs_world, t0), r)
    hits = sim.raycaster.cast(T.translation, dirs_world, t0)
    projector = T.apply(np.array([cfg.projector_baseline_m, 0.0, 0.0]))
    sc = np.flatnonzero(hits.hit)
    rays, cos_proj = kinect._projector_rays(sc, dirs_world, hits.distance_m, hits.normal, (T.translation - projector).astype(np.float32),
                                            projector.astype(np.float32), np.float32(cfg.shadow_tolerance_m))
    rows["  projector occlusion test"] = time_it(lambda: kinect._occluded(sim.raycaster, rays, t0), r)
    shadow = kinect._occluded(sim.raycaster, rays, t0)
    z = (hits.distance_m / kinect._rays(cfg.intrinsics)[1]).astype(np.float32)
    u = rng.random((4, sc.size), dtype=np.float32)
    noise = rng.standard_normal(sc.size, dtype=np.float32)
    params = np.array([np.radians(70.0), np.radians(85.0), 0.8, 0.5, 0.9, np.cos(np.radians(10.0)), cfg.fb_px_m, 0.125, 0.001, 1.0])
    rows["  noise + dropout kernel"] = time_it(lambda: kinect._dropouts_and_depth(
        sc, z, hits.normal, dirs_world, hits.flags, rays, cos_proj, shadow, u, noise, params), r)
    radiance = hits.radiance.reshape(480, 640, 3)
    rows["  colour exposure 640x480"] = time_it(lambda: kinect._expose(radiance, AutoExposureState(), cfg.colour, rng), r)
    small = cfg.with_resolution(320, 240)
    rows["depth only 320x240"] = time_it(lambda: depth(small), r)

    with tempfile.TemporaryDirectory() as tmp:
        recorded = list(KinectSimulator(scene, traj, cfg, seed=1).run(1.0))  # 30 frames
        write_tum_sequence(Path(tmp) / "seq", recorded, cfg.intrinsics, timestamp_decimals=6)
        counter = iter(range(1, 10**6))

        def write_one():
            write_tum_sequence(Path(tmp) / f"w{next(counter)}", recorded[:1], cfg.intrinsics)

        rows["tum write one frame 640x480"] = time_it(write_one, r)
        rows["tum open + associate 30 frames"] = time_it(lambda: read_tum_sequence(Path(tmp) / "seq"), r)
        seq = read_tum_sequence(Path(tmp) / "seq")
        index = iter(range(10**6))
        rows["tum load one frame 640x480"] = time_it(lambda: seq.load(next(index) % len(seq)), r)

    print_table(rows)
    print(f"kinect frame 640x480: {cpu_ms:.1f} ms CPU time per frame, all threads (mean of {r})")
    rows["kinect frame 640x480 cpu_ms_all_threads"] = {"mean_ms": cpu_ms, "n": r}
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
