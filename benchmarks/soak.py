"""Soak test and fault recovery (issue 22, items 4 and 5): a benchmark, not a CI test.

    python benchmarks/soak.py soak [--minutes 10] [--colour-size 960x540] [--no-render] [--runs both] [--out runs/soak]
    python benchmarks/soak.py recovery [--duration 40] [--trajectory alternating] [--scene office] [--only WORD] [--set K=V] [--out runs/recovery]
    python benchmarks/soak.py join [--duration 120] [--every 20] [--out runs/join]
    python benchmarks/soak.py quality LOG [--every 10] [--set KEY=VALUE]

``soak``: a long simulated session of the office with every fault on (random depth and colour
dropouts and bursts of them, tracking losses with no pose and with a frozen pose, relocalisation
jumps, timestamp jitter, reordering, frozen colour frames), a scene change (the box on the table
goes at 40 % of the session) and the ceiling lamp dimming (at 60 %), run live through the pipeline
with compositing on, and the same session without faults. The device alternates the default
trajectory's two orbits (outward, inward, joined by blends), 20 s a cycle. Reports peak RSS and RSS
over the session, per-frame times over the session (median per minute), what the pipeline skipped
and why against what the device did, and the final maps of both runs against the true map at the
end. No log is written (ten minutes of colour frames would take gigabytes); packets go through
:func:`rgbd_envmap.logs.as_logged`, as in ``simulate``.

``recovery``: a session of the office with one fault early in it (a depth or colour dropout burst,
a tracking loss without pose or with a frozen pose, a relocalisation jump, random dropouts), each
against the fault-free run: final coverage and WS-PSNR (criterion: within 0.5 dB). By default 40 s
of the alternating orbits, so that the part of the room the fault hid is seen again; with
``--trajectory orbit --duration 20`` the default session, whose outward orbit passes only once.

``join``: the default session with its orbits cut (the old trajectory) and blended (the new one),
scored against the truth every ``--every`` seconds: the trajectory fix before and after, and the
quality over a long session.

``quality``: replay a recorded session log and print coverage and WS-PSNR against its true map
every ``--every`` seconds (the 20 s → 120 s study in docs/studies/soak.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apps.process import configure_process  # noqa: E402

configure_process()  # one BLAS and one OpenCV thread, as the apps run

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from rgbd_envmap import metrics  # noqa: E402
from rgbd_envmap.logs import as_logged  # noqa: E402
from rgbd_envmap.pipeline import DEPTH_TOTAL, DepthStep, Pipeline, PipelineConfig, RenderConfig  # noqa: E402
from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.faults import FaultConfig, PoseJump, Span, TrackingLoss, random_spans  # noqa: E402
from sim.groundtruth import render_envmap  # noqa: E402
from sim.scene import SCENES_DIR, load_scene, scene_from_dict  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import SequenceTrajectory, load_trajectory  # noqa: E402


def rss_mib() -> float:
    """Resident set size now, from /proc (MiB)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def peak_rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def map_scores(em, truth) -> dict:
    gv = truth.valid
    covered = em.valid & gv
    return {"coverage_pct": 100.0 * metrics.coverage_of(em.valid, gv),
            "ws_psnr_db": metrics.ws_psnr(np.clip(em.radiance, 0, 1), np.clip(truth.radiance, 0, 1), covered)
            if covered.any() else float("nan")}


def soak_scene(duration_s: float):
    """The office with its box removed at 40 % of the session and its lamp dimmed at 60 %."""
    spec = yaml.safe_load((SCENES_DIR / "office.yaml").read_text())
    for obj in spec["objects"]:
        if obj.get("name") == "ceiling_lamp":
            obj["timeline"] = [{"t": round(0.6 * duration_s, 3), "scale": 0.4}]
        if obj.get("name") == "removed_box":
            obj["visible"] = {"until": round(0.4 * duration_s, 3)}
    return scene_from_dict(spec)


def alternating_orbits(duration_s: float) -> SequenceTrajectory:
    """The default trajectory's outward and inward orbits in turn, 10 s each, joined by 2 s blends."""
    outward, inward = load_trajectory("orbit").parts
    n = int(math.ceil(duration_s / 10.0)) + 1
    parts = tuple(outward if i % 2 == 0 else inward for i in range(n))
    return SequenceTrajectory(parts, tuple(10.0 * (i + 1) for i in range(n - 1)), (2.0,) * (n - 1))


