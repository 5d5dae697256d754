"""The ``rgbd-envmap`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["main", "build_parser"]


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 1920x1080, got {text!r}") from None
    if w <= 0 or h <= 0 or w % 2 or h % 2:
        raise argparse.ArgumentTypeError(f"width and height must be even and > 0 (NV21), got {text!r}")
    return w, h


def _em_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 2000x1000, got {text!r}") from None
    if h <= 0 or w != 2 * h:
        raise argparse.ArgumentTypeError(f"an equirect map is twice as wide as high (W = 2H > 0), got {text!r}")
    return w, h


def _xyz(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in metres, got {text!r}") from None


class _HelpFormatter(argparse.HelpFormatter):
    """Shows an option's default only where it says something: not for flags, empty values, or
    help texts that already name the default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or default in (None, False, [], argparse.SUPPRESS) or not action.option_strings
                or action.nargs == 0):
            return text
        return text + " (default: %(default)s)"


def _add_pipeline_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "pipeline settings",
        "Defaults follow the paper (Monroy et al. 2018) where it gives a value; ours are the depth "
        "denoising, footprint splatting, free-space carving, colour averaging, the edge margin, the ridge "
        "colour fit and two threads (docs/guide.md lists every field and says whose default it is; "
        "config.yaml of any run holds the resolved values).")
    g.add_argument("--config", type=Path, default=None, metavar="YAML", help="a (partial) PipelineConfig YAML file")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set capture.ccm_method=least_squares --set shading.bands=3 (repeatable)")
    g.add_argument("--em-size", type=_em_size, default=None, metavar="WxH", help="environment map size, e.g. 1000x500")
    g.add_argument("--no-render", action="store_true", help="capture only: no virtual object, no composites")
    from apps.export import add_envmap_args

    add_envmap_args(g)
    o = p.add_argument_group("outputs")
    o.add_argument("--composite-every", type=int, default=30, metavar="N", help="save every N-th composited frame as PNG")
    o.add_argument("--no-video", action="store_true", help="do not write composites.mp4")
    o.add_argument("--rerun", type=Path, default=None, metavar="FILE.rrd",
                   help="also record frames, the map and poses for the rerun viewer (needs rerun-sdk)")
    o.add_argument("--cache-dir", type=Path, default=None, metavar="DIR",
                   help="where the object's PRT transfer is cached (default $RGBD_ENVMAP_CACHE or ~/.cache/rgbd-envmap)")


