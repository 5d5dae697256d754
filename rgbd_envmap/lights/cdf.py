"""Halton points and the inversion of a piecewise-constant 2D distribution (the PDF samplers' core).

A 2D distribution over an R × C grid is given by its flat cumulative sum ``cdf`` in row-major order
(cdf[r·C + c] = Σ of the weights up to and including cell (r, c)). A point (u₁, u₂) ∈ [0, 1)² is
inverted as Pharr and Humphreys do: u₁ picks the row from the marginal (the rows' totals) and u₂ the
cell within that row from the conditional, each continuously, so that the sample lands at a
continuous position inside its cell. Cells of zero weight are never chosen.

References:
    - Pharr, Humphreys: Infinite Area Light Source with Importance Sampling (pbrt plugin, 2004),
      the marginal / conditional inversion (paper 002 §3.1, [18]).
    - Halton points in bases 2 and 3 (paper 002 §6.1: one fixed sequence for every frame).
"""

from __future__ import annotations

import numpy as np

__all__ = ["halton", "halton_points", "invert_cdf"]


def halton(index: np.ndarray, base: int) -> np.ndarray:
    """Radical inverse of the non-negative integers ``index`` in ``base``: float64 in [0, 1)."""
    i = np.array(index, dtype=np.int64, copy=True)
    out = np.zeros(i.shape)
    f = 1.0 / base
    while np.any(i > 0):
        out += f * (i % base)
        i //= base
        f /= base
    return out


def halton_points(n: int) -> np.ndarray:
    """(n, 2) float64 the Halton points 1 … n in bases (2, 3) (point 0, the corner, is skipped)."""
    k = np.arange(1, n + 1)
    return np.stack([halton(k, 2), halton(k, 3)], axis=1)


def invert_cdf(cdf: np.ndarray, rows: int, cols: int, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Invert the flat CDF (rows·cols,) float64 (non-decreasing, total > 0) at points u (n, 2).

    Returns (row, col) int64 of the chosen cells and the continuous offsets (fr, fc) in [0, 1) of the
    samples inside them (row fraction from u₁, column fraction from u₂)."""
    row_end = cdf[cols - 1::cols]
    row_start = np.concatenate([[0.0], row_end[:-1]])
    total = row_end[-1]
    x1 = np.minimum(u[:, 0] * total, np.nextafter(total, -np.inf))
    r = np.searchsorted(row_end, x1, side="right")
    width = row_end[r] - row_start[r]
    fr = np.clip((x1 - row_start[r]) / width, 0.0, np.nextafter(1.0, 0.0))
    x2 = np.minimum(row_start[r] + u[:, 1] * width, np.nextafter(row_end[r], -np.inf))
    x2 = np.maximum(x2, row_start[r])
    flat = np.searchsorted(cdf, x2, side="right")
    flat = np.clip(flat, r * cols, r * cols + cols - 1)
    prev = np.where(flat % cols == 0, row_start[r], cdf[np.maximum(flat - 1, 0)])
    step = cdf[flat] - prev
    fc = np.clip(np.where(step > 0, (x2 - prev) / np.where(step > 0, step, 1.0), 0.5), 0.0, np.nextafter(1.0, 0.0))
    return r.astype(np.int64), (flat % cols).astype(np.int64), fr, fc
