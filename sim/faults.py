"""A faulty device: dropouts, tracking loss, relocalisation jumps, timestamp jitter, reordering and
frozen colour frames, each seeded and recorded in the ground truth.

:class:`FaultConfig` says which faults a :class:`~sim.session.Simulator` injects into its packet
stream; every fault is off by default, and a session with no fault on is bit for bit the session of
a fault-free device. What each fault does to what the device *delivers* (the truth behind each
packet is unchanged):

- **Depth dropout**: the point cloud arrives empty (the ToF returned nothing), at random
  (``depth_dropout_p`` per packet) or for given spans (``depth_dropout_bursts``).
- **Colour dropout**: the frame is never delivered (a gap in the 30 Hz stream), at random or in spans.
- **Tracking loss** (:class:`TrackingLoss`), for a span: ``"none"``, the tracker gives no pose and
  the device withholds the packets (the session log needs a pose per packet, so such a packet is
  not recorded; the fault record lists it); ``"frozen"``, the tracker keeps reporting the pose it had
  when the span began while the device moves on.
- **Relocalisation jump** (:class:`PoseJump`): from ``start_s`` the reported pose snaps by an offset
  (a world translation and a turn about the world's vertical axis through the device) and stays off
  for ``duration_s`` (inf: to the end), then snaps back.
- **Timestamp jitter**: each packet's timestamp is off its capture time by a uniform amount within
  ± ``timestamp_jitter_ms``; its pose is the tracker's at the stamped time (what a device that
  looks poses up by timestamp reports), so image and pose disagree by the device's motion in that
  time. Packets are delivered in timestamp order.
- **Reordering**: a packet is delivered up to ``reorder_window - 1`` packets late (uniform), so
  packets overtake each other within the window.
- **Frozen colour frame**: the camera delivers its previous image again with a new timestamp and
  pose, at random (``frozen_colour_p``) or in spans (``frozen_colour_bursts``).

Random draws come from generators seeded by (``seed``, fault, stream, packet index), so a packet's
faults do not depend on which other faults are on or on the session's length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_method, check_number
from rgbd_envmap.errors import DTypeError, InvalidInputError

__all__ = ["Span", "TrackingLoss", "PoseJump", "FaultConfig", "TRACKING_LOSS_MODES", "random_spans", "add_arguments",
           "from_arguments"]

TRACKING_LOSS_MODES = ("none", "frozen")
#: stream ids of the fault generators (beside the simulator's own 1, 2, 3).
_F_DEPTH_DROP, _F_COLOUR_DROP, _F_JITTER, _F_REORDER, _F_FREEZE = 11, 12, 13, 14, 15


@dataclass(frozen=True)
class Span:
    """[``start_s``, ``start_s + duration_s``) in session seconds (``duration_s`` may be inf)."""

    start_s: float
    duration_s: float

    def __post_init__(self) -> None:
        check_number(self.start_s, "span start_s", low=0.0)
        if self.duration_s != math.inf:  # inf: to the end of the session
            check_number(self.duration_s, "span duration_s", low=0.0, low_open=True)

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s


@dataclass(frozen=True)
class TrackingLoss(Span):
    """A span without tracking: ``mode`` "none" (no pose: packets withheld) or "frozen" (the pose
    of ``start_s`` is reported throughout)."""

    mode: str = "none"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_method(self.mode, TRACKING_LOSS_MODES, "tracking loss mode")


@dataclass(frozen=True)
class PoseJump(Span):
    """The reported pose is off by ``offset_m`` (world metres) and ``yaw_deg`` (a turn about the
    world's vertical through the device) during the span."""

    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.offset_m) != 3:
            raise InvalidInputError(f"pose jump offset_m: expected 3 numbers, got {self.offset_m!r}")
        object.__setattr__(self, "offset_m", tuple(check_number(x, "pose jump offset_m") for x in self.offset_m))
        check_number(self.yaw_deg, "pose jump yaw_deg", low=-180.0, high=180.0)

    def apply(self, T: np.ndarray) -> np.ndarray:
        """The (4, 4) pose ``T`` as the jumped tracker reports it."""
        a = math.radians(self.yaw_deg)
        rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        out = T.copy()
        out[:3, :3] = rz @ T[:3, :3]
        out[:3, 3] = T[:3, 3] + np.asarray(self.offset_m)
        return out


def _spans(value: object, cls: type, name: str) -> tuple:
    if not isinstance(value, tuple) or not all(isinstance(s, cls) for s in value):
        raise DTypeError(f"{name}: expected a tuple of {cls.__name__}, got {value!r}")
    return value


