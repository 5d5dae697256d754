"""Compare the hole-filling methods on simulated ToF frames: time per frame and depth error.

    python benchmarks/compare_hole_filling.py [--packets N] [--doc docs/design/hole_filling.md]

Runs the simulator's default scene ("office") and trajectory ("orbit") for N depth packets (one every
200 ms), rasterises each point cloud into the 224×172 depth image with ``known`` = confidence ≥ 0.7
(closest point per pixel), fills the holes with every method of :data:`FILL_METHODS` (plus the
original IP-Basic settings, for reference) and scores the filled depth against the simulator's true
z-depth:

* on the pixels each method filled (its own coverage), and
* on the pixels *every* library method (:data:`FILL_METHODS`) filled (the fair comparison), also
  split by why the pixel was unknown (an emissive / shiny / dark surface, a mixed pixel at a depth
  edge, or anything else: grazing incidence, long range, confidence jitter) and by its distance to
  the nearest known pixel. The original-IP-Basic reference row reaches only ~5 px into a hole, so
  it is left out of that set rather than shrinking it.

A last table fills a synthetic noise-free slanted plane with one disc hole, to isolate the effect
of slope and hole size.

Only pixels with a true surface in range can be scored; filled pixels without one are counted. Errors
of the measured (known) pixels are given as the noise floor. Numba and OpenCV run on one thread.
The Markdown tables are printed and, with ``--doc``, written between the ``results`` markers of that
file (the rest of the file, the discussion, is kept).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import cv2
import numba
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.scene import FLAG_BITS, load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402

from rgbd_envmap.depth import FILL_METHODS, fill_holes  # noqa: E402

try:
    from rgbd_envmap.ingest.tango import depth_image_from_points  # noqa: E402

    DEPTH_IMAGE_SOURCE = "rgbd_envmap.ingest.tango.depth_image_from_points"
except ImportError:
    depth_image_from_points = None
    DEPTH_IMAGE_SOURCE = "built in this script from groundtruth['pixel_index'] (ingest.tango not importable)"

CONFIDENCE_THRESHOLD = 0.7
TIMING_REPEATS = 5
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
#: bins of the distance (px) from an unknown pixel to its nearest known pixel.
DIST_BINS = {"≤ 2 px": (0.0, 2.0), "2–5 px": (2.0, 5.0), "5–15 px": (5.0, 15.0), "> 15 px": (15.0, np.inf)}
#: synthetic slanted planes: z-depth slope along x in m/px (0.002 ≈ facing the camera at 2 m,
#: 0.015 ≈ a wall seen at ~55° incidence), and disc hole radii in px.
SLOPES_M_PER_PX = (0.002, 0.015)
HOLE_RADII_PX = (5, 15, 40)

#: label → (method, options). The first three are the library's defaults; the last is IP-Basic as
#: published for KITTI (no large fill, since "extrapolate" is off by default; bilateral σ_r 1.5 m).
CONFIGS: dict[str, tuple[str, dict]] = {m: (m, {}) for m in FILL_METHODS}
CONFIGS["ip_basic (KITTI settings)"] = ("ip_basic", {"large_fill": False, "bilateral_sigma_m": 1.5})


def depth_image(sp, intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(depth_m (H, W) float32, known (H, W) bool) of one depth packet."""
    pkt = sp.packet
    if depth_image_from_points is not None:
        img = depth_image_from_points(pkt.points_m, pkt.confidence, intrinsics,
                                      confidence_threshold=CONFIDENCE_THRESHOLD)
        return img.depth_m, img.known
    # Fallback: the simulator's own pixel of each point; closest confident point wins.
    h, w = intrinsics.height, intrinsics.width
    z = pkt.points_m[:, 2].astype(np.float32)
    ok = (pkt.confidence >= CONFIDENCE_THRESHOLD) & np.isfinite(z) & (z > 0)
    idx, z = sp.groundtruth["pixel_index"][ok], z[ok]
    depth = np.full(h * w, np.inf, np.float32)
    np.minimum.at(depth, idx, z)
    known = np.isfinite(depth)
    return np.where(known, depth, 0.0).astype(np.float32).reshape(h, w), known.reshape(h, w)


def timed_fill(depth, known, method, options):
    times = []
    for _ in range(TIMING_REPEATS):
        t0 = time.perf_counter()
        out = fill_holes(depth, known, method, **options)
        times.append((time.perf_counter() - t0) * 1e3)
    return out, float(np.median(times))


