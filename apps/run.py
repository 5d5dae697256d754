"""Running the pipeline over a packet stream and writing a run folder (shared by simulate and replay).

A run folder holds:

- ``envmap.npz`` (arrays ``radiance`` (H, W, 3) float32 linear, ``depth_m`` (H, W) float32 distance
  from the origin, ``valid`` (H, W) bool, ``origin`` (3,) float64), the same map as ``envmap.hdr``
  (Radiance RGBE, linear; invalid pixels 0) and ``envmap.exr`` (OpenEXR: float32 R, G, B, ``valid``,
  ``depth``), both in our orientation (:mod:`rgbd_envmap.envmap_io`; ``rgbd-envmap export`` writes
  other tools' orientations), ``envmap.png`` (tone-mapped colour) and ``envmap_depth.png``;
- ``composites/`` (every ``composite_every``-th composited frame as PNG) and ``composites.mp4`` (all);
- ``stage_times.csv`` (raw: one row per stage execution) and, generated from it by
  :mod:`apps.report`, ``timing.csv``, ``timing.md`` and ``timing.png``;
- ``depth_frames.csv`` (per depth packet: outcome, pairs, MSE, per-frame errors), ``accuracy.json``
  (flat metric → value against ground truth), ``config.yaml`` (the resolved pipeline config) and
  ``run.json`` (counts, skipped packets, wall time).
"""

from __future__ import annotations

import csv
import gc
import json
import os
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from apps.accuracy import AccuracyTracker
from apps.preview import depth_to_colourmap, tonemap
from apps.progress import bar_disable
from rgbd_envmap.config import dump_yaml
from rgbd_envmap.envmap_io import write_envmap
from rgbd_envmap.pipeline import ColourStep, DepthStep, Pipeline
from rgbd_envmap.timing import write_records
from rgbd_envmap.types import ColourPacket, DepthPacket

__all__ = ["RunOptions", "VideoWriter", "run_pipeline", "save_envmap"]


@dataclass(frozen=True)
class RunOptions:
    """What a run writes besides the map and reports."""

    out: Path
    composite_every: int = 30
    video: bool = True
    progress: bool = True
    rerun: Path | None = None


