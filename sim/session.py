"""A simulated capture session: the time-ordered stream of depth and colour packets with ground truth.

Depth packets come at the ToF rate (5 Hz) and colour frames at 30 Hz, both from ``start_ns``; on equal
timestamps the depth packet comes first. Each depth packet's noise is drawn from its own generator
seeded by (seed, stream, index), so any packet can be regenerated alone. Colour frames depend on the
auto-exposure state of the frame before, so they are generated in order.

The schedule is generated lazily (a session of any length takes constant memory); sessions are at
most :data:`MAX_DURATION_S` long. With ``faults`` (:class:`sim.faults.FaultConfig`) the device
misbehaves as that module describes; each packet's faults are in :attr:`SimPacket.faults`, and
withheld packets (never delivered) are reported to ``on_fault``.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_number
from rgbd_envmap.types import ColourPacket, DepthPacket, RigidTransform, SensorPacket
from sim.colour_camera import AutoExposureState, capture_colour
from sim.device import TangoDeviceConfig
from sim.faults import FaultConfig
from sim.limits import MAX_DURATION_S, check_duration
from sim.raycast import SceneRaycaster
from sim.scene import Scene
from sim.tof import capture_tof
from sim.trajectory import Trajectory

__all__ = ["SimPacket", "Simulator", "MAX_DURATION_S", "check_duration"]

_DEPTH, _COLOUR, _TRACKING = 1, 2, 3
@dataclass(frozen=True)
class SimPacket:
    """A packet as the device delivers it, with the truth behind it.

    Attributes:
        packet: the DepthPacket or ColourPacket (reported pose, possibly with tracking noise).
        true_pose: the sensor's true ``T_world_from_<sensor>``.
        groundtruth: named arrays. Depth: ``true_depth_m``, ``true_valid``, ``object_index``,
            ``flags``, ``mixed`` (all (H, W)) and ``pixel_index`` (N,). Colour: ``gains`` (3,).
        t_s: session time in seconds (the capture time; the packet's timestamp may be jittered).
        faults: what the faulty device did to this packet (names, see :meth:`Simulator.run`).
    """

    packet: SensorPacket
    true_pose: RigidTransform
    groundtruth: dict[str, np.ndarray]
    t_s: float
    faults: tuple[str, ...] = ()


class Simulator:
    """Simulates a Tango-like device moving along ``trajectory`` through ``scene``."""

    def __init__(
        self,
        scene: Scene,
        trajectory: Trajectory,
        device: TangoDeviceConfig | None = None,
        seed: int = 0,
        start_ns: int = 1_000_000_000,
        faults: FaultConfig | None = None,
        on_fault: Callable[[dict], None] | None = None,
    ) -> None:
        """``faults``: what goes wrong (None: nothing); ``on_fault``: called with a dict (kind,
        index, timestamp_ns, t_s, faults) for every packet a fault touched, delivered or not."""
        self.scene = scene
        self.trajectory = trajectory
        self.device = device or TangoDeviceConfig()
        self.seed = int(seed)
        self.start_ns = int(start_ns)
        self.faults = faults if faults is not None and faults.enabled else None
        self.on_fault = on_fault
        if self.faults is not None:
            period_ms = 1e3 / max(self.device.tof.rate_hz, self.device.colour.rate_hz)
            # A quarter period: each stream keeps its order, and a gap is told from jitter.
            check_number(self.faults.timestamp_jitter_ms, "faults timestamp_jitter_ms", low=0.0, high=0.25 * period_ms)
        self.raycaster = SceneRaycaster(scene)
        self.calibration = self.device.calibration()

    def _rng(self, stream: int, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, stream, index])

    def _rates(self) -> tuple[tuple[str, float], ...]:
        return (("depth", self.device.tof.rate_hz), ("colour", self.device.colour.rate_hz))

    def counts(self, duration_s: float) -> dict[str, int]:
        """{kind: packets captured in [0, duration_s)} (before any fault)."""
        duration_s = check_duration(duration_s)
        return {kind: int(math.ceil(duration_s * rate - 1e-9)) for kind, rate in self._rates()}

    def iter_schedule(self, duration_s: float) -> Iterator[tuple[int, str, int]]:
        """(timestamp_ns, kind, index) of every packet captured in [0, duration_s), in capture order
        (depth first on equal timestamps); lazily, in constant memory."""
        counts = self.counts(duration_s)

        def stream(kind: str, rate: float) -> Iterator[tuple[int, str, int]]:
            # Packet i is at round(i / rate) seconds (no drift from a rounded period); t < duration.
            for i in range(counts[kind]):
                yield self.start_ns + round(i * 1e9 / rate), kind, i

        return heapq.merge(*(stream(k, r) for k, r in self._rates()), key=lambda e: (e[0], e[1] != "depth"))

    def schedule(self, duration_s: float) -> list[tuple[int, str, int]]:
        """:meth:`iter_schedule` as a list."""
        return list(self.iter_schedule(duration_s))

    def true_pose_colour(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_colour``: the trajectory moves the colour camera."""
        return RigidTransform(self.trajectory.pose(t_s).matrix, "world", "colour")

    def true_pose_depth(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_depth`` = ``T_world_from_colour @ T_colour_from_depth``."""
        return self.true_pose_colour(t_s) @ self.device.T_colour_from_depth

    def depth_packet(self, index: int, timestamp_ns: int) -> SimPacket:
        """The ``index``-th depth packet of a fault-free device, captured at ``timestamp_ns``."""
        t_s = (timestamp_ns - self.start_ns) * 1e-9
        T_true = self.true_pose_depth(t_s)
        cap = capture_tof(self.raycaster, T_true, t_s, self.device.tof, self._rng(_DEPTH, index))
        reported = self.device.reported(T_true, self._rng(_TRACKING, 2 * index))
        gt = {
            "true_depth_m": cap.true_depth_m, "true_valid": cap.true_valid, "object_index": cap.object_index,
            "flags": cap.flags, "mixed": cap.mixed, "pixel_index": cap.pixel_index,
        }
        return SimPacket(DepthPacket(timestamp_ns, cap.points_m, cap.confidence, reported), T_true, gt, t_s)

    def _true_pose(self, kind: str, t_s: float) -> RigidTransform:
        return self.true_pose_depth(t_s) if kind == "depth" else self.true_pose_colour(t_s)

    def run(self, duration_s: float) -> Iterator[SimPacket]:
        """Yield every packet of the first ``duration_s`` seconds in delivery order.

        With faults, a delivered packet's :attr:`SimPacket.faults` names what happened to it:
        ``depth_dropout`` (empty cloud), ``frozen_pose`` (tracking loss, frozen), ``pose_jump``,
        ``timestamp_jitter`` (its timestamp is off its capture time), ``reordered`` (delivered
        after a later packet), ``frozen_colour`` (the previous image again). Withheld packets
        (``colour_dropout``, ``no_pose``) are only reported to ``on_fault``."""
        if self.faults is None:
            state = AutoExposureState()
            for timestamp_ns, kind, index in self.iter_schedule(duration_s):
                if kind == "depth":
                    yield self.depth_packet(index, timestamp_ns)
                    continue
                t_s = (timestamp_ns - self.start_ns) * 1e-9
                T_true = self.true_pose_colour(t_s)
                cap = capture_colour(self.raycaster, T_true, t_s, self.device.colour, state, self._rng(_COLOUR, index),
                                     self.device.colour.bracket_at(index))
                state = cap.next_state
                reported = self.device.reported(T_true, self._rng(_TRACKING, 2 * index + 1))
                packet = ColourPacket(timestamp_ns, cap.nv21, reported, cap.exposure_s, cap.iso, cap.bracketed,
                                      cap.white_balance)
                yield SimPacket(packet, T_true, {"gains": cap.gains}, t_s)
            return
        yield from self._reordered(self._faulty(duration_s))

    def _report(self, kind: str, index: int, timestamp_ns: int, t_s: float, faults: list[str]) -> None:
        if faults and self.on_fault is not None:
            self.on_fault({"kind": kind, "index": index, "timestamp_ns": timestamp_ns, "t_s": round(t_s, 6),
                           "faults": list(faults)})

    def _faulty(self, duration_s: float) -> Iterator[SimPacket]:
        """The faulty stream in timestamp order, before reordering."""
        f = self.faults
        state = AutoExposureState()
        last_colour: tuple | None = None  # the camera's last delivered (nv21, gains, exposure metadata)
        # Jittered timestamps stay within ±0.25 of a colour period of the capture times, so each
        # stream keeps its order and merging by timestamp needs only the capture order plus a
        # look-ahead over one jitter width: a packet is released once no later capture can precede it.
        width_ns = 2 * int(math.ceil(f.timestamp_jitter_ms * 1e6)) + 1
        held: list = []
        n = 0
        for true_ns, kind, index in self.iter_schedule(duration_s):
            t_s = (true_ns - self.start_ns) * 1e-9
            while held and held[0][0] < true_ns - width_ns:
                yield heapq.heappop(held)[-1]
            faults: list[str] = []
            jitter = f.jitter_ns(kind, index)
            stamp_ns = true_ns + jitter
            stamp_s = (stamp_ns - self.start_ns) * 1e-9
            if jitter:
                faults.append("timestamp_jitter")
            loss = f.tracking_at(stamp_s)
            if kind == "colour":  # the camera captures whatever happens to the frame afterwards
                T_true = self.true_pose_colour(t_s)
                cap = capture_colour(self.raycaster, T_true, t_s, self.device.colour, state, self._rng(_COLOUR, index),
                                     self.device.colour.bracket_at(index))
                state = cap.next_state
                nv21, gains, meta = cap.nv21, cap.gains, (cap.exposure_s, cap.iso, cap.bracketed, cap.white_balance)
            if loss is not None and loss.mode == "none":
                self._report(kind, index, stamp_ns, t_s, faults + ["no_pose"])
                continue
            if kind == "colour" and f.dropped("colour", index, t_s):
                self._report(kind, index, stamp_ns, t_s, faults + ["colour_dropout"])
                continue
            if kind == "colour" and last_colour is not None and f.frozen_colour(index, t_s):
                nv21, gains, meta = last_colour  # the last image delivered, again
                faults.append("frozen_colour")
            stream = 2 * index + (kind == "colour")
            if loss is not None:  # frozen: the pose the tracker had when it was lost
                reported = self._true_pose(kind, loss.start_s).matrix
                faults.append("frozen_pose")
            else:
                reported = self.device.reported(self._true_pose(kind, stamp_s), self._rng(_TRACKING, stream)).matrix
            for jump in f.jumps_at(stamp_s):
                reported = jump.apply(reported)
                faults.append("pose_jump")
            if kind == "depth":
                sp = self.depth_packet(index, true_ns)
                points, confidence = sp.packet.points_m, sp.packet.confidence
                if f.dropped("depth", index, t_s):
                    points, confidence = points[:0], confidence[:0]
                    faults.append("depth_dropout")
                packet = DepthPacket(stamp_ns, points, confidence, RigidTransform(reported, "world", "depth"))
                out = SimPacket(packet, sp.true_pose, sp.groundtruth, t_s, tuple(faults))
            else:
                last_colour = (nv21, gains, meta)
                packet = ColourPacket(stamp_ns, nv21, RigidTransform(reported, "world", "colour"), *meta)
                out = SimPacket(packet, T_true, {"gains": gains}, t_s, tuple(faults))
            n += 1
            heapq.heappush(held, (stamp_ns, kind != "depth", n, (out, index)))
        while held:
            yield heapq.heappop(held)[-1]

    def _reordered(self, packets: Iterator[tuple[SimPacket, int]]) -> Iterator[SimPacket]:
        """Each packet delivered up to ``reorder_window - 1`` packets late (see :mod:`sim.faults`);
        one delivered after a packet that followed it is marked ``reordered``."""
        f = self.faults
        held: list = []
        newest = -1

        def deliver(item) -> SimPacket:
            nonlocal newest
            _, seq, (sp, index) = item
            faults = list(sp.faults)
            if seq < newest:
                faults.append("reordered")
                sp = SimPacket(sp.packet, sp.true_pose, sp.groundtruth, sp.t_s, tuple(faults))
            newest = max(newest, seq)
            self._report(sp.packet.kind, index, sp.packet.timestamp_ns, sp.t_s, faults)
            return sp

        for seq, item in enumerate(packets):
            heapq.heappush(held, (f.delay(seq), seq, item))
            while held and held[0][0] <= seq:
                yield deliver(heapq.heappop(held))
        while held:
            yield deliver(heapq.heappop(held))
