"""Time the Tango ingest of one packet (paper Table 1 rows "YUV420 to linear RGB" … "Hole filling").

    python benchmarks/bench_ingest.py [--repeats N] [--session DIR] [--json PATH]

Single thread (numba kernels are serial; OpenCV is set to one thread). The NV21 decode of the FullHD
frame is reported on its own row, as is the choice of sRGB decoder (ours, colour-science, LUT).

Session rows ("session: …"): depth frames of the recorded default session (``runs/default/session``,
written by ``rgbd-envmap simulate``; skipped when absent), 224×172 depth with its 960×540 colour frame,
eight frames spread over the session and cycled so that nothing is reused from the previous call
(the registration is computed afresh, as for each new packet in the pipeline). The stage rows run what
``Pipeline._depth_step`` runs under each Table 1 name. :func:`session_frames` is shared with
bench_holes.py and bench_reliability.py.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.colour import decode_nv21, srgb8_to_linear_lut, srgb_to_linear  # noqa: E402
from rgbd_envmap.depth import fill_holes, mark_reliable  # noqa: E402
from rgbd_envmap.ingest.tango import (  # noqa: E402
    TangoIngestConfig,
    colour_filled_pixels,
    colour_registration,
    decode_colour,
    ingest_tango,
    rgbd_frame_from_packets,
)
from rgbd_envmap.logs import SessionLog  # noqa: E402
from rgbd_envmap.types import Calibration, DepthPacket, RGBDFrame, RigidTransform  # noqa: E402

DEFAULT_SESSION = Path(__file__).resolve().parent.parent / "runs" / "default" / "session"


@dataclass(frozen=True)
class SessionFrame:
    """The ingest inputs of one depth frame of a recorded session (what the pipeline's stages get)."""

    packet: DepthPacket
    srgb8: np.ndarray  # the paired colour frame, decoded (960×540 in the default session)
    T_world_from_colour: RigidTransform
    calibration: Calibration
    frame: RGBDFrame  # point cloud → RGB-D
    filled_depth: np.ndarray  # fill_holes of it
    filled_known: np.ndarray
    T_colour_from_depth: RigidTransform


def session_frames(root: Path = DEFAULT_SESSION, count: int = 8) -> list[SessionFrame] | None:
    """``count`` depth frames spread over the session at ``root`` (from a quarter of the way in, when
    the map is filling), each paired with the colour frame nearest in time; None without a session."""
    if not (Path(root) / "calibration.json").is_file():
        return None
    log = SessionLog.open(root)
    cfg = TangoIngestConfig()
    n = len(log.depth_timestamps_ns)
    out = []
    for i in np.linspace(n // 4, n - 1, count).astype(int):
        pk = log.read_depth(int(i))
        cp = log.read_colour(int(np.argmin(np.abs(log.colour_timestamps_ns - pk.timestamp_ns))))
        srgb8 = decode_colour(cp)
        frame, _ = rgbd_frame_from_packets(pk, srgb8, cp.T_world_from_colour, log.calibration, cfg)
        depth, known = fill_holes(frame.depth_m, frame.known, method=cfg.fill_method)
        T_cd = colour_registration(pk, cp.T_world_from_colour, log.calibration, cfg.registration)
        out.append(SessionFrame(pk, srgb8, cp.T_world_from_colour, log.calibration, frame, depth, known, T_cd))
    return out


def cycling(frames: list, fn: Callable) -> Callable[[], object]:
    """A no-argument callable running ``fn`` on the next frame each call."""
    it = itertools.cycle(frames)
    return lambda: fn(next(it))


def session_rows(frames: list[SessionFrame], repeats: int) -> dict[str, dict]:
    """The ingest stages of the pipeline (Table 1 names) on session frames, and their parts."""
    cfg = TangoIngestConfig()
    f0 = frames[0]
    cal = f0.calibration

    def cloud(f):
        return rgbd_frame_from_packets(f.packet, f.srgb8, f.T_world_from_colour, cal, cfg)

    def holes(f):  # "Hole filling RGB-D" as Pipeline._depth_step runs it
        d, k = fill_holes(f.frame.depth_m, f.frame.known, method=cfg.fill_method)
        T_cd = colour_registration(f.packet, f.T_world_from_colour, cal, cfg.registration)
        return colour_filled_pixels(f.frame, d, k, f.srgb8, T_cd, cal.colour)

    def stages(f):  # the three stages in pipeline order: the registration is reused by the third
        frame, _ = cloud(f)
        mark_reliable(frame.rgb, frame.depth_m, frame.known, method=cfg.reliability_method)
        d, k = fill_holes(frame.depth_m, frame.known, method=cfg.fill_method)
        T_cd = colour_registration(f.packet, f.T_world_from_colour, cal, cfg.registration)
        return colour_filled_pixels(frame, d, k, f.srgb8, T_cd, cal.colour)

    unknown = 100 * (1 - np.mean([f.frame.known.mean() for f in frames]))
    return {
        f"session: 'Point cloud to RGB-D' ({len(f0.packet.points_m)} pts)": time_it(cycling(frames, cloud), repeats),
        "session: 'Mark reliable RGB-D' (noise_model)": time_it(
            cycling(frames, lambda f: mark_reliable(f.frame.rgb, f.frame.depth_m, f.frame.known)), repeats),
        "session: 'Hole filling RGB-D' (fill + registration + colour)": time_it(cycling(frames, holes), repeats),
        f"session:   fill_holes ({unknown:.1f} % unknown)": time_it(
            cycling(frames, lambda f: fill_holes(f.frame.depth_m, f.frame.known)), repeats),
        "session:   colour_filled_pixels": time_it(cycling(frames, lambda f: colour_filled_pixels(
            f.frame, f.filled_depth, f.filled_known, f.srgb8, f.T_colour_from_depth, cal.colour)), repeats),
        "session: the three stages, in pipeline order": time_it(cycling(frames, stages), repeats),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=100)
    parser.add_argument("--session", type=Path, default=DEFAULT_SESSION, help="a recorded session (rgbd-envmap simulate)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    import colour as colour_science  # slow to import, and only for the decoder comparison

    from sim.device import TangoDeviceConfig
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    sim = Simulator(load_scene("office"), load_trajectory("orbit"), TangoDeviceConfig(), seed=0)
    stream = sim.run(0.05)
    depth_sp, colour_sp = next(stream), next(stream)
    cal, pk, cp = sim.calibration, depth_sp.packet, colour_sp.packet
    srgb8 = decode_nv21(cp.nv21, cp.height, cp.width)
    cfg = TangoIngestConfig()
    frame, _ = rgbd_frame_from_packets(pk, srgb8, cp.T_world_from_colour, cal, cfg)
    T_cd = colour_registration(pk, cp.T_world_from_colour, cal, cfg.registration)
    filled_depth, filled_known = fill_holes(frame.depth_m, frame.known)
    lut = srgb8_to_linear_lut()
    unit = srgb8.astype(np.float32) / 255.0
    r = args.repeats
    rows = {
        "nv21 decode 1920x1080 (cv2)": time_it(lambda: decode_nv21(cp.nv21, cp.height, cp.width), r),
        "srgb->linear 1920x1080 float32 (ours)": time_it(lambda: srgb_to_linear(unit), max(5, r // 10)),
        "srgb->linear 1920x1080 (colour-science)": time_it(lambda: colour_science.models.eotf_sRGB(unit), max(5, r // 10)),
        "srgb->linear 1920x1080 uint8 LUT": time_it(lambda: lut[srgb8], max(5, r // 10)),
        f"point cloud -> rgbd ({len(pk.points_m)} pts)": time_it(lambda: rgbd_frame_from_packets(pk, srgb8, cp.T_world_from_colour, cal, cfg), r),
        "mark_reliable": time_it(lambda: mark_reliable(frame.rgb, frame.depth_m, frame.known), r),
        f"fill_holes ({100 * (1 - frame.known.mean()):.0f} % unknown)": time_it(lambda: fill_holes(frame.depth_m, frame.known), r),
        "colour filled pixels": time_it(lambda: colour_filled_pixels(frame, filled_depth, filled_known, srgb8, T_cd, cal.colour), r),
        "ingest total (cloud->rgbd+reliable+fill+colour)": time_it(lambda: ingest_tango(pk, srgb8, cp.T_world_from_colour, cal, cfg), r),
    }
    frames = session_frames(args.session)
    if frames is None:
        print(f"no session at {args.session}: session rows skipped (rgbd-envmap simulate writes one)")
    else:
        rows.update(session_rows(frames, r))
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
