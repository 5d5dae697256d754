"""A phone with LiDAR (iPhone / iPad, ARKit), simulated and written in the Stray Scanner layout.

The device is the Tango-like one (:class:`sim.device.TangoDeviceConfig`, driven by
:class:`sim.session.Simulator`) with a phone's optics: a 4:3 pinhole colour camera (65° horizontal
field of view, no distortion: the layout's ``camera_matrix.csv`` holds none), and a depth camera
registered to it, as ARKit delivers its depth: the same optical frame (identity extrinsics) and the
same field of view, at 256×192 (:func:`phone_device`; at another aspect ratio the depth is 256 wide
with square pixels). The depth comes from the simulator's ToF model (range noise, dropped and
low-confidence returns on emitters, shiny, dark and grazing surfaces, mixed pixels at depth edges), at
5 Hz by default, on the colour frames at the same instants.

:func:`write_phone_session` runs a :class:`~sim.session.Simulator` of such a device and writes the
capture with :class:`rgbd_envmap.sources.stray.StrayWriter`: every colour frame into ``rgb.mp4`` with
its odometry row (the *reported* colour pose, in ARKit's y-up world), and each depth packet as the
depth and confidence PNGs of the frame it coincides with. The ToF confidence becomes ARKit's three
levels (:func:`confidence_levels`): ≥ 0.7 → 2 (high: exactly what the Tango path keeps), ≥ 0.3 → 1
(medium), else 0; the reader maps them back to 1.0 / 0.5 / 0.0, so the mobile path with its default
threshold keeps the points the Tango path would. Ground truth goes beside the capture, under
``groundtruth/`` (not part of the layout; readers of the layout ignore it):

- ``envmap.npz``: the true map at the session's end (``radiance``, ``distance_m``, ``valid``,
  ``origin`` = the scene's virtual-object position, ``t_s``), as ``simulate`` writes it;
- ``frames/NNNNNN.npz`` per frame: ``gains`` (the colour camera's hidden per-channel gains), and at
  depth frames ``true_depth_m`` / ``true_valid`` (the true z-depth on the depth grid);
- ``simulation.json``: the scene, trajectory, seed and device.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.sources.stray import StrayWriter
from rgbd_envmap.types import DepthPacket, Distortion, RigidTransform
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.groundtruth import render_envmap
from sim.session import SimPacket, Simulator
from sim.tof import ToFConfig

__all__ = [
    "PHONE_COLOUR_SIZE",
    "PHONE_HFOV_DEG",
    "PHONE_DEPTH_WIDTH",
    "LEVEL_THRESHOLDS",
    "phone_device",
    "confidence_levels",
    "depth_image",
    "PhoneSessionInfo",
    "write_phone_session",
]

#: (width, height) of the simulated phone's colour video: 4:3 like an iPhone's 1920×1440, at half size.
PHONE_COLOUR_SIZE = (960, 720)
#: horizontal field of view of the colour camera (an iPhone's main camera in ARKit's 4:3 format).
PHONE_HFOV_DEG = 65.0
#: width of ARKit's depth map (256×192 at 4:3).
PHONE_DEPTH_WIDTH = 256
#: ToF confidence at or above which a pixel is ARKit level 1 (medium) and level 2 (high).
LEVEL_THRESHOLDS = (0.3, 0.7)


def phone_device(colour_width: int = PHONE_COLOUR_SIZE[0], colour_height: int = PHONE_COLOUR_SIZE[1], *,
                 hfov_deg: float = PHONE_HFOV_DEG, depth_rate_hz: float = 5.0, max_range_m: float = 5.0,
                 tracking_noise_m: float = 0.0, tracking_noise_deg: float = 0.0, auto_exposure: bool = True,
                 auto_white_balance: bool = True) -> TangoDeviceConfig:
    """A phone-like :class:`TangoDeviceConfig`: pinhole 4:3 colour camera, depth registered to it.

    The depth camera's intrinsics are the colour camera's scaled to 256 × (256 · H / W) (even; 256×192
    at 4:3) with :meth:`Intrinsics.scaled`, its frame is the colour camera's, and it fires at
    ``depth_rate_hz`` (which must divide the colour camera's 30 Hz, so each depth packet falls on a
    colour frame). The ToF model's other settings are the Tango's except ``max_range_m`` (ARKit reaches 5 m).
    """
    colour = replace(ColourCameraConfig(), width=int(colour_width), height=int(colour_height), hfov_deg=float(hfov_deg),
                     distortion=Distortion(), auto_exposure=bool(auto_exposure), auto_white_balance=bool(auto_white_balance),
                     bracket_every=0)  # a phone capture app records one exposure stream (the layout holds no exposures)
    if colour.width % 2 or colour.height % 2 or colour.width <= 0 or colour.height <= 0:
        raise InvalidInputError(f"colour size: expected an even width and height > 0 (NV21), got {colour.width}×{colour.height}")
    ratio = colour.rate_hz / float(depth_rate_hz) if depth_rate_hz > 0 else 0.0
    if not (ratio >= 1.0 and abs(ratio - round(ratio)) < 1e-9):
        raise InvalidInputError(f"depth_rate_hz: expected a rate that divides the colour camera's {colour.rate_hz:g} Hz, got {depth_rate_hz}")
    depth_h = max(2, int(round(PHONE_DEPTH_WIDTH * colour.height / colour.width / 2.0)) * 2)
    tof = replace(ToFConfig(), intrinsics=colour.intrinsics.scaled(PHONE_DEPTH_WIDTH, depth_h), rate_hz=float(depth_rate_hz),
                  max_range_m=float(max_range_m))
    return TangoDeviceConfig(tof=tof, colour=colour, T_colour_from_depth=RigidTransform.identity("colour", "depth"),
                             tracking_noise_m=tracking_noise_m, tracking_noise_deg=tracking_noise_deg)


def confidence_levels(confidence: np.ndarray) -> np.ndarray:
    """ToF confidence in [0, 1] → ARKit levels (uint8): ≥ 0.7 → 2, ≥ 0.3 → 1, else 0."""
    c = np.asarray(confidence)
    return ((c >= LEVEL_THRESHOLDS[0]).astype(np.uint8) + (c >= LEVEL_THRESHOLDS[1]).astype(np.uint8))


def depth_image(packet: DepthPacket, pixel_index: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ToF packet back on its pixel grid: (depth_m (H, W) float32 z-depth, known (H, W) bool, levels
    (H, W) uint8), from each point's ``pixel_index`` (the simulator's ground truth)."""
    h, w = shape
    depth = np.zeros(h * w, np.float32)
    levels = np.zeros(h * w, np.uint8)
    known = np.zeros(h * w, bool)
    idx = np.asarray(pixel_index, np.int64)
    depth[idx] = packet.points_m[:, 2]
    levels[idx] = confidence_levels(packet.confidence)
    known[idx] = True
    return depth.reshape(h, w), known.reshape(h, w), levels.reshape(h, w)


