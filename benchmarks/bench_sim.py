"""Time the simulator per packet on the default scene and trajectory.

    python benchmarks/bench_sim.py [--repeats N] [--json PATH] [--compare-scenes A,B]

``--compare-scenes office_unlit,office`` times the ToF packet and the colour frames of each scene side by
side in one run (a lit scene's ray caster adds the lightmap lookup; its bake is loaded from the cache,
or made once, before timing).
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
    parser.add_argument("--compare-scenes", default=None, metavar="A,B")
    args = parser.parse_args()
    if args.compare_scenes:
        rows = compare_scenes(args.compare_scenes.split(","), args.repeats)
        print_table(rows)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return

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


def compare_scenes(names: list[str], repeats: int) -> dict:
    """ToF packet and colour frames of each scene, interleaved so the machine's load hits all alike."""
    sims = {n: Simulator(load_scene(n), load_trajectory("orbit"), TangoDeviceConfig(), seed=0) for n in names}
    cfg = ColourCameraConfig(width=960, height=540)
    times = np.linspace(0.0, 20.0, repeats)
    rows = {}
    for label, fn in (
        ("tof packet 224x172", lambda s, t: capture_tof(s.raycaster, s.true_pose_depth(t), t, s.device.tof,
                                                        np.random.default_rng(0))),
        ("colour frame 960x540", lambda s, t: capture_colour(s.raycaster, s.true_pose_colour(t), t, cfg,
                                                             AutoExposureState(), np.random.default_rng(0))),
    ):
        for name, s in sims.items():
            fn(s, 0.0)  # warm up (compilation, the lit caster's tables)
        samples = {name: [] for name in sims}
        for t in times:
            for name, s in sims.items():
                samples[name].append(time_it(lambda: fn(s, float(t)), 1, warmup=0)["median_ms"])
        for name in sims:
            a = np.asarray(samples[name])
            rows[f"{name}: {label}"] = {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
                                        "n": len(a)}
    return rows


if __name__ == "__main__":
    main()
