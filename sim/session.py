"""A simulated capture session: the time-ordered stream of depth and colour packets with ground truth.

Depth packets come at the ToF rate (5 Hz) and colour frames at 30 Hz, both from ``start_ns``; on equal
timestamps the depth packet comes first. Each depth packet's noise is drawn from its own generator
seeded by (seed, stream, index), so any packet can be regenerated alone. Colour frames depend on the
auto-exposure state of the frame before, so they are generated in order.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.types import ColourPacket, DepthPacket, RigidTransform, SensorPacket
from sim.colour_camera import AutoExposureState, capture_colour
from sim.device import TangoDeviceConfig
from sim.raycast import SceneRaycaster
from sim.scene import Scene
from sim.tof import capture_tof
from sim.trajectory import Trajectory

__all__ = ["SimPacket", "Simulator"]

_DEPTH, _COLOUR, _TRACKING = 1, 2, 3


@dataclass(frozen=True)
class SimPacket:
    """A packet as the device delivers it, with the truth behind it.

    Attributes:
        packet: the DepthPacket or ColourPacket (reported pose, possibly with tracking noise).
        true_pose: the sensor's true ``T_world_from_<sensor>``.
        groundtruth: named arrays. Depth: ``true_depth_m``, ``true_valid``, ``object_index``,
            ``flags``, ``mixed`` (all (H, W)) and ``pixel_index`` (N,). Colour: ``gains`` (3,).
        t_s: session time in seconds.
    """

    packet: SensorPacket
    true_pose: RigidTransform
    groundtruth: dict[str, np.ndarray]
    t_s: float


class Simulator:
    """Simulates a Tango-like device moving along ``trajectory`` through ``scene``."""

    def __init__(
        self,
        scene: Scene,
        trajectory: Trajectory,
        device: TangoDeviceConfig | None = None,
        seed: int = 0,
        start_ns: int = 1_000_000_000,
    ) -> None:
        self.scene = scene
        self.trajectory = trajectory
        self.device = device or TangoDeviceConfig()
        self.seed = int(seed)
        self.start_ns = int(start_ns)
        self.raycaster = SceneRaycaster(scene)
        self.calibration = self.device.calibration()

    def _rng(self, stream: int, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, stream, index])

    def schedule(self, duration_s: float) -> list[tuple[int, str, int]]:
        """(timestamp_ns, kind, index) of every packet in [0, duration_s), in delivery order."""
        out = []
        for kind, rate in (("depth", self.device.tof.rate_hz), ("colour", self.device.colour.rate_hz)):
            # Packet i is at round(i / rate) seconds (no drift from a rounded period); t < duration.
            n = int(np.ceil(duration_s * rate - 1e-9))
            out += [(self.start_ns + round(i * 1e9 / rate), kind, i) for i in range(n)]
        return sorted(out, key=lambda e: (e[0], e[1] != "depth"))

    def true_pose_colour(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_colour``: the trajectory moves the colour camera."""
        return RigidTransform(self.trajectory.pose(t_s).matrix, "world", "colour")

    def true_pose_depth(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_depth`` = ``T_world_from_colour @ T_colour_from_depth``."""
        return self.true_pose_colour(t_s) @ self.device.T_colour_from_depth

    def depth_packet(self, index: int, timestamp_ns: int) -> SimPacket:
        t_s = (timestamp_ns - self.start_ns) * 1e-9
        T_true = self.true_pose_depth(t_s)
        cap = capture_tof(self.raycaster, T_true, t_s, self.device.tof, self._rng(_DEPTH, index))
        reported = self.device.reported(T_true, self._rng(_TRACKING, 2 * index))
        gt = {
            "true_depth_m": cap.true_depth_m, "true_valid": cap.true_valid, "object_index": cap.object_index,
            "flags": cap.flags, "mixed": cap.mixed, "pixel_index": cap.pixel_index,
        }
        return SimPacket(DepthPacket(timestamp_ns, cap.points_m, cap.confidence, reported), T_true, gt, t_s)

    def run(self, duration_s: float) -> Iterator[SimPacket]:
        """Yield every packet of the first ``duration_s`` seconds in delivery order."""
        state = AutoExposureState()
        for timestamp_ns, kind, index in self.schedule(duration_s):
            if kind == "depth":
                yield self.depth_packet(index, timestamp_ns)
                continue
            t_s = (timestamp_ns - self.start_ns) * 1e-9
            T_true = self.true_pose_colour(t_s)
            cap = capture_colour(self.raycaster, T_true, t_s, self.device.colour, state, self._rng(_COLOUR, index))
            state = cap.next_state
            reported = self.device.reported(T_true, self._rng(_TRACKING, 2 * index + 1))
            yield SimPacket(ColourPacket(timestamp_ns, cap.nv21, reported), T_true, {"gains": cap.gains}, t_s)