@dataclass(frozen=True)
class FaultConfig:
    """Which faults to inject (see the module docstring); all off by default."""

    seed: int = 0
    depth_dropout_p: float = 0.0
    depth_dropout_bursts: tuple[Span, ...] = ()
    colour_dropout_p: float = 0.0
    colour_dropout_bursts: tuple[Span, ...] = ()
    tracking_loss: tuple[TrackingLoss, ...] = ()
    pose_jumps: tuple[PoseJump, ...] = ()
    #: ± this many milliseconds, uniform; at most a quarter of the colour period (8.3 ms at 30 Hz), so
    #: each stream stays in order and a missing packet is told from a late one.
    timestamp_jitter_ms: float = 0.0
    #: packets; 0 or 1: delivered in order.
    reorder_window: int = 0
    frozen_colour_p: float = 0.0
    frozen_colour_bursts: tuple[Span, ...] = ()

    def __post_init__(self) -> None:
        check_number(self.seed, "faults seed", low=0, integer=True)
        for name in ("depth_dropout_p", "colour_dropout_p", "frozen_colour_p"):
            check_number(getattr(self, name), f"faults {name}", low=0.0, high=1.0)
        for name in ("depth_dropout_bursts", "colour_dropout_bursts", "frozen_colour_bursts"):
            _spans(getattr(self, name), Span, f"faults {name}")
        _spans(self.tracking_loss, TrackingLoss, "faults tracking_loss")
        _spans(self.pose_jumps, PoseJump, "faults pose_jumps")
        check_number(self.timestamp_jitter_ms, "faults timestamp_jitter_ms", low=0.0, high=1000.0)
        check_number(self.reorder_window, "faults reorder_window", low=0, high=1000, integer=True)

    @property
    def enabled(self) -> bool:
        """Any fault on."""
        return bool(self.depth_dropout_p or self.depth_dropout_bursts or self.colour_dropout_p
                    or self.colour_dropout_bursts or self.tracking_loss or self.pose_jumps or self.timestamp_jitter_ms
                    or self.reorder_window > 1 or self.frozen_colour_p or self.frozen_colour_bursts)

    def _rng(self, fault: int, stream: int, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, fault, stream, index])

    def dropped(self, kind: str, index: int, t_s: float) -> bool:
        """Depth: the cloud arrives empty; colour: the frame is not delivered."""
        if kind == "depth":
            p, bursts, f = self.depth_dropout_p, self.depth_dropout_bursts, _F_DEPTH_DROP
        else:
            p, bursts, f = self.colour_dropout_p, self.colour_dropout_bursts, _F_COLOUR_DROP
        if any(s.contains(t_s) for s in bursts):
            return True
        return bool(p) and self._rng(f, kind == "colour", index).random() < p

    def frozen_colour(self, index: int, t_s: float) -> bool:
        if any(s.contains(t_s) for s in self.frozen_colour_bursts):
            return True
        return bool(self.frozen_colour_p) and self._rng(_F_FREEZE, 1, index).random() < self.frozen_colour_p

    def jitter_ns(self, kind: str, index: int) -> int:
        if not self.timestamp_jitter_ms:
            return 0
        u = self._rng(_F_JITTER, kind == "colour", index).uniform(-1.0, 1.0)
        return int(round(u * self.timestamp_jitter_ms * 1e6))

    def delay(self, sequence: int) -> float:
        """Delivery key of the ``sequence``-th packet: its position plus a delay in [0, window - 1)."""
        if self.reorder_window <= 1:
            return float(sequence)
        return sequence + self._rng(_F_REORDER, 0, sequence).uniform(0.0, self.reorder_window - 1)

    def tracking_at(self, t_s: float) -> TrackingLoss | None:
        for s in self.tracking_loss:
            if s.contains(t_s):
                return s
        return None

    def jumps_at(self, t_s: float) -> list[PoseJump]:
        return [j for j in self.pose_jumps if j.contains(t_s)]

    def to_dict(self) -> dict:
        """JSON-ready description (for the fault record)."""
        def spans(v):
            return [{k: (None if x == math.inf else x) for k, x in vars(s).items()} for s in v]
        return {
            "seed": self.seed, "depth_dropout_p": self.depth_dropout_p, "depth_dropout_bursts": spans(self.depth_dropout_bursts),
            "colour_dropout_p": self.colour_dropout_p, "colour_dropout_bursts": spans(self.colour_dropout_bursts),
            "tracking_loss": spans(self.tracking_loss), "pose_jumps": spans(self.pose_jumps),
            "timestamp_jitter_ms": self.timestamp_jitter_ms, "reorder_window": self.reorder_window,
            "frozen_colour_p": self.frozen_colour_p, "frozen_colour_bursts": spans(self.frozen_colour_bursts),
        }


def random_spans(seed: int, duration_s: float, every_s: float, length_s: float, *, after_s: float = 0.0) -> tuple[Span, ...]:
    """Spans of ``length_s`` starting at random about every ``every_s`` seconds (exponential gaps)
    between ``after_s`` and ``duration_s``: random bursts for long sessions."""
    check_number(every_s, "every_s", low=0.0, low_open=True)
    check_number(length_s, "length_s", low=0.0, low_open=True)
    rng = np.random.default_rng([seed, 99])
    out, t = [], after_s
    while True:
        t += rng.exponential(every_s)
        if t >= duration_s:
            return tuple(out)
        out.append(Span(round(float(t), 3), float(length_s)))
        t += length_s


