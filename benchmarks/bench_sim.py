"""Time the simulator per packet on the default scene and trajectory.

    python benchmarks/bench_sim.py [--repeats N] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.logs import SessionWriter  # noqa: E402
from sim.colour_camera import AutoExposureState, ColourCameraConfig, capture_colour  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.groundtruth import render_envmap  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.tof import capture_tof  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    scene, traj = load_scene("office"), load_trajectory("orbit")
    sim = Simulator(scene, traj, TangoDeviceConfig(), seed=0)
    rows = {}
    poses = iter(np.linspace(0.0, 20.0, 10_000))

    def tof():
        t = next(poses)
        capture_tof(sim.raycaster, sim.true_pose_depth(t), t, sim.device.tof, np.random.default_rng(0))

    rows["tof packet 224x172"] = time_it(tof, args.repeats)
    for w, h in ((960, 540), (1920, 1080)):
        cfg = ColourCameraConfig(width=w, height=h)

        def colour(cfg=cfg):
            t = next(poses)
            capture_colour(sim.raycaster, sim.true_pose_colour(t), t, cfg, AutoExposureState(), np.random.default_rng(0))

        rows[f"colour frame {w}x{h}"] = time_it(colour, args.repeats)

    with tempfile.TemporaryDirectory() as tmp:
        packets = list(sim.run(0.2))  # one depth packet, six FullHD colour frames
        writer = SessionWriter(Path(tmp) / "s", sim.calibration)
        depth = [p for p in packets if p.packet.kind == "depth"][0]
        colour_sp = [p for p in packets if p.packet.kind == "colour"][0]
        counter = iter(range(1, 1_000_000))

        def write_depth():
            ts = depth.packet.timestamp_ns + next(counter)
            writer.write(type(depth.packet)(ts, depth.packet.points_m, depth.packet.confidence, depth.packet.T_world_from_depth),
                         true_pose=depth.true_pose, groundtruth=depth.groundtruth)

        def write_colour():
            ts = colour_sp.packet.timestamp_ns + next(counter)
            writer.write(type(colour_sp.packet)(ts, colour_sp.packet.nv21, colour_sp.packet.T_world_from_colour),
                         true_pose=colour_sp.true_pose, groundtruth=colour_sp.groundtruth)

        rows["log write depth packet (+gt)"] = time_it(write_depth, args.repeats)
        rows["log write colour 1920x1080"] = time_it(write_colour, args.repeats)
        writer.close()

    rows["gt envmap 2000x1000"] = time_it(lambda: render_envmap(sim.raycaster, scene.virtual_object_position, 1000, 2000, 0.0),
                                          max(3, args.repeats // 5))
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
