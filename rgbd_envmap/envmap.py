"""The RGB-D environment map (paper 003 §6): state, the update rules, colour pairs, translation.

The map is equirectangular (docs/CONVENTIONS.md) around an ``origin`` in the world frame. Each pixel
holds linear radiance in the *reference* colour space (the first frame's), the Euclidean distance of
the surface from the origin (``depth_m``), and a ``valid`` flag. Radiance is stored planar,
(3, H, W) float32, because SH projection reads one channel at a time; ``radiance`` is an (H, W, 3)
view of it.

Update (§6.1), per pixel hit by a frame; within one frame the closest sample wins. The stored pixel
takes the sample when any rule holds:

* **empty** — the pixel has no data;
* **closer** — the sample is closer to the origin than the stored depth;
* **trusted** — the device is inside the trusted sphere (10 cm) around the origin;
* **removal** — the device lies within 3 cm of the pixel's ray and the sample is not a *backface*:
  the device's projection on the ray, (device − origin)·d, is not larger than the stored or the new
  depth.

Taking a sample replaces the colour; the depth becomes the mean of the old and new depth (the new
depth for an empty pixel).

**Footprint splatting.** At 2000×1000 a far wall's EM pixel (0.18°) is smaller than a ToF pixel seen
from near the origin, so projecting each sample to one pixel (the paper's description) leaves a
sieve of holes that the SH stage must paper over. By default each sample covers the EM pixels of
its footprint: its lateral size at the surface, ``range / f`` (``f`` the depth camera's focal length
in pixels), seen from the origin at distance ``r``, in rows and (divided by sin θ) columns.
``splat=False`` is the paper's one-pixel projection. Pairs for colour correction always use the one
pixel a sample falls in.

Translation (§6.2): every valid pixel is unprojected with its depth, the origin moves, and the
points are reprojected with a z-buffer (closest wins). Each pixel covers the target pixels within
half the distance to where its 4-neighbours land, so magnified regions (moving towards a surface,
oblique floors and ceilings) stay closed; neighbours across a depth jump are ignored, so the
disoccluded region behind an edge stays empty instead of being smeared. The baseline ``gardner``
(Gardner et al. 2017) assumes every pixel lies on a sphere of fixed radius around the old origin and
warps backwards (no holes, wrong parallax).

Implementation (for speed; figures in docs/envmap.md). The update computes map coordinates and
footprints 256 samples at a time in vectorised loops and records each footprint with an int64
z-buffer key (float32 distance bits, then an order code, then the fill-only flag) whose ``min``
over the samples covering a pixel is the sample a sequential "closer wins" test in sample order
keeps, so footprints can be merged in any order. They are listed per band of 16 map rows; band
by band they are merged into a one-band z-buffer that stays in cache (a footprint of at most 2×2
pixels is four branch-free tests, one of at most 4 or 8 columns four or eight per row) and the
band's rows go through the rules at once, over the runs of 32-column tiles they touched. The rules
are branch-free selects except in the few rows where the removal rule can hold (the device within
the removal radius of the pixel's ray: a cone around the device's direction); a row's carving
candidates are projected into the frame together (a vectorised loop); taken pixels are written in
raster order, so the change log is too.
Translation (its kernels) lives in :mod:`rgbd_envmap.translation`; :func:`translate` here is its entry point.

References:
    Monroy, Hudon, Smolic (2018), §5.2 (pairs), §6.1 (update), §6.2 (translation).
    Gardner et al. (2017), Learning to Predict Indoor Illumination from a Single Image, §4 (warping).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
import numpy as np

from rgbd_envmap._intrinsics import _PRANGE_ONLY, _bits_f32, _f32_bits, _min_run8, _prefetch
from rgbd_envmap.checks import check_array, check_positive_int
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import brown_distort, pixel_rays
from rgbd_envmap.types import Intrinsics, RigidTransform

__all__ = [
    "EnvironmentMap",
    "MapChanges",
    "SeenDepth",
    "UpdateConfig",
    "UpdateStats",
    "collect_pairs",
    "frame_points",
    "update",
    "translate",
    "rule_empty",
    "rule_closer",
    "rule_trusted",
    "rule_removal",
    "rule_freed",
    "is_backface",
    "TRANSLATE_METHODS",
]

TRANSLATE_METHODS = ("depth", "gardner")


class EnvironmentMap:
    """An RGB-D equirect environment map; the only stateful object of the pipeline.

    Attributes:
        height, width: map size (W = 2H by convention).
        origin: (3,) float64 world position of the map's centre.
        radiance: (H, W, 3) float32 view of the planar storage ``radiance_planes`` (3, H, W).
        depth_m: (H, W) float32 Euclidean distance from ``origin``; meaningful where ``valid``.
        valid: (H, W) bool.
    """

    def __init__(self, height: int = 1000, width: int = 2000, origin: np.ndarray = (0.0, 0.0, 0.0)) -> None:
        self.height = check_positive_int(height, "height")
        self.width = check_positive_int(width, "width")
        self.origin = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
        self.radiance_planes = np.zeros((3, self.height, self.width), np.float32)
        self.depth_m = np.zeros((self.height, self.width), np.float32)
        self.valid = np.zeros((self.height, self.width), bool)
        self._scratch: tuple[np.ndarray, ...] | None = None
        self._scratch2: tuple[np.ndarray, np.ndarray, _ChangeLog] | None = None
        self._averaged: np.ndarray | None = None
        self._changes: _ChangeLog | None = None
        self._spare_changes: _ChangeLog | None = None

    def _update_scratch(self, n_samples: int = 0) -> tuple[np.ndarray, ...]:
        """The scratch of :func:`update`, allocated on the first update (maps made by ``translate``
        or ``copy`` for viewing never need it) and grown to ``n_samples``: the z-buffer, one band of
        2**_BAND_SHIFT rows of int64 keys (flat), :data:`_EMPTY_Z` between updates; its flat uint8
        map of touched 32-column tiles, all clear between updates (each update resets what it
        touched); and per-sample footprint records (n, 4) int32, keys (n,) int64 and band lists
        (2n,) int32 (fresh buffers of these sizes cost page faults on every update)."""
        if self._scratch is None:
            rows = min(1 << _BAND_SHIFT, self.height)
            n_tiles = (self.width + (1 << _TILE_SHIFT) - 1) >> _TILE_SHIFT
            self._scratch = (np.full(rows * self.width, _EMPTY_Z, np.int64), np.zeros(rows * n_tiles, np.uint8),
                             np.empty((0, 4), np.int32), np.empty(0, np.int64), np.empty(0, np.int32))
        if len(self._scratch[2]) < n_samples:
            n = max(n_samples, 2 * len(self._scratch[2]))
            self._scratch = (*self._scratch[:2], np.empty((n, 4), np.int32), np.empty(n, np.int64), np.empty(2 * n, np.int32))
        return self._scratch

    def _second_thread_scratch(self, log_capacity: int) -> tuple[np.ndarray, np.ndarray, "_ChangeLog"]:
        """The second thread's z-buffer band, tile flags and change log (as long as the map's, or
        empty when the map is not recording) for a two-thread :func:`update`."""
        zband, tiles = self._update_scratch()[:2]
        if self._scratch2 is None:
            self._scratch2 = (np.full_like(zband, _EMPTY_Z), np.zeros_like(tiles), _NO_LOG)
        if self._scratch2[2].capacity != log_capacity:
            self._scratch2 = (*self._scratch2[:2], _NO_LOG if log_capacity == 0 else _ChangeLog(log_capacity))
        return self._scratch2

    def _averaged_counts(self) -> np.ndarray:
        """(H, W) uint8: how many samples beyond the first each pixel's colour averages (the
        ``colour_average`` of :class:`UpdateConfig`), allocated (zeros) on the first update that
        averages. Maps made by ``from_arrays``, ``copy`` or ``translate`` start at zero: each pixel's
        colour counts as one sample."""
        if self._averaged is None:
            self._averaged = np.zeros((self.height, self.width), np.uint8)
        return self._averaged

    @classmethod
    def _uninitialised(cls, height: int, width: int, origin: np.ndarray) -> "EnvironmentMap":
        """A map whose arrays are allocated but not zeroed, for a kernel that writes every pixel."""
        em = cls.__new__(cls)
        em.height, em.width = int(height), int(width)
        em.origin = np.asarray(origin, np.float64).copy()
        em.radiance_planes = np.empty((3, em.height, em.width), np.float32)
        em.depth_m = np.empty((em.height, em.width), np.float32)
        em.valid = np.empty((em.height, em.width), bool)
        em._scratch = None
        em._scratch2 = None
        em._averaged = None
        em._changes = None
        em._spare_changes = None
        return em

    @property
    def radiance(self) -> np.ndarray:
        return self.radiance_planes.transpose(1, 2, 0)

    @classmethod
    def from_arrays(cls, radiance: np.ndarray, depth_m: np.ndarray, valid: np.ndarray, origin: np.ndarray) -> "EnvironmentMap":
        """A map holding copies of (H, W, 3) radiance, (H, W) depth_m and (H, W) bool valid."""
        rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype="float")
        h, w = rad.shape[:2]
        depth = check_array(depth_m, "depth_m", shape=(h, w), dtype="float")
        ok = check_array(valid, "valid", shape=(h, w), dtype="bool")
        em = cls(h, w, origin)
        em.radiance_planes[:] = np.moveaxis(rad, -1, 0)
        em.depth_m[:] = depth
        em.valid[:] = ok
        return em

    def record_changes(self) -> None:
        """Start (or restart) logging the pixels :func:`update` writes, for consumers that keep
        derived state in sync incrementally (:class:`rgbd_envmap.sh.IncrementalProjection`). Each
        taken pixel is logged with its flat index, its colour and ``valid`` flag before the write.
        The log costs a few stores per taken pixel; a map that is not recording pays nothing."""
        self._changes = _ChangeLog(_ChangeLog.DEFAULT_CAPACITY if self._changes is None else self._changes.capacity)

    def take_changes(self) -> "MapChanges | None":
        """The pixels written since :meth:`record_changes` or the last call, and a fresh log; None
        when the map is not recording. ``complete`` is False when the log cannot describe what
        happened (it overflowed, or :meth:`mark_modified` was called): rebuild derived state.
        The arrays are views into the map's log buffers (two, used in turn: fresh pages cost page
        faults in the update), valid until the next call."""
        log = self._changes
        if log is None:
            return None
        spare = self._spare_changes
        if log.n > log.capacity:
            spare = _ChangeLog(min(4 * log.n, self.height * self.width))
        elif spare is None or spare.capacity < log.capacity:
            spare = _ChangeLog(log.capacity)
        spare.n, spare.updates, spare.complete = 0, 0, True
        self._changes, self._spare_changes = spare, log
        n = min(log.n, log.capacity)
        idx, old, was_valid = log.idx[:n], log.old[:n], log.was_valid[:n]
        if log.updates > 1:  # a pixel taken by several updates: its state before the first one
            idx, first = np.unique(idx, return_index=True)  # raster order, as one update logs
            old, was_valid = old[first], was_valid[first]
        return MapChanges(idx, old, was_valid, log.complete and log.n <= log.capacity, log.updates)

    def mark_modified(self) -> None:
        """Say that the arrays were written other than by :func:`update` (the change log, if any,
        can no longer describe the map's history, and each pixel's colour counts as one sample again
        for ``UpdateConfig.colour_average``)."""
        if self._changes is not None:
            self._changes.complete = False
        self._averaged = None

    def copy(self) -> "EnvironmentMap":
        return EnvironmentMap.from_arrays(self.radiance, self.depth_m, self.valid, self.origin)

    def __repr__(self) -> str:
        return f"EnvironmentMap({self.height}×{self.width}, origin={self.origin.tolist()}, valid={self.valid.mean():.3f})"


@dataclass(frozen=True, eq=False)
class MapChanges:
    """Pixels written by :func:`update` since the last :meth:`EnvironmentMap.take_changes`, each once
    (the first write when several updates took it), with their state before that write.

    Attributes:
        index: (n,) int64 flat pixel index v·W + u, increasing.
        old_radiance: (n, 3) float32 colour before the write (meaningless where not ``was_valid``).
        was_valid: (n,) bool, the pixel had data before the write.
        complete: False when pixels were written that are not listed (log overflow,
            :meth:`EnvironmentMap.mark_modified`).
        updates: calls of :func:`update` the log covers.
    """

    index: np.ndarray
    old_radiance: np.ndarray
    was_valid: np.ndarray
    complete: bool
    updates: int


class _ChangeLog:
    """Growable buffers the update kernel appends to (``n`` counts past ``capacity`` on overflow)."""

    #: 262,144 entries (5.5 MB a buffer, two in turn): frames of the default session write up to
    #: ~350k pixels; with 65,536 the log overflowed twice before growing, each time forcing a full SH
    #: projection that the incremental path would have done in a third of the time.
    DEFAULT_CAPACITY = 1 << 18

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        self.capacity = int(capacity)
        self.idx = np.empty(self.capacity, np.int64)
        self.old = np.empty((self.capacity, 3), np.float32)
        self.was_valid = np.empty(self.capacity, bool)
        self.n = 0
        self.updates = 0
        self.complete = True


_NO_LOG = _ChangeLog(0)  # passed to the kernel when the map is not recording


# --- the update rules, one function each (numba-compiled, callable from Python on scalars) ----------

@numba.njit(cache=True)
def rule_empty(valid: bool) -> bool:
    """The pixel has no data yet."""
    return not valid


@numba.njit(cache=True)
def rule_closer(new_depth_m: float, stored_depth_m: float) -> bool:
    """The sample is closer to the origin than the stored surface."""
    return new_depth_m < stored_depth_m


@numba.njit(cache=True)
def rule_trusted(device_to_origin_m: float, trusted_radius_m: float) -> bool:
    """The device is inside the trusted sphere around the origin."""
    return device_to_origin_m < trusted_radius_m


@numba.njit(cache=True)
def is_backface(device_along_ray_m: float, new_depth_m: float, stored_depth_m: float) -> bool:
    """The device's projection on the ray lies beyond the stored or the new depth."""
    return device_along_ray_m > stored_depth_m or device_along_ray_m > new_depth_m