def errors(est: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """MAE, RMSE, p95 |error| in metres (NaN when empty)."""
    if est.size == 0:
        return float("nan"), float("nan"), float("nan")
    e = np.abs(est.astype(np.float64) - truth.astype(np.float64))
    return float(e.mean()), float(np.sqrt(np.mean(e * e))), float(np.percentile(e, 95))


def fmt_mm(x: float) -> str:
    return "–" if not np.isfinite(x) else f"{1e3 * x:.1f}"


def slanted_plane_table(labels: list[str]) -> list[str]:
    """Synthetic check: a noise-free plane z = 2 m + slope·(x − W/2) with one disc hole in the middle;
    MAE over the pixels each method filled (and the share of the hole it filled)."""
    h, w = 172, 224
    yy, xx = np.mgrid[:h, :w]
    out = ["Synthetic slanted plane (224×172, z = 2 m + slope·(x − 112), one centred disc hole, no noise): "
           "MAE in mm over the pixels each method filled (% of the hole filled):", ""]
    cases = [(g, r) for g in SLOPES_M_PER_PX for r in HOLE_RADII_PX]
    out.append("| method | " + " | ".join(f"{1e3 * g:g} mm/px, r = {r} px" for g, r in cases) + " |")
    out.append("|---|" + "---:|" * len(cases))
    for label in labels:
        method, options = CONFIGS[label]
        cells = []
        for g, r in cases:
            truth = (2.0 + g * (xx - w / 2)).astype(np.float32)
            known = (yy - h / 2) ** 2 + (xx - w / 2) ** 2 > r * r
            est, after = fill_holes(np.where(known, truth, np.nan).astype(np.float32), known, method, **options)
            f = after & ~known
            mae = errors(est[f], truth[f])[0]
            cells.append(f"{fmt_mm(mae)} ({100 * f.sum() / (~known).sum():.0f} %)")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--packets", type=int, default=30, help="depth packets (≥ 20)")
    parser.add_argument("--scene", default="office")
    parser.add_argument("--trajectory", default="orbit")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--doc", type=Path, default=None, help="Markdown file to write the results into")
    args = parser.parse_args()

    numba.set_num_threads(1)
    cv2.setNumThreads(1)
    device = TangoDeviceConfig(colour=ColourCameraConfig(width=64, height=48))  # colour unused here
    sim = Simulator(load_scene(args.scene), load_trajectory(args.trajectory), device, seed=args.seed)
    intr = sim.calibration.depth
    for m, o in CONFIGS.values():  # compile / warm up
        fill_holes(np.ones((4, 4), np.float32), np.eye(4, dtype=bool), m, **o)

    labels = list(CONFIGS)
    compared = list(FILL_METHODS)  # the common set and the breakdowns: the library's methods only
    own = {k: [[], []] for k in labels}  # est, truth on each method's own filled pixels
    common = {k: [[], []] for k in compared}
    causes = ("emissive/shiny/dark", "mixed (depth edge)", "other")
    common_cause = {k: {c: [[], []] for c in causes} for k in compared}
    common_dist = {k: {b: [[], []] for b in DIST_BINS} for k in compared}
    ms = {k: [] for k in labels}
    n_filled = {k: 0 for k in labels}
    n_filled_no_truth = {k: 0 for k in labels}
    n_unknown = n_unknown_scorable = n_common = 0
    known_err = [[], []]
    n_pixels = 0

    for i in range(args.packets):
        sp = sim.depth_packet(i, sim.start_ns + i * 200_000_000)
        depth, known = depth_image(sp, intr)
        truth = sp.groundtruth["true_depth_m"]
        valid = sp.groundtruth["true_valid"]
        flagged = (sp.groundtruth["flags"] & (FLAG_BITS["emissive"] | FLAG_BITS["shiny"] | FLAG_BITS["dark"])) != 0
        mixed = sp.groundtruth["mixed"]
        n_pixels += known.size
        n_unknown += int((~known).sum())
        n_unknown_scorable += int((~known & valid).sum())
        kv = known & valid
        known_err[0].append(depth[kv])
        known_err[1].append(truth[kv])
        filled = {}
        for label, (method, options) in CONFIGS.items():
            (out, after), t_ms = timed_fill(depth, known, method, options)
            ms[label].append(t_ms)
            f = after & ~known
            filled[label] = (out, f)
            n_filled[label] += int(f.sum())
            n_filled_no_truth[label] += int((f & ~valid).sum())
            sel = f & valid
            own[label][0].append(out[sel])
            own[label][1].append(truth[sel])
        all_filled = np.logical_and.reduce([filled[k][1] for k in compared]) & valid
        # Distance (px, Euclidean) from each unknown pixel to the nearest known pixel.
        hole_dist = cv2.distanceTransform((~known).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        n_common += int(all_filled.sum())
        for label in compared:
            out = filled[label][0]
            common[label][0].append(out[all_filled])
            common[label][1].append(truth[all_filled])
            for cause, cmask in (("emissive/shiny/dark", flagged), ("mixed (depth edge)", mixed & ~flagged),
                                 ("other", ~flagged & ~mixed)):
                sel = all_filled & cmask
                common_cause[label][cause][0].append(out[sel])
                common_cause[label][cause][1].append(truth[sel])
            for name, (lo, hi) in DIST_BINS.items():
                sel = all_filled & (hole_dist > lo) & (hole_dist <= hi)
                common_dist[label][name][0].append(out[sel])
                common_dist[label][name][1].append(truth[sel])
        print(f"packet {i + 1}/{args.packets}: {100 * (~known).mean():.1f} % unknown", file=sys.stderr)

    cat = np.concatenate
    lines = []
    cmd = "python benchmarks/compare_hole_filling.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    lines.append(f"Command: `{cmd.strip()}`  ")
    lines.append(
        f"Scene `{args.scene}`, trajectory `{args.trajectory}`, seed {args.seed}, {args.packets} depth packets "
        f"(224×172, one every 200 ms); known = confidence ≥ {CONFIDENCE_THRESHOLD}; depth image "
        f"{DEPTH_IMAGE_SOURCE}. Numba and OpenCV on 1 thread; time = median over packets of the per-packet "
        f"median of {TIMING_REPEATS} calls to `fill_holes`."
    )
    lines.append("")
    lines.append(
        f"Unknown pixels: {100 * n_unknown / n_pixels:.1f} % of all pixels; "
        f"{100 * n_unknown_scorable / n_unknown:.1f} % "
        f"of them have a true surface in range (scorable). Common pixels (filled by all of {', '.join(compared)}, "
        f"and scorable): "
        f"{n_common} ({n_common / args.packets:.0f} per frame). Noise floor, measured known pixels vs truth: "
        f"MAE {fmt_mm(errors(cat(known_err[0]), cat(known_err[1]))[0])} mm, "
        f"RMSE {fmt_mm(errors(cat(known_err[0]), cat(known_err[1]))[1])} mm."
    )
    lines.append("")
    lines.append("| method | median ms | p95 ms | filled / frame | filled, no true surface / frame "
                 "| MAE mm (own) | RMSE mm (own) | MAE mm (common) | RMSE mm (common) | p95 mm (common) |")
    lines.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label in labels:
        mae_o, rmse_o, _ = errors(cat(own[label][0]), cat(own[label][1]))
        nan3 = (float("nan"),) * 3
        mae_c, rmse_c, p95_c = errors(cat(common[label][0]), cat(common[label][1])) if label in common else nan3
        t = np.asarray(ms[label])
        lines.append(
            f"| {label} | {np.median(t):.2f} | {np.percentile(t, 95):.2f} | {n_filled[label] / args.packets:.0f} "
            f"| {n_filled_no_truth[label] / args.packets:.0f} | {fmt_mm(mae_o)} | {fmt_mm(rmse_o)} "
            f"| {fmt_mm(mae_c)} | {fmt_mm(rmse_c)} | {fmt_mm(p95_c)} |"
        )
    lines.append("")
    counts = [sum(a.size for a in common_cause[compared[0]][c][0]) for c in causes]
    lines.append("Common pixels by why they were unknown, MAE / RMSE in mm:")
    lines.append("")
    lines.append("| method | " + " | ".join(f"{c} (n = {n})" for c, n in zip(causes, counts)) + " |")
    lines.append("|---|" + "---:|" * len(causes))
    for label in compared:
        cells = []
        for c in causes:
            mae, rmse, _ = errors(cat(common_cause[label][c][0]), cat(common_cause[label][c][1]))
            cells.append(f"{fmt_mm(mae)} / {fmt_mm(rmse)}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Common pixels by distance to the nearest known pixel, MAE / RMSE in mm:")
    lines.append("")
    counts = [sum(a.size for a in common_dist[compared[0]][b][0]) for b in DIST_BINS]
    lines.append("| method | " + " | ".join(f"{b} (n = {n})" for b, n in zip(DIST_BINS, counts)) + " |")
    lines.append("|---|" + "---:|" * len(DIST_BINS))
    for label in compared:
        cells = []
        for b in DIST_BINS:
            mae, rmse, _ = errors(cat(common_dist[label][b][0]), cat(common_dist[label][b][1]))
            cells.append(f"{fmt_mm(mae)} / {fmt_mm(rmse)}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    lines += slanted_plane_table(labels)
    text = "\n".join(lines)
    print(text)

    if args.doc:
        doc = args.doc.read_text() if args.doc.exists() else f"# Hole filling\n\n{BEGIN}\n{END}\n"
        if BEGIN not in doc or END not in doc:
            doc = doc.rstrip("\n") + f"\n\n{BEGIN}\n{END}\n"
        head, rest = doc.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
        args.doc.write_text(f"{head}{BEGIN}\n{text}\n{END}{tail}")
        print(f"wrote {args.doc}", file=sys.stderr)


if __name__ == "__main__":
    main()
