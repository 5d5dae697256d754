"""Phone LiDAR captures (iPhone / iPad, the Stray Scanner layout) through the mobile path.

- :func:`run_replay_phone` replays a capture (:mod:`rgbd_envmap.sources.stray` turns it into depth and
  colour packets and a ``"tango"`` calibration) through :class:`rgbd_envmap.pipeline.Pipeline` and
  writes the run folder of :mod:`apps.run`, as ``replay`` does for a session log.
  :func:`is_phone_capture` recognises the layout.
- :func:`write_phone_capture` simulates a phone (:func:`sim.phone.phone_device`) along a scene's
  trajectory and writes the capture with its ground truth; :func:`run_simulate_phone` does that into
  ``OUT/session`` and replays it into ``OUT`` (what ``simulate --device phone`` runs).

Ground truth beside a capture (``groundtruth/``, written by the simulator, never by the phone) feeds the
accuracy report: ``envmap.npz`` (the true map; its origin is the default EM origin) and
``frames/NNNNNN.npz`` (per frame: the colour camera's gains; at depth frames the true z-depth). The
EM origin is ``--origin`` if given, else the true map's, else 1 m along the first frame's optical axis.

Unreadable files never build a map silently: a depth or confidence PNG that cannot be read skips that
frame's depth packet (counted under ``skipped`` in ``run.json``, the file named); a video that stops
decoding ends the stream there (counted); with ``strict`` either ends the run with the error.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from apps.progress import bar_disable
from apps.run import RunOptions, run_pipeline
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.pipeline import Pipeline
from rgbd_envmap.sources.frames import read_truth
from rgbd_envmap.sources.stray import CONFIDENCE_VALUES, is_stray_capture, read_stray_capture

if TYPE_CHECKING:  # imported where used: apps.replay may import this module for its table of layouts
    from apps.replay import ReplayOptions
    from apps.simulate import SimulateOptions

__all__ = ["is_phone_capture", "run_replay_phone", "write_phone_capture", "run_simulate_phone", "DEFAULT_DEPTH_RATE_HZ"]

#: depth packets per second fed from a capture (Stray writes one per video frame, 60 Hz): the Tango's.
DEFAULT_DEPTH_RATE_HZ = 5.0


def is_phone_capture(path: Path) -> bool:
    """True for a folder in the Stray Scanner layout (``odometry.csv``, ``camera_matrix.csv``, ``rgb.mp4``)."""
    return is_stray_capture(Path(path))


def _load_npz(path: Path) -> dict:
    arrays = read_truth(path)
    if arrays is None:
        raise LogFormatError(f"{path}: missing file")
    return arrays


def _check_origin(origin) -> np.ndarray:
    o = np.asarray(origin, np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InvalidInputError(f"origin: expected three finite numbers, got {origin}")
    return o


#: "not given": take the setting from the options (``phone_depth_rate_hz`` / ``phone_colour_size``) or the default.
_FROM_OPTIONS = object()


def run_replay_phone(opts: "ReplayOptions", *, depth_rate_hz=_FROM_OPTIONS, colour_size=_FROM_OPTIONS) -> dict:
    """Replay the phone capture ``opts.log`` through the mobile path into ``opts.out``; returns the run
    summary (also ``run.json``).

    Args:
        opts: the replay options (log, out, origin, config, outputs, strict).
        depth_rate_hz: depth packets per second taken from the capture (float > 0; None: every depth
            image). Not given: ``opts.phone_depth_rate_hz`` if the options have that field, else
            :data:`DEFAULT_DEPTH_RATE_HZ`.
        colour_size: (width, height) to decode the video at (even), or None for its own size. Not
            given: ``opts.phone_colour_size`` if the options have that field, else None.
    """
    if depth_rate_hz is _FROM_OPTIONS:
        depth_rate_hz = getattr(opts, "phone_depth_rate_hz", DEFAULT_DEPTH_RATE_HZ)
    if colour_size is _FROM_OPTIONS:
        colour_size = getattr(opts, "phone_colour_size", None)
    root = Path(opts.log)
    cap = read_stray_capture(root, depth_rate_hz=depth_rate_hz, colour_size=colour_size)
    gt_path = root / "groundtruth" / "envmap.npz"
    gt_map = _load_npz(gt_path) if gt_path.is_file() else None
    if opts.origin is not None:
        origin = _check_origin(opts.origin)
    elif gt_map is not None and "origin" in gt_map:
        origin = np.asarray(gt_map["origin"], np.float64)
    else:
        T = cap.frames[0].T_world_from_cam
        origin = T.translation + T.rotation[:, 2]
    skipped: Counter = Counter()
    skipped_files: list[str] = []

    def on_error(kind: str, exc: LogFormatError) -> None:
        if opts.strict:
            raise exc
        skipped[kind] += 1
        skipped_files.append(str(exc))

    truth_dir = root / "groundtruth" / "frames"
    cached: dict[int, dict] = {}

    def truth(frame: int) -> dict:
        if frame not in cached:
            cached.clear()
            path = truth_dir / f"{frame:06d}.npz"
            try:
                cached[frame] = _load_npz(path) if path.is_file() else {}
            except LogFormatError as exc:
                skipped["groundtruth"] += 1
                skipped_files.append(str(exc))
                cached[frame] = {}
        return cached[frame]

    def packets():
        for packet, row in cap.packets(on_error):
            yield packet, truth(row.frame)

    def extra() -> dict:
        return {
            "source": "replay (phone capture, Stray Scanner layout, mobile path)", "log": str(root),
            "skipped": dict(skipped), "skipped_files": skipped_files[:50],
            "phone": {
                "video_size": list(cap.video_size), "colour_size": list(cap.colour_size),
                "depth_size": [cap.calibration.depth.width, cap.calibration.depth.height],
                "frames": len(cap.frames), "depth_frames_taken": len(cap.depth_frames), "depth_rate_hz": depth_rate_hz,
                "confidence_values": list(CONFIDENCE_VALUES), "has_confidence": cap.has_confidence,
                "not_fed": {k: v for k, v in cap.skipped.items() if v},
            },
        }

    with Pipeline(opts.config, cap.calibration, origin, cache_dir=opts.cache_dir) as pipe:
        summary = run_pipeline(
            pipe, packets(), len(cap),
            RunOptions(opts.out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress, rerun=opts.rerun),
            groundtruth_envmap=lambda: gt_map, extra=extra,
        )
    return summary


def write_phone_capture(opts: "SimulateOptions", root: Path | None = None, *, crf: int = 0, depth_rate_hz: float = 5.0) -> dict:
    """Simulate a phone along ``opts``' scene and trajectory and write the capture (Stray layout, with
    ground truth) to ``root`` (default ``opts.out / "session"``); returns a summary.

    The colour camera is ``opts.colour_width`` × ``opts.colour_height`` (4:3 for a phone's 256×192
    depth: :data:`sim.phone.PHONE_COLOUR_SIZE` is 960×720), pinhole, 65° wide; ``opts``' seed, tracking
    noise, auto-exposure and white balance apply as in ``simulate``. The true map is written at the
    size of ``opts.config.capture``.
    """
    from sim.phone import phone_device, write_phone_session
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    if not opts.duration_s > 0:
        raise InvalidInputError(f"duration: expected seconds > 0, got {opts.duration_s}")
    root = Path(opts.out) / "session" if root is None else Path(root)
    scene = load_scene(opts.scene)
    trajectory_name = opts.trajectory or scene.default_trajectory
    device = phone_device(opts.colour_width, opts.colour_height, depth_rate_hz=depth_rate_hz,
                          tracking_noise_m=opts.tracking_noise_m, tracking_noise_deg=opts.tracking_noise_deg,
                          auto_exposure=opts.auto_exposure, auto_white_balance=opts.auto_white_balance)
    sim = Simulator(scene, load_trajectory(trajectory_name), device, seed=opts.seed)
    n = len(sim.schedule(opts.duration_s))
    bar = tqdm(total=n, desc="simulate phone", unit="pkt", disable=bar_disable(opts.progress))
    wall0 = time.perf_counter()
    try:
        info = write_phone_session(sim, opts.duration_s, root, crf=crf, origin=scene.virtual_object_position,
                                   envmap_size=(opts.config.capture.width, opts.config.capture.height), overwrite=opts.overwrite,
                                   on_packet=lambda _: bar.update(1), info={"trajectory": trajectory_name})
    finally:
        bar.close()
    return {
        "scene": scene.name, "device": "phone", "trajectory": trajectory_name, "seed": opts.seed, "duration_s": opts.duration_s,
        "colour_size": [device.colour.width, device.colour.height], "depth_size": [device.tof.intrinsics.width, device.tof.intrinsics.height],
        "depth_packets": info.depth_frames, "colour_packets": info.colour_frames, "video_crf": crf,
        "record_wall_s": time.perf_counter() - wall0, "session": str(root),
    }


def run_simulate_phone(opts: "SimulateOptions") -> dict:
    """``simulate --device phone``: write a simulated phone capture to ``OUT/session`` (Stray layout,
    ground truth under ``session/groundtruth/``), then, unless ``opts.pipeline`` is False, replay it
    through the mobile path into ``OUT``; writes ``OUT/simulation.json`` and returns its summary."""
    from apps.replay import ReplayOptions

    out = Path(opts.out)
    wall0 = time.perf_counter()
    summary = write_phone_capture(opts)
    if opts.pipeline:
        scene_origin = _check_origin(_load_npz(Path(summary["session"]) / "groundtruth" / "envmap.npz")["origin"])
        run_replay_phone(ReplayOptions(Path(summary["session"]), out, origin=tuple(scene_origin), config=opts.config,
                                       composite_every=opts.composite_every, video=opts.video, progress=opts.progress,
                                       rerun=opts.rerun, cache_dir=opts.cache_dir))
    summary = {**summary, "wall_s": time.perf_counter() - wall0, "pipeline": opts.pipeline, "preview": None}
    out.mkdir(parents=True, exist_ok=True)
    (out / "simulation.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary

