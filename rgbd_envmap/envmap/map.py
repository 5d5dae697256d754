"""The RGB-D environment map's state (paper 003 §6): :class:`EnvironmentMap` and its change log.

The map is equirectangular (docs/reference/conventions.md) around an ``origin`` in the world frame.
Each pixel holds linear radiance in the *reference* colour space (the first frame's), the Euclidean
distance of the surface from the origin (``depth_m``), and a ``valid`` flag. Radiance is stored
planar, (3, H, W) float32, because SH projection reads one channel at a time; ``radiance`` is an
(H, W, 3) view of it. The map is the pipeline's one stateful object: :func:`rgbd_envmap.envmap.update`
writes it in place; the translation makes new maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_array, check_number, check_positive_int
from rgbd_envmap.errors import DTypeError, InvalidInputError, NonFiniteError, RangeError

__all__ = ["EnvironmentMap", "MapChanges", "ChangeLog", "check_map", "MAX_MAP_PIXELS", "MAP_BYTES_PER_PIXEL"]

#: bytes a map pixel takes: planar float32 radiance (12), float32 distance (4), the valid flag (1);
#: capturing adds the colour-average count (1) and per-update scratch, a translated view as much again.
MAP_BYTES_PER_PIXEL = 17
#: the largest map the library makes (8192 × 4096: about 0.5 GiB).
MAX_MAP_PIXELS = 8192 * 4096


def check_map(em: object, name: str = "em", *, writable: bool = False) -> "EnvironmentMap":
    """Raise the project's typed errors unless ``em`` is an :class:`EnvironmentMap` whose arrays have
    the layout the stages read (C-contiguous float32 (3, H, W) radiance, float32 (H, W) distance,
    bool (H, W) valid, finite (3,) origin) and, with ``writable``, can be written. Returns ``em``."""
    if not isinstance(em, EnvironmentMap):
        raise DTypeError(f"{name}: expected an EnvironmentMap, got {type(em).__name__}")
    shapes = {"radiance_planes": ((3, em.height, em.width), np.float32), "depth_m": ((em.height, em.width), np.float32),
              "valid": ((em.height, em.width), np.bool_)}
    for attr, (shape, dtype) in shapes.items():
        a = getattr(em, attr)
        if not isinstance(a, np.ndarray) or a.shape != shape or a.dtype != dtype:
            got = f"{a.dtype} {a.shape}" if isinstance(a, np.ndarray) else type(a).__name__
            raise InvalidInputError(f"{name}.{attr}: expected a {np.dtype(dtype)} array of shape {shape}, got {got}")
        if not a.flags.c_contiguous:
            raise InvalidInputError(f"{name}.{attr}: expected a C-contiguous array (the map's own storage)")
        if writable and not a.flags.writeable:
            raise InvalidInputError(f"{name}.{attr}: expected a writable array, got a read-only one")
    check_array(em.origin, f"{name}.origin", shape=(3,), dtype="float", finite=True)
    return em


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
        if self.height * self.width > MAX_MAP_PIXELS:
            raise RangeError(f"height × width: a {self.height}×{self.width} map would take about "
                             f"{self.height * self.width * MAP_BYTES_PER_PIXEL / 2**30:.1f} GiB; at most "
                             f"{MAX_MAP_PIXELS:,} pixels (e.g. 8192×4096)")
        self.origin = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
        self.radiance_planes = np.zeros((3, self.height, self.width), np.float32)
        self.depth_m = np.zeros((self.height, self.width), np.float32)
        self.valid = np.zeros((self.height, self.width), bool)
        #: working buffers the stages keep with this map between calls (the update's z-buffer band
        #: and per-sample records), keyed by stage; not part of the map's content.
        self.scratch: dict[str, tuple] = {}
        #: the change log :func:`update` appends to while recording (:meth:`record_changes`), else None.
        self.change_log: ChangeLog | None = None
        self._averaged: np.ndarray | None = None
        self._spare_changes: ChangeLog | None = None

    def colour_counts(self) -> np.ndarray:
        """(H, W) uint8: how many samples beyond the first each pixel's colour averages (the
        ``colour_average`` of :class:`UpdateConfig`), allocated (zeros) on the first update that
        averages. Maps made by ``from_arrays``, ``copy`` or ``translate`` start at zero: each pixel's
        colour counts as one sample."""
        if self._averaged is None:
            self._averaged = np.zeros((self.height, self.width), np.uint8)
        return self._averaged

    @classmethod
    def uninitialised(cls, height: int, width: int, origin: np.ndarray) -> "EnvironmentMap":
        """A map whose arrays are allocated but not zeroed, for a stage that writes every pixel
        (the translation); its content is garbage until then."""
        em = cls.__new__(cls)
        em.height, em.width = int(height), int(width)
        em.origin = np.asarray(origin, np.float64).copy()
        em.radiance_planes = np.empty((3, em.height, em.width), np.float32)
        em.depth_m = np.empty((em.height, em.width), np.float32)
        em.valid = np.empty((em.height, em.width), bool)
        em.scratch = {}
        em.change_log = None
        em._averaged = None
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
        # Where a pixel is valid its data must mean something; elsewhere anything goes (it is ignored).
        bad = ok & ~np.isfinite(rad).all(axis=-1)
        if bad.any():
            raise NonFiniteError(f"radiance: expected finite values where valid, got {int(bad.sum())} pixels with NaN or inf")
        bad = ok & ~(np.isfinite(depth) & (depth > 0))
        if bad.any():
            raise RangeError(f"depth_m: expected a finite distance > 0 where valid, got {int(bad.sum())} pixels that are "
                             "not (NaN, inf, zero or negative)")
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
        self.change_log = ChangeLog(ChangeLog.DEFAULT_CAPACITY if self.change_log is None else self.change_log.capacity)

    def take_changes(self) -> "MapChanges | None":
        """The pixels written since :meth:`record_changes` or the last call, and a fresh log; None
        when the map is not recording. ``complete`` is False when the log cannot describe what
        happened (it overflowed, or :meth:`mark_modified` was called): rebuild derived state.
        The arrays are views into the map's log buffers (two, used in turn: fresh pages cost page
        faults in the update), valid until the next call."""
        log = self.change_log
        if log is None:
            return None
        spare = self._spare_changes
        if log.n > log.capacity:
            spare = ChangeLog(min(4 * log.n, self.height * self.width))
        elif spare is None or spare.capacity < log.capacity:
            spare = ChangeLog(log.capacity)
        spare.n, spare.updates, spare.complete = 0, 0, True
        self.change_log, self._spare_changes = spare, log
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
        if self.change_log is not None:
            self.change_log.complete = False
        self._averaged = None

    def copy(self) -> "EnvironmentMap":
        """An independent map with the same content (no change log, colour counts restarted)."""
        em = EnvironmentMap(self.height, self.width, self.origin)
        em.radiance_planes[:] = self.radiance_planes
        em.depth_m[:] = self.depth_m
        em.valid[:] = self.valid
        return em

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


class ChangeLog:
    """Growable buffers the update kernel appends to (``n`` counts past ``capacity`` on overflow)."""

    #: 262,144 entries (5.5 MB a buffer, two in turn): frames of the default session write up to
    #: ~350k pixels; with 65,536 the log overflowed twice before growing, each time forcing a full SH
    #: projection that the incremental path would have done in a third of the time.
    DEFAULT_CAPACITY = 1 << 18

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        # 21 bytes per entry; a map has at most MAX_MAP_PIXELS pixels to change.
        self.capacity = int(check_number(capacity, "capacity", low=0, high=MAX_MAP_PIXELS, integer=True))
        self.idx = np.empty(self.capacity, np.int64)
        self.old = np.empty((self.capacity, 3), np.float32)
        self.was_valid = np.empty(self.capacity, bool)
        self.n = 0
        self.updates = 0
        self.complete = True


