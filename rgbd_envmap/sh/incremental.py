"""SH coefficients that follow an environment map's updates: :class:`IncrementalProjection`.

The coefficients c_k = Σ_p w_p Y_k(p) L̃(p) of the filled map L̃ are linear in the map. Between two
frames the map update writes a few percent of the pixels, so instead of projecting the whole map
again the tracker applies the map's change log to the coefficients: the written pixels' colour
changes, the missing pixels that copy them, and the missing pixels whose fill source a new data
pixel changes (steps A–C in :mod:`rgbd_envmap._kernels.sh_incremental`). It keeps, per pixel, the
fill state as one rank key, so that it always equals a fresh fill plan
(:func:`rgbd_envmap.sh.projection.fill_plan`) of the map; the coefficients equal a full
:func:`~rgbd_envmap.sh.projection.project_planar` to float32 rounding of the latter's row sums.
"""

from __future__ import annotations

import weakref
from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import sh_incremental as kernels
from rgbd_envmap.checks import check_positive_int
from rgbd_envmap.errors import RangeError
from rgbd_envmap.sh.basis import check_bands
from rgbd_envmap.sh.projection import (
    FILL_RADIUS_PX,
    check_map_size,
    fill_plan,
    project_with_plan,
    projection_tables,
    raise_non_finite,
)

__all__ = ["IncrementalProjection"]

# Share of the pixels in one change set above which the full projection is cheaper.
_MAX_CHANGED_FRACTION = 1 / 5
_RECORDS = 1 << 13  # changes off the current row (copies met walking a column, C) sorted at a time


def _key_dtype(radius: int) -> type:
    """The smallest unsigned type whose largest value (the key of a missing pixel without a source)
    is above every rank key 4 · radius + 3: one byte per pixel up to radius 62 (the paper's 50)."""
    for dt in (np.uint8, np.uint16, np.uint32):
        if 4 * radius + 3 < np.iinfo(dt).max:
            return dt
    raise RangeError(f"fill_radius_px: expected < 2³⁰, got {radius}")


