"""Accuracy of the Tango RGB-D frame against simulator ground truth over N depth packets.

    python benchmarks/eval_ingest.py [--packets 20] [--colour-size 960x540]

Depth: relative z error of known pixels (clean surfaces: no emissive / shiny / dark flag, not a mixed
pixel) against the true depth; the noise model's σ is 1 % of range, so the median |error| should be
about 0.67 %. Colour: absolute linear error of known pixels whose 5×5 neighbourhood lies on one object,
against the true radiance × the frame's hidden gains (clipped to 1), i.e. in the current camera's
colour space.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap.geometry import pixel_rays  # noqa: E402
from rgbd_envmap.ingest.tango import decode_colour, rgbd_frame_from_packets  # noqa: E402
from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def _uniform(obj: np.ndarray, r: int = 2) -> np.ndarray:
    pad = np.pad(obj, r, mode="edge")
    out = np.ones(obj.shape, bool)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            out &= pad[dy:dy + obj.shape[0], dx:dx + obj.shape[1]] == obj
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--packets", type=int, default=20)
    parser.add_argument("--colour-size", default="960x540")
    args = parser.parse_args()
    w, h = (int(x) for x in args.colour_size.split("x"))
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), TangoDeviceConfig(colour=ColourCameraConfig(width=w, height=h)), seed=0)
    rays = pixel_rays(sim.calibration.depth)
    depth_err, colour_err, known_frac = [], [], []
    pending = None
    for sp in sim.run(args.packets / sim.device.tof.rate_hz):
        if sp.packet.kind == "depth":
            pending = sp
            continue
        if pending is None or sp.packet.timestamp_ns != pending.packet.timestamp_ns:
            continue
        d, gt = pending.packet, pending.groundtruth
        frame, _ = rgbd_frame_from_packets(d, decode_colour(sp.packet), sp.packet.T_world_from_colour, sim.calibration)
        known_frac.append(frame.known.mean())
        clean = frame.known & (gt["flags"] == 0) & ~gt["mixed"]
        depth_err.append(np.abs(frame.depth_m[clean] - gt["true_depth_m"][clean]) / gt["true_depth_m"][clean])
        sel = frame.known & _uniform(gt["object_index"]) & (gt["flags"] == 0)
        pts = rays[sel] * frame.depth_m[sel, None]
        T = pending.true_pose
        dirs = T.rotate(pts / np.linalg.norm(pts, axis=1, keepdims=True))
        radiance = sim.raycaster.cast(T.translation, dirs, pending.t_s).radiance
        colour_err.append(np.abs(frame.rgb[sel] - np.clip(radiance * sp.groundtruth["gains"], 0, 1)).ravel())
        pending = None
    de, ce = np.concatenate(depth_err), np.concatenate(colour_err)
    print(f"packets: {len(known_frac)}; known fraction: mean {np.mean(known_frac):.3f}")
    print(f"depth |rel error| (clean known pixels, n={de.size}): median {100 * np.median(de):.3f} %, "
          f"p95 {100 * np.percentile(de, 95):.3f} %  (noise model σ = {100 * sim.device.tof.noise_rel:.1f} %, "
          f"median |N(0,σ)| = {0.6745 * 100 * sim.device.tof.noise_rel:.3f} %)")
    print(f"colour |error| linear (interior known pixels, n={ce.size}): median {np.median(ce):.4f}, "
          f"p95 {np.percentile(ce, 95):.4f}, mean {np.mean(ce):.4f}")


if __name__ == "__main__":
    main()
