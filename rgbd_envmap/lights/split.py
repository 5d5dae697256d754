"""Splitting a map into a direct part, for lights, and the indirect rest, for SH (paper 000 §4.2).

The brightest pixels that together hold a fraction τ of the map's energy are the *direct* part: a
luminance threshold is found by accumulating the valid pixels' energy Y · Ω from the brightest pixel
down until τ of the total is reached (a histogram of energy over luminance narrows the search to one
bin, which alone is sorted: one compiled pass, :mod:`rgbd_envmap._kernels.lights_split`), and every
valid pixel at or above it is direct. :func:`direct_part` also sums the direct pixels' own SH
coefficients in that pass. The direct
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
from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import lights_split
from rgbd_envmap.checks import check_array, check_number, check_positive_int
from rgbd_envmap.errors import RangeError
from rgbd_envmap.lights.maps import LUMINANCE_WEIGHTS, check_inputs, luminance, raise_bad_values
from rgbd_envmap.sh.basis import check_bands
from rgbd_envmap.sh.projection import projection_tables

__all__ = ["DirectIndirect", "direct_mask", "direct_part", "light_grid", "split_direct_indirect"]


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


def light_grid(radiance: object, stride: int) -> np.ndarray:
    """The coarse grid a live pipeline splits and samples: every ``stride``-th row and column of an
    equirect map (H, W, 3) float32 or float64, from ``stride // 2`` (a pixel near the middle of
    each stride × stride block), with negative values set to 0 (a correction matrix can leave tiny
    negatives) and NaN kept (the split reports it). A new C-contiguous array of the map's dtype,
    (len(range(s // 2, H, s)), len(range(s // 2, W, s)), 3)."""
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype="float")
    s = check_positive_int(stride, "stride")
    H, W = rad.shape[:2]
    o = s // 2
    out = np.empty((len(range(o, H, s)), len(range(o, W, s)), 3), rad.dtype)
    if out.size:
        lights_split.clamped_subgrid(rad, s, out)
    return out


def direct_mask(radiance: object, tau: float, valid: object = None) -> tuple[np.ndarray, float]:
    """The direct part of a split alone: ((H, W) bool, the threshold) for an equirect map (H, W, 3),
    a fraction ``tau`` ∈ [0, 1] and ``valid`` (H, W) bool or None, with the checks of
    :func:`split_direct_indirect` (which builds on it) and none of its copies: what a caller that keeps
    its own map needs per frame."""
    direct, threshold, _ = _direct(radiance, tau, valid, None)
    return direct, threshold


def direct_part(radiance: object, tau: float, basis: object, valid: object = None
                ) -> tuple[np.ndarray, float, np.ndarray]:
    """:func:`direct_mask` and the direct pixels' own SH coefficients in the same pass: (mask,
    threshold, (K, 3) float64 Σ over direct pixels of radiance × basis × solid angle). ``basis``:
    an int n, the library's real SH basis of n bands (:func:`rgbd_envmap.sh.basis`, K = n², at the
    exact pixel-centre directions, from its separable factors: no table), or an (H·W, K) float
    table of each pixel's basis values times its solid angle (row-major pixels). The indirect
    part's coefficients are then the whole map's minus these, without projecting a second map."""
    direct, threshold, sh = _direct(radiance, tau, valid, basis)
    return direct, threshold, sh


@lru_cache(maxsize=4)
def _trig_tables(width: int, bands: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, W) float64 cos(m φ_u), sin(m φ_u) at the pixel-centre azimuths φ_u = 2π (u + ½) / W − π."""
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    m = np.arange(bands)[:, None]
    tc, ts = np.ascontiguousarray(np.cos(m * phi)), np.ascontiguousarray(np.sin(m * phi))
    tc.setflags(write=False)
    ts.setflags(write=False)
    return tc, ts


def _direct(radiance: object, tau: float, valid: object, basis: object) -> tuple[np.ndarray, float, np.ndarray]:
    """The checked inputs through the kernel: (mask, threshold, SH sums (K, 3), (0, 3) without
    ``basis``); bad values at valid pixels raise the typed errors."""
    tau = check_number(tau, "tau", low=0.0, high=1.0)
    m = check_inputs(radiance, valid)
    H, W = m.radiance.shape[:2]
    none2, none1 = np.zeros((1, 1)), np.zeros(1, np.int64)
    tc = ts = row_w = none2
    m_abs = m_sin = none1
    table = np.zeros((1, 0))
    if basis is None:
        mode, K = 0, 0
    elif isinstance(basis, (int, np.integer)) and not isinstance(basis, bool):
        n = check_bands(basis, "basis")
        tables = projection_tables(H, W, n)
        tc, ts = _trig_tables(W, n)
        row_w, m_abs, m_sin = tables.row_w, tables.m_abs, tables.m_sin
        mode, K = 2, n * n
    else:
        table = check_array(basis, "basis", shape=(H * W, "K"), dtype="float")
        table, mode, K = np.ascontiguousarray(table, np.float64), 1, table.shape[1]
    y = np.empty((H, W))
    mask = np.empty((H, W), bool)
    sh = np.zeros((K, 3))
    valid_arr = m.valid if m.valid is not None else np.ones((1, 1), bool)
    w = LUMINANCE_WEIGHTS
    threshold, _, lowest, finite = lights_split.direct_split(
        m.radiance, valid_arr, m.valid is not None, m.row_omega, w[0], w[1], w[2], tau, table, mode,
        tc, ts, row_w, m_abs, m_sin, y, mask, sh)
    raise_bad_values(m, lowest, finite)
    return mask, float(threshold), sh


def split_direct_indirect(radiance: object, tau: float, valid: object = None) -> DirectIndirect:
    """Split an equirect map (H, W, 3) into the brightest pixels holding a fraction ``tau`` ∈ [0, 1]
    of its luminance energy and the rest (see the module docstring). ``valid`` (H, W) bool or None.
    NaN / infinite / negative radiance at valid pixels raise the typed errors; no valid pixel raises
    InvalidInputError. :func:`direct_mask` gives the direct pixels alone, faster."""
    tau = check_number(tau, "tau", low=0.0, high=1.0)
    m = check_inputs(radiance, valid)
    rad = m.radiance
    direct, threshold, _ = _direct(rad, tau, m.valid, None)
    e = luminance(rad) * m.row_omega[:, None]
    ok = m.valid
    total = float(e.sum() if ok is None else e[ok].sum())
    indirect = rad.copy()
    indirect[direct] = 0
    # per channel Σ L·Ω of each part: row sums (float64) times the row's solid angle
    rest = indirect if ok is None else np.where(ok[..., None], indirect, np.zeros((), rad.dtype))
    i_e = np.sum(rest, axis=1, dtype=np.float64).T @ m.row_omega
    rows = np.nonzero(direct)[0]
    d_e = np.sum(rad[direct].astype(np.float64) * m.row_omega[rows, None], axis=0)
    frac = float(e[direct].sum() / total) if total > 0 else 0.0
    return DirectIndirect(direct, indirect, float(threshold), tau, frac, d_e, i_e)
