"""Accuracy of the Kinect warp / merge path (paper 001 §4.2) against simulator ground truth, beside the
raw sensor and an Open3D TSDF (KinectFusion-style) reconstruction ray-cast back into each view.

    python benchmarks/eval_kinect.py [--duration S] [--trajectory NAME] [--no-tsdf] [--json PATH]
                                     [--variant KEY=VALUE[,KEY=VALUE...]] ...

A 30 Hz session of the simulated Kinect (``sim.kinect.KinectSimulator``, office scene, by default the
``orbit_inward`` trajectory: circling the virtual object at 1 m, so foreground objects move across the
background and disocclude it) runs through, per frame:

* **raw**: the sensor's depth and ``normals_from_depth`` of it;
* **merged**: :class:`rgbd_envmap.ingest.kinect.KinectMerger` with the default config, and the same
  with ``occlusion_radius_px=0`` (the paper's rule alone, no occlusion test of warped-only pixels);
  each ``--variant`` adds a merger whose :class:`KinectMergeConfig` fields differ as given (all run
  on the same frames, so a sweep costs one simulation);
* **TSDF**: Open3D ``t.geometry.VoxelBlockGrid`` (1 cm voxels, truncation 4 voxels) integrating every raw frame, ray-cast
  into the current view after integrating it (``weight_threshold=1``; colour uint8 beside uint16 depth;
  ``ScalableTSDFVolume`` is broken in open3d 0.20). Open3D is limited to one thread (OMP_NUM_THREADS=1).

Metrics, over the frames after the first ``--skip`` (history needs a few frames):

* depth error on the pixels known in the raw frame *and* the estimate (true surface present): RMSE,
  MAE, median |e|, and the ratio of the estimate's mean RMSE to raw (target merged ≤ 0.6×);
* normal angular error (degrees) on pixels valid in raw and estimate: median and mean (target ≤ 0.5×);
* holes: fraction of the raw frame's holes (true surface present, no measurement) the estimate fills
  (target ≥ 50 %), with the median and 95th percentile |e| there;
* outliers: fraction of the estimate's pixels more than 5 % of the true depth off;
* disocclusion: each pixel's *visibility age* — how many consecutive frames its surface point has
  been visible (ground truth: the point, moved with the true poses into the previous frame, lies inside
  it and within 1 % of that frame's true depth) — and the merged errors by age; "frames to recover" is
  the first age whose median error is at most half the raw frame's, and the first within 2× of that
  of pixels visible for ≥ 10 frames;
* time per frame (wall, median): merger step; TSDF integrate and ray cast.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # Open3D's TSDF on one thread, like everything else here

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap.ingest.kinect import KinectMergeConfig, KinectMerger, normals_from_depth  # noqa: E402
from sim.kinect import KinectSimulator  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402

AGE_BUCKETS = [(0, 0), (1, 1), (2, 2), (3, 3), (4, 5), (6, 9), (10, 10**9)]


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a.astype(np.float64) * b, axis=-1), -1.0, 1.0)))


class _Tsdf:
    """Open3D VoxelBlockGrid fed raw frames, ray-cast into the current view."""

    def __init__(self, K: np.ndarray, width: int, height: int, voxel_m: float = 0.01, trunc_voxels: float = 4.0) -> None:
        import open3d as o3d
        import open3d.core as o3c

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        self.o3d, self.o3c = o3d, o3c
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=voxel_m, block_resolution=8, block_count=100_000,
            device=o3c.Device("CPU:0"))
        self.K = o3c.Tensor(K, o3c.Dtype.Float64)
        self.width, self.height = width, height
        self.trunc = trunc_voxels

    def integrate(self, depth_m: np.ndarray, known: np.ndarray, rgb: np.ndarray, T_cam_from_world: np.ndarray):
        o3d, o3c = self.o3d, self.o3c
        mm = np.where(known, np.round(depth_m * 1000.0), 0).astype(np.uint16)
        depth = o3d.t.geometry.Image(o3c.Tensor(mm))
        colour = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb)))
        ext = o3c.Tensor(T_cam_from_world, o3c.Dtype.Float64)
        blocks = self.vbg.compute_unique_block_coordinates(depth, self.K, ext, 1000.0, 5.0)
        self.vbg.integrate(blocks, depth, colour, self.K, self.K, ext, 1000.0, 5.0, self.trunc)

    def ray_cast(self, T_cam_from_world: np.ndarray):
        o3c = self.o3c
        hashmap = self.vbg.hashmap()
        keys = hashmap.key_tensor()[hashmap.active_buf_indices().to(o3c.int64)]
        ext = o3c.Tensor(T_cam_from_world, o3c.Dtype.Float64)
        res = self.vbg.ray_cast(block_coords=keys, intrinsic=self.K, extrinsic=ext, width=self.width,
                                height=self.height, render_attributes=["depth", "normal"], depth_scale=1000.0,
                                depth_min=0.3, depth_max=5.0, weight_threshold=1.0,
                                trunc_voxel_multiplier=self.trunc, range_map_down_factor=8)
        depth = res["depth"].numpy()[..., 0].astype(np.float32) / 1000.0
        n_cam = res["normal"].numpy().astype(np.float64)  # Open3D returns them in the camera frame
        known = depth > 0
        norm = np.linalg.norm(n_cam, axis=-1, keepdims=True)
        n_cam = np.divide(n_cam, norm, out=np.zeros_like(n_cam), where=norm > 0)
        rays = np.stack(np.meshgrid((np.arange(self.width) - self.K[0, 2].item()) / self.K[0, 0].item(),
                                    (np.arange(self.height) - self.K[1, 2].item()) / self.K[1, 1].item()), -1)
        facing = n_cam[..., 0] * rays[..., 0] + n_cam[..., 1] * rays[..., 1] + n_cam[..., 2] > 0
        n_cam[facing] *= -1
        return depth, known, n_cam.astype(np.float32), known & (norm[..., 0] > 0)


def _visibility_age(prev_age, prev_true_depth, prev_valid, T_prev_from_cur, true_depth, valid, K):
    """Frames each pixel's surface point has been visible (0: newly visible), from ground truth."""
    h, w = true_depth.shape
    age = np.zeros((h, w), np.int32)
    if prev_age is None:
        return age
    v, u = np.nonzero(valid)
    z = true_depth[v, u].astype(np.float64)
    p = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
    q = p @ T_prev_from_cur[:3, :3].T + T_prev_from_cur[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.round(K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]).astype(np.int64)
        vp = np.round(K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]).astype(np.int64)
    inside = (q[:, 2] > 0) & (up >= 0) & (up < w) & (vp >= 0) & (vp < h)
    seen = np.zeros(len(z), bool)
    idx = np.nonzero(inside)[0]
    zp = prev_true_depth[vp[idx], up[idx]]
    seen[idx] = prev_valid[vp[idx], up[idx]] & (np.abs(zp - q[idx, 2]) <= 0.01 * q[idx, 2])
    age[v[seen], u[seen]] = prev_age[vp[seen], up[seen]] + 1
    return age