def _pipeline_config(args: argparse.Namespace):
    from rgbd_envmap.config import apply_overrides, load_yaml
    from rgbd_envmap.pipeline import PipelineConfig

    cfg = load_yaml(PipelineConfig, args.config) if args.config is not None else PipelineConfig()
    extra = []
    if args.em_size is not None:
        extra += [f"capture.width={args.em_size[0]}", f"capture.height={args.em_size[1]}"]
    if args.no_render:
        extra.append("render.enabled=false")
    from apps.export import envmap_config

    return envmap_config(apply_overrides(cfg, extra + list(args.overrides)), args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rgbd-envmap",
        description="Simulated mobile RGB-D capture and real-time environment-map relighting.",
    )
    from rgbd_envmap import __version__

    parser.add_argument("--version", action="version", version=f"rgbd-envmap {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
    sub = parser.add_subparsers(dest="command", required=True)
    fmt = _HelpFormatter
    sim = sub.add_parser(
        "simulate", formatter_class=fmt,
        help="simulate a capture session and run the pipeline on it live",
        description="Simulate a Tango-like device (ToF depth at 5 Hz, colour at 30 Hz with auto-exposure and "
        "white balance) moving through a scene, and run the capture-and-relight pipeline on its packets as "
        "they arrive. Writes into OUT: envmap.npz / envmap.hdr / envmap.exr / envmap.png / envmap_depth.png, composites/ and "
        "composites.mp4, timing.csv / timing.md / timing.png, accuracy.json, depth_frames.csv, config.yaml, "
        "run.json; session/ (the log, with ground truth under groundtruth/), preview/ and simulation.json.",
    )
    sim.add_argument("--duration", type=float, required=True, metavar="SECONDS",
                     help="simulated time to record, in seconds (at most 86400)")
    sim.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    sim.add_argument("--scene", default="office", metavar="NAME", help="packaged scene name (office, empty) or a YAML path")
    sim.add_argument("--trajectory", default=None, metavar="NAME",
                     help="packaged trajectory name (orbit, orbit_inward, sweep, ...) or a YAML path (default: the scene's)")
    sim.add_argument("--seed", type=int, default=0, metavar="N", help="random seed; equal seeds give identical sessions")
    sim.add_argument("--colour-size", type=_size, default=None, metavar="WxH",
                     help="colour camera resolution in pixels (default 960x540; 960x720 for --device phone)")
    sim.add_argument("--tracking-noise-m", type=float, default=0.0, metavar="METRES", help="σ of reported-position noise per packet")
    sim.add_argument("--tracking-noise-deg", type=float, default=0.0, metavar="DEGREES", help="σ of reported-rotation noise per packet")
    sim.add_argument("--no-auto-exposure", action="store_true", help="hold the exposure gain at 1")
    sim.add_argument("--no-auto-white-balance", action="store_true", help="hold the white-balance gains at 1")
    sim.add_argument("--no-bracketing", action="store_true",
                     help="no exposure brackets (HDR capture's −4 / −2 EV frames; docs/design/hdr.md)")
    sim.add_argument("--preview-envmap-height", type=int, default=500, metavar="PIXELS",
                     help="height of the ground-truth environment map preview (width = 2 × height)")
    sim.add_argument("--overwrite", action="store_true",
                     help="replace an existing OUT, once the new run is complete (without it a non-empty OUT is refused)")
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
    sim.add_argument("--record-only", action="store_true", help="record the session without running the pipeline")
    sim.add_argument("--device", choices=("tango", "kinect", "phone"), default="tango",
                     help="tango: ToF point clouds (5 Hz) + NV21 colour (30 Hz), run live; kinect: registered 640×480 depth + "
                     "colour (30 Hz), recorded as a TUM RGB-D sequence in OUT/session and replayed through the Kinect path; "
                     "phone: a LiDAR phone (256×192 depth registered to 4:3 colour), recorded in the Stray Scanner layout "
                     "in OUT/session and replayed through the mobile path")
    sim.add_argument("--reference-every", type=float, default=5.0, metavar="SECONDS",
                     help="render a reference composite (the scene with and without the virtual object, in linear radiance) for "
                     "the first composited colour frame that shows the object in every window of SECONDS of the session, into "
                     "OUT/reference/, and score the "
                     "composite against it in accuracy.json (composite_*_rel_rmse); 0: none")
    sim.add_argument("--reference-method", choices=("gather", "path"), default="gather",
                     help="gather: the frame without the object is the bake (Mitsuba's global illumination) and only the "
                     "object's pixels and the change it makes around it are traced (little noise); path: both frames "
                     "path-traced by Mitsuba")
    sim.add_argument("--reference-spp", type=int, default=64, metavar="N",
                     help="per pixel near the object: directions towards it (gather) or paths (path)")
    sim.add_argument("--reference-object-spp", type=int, default=256, metavar="N",
                     help="paths per pixel of the object itself (gather)")
    sim.add_argument("--reference-radius", type=float, default=0.5, metavar="METRES",
                     help="render the pixels that see the object or a surface within METRES of it (the rest shows "
                     "the bake in both frames); 0: the whole frame")
    from sim.faults import add_arguments as add_fault_args

    add_fault_args(sim)
    _add_pipeline_args(sim)

    from rgbd_envmap.sources.frames import layouts_text

    class _ReplayFormatter(fmt):
        """Keeps the layouts table's lines (indented ones) as written; fills the rest."""

        def _fill_text(self, text, width, indent):
            parts = text.split("\n\n")
            return "\n\n".join("\n".join(indent + line for line in part.splitlines()) if part.startswith("  ")
                               else super(_ReplayFormatter, self)._fill_text(part, width, indent) for part in parts)

    rep = sub.add_parser(
        "replay", formatter_class=_ReplayFormatter,
        help="run the pipeline on a recording: session log, TUM RGB-D, ICL-NUIM, Redwood, phone capture, RealSense bag",
        description="Replay a recording through the pipeline, with any settings. Writes the same run folder as simulate "
        "(without session/ and preview/). Unreadable packets are skipped and counted in run.json, or end the run with "
        "--strict.\n\nLOG is recognised by its files, in this order (layout: files; where its poses come from):\n\n"
        + layouts_text() + "\n\nRGB-D recordings (TUM RGB-D, ICL-NUIM, Redwood, RealSense) take --intrinsics, "
        "--depth-scale and --poses; TUM RGB-D also --tum-depth-correction. A recording without poses (a RealSense bag, "
        "a TUM validation sequence, a Redwood folder without its trajectory) needs --poses FILE.",
    )
    rep.add_argument("log", type=Path, metavar="LOG",
                     help="the recording: a folder (session log, TUM RGB-D, ICL-NUIM or Redwood sequence, phone capture) "
                     "or a RealSense .bag file")
    rep.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    rep.add_argument("--origin", type=_xyz, nargs=3, default=None, metavar=("X", "Y", "Z"),
                     help="EM origin in world metres (default: the log's true-map origin, else 1 m in front of the first camera)")
    rep.add_argument("--strict", action="store_true", help="stop at the first unreadable packet instead of skipping it")
    rep.add_argument("--overwrite", action="store_true",
                     help="replace an existing OUT, once the new run is complete (without it a non-empty OUT is refused)")
    rep.add_argument("--quiet", action="store_true", help="no progress bar")
    seq = rep.add_argument_group(
        "RGB-D recordings (TUM RGB-D, ICL-NUIM, Redwood, RealSense)",
        "Camera, depth and poses of a recording; run.json records which intrinsics were used and why.")
    seq.add_argument("--intrinsics", default=None, metavar="fr1|fr2|fr3|default|icl-nuim|primesense|FILE",
                     help="the camera: a preset (the TUM benchmark's freiburg1/2/3 calibrations with their distortion, "
                     "the ROS default fx = fy = 525, ICL-NUIM's fx = 481.2, fy = -480, Open3D's PrimeSense default) or a "
                     "JSON file: Intrinsics (width, height, fx, fy, cx, cy, distortion {k1, k2, p1, p2, k3}) or Open3D's "
                     "PinholeCameraIntrinsic (width, height, intrinsic_matrix). Default: TUM: calibration.json if the "
                     "folder has one, else the camera its name names (rgbd_dataset_freiburg1_* → fr1), else default; "
                     "ICL-NUIM: icl-nuim; Redwood: camera_intrinsic.json, else primesense; RealSense: the bag's")
    seq.add_argument("--depth-scale", type=float, default=None, metavar="UNITS_PER_M",
                     help="depth units per metre (default: TUM RGB-D and ICL-NUIM 5000, Redwood 1000, RealSense the bag's)")
    seq.add_argument("--tum-depth-correction", action="store_const", const="auto", default=None,
                     help="TUM RGB-D: multiply the depth by the benchmark's correction factor of the freiburg camera in use "
                     "(fr1 1.035, fr2 1.031, fr3 1.0; from --intrinsics or the folder name). The published depth "
                     "images already carry it: this is for recordings that do not")
    seq.add_argument("--poses", type=Path, default=None, metavar="FILE",
                     help="a trajectory instead of the recording's own, or for one that has none: TUM format (timestamp "
                     "tx ty tz qx qy qz qw, looked up by time) or the .log format (per frame a line 'frame frame frame+1' "
                     "and a 4x4 camera-to-world matrix, looked up by frame number)")
    _add_pipeline_args(rep)

    rpt = sub.add_parser("report", formatter_class=fmt, help="regenerate the reports of a run folder",
                         description="Rewrite timing.csv, timing.md and timing.png of RUN from its stage_times.csv, "
                         "accuracy.json and run.json. RUN: a run folder written by simulate or replay (it needs "
                         "stage_times.csv; accuracy.json, run.json and config.yaml are read when present).")
    rpt.add_argument("run", type=Path, metavar="RUN", help="a run folder written by simulate or replay")

    sw = sub.add_parser(
        "sweep", formatter_class=fmt, help="speed-vs-error grid over pipeline settings",
        description="Replay one recorded log under a grid of settings (EM size, SH bands, hole filling, "
        "correction method, translation method; with rendering on: light sampler and count, composite mode; "
        "composites scored against the run's reference frames), in parallel over the cores, and write sweep.csv, "
        "sweep.md (time and error side by side) and pareto.png. LOG: a session log written by simulate (the "
        "session/ folder of a run, with its groundtruth/: the errors are measured against it); other layouts "
        "are not swept.",
    )
    sw.add_argument("log", type=Path, metavar="LOG", help="session log folder recorded by simulate (RUN/session)")
    sw.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    sw.add_argument("--jobs", type=int, default=None, metavar="N", help="parallel processes (default: the number of cores)")
    sw.add_argument("--axes", nargs="+", default=None, metavar="AXIS",
                    help="which axes to sweep (default all): em_size bands hole_filling ccm translation (rendering off); "
                    "lights composite (rendering on: light sampler × count; composite mode, object shading, tau)")
    sw.add_argument("--reference", type=Path, default=None, metavar="DIR",
                    help="reference frames (<timestamp>.npz of a simulated run) to score the rendering points' composites "
                    "against (default: LOG/../reference if it has any)")
    sw.add_argument("--no-reference", action="store_true", help="do not score composites against reference frames")
    sw.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a setting for every point, before the point's own (repeatable), e.g. the --set of the run that "
                    "recorded LOG")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    from apps.export import add_export_parser

    add_export_parser(sub, fmt)
    return parser


