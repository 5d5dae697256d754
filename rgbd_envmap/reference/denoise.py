"""Reference of the edge-aware plane-fit denoiser (:mod:`rgbd_envmap.depth.denoise`), one pixel at a
time with numpy's least squares.

At every measured pixel, fit 1/z = a·x + b·y + c over the measured pixels of its (2h+1)² window whose
depth lies within ``tol`` of the centre's (x, y the normalised ray coordinates relative to the centre
pixel's ray), and replace the depth by the fit at the centre, 1/c. A pixel keeps its measurement
when it has fewer than ``min_in`` inliers (itself included), when the inliers do not determine a
plane (rank < 3), or when the fit is not positive. The kernels solve the same normal equations in
float32 sums and a float64 Cramer's rule; the tests compare within float32 rounding.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics

__all__ = ["plane_fit_reference"]


def plane_fit_reference(z: np.ndarray, known: np.ndarray, intr: Intrinsics, half: int = 2, tol: float = 0.04,
                        min_in: int = 6) -> np.ndarray:
    """:func:`rgbd_envmap.depth.denoise.denoise_depth` (``half_window``, ``tol_rel``, ``min_inliers``)
    written out with ``np.linalg.lstsq``; ``known`` pixels must hold finite depths > 0.

    Returns:
        (H, W) float32: the fitted depth where the fit succeeds, the input elsewhere.
    """
    rays = pixel_rays(intr)
    out = z.astype(np.float32).copy()
    h, w = z.shape
    for r in range(h):
        for c in range(w):
            if not known[r, c]:
                continue
            rows, cols = np.mgrid[max(r - half, 0):min(r + half, h - 1) + 1, max(c - half, 0):min(c + half, w - 1) + 1]
            sel = known[rows, cols] & (np.abs(z[rows, cols] - z[r, c]) <= tol * z[r, c])
            if sel.sum() < min_in:
                continue
            x = rays[rows, cols, 0][sel] - rays[r, c, 0]
            y = rays[rows, cols, 1][sel] - rays[r, c, 1]
            A = np.stack([x, y, np.ones_like(x)], 1)
            if np.linalg.matrix_rank(A) < 3:
                continue
            sol = np.linalg.lstsq(A, 1.0 / z[rows, cols][sel], rcond=None)[0]
            if sol[2] > 0:
                out[r, c] = 1.0 / sol[2]
    return out
