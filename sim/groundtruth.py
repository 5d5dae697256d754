"""Ground truth that is computed on demand: the true environment map at any origin and resolution."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap.geometry import equirect_directions
from sim.raycast import SceneRaycaster

__all__ = ["GroundTruthEnvmap", "render_envmap"]


@dataclass(frozen=True)
class GroundTruthEnvmap:
    """The true RGB-D environment map.

    Attributes:
        radiance: (H, W, 3) float32 linear radiance (zero where not ``valid``).
        distance_m: (H, W) float32 Euclidean distance from ``origin`` (zero where not ``valid``).
        valid: (H, W) bool, a surface is hit. object_index: (H, W) int16 (−1 none).
        origin: (3,) float64 world position.
    """

    radiance: np.ndarray
    distance_m: np.ndarray
    valid: np.ndarray
    object_index: np.ndarray
    origin: np.ndarray


def render_envmap(raycaster: SceneRaycaster, origin: np.ndarray, height: int, width: int, t_s: float) -> GroundTruthEnvmap:
    """Ray-cast the scene at time ``t_s`` from ``origin`` through every equirect pixel centre."""
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    dirs = equirect_directions(height, width).reshape(-1, 3)
    hits = raycaster.cast(origin, dirs, t_s)
    shape = (height, width)
    return GroundTruthEnvmap(
        radiance=hits.radiance.reshape(height, width, 3),
        distance_m=np.where(hits.hit, hits.distance_m, 0.0).astype(np.float32).reshape(shape),
        valid=hits.hit.reshape(shape),
        object_index=hits.object_index.reshape(shape).astype(np.int16),
        origin=origin,
    )
