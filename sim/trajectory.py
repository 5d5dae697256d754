"""Device trajectories: the true pose of the device (its colour camera, OpenCV axes) over time.

Kinds (YAML under ``sim/data/trajectories/``, shipped as package data):

* ``orbit``: the device circles a centre; ``facing: outward`` looks away from it (scanning the room
  from near the virtual object, with a pitch sweep to reach floor and ceiling), ``inward`` looks at it.
* ``waypoints``: piecewise-linear positions and look-at targets at given times (a handheld sweep).
* ``sequence``: several of the above in turn, each ``until_s`` a time (global session time). A part's
  ``blend_s`` joins it to the next one smoothly: over ``blend_s`` seconds centred on ``until_s`` the
  pose moves from the one part to the other (a hand-held device cannot jump). Without it the device
  jumps at ``until_s`` wherever the parts do not meet.

Any kind takes ``jitter_m`` / ``jitter_deg``: smooth hand shake, a sum of seeded sinusoids (0.3–2 Hz),
part of the *true* pose. Tracking noise (error in the *reported* pose) belongs to the device.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import look_at
from rgbd_envmap.types import RigidTransform

__all__ = [
    "Jitter", "OrbitTrajectory", "blend_poses", "WaypointTrajectory", "SequenceTrajectory", "Trajectory", "load_trajectory", "TRAJECTORIES_DIR",
]

#: The packaged trajectories (``sim/data/trajectories/*.yaml``, shipped as package data; see pyproject.toml).
TRAJECTORIES_DIR = Path(__file__).resolve().parent / "data" / "trajectories"


@dataclass(frozen=True)
class Jitter:
    """Smooth, deterministic hand shake: per axis a sum of three sinusoids with seeded frequencies."""

    amplitude_m: float = 0.0
    amplitude_deg: float = 0.0
    seed: int = 0

    def offsets(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(3,) translation offset in metres and (3,) rotation vector in radians at time ``t_s``."""
        if self.amplitude_m == 0.0 and self.amplitude_deg == 0.0:
            return np.zeros(3), np.zeros(3)
        rng = np.random.default_rng(self.seed)
        freq = rng.uniform(0.3, 2.0, (2, 3, 3))
        phase = rng.uniform(0.0, 2.0 * np.pi, (2, 3, 3))
        wave = np.sin(2.0 * np.pi * freq * t_s + phase).sum(axis=2) / np.sqrt(3.0 / 2.0)
        return self.amplitude_m * wave[0], np.radians(self.amplitude_deg) * wave[1]

    def apply(self, T: RigidTransform, t_s: float) -> RigidTransform:
        dt, drot = self.offsets(t_s)
        if not (dt.any() or drot.any()):
            return T
        r = T.rotation @ Rotation.from_rotvec(drot).as_matrix()
        return RigidTransform.from_rt(r, T.translation + dt, T.dst, T.src)


def _look(position: np.ndarray, yaw: float, pitch: float) -> RigidTransform:
    d = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    return look_at(position, position + d)