@numba.njit(cache=True)
def rule_removal(
    device_along_ray_m: float, device_to_ray_m: float, new_depth_m: float, stored_depth_m: float, removal_radius_m: float
) -> bool:
    """The device is within ``removal_radius_m`` of the ray and the sample is not a backface."""
    return device_to_ray_m < removal_radius_m and not is_backface(device_along_ray_m, new_depth_m, stored_depth_m)


@numba.njit(cache=True, inline="always")
def _freed_limit(z_m, tol_rel, tol_abs_m):  # pragma: no cover - compiled
    """The measured depth beyond which a stored point at camera z-depth ``z_m`` is seen through."""
    return np.float32(z_m * (1.0 + tol_rel) + tol_abs_m)


@numba.njit(cache=True)
def rule_freed(stored_z_m: float, seen_min_depth_m: float, tol_rel: float, tol_abs_m: float) -> bool:
    """Free-space carving (ours, not the paper's): the stored surface point, at z-depth ``stored_z_m``
    in the frame's depth camera, is free space when the smallest measured depth of the pixels around
    its projection (``UpdateConfig.carve_window``; by default the one it falls in) lies beyond it by
    more than ``tol_rel`` · z + ``tol_abs_m`` (the device saw through it). Unmeasured pixels count as
    depth 0, so they never free a point."""
    return seen_min_depth_m > _freed_limit(stored_z_m, tol_rel, tol_abs_m)


@dataclass(frozen=True)
class UpdateConfig:
    """Update-rule parameters (paper defaults)."""

    trusted_radius_m: float = 0.10
    removal_radius_m: float = 0.03
    #: cover each sample's footprint (True) or only the pixel it falls in (the paper's description).
    splat: bool = True
    #: footprint = splat_scale · range / focal, the ToF pixel's size on a surface facing the sensor.
    #: 1.0 measured best with raw depth (1.25 closes a few more oblique gaps but dilates near
    #: foreground silhouettes more: benchmarks/eval_envmap.py); with the denoised depth of
    #: 2026-12-01, 0.95: +0.06 dB for 0.04 % less coverage (docs/em_error_study.md, third round).
    splat_scale: float = 0.95
    #: footprints are clamped to this many rows each side (columns: the same angle, so more pixels
    #: near the poles); guards samples right at the origin.
    max_splat_px: int = 24
    #: free-space carving (rule "freed"): a stored point the frame's measured depth shows to be empty
    #: space takes the frame's sample; needs the frame's depth (:class:`SeenDepth`) passed to
    #: :func:`update`. +1.4 dB WS-PSNR on the default session (docs/em_error_study.md).
    carve: bool = True
    #: the stored point is free space when all measured depths in the ``carve_window`` × ``carve_window``
    #: pixels around its projection exceed its z-depth by more than ``carve_tol_rel`` · z +
    #: ``carve_tol_abs_m`` (5 % + 2 cm was about 5 σ of the raw ToF noise; the 5×5 denoised depth
    #: is within 0.2 %, and 3 % measured better: docs/em_error_study.md, third round).
    carve_tol_rel: float = 0.03
    carve_tol_abs_m: float = 0.02
    #: odd window of measured depths the carving test looks at (1: the pixel the point projects
    #: into). 3 guarded the raw ToF depth's noise; with the 5×5 denoised depth a wider window mostly
    #: keeps stale points wherever any of its pixels measured something nearer: 30.03 → 30.24 dB
    #: WS-PSNR on the default session with 1 (5: 29.71), +0.18 to +1.10 dB on three sessions not
    #: used for the choice, the removed box's pixels replaced as before (docs/em_error_study.md,
    #: fourth round).
    carve_window: int = 1
    #: a pixel taken by a sample of the surface it holds (the sample's distance within the carving
    #: tolerance of the stored one, ``carve_tol_rel`` · d + ``carve_tol_abs_m``: beyond it is free
    #: space, within it the same surface) averages its colour over up to this many such samples (a
    #: running mean, then an exponential one with weight 1 / colour_average for each new sample);
    #: 1: the paper's rule, the colour replaced. Any other takeover replaces the colour and restarts
    #: the average. 4: 27.97 → 28.73 dB WS-PSNR on the default session (docs/envmap.md, item 6); 8,
    #: +0.08 dB more with the later defaults (docs/em_error_study.md, third round). A colour change
    #: of a static surface (a lamp dimming) then takes several samples instead of one (after n
    #: samples of the new colour the old one keeps a weight of (7/8)^n once the mean is full).
    colour_average: int = 8
    #: threads (1 or 2; more are used as 2, and 2 as 1 where numba has one thread): the footprints of
    #: each half of the samples, then the map's row bands in two parts of about equal estimated work,
    #: at once (:func:`_update_kernel_2t`). The map, counts and change log are the same bit for bit.
    threads: int = 2

    def __post_init__(self) -> None:
        check_positive_int(self.threads, "UpdateConfig.threads")
        check_positive_int(self.colour_average, "UpdateConfig.colour_average")
        check_positive_int(self.carve_window, "UpdateConfig.carve_window")
        if self.carve_window % 2 == 0 or self.carve_window > 15:
            raise RangeError(f"UpdateConfig.carve_window: expected an odd size from 1 to 15, got {self.carve_window}")
        if self.colour_average > 255:
            raise RangeError(f"UpdateConfig.colour_average: expected at most 255, got {self.colour_average}")


@dataclass(frozen=True)
class SeenDepth:
    """What the device measured in one frame, for free-space carving: (H, W) z-depth in metres where
    ``known`` (measured, not hole-filled), the depth camera's intrinsics (with distortion) and pose."""

    depth_m: np.ndarray
    known: np.ndarray
    intrinsics: Intrinsics
    T_world_from_cam: RigidTransform


@dataclass(frozen=True)
class UpdateStats:
    """What one update did: samples offered, pixels touched, and pixels taken per rule."""

    samples: int
    touched: int
    taken: int
    taken_empty: int
    taken_closer: int
    taken_trusted: int
    taken_removal: int
    #: taken by free-space carving (stored point seen through by the frame).
    taken_freed: int = 0
    #: pixels carving tested (projected into the frame's depth).
    carve_tested: int = 0
    #: taken pixels whose colour was averaged with the sample's (same surface; ``colour_average``).
    averaged: int = 0


#: atan(x)/x ≈ P(x²) on [0, 1]: a degree-8 Chebyshev fit, max error of atan 1.2e-8 rad (an EM pixel
#: at 2000×1000 is 3.1e-3 rad), so a point within 1.2e-8 rad of a pixel edge may land next door.
#: :func:`_atan2_branchless` writes these coefficients out (tests check it against math.atan2).
_ATAN_POLY = (0.9999999842426203, -0.33333066780599485, 0.1999248357706807, -0.1420257050187139, 0.10636754062743976, -0.07495445371631375, 0.04258760664298073, -0.01600503000542798, 0.0028340641752807177)


@numba.njit(cache=True, inline="always")
def _mx(a, b):  # pragma: no cover - compiled
    """max(a, b) with numba's semantics (b if b > a else a), as a select: in large kernels the
    builtin stayed a call, which kept loops from vectorising."""
    return b if b > a else a  # noqa: FURB136 - the point is not to call max()


@numba.njit(cache=True, inline="always")
def _mn(a, b):  # pragma: no cover - compiled
    """min(a, b) with numba's semantics (b if b < a else a), as a select (see :func:`_mx`)."""
    return b if b < a else a  # noqa: FURB136 - the point is not to call min()


@numba.njit(cache=True, inline="always")
def _span(x, half, limit):  # pragma: no cover - compiled
    """Pixels k whose centre k + 0.5 lies within ``half`` (≥ 0.5) of continuous coordinate x."""
    h = _mn(_mx(half, 0.5), limit)
    return int(math.ceil(x - h - 0.5)), int(math.floor(x + h - 0.5))


#: Samples are processed in blocks of this many: their map coordinates are computed for the whole
#: block in one vectorised loop into small buffers that stay in L1.
_BLOCK = 256


#: An :func:`update` z-buffer entry no sample has reached: +inf's float32 bits, no index.
_EMPTY_Z = 0x7F800000 << 32
#: r0 of a sample :func:`_block_footprints` found unusable (a real r0 is ≥ −max_splat − 1).
_UNUSABLE = -float(1 << 62)


@numba.njit(cache=True, error_model="numpy")
def _block_footprints(m, qx, qy, qz, device, bx, by, bv, bu, br, height, width, row_px, col_px,
                      focal_px, splat, splat_scale, max_splat, r0, r1, c0, c1):  # pragma: no cover - compiled
    """Per sample of the block (world coordinates qx, qy, qz; the rest :func:`_block_coords`
    outputs), the rows r0..r1 and (unwrapped) columns c0..c1 its footprint covers (the pixel it
    falls in without ``splat``), as whole float64 numbers; r0 = :data:`_UNUSABLE` for a non-finite
    point or a distance outside (0, float32 max). One loop without branches or float → int
    conversions (AVX2 has none for int64), so it vectorises. Every sample is divided by its
    distance, so divisions follow IEEE (``error_model="numpy"``: a sample at the origin gives inf
    and is then dropped) instead of raising. Not fastmath, so the spans are exactly the per-sample
    formulas' (:func:`_span`: ceil and floor of the same float64 expressions)."""
    fw, fh = np.float64(width), np.float64(height)
    lim_v, half_w = np.float64(max_splat), np.float64(width // 2)
    d0, d1, d2 = device[0], device[1], device[2]
    if not splat:
        for j in range(m):
            px, py, pz, r = qx[j], qy[j], qz[j], br[j]
            usable = (abs(px) < np.inf) & (abs(py) < np.inf) & (abs(pz) < np.inf) & (r > 0.0) & (np.float32(r) < np.inf)
            row = _mn(np.floor(bv[j]), fh - 1.0)  # v, u ≥ 0: floor is int()'s truncation
            col = np.floor(bu[j])
            col = col - fw if col >= fw else col
            r0[j] = row if usable else _UNUSABLE
            r1[j], c0[j], c1[j] = row, col, col
        return
    for j in range(m):
        px, py, pz, r = qx[j], qy[j], qz[j], br[j]
        # abs(x) < inf: finite, as a compare.
        usable = (abs(px) < np.inf) & (abs(py) < np.inf) & (abs(pz) < np.inf) & (r > 0.0) & (np.float32(r) < np.inf)
        v, u = bv[j], bu[j]
        ex, ey, ez = px - d0, py - d1, pz - d2
        angle = splat_scale * math.sqrt(ex * ex + ey * ey + ez * ez) / (focal_px * r)
        dx, dy = bx[j], by[j]
        s = _mx(math.sqrt(dx * dx + dy * dy) / r, 1e-6)  # sin θ, without a libm call
        h = _mn(_mx(0.5 * angle * row_px, 0.5), lim_v)
        a0, a1 = np.ceil(v - h - 0.5), np.floor(v + h - 0.5)
        h = _mn(_mx(0.5 * angle * col_px / s, 0.5), _mn(lim_v / s, half_w))
        r0[j] = a0 if usable else _UNUSABLE
        r1[j], c0[j], c1[j] = a1, np.ceil(u - h - 0.5), np.floor(u + h - 0.5)


#: The update's z-buffer covers one band of 2**_BAND_SHIFT map rows at a time (see _update_kernel).
_BAND_SHIFT = 4
#: Its touched-tile map has one flag per run of 2**_TILE_SHIFT columns: the rules visit those only
#: (at least 8 columns: the compaction reads the rules' flags 8 at a time, from tile boundaries).
_TILE_SHIFT = 5
#: Sample indices fit in 30 bits of a z-buffer key (:func:`_z_key`).
_INDEX_MAX = (1 << 30) - 1


@numba.njit(cache=True, inline="always")
def _u(i):  # pragma: no cover - compiled
    """An index as uint64: numba then skips the negative-index wraparound (a select per access that
    doubled the cost of the update's pixel loops)."""
    return np.uint64(i)


@numba.njit(cache=True, inline="always")
def _z_key(r, fill_only, i):  # pragma: no cover - compiled
    """The z-buffer key of sample i at float64 distance r: the smallest key covering a pixel is the
    sample a sequential z-test in sample order keeps (a later sample replaces the stored one when
    its float64 distance is below the stored float32 distance g), so the keys can be merged with
    ``min`` in any order.

    Bits 63–32 hold g = float32(r) rounded to nearest (its bits order like the values). Among the
    samples of the smallest g, the sequential test keeps the *last* with r < g (each replaces the
    one before) or, when there is none, the *first* (none replaces it): bit 31 is 0 for r < g and
    bits 30–1 hold 2³⁰ − 1 − i then, else bit 31 is 1 and bits 30–1 hold i. Bit 0 is the sample's
    ``fill_only`` flag (below the index, it never decides)."""
    f = np.float32(r)
    code = ((_INDEX_MAX - i) << 1) if np.float64(f) > r else ((1 << 31) | (i << 1))
    return (np.int64(_f32_bits(f)) << 32) | code | np.int64(fill_only)


@numba.njit(cache=True, inline="always")
def _key_index(q):  # pragma: no cover - compiled
    """The sample index of z-buffer key q (:func:`_z_key`)."""
    e = (q >> 1) & _INDEX_MAX
    return e if (q >> 31) & 1 else _INDEX_MAX - e


@numba.njit(cache=True, inline="always")
def _z_min4(z, p1, p2, p3, p4, key):  # pragma: no cover - compiled
    """z[p] = min(z[p], key) at four entries, all loaded before any is stored (chained tests would
    forward each store to the next load); equal entries load equal keys and store equal minima."""
    q1, q2, q3, q4 = z[p1], z[p2], z[p3], z[p4]
    w1, w2 = _mn(q1, key), _mn(q2, key)
    w3, w4 = _mn(q3, key), _mn(q4, key)
    z[p1] = w1
    z[p2] = w2
    z[p3] = w3
    z[p4] = w4


@numba.njit(cache=True, inline="always")
def _z_run(z, lo, hi, key):  # pragma: no cover - compiled
    """``min`` of the keys z[lo:hi] and ``key``, in place; a select per entry, so the run vectorises."""
    for k in range(lo, hi):
        z[_u(k)] = _mn(z[_u(k)], key)


@numba.njit(cache=True, inline="always")
def _is_free(ux, uy, uz, d, origin, cam, seen):  # pragma: no cover - compiled
    """Rule "freed": the stored point origin + d·(ux, uy, uz) projects into the frame's measured
    depth with all depths of the window around its pixel farther than its z by more than tol_rel·z +
    tol_abs. ``seen``: (H, W) float32, the minimum of the measured depth over each pixel's window
    (0 where any of them is not measured or lies outside the image; :func:`_seen_arrays`). ``cam``:
    T_cam_from_world rows (12), fx, fy, cx, cy, k1, k2, p1, p2, k3, tol_rel, tol_abs."""
    px, py, pz = origin[0] + d * ux, origin[1] + d * uy, origin[2] + d * uz
    z = cam[8] * px + cam[9] * py + cam[10] * pz + cam[11]
    if not z > 0.0:
        return False
    x = cam[0] * px + cam[1] * py + cam[2] * pz + cam[3]
    y = cam[4] * px + cam[5] * py + cam[6] * pz + cam[7]
    xd, yd = brown_distort(x / z, y / z, cam[16], cam[17], cam[18], cam[19], cam[20])
    u = cam[12] * xd + cam[14]
    v = cam[13] * yd + cam[15]
    h, w = seen.shape
    if not (u >= -0.5 and v >= -0.5 and u < w - 0.5 and v < h - 0.5):  # NaN fails
        return False
    return rule_freed(z, seen[int(v + 0.5), int(u + 0.5)], cam[21], cam[22])


@numba.njit(cache=True, error_model="numpy")
def _carve_tests(n, cols, flags, st, ct, col_sc, df, base, origin, cam, seen, buf):  # pragma: no cover - compiled
    """:func:`_is_free` for the pixels (row, cols[k]), k < n, of one row (sin θ ``st``, cos θ ``ct``,
    flat index of its first pixel ``base``): flags[cols[k]] = 3 where free, else 0. The same
    arithmetic as :func:`_is_free`, in three loops: the pixels' directions and depths gathered into
    ``buf`` (4, ≥ n), the projections (selects only, so the loop vectorises; a point behind the
    camera is divided by 1 instead of z and then refused), the lookups."""
    ux, uy, dd, thr = buf[0], buf[1], buf[2], buf[3]
    for k in range(n):
        c = cols[_u(k)]
        ux[_u(k)] = st * col_sc[c, 1]
        uy[_u(k)] = st * col_sc[c, 0]
        dd[_u(k)] = df[_u(base + c)]
    h, w = seen.shape
    fh, fw = h - 0.5, w - 0.5
    ox, oy, oz = origin[0], origin[1], origin[2]
    k1, k2, p1, p2, k3 = cam[16], cam[17], cam[18], cam[19], cam[20]
    for k in range(n):
        d = np.float32(dd[_u(k)])
        px, py, pz = ox + d * np.float32(ux[_u(k)]), oy + d * np.float32(uy[_u(k)]), oz + d * ct
        z = cam[8] * px + cam[9] * py + cam[10] * pz + cam[11]
        x = cam[0] * px + cam[1] * py + cam[2] * pz + cam[3]
        y = cam[4] * px + cam[5] * py + cam[6] * pz + cam[7]
        zs = z if z > 0.0 else 1.0
        xd, yd = brown_distort(x / zs, y / zs, k1, k2, p1, p2, k3)
        u = cam[12] * xd + cam[14]
        v = cam[13] * yd + cam[15]
        inside = (z > 0.0) & (u >= -0.5) & (v >= -0.5) & (u < fw) & (v < fh)  # NaN fails
        ux[_u(k)] = np.floor(u + 0.5) if inside else -1.0  # u + 0.5 ≥ 0: floor is int()'s truncation
        uy[_u(k)] = np.floor(v + 0.5) if inside else 0.0
        thr[_u(k)] = _freed_limit(z, cam[21], cam[22])
    for k in range(n):
        iu = ux[_u(k)]
        free = iu >= 0.0 and seen[int(uy[_u(k)]), int(iu)] > np.float32(thr[_u(k)])
        flags[_u(cols[_u(k)])] = 3 if free else 0


@numba.njit(cache=True)
def _footprint_records(points, colours, fill_only, origin, device, height, width, focal_px, splat, splat_scale,
                       max_splat, i0, i1, rec, rec_key, per_band, work):  # pragma: no cover - compiled
    """:func:`_update_kernel`'s step 1 for samples ``i0`` to ``i1`` − 1: each usable sample's
    footprint (rows, first column, columns) and key into ``rec`` / ``rec_key`` from index ``i0`` on,
    and the count of footprints reaching band b added to ``per_band[b + 1]``. With ``work`` (one
    entry per band; empty: none), 24 + the footprint's pixels are added to its first band's entry,
    an estimate of the band's share of steps 3 and 4. Returns how many records were written."""
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    qx, qy, qz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    fr0, fr1, fc0, fc1 = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    # 1. Footprints: rows ra..rb, columns a0 (wrapped) and how many, and the key, per usable sample.
    n_rec = i0
    # Band counts: consecutive samples mostly fall in the same band, so the counts of the current
    # band b_cur and of the next (footprints reaching into it) are kept in locals and added when
    # the band changes. A loop over the one or two bands each footprint reaches, exiting after one
    # or two unpredictably, cost more than its counting (with the listing below: 135 → 85 µs a
    # frame of the recorded session; spreading the counters over lanes alone gained 15).
    b_cur, n_cur, n_next = 0, 0, 0
    for start in range(i0, i1, _BLOCK):
        m = _mn(_BLOCK, i1 - start)
        _block_coords(points, start, m, origin[0], origin[1], origin[2], row_px, col_px, bx, by, bz, bv, bu, br)
        for j in range(m):  # the points again, block-local: read from (N, 3) the loop stayed scalar
            qx[j], qy[j], qz[j] = points[start + j, 0], points[start + j, 1], points[start + j, 2]
        _block_footprints(m, qx, qy, qz, device, bx, by, bv, bu, br, height, width, row_px, col_px,
                          focal_px, splat, splat_scale, max_splat, fr0, fr1, fc0, fc1)
        for j in range(m):
            i = start + j
            if fr0[j] == _UNUSABLE or not (np.isfinite(colours[_u(i), 0]) and np.isfinite(colours[_u(i), 1])
                                           and np.isfinite(colours[_u(i), 2])):
                continue
            r0, r1, c0, c1 = int(fr0[j]), int(fr1[j]), int(fc0[j]), int(fc1[j])
            ra, rb = _mx(r0, 0), _mn(r1, height - 1)
            if ra > rb:
                continue
            rec[_u(n_rec), 0], rec[_u(n_rec), 1] = ra, rb
            # c0 ≥ −width (a column half-width is at most width / 2) and ≤ width: one wrap. A span
            # wider than the map covers each column once.
            rec[_u(n_rec), 2] = c0 + width if c0 < 0 else (c0 - width if c0 >= width else c0)
            rec[_u(n_rec), 3] = _mn(c1 - c0 + 1, width)
            rec_key[_u(n_rec)] = _z_key(br[j], fill_only[_u(i)], i)
            n_rec += 1
            b0, b1 = ra >> _BAND_SHIFT, rb >> _BAND_SHIFT
            if work.shape[0] > 0:
                work[_u(b0)] += 24 + (rb - ra + 1) * rec[_u(n_rec - 1), 3]
            if b0 != b_cur:
                per_band[_u(b_cur + 1)] += n_cur
                per_band[_u(b_cur + 2)] += n_next
                b_cur, n_cur, n_next = b0, 0, 0
            n_cur += 1
            n_next += b1 > b0
            for b in range(b0 + 2, b1 + 1):  # footprints reaching a third band (rare)
                per_band[_u(b + 1)] += 1
    per_band[_u(b_cur + 1)] += n_cur
    per_band[_u(b_cur + 2)] += n_next
    return n_rec - i0


@numba.njit(cache=True)
def _list_footprints(rec, n_bands, k0, n0, k1, n1, per_band, listed):  # pragma: no cover - compiled
    """:func:`_update_kernel`'s step 2: the records ``k0`` to ``k0 + n0`` − 1, then ``k1`` to
    ``k1 + n1`` − 1, listed per band they reach (counting sort, in that order), from the counts of
    :func:`_footprint_records`. Returns (per_band, listed): the lists of band b are
    ``listed[per_band[b]:per_band[b + 1]]`` (``listed`` is a new array when the given one is too
    short)."""
    for b in range(n_bands):
        per_band[b + 1] += per_band[b]
    if per_band[n_bands] >= listed.shape[0]:  # footprints over about two bands on average
        listed = np.empty(per_band[n_bands] + 1, np.int32)
    # The same way: the fill positions of the current band and the next in locals (the others in
    # ``fill``); a footprint within one band stores its second entry into a spare slot past the
    # last, so the lists are those of the loop over bands, in sample order.
    fill = per_band[:n_bands + 1].copy()
    spare = per_band[n_bands]
    b_cur, f_cur, f_next = 0, fill[0], fill[1]
    for part in range(2):
        lo, hi = (k0, k0 + n0) if part == 0 else (k1, k1 + n1)
        for k in range(lo, hi):
            b0, b1 = rec[_u(k), 0] >> _BAND_SHIFT, rec[_u(k), 1] >> _BAND_SHIFT
            if b0 != b_cur:
                fill[_u(b_cur)], fill[_u(b_cur + 1)] = f_cur, f_next
                b_cur, f_cur, f_next = b0, fill[_u(b0)], fill[_u(b0 + 1)]
            listed[_u(f_cur)] = k
            f_cur += 1
            listed[_u(f_next if b1 > b0 else spare)] = k
            f_next += b1 > b0
            for b in range(b0 + 2, b1 + 1):
                listed[_u(fill[_u(b)])] = k
                fill[_u(b)] += 1
    return per_band, listed


@numba.njit(cache=True)
def _update_bands(
    band_lo, band_hi, per_band, listed, rec, rec_key, colours, origin, device, height, width, planes, depth, valid,
    trusted_r, removal_r, zband, tiles, row_sc, col_sc, log_idx, log_old, log_valid, log_n, carve, cam, seen,
    averaged, avg,
):  # pragma: no cover - compiled
    """:func:`_update_kernel`'s steps 3 and 4 for bands ``band_lo`` to ``band_hi`` − 1: the bands'
    footprints z-buffered into ``zband`` (``tiles`` flag the touched 32-column tiles), then the rules
    and writes row by row, appending to the log from ``log_n`` on. Bands touch disjoint rows, so two
    calls on disjoint band ranges, each with its own ``zband``, ``tiles`` and log, may run at once.
    ``averaged`` (H·W,) uint8 and ``avg`` = (colour_average, same-surface tolerance relative, absolute):
    see :func:`_update_kernel`.
    Returns (pixels touched, taken, taken that had data, of those closer, freed, carving tests, averaged,
    log length)."""
    band_rows = 1 << _BAND_SHIFT
    n_tiles = (width + (1 << _TILE_SHIFT) - 1) >> _TILE_SHIFT
    hw = height * width
    pf, df, vf = planes.reshape(3, hw), depth.reshape(hw), valid.reshape(hw)
    # The removal rule needs the device within removal_r of the pixel's ray, at an angle α from the
    # device's direction with dev_r·sin α < removal_r and α < 90°, so α < asin(removal_r / dev_r);
    # a row whose polar angle differs from the device's by more than that (plus two rows, far above
    # rounding) has no such pixel, and its pixels skip the ray geometry (the vectorised rules
    # below). Inside the trusted sphere the trusted rule takes every such pixel first.
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    dev_r = math.sqrt(ox * ox + oy * oy + oz * oz)
    trusted = rule_trusted(dev_r, trusted_r)
    all_rows = not trusted and not removal_r < dev_r
    theta_dev = math.acos(_mx(-1.0, _mn(1.0, oz / dev_r))) if dev_r > 0.0 else 0.0
    cap = math.asin(_mx(removal_r, 0.0) / dev_r) + 2.0 * math.pi / height if removal_r < dev_r else math.pi
    n_touched, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg = 0, 0, 0, 0, 0, 0, 0
    n_average, same_rel, same_abs = int(avg[0]), avg[1], avg[2]
    avg_top = np.uint8(_mx(n_average - 2, 0))  # the count after which a new sample weighs 1 / n_average
    inv = np.empty(256, np.float32)  # a new sample's weight after k samples: 1 / (k + 2), looked up
    for k in range(256):
        inv[k] = np.float32(1.0) / (np.float32(k) + np.float32(2.0))
    take_p = np.empty(width + 8, np.int64)  # + 8: the compaction stores past the last taken pixel
    freed = np.zeros(width + 8, np.bool_)
    # Carving candidates: refused pixels whose sample lies beyond the stored point by the carving
    # tolerance (distances from the origin); the rest are the same surface or nearer, and the
    # projection into the frame (the cost: ~60 ns a pixel) is skipped. Without carving: none.
    carve_scale = 1.0 + cam[21] if carve else 1.0
    carve_abs = cam[22] if carve else np.inf
    # Padded to whole 8-byte words (the padding stays 0): the compaction and the candidate listing
    # skip words of 8 pixels with nothing to do (186 → 93 µs and about −20 µs a frame).
    flags = np.zeros(((width + 7) >> 3) << 3, np.uint8)
    flag_words = flags.view(np.uint64)
    cand_c, cand_u = np.empty(width + 8, np.int64), np.empty((4, width))
    run_lo, run_hi, run_flagged = np.empty(n_tiles, np.int64), np.empty(n_tiles, np.int64), np.empty(n_tiles, np.int64)
    for band in range(band_lo, band_hi):
        if per_band[band] == per_band[band + 1]:
            continue
        row0 = band << _BAND_SHIFT
        row1 = _mn(row0 + band_rows, height) - 1
        # 3. The band's z-buffer: keys merged with min, tiles flagged (plain stores).
        for e in range(per_band[band], per_band[band + 1]):
            k = listed[e]
            ra, rb, a0, n_cols = rec[k, 0], rec[k, 1], rec[k, 2], rec[k, 3]
            key = rec_key[k]
            lo_r, hi_r = _mx(ra, row0) - row0, _mn(rb, row1) - row0
            if n_cols <= 2 and rb - ra <= 1:
                # At most 2×2 pixels (nearly every sample far from the origin): four branch-free
                # tests, the entries loaded before any is stored (most footprints are one pixel
                # wide or high; tests one after the other chained store-to-load forwards through
                # one entry). Equal pixels load equal keys and store equal minima.
                cb = a0 + n_cols - 1
                cb = 0 if cb == width else cb
                pa, pb = lo_r * width, hi_r * width
                _z_min4(zband, _u(pa + a0), _u(pa + cb), _u(pb + a0), _u(pb + cb), key)
                ta, tb = lo_r * n_tiles, hi_r * n_tiles
                tiles[_u(ta + (a0 >> _TILE_SHIFT))] = 1
                tiles[_u(ta + (cb >> _TILE_SHIFT))] = 1
                tiles[_u(tb + (a0 >> _TILE_SHIFT))] = 1
                tiles[_u(tb + (cb >> _TILE_SHIFT))] = 1
                continue
            if n_cols <= 8 and a0 + n_cols <= width:
                # 3 to 8 columns that do not wrap: per row one masked 8-lane min (_min_run8).
                y0, y1 = a0 >> _TILE_SHIFT, (a0 + n_cols - 1) >> _TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    _min_run8(zband, base + a0, n_cols, key)
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                continue
            if n_cols <= 4:
                # At most 4 columns (most of the rest): per row four branch-free tests at columns
                # a0 + min(k, n_cols - 1), wrapped; duplicates load and store equal minima.
                x1, x2, x3 = a0 + _mn(1, n_cols - 1), a0 + _mn(2, n_cols - 1), a0 + n_cols - 1
                x1 = x1 - width if x1 >= width else x1
                x2 = x2 - width if x2 >= width else x2
                x3 = x3 - width if x3 >= width else x3
                # The run's tiles: those of its first and last column and, where it wraps, of the
                # map's last column (at most 32 columns: no tile between them).
                y0, y1, y2 = a0 >> _TILE_SHIFT, _mn(a0 + n_cols - 1, width - 1) >> _TILE_SHIFT, x3 >> _TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    _z_min4(zband, _u(base + a0), _u(base + x1), _u(base + x2), _u(base + x3), key)
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                    tiles[_u(tbase + y2)] = 1
                continue
            if n_cols <= 8:
                # 5 to 8 columns: the same with eight tests per row.
                x1, x2, x3 = a0 + 1, a0 + 2, a0 + 3
                x4, x5, x6, x7 = a0 + 4, a0 + _mn(5, n_cols - 1), a0 + _mn(6, n_cols - 1), a0 + n_cols - 1
                x1 = x1 - width if x1 >= width else x1
                x2 = x2 - width if x2 >= width else x2
                x3 = x3 - width if x3 >= width else x3
                x4 = x4 - width if x4 >= width else x4
                x5 = x5 - width if x5 >= width else x5
                x6 = x6 - width if x6 >= width else x6
                x7 = x7 - width if x7 >= width else x7
                y0, y1, y2 = a0 >> _TILE_SHIFT, _mn(a0 + n_cols - 1, width - 1) >> _TILE_SHIFT, x7 >> _TILE_SHIFT
                for rr in range(lo_r, hi_r + 1):
                    base, tbase = rr * width, rr * n_tiles
                    p0, p1, p2, p3 = _u(base + a0), _u(base + x1), _u(base + x2), _u(base + x3)
                    p4, p5, p6, p7 = _u(base + x4), _u(base + x5), _u(base + x6), _u(base + x7)
                    q0, q1, q2, q3 = zband[p0], zband[p1], zband[p2], zband[p3]
                    q4, q5, q6, q7 = zband[p4], zband[p5], zband[p6], zband[p7]
                    w0, w1, w2, w3 = _mn(q0, key), _mn(q1, key), _mn(q2, key), _mn(q3, key)
                    w4, w5, w6, w7 = _mn(q4, key), _mn(q5, key), _mn(q6, key), _mn(q7, key)
                    zband[p0] = w0
                    zband[p1] = w1
                    zband[p2] = w2
                    zband[p3] = w3
                    zband[p4] = w4
                    zband[p5] = w5
                    zband[p6] = w6
                    zband[p7] = w7
                    tiles[_u(tbase + y0)] = 1
                    tiles[_u(tbase + y1)] = 1
                    tiles[_u(tbase + y2)] = 1
                continue
            # Larger footprints: per row at most two runs (the seam). The first and last tile of
            # a run are flagged by plain stores, the ones between (wide runs only) by a loop.
            a1 = _mn(a0 + n_cols, width)
            b1 = a0 + n_cols - width
            t0, t1 = a0 >> _TILE_SHIFT, (a1 - 1) >> _TILE_SHIFT
            s1 = (b1 - 1) >> _TILE_SHIFT
            for rr in range(lo_r, hi_r + 1):
                base, tbase = rr * width, rr * n_tiles
                _z_run(zband, base + a0, base + a1, key)
                tiles[_u(tbase + t0)] = 1
                tiles[_u(tbase + t1)] = 1
                for t in range(t0 + 1, t1):
                    tiles[_u(tbase + t)] = 1
                if b1 > 0:
                    _z_run(zband, base, base + b1, key)
                    for t in range(s1 + 1):
                        tiles[_u(tbase + t)] = 1
        # 4. The rules for the band's rows, per touched pixel against the pixel's own ray.
        for rr in range(row0, row1 + 1):
            zb, tb = (rr - row0) * width, (rr - row0) * n_tiles
            base = rr * width
            n_runs = 0
            t = 0
            while t < n_tiles:  # the row's runs of flagged tiles, the flags cleared on the way
                if tiles[_u(tb + t)] == 0:
                    t += 1
                    continue
                t0 = t
                while t < n_tiles and tiles[_u(tb + t)] != 0:
                    tiles[_u(tb + t)] = 0
                    t += 1
                run_lo[n_runs], run_hi[n_runs] = t0 << _TILE_SHIFT, _mn(t << _TILE_SHIFT, width)
                n_runs += 1
            if n_runs == 0:
                continue
            # The taken columns of the row, in order, into take_p[:nt].
            nt = 0
            st, ct = row_sc[rr, 0], row_sc[rr, 1]
            if not (all_rows or (not trusted and abs(math.pi * (rr + 0.5) / height - theta_dev) <= cap)):
                n_cand = 0
                for j in range(n_runs):
                    lo, hi = run_lo[j], run_hi[j]
                    # Without the removal rule: selects only, so the loop vectorises; the taken
                    # pixels are then compacted branch-free (taking and refusing mix unpredictably).
                    n_flagged = 0
                    for c in range(lo, hi):
                        q = zband[_u(zb + c)]
                        hit = q != _EMPTY_Z
                        closer = (_bits_f32(np.int32(q >> 32)) < df[_u(base + c)]) & ((q & 1) == 0)
                        n_touched += hit
                        take = hit & ((not vf[_u(base + c)]) | closer | trusted)
                        # 2 taken; 1 refused but a carving candidate (see below); 0 otherwise.
                        far = _bits_f32(np.int32(q >> 32)) > df[_u(base + c)] * carve_scale + carve_abs
                        cand = hit & far & (not take)
                        n_cand += cand
                        n_flagged += take | cand
                        flags[_u(c)] = take + take + cand
                    run_flagged[j] = n_flagged
                if n_cand > 0:  # the row's candidates, listed, then tested together: 3 freed, else 0
                    n_cand = 0
                    for j in range(n_runs):
                        for w in range(run_lo[j] >> 3, (run_hi[j] + 7) >> 3):
                            if flag_words[_u(w)] & 0x0101010101010101 == 0:  # no flag 1 among the 8
                                continue
                            for c in range(w << 3, (w << 3) + 8):
                                cand_c[_u(n_cand)] = c  # cand_c has spare slots past the last candidate
                                n_cand += flags[_u(c)] == 1
                    _carve_tests(np.int64(n_cand), cand_c, flags, st, ct, col_sc, df, base, origin, cam, seen, cand_u)
                    n_tested += n_cand
                for j in range(n_runs):
                    if run_flagged[j] == 0:  # nothing taken or tested in the run (often)
                        continue
                    # Runs start at tile boundaries (2**_TILE_SHIFT ≥ 8 columns) and end at one or
                    # at the map's width, so their words hold their own flags or the padding only.
                    for w in range(run_lo[j] >> 3, (run_hi[j] + 7) >> 3):
                        if flag_words[_u(w)] == 0:  # nothing taken or tested in these 8 pixels
                            continue
                        for c in range(w << 3, (w << 3) + 8):
                            f = flags[_u(c)]
                            take_p[_u(nt)] = c
                            freed[_u(nt)] = f == 3
                            nt += f >> 1
            else:
                for j in range(n_runs):
                    for c in range(run_lo[j], run_hi[j]):
                        q = zband[_u(zb + c)]
                        if q == _EMPTY_Z:
                            continue
                        n_touched += 1
                        r = _bits_f32(np.int32(q >> 32))
                        p = _u(base + c)
                        freed[_u(nt)] = False
                        if rule_empty(vf[p]) or (rule_closer(r, df[p]) and (q & 1) == 0) or trusted:
                            take = True
                        else:
                            ux, uy, uz = st * col_sc[c, 1], st * col_sc[c, 0], ct
                            along = ox * ux + oy * uy + oz * uz
                            if along > 0.0:
                                px, py, pz = ox - along * ux, oy - along * uy, oz - along * uz
                                to_ray = math.sqrt(px * px + py * py + pz * pz)
                            else:
                                to_ray = dev_r  # the ray starts at the origin: the closest point is the origin
                            take = rule_removal(along, to_ray, r, df[p], removal_r)
                            if not take and carve and r > df[p] * carve_scale + carve_abs:
                                n_tested += 1
                                take = _is_free(ux, uy, uz, df[p], origin, cam, seen)
                                freed[_u(nt)] = take
                        if take:
                            take_p[_u(nt)] = c
                            nt += 1
            # The writes, in raster order (so the change log is too); the rule that took a pixel
            # is the first that holds, in the documented order. The rules' counts follow from four
            # sums (pixels taken, those that had data, those of them closer, the freed ones): a
            # freed pixel had data and was neither closer nor trusted (carving tests only pixels
            # the other rules refuse), and "trusted" holds for all pixels or none (50 µs a frame
            # less than five counts per pixel).
            n_taken += nt
            for k in range(nt):
                c = take_p[k]
                p = _u(base + c)
                q = zband[_u(zb + c)]
                i = _u(_key_index(q))
                r = _bits_f32(np.int32(q >> 32))
                ok, d = vf[p], df[p]
                closer = (r < d) & ((q & 1) == 0)
                free = carve and freed[k]
                # The same surface (a freed pixel's sample lies beyond the tolerance): the colour
                # averages; anything else replaces it and restarts the count.
                same = ok & (abs(r - d) <= d * same_rel + same_abs) & (n_average > 1)
                pa = p if n_average > 1 else _u(0)  # one dummy entry when not averaging
                a = averaged[pa]
                weight = inv[a]
                n_ok += ok
                n_closer += ok & closer
                n_freed += free
                n_avg += same
                if log_n < log_idx.shape[0]:
                    log_idx[_u(log_n)] = p
                    for ch in range(3):
                        log_old[_u(log_n), ch] = pf[ch, p]
                    log_valid[_u(log_n)] = ok
                if log_idx.shape[0] > 0:
                    log_n += 1
                for ch in range(3):
                    old, new = pf[ch, p], colours[i, ch]
                    pf[ch, p] = old + (new - old) * weight if same else new
                averaged[pa] = _mn(a + np.uint8(1), avg_top) if same else np.uint8(0)
                df[p] = r if (not ok) | free else 0.5 * (d + r)
                vf[p] = True
            for j in range(n_runs):  # the band's z-buffer is empty again where this row was touched
                for c in range(run_lo[j], run_hi[j]):
                    zband[_u(zb + c)] = _EMPTY_Z
    return n_touched, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg, log_n


@numba.njit(cache=True, inline="always")
def _rule_counts(origin, device, trusted_r, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg):  # pragma: no cover - compiled
    """The update's counts (taken, empty, closer, trusted, removal, freed, carving tests, averaged)
    from four sums: a freed pixel had data and was neither closer nor trusted (carving tests only
    pixels the other rules refuse), and "trusted" holds for all pixels or none."""
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    trusted = rule_trusted(math.sqrt(ox * ox + oy * oy + oz * oz), trusted_r)
    n_trusted = n_ok - n_closer if trusted else 0
    n_removal = 0 if trusted else n_ok - n_closer - n_freed
    return np.array([n_taken, n_taken - n_ok, n_closer, n_trusted, n_removal, n_freed, n_tested, n_avg], np.int64)


@numba.njit(cache=True)
def _update_kernel(
    points, colours, fill_only, origin, device, height, width, focal_px, splat, splat_scale, max_splat,
    planes, depth, valid, trusted_r, removal_r, zband, tiles, rec, rec_key, listed, row_sc, col_sc,
    log_idx, log_old, log_valid, log_n, carve, cam, seen, averaged, avg,
):  # pragma: no cover - compiled
    """:func:`update`: the frame's samples z-buffered (the closest wins, the first on equal float32
    distances; :func:`_z_key`), then the rules per touched pixel, in raster order. Every taken pixel
    is appended to the change log (``log_*``, entries from ``log_n`` on, while they fit; a
    zero-length log records nothing).

    Band by band: the samples' footprints are recorded and listed per band of 2**_BAND_SHIFT rows
    they reach, then for each band they are z-buffered into ``zband`` (one band of int64 keys,
    :data:`_EMPTY_Z` between updates: it stays in cache, where a whole-map z-buffer cost a memory
    round trip per touched pixel twice) and the band's rows go through the rules at once.
    With ``carve``, a touched pixel no other rule takes, whose sample lies beyond the stored depth by
    more than the carving tolerance, is tested with :func:`_is_free` (``cam``, ``seen``; a row's
    candidates at once by :func:`_carve_tests`, the same arithmetic) and taken if free ("freed":
    the depth is replaced, not averaged).
    A taken pixel that had data, whose sample lies within ``avg[1]`` · d + ``avg[2]`` of its stored
    distance d (the same surface), averages its colour: the new sample weighs 1 / (k + 2) with k =
    ``averaged[p]`` (flat (H·W,) uint8, then min(k + 1, ``avg[0]`` − 2)), so up to ``avg[0]``
    samples count equally and later ones weigh 1 / ``avg[0]``; any other taken pixel takes the
    sample's colour and k = 0. ``avg[0]`` = 1: the colour is always replaced (the paper).
    Returns (pixels touched, counts: taken, empty, closer, trusted, removal, freed, carving tests,
    averaged; new log length)."""
    n_bands = (height + (1 << _BAND_SHIFT) - 1) >> _BAND_SHIFT
    per_band = np.zeros(n_bands + 2, np.int64)
    n_rec = _footprint_records(points, colours, fill_only, origin, device, height, width, focal_px, splat,
                               splat_scale, max_splat, 0, points.shape[0], rec, rec_key, per_band, per_band[:0])
    per_band, listed = _list_footprints(rec, n_bands, 0, n_rec, 0, 0, per_band, listed)
    n_touched, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg, log_n = _update_bands(
        0, n_bands, per_band, listed, rec, rec_key, colours, origin, device, height, width, planes, depth, valid,
        trusted_r, removal_r, zband, tiles, row_sc, col_sc, log_idx, log_old, log_valid, log_n, carve, cam, seen,
        averaged, avg)
    return n_touched, _rule_counts(origin, device, trusted_r, n_taken, n_ok, n_closer, n_freed, n_tested, n_avg), log_n


@numba.njit(cache=True, parallel=_PRANGE_ONLY)
def _update_kernel_2t(
    points, colours, fill_only, origin, device, height, width, focal_px, splat, splat_scale, max_splat,
    planes, depth, valid, trusted_r, removal_r, zband, tiles, rec, rec_key, listed, row_sc, col_sc,
    log_idx, log_old, log_valid, log_n, carve, cam, seen, averaged, avg, zband2, tiles2, log2_idx, log2_old,
    log2_valid,
):  # pragma: no cover - compiled
    """:func:`_update_kernel` on two threads, with the same result (the map, counts and change log
    bit for bit): the footprints of each half of the samples are recorded at the same time and
    listed, then the bands are split where half the estimated work (footprints and their pixels,
    :func:`_footprint_records`) lies before the split, the upper part updated with ``zband`` / ``tiles`` and
    logged into ``log_*`` as there, the lower part at the same time with ``zband2`` / ``tiles2``
    into ``log2_*`` (as long as ``log_idx``, or empty when not logging), whose entries are then
    appended, so the log stays in raster order."""
    n_bands = (height + (1 << _BAND_SHIFT) - 1) >> _BAND_SHIFT
    n = points.shape[0]
    mid = n >> 1
    counts2 = np.zeros((2, n_bands + 2), np.int64)
    work2 = np.zeros((2, n_bands), np.int64)
    n_recs = np.zeros(2, np.int64)
    for t in numba.prange(2):  # the footprints of each half of the samples
        n_recs[t] = _footprint_records(points, colours, fill_only, origin, device, height, width, focal_px, splat,
                                       splat_scale, max_splat, 0 if t == 0 else mid, mid if t == 0 else n, rec,
                                       rec_key, counts2[t], work2[t])
    per_band = counts2[0] + counts2[1]
    per_band, listed = _list_footprints(rec, n_bands, 0, n_recs[0], mid, n_recs[1], per_band, listed)
    # The split: where the estimated work before it first reaches half of all.
    work = work2[0] + work2[1]
    half = work.sum() >> 1
    split, done = 0, 0
    while split < n_bands and done + work[split] <= half:
        done += work[split]
        split += 1
    res = np.zeros((2, 8), np.int64)
    for t in numba.prange(2):
        # One call site (a call per branch compiled _update_bands twice, for its literal arguments).
        lo, hi, n_log = (0, split, log_n) if t == 0 else (split, n_bands, 0)
        a, b, c, d, e, f, g, h = _update_bands(
            lo, hi, per_band, listed, rec, rec_key, colours, origin, device, height, width, planes, depth, valid,
            trusted_r, removal_r, zband if t == 0 else zband2, tiles if t == 0 else tiles2, row_sc, col_sc,
            log_idx if t == 0 else log2_idx, log_old if t == 0 else log2_old, log_valid if t == 0 else log2_valid,
            n_log, carve, cam, seen, averaged, avg)
        res[t, 0], res[t, 1], res[t, 2], res[t, 3], res[t, 4], res[t, 5], res[t, 6], res[t, 7] = a, b, c, d, e, f, g, h
    # The lower part's log after the upper part's (while it fits: the log's length counts on past
    # its capacity, as the single-threaded kernel's does).
    n0, n1 = res[0, 7], res[1, 7]
    cap = log_idx.shape[0]
    for j in range(_mn(n1, _mn(log2_idx.shape[0], cap - n0))):
        log_idx[n0 + j] = log2_idx[j]
        log_old[n0 + j, 0], log_old[n0 + j, 1], log_old[n0 + j, 2] = log2_old[j, 0], log2_old[j, 1], log2_old[j, 2]
        log_valid[n0 + j] = log2_valid[j]
    log_n = n0 + n1
    t = res[0] + res[1]
    return t[0], _rule_counts(origin, device, trusted_r, t[1], t[2], t[3], t[4], t[5], t[6]), log_n


@lru_cache(maxsize=8)
def _trig_tables(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, 2) sin θ, cos θ of each row centre and (W, 2) sin φ, cos φ of each column centre, float32."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    rows = np.stack([np.sin(theta), np.cos(theta)], -1).astype(np.float32)
    cols = np.stack([np.sin(phi), np.cos(phi)], -1).astype(np.float32)
    return rows, cols


@lru_cache(maxsize=8)
def _trig_columns(height: int, width: int) -> tuple[np.ndarray, ...]:
    """Contiguous float32 sin θ, cos θ of the rows and sin φ, cos φ of the columns."""
    rows, cols = _trig_tables(height, width)
    return tuple(np.ascontiguousarray(a) for a in (rows[:, 0], rows[:, 1], cols[:, 0], cols[:, 1]))


@lru_cache(maxsize=8)
def _col_limits(height: int, width: int, max_splat: int) -> np.ndarray:
    """(H,) float64 largest half-width in columns of a footprint landing in each row: ``max_splat``
    rows' angle at that latitude (1/sin θ more columns), at most half the map."""
    rows, _ = _trig_tables(height, width)
    return np.minimum(max_splat / np.maximum(rows[:, 0].astype(np.float64), 1e-6), width // 2)


def _threads(requested: int) -> int:
    """Threads a kernel may use: ``requested``, at most numba's thread count."""
    return min(int(requested), numba.get_num_threads())


def update(
    em: EnvironmentMap,
    points_world: np.ndarray,
    colours: np.ndarray,
    device_position: np.ndarray,
    focal_px: float,
    config: UpdateConfig = UpdateConfig(),
    fill_only: np.ndarray | None = None,
    seen: SeenDepth | None = None,
) -> UpdateStats:
    """Project (N, 3) world points with (N, 3) reference-space linear colours into ``em`` in place.

    ``device_position`` (3,) is the sensor's world position at capture; ``focal_px`` its focal length
    in pixels (sets the footprint). ``fill_only`` (N,) bool marks samples the "closer" rule does not
    apply to (they still fill empty pixels and obey the trusted-sphere and removal rules; see
    :class:`rgbd_envmap.capture.CaptureConfig.edge_margin_px`). ``seen``: the frame's measured depth,
    for free-space carving (``config.carve``; without it no pixel is freed). Returns what the update did.
    The first update allocates the map's scratch: a z-buffer of 16 map rows (256 KB at 2000×1000)
    and per-sample buffers (about 40 bytes a sample), grown to the largest frame.

    Raises:
        RangeError: ``focal_px`` not positive and finite while splatting.
        InvalidInputError: more than 2³⁰ points.
    """
    pts = check_array(points_world, "points_world", shape=("N", 3), dtype="float").astype(np.float64, copy=False)
    col = check_array(colours, "colours", shape=(pts.shape[0], 3), dtype="float").astype(np.float32, copy=False)
    dev = check_array(device_position, "device_position", shape=(3,), dtype="float", finite=True).astype(np.float64)
    if config.splat and not 0.0 < float(focal_px) < math.inf:
        raise RangeError(f"focal_px: expected a positive finite focal length in pixels, got {focal_px}")
    # Non-finite points or colours are skipped inside the kernel (a numpy pre-pass cost 1.5 ms).
    if len(pts) > _INDEX_MAX + 1:
        raise InvalidInputError(f"points_world: expected at most {_INDEX_MAX + 1} points, got {len(pts)}")
    zband, tiles, rec, rec_key, listed = em._update_scratch(len(pts))
    pts = np.ascontiguousarray(pts)
    flags = np.zeros(len(pts), bool) if fill_only is None else check_array(fill_only, "fill_only", shape=(len(pts),), dtype="bool")
    log = _NO_LOG if em._changes is None else em._changes
    carve = bool(config.carve) and seen is not None
    cam, seen_depth = _seen_arrays(seen, config) if carve else (_NO_CAM, _NO_SEEN)
    args = (
        pts, np.ascontiguousarray(col), np.ascontiguousarray(flags), em.origin, dev, em.height, em.width,
        float(focal_px), bool(config.splat), float(config.splat_scale), int(config.max_splat_px),
        em.radiance_planes, em.depth_m, em.valid,
        float(config.trusted_radius_m), float(config.removal_radius_m), zband, tiles, rec, rec_key, listed,
        *_trig_tables(em.height, em.width), log.idx, log.old, log.was_valid, log.n, carve, cam, seen_depth,
        *_averaging(em, config),
    )
    if _threads(config.threads) >= 2:
        zband2, tiles2, log2 = em._second_thread_scratch(log.capacity)
        n_touched, counts, n_logged = _update_kernel_2t(*args, zband2, tiles2, log2.idx, log2.old, log2.was_valid)
    else:
        n_touched, counts, n_logged = _update_kernel(*args)
    if log is not _NO_LOG:
        log.n = int(n_logged)
        log.updates += 1
    return UpdateStats(len(pts), int(n_touched), *(int(c) for c in counts))


def _averaging(em: EnvironmentMap, config: UpdateConfig) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' (H·W,) uint8 per-pixel average counts and (3,) float64 (colour_average,
    tolerance relative, absolute); a map that never averages gets a one-entry dummy."""
    n = int(config.colour_average)
    counts = em._averaged_counts().reshape(-1) if n > 1 else _NO_AVERAGED
    return counts, np.array([n, float(config.carve_tol_rel), float(config.carve_tol_abs_m)], np.float64)


_NO_AVERAGED = np.zeros(1, np.uint8)
_NO_CAM = np.zeros(23)
_NO_SEEN = np.zeros((1, 1), np.float32)


@lru_cache(maxsize=8)
def _window(size: int) -> np.ndarray:
    """The structuring element of the carving window (``UpdateConfig.carve_window``)."""
    return np.ones((size, size), np.uint8)


@numba.njit(cache=True)
def _measured_depth(depth, known):  # pragma: no cover - compiled
    """(H, W) float32: ``depth`` where ``known`` and finite and > 0, else 0 (numpy's where and
    casts of a 224×172 frame took 70 µs)."""
    out = np.empty(depth.shape, np.float32)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            out[r, c] = np.float32(z) if known[r, c] and z > 0.0 and z < np.inf else np.float32(0.0)
    return out


def _seen_arrays(seen: SeenDepth, config: UpdateConfig) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's view of ``seen``: (23,) float64 camera (see :func:`_is_free`) and (H, W) float32
    depth, 0 where not measured (or not finite)."""
    intr = seen.intrinsics
    if not isinstance(intr, Intrinsics) or not isinstance(seen.T_world_from_cam, RigidTransform):
        raise InvalidInputError("seen: expected Intrinsics and a RigidTransform")
    shape = (intr.height, intr.width)
    depth = check_array(seen.depth_m, "seen.depth_m", shape=shape, dtype="float")
    known = check_array(seen.known, "seen.known", shape=shape, dtype="bool")
    for name in ("carve_tol_rel", "carve_tol_abs_m"):
        if not 0.0 <= float(getattr(config, name)) < math.inf:
            raise RangeError(f"UpdateConfig.{name}: expected a finite value ≥ 0, got {getattr(config, name)}")
    # float64 stays float64 (a value beyond float32's range must become inf, as numpy's cast does).
    d = _measured_depth(np.ascontiguousarray(depth, np.float64 if depth.dtype.itemsize > 4 else np.float32),
                        np.ascontiguousarray(known))
    # Each pixel's minimum over the carving window, 0 where the window leaves the image: one lookup
    # per tested map pixel.
    if config.carve_window > 1:
        d = cv2.erode(d, _window(int(config.carve_window)), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    # T_cam_from_world's top rows, as RigidTransform.inverse() computes them (without its checks,
    # 40 µs of the update's call).
    r = seen.T_world_from_cam.rotation
    rt = np.concatenate([r.T, (-r.T @ seen.T_world_from_cam.translation)[:, None]], axis=1).reshape(-1)
    dist = intr.distortion.coefficients
    cam = np.concatenate([rt, [intr.fx, intr.fy, intr.cx, intr.cy], dist,
                          [float(config.carve_tol_rel), float(config.carve_tol_abs_m)]])
    return cam, d


@numba.njit(cache=True, inline="always")
def _pairs_block(points, start, m, colours, cstart, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                 bx, by, bz, bv, bu, br, bi, sums, counts, saturation):  # pragma: no cover - compiled
    """The pairs of points[start : start + m] (colours from row cstart on) appended to src / dst
    from row k on; returns the new count. With a non-empty ``sums`` the pairs are not stored but
    accumulated as :func:`rgbd_envmap.colour._ccm_sums` accumulates (src, dst): ``sums`` gets
    AᵀA (6 upper entries), AᵀB (9, row-major) and tr(BᵀB) in float64, ``counts`` the pairs kept, the
    ones dropped as non-finite and as saturated (any src channel ≥ ``saturation``), in that order
    and pair order, so the sums are bit-identical to collecting the pairs and then summing."""
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    hw = height * width
    pf, df, vf = planes.reshape(3, hw), depth.reshape(hw), valid.reshape(hw)
    accumulate = sums.shape[0] > 0
    # int64 start and count: _pairs_block is inlined where they are literal zeros, and numba compiled
    # _block_coords once more per literal.
    _block_coords(points, np.int64(start), np.int64(m), origin[0], origin[1], origin[2], row_px, col_px,
                  bx, by, bz, bv, bu, br)
    # In stages over the block: the map pixels of the whole block are requested before any is
    # read, and the colours of the block's pairs before any is used: the frame's region of the
    # 34 MB map is rarely still cached when the next depth frame arrives, and one miss at a time
    # was half of the pass (0.92 ms with a cold cache vs 0.49 ms warm for 37.6k points).
    pix, hits = bi[0], bi[1]
    for j in range(m):
        i = start + j
        # abs(x) < inf: finite, as a compare; an unusable point is marked -1 (looks up pixel 0, dropped).
        usable = ((abs(points[i, 0]) < np.inf) & (abs(points[i, 1]) < np.inf) & (abs(points[i, 2]) < np.inf)
                  & (br[j] > 0.0))
        row = _mn(int(bv[j]), height - 1)
        col = int(bu[j])
        q = row * width + (col - width if col >= width else col)
        q = q if usable else -1
        pix[j] = q
        _prefetch(df, q)
        _prefetch(vf, q)
    # The pair test without branches (whether a point pairs is as good as random), its hits compacted.
    n_hit = 0
    for j in range(m):
        q = pix[j]
        p = _u(_mx(q, 0))  # row, col ≥ 0 (v, u ≥ 0)
        hit = (q >= 0) & vf[p] & (abs(df[p] - br[j]) <= max_diff)
        hits[n_hit] = j
        n_hit += hit
    for h in range(n_hit):
        p = _u(pix[hits[h]])
        _prefetch(pf[0], p)
        _prefetch(pf[1], p)
        _prefetch(pf[2], p)
    for h in range(n_hit):
        j = hits[h]
        p = _u(pix[j])
        if accumulate:
            _accumulate_pair(colours, _u(cstart + j), pf, p, sums, counts, saturation)
        else:
            for c in range(3):
                src[_u(k), c] = colours[_u(cstart + j), c]
                dst[_u(k), c] = pf[c, p]
        k += 1
    return k


@numba.njit(cache=True, inline="always")
def _accumulate_pair(colours, i, pf, p, sums, counts, saturation):  # pragma: no cover - compiled
    """Pair (colours[i], map colour p) into the normal-equation sums (see :func:`_pairs_block`)."""
    a0, a1, a2 = np.float64(colours[i, 0]), np.float64(colours[i, 1]), np.float64(colours[i, 2])
    b0, b1, b2 = np.float64(pf[0, p]), np.float64(pf[1, p]), np.float64(pf[2, p])
    if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
            and math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)):
        counts[1] += 1
    elif a0 >= saturation or a1 >= saturation or a2 >= saturation:
        counts[2] += 1
    else:
        counts[0] += 1
        sums[0] += a0 * a0
        sums[1] += a0 * a1
        sums[2] += a0 * a2
        sums[3] += a1 * a1
        sums[4] += a1 * a2
        sums[5] += a2 * a2
        sums[6] += a0 * b0
        sums[7] += a0 * b1
        sums[8] += a0 * b2
        sums[9] += a1 * b0
        sums[10] += a1 * b1
        sums[11] += a1 * b2
        sums[12] += a2 * b0
        sums[13] += a2 * b1
        sums[14] += a2 * b2
        sums[15] += b0 * b0 + b1 * b1 + b2 * b2


@numba.njit(cache=True)
def _pairs_kernel(points, colours, origin, height, width, depth, valid, planes, max_diff, src, dst):  # pragma: no cover - compiled
    """The pairs of :func:`collect_pairs`, written compacted into src / dst; returns their count.
    Map coordinates are computed a block at a time (:func:`_block_coords`), so no per-point
    temporaries outlive a block."""
    n = points.shape[0]
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bi = np.empty((2, _BLOCK), np.int64)
    no_sums, no_counts = np.zeros(0), np.zeros(0, np.int64)  # store the pairs
    k = 0
    for start in range(0, n, _BLOCK):
        k = _pairs_block(points, start, _mn(_BLOCK, n - start), colours, start, origin, height, width, depth, valid,
                         planes, max_diff, src, dst, k, bx, by, bz, bv, bu, br, bi, no_sums, no_counts, np.inf)
    return k


@numba.njit(cache=True)
def _frame_pairs_kernel(depth_img, mask, rays, rot, trans, rgb, origin, height, width, depth, valid, planes,
                        max_diff, sums, counts, saturation):  # pragma: no cover - compiled
    """:func:`collect_pairs` of :func:`frame_points` of the ``mask`` pixels with colours
    ``rgb[mask]``, without either array: the points are unprojected a block at a time into a
    buffer that :func:`_pairs_block` reads as it reads an (N, 3) array, so the pairs are the same.
    With a non-empty ``sums`` the pairs are accumulated there (:func:`_pairs_block`) and the
    returned arrays are empty; the count of pairs is returned either way."""
    n = 0 if sums.shape[0] > 0 else np.count_nonzero(mask)
    src, dst = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    k = _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, 0, depth_img.shape[0], origin, height, width, depth,
                          valid, planes, max_diff, src, dst, sums, counts, saturation)
    return src[:k] if n else src, dst[:k] if n else dst, k


@numba.njit(cache=True)
def _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, r0, r1, origin, height, width, depth, valid, planes,
                      max_diff, src, dst, sums, counts, saturation):  # pragma: no cover - compiled
    """:func:`_frame_pairs_kernel`'s pass over frame rows ``r0`` to ``r1`` − 1: the pairs stored
    into ``src`` / ``dst`` or, with a non-empty ``sums``, accumulated there. Returns their count."""
    w = depth_img.shape[1]
    pts, col = np.empty((_BLOCK, 3)), np.empty((_BLOCK, 3), np.float32)
    bx, by, bz = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bv, bu, br = np.empty(_BLOCK), np.empty(_BLOCK), np.empty(_BLOCK)
    bi = np.empty((2, _BLOCK), np.int64)
    k, m = 0, 0
    for r in range(r0, r1):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth_img, rays, rot, trans, r, c, pts, m)
                col[m, 0], col[m, 1], col[m, 2] = rgb[r, c, 0], rgb[r, c, 1], rgb[r, c, 2]
                m += 1
                if m == _BLOCK:
                    k = _pairs_block(pts, 0, m, col, 0, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                                     bx, by, bz, bv, bu, br, bi, sums, counts, saturation)
                    m = 0
    return _pairs_block(pts, 0, m, col, 0, origin, height, width, depth, valid, planes, max_diff, src, dst, k,
                        bx, by, bz, bv, bu, br, bi, sums, counts, saturation)


@numba.njit(cache=True, parallel=_PRANGE_ONLY)
def _frame_pair_sums_2t(depth_img, mask, rays, rot, trans, rgb, origin, height, width, depth, valid, planes,
                        max_diff, sums, counts, saturation):  # pragma: no cover - compiled
    """:func:`_frame_pairs_kernel` with ``sums`` on two threads, the same sums bit for bit: the
    frame's rows split where about half the ``mask`` pixels lie above, each part's pairs found and
    stored at the same time, then accumulated in order (the first part's, then the second's), as
    the one-thread pass accumulates them. Returns the count of pairs."""
    h = depth_img.shape[0]
    per_row = np.zeros(h + 1, np.int64)
    for r in range(h):
        per_row[r + 1] = per_row[r] + np.count_nonzero(mask[r])
    split = 0
    while split < h and 2 * per_row[split + 1] <= per_row[h]:
        split += 1
    src = np.empty((per_row[h], 3), np.float32)
    dst = np.empty((per_row[h], 3), np.float32)
    found = np.zeros(2, np.int64)
    none_f, none_i = np.zeros(0), np.zeros(0, np.int64)
    for t in numba.prange(2):
        lo, hi = (0, split) if t == 0 else (split, h)
        at = per_row[lo]  # the part's pairs from its first mask pixel's slot on
        found[t] = _frame_pairs_rows(depth_img, mask, rays, rot, trans, rgb, lo, hi, origin, height, width, depth,
                                     valid, planes, max_diff, src[at:per_row[hi]], dst[at:per_row[hi]], none_f, none_i,
                                     saturation)
    pf = dst.T
    for t in range(2):
        at = 0 if t == 0 else per_row[split]
        for j in range(at, at + found[t]):
            _accumulate_pair(src, j, pf, j, sums, counts, saturation)
    return found[0] + found[1]