class _Stats:
    def __init__(self):
        self.rmse, self.mae, self.med, self.nmed, self.nmean, self.fill, self.outl = [], [], [], [], [], [], []
        self.fill_err = []
        self.age_depth = {b: [] for b in AGE_BUCKETS}
        self.age_normal = {b: [] for b in AGE_BUCKETS}

    def add(self, est_d, est_k, est_n, est_nv, raw_k, raw_nv, f, age, keep_err=True):
        tv = f.true_valid
        common = raw_k & est_k & tv
        e = est_d[common].astype(np.float64) - f.true_depth_m[common]
        self.rmse.append(np.sqrt(np.mean(e * e)))
        self.mae.append(np.mean(np.abs(e)))
        self.med.append(np.median(np.abs(e)))
        nb = raw_nv & est_nv & tv
        ang = _angles_deg(est_n[nb], f.true_normals_cam[nb])
        self.nmed.append(np.median(ang))
        self.nmean.append(np.mean(ang))
        holes = tv & ~raw_k
        filled = holes & est_k
        self.fill.append(filled.sum() / max(holes.sum(), 1))
        if filled.any():
            self.fill_err.append(np.abs(est_d[filled] - f.true_depth_m[filled]))
        ek = est_k & tv
        self.outl.append(np.mean(np.abs(est_d[ek] - f.true_depth_m[ek]) > 0.05 * f.true_depth_m[ek]))
        if keep_err:
            err = np.abs(est_d.astype(np.float64) - f.true_depth_m) / np.maximum(f.true_depth_m, 1e-6)
            nerr = _angles_deg(est_n, f.true_normals_cam)
            for lo, hi in AGE_BUCKETS:
                sel = (age >= lo) & (age <= hi) & ek
                self.age_depth[(lo, hi)].append(err[sel])
                seln = (age >= lo) & (age <= hi) & est_nv & tv
                self.age_normal[(lo, hi)].append(nerr[seln])

    def summary(self):
        fe = np.concatenate(self.fill_err) if self.fill_err else np.array([np.nan])
        out = {
            "rmse_m": float(np.mean(self.rmse)), "mae_m": float(np.mean(self.mae)),
            "median_abs_m": float(np.mean(self.med)), "normal_median_deg": float(np.mean(self.nmed)),
            "normal_mean_deg": float(np.mean(self.nmean)), "holes_filled": float(np.mean(self.fill)),
            "fill_median_abs_m": float(np.median(fe)), "fill_p95_abs_m": float(np.percentile(fe, 95)),
            "outliers_5pct": float(np.mean(self.outl)),
        }
        by_age = {}
        for b in AGE_BUCKETS:
            d = np.concatenate(self.age_depth[b]) if self.age_depth[b] else np.array([])
            n = np.concatenate(self.age_normal[b]) if self.age_normal[b] else np.array([])
            by_age[f"{b[0]}-{b[1]}" if b[1] < 10**9 else f"{b[0]}+"] = {
                "n": int(d.size), "depth_rel_median": float(np.median(d)) if d.size else float("nan"),
                "normal_median_deg": float(np.median(n)) if n.size else float("nan")}
        out["by_age"] = by_age
        return out


