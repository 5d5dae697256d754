"""Splitting a map into a direct part, for lights, and the indirect rest, for SH (paper 000 §4.2).

The brightest pixels that together hold a fraction τ of the map's energy are the *direct* part: a
luminance threshold is found by accumulating the valid pixels' energy Y · Ω from the brightest pixel
down until τ of the total is reached (a log-luminance histogram narrows the search to one bin, which
alone is sorted), and every valid pixel at or above it is direct. The direct
pixels are handed to a light sampler (``sample_lights(radiance, n, valid=split.direct)``); the
*indirect* rest is the map with those pixels set to zero (and still valid, so that SH projection
does not fill them from their neighbours), to be projected to SH. Every valid pixel is in exactly
one part, so the energy is counted once: direct + indirect = the map's integral, per channel.

Where we depart: the source thresholds each colour channel on its own; we threshold luminance, so
that a pixel is wholly a light or wholly indirect and the two parts partition the pixels.

References:
    - Rohmer, Büschel, Dachselt, Grosch (paper 000) §4.2 (τ, the threshold from the radiance
      histogram accumulated from high to low).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_finite, check_number
from rgbd_envmap.errors import RangeError
from rgbd_envmap.lights.maps import check_inputs, luminance

__all__ = ["DirectIndirect", "direct_mask", "split_direct_indirect"]


@dataclass(frozen=True)
class DirectIndirect:
    """A map split into direct pixels and the indirect rest.

    Attributes:
        direct: (H, W) bool, the valid pixels given to lights.
        indirect: (H, W, 3) float (the map's dtype), the map with the direct pixels set to 0.
        threshold: the luminance at and above which a valid pixel is direct (inf when none is).
        tau: the fraction asked for; ``direct_fraction`` the fraction of energy (luminance) the
            direct pixels hold (≥ tau, unless the map has no energy).
        direct_energy, indirect_energy: (3,) float64 Σ L · Ω of each part over valid pixels.
    """

    direct: np.ndarray
    indirect: np.ndarray
    threshold: float
    tau: float
    direct_fraction: float
    direct_energy: np.ndarray
    indirect_energy: np.ndarray

    def __post_init__(self) -> None:
        for name in ("direct", "indirect", "direct_energy", "indirect_energy"):
            a = np.array(getattr(self, name), copy=True)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.indirect.shape[:2] != self.direct.shape or self.direct.dtype != bool:
            raise RangeError(f"direct: expected an (H, W) bool mask matching indirect {self.indirect.shape}")


def _threshold(y: np.ndarray, e: np.ndarray, target: float) -> float:
    """The largest luminance t such that the pixels with y ≥ t hold ≥ ``target`` energy (y, e: the
    valid pixels' luminance and energy; Σ e ≥ target > 0). A log-luminance histogram of energy finds
    the bin where the sum from the top crosses the target; only that bin's pixels are sorted, so the
    answer is that of a full sort at the cost of one pass."""
    pos = y > 0
    y, e = y[pos], e[pos]
    ly = np.log2(y)
    lo, hi = float(ly.min()), float(ly.max())
    nb = 4096
    idx = np.zeros(y.size, np.int64) if hi == lo else np.clip(((ly - lo) * (nb / (hi - lo))).astype(np.int64), 0, nb - 1)
    e_bin = np.bincount(idx, e, nb)
    above = np.concatenate([np.cumsum(e_bin[::-1])[::-1], [0.0]])  # above[b]: energy of bins ≥ b
    b = int(np.flatnonzero(above[:nb] >= target)[-1]) if (above[:nb] >= target).any() else 0
    inside = idx == b
    yb, eb = y[inside], e[inside]
    order = np.argsort(-yb, kind="stable")
    cum = above[b + 1] + np.cumsum(eb[order])
    m = min(int(np.searchsorted(cum, target, side="left")), yb.size - 1)
    return float(yb[order[m]])


def direct_mask(radiance: object, tau: float, valid: object = None) -> tuple[np.ndarray, float]:
    """The direct part of a split alone: ((H, W) bool, the threshold) for an equirect map (H, W, 3),
    a fraction ``tau`` ∈ [0, 1] and ``valid`` (H, W) bool or None, with the checks of
    :func:`split_direct_indirect` (which builds on it) and none of its copies: what a caller that keeps
    its own map needs per frame."""
    tau = check_number(tau, "tau", low=0.0, high=1.0)
    m = check_inputs(radiance, valid)
    direct, threshold, _, _ = _direct(m, tau)
    return direct, threshold


def _direct(m, tau: float) -> tuple[np.ndarray, float, np.ndarray, float]:
    """(direct mask, threshold, per-pixel energy Y · Ω (H, W), total energy) of checked inputs."""
    rad = m.radiance
    H, W = rad.shape[:2]
    y = luminance(rad)
    ok = m.valid
    where = "" if ok is None else " (at valid pixels)"
    # a NaN or infinite channel makes the (positive-weighted) luminance non-finite
    if not np.isfinite(y if ok is None else y[ok]).all():
        check_finite(rad if ok is None else rad[ok], "radiance" + where)
    low = float(rad.min()) if ok is None else float(np.min(np.where(ok[..., None], rad, 0), initial=0.0))
    if low < 0:
        raise RangeError(f"radiance: expected values ≥ 0{where}, got a smallest value of {low}")
    e = y * m.row_omega[:, None]
    yv, ev = (y.ravel(), e.ravel()) if ok is None else (y[ok], e[ok])
    total = float(ev.sum())
    if tau > 0 and total > 0:
        threshold = _threshold(yv, ev, tau * total * (1 - 1e-12))
        direct = y >= threshold
        if ok is not None:
            direct &= ok
        return direct, threshold, e, total
    return np.zeros((H, W), bool), np.inf, e, total


def split_direct_indirect(radiance: object, tau: float, valid: object = None) -> DirectIndirect:
    """Split an equirect map (H, W, 3) into the brightest pixels holding a fraction ``tau`` ∈ [0, 1]
    of its luminance energy and the rest (see the module docstring). ``valid`` (H, W) bool or None.
    NaN / infinite / negative radiance at valid pixels raise the typed errors; no valid pixel raises
    InvalidInputError. :func:`direct_mask` gives the direct pixels alone, faster."""
    tau = check_number(tau, "tau", low=0.0, high=1.0)
    m = check_inputs(radiance, valid)
    rad = m.radiance
    direct, threshold, e, total = _direct(m, tau)
    ok = m.valid
    indirect = rad.copy()
    indirect[direct] = 0
    # per channel Σ L·Ω of each part: row sums (float64) times the row's solid angle
    rest = indirect if ok is None else np.where(ok[..., None], indirect, np.zeros((), rad.dtype))
    i_e = np.sum(rest, axis=1, dtype=np.float64).T @ m.row_omega
    rows = np.nonzero(direct)[0]
    d_e = np.sum(rad[direct].astype(np.float64) * m.row_omega[rows, None], axis=0)
    frac = float(e[direct].sum() / total) if total > 0 else 0.0
    return DirectIndirect(direct, indirect, float(threshold), tau, frac, d_e, i_e)
