"""Time the Tango ingest of one packet (paper Table 1 rows "YUV420 to linear RGB" … "Hole filling").

    python benchmarks/bench_ingest.py [--repeats N] [--json PATH]

Single thread (numba kernels are serial; OpenCV is set to one thread). The NV21 decode of the FullHD
frame is reported on its own row, as is the choice of sRGB decoder (ours, colour-science, LUT).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import colour as colour_science  # noqa: E402

from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.colour import decode_nv21, srgb8_to_linear_lut, srgb_to_linear  # noqa: E402
from rgbd_envmap.depth import fill_holes, mark_reliable  # noqa: E402
from rgbd_envmap.ingest.tango import (  # noqa: E402
    TangoIngestConfig,
    colour_filled_pixels,
    colour_registration,
    ingest_tango,
    rgbd_frame_from_packets,
)
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=100)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    cv2.setNumThreads(1)

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
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
