"""Reference of the SH projection (:func:`rgbd_envmap.sh.project_equirect`,
:func:`rgbd_envmap.sh.project_planar`): the sum over pixels written out in float64.

L_k = Σ_p Y_k(d_p) L̃_p Ω_p over the pixels p = (v, u) of an H × W equirect map, with

- d_p the direction of the pixel centre (docs/reference/conventions.md): polar angle
  θ_v = π (v + ½) / H from +z (row 0 is the zenith), azimuth φ_u = 2π (u + ½) / W − π;
- Ω_p the exact solid angle of the pixel, (2π / W) (cos(π v / H) − cos(π (v + 1) / H));
- L̃ the map read as float32 (what the projection reads) with its missing pixels filled by the
  rule of :mod:`rgbd_envmap.reference.sh_fill`; pixels that cannot be filled count as 0;
- Y_k the real SH basis of :func:`rgbd_envmap.sh.basis`.

The library computes the same sum separably, in float32 per row and float64 over rows, so the two
agree to float32 rounding of the row sums (about 1e-6 of the largest coefficient).
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.reference.sh_fill import fill_missing
from rgbd_envmap.sh.basis import basis

__all__ = ["pixel_directions", "pixel_solid_angles", "project_equirect"]


def pixel_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) float64 unit directions of the pixel centres."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def pixel_solid_angles(height: int, width: int) -> np.ndarray:
    """(H, W) float64 exact solid angles of the pixels (they sum to 4π)."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return np.repeat(((2.0 * np.pi / width) * (edges[:-1] - edges[1:]))[:, None], width, axis=1)


def project_equirect(radiance: np.ndarray, valid: np.ndarray | None = None, bands: int = 5,
                     fill_radius_px: int = 50) -> np.ndarray:
    """(bands², 3) float64 coefficients of an (H, W, 3) radiance map, ``valid`` (H, W) bool or None
    (every pixel has data). Slow (the fill visits pixels one by one): for small maps."""
    rad = np.asarray(radiance, np.float32).astype(np.float64)
    H, W = rad.shape[:2]
    if valid is not None:
        filled, used = fill_missing(rad, np.asarray(valid, bool), fill_radius_px)
        rad = np.where(used[..., None], filled, 0.0)
    Y = basis(pixel_directions(H, W).reshape(-1, 3), bands)  # (H W, bands²)
    return Y.T @ (rad.reshape(-1, 3) * pixel_solid_angles(H, W).reshape(-1, 1))