def soak_faults(duration_s: float, seed: int = 1) -> FaultConfig:
    """Every fault on, from the first minute on (bursts at random, about every 20–60 s)."""
    after = min(60.0, 0.2 * duration_s)
    losses = [TrackingLoss(s.start_s, s.duration_s, "none") for s in random_spans(seed + 1, duration_s, 45.0, 1.0, after_s=after)]
    losses += [TrackingLoss(s.start_s, s.duration_s, "frozen") for s in random_spans(seed + 2, duration_s, 60.0, 0.8, after_s=after)]
    losses = sorted(losses, key=lambda s: s.start_s)
    jumps = tuple(PoseJump(s.start_s, s.duration_s, (0.08, -0.05, 0.02), 4.0)
                  for s in random_spans(seed + 3, duration_s, 60.0, 3.0, after_s=after))
    return FaultConfig(
        seed=seed, depth_dropout_p=0.03, depth_dropout_bursts=random_spans(seed + 4, duration_s, 30.0, 1.5, after_s=after),
        colour_dropout_p=0.02, colour_dropout_bursts=random_spans(seed + 5, duration_s, 30.0, 0.5, after_s=after),
        tracking_loss=tuple(losses), pose_jumps=jumps, timestamp_jitter_ms=4.0, reorder_window=3,
        frozen_colour_p=0.02, frozen_colour_bursts=random_spans(seed + 6, duration_s, 40.0, 0.5, after_s=after),
    )


def run_session(scene, trajectory, duration_s: float, faults: FaultConfig | None, config: PipelineConfig,
                *, label: str, sample_s: float = 5.0, colour_size: tuple[int, int] = (960, 540),
                score_every_s: float | None = None) -> dict:
    """Simulate and run the pipeline live; sample RSS and per-frame times; score the final map."""
    counts: dict[str, int] = {}

    def on_fault(event: dict) -> None:
        for name in event["faults"]:
            counts[name] = counts.get(name, 0) + 1

    device = TangoDeviceConfig(colour=replace(ColourCameraConfig(), width=colour_size[0], height=colour_size[1]))
    sim = Simulator(scene, trajectory, device, seed=0, faults=faults, on_fault=on_fault)
    origin = np.asarray(scene.virtual_object_position, np.float64)
    rss, frames = [], []
    # What simulate's run keeps per packet besides the pipeline: its accuracy tracker (apps/accuracy.py).
    from apps.accuracy import AccuracyTracker

    tracker = AccuracyTracker()
    wall0 = time.perf_counter()
    next_sample = 0.0
    next_score = score_every_s if score_every_s else math.inf
    scored = []
    n_packets = 0
    with Pipeline(config, sim.calibration, origin) as pipe:
        timer = pipe.timer
        for sp in sim.run(duration_s):
            n_packets += 1
            t0 = time.perf_counter()
            steps = pipe.feed(as_logged(sp.packet))
            ms = (time.perf_counter() - t0) * 1e3
            if sp.packet.kind == "colour":
                tracker.on_colour(sp.packet.timestamp_ns, sp.groundtruth)
            else:
                depth_gt = sp.groundtruth
            for r in steps:
                if isinstance(r, DepthStep):
                    frames.append((sp.t_s, ms))
                    tracker.on_depth(r, depth_gt)  # the step is the latest depth packet's
            # The run keeps per-stage records for its report; the soak needs only the totals above.
            timer.records.clear()
            if sp.t_s >= next_score:  # the map against the truth of that moment
                truth = render_envmap(sim.raycaster, origin, config.capture.height, config.capture.width, sp.t_s)
                scored.append({"t_s": round(sp.t_s, 2), **map_scores(pipe.capture.em, truth)})
                next_score += score_every_s
            if sp.t_s >= next_sample:
                rss.append((round(sp.t_s, 2), round(rss_mib(), 1), round(tracker.retained_bytes() / 2**20, 2)))
                next_sample += sample_s
                print(f"[{label}] t={sp.t_s:7.1f} s rss={rss[-1][1]:.0f} MiB wall={time.perf_counter() - wall0:.0f} s",
                      flush=True)
        pipe.finish()
        wall = time.perf_counter() - wall0
        truth = render_envmap(sim.raycaster, origin, config.capture.height, config.capture.width, duration_s)
        scores = map_scores(pipe.capture.em, truth)
        skipped = dict(sorted(pipe.skipped.items()))
        processed = pipe.depth_steps
        late_pairs, accepted = pipe.late_pairs, pipe.map_check_accepted
    tracker_mib = tracker.retained_bytes() / 2**20
    t = np.array([f[0] for f in frames])
    ms = np.array([f[1] for f in frames])
    per_minute = []
    for m in range(int(math.ceil(duration_s / 60.0))):
        sel = (t >= 60 * m) & (t < 60 * (m + 1))
        if sel.any():
            per_minute.append({"minute": m + 1, "frames": int(sel.sum()), "median_ms": round(float(np.median(ms[sel])), 2),
                               "p95_ms": round(float(np.percentile(ms[sel], 95)), 2)})
    after_first = [r for tt, r, _ in rss if tt >= min(60.0, 0.2 * duration_s)]
    return {
        "label": label, "duration_s": duration_s, "packets": n_packets, "depth_frames_processed": processed,
        "wall_s": round(wall, 1), "peak_rss_mib": round(peak_rss_mib(), 1), "rss_mib": rss,  # (t_s, RSS MiB, tracker MiB)
        "rss_growth_after_first_minute_mib": round(max(after_first) - after_first[0], 1) if after_first else None,
        "depth_feed_ms_per_minute": per_minute,
        "scores_over_time": scored, "accuracy_tracker_mib": round(tracker_mib, 1), "accuracy_tracker_mib_per_minute": round(tracker_mib / (duration_s / 60), 2), "faults": dict(sorted(counts.items())), "skipped": skipped,
        "late_pairs": late_pairs, "map_check_accepted": accepted, **scores,
    }