def _frame_pair_inputs(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                       T_world_from_cam: RigidTransform, rgb: np.ndarray) -> tuple:
    """The checked arguments of :func:`_frame_pairs_kernel` up to the map's arrays."""
    shape = intrinsics.shape
    depth = check_array(depth_m, "depth_m", shape=shape, dtype="float")
    ok = check_array(mask, "mask", shape=shape, dtype="bool")
    colours = check_array(rgb, "rgb", shape=(*shape, 3), dtype="float")
    if colours.dtype != np.float32:  # collect_pairs keeps the colours' values; float32 is what frames hold
        raise InvalidInputError(f"rgb: expected float32, got {colours.dtype}")
    return (np.ascontiguousarray(depth), np.ascontiguousarray(ok), pixel_rays(intrinsics),
            np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation),
            np.ascontiguousarray(colours), em.origin, em.height, em.width, em.depth_m, em.valid, em.radiance_planes)


def _frame_pairs(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                 T_world_from_cam: RigidTransform, rgb: np.ndarray, max_depth_diff_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """``collect_pairs(em, frame_points(depth_m, mask, …), rgb[mask], max_depth_diff_m)`` in one pass
    over the frame (identical pairs; the numpy boolean gather of the colours alone took 1.1 ms)."""
    args = _frame_pair_inputs(em, depth_m, mask, intrinsics, T_world_from_cam, rgb)
    src, dst, _ = _frame_pairs_kernel(*args, float(max_depth_diff_m), np.zeros(0), np.zeros(0, np.int64), np.inf)
    return src, dst


def _frame_pair_sums(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                     T_world_from_cam: RigidTransform, rgb: np.ndarray, max_depth_diff_m: float = 0.01,
                     saturation: float = 1.0, threads: int = 1) -> tuple[np.ndarray, np.ndarray, float, int, int, int, int]:
    """The pairs of :func:`_frame_pairs` reduced, in the same pass, to the colour fit's
    normal-equation sums: ``(AᵀA, AᵀB, tr(BᵀB), kept, non-finite, saturated, pairs)``, bit for bit
    what :func:`rgbd_envmap.colour._ccm_sums` gives for those pairs (same values, same order).
    No pair array is written or read back (the pairs stage plus the fit's pass over them cost
    1.15 + 0.33 ms in the main run). ``threads=2``: :func:`_frame_pair_sums_2t` (the same result)."""
    args = _frame_pair_inputs(em, depth_m, mask, intrinsics, T_world_from_cam, rgb)
    sums, counts = np.zeros(16), np.zeros(3, np.int64)
    if _threads(threads) >= 2:
        k = _frame_pair_sums_2t(*args, float(max_depth_diff_m), sums, counts, float(saturation))
    else:
        _, _, k = _frame_pairs_kernel(*args, float(max_depth_diff_m), sums, counts, float(saturation))
    ata = sums[[0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(3, 3)
    return ata, sums[6:15].reshape(3, 3).copy(), float(sums[15]), int(counts[0]), int(counts[1]), int(counts[2]), int(k)


def collect_pairs(
    em: EnvironmentMap, points_world: np.ndarray, colours: np.ndarray, max_depth_diff_m: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Colour pairs (paper §5.2): for (N, 3) world points of *reliable* frame pixels with their (N, 3)
    current-space colours, the EM pixel each falls in; a pair is kept where the EM has data whose
    depth differs by at most ``max_depth_diff_m``. Returns (src (M, 3) float32 frame colours, dst
    (M, 3) float32 EM colours in the reference space), in the order of the points."""
    pts = check_array(points_world, "points_world", shape=("N", 3), dtype="float").astype(np.float64, copy=False)
    col = check_array(colours, "colours", shape=(pts.shape[0], 3), dtype="float")
    n = len(pts)
    src, dst = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    k = _pairs_kernel(np.ascontiguousarray(pts), np.ascontiguousarray(col), em.origin, em.height, em.width, em.depth_m,
                      em.valid, em.radiance_planes, float(max_depth_diff_m), src, dst)
    return src[:k], dst[:k]


def frame_points(depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, T_world_from_cam: RigidTransform) -> np.ndarray:
    """(M, 3) float64 world points of the ``mask`` pixels of a z-depth image, in raster order.
    (numba: the numpy gather-scale-transform chain took 2.5 ms for a 224×172 frame.)"""
    check_array(depth_m, "depth_m", shape=intrinsics.shape, dtype="float")
    check_array(mask, "mask", shape=intrinsics.shape, dtype="bool")
    return _world_points(np.ascontiguousarray(depth_m), np.ascontiguousarray(mask), pixel_rays(intrinsics),
                         np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation))


@numba.njit(cache=True, inline="always")
def _world_point(depth, rays, rot, trans, r, c, out, k):  # pragma: no cover - compiled
    """out[k] = the world point of pixel (r, c) of a z-depth image (callers are not fastmath, so
    every caller computes the same bits)."""
    z = depth[r, c]
    x, y = rays[r, c, 0] * z, rays[r, c, 1] * z
    for j in range(3):
        out[k, j] = rot[j, 0] * x + rot[j, 1] * y + rot[j, 2] * z + trans[j]


@numba.njit(cache=True)
def _world_points(depth, mask, rays, rot, trans):  # pragma: no cover - compiled
    h, w = depth.shape
    out = np.empty((np.count_nonzero(mask), 3))
    k = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth, rays, rot, trans, r, c, out, k)
                k += 1
    return out


@numba.njit(cache=True)
def _frame_samples_kernel(depth, mask, rays, rot, trans, rgb, flag, matrix, correct):  # pragma: no cover - compiled
    """:func:`frame_points` of the ``mask`` pixels with their (M, 3) float32 colours (times the
    float32 ``matrix``ᵀ when ``correct``) and (M,) bool ``flag`` (uint8 image) in one pass (numpy's
    boolean gathers of a 224×172 frame took 1.1 ms)."""
    h, w = depth.shape
    n = np.count_nonzero(mask)
    pts, col, out_flag = np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty(n, np.bool_)
    k = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                _world_point(depth, rays, rot, trans, r, c, pts, k)
                x, y, z = rgb[r, c, 0], rgb[r, c, 1], rgb[r, c, 2]
                if correct:
                    for j in range(3):
                        col[k, j] = matrix[j, 0] * x + matrix[j, 1] * y + matrix[j, 2] * z
                else:
                    col[k, 0], col[k, 1], col[k, 2] = x, y, z
                out_flag[k] = flag[r, c] != 0
                k += 1
    return pts, col, out_flag


def _frame_samples(depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, T_world_from_cam: RigidTransform,
                   rgb: np.ndarray, flag: np.ndarray | None = None,
                   matrix: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples of the ``mask`` pixels of an RGB-D frame, in raster order: (M, 3) float64 world
    points (exactly :func:`frame_points`), (M, 3) float32 colours ``rgb[mask]`` (corrected by
    ``matrix`` when given: ``rgb[mask] @ matrix.T`` in float32, as
    :func:`rgbd_envmap.colour.apply_ccm` computes it up to rounding; that pass over the samples
    cost 0.19 ms) and (M,) bool ``flag[mask]`` (all False when ``flag`` is None). One pass over
    the frame instead of numpy's boolean gathers.

    Args:
        depth_m: (H, W) float z-depth in metres; mask: (H, W) bool; rgb: (H, W, 3) float linear RGB;
        flag: (H, W) bool or uint8 (non-zero is True), or None; matrix: (3, 3) finite, or None.
    """
    shape = intrinsics.shape
    depth = check_array(depth_m, "depth_m", shape=shape, dtype="float")
    ok = check_array(mask, "mask", shape=shape, dtype="bool")
    colours = check_array(rgb, "rgb", shape=(*shape, 3), dtype="float")
    flags = np.zeros(shape, np.uint8) if flag is None else check_array(flag, "flag", shape=shape, dtype=("bool", np.uint8))
    m = np.eye(3, dtype=np.float32) if matrix is None else check_array(matrix, "matrix", shape=(3, 3), dtype="float", finite=True)
    return _frame_samples_kernel(np.ascontiguousarray(depth), np.ascontiguousarray(ok), pixel_rays(intrinsics),
                           np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation),
                           np.ascontiguousarray(colours, dtype=np.float32), np.ascontiguousarray(flags).view(np.uint8),
                           np.ascontiguousarray(m, dtype=np.float32), matrix is not None)


@numba.njit(cache=True, fastmath=True, inline="always")
def _atan2_branchless(y, x):  # pragma: no cover - compiled
    """atan2 from :data:`_ATAN_POLY`, written with selects only so that loops calling it vectorise
    (libm's atan2 is ~40 ns a call and blocks vectorisation)."""
    ax, ay = abs(x), abs(y)
    mx = _mx(ax, ay)
    t = _mn(ax, ay) / (mx if mx > 0.0 else 1.0)
    t2 = t * t
    # _ATAN_POLY written out: a loop over the tuple kept this from vectorising (28 ms → 10 ms pass).
    p = 0.0028340641752807177
    p = p * t2 + -0.01600503000542798
    p = p * t2 + 0.04258760664298073
    p = p * t2 + -0.07495445371631375
    p = p * t2 + 0.10636754062743976
    p = p * t2 + -0.1420257050187139
    p = p * t2 + 0.1999248357706807
    p = p * t2 + -0.33333066780599485
    p = p * t2 + 0.9999999842426203
    a = t * p
    a = 0.5 * math.pi - a if ay > ax else a
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a


@numba.njit(cache=True, fastmath=True)
def _block_coords(points, start, m, ox, oy, oz, kv, ku, bx, by, bz, bv, bu, br):  # pragma: no cover - compiled
    """Continuous (v, u) and distance from the origin (ox, oy, oz) of points[start : start + m] into
    the block buffers. The points are copied into structure-of-arrays block buffers first: the
    (N, 3) layout read directly vectorised 3× worse. Branch-free (:func:`_atan2_branchless`), so
    it vectorises. Non-finite points give garbage: callers test the points themselves (fastmath may
    fold a finiteness test on the results away)."""
    for j in range(m):
        bx[j] = points[start + j, 0] - ox
        by[j] = points[start + j, 1] - oy
        bz[j] = points[start + j, 2] - oz
    for j in range(m):
        dx, dy, dz = bx[j], by[j], bz[j]
        h = math.sqrt(dx * dx + dy * dy)
        br[j] = math.sqrt(h * h + dz * dz)
        bv[j] = _atan2_branchless(h, dz) * kv
        bu[j] = (_atan2_branchless(dy, dx) + math.pi) * ku


def translate(em: EnvironmentMap, offset: np.ndarray, method: str = "depth", *, radius_m: float = 2.0,
              max_splat_px: int = 8, max_rel_jump: float = 0.2, out: EnvironmentMap | None = None,
              threads: int = 2) -> EnvironmentMap:
    """A new map at ``em.origin + offset``; ``em`` is left intact (use the result in place of ``em``
    for a permanent move, or keep both for a temporary view). Paper §6.2; the work is in
    :mod:`rgbd_envmap.translation` (see :func:`~rgbd_envmap.translation.translate_map` for the
    methods and parameters; ``out``: a map of the same size to overwrite and return instead;
    ``threads``: 1 or 2, the same result)."""
    from rgbd_envmap.translation import translate_map  # it imports this module

    return translate_map(em, offset, method, radius_m=radius_m, max_splat_px=max_splat_px, max_rel_jump=max_rel_jump,
                         out=out, threads=threads)