class VideoWriter:
    """H.264 MP4 through the ffmpeg of imageio-ffmpeg (libx264) when present, else OpenCV's MPEG-4
    Part 2.

    The encoder runs beside the pipeline on this 2-core machine, so it is started with one encoder
    thread at the lowest CPU priority (nice 19): libx264's default of 1.5 threads per core took
    cycles and cache from the pipeline's core (the main job's median depth frame: 10.5 ms with the
    encoder at its defaults, 9.7 ms with no video at all). Frames are piped raw (rgb24); CRF 15 is
    the quality imageio-ffmpeg's ``quality=7`` gave before; an odd width or height is padded by one
    pixel (4:2:0 needs even sizes)."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self._proc: subprocess.Popen | None = None
        self._log = None
        self._cv = None

    def write(self, rgb: np.ndarray) -> None:
        if self._proc is None and self._cv is None:
            h, w = rgb.shape[:2]
            try:
                import imageio_ffmpeg

                exe = imageio_ffmpeg.get_ffmpeg_exe()
            except (ImportError, RuntimeError):
                self._cv = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h))
            else:
                cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
                       "-r", f"{self.fps:g}", "-i", "-", "-an", "-c:v", "libx264", "-preset", "veryfast", "-crf", "15",
                       "-threads", "1", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", str(self.path)]
                self._log = tempfile.TemporaryFile()
                # A session of its own (Ctrl-C on the job does not cut the video short before close),
                # then the lowest CPU priority (set from here: preexec_fn is unsafe with threads).
                self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log,
                                              start_new_session=True)
                try:
                    os.setpriority(os.PRIO_PROCESS, self._proc.pid, 19)
                except OSError:  # it exited already; close() reports why
                    pass
        if self._proc is not None:
            try:
                self._proc.stdin.write(np.ascontiguousarray(rgb, dtype=np.uint8).data)
            except BrokenPipeError:
                self.close()  # raises with ffmpeg's message
                raise
        else:
            self._cv.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        if self._proc is not None:
            proc, self._proc = self._proc, None
            try:
                proc.stdin.close()
            except BrokenPipeError:
                pass
            code = proc.wait()
            self._log.seek(0)
            message = self._log.read().decode(errors="replace").strip()
            self._log.close()
            if code != 0:
                raise OSError(f"{self.path}: ffmpeg exited with {code}: {message}")
        if self._cv is not None:
            self._cv.release()
            self._cv = None


def save_envmap(out: Path, em) -> None:
    """``envmap.npz``, ``envmap.hdr``, ``envmap.exr`` and colour and depth PNGs of an
    :class:`~rgbd_envmap.envmap.EnvironmentMap`."""
    np.savez_compressed(out / "envmap.npz", radiance=np.ascontiguousarray(em.radiance), depth_m=em.depth_m,
                        valid=em.valid, origin=em.origin)
    for name in ("envmap.hdr", "envmap.exr"):
        write_envmap(out / name, em.radiance, em.valid, em.depth_m, convention="ours", origin=em.origin)
    _write_png(out / "envmap.png", tonemap(em.radiance, em.valid) if em.valid.any() else np.zeros((*em.valid.shape, 3), np.uint8))
    _write_png(out / "envmap_depth.png", depth_to_colourmap(em.depth_m, em.valid, 4.0))


def _write_png(path: Path, rgb: np.ndarray) -> None:
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: could not write PNG")


#: packets between two young-generation garbage collections in :func:`run_pipeline`.
_GC_EVERY = 20


def run_pipeline(
    pipeline: Pipeline,
    packets: Iterable[tuple[DepthPacket | ColourPacket, dict]],
    total: int,
    opts: RunOptions,
    *,
    groundtruth_envmap: Callable[[], dict | None] = lambda: None,
    extra: dict | Callable[[], dict] | None = None,
    reference=None,
) -> dict:
    """Feed ``(packet, groundtruth)`` pairs through ``pipeline`` and write the run folder.

    ``groundtruth_envmap`` is called once at the end; it returns the true map as a dict with
    ``radiance``, ``distance_m``, ``valid``, ``origin`` (or None). ``reference``: an
    :class:`apps.reference_frames.ReferenceRecorder` (simulated runs), which sees every colour packet
    and composite and, at the end, renders and scores its frames into ``reference/`` and
    ``accuracy.json``. Returns the run summary.
    """
    from apps.report import write_reports

    out = Path(opts.out)
    comp_dir = out / "composites"
    comp_dir.mkdir(parents=True, exist_ok=True)
    tracker = AccuracyTracker()
    video = VideoWriter(out / "composites.mp4", pipeline.calibration.colour_rate_hz) if opts.video else None
    recorder = None
    if opts.rerun is not None:
        from apps.rerun_log import RerunRecorder

        recorder = RerunRecorder(opts.rerun, pipeline)
    n_colour = n_depth = 0
    depth_gt: dict[int, dict] = {}
    wall0 = time.perf_counter()
    # Garbage collection between packets, as a real-time loop schedules it, not inside a timed
    # stage, where collections over the renderer's and the simulator's objects would land at random
    # and inflate whichever stage they hit.
    gc_was_enabled = gc.isenabled()
    gc.collect()
    gc.freeze()  # what exists now (models, scene, kernels) is never garbage: leave it out of collections
    gc.disable()
    try:
        for i_packet, (packet, gt) in enumerate(tqdm(packets, total=total, desc="pipeline", unit="pkt", disable=bar_disable(opts.progress))):
            if i_packet % _GC_EVERY == 0:
                gc.collect(1)
            if isinstance(packet, ColourPacket):
                tracker.on_colour(packet.timestamp_ns, gt)
                if reference is not None:
                    reference.on_colour(packet.timestamp_ns, gt)
                n_colour += 1
                pose = packet.T_world_from_colour
                results = pipeline.feed(packet)
            elif isinstance(packet, DepthPacket):
                n_depth += 1
                # a depth step may complete on a later packet (after the next depth packet, if it waited for
                # a lost colour frame): the truth of the last two depth packets is kept
                depth_gt = {**dict(list(depth_gt.items())[-1:]), packet.timestamp_ns: gt}
                results = pipeline.feed(packet)
            else:  # a registered RGB-D frame (Kinect / TUM): depth and colour at once
                n_depth += 1
                n_colour += 1
                tracker.on_colour(packet.timestamp_ns, gt)
                depth_gt = {packet.timestamp_ns: gt}
                pose = packet.T_world_from_cam
                results = pipeline.feed_rgbd(packet.timestamp_ns, packet.rgb, packet.depth_m, packet.known, pose)
            for result in results:
                if isinstance(result, DepthStep):
                    tracker.on_depth(result, depth_gt.get(result.timestamp_ns, {}))
                    if recorder is not None:
                        recorder.depth(result)
                elif isinstance(result, ColourStep):
                    image = result.image if result.image is not None else result.frame_srgb
                    if video is not None:
                        video.write(image)
                    if (n_colour - 1) % opts.composite_every == 0:
                        _write_png(comp_dir / f"{result.timestamp_ns}.png", image)
                    if reference is not None:
                        reference.on_step(result, pipeline)
                    if recorder is not None:
                        recorder.colour(result, pose)
        for result in pipeline.finish() or ():  # a depth packet that paired with the last colour frame
            if isinstance(result, DepthStep):
                tracker.on_depth(result, depth_gt.get(result.timestamp_ns, {}))
                if recorder is not None:
                    recorder.depth(result)
    finally:
        gc.unfreeze()
        if gc_was_enabled:
            gc.enable()
        if video is not None:
            video.close()
        if recorder is not None:
            recorder.close()
    wall = time.perf_counter() - wall0
    save_envmap(out, pipeline.capture.em)
    write_records(out / "stage_times.csv", pipeline.timer.records)
    _write_depth_frames(out / "depth_frames.csv", tracker.rows)
    accuracy = tracker.summary(pipeline, groundtruth_envmap())
    reference_facts: dict = {}
    if reference is not None:
        metrics, reference_facts = reference.finish(pipeline, out)
        accuracy.update(metrics)
    (out / "accuracy.json").write_text(json.dumps(accuracy, indent=2) + "\n")
    dump_yaml(pipeline.config, out / "config.yaml")
    summary = {
        "depth_packets": n_depth, "colour_packets": n_colour, "depth_frames_processed": pipeline.depth_steps,
        "depth_packets_dropped": pipeline.dropped_depth, "packets_skipped": dict(sorted(pipeline.skipped.items())),
        "depth_frames_rejected": dict(sorted(tracker.rejected_by_reason.items())),
        "depth_late_pairs": pipeline.late_pairs, "map_check_accepted": pipeline.map_check_accepted,
        "frozen_pose_resumes": pipeline.frozen_resumes,
        "relights_lights_kept": pipeline.lights_kept,
        "bracketed_colour_frames": pipeline.bracketed_frames,
        "pipeline_wall_s": wall,
        "em_origin": pipeline.capture.em.origin.tolist(), **reference_facts,
        **((extra() if callable(extra) else extra) or {}),
    }
    (out / "run.json").write_text(json.dumps(summary, indent=2) + "\n")
    write_reports(out)
    return summary


def _write_depth_frames(path: Path, rows: list[dict]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys or ["timestamp_ns"])
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
