"""Composites for docs/gallery/ (paper 003 Fig. 8): the bunny lit by the captured map, on the table
with its soft shadow, then moved towards the red and the blue panel (temporary EM translation).

Captures the default session (office, orbit, 20 s, colour 960×540) through the Pipeline with
rendering off, then renders fixed viewpoints: each view is a simulated colour frame at that pose
(same camera, auto-exposure settled) composited by the pipeline exactly as a live frame would be.

    python docs/figures/make_gallery.py [--duration 20] [--out docs/gallery]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from apps.preview import tonemap  # noqa: E402
from rgbd_envmap.geometry import look_at  # noqa: E402
from rgbd_envmap.pipeline import ColourStep, Pipeline, PipelineConfig, RenderConfig  # noqa: E402
from rgbd_envmap.types import ColourPacket, RigidTransform  # noqa: E402
from sim.colour_camera import AutoExposureState, ColourCameraConfig, capture_colour  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402

VIEWS = {
    # name: (eye, target, object offset from the EM origin). The panels stand at +x (red), −y (green)
    # and +y (blue); the views look in from the open −x side, over the table.
    "at_origin": ((-0.75, -0.15, 1.15), (0.10, 0.0, 0.80), (0.0, 0.0, 0.0)),
    "towards_red": ((-0.75, -0.15, 1.15), (0.10, 0.0, 0.80), (0.28, 0.0, 0.0)),
    "towards_blue": ((-0.75, -0.15, 1.15), (0.10, 0.0, 0.80), (0.0, 0.24, 0.0)),
    "towards_green": ((-0.75, -0.15, 1.15), (0.10, 0.0, 0.80), (0.0, -0.24, 0.0)),
}


def frame_at(sim: Simulator, cfg: ColourCameraConfig, T: RigidTransform, t_s: float, timestamp_ns: int) -> ColourPacket:
    """A colour frame at pose ``T`` with the auto-exposure settled on that view."""
    state = AutoExposureState()
    rng = np.random.default_rng(0)
    for _ in range(40):
        cap = capture_colour(sim.raycaster, T, t_s, cfg, state, rng)
        state = cap.next_state
    return ColourPacket(timestamp_ns, cap.nv21, T)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "gallery")
    args = ap.parse_args()
    colour = ColourCameraConfig(width=960, height=540)
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), TangoDeviceConfig(colour=colour), seed=0)
    origin = np.asarray(sim.scene.virtual_object_position, np.float64)
    pipe = Pipeline(replace(PipelineConfig(), render=RenderConfig(enabled=False)), sim.calibration, origin)
    last = None
    for sp in sim.run(args.duration):
        pipe.feed(sp.packet)
        last = sp
    # Render with the same pipeline state: switch rendering on and load the object.
    pipe.config = replace(pipe.config, render=RenderConfig(enabled=True))
    pipe._load_object()
    pipe._relight()
    args.out.mkdir(parents=True, exist_ok=True)
    tiles, closeups = [], []
    t_s = last.t_s
    ns = last.packet.timestamp_ns
    for name, (eye, target, offset) in VIEWS.items():
        pipe.object_offset = np.zeros(3)
        pipe.move_object(np.asarray(offset, np.float64))
        ns += 33_333_333
        packet = frame_at(sim, colour, look_at(np.asarray(eye), np.asarray(target)), t_s, ns)
        step = next(r for r in pipe.feed(packet) if isinstance(r, ColourStep))
        em = pipe._lighting_map()
        inset = cv2.resize(tonemap(np.ascontiguousarray(em.radiance), em.valid), (320, 160), interpolation=cv2.INTER_AREA)
        tile = step.image.copy()
        tile[-170:-10, 10:330] = inset
        tiles.append(cv2.resize(tile, (480, 270), interpolation=cv2.INTER_AREA))
        # a close-up around the object's base
        from rgbd_envmap.geometry import project_points

        T = packet.T_world_from_colour
        pc = (np.linalg.inv(T.matrix) @ np.append(pipe.object_base + [0.0, 0.0, 0.05], 1.0))[:3]
        (u, v), _ = project_points(pc[None], sim.calibration.colour)[0][0], None
        r0 = int(np.clip(v - 90, 0, 540 - 180))
        c0 = int(np.clip(u - 160, 0, 960 - 320))
        closeups.append(cv2.resize(step.image[r0:r0 + 180, c0:c0 + 320], (480, 270), interpolation=cv2.INTER_CUBIC))
        print(f"{name}: object base {np.round(pipe.object_base, 3).tolist()}")
    sheet = np.concatenate([np.concatenate(tiles[:2], axis=1), np.concatenate(tiles[2:4], axis=1)], axis=0)
    cv2.imwrite(str(args.out / "gallery.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    close = np.concatenate([np.concatenate(closeups[:2], axis=1), np.concatenate(closeups[2:4], axis=1)], axis=0)
    cv2.imwrite(str(args.out / "closeups.png"), cv2.cvtColor(close, cv2.COLOR_RGB2BGR))
    pipe.close()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
