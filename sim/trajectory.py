"""Device trajectories: the true pose of the device (its colour camera, OpenCV axes) over time.

Kinds (YAML under ``sim/data/trajectories/``, shipped as package data):

* ``orbit``: the device circles a centre; ``facing: outward`` looks away from it (scanning the room
  from near the virtual object, with a pitch sweep to reach floor and ceiling), ``inward`` looks at it.
* ``waypoints``: piecewise-linear positions and look-at targets at given times (a handheld sweep).
* ``sequence``: several of the above in turn, each ``until_s`` a time (global session time).

Any kind takes ``jitter_m`` / ``jitter_deg``: smooth hand shake, a sum of seeded sinusoids (0.3–2 Hz),
part of the *true* pose. Tracking noise (error in the *reported* pose) belongs to the device.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import look_at
from rgbd_envmap.types import RigidTransform

__all__ = [
    "Jitter", "OrbitTrajectory", "WaypointTrajectory", "SequenceTrajectory", "Trajectory", "load_trajectory", "TRAJECTORIES_DIR",
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


@dataclass(frozen=True)
class SequenceTrajectory:
    """Part i drives the device for t < ``until_s[i]`` (and after the previous part); the last part
    runs on forever. Times are session times."""

    parts: tuple
    until_s: tuple[float, ...]

    def __post_init__(self) -> None:
        if not self.parts or len(self.until_s) != len(self.parts) - 1:
            raise InvalidInputError("sequence: give one until_s for every part but the last")
        if np.any(np.diff(self.until_s) <= 0):
            raise InvalidInputError(f"sequence: until_s must increase strictly, got {self.until_s}")

    def pose(self, t_s: float) -> RigidTransform:
        i = int(np.searchsorted(np.asarray(self.until_s), t_s, side="right"))
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
        parts[-1].pop("until_s", None)
        return SequenceTrajectory(tuple(trajectory_from_dict(p) for p in parts), tuple(until))
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
