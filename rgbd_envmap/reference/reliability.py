"""References of reliability marking (:mod:`rgbd_envmap.depth.reliability`), one pixel at a time.

- :func:`monroy2018_reference`: the authors' statistic S = Σ (d_i − d)² / d over the known
  8-neighbours, term by term;
- :func:`noise_model_reference`: the noise-model χ² of each pixel, from a weighted least-squares plane
  fit of 1/z over its known 3×3 window (``np.linalg.lstsq``), with the pixel's neighbour count;
- :func:`exposure_reference`: the exposure rule with every comparison made exactly, in float64;
- :func:`known_offsets` and :func:`in_image_neighbours`: the window and the border rule.

A pixel is testable when it is known and has at least min(``min_neighbours``, its in-image
neighbours) known 8-neighbours (and, for the noise model, ≥ 3 for the plane fit); it passes when the
statistic is at most the threshold: 14.07 for ``monroy2018``, the χ² (1 − p)-quantile at n − 3
degrees of freedom (n known pixels in the window) for ``noise_model``.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

__all__ = ["known_offsets", "monroy2018_reference", "noise_model_reference", "in_image_neighbours",
           "exposure_reference"]


def known_offsets(known: np.ndarray, r: int, c: int, centre: bool) -> Iterator[tuple[int, int]]:
    """The offsets (dr, dc) ∈ {−1, 0, 1}² of the known pixels of the 3×3 window around (r, c) inside
    the image, row by row; the centre itself only when ``centre``."""
    h, w = known.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if (dr, dc) == (0, 0) and not centre:
                continue
            rr, cc = r + dr, c + dc
            if 0 <= rr < h and 0 <= cc < w and known[rr, cc]:
                yield dr, dc


def monroy2018_reference(depth: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The authors' S = Σ_{known 8-neighbours} (d_i − d)² / d at every known pixel (0 elsewhere),
    term by term, with d the z-depth in metres."""
    s = np.zeros(depth.shape)
    for r, c in zip(*np.nonzero(known)):
        d = depth[r, c]
        s[r, c] = sum((depth[r + dr, c + dc] - d) ** 2 / d for dr, dc in known_offsets(known, r, c, False))
    return s


def noise_model_reference(depth: np.ndarray, known: np.ndarray, noise_rel: float = 0.01,
                          noise_abs: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per known pixel: the weighted least-squares plane fit of 1/z over the known pixels of its 3×3
    window, 1/z ≈ β₀ + β₁ dc + β₂ dr with weights 1/σ_i², σ_i = (noise_abs + noise_rel z_i) / z_i²
    (the depth noise σ_z propagated to 1/z), and its statistic T = Σ (r_i / σ_i)² of the residuals.

    Returns:
        (T (H, W) float64, NaN where the window has fewer than 4 known pixels or the pixel is unknown;
        the number of known 8-neighbours (H, W) int, 0 at unknown pixels).
    """
    t = np.full(depth.shape, np.nan)
    n_nb = np.zeros(depth.shape, int)
    for r, c in zip(*np.nonzero(known)):
        win = list(known_offsets(known, r, c, True))
        n_nb[r, c] = len(win) - 1
        if len(win) < 4:
            continue
        z = np.array([depth[r + dr, c + dc] for dr, dc in win])
        a = np.array([[1.0, dc, dr] for dr, dc in win])
        y = 1.0 / z
        sig = (noise_abs + noise_rel * z) / z**2
        beta, *_ = np.linalg.lstsq(a / sig[:, None], y / sig, rcond=None)
        t[r, c] = np.sum(((y - a @ beta) / sig) ** 2)
    return t, n_nb


def in_image_neighbours(shape: tuple[int, int]) -> np.ndarray:
    """(H, W) int: the number of 8-neighbours of each pixel that lie inside the image (8 inside, 5 on
    a border, 3 in a corner; fewer in images one pixel wide)."""
    h, w = shape
    rows = np.array([min(r + 1, h - 1) - max(r - 1, 0) + 1 for r in range(h)])
    cols = np.array([min(c + 1, w - 1) - max(c - 1, 0) + 1 for c in range(w)])
    return rows[:, None] * cols[None, :] - 1


def exposure_reference(rgb: np.ndarray, dark: float, bright: float) -> np.ndarray:
    """The exposure rule, (..., 3) → (...) bool: False where all three channels are < ``dark`` or all
    three are > ``bright``, or where the channel sum is not finite. Every comparison is made exactly
    (in float64); the finiteness of the channel sum in the colour's own precision (a float32 sum of
    channels near 3.4e38 overflows, and such a pixel counts as non-finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.isfinite(rgb[..., 0] + rgb[..., 1] + rgb[..., 2])
    x = rgb.astype(np.float64)
    return finite & ~(x < dark).all(axis=-1) & ~(x > bright).all(axis=-1)