@lru_cache(maxsize=8)
def _column_tables(width: int, bands: int) -> tuple[np.ndarray, np.ndarray]:
    """(W, 2) float64 cos φ_u, sin φ_u, and for each coefficient k where the change kernel keeps
    its longitude sum: m_col (n²,) int64, 10 ⌊|m| / 5⌋ + |m| mod 5, plus 5 for sin (m < 0)."""
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    phi1 = np.ascontiguousarray(np.stack([np.cos(phi), np.sin(phi)], 1))
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(bands)])
    a = np.abs(m_of_k)
    B = kernels.BLOCK
    m_col = (2 * B * (a // B) + a % B + B * (m_of_k < 0)).astype(np.int64)
    for t in (phi1, m_col):
        t.setflags(write=False)
    return phi1, m_col


class IncrementalProjection:
    """SH coefficients of an :class:`~rgbd_envmap.envmap.EnvironmentMap` that follow its updates.

    ``coefficients(em)`` returns what ``project_planar(em.radiance_planes, em.valid, bands)`` would
    (same fill rule, float64; equal to ~1e-6 relative, the full projection's float32 row sums), but
    after the first call it only visits the pixels ``envmap.update`` wrote since the previous call
    and the missing pixels whose fill they change (the map's change log,
    :meth:`~rgbd_envmap.envmap.EnvironmentMap.record_changes`, which the first call switches on).
    A full projection runs again when the log cannot describe the map's history: another map
    object (e.g. a translated view), a log overflow, or arrays written directly (call
    ``em.mark_modified()`` after doing that), and for change sets above 1/5 of the pixels (then
    the full projection is cheaper). Keeps one byte of fill state per pixel (2 MB at 2000×1000;
    two bytes for ``fill_radius_px`` > 62).

    Args:
        bands: number of SH bands n ≥ 1.
        fill_radius_px: the fill's search radius in pixels (paper: 50).
    """

    def __init__(self, bands: int = 5, *, fill_radius_px: int = FILL_RADIUS_PX) -> None:
        self.bands = check_bands(bands)
        self.fill_radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
        self.full_projections = 0
        self.incremental_updates = 0
        self._map = None
        self._coeffs: np.ndarray | None = None
        self._key_dtype = _key_dtype(self.fill_radius_px)
        self._key_none = int(np.iinfo(self._key_dtype).max)  # the key of a pixel without a source
        self._state: np.ndarray | None = None  # (H W,) fill key per pixel, see kernels.apply_changes
        self._records = _RECORDS  # buffer size of the changes off the current row (tests shrink it)
        self._max_changed_fraction = _MAX_CHANGED_FRACTION
        self._fscr = np.empty(0)  # scratch of kernels.apply_changes, kept between calls
        self._iscr = np.empty(0, np.int64)
        self._acc: np.ndarray | None = None  # (H, 3, 2n − 1) per-row longitude sums of the changes
        self._dirty: np.ndarray | None = None

    def coefficients(self, em) -> np.ndarray:
        """(n², 3) float64 coefficients of ``em`` now (a copy).

        Raises:
            ShapeError: an empty map. NonFiniteError: NaN or infinity at a contributing pixel.
        """
        from rgbd_envmap.envmap.map import check_map  # the envmap package imports nothing of sh

        check_map(em)
        tracked = self._map() if self._map is not None else None
        changes = em.take_changes() if tracked is em else None
        # Past a share of the pixels (a frame from inside the trusted sphere rewrites everything it
        # sees) projecting the whole map costs less.
        if (changes is None or not changes.complete
                or len(changes.index) > em.height * em.width * self._max_changed_fraction):
            self._rebuild(em)
        elif len(changes.index):
            H, W = em.height, em.width
            phi1, m_col = _column_tables(W, self.bands)
            n_float, n_int = kernels.scratch_sizes(H, W, len(changes.index), self._records)
            if self._fscr.size < n_float or self._iscr.size < n_int:
                self._fscr = np.empty(max(n_float, self._fscr.size))
                self._iscr = np.empty(max(n_int, 2 * self._iscr.size), np.int64)
            kernels.apply_changes(em.radiance_planes.reshape(3, H * W), H, W, changes.index, changes.old_radiance,
                                  changes.was_valid, self._state, self._key_none, phi1, self.fill_radius_px,
                                  self._acc, self._dirty, self._records, self._fscr, self._iscr)
            kernels.contract_rows(self._acc, self._dirty, projection_tables(H, W, self.bands).row_w, m_col,
                                  self._coeffs)
            self.incremental_updates += 1
            if not np.isfinite(self._coeffs).all():
                self._rebuild(em)  # names the bad pixel
        return self._coeffs.copy()

    def _rebuild(self, em) -> None:
        H, W = em.height, em.width
        check_map_size(H, W, "em")
        if H * W >= 2**31 - 1:
            raise RangeError(f"em: {H}×{W} pixels is too large for incremental tracking")
        self._map = None
        em.record_changes()
        planes = np.ascontiguousarray(em.radiance_planes, dtype=np.float32)
        plan = fill_plan(em.valid, self.fill_radius_px)
        coeffs = project_with_plan(planes, True, plan, self.bands)
        self.full_projections += 1
        if not np.isfinite(coeffs).all():
            raise_non_finite(planes, True, em.valid, "em.radiance")
        if self._state is None or self._state.size != H * W or self._acc.shape[0] != H:
            self._state = np.empty(H * W, self._key_dtype)
            self._acc = np.zeros((H, 3, 2 * kernels.BLOCK * -(-self.bands // kernels.BLOCK)))
            self._dirty = np.zeros(H, bool)
        kernels.dense_fill_state(plan.row_ptr, plan.col, plan.key, W, self._state, self._key_none)
        self._coeffs = coeffs
        self._map = weakref.ref(em)

    def _fill_state(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """The tracked fill state as a fresh plan states it (for tests): per pixel the flat index of
        the source (−2 data, −1 none) and the rank key (0 data, ``NO_KEY`` none), (H W,) int64."""
        k = self._state.astype(np.int64)
        p = np.arange(k.size)
        d, r = k >> 2, k & 3
        u = p % width
        side = np.where(r == 2, u - d, u + d) % width
        src = np.where(r == 0, p - d * width, np.where(r == 1, p + d * width, p - u + side))
        none = k == self._key_none
        src = np.where(k == kernels.KEY_DATA, -2, np.where(none, -1, src))
        return src, np.where(none, kernels.NO_KEY, k)