def cmd_soak(args) -> dict:
    duration = 60.0 * args.minutes
    scene, traj = soak_scene(duration), alternating_orbits(duration)
    config = PipelineConfig(render=RenderConfig(enabled=not args.no_render))
    size = tuple(int(x) for x in args.colour_size.split("x"))
    every = max(10.0, duration / 12)
    runs = {}
    if args.runs in ("both", "faults"):
        runs["faulty"] = run_session(scene, traj, duration, soak_faults(duration), config, label="faults",
                                     colour_size=size, score_every_s=every)
    if args.runs in ("both", "fault-free"):
        runs["fault_free"] = run_session(scene, traj, duration, None, config, label="fault-free", colour_size=size,
                                         score_every_s=every)
    out = {"command": " ".join(sys.argv), **runs}
    if len(runs) == 2:
        faulty, clean = runs["faulty"], runs["fault_free"]
        out["ws_psnr_gap_db"] = round(clean["ws_psnr_db"] - faulty["ws_psnr_db"], 3)
        out["coverage_gap_pct"] = round(clean["coverage_pct"] - faulty["coverage_pct"], 3)
    return out


RECOVERY_FAULTS = {
    "depth dropout burst 3–5 s": FaultConfig(depth_dropout_bursts=(Span(3.0, 2.0),)),
    "colour dropout burst 3–4 s": FaultConfig(colour_dropout_bursts=(Span(3.0, 1.0),)),
    "tracking loss, no pose, 3–5 s": FaultConfig(tracking_loss=(TrackingLoss(3.0, 2.0, "none"),)),
    "tracking loss, frozen pose, 3–4 s": FaultConfig(tracking_loss=(TrackingLoss(3.0, 1.0, "frozen"),)),
    "relocalisation jump 3–4 s (10 cm, 5°)": FaultConfig(pose_jumps=(PoseJump(3.0, 1.0, (0.1, 0.0, 0.0), 5.0),)),
    "relocalisation jumps 5–8 s, 13–16 s (8, −5, 2 cm, 4°)": FaultConfig(pose_jumps=(
        PoseJump(5.0, 3.0, (0.08, -0.05, 0.02), 4.0), PoseJump(13.0, 3.0, (0.08, -0.05, 0.02), 4.0))),
    "random dropouts (5 % depth, 5 % colour)": FaultConfig(seed=3, depth_dropout_p=0.05, colour_dropout_p=0.05),
}