def _print_rejected(run: Path) -> None:
    """One line for the depth frames the capture did not project (``run.json``'s depth_frames_rejected)."""
    try:
        rejected = json.loads((run / "run.json").read_text()).get("depth_frames_rejected") or {}
    except (OSError, ValueError):
        return
    if rejected:
        reasons = ", ".join(f"{why} {n}" for why, n in rejected.items())
        print(f"depth frames not projected into the map: {sum(rejected.values())} ({reasons}; depth_frames.csv)")


def main(argv: list[str] | None = None) -> int:
    from apps.process import configure_process

    configure_process()  # before numpy, OpenCV and the library load
    from rgbd_envmap.errors import LogFormatError, RgbdEnvmapError

    args = build_parser().parse_args(argv)
    from apps.compile_once import install_from_env

    install_from_env()  # a first run's warm-up beside this process: compile each kernel once (scripts/main.sh)
    from apps.run_folder import staged_run

    try:
        if args.command == "simulate":
            colour_size = args.colour_size or ((960, 720) if args.device == "phone" else (960, 540))
            from apps.simulate import SimulateOptions, run_simulate
            from sim.faults import from_arguments as fault_options
            from sim.limits import check_duration

            check_duration(args.duration, "--duration")  # inf or 1e7 before anything is allocated or written
            config = _pipeline_config(args)  # usage errors before anything is written
            from apps.reference_frames import ReferenceOptions

            reference = ReferenceOptions(every_s=args.reference_every, method=args.reference_method, spp=args.reference_spp,
                                         object_spp=args.reference_object_spp,
                                         radius_m=args.reference_radius if args.reference_radius != 0 else None)

            with staged_run(args.out, overwrite=args.overwrite) as partial:
                summary = run_simulate(SimulateOptions(
                    duration_s=args.duration, out=partial, scene=args.scene, trajectory=args.trajectory, seed=args.seed,
                    colour_width=colour_size[0], colour_height=colour_size[1],
                    tracking_noise_m=args.tracking_noise_m, tracking_noise_deg=args.tracking_noise_deg,
                    auto_exposure=not args.no_auto_exposure, auto_white_balance=not args.no_auto_white_balance,
                    bracketing=not args.no_bracketing,
                    preview_envmap_height=args.preview_envmap_height, overwrite=True, progress=not args.quiet,
                    pipeline=not args.record_only, config=config, composite_every=args.composite_every,
                    video=not args.no_video, rerun=args.rerun, cache_dir=args.cache_dir, device=args.device,
                    faults=fault_options(args), reference=reference,
                ))
            print(
                f"recorded {summary['depth_packets']} depth and {summary['colour_packets']} colour packets "
                f"in {summary['wall_s']:.1f} s → {args.out / 'session'}"
            )
            if summary["pipeline"]:
                print(f"report: {args.out / 'timing.md'}\ncomposites: {args.out / 'composites'}/"
                      + ("" if args.no_video else f" and {args.out / 'composites.mp4'}"))
                _print_rejected(args.out)
        elif args.command == "replay":
            from apps.replay import ReplayOptions, run_replay

            config = _pipeline_config(args)  # usage errors before anything is written
            from rgbd_envmap.sources.frames import detect_source_layout

            detect_source_layout(args.log)  # and a recording replay cannot read
            with staged_run(args.out, overwrite=args.overwrite) as partial:
                summary = run_replay(ReplayOptions(
                    log=args.log, out=partial, origin=tuple(args.origin) if args.origin else None, config=config,
                    composite_every=args.composite_every, video=not args.no_video, progress=not args.quiet,
                    strict=args.strict, rerun=args.rerun, cache_dir=args.cache_dir, intrinsics=args.intrinsics,
                    depth_scale=args.depth_scale, poses=args.poses, tum_depth_correction=args.tum_depth_correction,
                ))
            skipped = summary.get("skipped") or {}
            print(f"replayed {summary['depth_packets']} depth and {summary['colour_packets']} colour packets"
                  + (f" (skipped unreadable: {skipped})" if skipped else "") + f" → {args.out / 'timing.md'}")
            _print_rejected(args.out)
        elif args.command == "report":
            from apps.report import write_reports

            write_reports(args.run)
            print(f"wrote {args.run / 'timing.csv'}, {args.run / 'timing.md'}, {args.run / 'timing.png'}")
        elif args.command == "export":
            from apps.export import run_export

            return run_export(args)
        elif args.command == "sweep":
            from apps.sweep import run_sweep

            reference = None if args.no_reference else (args.reference if args.reference is not None else "auto")
            path = run_sweep(args.log, args.out, jobs=args.jobs, axes=args.axes, progress=not args.quiet,
                             reference=reference, base_overrides=args.overrides)
            print(f"wrote {path}")
    except KeyboardInterrupt as exc:
        if args.debug:
            raise
        from apps.run_folder import Terminated, partial_path

        where = ""
        if getattr(args, "out", None) is not None and partial_path(args.out).exists():
            where = f"; the partial run is in {partial_path(args.out)} (its run.json says what it holds)"
        print(f"rgbd-envmap: interrupted{where}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except (RgbdEnvmapError, OSError) as exc:
        if args.debug:
            raise
        # Unreadable or malformed data (a log, a dataset, a file) and the file system: exit 1. Anything
        # else the project raises is about what was asked (options, settings): a usage error, exit 2.
        data = isinstance(exc, (LogFormatError, OSError))
        what = f"{exc.filename}: {exc.strerror}" if isinstance(exc, OSError) and exc.filename else str(exc)
        print(f"rgbd-envmap: error: {' '.join(what.split())}", file=sys.stderr)
        return 1 if data else 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
