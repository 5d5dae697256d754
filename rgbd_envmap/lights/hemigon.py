"""The Hemigon light sampler: a PDF over an equal-area square mapping of the sphere, inverted at
fixed Halton points, with two temporal low-pass filters across frames (paper 002 §3.1, after Havran
et al. 2005).

Each frame: the map's radiance × solid angle is summed into the cells of two S × S squares, one per
hemisphere (:mod:`rgbd_envmap.lights.hemisphere`; every cell covers 2π / S², so the PDF needs no
sin θ factor, and the mapping has no seam at φ = 0 and no singular pole). The cells' luminance is the
PDF; the n Halton points are inverted as in Pharr (:mod:`rgbd_envmap.lights.cdf`) and mapped back to
directions. Every light carries the luminance power Σ Y·Ω / n in its cell's colour.

Across frames, a :class:`HemigonState` keeps the last ``history`` frames' raw samples and applies
the two filters of the source:

- **energy**: the lights' total power (per channel) is the mean of the last ``history`` frames'
  totals, so a flickering source (a fluorescent tube) does not make the lights flicker;
- **trajectories**: light i's direction is the normalised mean of light i's directions over the last
  ``history`` frames (light i comes from Halton point i in every frame), so lights do not jump.

Both are box FIR filters over the window (our choice of window; the source does not give one we
could follow). They lag abrupt changes by up to ``history`` − 1 frames, as the paper observes. The
history restarts when n or the map's size changes.

References:
    - Havran, Smyk, Krawczyk, Myszkowski, Seidel: Interactive System for Dynamic Scene Lighting using
      Captured Video Environment Maps, EGSR 2005 (the two temporal filters).
    - Nikodým, Havran, Bittner (paper 002) §3.1 and Table 1 ("Hemigon").
"""

from __future__ import annotations

from collections import deque

import numpy as np

from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.lights.cdf import halton_points, invert_cdf
from rgbd_envmap.lights.cells import cell_sums, square_table
from rgbd_envmap.lights.hemisphere import square_to_hemisphere
from rgbd_envmap.lights.maps import MapInputs, luminance

__all__ = ["HemigonState", "default_side", "hemigon_samples"]


def default_side(height: int, width: int) -> int:
    """Side S of the two squares for an H × W map: about 8 map pixels per cell (2S² ≈ H·W / 8),
    at least 2 (S = 354 for 2000 × 1000)."""
    return max(2, int(round(np.sqrt(height * width / 16.0))))


class HemigonState:
    """The history the Hemigon filters need, fed frame after frame by
    ``sample_lights(..., method="hemigon", state=state)``.

    Args:
        history: frames in the filters' window (1 = no filtering); 4 by default.
    """

    def __init__(self, history: int = 4) -> None:
        self.history = check_number(history, "history", low=1, high=1000, integer=True)
        self._key: tuple | None = None
        self._dirs: deque = deque(maxlen=self.history)
        self._totals: deque = deque(maxlen=self.history)

    @property
    def frames(self) -> int:
        """Frames in the window now."""
        return len(self._dirs)

    def reset(self) -> None:
        """Forget the history (the next frame is sampled unfiltered)."""
        self._key = None
        self._dirs.clear()
        self._totals.clear()

    def filter(self, key: tuple, directions: np.ndarray, power: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add a frame's raw lights and return the filtered (directions, power)."""
        if key != self._key:
            self.reset()
            self._key = key
        raw_total = power.sum(axis=0)
        self._dirs.append(directions.copy())
        self._totals.append(raw_total)
        mean_dir = np.mean(np.stack(self._dirs), axis=0)
        norm = np.linalg.norm(mean_dir, axis=1, keepdims=True)
        dirs = np.where(norm > 1e-12, mean_dir / np.where(norm > 1e-12, norm, 1.0), directions)
        total = np.mean(np.stack(self._totals), axis=0)
        n = power.shape[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            scaled = np.where(raw_total > 0, power * (total / np.where(raw_total > 0, raw_total, 1.0)), total / n)
        return dirs, scaled


def hemigon_samples(inputs: MapInputs, n: int, state: HemigonState | None = None, side: int | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Sample n lights from a checked map. Returns (directions (n, 3), power (n, 3), raw directions
    (n, 3) (before the trajectory filter), the chosen cells' mean distance (n,) or None)."""
    H, W = inputs.radiance.shape[:2]
    S = default_side(H, W) if side is None else check_number(side, "side", low=1, high=4096, integer=True)
    if state is not None and not isinstance(state, HemigonState):
        raise InvalidInputError(f"state: expected a HemigonState for method 'hemigon', got {type(state).__name__}")
    with_depth = inputs.depth_m is not None
    sums = cell_sums(inputs, square_table(H, W, S), 2 * S * S, with_depth)
    y = luminance(sums[:, :3])
    total = float(np.sum(y))
    u = halton_points(n)
    if total > 0:
        rows, j, fr, fc = invert_cdf(np.cumsum(y), 2 * S, S, u)
        cell = rows * S + j
        power = sums[cell, :3] / y[cell, None] * (total / n)
    else:
        rows, j, fr, fc = invert_cdf(np.arange(1, 2 * S * S + 1, dtype=np.float64), 2 * S, S, u)
        cell = rows * S + j
        power = np.zeros((n, 3))
    h, i = rows // S, rows % S
    ab = np.stack([-1.0 + 2.0 * (j + fc) / S, -1.0 + 2.0 * (i + fr) / S], axis=1)
    d = square_to_hemisphere(ab)
    d[:, 2] = np.where(h == 1, -d[:, 2], d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    raw = d
    if state is not None:
        d, power = state.filter((n, H, W, S), d, power)
    dist = None
    if with_depth:
        with np.errstate(divide="ignore", invalid="ignore"):
            yo = y[cell]
            dist = np.where(yo > 0, sums[cell, 3] / np.where(yo > 0, yo, 1.0),
                            sums[cell, 4] / np.where(sums[cell, 5] > 0, sums[cell, 5], np.nan))
    return d, power, raw, dist