def cmd_recovery(args) -> dict:
    scene = load_scene(args.scene)
    traj = alternating_orbits(args.duration) if args.trajectory == "alternating" else load_trajectory(args.trajectory)
    config = PipelineConfig(render=RenderConfig(enabled=False))
    if args.set:
        from rgbd_envmap.config import apply_overrides

        config = apply_overrides(config, args.set)
    clean = run_session(scene, traj, args.duration, None, config, label="fault-free", sample_s=1e9)
    rows = [{"fault": "none", **{k: clean[k] for k in ("coverage_pct", "ws_psnr_db", "skipped", "depth_frames_processed")}}]
    for name, faults in RECOVERY_FAULTS.items():
        if args.only and not any(word in name for word in args.only):
            continue
        r = run_session(scene, traj, args.duration, faults, config, label=name, sample_s=1e9)
        rows.append({"fault": name, **{k: r[k] for k in ("coverage_pct", "ws_psnr_db", "skipped", "depth_frames_processed",
                                                          "late_pairs", "map_check_accepted")},
                     "ws_psnr_drop_db": round(clean["ws_psnr_db"] - r["ws_psnr_db"], 3),
                     "coverage_drop_pct": round(clean["coverage_pct"] - r["coverage_pct"], 3)})
    return {"command": " ".join(sys.argv), "rows": rows}


def cmd_join(args) -> dict:
    """The default session with its two orbits cut (the old trajectory, a 1.11 m jump at 10 s) and
    blended (the new one), scored against the truth every ``--every`` seconds."""
    scene = load_scene("office")
    blended = load_trajectory("orbit")
    cut = SequenceTrajectory(blended.parts, blended.until_s, (0.0,) * len(blended.until_s))
    config = PipelineConfig(render=RenderConfig(enabled=False))
    out = {"command": " ".join(sys.argv)}
    for label, traj in (("cut (before)", cut), ("blended (after)", blended)):
        r = run_session(scene, traj, args.duration, None, config, label=label, sample_s=1e9, score_every_s=args.every)
        out[label] = {k: r[k] for k in ("scores_over_time", "coverage_pct", "ws_psnr_db", "wall_s")}
    return out


def cmd_quality(args) -> dict:
    from rgbd_envmap.logs import SessionLog

    log = SessionLog.open(args.log)
    gt = np.load(Path(args.log) / "groundtruth" / "envmap.npz")
    config = PipelineConfig(render=RenderConfig(enabled=False))
    if args.set:
        from rgbd_envmap.config import apply_overrides

        config = apply_overrides(config, args.set)

    class Truth:
        valid = np.asarray(gt["valid"], bool)
        radiance = np.asarray(gt["radiance"], np.float32)

    rows = []
    with Pipeline(config, log.calibration, gt["origin"]) as pipe:
        t0 = int(log.depth_timestamps_ns[0])
        mark = args.every
        for p in log:
            t = (p.timestamp_ns - t0) * 1e-9
            if t >= mark:
                rows.append({"t_s": mark, **map_scores(pipe.capture.em, Truth)})
                print(rows[-1], flush=True)
                mark += args.every
            pipe.feed(p)
            pipe.timer.records.clear()
        pipe.finish()
        rows.append({"t_s": round(t, 2), **map_scores(pipe.capture.em, Truth)})
    return {"command": " ".join(sys.argv), "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("soak")
    s.add_argument("--minutes", type=float, default=10.0)
    s.add_argument("--no-render", action="store_true")
    s.add_argument("--colour-size", default="960x540", metavar="WxH", help="the colour camera's resolution")
    s.add_argument("--out", type=Path, default=Path("runs/soak"))
    s.add_argument("--runs", choices=("both", "faults", "fault-free"), default="both",
                   help="which sessions to run (two processes can run one each, side by side)")
    r = sub.add_parser("recovery")
    r.add_argument("--duration", type=float, default=40.0)
    r.add_argument("--trajectory", default="alternating",
                   help="alternating (the default orbit's two parts in turn: the fault's region is seen again) or a name")
    r.add_argument("--out", type=Path, default=Path("runs/recovery"))
    r.add_argument("--scene", default="office", help="office (lit, the default) or office_unlit (faster)")
    r.add_argument("--only", action="append", default=[], metavar="WORD",
                   help="run only the faults whose name contains WORD (repeatable), besides the fault-free run")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a config override for every run (e.g. colour_fallback_lag_ms=null: the earlier pairing)")
    j = sub.add_parser("join")
    j.add_argument("--duration", type=float, default=120.0)
    j.add_argument("--every", type=float, default=20.0)
    j.add_argument("--out", type=Path, default=Path("runs/join"))
    q = sub.add_parser("quality")
    q.add_argument("log", type=Path)
    q.add_argument("--every", type=float, default=10.0)
    q.add_argument("--set", action="append", default=[])
    q.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    result = {"soak": cmd_soak, "recovery": cmd_recovery, "join": cmd_join, "quality": cmd_quality}[args.cmd](args)
    text = json.dumps(result, indent=2, default=float)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / f"{args.cmd}.json").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
