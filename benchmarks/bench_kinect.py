"""Time the Kinect ingest path (paper 001 §4.2) per 640×480 frame: warp + merge + normals, by part and
in total, beside OpenCV's and kornia's functions for the same jobs.

    python benchmarks/bench_kinect.py [--repeats N] [--frames N] [--json PATH] [--baseline PATH]

Input: consecutive frames of the simulated Kinect (office scene, ``orbit_inward`` trajectory, 30 Hz).
The merger is warmed up on them, then every row is timed on the steady state, cycling through the
frames forwards and backwards so that each step warps between neighbouring poses.

Rows ``KinectMerger.step`` are the per-frame cost (the speed target: ≤ 8 ms median on one thread);
the part rows call the same kernels (:mod:`rgbd_envmap._kernels.kinect`) with the merger's workspace; "pure" rows call the public
functions, which allocate their scratch on every call.

``--baseline PATH`` loads another version of ``rgbd_envmap/ingest/kinect.py`` (e.g. the last commit's,
``git show HEAD:rgbd_envmap/ingest/kinect.py > /tmp/kinect_head.py``; a version that imports its
kernels from ``rgbd_envmap._kernels.kinect`` runs the current kernels) and times its
``KinectMerger.step`` in the same loop as the current one, alternating call by call on the same frames,
so that both see the same load; its parts are timed too if it has the kernels of the version before
the one-pass warp. Reference rows: ``cv2.warpFrame`` (a point
forward warp: no triangles, so it leaves cracks), kornia ``warp_frame_depth`` (a *backward* warp that
needs the destination depth, i.e. a different job, shown for scale), ``cv2.RgbdNormals`` (FALS and
CROSS_PRODUCT) and kornia ``depth_to_normals``. Everything runs on one thread (numba kernels are
serial; OpenCV and torch are set to one thread).

Besides wall-clock median / p95 (``benchmarks.common.time_it``) each row reports the median *thread
CPU time*, which other jobs on the shared 2-core box disturb much less.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import time_it  # noqa: E402
from rgbd_envmap._kernels import kinect as KK  # noqa: E402
from rgbd_envmap.ingest import kinect as K  # noqa: E402
from rgbd_envmap.types import RigidTransform  # noqa: E402
from sim.kinect import KinectSimulator  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def thread_ms(fn, repeats: int) -> float:
    """Median thread CPU time of ``fn`` in ms (after one untimed call)."""
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.thread_time()
        fn()
        ts.append((time.thread_time() - t0) * 1e3)
    return float(np.median(ts))


def load_baseline(path: Path):
    """Import another version of the kinect module under a private name."""
    spec = importlib.util.spec_from_file_location("_kinect_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def interleaved(fns: dict, repeats: int) -> dict:
    """Wall and thread-CPU times of several functions called in turn, round by round."""
    for fn in fns.values():
        fn()
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            fn()
            cpu[k].append((time.thread_time() - c0) * 1e3)
            wall[k].append((time.perf_counter() - t0) * 1e3)
    return {k: {"median_ms": float(np.median(wall[k])), "p95_ms": float(np.percentile(wall[k], 95)),
                "min_ms": float(np.min(wall[k])), "n": repeats, "cpu_median_ms": float(np.median(cpu[k]))}
            for k in fns}


def baseline_parts(KB, frames, intr, T) -> dict:
    """Part rows of the pre-one-pass version (vertices, quad codes, raster, merge, normals)."""
    m = KB.KinectMerger(intr)
    for f in frames[:2]:
        m.step(f.depth_m, f.known, f.T_world_from_cam)
    f2 = frames[2]
    ws, cfg = m._ws, m.config
    rays, use_table, rx, ry, camv, dist, _, has_dist = m._cam[:8]
    R, t = np.ascontiguousarray(T.rotation), np.ascontiguousarray(T.translation)
    k2s, k2d = np.float32(m._k_side2), np.float32(m._k_diag2)
    P_next = np.zeros_like(ws.P[0])

    def raster():
        ws.izbuf.fill(0.0)
        KB._raster_into(ws.V, ws.code, m._weight, ws.izbuf, ws.wbuf)
        KB._rim_flags_into(ws.code, ws.rim)
        KB._rim_splat(ws.V, ws.code, m._weight, ws.rim, ws.izbuf, ws.wbuf)

    def merge():
        near = KB._window_min_into(f2.depth_m, f2.known, cfg.occlusion_radius_px, ws.near_tmp, ws.near_new)
        return KB._merge_zbuffer(ws.izbuf, ws.wbuf, f2.depth_m, f2.known, near, cfg.max_weight,
                                 cfg.threshold, cfg.threshold_abs_m, rays, use_table, rx, ry, P_next)

    KB._vertices_into(m._depth, rays, use_table, rx, ry, R, t, camv, dist, has_dist, cfg.near_m, ws.V, ws.G)
    KB._codes_into(m._P, ws.G, k2s, k2d, ws.code)
    return {
        "  baseline: vertices (transform + project)": lambda: KB._vertices_into(
            m._depth, rays, use_table, rx, ry, R, t, camv, dist, has_dist, cfg.near_m, ws.V, ws.G),
        "  baseline: quad codes (stretch test)": lambda: KB._codes_into(m._P, ws.G, k2s, k2d, ws.code),
        "  baseline: rasterise + z-buffer + rim splat": raster,
        "  baseline: merge (occlusion window + average + points)": merge,
        "  baseline: normals": lambda: KB._normals(P_next, k2s),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--frames", type=int, default=12, help="simulated frames to cycle through")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--baseline", type=Path, default=None,
                        help="another kinect.py to time side by side (e.g. the last commit's)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    import torch

    torch.set_num_threads(1)
    import kornia

    sim = KinectSimulator(load_scene("office"), load_trajectory("orbit_inward"), seed=0)
    frames = list(sim.run(args.frames / sim.config.rate_hz))
    intr = sim.config.intrinsics
    order = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))  # ping-pong: neighbours only
    cycle = iter(order * 10_000)

    KB = load_baseline(args.baseline) if args.baseline else None
    mergers = {"new": K.KinectMerger(intr)}
    if KB is not None:
        mergers["baseline"] = KB.KinectMerger(intr)
    for merger in mergers.values():
        for f in frames:
            merger.step(f.depth_m, f.known, f.T_world_from_cam)
    current = [frames[0]]

    def advance():
        current[0] = frames[next(cycle)]

    def stepper(merger):
        def step():
            f = current[0]
            merger.step(f.depth_m, f.known, f.T_world_from_cam)
        return step

    def step():
        advance()
        stepper(mergers["new"])()

    # a frozen state for the part rows: the merger after frame 1, warping into frame 2's view
    m = K.KinectMerger(intr)
    for f in frames[:2]:
        m.step(f.depth_m, f.known, f.T_world_from_cam)
    f2 = frames[2]
    T = RigidTransform(f2.T_world_from_cam.inverse().matrix @ frames[1].T_world_from_cam.matrix)
    ws, cfg, cam = m._ws, m.config, m._cam
    rays, use_table, rx, ry, camv, dist, _, has_dist, rx32, ry32 = cam
    R, t = np.ascontiguousarray(T.rotation), np.ascontiguousarray(T.translation)
    k2s, k2d = np.float32(m._k_side2), np.float32(m._k_diag2)
    E_prev = ws.E.copy()  # the edge flags of frame 1's merged map; the merge row overwrites ws.E
    E_next = np.zeros_like(ws.E)

    def warp():
        KK.warp_kernel(m._depth, E_prev, m._weight, R, t, rays, use_table, rx, ry, rx32, ry32, camv, dist,
                       has_dist, cfg.near_m, ws.zw, ws.s_t, ws.s_z, ws.s_w)

    def window():
        return K._window_min_into(f2.depth_m, f2.known, cfg.occlusion_radius_px, ws.near_tmp, ws.near_new)

    warp()
    near = window()

    def merge_normals():
        return KK.merge_normals(ws.zw, f2.depth_m, f2.known, near, np.float32(cfg.max_weight),
                                np.float32(cfg.threshold), np.float32(cfg.threshold_abs_m), rays, use_table, rx32,
                                ry32, k2s, k2d, E_next)

    prev_depth, prev_known = m._depth, m._depth > 0
    weight = np.ascontiguousarray(m._weight)
    warped = K.warp_depth(prev_depth, weight, prev_known, intr, T)
    Kt = torch.from_numpy(intr.K.astype(np.float32))[None]
    T_prev_from_cur = torch.from_numpy(T.inverse().matrix.astype(np.float32))[None]
    src_t = torch.from_numpy(prev_depth.astype(np.float32))[None, None]
    dst_t = torch.from_numpy(warped[0])[None, None]
    depth_t = torch.from_numpy(f2.depth_m)[None, None]
    pts = cv2.depthTo3d(f2.depth_m, intr.K)
    fals = cv2.RgbdNormals.create(intr.height, intr.width, cv2.CV_32F, intr.K, 5, 50.0,
                                  cv2.RgbdNormals_RGBD_NORMALS_METHOD_FALS)
    cross = cv2.RgbdNormals.create(intr.height, intr.width, cv2.CV_32F, intr.K, 5, 50.0,
                                   cv2.RgbdNormals_RGBD_NORMALS_METHOD_CROSS_PRODUCT)
    r = args.repeats
    rows = {}
    if KB is not None:  # the two steps alternate call by call on the same frames
        fns = {"new": stepper(mergers["new"]), "baseline": stepper(mergers["baseline"])}
        both = interleaved({"advance": advance, **fns}, r)
        rows["KinectMerger.step (warp + merge + normals)"] = both["new"]
        rows["baseline: KinectMerger.step"] = both["baseline"]
    cases = {
        "KinectMerger.step (warp + merge + normals)": step,
        "  warp (vertices, quad codes, rasterise, rim splat: one pass)": warp,
        "  occlusion window (min filter of the new depth)": window,
        "  merge + normals + edge flags": merge_normals,
        "warp_depth (pure, allocates scratch)": lambda: K.warp_depth(prev_depth, weight, prev_known, intr, T),
        "merge_depth (pure)": lambda: K.merge_depth(*warped, f2.depth_m, f2.known),
        "normals_from_depth (pure)": lambda: K.normals_from_depth(f2.depth_m, f2.known, intr),
        "ref: cv2.warpFrame (point warp, cracks)": lambda: cv2.warpFrame(  # no None image / mask: OpenCV 5.1 crashes
            prev_depth, np.zeros((*prev_depth.shape, 3), np.uint8), np.full(prev_depth.shape, 255, np.uint8), T.matrix,
            intr.K),
        "ref: kornia warp_frame_depth (backward)": lambda: kornia.geometry.depth.warp_frame_depth(
            src_t, dst_t, T_prev_from_cur, Kt),
        "ref: cv2.RgbdNormals FALS (+ depthTo3d)": lambda: fals.apply(cv2.depthTo3d(f2.depth_m, intr.K)),
        "ref: cv2.RgbdNormals CROSS_PRODUCT": lambda: cross.apply(pts),
        "ref: kornia depth_to_normals": lambda: kornia.geometry.depth.depth_to_normals(depth_t, Kt),
    }
    if KB is not None:
        del cases["KinectMerger.step (warp + merge + normals)"]
        if hasattr(KB, "_raster_into"):  # its parts right after ours
            names = list(cases)
            at = names.index("  merge + normals + edge flags") + 1
            cases = {**{k: cases[k] for k in names[:at]}, **baseline_parts(KB, frames, intr, T),
                     **{k: cases[k] for k in names[at:]}}
    for name, fn in cases.items():
        reps = r if not name.startswith("ref: kornia") else max(5, r // 6)
        row = time_it(fn, reps, warmup=3)
        row["cpu_median_ms"] = thread_ms(fn, reps)
        rows[name] = row
    width = max(len(k) for k in rows)
    print(f"{'case (640x480, one thread)':<{width}}  {'median ms':>10}  {'p95 ms':>8}  {'cpu med ms':>10}  {'n':>4}")
    for name, row in rows.items():
        print(f"{name:<{width}}  {row['median_ms']:>10.2f}  {row['p95_ms']:>8.2f}  {row['cpu_median_ms']:>10.2f}  {row['n']:>4}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
