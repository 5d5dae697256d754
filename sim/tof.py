"""Tango-like time-of-flight depth camera: a point cloud with per-point confidence.

Model (docs/design/overview.md, the simulator): 224×172 pixels, 58.5°×46.5° field of view, 3-coefficient radial distortion, returns
between 0.1 and 4 m, Gaussian range noise of ``noise_rel`` × range (1 %). Confidence in [0, 1] is a
product of factors, each from a known failure of ToF sensing:

* emissive surfaces (screens, lamps, windows swamp the IR signal), shiny surfaces (specular multipath)
  and very dark surfaces (weak return): a fixed factor each, and a larger range error;
* grazing incidence: linear in |cos| below ``grazing_cos``;
* long range: falls off over the last metre;
* mixed ("flying") pixels at depth edges: the return mixes foreground and background, the range lands
  in between and confidence drops.

The paper treats confidence < 0.7 as unknown. All randomness comes from the ``rng`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Distortion, Intrinsics, RigidTransform
from sim.raycast import SceneRaycaster
from sim.scene import FLAG_BITS

__all__ = ["ToFConfig", "ToFCapture", "capture_tof"]


def _default_tof_intrinsics() -> Intrinsics:
    # fx = fy = 200 px: 58.5° × 46.5°, inside the colour camera's 78° × 49° so every depth pixel has colour.
    return Intrinsics(224, 172, 200.0, 200.0, 111.5, 85.5, Distortion.radial(-0.04, 0.012, -0.002))


@dataclass(frozen=True)
class ToFConfig:
    """ToF depth camera parameters (defaults: a Tango-like Phab 2 Pro sensor)."""

    intrinsics: Intrinsics = field(default_factory=_default_tof_intrinsics)
    rate_hz: float = 5.0
    #: returns closer than this or farther than ``max_range_m`` are dropped (metres).
    min_range_m: float = 0.1
    max_range_m: float = 4.0
    #: range noise σ as a fraction of the range (0.01 = 1 %).
    noise_rel: float = 0.01
    #: confidence factor and range-noise multiplier per material flag.
    emissive_confidence: float = 0.15
    shiny_confidence: float = 0.4
    dark_confidence: float = 0.3
    flagged_noise_factor: float = 5.0
    #: |cos incidence| below which confidence falls linearly to 0.
    grazing_cos: float = 0.3
    #: relative range jump to a 4-neighbour that marks a depth edge (mixed pixels).
    edge_rel_jump: float = 0.05
    mixed_confidence: float = 0.3
    #: confidence falls by this much over the last metre of range.
    far_confidence_drop: float = 0.15
    #: uniform per-point confidence jitter amplitude.
    confidence_jitter: float = 0.08


@dataclass(frozen=True)
class ToFCapture:
    """One simulated ToF frame with its ground truth.

    Attributes:
        points_m: (N, 3) float32 in the depth sensor frame. confidence: (N,) float32 in [0, 1].
        pixel_index: (N,) int32 flat index (row * W + col) of the pixel each point came from.
        true_depth_m: (H, W) float32 true z-depth (0 where ``true_valid`` is False).
        true_valid: (H, W) bool, a surface within range. object_index: (H, W) int16 (−1 none).
        flags: (H, W) uint8 material flag bits. mixed: (H, W) bool mixed-pixel mask.
    """

    points_m: np.ndarray
    confidence: np.ndarray
    pixel_index: np.ndarray
    true_depth_m: np.ndarray
    true_valid: np.ndarray
    object_index: np.ndarray
    flags: np.ndarray
    mixed: np.ndarray


def capture_tof(
    raycaster: SceneRaycaster, T_world_from_depth: RigidTransform, t_s: float, config: ToFConfig, rng: np.random.Generator
) -> ToFCapture:
    """Simulate one ToF capture of the scene at time ``t_s`` from the true pose ``T_world_from_depth``."""
    intr = config.intrinsics
    h, w = intr.height, intr.width
    rays_z1 = pixel_rays(intr).reshape(-1, 3)
    ray_len = np.linalg.norm(rays_z1, axis=1)
    dirs_cam = rays_z1 / ray_len[:, None]
    dirs_world = T_world_from_depth.rotate(dirs_cam)
    hits = raycaster.cast(T_world_from_depth.translation, dirs_world, t_s)

    rng_true = hits.distance_m.astype(np.float64)
    in_range = hits.hit & (rng_true >= config.min_range_m) & (rng_true <= config.max_range_m)
    true_z = np.where(in_range, rng_true / ray_len, 0.0)

    # Mixed pixels: a 4-neighbour much farther away (or a miss) means the footprint straddles an edge.
    r_img = np.where(hits.hit, rng_true, np.inf).reshape(h, w)
    padded = np.pad(r_img, 1, mode="edge")
    neighbours = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    with np.errstate(invalid="ignore"):
        far_neighbour = np.max(np.where(np.isfinite(neighbours), neighbours, 0.0), axis=0)
        jump = (far_neighbour - r_img) > config.edge_rel_jump * r_img
    mixed = (jump & np.isfinite(r_img)).reshape(-1) & in_range

    flags = hits.flags
    noise_scale = np.ones(h * w)
    conf = 1.0 - rng.uniform(0.0, config.confidence_jitter, h * w)
    for flag, factor in (("emissive", config.emissive_confidence), ("shiny", config.shiny_confidence), ("dark", config.dark_confidence)):
        sel = (flags & FLAG_BITS[flag]) != 0
        conf[sel] *= factor
        noise_scale[sel] = config.flagged_noise_factor
    cos_inc = np.abs(np.sum(hits.normal * dirs_world, axis=1))
    conf *= np.clip(cos_inc / config.grazing_cos, 0.0, 1.0)
    conf *= 1.0 - config.far_confidence_drop * np.clip(rng_true - (config.max_range_m - 1.0), 0.0, 1.0)

    measured = rng_true + rng.normal(0.0, 1.0, h * w) * config.noise_rel * noise_scale * np.where(in_range, rng_true, 0.0)
    alpha = rng.uniform(0.0, 1.0, h * w)
    far = far_neighbour.reshape(-1)
    measured = np.where(mixed, alpha * measured + (1.0 - alpha) * np.where(np.isfinite(far), far, measured), measured)
    conf[mixed] *= config.mixed_confidence

    keep = np.flatnonzero(in_range & (measured > 0))
    z = measured[keep] / ray_len[keep]
    points = (rays_z1[keep] * z[:, None]).astype(np.float32)
    return ToFCapture(
        points_m=points,
        confidence=np.clip(conf[keep], 0.0, 1.0).astype(np.float32),
        pixel_index=keep.astype(np.int32),
        true_depth_m=true_z.reshape(h, w).astype(np.float32),
        true_valid=in_range.reshape(h, w),
        object_index=hits.object_index.reshape(h, w).astype(np.int16),
        flags=flags.reshape(h, w),
        mixed=mixed.reshape(h, w),
    )