@dataclass(frozen=True)
class OrbitTrajectory:
    """Circle of ``radius_m`` around ``centre`` at ``height_m`` above it, one turn per ``period_s``.

    Pitch (radians above the horizon) is ``pitch_offset_deg`` (for ``outward``; for ``inward`` the
    elevation towards the centre) plus ``pitch_amplitude_deg`` · sin(2π t / ``pitch_period_s``).
    """

    centre: tuple[float, float, float] = (0.0, 0.0, 0.8)
    radius_m: float = 0.3
    height_m: float = 0.3
    period_s: float = 20.0
    start_deg: float = 0.0
    facing: str = "outward"
    pitch_offset_deg: float = 0.0
    pitch_amplitude_deg: float = 55.0
    pitch_period_s: float = 4.0
    bob_m: float = 0.0
    bob_period_s: float = 5.0
    jitter: Jitter = field(default_factory=Jitter)

    def __post_init__(self) -> None:
        if self.facing not in ("inward", "outward"):
            raise InvalidInputError(f"orbit facing: expected 'inward' or 'outward', got {self.facing!r}")
        if self.period_s <= 0 or self.pitch_period_s <= 0 or self.bob_period_s <= 0:
            raise InvalidInputError("orbit periods must be > 0")
        if abs(self.pitch_offset_deg) + abs(self.pitch_amplitude_deg) >= 89.0 and self.facing == "outward":
            raise InvalidInputError("orbit pitch must stay within ±89° (the camera cannot look straight up)")

    def pose(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_device`` at time ``t_s``."""
        c = np.asarray(self.centre, dtype=np.float64)
        a = np.radians(self.start_deg) + 2.0 * np.pi * t_s / self.period_s
        bob = self.bob_m * np.sin(2.0 * np.pi * t_s / self.bob_period_s)
        pos = c + np.array([self.radius_m * np.cos(a), self.radius_m * np.sin(a), self.height_m + bob])
        sweep = np.radians(self.pitch_amplitude_deg) * np.sin(2.0 * np.pi * t_s / self.pitch_period_s)
        if self.facing == "outward":
            yaw, pitch = a, np.radians(self.pitch_offset_deg) + sweep
        else:
            to_c = c - pos
            yaw = np.arctan2(to_c[1], to_c[0])
            pitch = np.arctan2(to_c[2], np.hypot(to_c[0], to_c[1])) + sweep
        pitch = float(np.clip(pitch, np.radians(-85.0), np.radians(85.0)))
        return self.jitter.apply(_look(pos, yaw, pitch), t_s)


@dataclass(frozen=True)
class WaypointTrajectory:
    """Piecewise-linear path: at ``times_s[i]`` the device is at ``positions[i]`` looking at
    ``targets[i]``; held constant before the first and after the last waypoint."""

    times_s: tuple[float, ...]
    positions: tuple[tuple[float, float, float], ...]
    targets: tuple[tuple[float, float, float], ...]
    jitter: Jitter = field(default_factory=Jitter)

    def __post_init__(self) -> None:
        n = len(self.times_s)
        if n == 0 or len(self.positions) != n or len(self.targets) != n:
            raise InvalidInputError("waypoints: times_s, positions and targets must be non-empty and of equal length")
        if np.any(np.diff(self.times_s) <= 0):
            raise InvalidInputError(f"waypoints: times_s must increase strictly, got {self.times_s}")

    def pose(self, t_s: float) -> RigidTransform:
        times = np.asarray(self.times_s)
        pos = np.array([np.interp(t_s, times, np.asarray(self.positions)[:, k]) for k in range(3)])
        tgt = np.array([np.interp(t_s, times, np.asarray(self.targets)[:, k]) for k in range(3)])
        return self.jitter.apply(look_at(pos, tgt), t_s)


def _smootherstep(x: float) -> float:
    """0 → 1 on [0, 1] with zero first and second derivatives at both ends (6x⁵ − 15x⁴ + 10x³)."""
    x = min(max(x, 0.0), 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def blend_poses(a: RigidTransform, b: RigidTransform, w: float) -> RigidTransform:
    """The pose a fraction ``w`` of the way from ``a`` to ``b``: positions mixed linearly, rotations
    along the shortest arc between them (slerp)."""
    if w <= 0.0:
        return a
    if w >= 1.0:
        return b
    rel = Rotation.from_matrix(a.rotation.T @ b.rotation).as_rotvec()
    r = a.rotation @ Rotation.from_rotvec(w * rel).as_matrix()
    return RigidTransform.from_rt(r, (1.0 - w) * a.translation + w * b.translation, a.dst, a.src)


@dataclass(frozen=True)
class SequenceTrajectory:
    """Part i drives the device for t < ``until_s[i]`` (and after the previous part); the last part
    runs on forever. Times are session times.

    ``blend_s[i]`` (0: a cut) joins part i to part i + 1: for |t − until_s[i]| < blend_s[i] / 2 the
    pose is ``blend_poses(part_i(t), part_{i+1}(t), w)`` with w rising from 0 to 1 by a smootherstep,
    so position and orientation stay continuous, with continuous velocity and acceleration (both parts
    are smooth and the weight's first two derivatives vanish at the ends). Blend windows must not
    overlap.
    """

    parts: tuple
    until_s: tuple[float, ...]
    blend_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not self.parts or len(self.until_s) != len(self.parts) - 1:
            raise InvalidInputError("sequence: give one until_s for every part but the last")
        if np.any(np.diff(self.until_s) <= 0):
            raise InvalidInputError(f"sequence: until_s must increase strictly, got {self.until_s}")
        if not self.blend_s:
            object.__setattr__(self, "blend_s", (0.0,) * len(self.until_s))
        if len(self.blend_s) != len(self.until_s):
            raise InvalidInputError(f"sequence: blend_s needs one value per until_s ({len(self.until_s)}), got {self.blend_s}")
        for b in self.blend_s:
            check_number(b, "sequence blend_s", low=0.0)
        edges = [(u - b / 2, u + b / 2) for u, b in zip(self.until_s, self.blend_s)]
        if any(edges[i][1] > edges[i + 1][0] for i in range(len(edges) - 1)):
            raise InvalidInputError(f"sequence: blend windows overlap (until_s {self.until_s}, blend_s {self.blend_s})")

    def pose(self, t_s: float) -> RigidTransform:
        i = int(np.searchsorted(np.asarray(self.until_s), t_s, side="right"))
        # A blend window around the boundary before t (i - 1) or after it (i).
        for j in (i - 1, i):
            if 0 <= j < len(self.until_s) and self.blend_s[j] > 0.0:
                lo = self.until_s[j] - self.blend_s[j] / 2
                if lo < t_s < self.until_s[j] + self.blend_s[j] / 2:
                    w = _smootherstep((t_s - lo) / self.blend_s[j])
                    return blend_poses(self.parts[j].pose(t_s), self.parts[j + 1].pose(t_s), w)
        return self.parts[i].pose(t_s)


Trajectory = OrbitTrajectory | WaypointTrajectory | SequenceTrajectory


def trajectory_from_dict(d: dict) -> Trajectory:
    d = dict(d)
    kind = d.pop("kind", None)
    d.pop("name", None)
    if kind == "sequence":
        parts = [dict(p) for p in d.get("parts", []) or []]
        if not parts:
            raise InvalidInputError("sequence: no parts")
        until = [float(p.pop("until_s")) for p in parts[:-1]]
        blend = [float(p.pop("blend_s", 0.0)) for p in parts[:-1]]
        parts[-1].pop("until_s", None)
        parts[-1].pop("blend_s", None)
        return SequenceTrajectory(tuple(trajectory_from_dict(p) for p in parts), tuple(until), tuple(blend))
    jitter = Jitter(**(d.pop("jitter", None) or {}))
    if kind == "orbit":
        if "centre" in d:
            d["centre"] = tuple(float(x) for x in d["centre"])
        return OrbitTrajectory(jitter=jitter, **d)
    if kind == "waypoints":
        return WaypointTrajectory(
            times_s=tuple(float(t) for t in d["times_s"]),
            positions=tuple(tuple(float(x) for x in p) for p in d["positions"]),
            targets=tuple(tuple(float(x) for x in p) for p in d["targets"]),
            jitter=jitter,
        )
    raise InvalidInputError(f"trajectory kind: unknown {kind!r}; valid kinds are ['orbit', 'sequence', 'waypoints']")


def load_trajectory(name_or_path: str | Path) -> Trajectory:
    """Load a trajectory by name (the packaged ``sim/data/trajectories/NAME.yaml``) or by path (anything with a suffix)."""
    path = Path(name_or_path)
    if not path.suffix:
        path = TRAJECTORIES_DIR / f"{name_or_path}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in TRAJECTORIES_DIR.glob("*.yaml"))
        raise InvalidInputError(f"trajectory {name_or_path!r}: no file {path}; known trajectories are {known}")
    with open(path) as f:
        return trajectory_from_dict(yaml.safe_load(f) or {})
