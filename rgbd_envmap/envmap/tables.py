"""Per-size tables of the equirect map that the update and the translation read (cached: they
depend only on the map's size)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["trig_tables", "trig_columns", "col_limits"]


@lru_cache(maxsize=8)
def trig_tables(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, 2) sin θ, cos θ of each row centre and (W, 2) sin φ, cos φ of each column centre, float32."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    rows = np.stack([np.sin(theta), np.cos(theta)], -1).astype(np.float32)
    cols = np.stack([np.sin(phi), np.cos(phi)], -1).astype(np.float32)
    return rows, cols


@lru_cache(maxsize=8)
def trig_columns(height: int, width: int) -> tuple[np.ndarray, ...]:
    """Contiguous float32 sin θ, cos θ of the rows and sin φ, cos φ of the columns."""
    rows, cols = trig_tables(height, width)
    return tuple(np.ascontiguousarray(a) for a in (rows[:, 0], rows[:, 1], cols[:, 0], cols[:, 1]))


@lru_cache(maxsize=8)
def col_limits(height: int, width: int, max_splat: int) -> np.ndarray:
    """(H,) float64 largest half-width in columns of a footprint landing in each row: ``max_splat``
    rows' angle at that latitude (1/sin θ more columns), at most half the map."""
    rows, _ = trig_tables(height, width)
    return np.minimum(max_splat / np.maximum(rows[:, 0].astype(np.float64), 1e-6), width // 2)

