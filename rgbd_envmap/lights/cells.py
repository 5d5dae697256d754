"""Which cell each equirect pixel falls in, and the per-cell sums of radiance × solid angle.

Both region-based samplers work on cells that are not equirect pixels: the Q2-Tree on HEALPix quads
(nested scheme, so the cells of level l + 1 inside cell p of level l are 4p … 4p + 3) and Hemigon on
the two S × S squares of :mod:`rgbd_envmap.lights.hemisphere`. A pixel belongs to the cell its
centre falls in (``healpy.vec2pix`` on the pixel-centre direction for HEALPix). The tables depend
only on the sizes and are cached (read-only int32 (H, W)). :func:`cell_sums` adds each valid pixel's
radiance × exact solid angle into its cell in one pass (a numba kernel,
:mod:`rgbd_envmap._kernels.lights_cells`), so the cells' sums add up to the map's integral exactly,
to float64 rounding: no pixel is resampled, split or lost.

The price of the choice: a cell gets the whole of every pixel whose centre it holds, so a cell's
power is that of a union of pixels, not of its exact area; at the finest level, cells smaller than a
pixel can be empty. The Q2-Tree's finest level is chosen so that cells are no smaller than the mean
pixel (:func:`finest_level`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import lights_cells
from rgbd_envmap.geometry import equirect_directions
from rgbd_envmap.lights.hemisphere import hemisphere_to_square
from rgbd_envmap.lights.maps import LUMINANCE_WEIGHTS, MapInputs, raise_bad_values

__all__ = ["MAX_LEVEL", "finest_level", "healpix_table", "square_table", "cell_sums"]

#: deepest Q2-Tree level made (nside 2^9 = 512: 3.1 M quads, about 150 MB of sums with depth).
MAX_LEVEL = 9


def finest_level(height: int, width: int, n: int) -> int:
    """The Q2-Tree's finest level for an H × W map and n lights: the deepest level whose quads hold
    at least 4 pixels on average (12 · 4^l ≤ H · W / 4: level 7, nside 128, for 2000 × 1000),
    deepened if needed so that 12 · 4^l ≥ n, at most :data:`MAX_LEVEL`."""
    level = 0
    while level < MAX_LEVEL and 4 * 12 * 4 ** (level + 1) <= height * width:
        level += 1
    while level < MAX_LEVEL and 12 * 4 ** level < n:
        level += 1
    return level


@lru_cache(maxsize=4)
def _healpix_cached(height: int, width: int, level: int) -> np.ndarray:
    import healpy

    d = equirect_directions(height, width).reshape(-1, 3).astype(np.float64)
    pix = healpy.vec2pix(2 ** level, d[:, 0], d[:, 1], d[:, 2], nest=True).astype(np.int32)
    pix = pix.reshape(height, width)
    pix.setflags(write=False)
    return pix


def healpix_table(height: int, width: int, level: int) -> np.ndarray:
    """(H, W) int32: the nested HEALPix index, at nside = 2^level, of each pixel centre (cached)."""
    return _healpix_cached(int(height), int(width), int(level))


@lru_cache(maxsize=4)
def _square_cached(height: int, width: int, side: int) -> np.ndarray:
    d = equirect_directions(height, width).astype(np.float64)
    ab = hemisphere_to_square(d)
    j = np.clip(np.floor((ab[..., 0] + 1.0) * 0.5 * side), 0, side - 1).astype(np.int64)
    i = np.clip(np.floor((ab[..., 1] + 1.0) * 0.5 * side), 0, side - 1).astype(np.int64)
    lower = d[..., 2] < 0
    table = (lower * side * side + i * side + j).astype(np.int32)
    table.setflags(write=False)
    return table


def square_table(height: int, width: int, side: int) -> np.ndarray:
    """(H, W) int32: the Hemigon cell of each pixel centre, h·S² + i·S + j with h = 0 for the upper
    hemisphere (z ≥ 0), 1 for the lower, row i along the square's b axis, column j along a (cached)."""
    return _square_cached(int(height), int(width), int(side))


def cell_sums(inputs: MapInputs, table: np.ndarray, ncells: int, with_depth: bool) -> np.ndarray:
    """(ncells, 3) float64 Σ radiance × Ω per cell, or with depth (ncells, 6): then also Σ Y·Ω·depth,
    Σ Ω·depth and Σ Ω of the valid pixels (Y the luminance). Raises the typed errors for NaN,
    infinite or negative radiance at valid pixels."""
    out = np.zeros((ncells, 6 if with_depth else 3))
    dummy_b = np.ones((1, 1), bool)
    dummy_d = np.zeros((1, 1), np.float32)
    valid = dummy_b if inputs.valid is None else inputs.valid
    depth = dummy_d if (inputs.depth_m is None or not with_depth) else inputs.depth_m
    wr, wg, wb = LUMINANCE_WEIGHTS
    lo, finite = lights_cells.cell_sums(inputs.radiance, valid, inputs.valid is not None, inputs.row_omega, table,
                                        depth, with_depth, wr, wg, wb, out)
    raise_bad_values(inputs, lo, finite)
    return out