def _frames_to_recover(by_age: dict, raw_by_age: dict, key: str) -> tuple[str, str]:
    """First visibility age at which the median error is ≤ half the raw frame's at that age, and
    first age within 2× of the steady state (pixels visible for ≥ 10 frames)."""
    half = next((name for name, row in by_age.items() if row["n"] and row[key] <= 0.5 * raw_by_age[name][key]), "never")
    steady = by_age["10+"][key]
    near = next((name for name, row in by_age.items() if row["n"] and row[key] <= 2.0 * steady), "never")
    return half, near


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=4.0)
    parser.add_argument("--trajectory", default="orbit_inward")
    parser.add_argument("--scene", default="office")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip", type=int, default=10, help="frames before the metrics start")
    parser.add_argument("--no-tsdf", action="store_true")
    parser.add_argument("--voxel", type=float, default=0.01, help="TSDF voxel size, metres")
    parser.add_argument("--variant", action="append", default=[],
                        help="extra merger: comma-separated KinectMergeConfig fields, e.g. threshold=0.02,max_weight=8")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    sim = KinectSimulator(load_scene(args.scene), load_trajectory(args.trajectory), seed=args.seed)
    intr = sim.config.intrinsics
    mergers = {"merged": KinectMerger(intr), "merged, no occlusion test": KinectMerger(intr, KinectMergeConfig(occlusion_radius_px=0))}
    for spec in args.variant:
        fields = {}
        for item in spec.split(","):
            key, value = item.split("=")
            fields[key.strip()] = int(value) if key.strip() == "occlusion_radius_px" else float(value)
        mergers[f"merged, {spec}"] = KinectMerger(intr, KinectMergeConfig(**fields))
    stats = {"raw": _Stats(), **{k: _Stats() for k in mergers}}
    times = {k: [] for k in mergers}
    tsdf = None if args.no_tsdf else _Tsdf(intr.K, intr.width, intr.height, args.voxel)
    if tsdf is not None:
        stats["TSDF (Open3D, 1 cm)"] = _Stats()
        times["TSDF integrate"], times["TSDF ray cast"] = [], []
    prev = None
    age = None
    n_frames = 0
    for f in sim.run(args.duration):
        n_frames += 1
        T_true = f.true_T_world_from_cam.matrix
        if prev is not None:
            T_prev_from_cur = np.linalg.inv(prev.true_T_world_from_cam.matrix) @ T_true
            age = _visibility_age(age, prev.true_depth_m, prev.true_valid, T_prev_from_cur, f.true_depth_m, f.true_valid, intr.K)
        else:
            age = np.zeros(intr.shape, np.int32)
        raw_n, raw_nv = normals_from_depth(f.depth_m, f.known, intr)
        score = f.index >= args.skip
        if score:
            stats["raw"].add(f.depth_m, f.known, raw_n, raw_nv, f.known, raw_nv, f, age)
        for name, merger in mergers.items():
            t0 = time.perf_counter()
            r = merger.step(f.depth_m, f.known, f.T_world_from_cam)
            times[name].append((time.perf_counter() - t0) * 1e3)
            if score:
                stats[name].add(r.depth_m, r.known, r.normals, r.normals_valid, f.known, raw_nv, f, age)
        if tsdf is not None:
            T_cw = np.linalg.inv(f.T_world_from_cam.matrix)
            t0 = time.perf_counter()
            tsdf.integrate(f.depth_m, f.known, f.rgb, T_cw)
            t1 = time.perf_counter()
            d, k, n, nv = tsdf.ray_cast(T_cw)
            t2 = time.perf_counter()
            times["TSDF integrate"].append((t1 - t0) * 1e3)
            times["TSDF ray cast"].append((t2 - t1) * 1e3)
            if score:
                stats["TSDF (Open3D, 1 cm)"].add(d, k, n, nv, f.known, raw_nv, f, age)
        prev = f

    summary = {name: s.summary() for name, s in stats.items()}
    raw = summary["raw"]
    print(f"{n_frames} frames of {args.scene} / {args.trajectory} at 30 Hz; metrics over frames {args.skip}.."
          f"{n_frames - 1}\n")
    print("| estimate | depth RMSE mm (× raw) | MAE mm | median mm | normals median ° (× raw) | mean ° "
          "| raw holes filled | filled median / p95 mm | outliers > 5 % |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, s in summary.items():
        print(f"| {name} | {s['rmse_m'] * 1e3:.2f} ({s['rmse_m'] / raw['rmse_m']:.2f}) | {s['mae_m'] * 1e3:.2f} "
              f"| {s['median_abs_m'] * 1e3:.2f} | {s['normal_median_deg']:.1f} ({s['normal_median_deg'] / raw['normal_median_deg']:.2f}) "
              f"| {s['normal_mean_deg']:.1f} | {100 * s['holes_filled']:.0f} % "
              f"| {s['fill_median_abs_m'] * 1e3:.1f} / {s['fill_p95_abs_m'] * 1e3:.1f} | {100 * s['outliers_5pct']:.2f} % |")
    print("\nBy visibility age (frames the surface point has been visible; relative depth error, normal error):\n")
    names = [n for n in summary if n != "raw"]
    print("| age | pixels | " + " | ".join(f"{n}: depth rel. median, normal median °" for n in ["raw"] + names) + " |")
    print("|---" * (2 + len(names) + 1) + "|")
    for age_key in summary["raw"]["by_age"]:
        cells = [f"{summary[n]['by_age'][age_key]['depth_rel_median'] * 100:.2f} %, "
                 f"{summary[n]['by_age'][age_key]['normal_median_deg']:.1f}" for n in ["raw"] + names]
        print(f"| {age_key} | {summary['merged']['by_age'][age_key]['n']} | " + " | ".join(cells) + " |")
    print()
    for n in names:
        rec = {k: _frames_to_recover(summary[n]["by_age"], summary["raw"]["by_age"], k)
               for k in ("depth_rel_median", "normal_median_deg")}
        summary[n]["frames_to_recover"] = rec
        print(f"{n}: visibility age at which the median error is ≤ 0.5× raw: depth {rec['depth_rel_median'][0]}, "
              f"normals {rec['normal_median_deg'][0]}; within 2× of the steady state (age ≥ 10): depth "
              f"{rec['depth_rel_median'][1]}, normals {rec['normal_median_deg'][1]}")
    print("\nTime per frame (wall, ms): " + ", ".join(
        f"{k} median {np.median(v[3:]):.1f} / p95 {np.percentile(v[3:], 95):.1f}" for k, v in times.items()))
    if args.json:
        summary["time_ms"] = {k: {"median": float(np.median(v[3:])), "p95": float(np.percentile(v[3:], 95))}
                              for k, v in times.items()}
        args.json.write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