# --- the command line (``rgbd-envmap simulate``) ------------------------------------------------------

def _arg_span(text: str) -> Span:
    import argparse

    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise InvalidInputError("expected START:DURATION")
        return Span(float(parts[0]), float(parts[1]))
    except (ValueError, InvalidInputError) as exc:
        raise argparse.ArgumentTypeError(f"expected START:DURATION in seconds such as 5:1.5 ({exc}), got {text!r}") from None


def _arg_loss(text: str) -> TrackingLoss:
    import argparse

    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise InvalidInputError("expected START:DURATION[:MODE]")
        return TrackingLoss(float(parts[0]), float(parts[1]), *(parts[2:] or ["none"]))
    except (ValueError, InvalidInputError) as exc:
        raise argparse.ArgumentTypeError(f"expected START:DURATION[:none|frozen] such as 5:2:frozen ({exc}), got {text!r}") from None


def _arg_jump(text: str) -> PoseJump:
    import argparse

    parts = text.split(":")
    try:
        if len(parts) not in (5, 6):
            raise InvalidInputError("expected START:DURATION:DX:DY:DZ[:YAW_DEG]")
        v = [float(x) for x in parts]
        return PoseJump(v[0], v[1], tuple(v[2:5]), v[5] if len(v) == 6 else 0.0)
    except (ValueError, InvalidInputError) as exc:
        raise argparse.ArgumentTypeError(
            f"expected START:DURATION:DX:DY:DZ[:YAW_DEG] (seconds, metres, degrees; DURATION may be inf) ({exc}), got {text!r}") from None


def _arg_p(text: str) -> float:
    import argparse

    try:
        return check_number(float(text), "probability", low=0.0, high=1.0)
    except (ValueError, InvalidInputError) as exc:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], got {text!r} ({exc})") from None


def add_arguments(parser) -> None:
    """The fault options of ``simulate`` (an argument group of ``parser``)."""
    g = parser.add_argument_group(
        "a faulty device (tango only)",
        "Each fault is seeded and recorded in OUT/session/groundtruth/faults.jsonl; run.json counts what the "
        "device did (faults) and what the pipeline skipped and why (packets_skipped). Spans are START:DURATION "
        "in session seconds and repeat; docs/design/faults.md describes each fault.")
    g.add_argument("--depth-dropout", type=_arg_p, default=0.0, metavar="P", help="probability that a point cloud arrives empty")
    g.add_argument("--depth-dropout-burst", type=_arg_span, action="append", default=[], metavar="START:DURATION",
                   help="every point cloud in the span arrives empty")
    g.add_argument("--colour-dropout", type=_arg_p, default=0.0, metavar="P", help="probability that a colour frame is lost")
    g.add_argument("--colour-dropout-burst", type=_arg_span, action="append", default=[], metavar="START:DURATION",
                   help="every colour frame in the span is lost")
    g.add_argument("--tracking-loss", type=_arg_loss, action="append", default=[], metavar="START:DURATION[:MODE]",
                   help="no tracking in the span: MODE none (no pose, packets withheld; the default) or frozen (the "
                   "span's first pose is reported throughout)")
    g.add_argument("--pose-jump", type=_arg_jump, action="append", default=[], metavar="START:DURATION:DX:DY:DZ[:YAW]",
                   help="the reported pose is off by (DX, DY, DZ) metres and YAW degrees about the vertical during the span "
                   "(DURATION inf: to the end)")
    g.add_argument("--timestamp-jitter-ms", type=float, default=0.0, metavar="MS",
                   help="timestamps off their capture time by up to ± MS (uniform; at most a quarter of a colour period, 8.3 ms)")
    g.add_argument("--reorder-window", type=int, default=0, metavar="N", help="packets delivered up to N - 1 packets late")
    g.add_argument("--frozen-colour", type=_arg_p, default=0.0, metavar="P",
                   help="probability that the camera repeats its previous image")
    g.add_argument("--frozen-colour-burst", type=_arg_span, action="append", default=[], metavar="START:DURATION",
                   help="the camera repeats one image through the span")
    g.add_argument("--fault-seed", type=int, default=None, metavar="N", help="seed of the faults (default: --seed)")


def from_arguments(args) -> FaultConfig | None:
    """The :class:`FaultConfig` of parsed :func:`add_arguments` options; None when no fault is on."""
    f = FaultConfig(
        seed=args.seed if args.fault_seed is None else args.fault_seed,
        depth_dropout_p=args.depth_dropout, depth_dropout_bursts=tuple(args.depth_dropout_burst),
        colour_dropout_p=args.colour_dropout, colour_dropout_bursts=tuple(args.colour_dropout_burst),
        tracking_loss=tuple(args.tracking_loss), pose_jumps=tuple(args.pose_jump),
        timestamp_jitter_ms=args.timestamp_jitter_ms, reorder_window=args.reorder_window,
        frozen_colour_p=args.frozen_colour, frozen_colour_bursts=tuple(args.frozen_colour_burst),
    )
    return f if f.enabled else None