def _check_phone(sim: Simulator) -> None:
    cal = sim.calibration
    if not (cal.colour.distortion.is_zero and cal.depth.distortion.is_zero):
        raise InvalidInputError("sim: the Stray layout has no distortion; expected pinhole cameras (use sim.phone.phone_device)")
    if not np.allclose(cal.T_colour_from_depth.matrix, np.eye(4)):
        raise InvalidInputError("sim: expected depth registered to colour (identity T_colour_from_depth; use sim.phone.phone_device)")
    want = cal.colour.scaled(cal.depth.width, cal.depth.height)
    if not np.allclose(want.K, cal.depth.K, rtol=0, atol=1e-9):
        raise InvalidInputError("sim: expected the depth camera's intrinsics to be the colour camera's scaled to the depth size "
                                "(the same field of view; use sim.phone.phone_device)")


@dataclass(frozen=True)
class PhoneSessionInfo:
    """What :func:`write_phone_session` wrote: frame counts, the last frame's session time, the true map's origin."""

    root: Path
    colour_frames: int
    depth_frames: int
    last_t_s: float
    origin: np.ndarray


def write_phone_session(sim: Simulator, duration_s: float, root: Path, *, crf: int = 0, envmap_size: tuple[int, int] = (2000, 1000),
                        origin: np.ndarray | None = None, overwrite: bool = False,
                        on_packet: Callable[[SimPacket], None] | None = None, info: dict | None = None) -> PhoneSessionInfo:
    """Simulate ``duration_s`` seconds of a phone-like device and write them in the Stray layout.

    Args:
        sim: a simulator of a device from :func:`phone_device` (pinhole cameras, registered depth).
        duration_s: simulated seconds.
        root: the capture folder; ground truth goes to ``root/groundtruth``.
        crf: the video's libx264 CRF (0: lossless).
        envmap_size: (width, height) of the true map written to ``groundtruth/envmap.npz``.
        origin: the true map's origin (default the scene's virtual-object position).
        overwrite: replace a capture already in ``root``.
        on_packet: called with each simulated packet after it is written (progress, previews).
        info: extra entries for ``groundtruth/simulation.json``.
    """
    if not duration_s > 0:
        raise InvalidInputError(f"duration_s: expected seconds > 0, got {duration_s}")
    _check_phone(sim)
    cal = sim.calibration
    root = Path(root)
    if (root / "groundtruth").exists():
        if not overwrite:
            raise InvalidInputError(f"{root}: already holds ground truth (groundtruth/); pass overwrite=True to replace it")
        shutil.rmtree(root / "groundtruth")
    truth = root / "groundtruth" / "frames"
    origin = np.asarray(sim.scene.virtual_object_position if origin is None else origin, np.float64).reshape(3)
    pending: SimPacket | None = None
    last_t = 0.0
    n_depth = 0
    with StrayWriter(root, cal.colour, depth_size=(cal.depth.width, cal.depth.height), fps=cal.colour_rate_hz, crf=crf,
                     overwrite=overwrite) as writer:
        truth.mkdir(parents=True)
        for sp in sim.run(duration_s):
            packet = sp.packet
            if isinstance(packet, DepthPacket):
                if pending is not None:
                    raise InvalidInputError(f"depth packet at {pending.packet.timestamp_ns} ns falls on no colour frame")
                pending = sp
                continue
            frame = writer.write_colour(packet.timestamp_ns, packet.T_world_from_colour, packet.nv21)
            arrays = {"gains": np.asarray(sp.groundtruth["gains"], np.float64)}
            if pending is not None:
                if pending.packet.timestamp_ns != packet.timestamp_ns:
                    raise InvalidInputError(f"depth packet at {pending.packet.timestamp_ns} ns falls on no colour frame "
                                            f"(next colour frame at {packet.timestamp_ns} ns)")
                gt = pending.groundtruth
                d, k, lv = depth_image(pending.packet, gt["pixel_index"], cal.depth.shape)
                writer.write_depth(frame, d, k, lv)
                arrays.update(true_depth_m=gt["true_depth_m"], true_valid=gt["true_valid"])
                n_depth += 1
                if on_packet is not None:
                    on_packet(pending)
                pending = None
            np.savez_compressed(truth / f"{frame:06d}.npz", **arrays)
            last_t = sp.t_s
            if on_packet is not None:
                on_packet(sp)
        n_colour = writer.frames
    if pending is not None:  # the session ended between a depth packet and its colour frame
        raise InvalidInputError(f"depth packet at {pending.packet.timestamp_ns} ns falls on no colour frame")
    w, h = envmap_size
    gt_map = render_envmap(sim.raycaster, origin, int(h), int(w), last_t)
    np.savez_compressed(root / "groundtruth" / "envmap.npz", radiance=gt_map.radiance, distance_m=gt_map.distance_m,
                        valid=gt_map.valid, origin=gt_map.origin, t_s=np.float64(last_t))
    meta = {
        "format": "rgbd-envmap-phone-groundtruth", "version": 1, "scene": sim.scene.name, "seed": sim.seed,
        "duration_s": float(duration_s), "colour_frames": n_colour, "depth_frames": n_depth,
        "calibration": cal.to_dict(), "confidence_level_thresholds": list(LEVEL_THRESHOLDS), "video_crf": int(crf),
        **(info or {}),
    }
    (root / "groundtruth" / "simulation.json").write_text(json.dumps(meta, indent=2) + "\n")
    return PhoneSessionInfo(root, n_colour, n_depth, last_t, origin)
