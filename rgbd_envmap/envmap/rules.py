"""The map update's rules (paper 003 §6.1, plus free-space carving), one scalar function each.

These are the spec of :func:`rgbd_envmap.envmap.map_update.update`: the update's kernel inlines exactly
these functions, and :func:`rgbd_envmap.reference.envmap.update_reference` applies them pixel by
pixel. They are numba-compiled and callable from Python on scalars. A stored pixel takes a frame's
sample when any rule holds:

* **empty** — the pixel has no data;
* **closer** — the sample is closer to the origin than the stored depth;
* **trusted** — the device is inside the trusted sphere (10 cm) around the origin;
* **removal** — the device lies within 3 cm of the pixel's ray and the sample is not a *backface*:
  the device's projection on the ray, (device − origin)·d, is not larger than the stored or the new
  depth;
* **freed** (ours) — the frame's measured depth shows the stored point to be free space.

References:
    Monroy, Hudon, Smolic (2018), Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §6.1.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["rule_empty", "rule_closer", "rule_trusted", "rule_removal", "rule_freed", "is_backface", "freed_limit"]


@numba.njit(cache=True)
def rule_empty(valid: bool) -> bool:
    """The pixel has no data yet."""
    return not valid


@numba.njit(cache=True)
def rule_closer(new_depth_m: float, stored_depth_m: float) -> bool:
    """The sample is closer to the origin than the stored surface."""
    return new_depth_m < stored_depth_m


@numba.njit(cache=True)
def rule_trusted(device_to_origin_m: float, trusted_radius_m: float) -> bool:
    """The device is inside the trusted sphere around the origin."""
    return device_to_origin_m < trusted_radius_m


@numba.njit(cache=True)
def is_backface(device_along_ray_m: float, new_depth_m: float, stored_depth_m: float) -> bool:
    """The device's projection on the ray lies beyond the stored or the new depth."""
    return device_along_ray_m > stored_depth_m or device_along_ray_m > new_depth_m


@numba.njit(cache=True)
def rule_removal(
    device_along_ray_m: float, device_to_ray_m: float, new_depth_m: float, stored_depth_m: float, removal_radius_m: float
) -> bool:
    """The device is within ``removal_radius_m`` of the ray and the sample is not a backface."""
    return device_to_ray_m < removal_radius_m and not is_backface(device_along_ray_m, new_depth_m, stored_depth_m)


@numba.njit(cache=True, inline="always")
def freed_limit(z_m, tol_rel, tol_abs_m):  # pragma: no cover - compiled
    """The measured depth beyond which a stored point at camera z-depth ``z_m`` is seen through."""
    return np.float32(z_m * (1.0 + tol_rel) + tol_abs_m)


@numba.njit(cache=True)
def rule_freed(stored_z_m: float, seen_min_depth_m: float, tol_rel: float, tol_abs_m: float) -> bool:
    """Free-space carving (ours, not the paper's): the stored surface point, at z-depth ``stored_z_m``
    in the frame's depth camera, is free space when the smallest measured depth of the pixels around
    its projection (``UpdateConfig.carve_window``; by default the one it falls in) lies beyond it by
    more than ``tol_rel`` · z + ``tol_abs_m`` (the device saw through it). Unmeasured pixels count as
    depth 0, so they never free a point."""
    return seen_min_depth_m > freed_limit(stored_z_m, tol_rel, tol_abs_m)

