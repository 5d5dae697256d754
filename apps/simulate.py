"""``rgbd-envmap simulate``: simulate a capture session, run the pipeline on it live, and record it.

Writes the run folder of :mod:`apps.run` (map, composites, timing and accuracy reports, config) plus
``session/`` (the log, replayable with ``rgbd-envmap replay``; ground truth under
``session/groundtruth/``, including ``envmap.npz``, the true map at the session's end),
``preview/`` (contact sheet, depth and confidence images, the true map), ``simulation.json`` and
``reference/`` (reference composites of chosen frames and their scores: :mod:`apps.reference_frames`).

With ``faults`` (:class:`sim.faults.FaultConfig`, Tango device only) the device misbehaves; what it
did is recorded in ``session/groundtruth/faults.jsonl`` (the configuration, then one line per packet
a fault touched, delivered or withheld) and summed in ``simulation.json`` and ``run.json``
(``faults``), beside what the pipeline skipped and why (``packets_skipped`` in ``run.json``). With
reordering on, the log holds the packets in timestamp order (its format needs that), so a replay
sees them sorted while the live run saw them as delivered; every other fault replays bit for bit.

The pipeline is fed each packet exactly as the log stores it (:func:`rgbd_envmap.logs.as_logged`),
so replaying the log with the same config reproduces ``envmap.npz`` bit for bit.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import json
import time
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from apps.progress import bar_disable
from apps.reference_frames import ReferenceOptions, ReferenceRecorder
from apps.run import RunOptions, run_pipeline
from apps.preview import colour_thumbnail, contact_sheet, depth_confidence_images, depth_to_colourmap, tonemap
from rgbd_envmap.checks import check_method
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.logs import SessionWriter, as_logged
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.faults import FaultConfig
from sim.groundtruth import render_envmap
from sim.scene import load_scene
from sim.limits import check_duration
from sim.session import Simulator
from sim.trajectory import load_trajectory

__all__ = ["SimulateOptions", "run_simulate"]


@dataclass(frozen=True)
class SimulateOptions:
    """Options of ``simulate`` (the CLI flags, with units)."""

    duration_s: float
    out: Path
    scene: str = "office"
    trajectory: str | None = None
    seed: int = 0
    colour_width: int = 960
    colour_height: int = 540
    tracking_noise_m: float = 0.0
    tracking_noise_deg: float = 0.0
    auto_exposure: bool = True
    auto_white_balance: bool = True
    #: exposure brackets in the colour stream (HDR capture; ``ColourCameraConfig.bracket_every``).
    bracketing: bool = True
    preview_envmap_height: int = 500
    overwrite: bool = False
    progress: bool = True
    #: run the pipeline live (False: record only).
    pipeline: bool = True
    config: PipelineConfig = PipelineConfig()
    composite_every: int = 30
    video: bool = True
    rerun: Path | None = None
    cache_dir: Path | None = None
    #: "tango" (ToF point clouds at 5 Hz + NV21 colour at 30 Hz) or "kinect" (registered 640×480
    #: depth + colour at 30 Hz, recorded as a TUM RGB-D sequence, then run through the Kinect path).
    device: str = "tango"
    #: what goes wrong with the device (None: nothing; Tango device only).
    faults: FaultConfig | None = None
    #: reference composites (the rendered ground truth of chosen frames, ``reference/``; Tango device only).
    reference: ReferenceOptions = ReferenceOptions()


@contextlib.contextmanager
def _fault_record(session: Path, faults: FaultConfig | None, holder: list):
    """``session/groundtruth/faults.jsonl``: the fault configuration, then one line per event."""
    if faults is None:
        yield None
        return
    (session / "groundtruth").mkdir(parents=True, exist_ok=True)
    with open(session / "groundtruth" / "faults.jsonl", "w", buffering=1) as f:
        f.write(json.dumps({"faults": faults.to_dict()}) + "\n")
        holder[0] = f
        yield f


def _pick(n: int, k: int) -> set[int]:
    return set(np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(int)).tolist()) if n else set()


def run_simulate(opts: SimulateOptions) -> dict:
    """Simulate, write ``out/session/``, ``out/preview/`` and ``out/simulation.json``; return the summary."""
    check_duration(opts.duration_s)
    check_method(opts.device, ("tango", "kinect", "phone"), "device")
    if opts.faults is not None and opts.faults.enabled and opts.device != "tango":
        raise InvalidInputError(f"faults: only the tango device simulates faults, got device {opts.device!r}")
    if opts.device == "phone":
        from apps.phone import run_simulate_phone

        return run_simulate_phone(opts)
    scene = load_scene(opts.scene)
    trajectory = load_trajectory(opts.trajectory or scene.default_trajectory)
    if opts.device == "kinect":
        return _run_simulate_kinect(opts, scene, trajectory)
    colour = replace(
        ColourCameraConfig(), width=opts.colour_width, height=opts.colour_height,
        auto_exposure=opts.auto_exposure, auto_white_balance=opts.auto_white_balance,
        **({} if opts.bracketing else {"bracket_every": 0}),
    )
    device = TangoDeviceConfig(colour=colour, tracking_noise_m=opts.tracking_noise_m, tracking_noise_deg=opts.tracking_noise_deg)
    out = Path(opts.out)
    preview_dir = out / "preview"
    preview_dir.mkdir(parents=True, exist_ok=True)
    faults = opts.faults if opts.faults is not None and opts.faults.enabled else None
    fault_counts: Counter = Counter()
    fault_file: list = [None]  # opened once the session writer has made the session folder

    def on_fault(event: dict) -> None:
        fault_counts.update(event["faults"])
        fault_file[0].write(json.dumps(event) + "\n")

    sim = Simulator(scene, trajectory, device, seed=opts.seed, faults=faults, on_fault=on_fault if faults else None)
    counts = sim.counts(opts.duration_s)
    n_depth, n_colour = counts["depth"], counts["colour"]
    show_depth, show_colour = _pick(n_depth, 6), _pick(n_colour, 12)
    total = n_depth + n_colour  # captured; with faults fewer may be delivered
    times: dict[str, list[float]] = {"depth": [], "colour": []}
    thumbs, depth_tiles = [], []
    counters = {"depth": 0, "colour": 0}
    last_t = [0.0]
    origin = np.asarray(scene.virtual_object_position, np.float64)

    # Reordered packets are logged in timestamp order: held until no later delivery can precede them.
    hold = faults.reorder_window + 1 if faults is not None and faults.reorder_window > 1 else 0
    unwritten: list = []
    order = itertools.count()

    def log(writer: SessionWriter, sp=None) -> None:
        if not hold:
            if sp is not None:
                writer.write(sp.packet, true_pose=sp.true_pose, groundtruth=sp.groundtruth)
            return
        if sp is not None:
            heapq.heappush(unwritten, (sp.packet.timestamp_ns, sp.packet.kind != "depth", next(order), sp))
        while unwritten and (sp is None or len(unwritten) > hold):
            w = heapq.heappop(unwritten)[-1]
            writer.write(w.packet, true_pose=w.true_pose, groundtruth=w.groundtruth)

    def recorded(writer: SessionWriter):
        stream = iter(sim.run(opts.duration_s))
        while True:
            t0 = time.perf_counter()
            sp = next(stream, None)
            if sp is None:
                log(writer)
                return
            kind = sp.packet.kind
            times[kind].append(time.perf_counter() - t0)
            log(writer, sp)
            last_t[0] = sp.t_s
            i = counters[kind]
            counters[kind] += 1
            if kind == "colour" and i in show_colour:
                thumbs.append(colour_thumbnail(sp.packet))
            elif kind == "depth" and i in show_depth:
                d, c = depth_confidence_images(sp.packet, sim.calibration.depth)
                depth_tiles.extend([d, c])
            if kind == "colour":  # what a reference frame needs: the time and the true pose
                yield as_logged(sp.packet), {**sp.groundtruth, "t_s": sp.t_s, "true_pose": sp.true_pose}
            else:
                yield as_logged(sp.packet), sp.groundtruth

    def groundtruth_envmap() -> dict:
        em = opts.config.capture
        gt = render_envmap(sim.raycaster, origin, em.height, em.width, last_t[0])
        arrays = {"radiance": gt.radiance, "distance_m": gt.distance_m, "valid": gt.valid, "origin": gt.origin,
                  "t_s": np.float64(last_t[0])}
        (out / "session" / "groundtruth").mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out / "session" / "groundtruth" / "envmap.npz", **arrays)
        return arrays

    wall0 = time.perf_counter()
    with SessionWriter(out / "session", sim.calibration, overwrite=opts.overwrite) as writer, \
            _fault_record(out / "session", faults, fault_file):
        if opts.pipeline:
            pipe = Pipeline(opts.config, sim.calibration, origin, cache_dir=opts.cache_dir)
            reference = (ReferenceRecorder(scene, sim.raycaster, sim.calibration.colour, opts.reference)
                         if opts.reference.enabled and opts.config.render.enabled else None)
            with pipe:
                run_pipeline(
                    pipe, recorded(writer), total,
                    RunOptions(out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress,
                               rerun=opts.rerun),
                    groundtruth_envmap=groundtruth_envmap,
                    reference=reference,
                    extra=lambda: {"source": "simulate", "scene": scene.name,
                                   **({"faults": dict(sorted(fault_counts.items()))} if faults else {})},
                )
        else:
            for _ in tqdm(recorded(writer), total=total, desc="simulate", unit="pkt", disable=bar_disable(opts.progress)):
                pass
            groundtruth_envmap()
    wall = time.perf_counter() - wall0

    cv2.imwrite(str(preview_dir / "contact_sheet.png"), cv2.cvtColor(contact_sheet(thumbs, 4), cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(preview_dir / "depth_confidence.png"), cv2.cvtColor(contact_sheet(depth_tiles, 4), cv2.COLOR_RGB2BGR))
    h = opts.preview_envmap_height
    gt = render_envmap(sim.raycaster, scene.virtual_object_position, h, 2 * h, 0.0)
    cv2.imwrite(str(preview_dir / "groundtruth_envmap.png"), cv2.cvtColor(tonemap(gt.radiance, gt.valid), cv2.COLOR_RGB2BGR))
    cv2.imwrite(
        str(preview_dir / "groundtruth_envmap_depth.png"),
        cv2.cvtColor(depth_to_colourmap(gt.distance_m, gt.valid, 4.0), cv2.COLOR_RGB2BGR),
    )

    def stats(v: list[float]) -> dict:
        a = np.asarray(v) * 1e3
        return {"count": len(a), "median_ms": float(np.median(a)) if len(a) else None, "p95_ms": float(np.percentile(a, 95)) if len(a) else None}

    summary = {
        "scene": scene.name,
        "trajectory": opts.trajectory or scene.default_trajectory,
        "seed": opts.seed,
        "duration_s": opts.duration_s,
        "colour_size": [opts.colour_width, opts.colour_height],
        "depth_packets": counters["depth"],
        "colour_packets": counters["colour"],
        **({"faults": dict(sorted(fault_counts.items()))} if faults else {}),
        "simulate_depth_packet": stats(times["depth"]),
        "simulate_colour_packet": stats(times["colour"]),
        "wall_s": wall,
        "pipeline": opts.pipeline,
        "session": str(out / "session"),
        "preview": str(preview_dir),
    }
    (out / "simulation.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _run_simulate_kinect(opts: SimulateOptions, scene, trajectory) -> dict:
    """Record a Kinect session as a TUM RGB-D sequence (with per-frame truth and the true map under
    ``session/groundtruth/``), then replay it through the Kinect path into ``out``."""
    from apps.replay import ReplayOptions, run_replay_tum
    from rgbd_envmap.tum import write_tum_sequence
    from sim.kinect import KinectConfig, KinectSimulator

    out = Path(opts.out)
    session = out / "session"
    truth = session / "groundtruth" / "frames"
    config = KinectConfig(tracking_noise_m=opts.tracking_noise_m, tracking_noise_deg=opts.tracking_noise_deg)
    config = replace(config, colour=replace(config.colour, auto_exposure=opts.auto_exposure,
                                            auto_white_balance=opts.auto_white_balance))
    sim = KinectSimulator(scene, trajectory, config, seed=opts.seed)
    n = len(sim.schedule(opts.duration_s))
    times: list[float] = []
    last_t = [0.0]

    def frames():
        stream = iter(sim.run(opts.duration_s))
        for _ in tqdm(range(n), desc="simulate kinect", unit="frame", disable=bar_disable(opts.progress)):
            t0 = time.perf_counter()
            f = next(stream)
            times.append(time.perf_counter() - t0)
            truth.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(truth / f"{f.timestamp_ns}.npz", true_depth_m=f.true_depth_m, true_valid=f.true_valid, gains=f.gains)
            last_t[0] = f.t_s
            yield f

    wall0 = time.perf_counter()
    written = write_tum_sequence(session, frames(), sim.calibration.depth, overwrite=opts.overwrite)
    gt = render_envmap(sim.raycaster, scene.virtual_object_position, opts.config.capture.height, opts.config.capture.width, last_t[0])
    np.savez_compressed(session / "groundtruth" / "envmap.npz", radiance=gt.radiance, distance_m=gt.distance_m, valid=gt.valid,
                        origin=gt.origin, t_s=np.float64(last_t[0]))
    record_s = time.perf_counter() - wall0
    if opts.pipeline:
        run_replay_tum(ReplayOptions(session, out, origin=tuple(scene.virtual_object_position), config=opts.config,
                                     composite_every=opts.composite_every, video=opts.video, progress=opts.progress,
                                     rerun=opts.rerun, cache_dir=opts.cache_dir))
    a = np.asarray(times) * 1e3
    summary = {
        "scene": scene.name, "device": "kinect", "trajectory": opts.trajectory or scene.default_trajectory, "seed": opts.seed,
        "duration_s": opts.duration_s, "depth_packets": written, "colour_packets": written,
        "simulate_frame": {"count": len(a), "median_ms": float(np.median(a)) if len(a) else None,
                           "p95_ms": float(np.percentile(a, 95)) if len(a) else None},
        "record_wall_s": record_s, "wall_s": time.perf_counter() - wall0, "pipeline": opts.pipeline,
        "session": str(session), "preview": None,
    }
    (out / "simulation.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
