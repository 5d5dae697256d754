"""The map update (paper 003 §6.1): a frame's samples written into the map by the rules.

:func:`update` projects a frame's world points into the map; a stored pixel takes a sample when one
of the rules of :mod:`rgbd_envmap.envmap.rules` holds (within one frame the closest sample wins).
Taking a sample replaces the colour (or, ours, averages it with earlier samples of the same surface:
``UpdateConfig.colour_average``); the depth becomes the mean of the old and new depth (the new depth
for an empty pixel). The pixel-by-pixel spec is :func:`rgbd_envmap.reference.envmap.update_reference`;
the kernels (:mod:`rgbd_envmap._kernels.envmap_update`) compute the same map bit for bit.

**Footprint splatting** (ours). At 2000×1000 a far wall's map pixel (0.18°) is smaller than a ToF
pixel seen from near the origin, so projecting each sample to one pixel (the paper's description)
leaves a sieve of holes that the SH stage must paper over. By default each sample covers the map
pixels of its footprint: its lateral size at the surface, ``range / f`` (``f`` the depth camera's
focal length in pixels), seen from the origin at distance ``r``, in rows and (divided by sin θ)
columns. ``splat=False`` is the paper's one-pixel projection. Pairs for colour correction always use
the one pixel a sample falls in.

**Free-space carving** (ours). A stored point that the frame's measured depth shows to be empty
space (the device saw through it) takes the frame's sample: it removes stale surfaces that the
paper's removal rule, which needs the device on the pixel's ray, rarely reaches.

**The viewpoint rule** (ours). Each pixel keeps the nearest distance from the origin of the devices
that saw its surface (:func:`view_distances`); a sample of that surface from a device more than
``UpdateConfig.view_ratio`` times as far out is refused, so a session that moves away from the
origin does not average its far, parallax-smeared views into what near views captured. Takeovers by
another surface are never refused.

References:
    Monroy, Hudon, Smolic (2018), §6.1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from rgbd_envmap._kernels import envmap_update as kernels
from rgbd_envmap._kernels.parallel import parallel_call
from rgbd_envmap.checks import check_array, check_flag, check_instance, check_number, check_positive_int
from rgbd_envmap.envmap.map import ChangeLog, EnvironmentMap, check_map
from rgbd_envmap.envmap.tables import trig_tables
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError
from rgbd_envmap.types import Intrinsics, RigidTransform, check_transform

__all__ = ["UpdateConfig", "SeenDepth", "UpdateStats", "update", "map_coordinates", "view_distances", "clip_flags"]


#: the largest ``UpdateConfig.max_splat_px``: a footprint of 2·256 + 1 rows already covers a quarter
#: of a 2000×1000 map's height.
MAX_SPLAT_PX = 256


@dataclass(frozen=True)
class UpdateConfig:
    """Parameters of :func:`update`. The radii are the paper's; splatting, carving and colour
    averaging are ours (docs/design/envmap.md says why, with the measurements)."""

    #: the trusted sphere's radius around the origin (paper: 10 cm).
    trusted_radius_m: float = 0.10
    #: the removal rule's distance of the device from a pixel's ray (paper: 3 cm).
    removal_radius_m: float = 0.03
    #: cover each sample's footprint (True, ours) or only the pixel it falls in (the paper's description).
    splat: bool = True
    #: footprint = splat_scale · range / focal, the ToF pixel's size on a surface facing the sensor;
    #: slightly under 1 keeps foreground silhouettes from dilating.
    splat_scale: float = 0.95
    #: footprints are clamped to this many rows each side (columns: the same angle, so more pixels
    #: near the poles); guards samples right at the origin.
    max_splat_px: int = 24
    #: free-space carving (rule "freed", ours): a stored point the frame's measured depth shows to be
    #: empty space takes the frame's sample; needs the frame's depth (:class:`SeenDepth`) passed to
    #: :func:`update`.
    carve: bool = True
    #: the stored point is free space when all measured depths in the ``carve_window`` × ``carve_window``
    #: pixels around its projection exceed its z-depth by more than ``carve_tol_rel`` · z +
    #: ``carve_tol_abs_m`` (a few σ of the denoised depth's noise).
    carve_tol_rel: float = 0.03
    carve_tol_abs_m: float = 0.02
    #: odd window of measured depths the carving test looks at (1: the pixel the point projects
    #: into). A wider window guards raw ToF noise, but with denoised depth it mostly keeps stale
    #: points wherever any of its pixels measured something nearer.
    carve_window: int = 1
    #: a pixel taken by a sample of the surface it holds (the sample's distance within the carving
    #: tolerance of the stored one, ``carve_tol_rel`` · d + ``carve_tol_abs_m``: beyond it is free
    #: space, within it the same surface) averages its colour over up to this many such samples (a
    #: running mean, then an exponential one with weight 1 / colour_average for each new sample);
    #: 1: the paper's rule, the colour replaced. Any other takeover replaces the colour and restarts
    #: the average. A colour change of a static surface (a lamp dimming) then takes several samples
    #: instead of one (after n samples of the new colour the old one keeps a weight of (7/8)^n once
    #: the mean is full).
    colour_average: int = 8
    #: the viewpoint rule (ours): a sample of the surface a pixel holds (the same-surface test of
    #: ``colour_average``) is refused, the pixel kept as it is, when the device is farther from the
    #: origin than ``view_ratio`` × the nearest device distance that surface was seen from (since it
    #: last replaced another); any other takeover (empty, a different surface, freed) still happens
    #: and resets that distance, and the trusted sphere's samples are never refused. Far viewpoints
    #: see the same surface with more parallax, so their depth noise smears it in the map; without
    #: the rule a session that moves away from the origin slowly trades its near views for them.
    #: ``math.inf``: off (the paper's rules). At least 1.
    view_ratio: float = 1.5

    def __post_init__(self) -> None:
        check_number(self.trusted_radius_m, "UpdateConfig.trusted_radius_m", low=0.0)
        check_number(self.removal_radius_m, "UpdateConfig.removal_radius_m", low=0.0)
        check_flag(self.splat, "UpdateConfig.splat")
        check_number(self.splat_scale, "UpdateConfig.splat_scale", low=0.0, low_open=True)
        check_number(self.max_splat_px, "UpdateConfig.max_splat_px", low=1, high=MAX_SPLAT_PX, integer=True)
        check_flag(self.carve, "UpdateConfig.carve")
        check_number(self.carve_tol_rel, "UpdateConfig.carve_tol_rel", low=0.0)
        check_number(self.carve_tol_abs_m, "UpdateConfig.carve_tol_abs_m", low=0.0)
        check_positive_int(self.colour_average, "UpdateConfig.colour_average")
        check_positive_int(self.carve_window, "UpdateConfig.carve_window")
        if not (isinstance(self.view_ratio, (float, np.floating)) and self.view_ratio == math.inf):  # inf: off
            check_number(self.view_ratio, "UpdateConfig.view_ratio", low=1.0)
        if self.carve_window % 2 == 0 or self.carve_window > 15:
            raise RangeError(f"UpdateConfig.carve_window: expected an odd size from 1 to 15, got {self.carve_window}")
        if self.colour_average > 255:
            raise RangeError(f"UpdateConfig.colour_average: expected at most 255, got {self.colour_average}")


@dataclass(frozen=True)
class SeenDepth:
    """What the device measured in one frame, for free-space carving: (H, W) z-depth in metres where
    ``known`` (measured, not hole-filled), the depth camera's intrinsics (with distortion) and pose
    (into ``"world"`` where the frames are named). A non-finite or non-positive depth counts as not
    measured."""

    depth_m: np.ndarray
    known: np.ndarray
    intrinsics: Intrinsics
    T_world_from_cam: RigidTransform

    def __post_init__(self) -> None:
        # Types, shapes and frames only (a few µs per frame); the arrays are kept as given.
        check_instance(self.intrinsics, Intrinsics, "SeenDepth.intrinsics")
        check_transform(self.T_world_from_cam, "SeenDepth.T_world_from_cam", "world")
        check_array(self.depth_m, "SeenDepth.depth_m", shape=self.intrinsics.shape, dtype=("float", "int"))
        check_array(self.known, "SeenDepth.known", shape=self.intrinsics.shape, dtype="bool")


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
    #: pixels refused by the viewpoint rule (``view_ratio``): a same-surface sample from too far
    #: out; they are not in ``taken``.
    kept_view: int = 0
    #: pixels refused by the HDR clip rule: a clipped sample of the surface an unclipped colour
    #: holds (``clipped`` of :func:`update`); they are not in ``taken``.
    kept_clipped: int = 0


#: atan(x)/x ≈ P(x²) on [0, 1]: a degree-8 Chebyshev fit, max error of atan 1.2e-8 rad (an EM pixel


def _update_scratch(em: EnvironmentMap, n_samples: int = 0) -> tuple[np.ndarray, ...]:
    """The scratch of :func:`update`, kept in ``em.scratch``, allocated on the first update (maps
    made by ``translate`` or ``copy`` for viewing never need it) and grown to ``n_samples``: the
    z-buffer, one band of 2**BAND_SHIFT rows of int64 keys (flat), EMPTY_Z between updates; its flat
    uint8 map of touched 32-column tiles, all clear between updates (each update resets what it
    touched); and per-sample footprint records (n, 4) int32, keys (n,) int64 and band lists (2n,)
    int32 (fresh buffers of these sizes cost page faults on every update)."""
    scratch = em.scratch.get("update")
    if scratch is None:
        rows = min(1 << kernels.BAND_SHIFT, em.height)
        n_tiles = (em.width + (1 << kernels.TILE_SHIFT) - 1) >> kernels.TILE_SHIFT
        scratch = (np.full(rows * em.width, kernels.EMPTY_Z, np.int64), np.zeros(rows * n_tiles, np.uint8),
                   np.empty((0, 4), np.int32), np.empty(0, np.int64), np.empty(0, np.int32))
    if len(scratch[2]) < n_samples:
        n = max(n_samples, 2 * len(scratch[2]))
        scratch = (*scratch[:2], np.empty((n, 4), np.int32), np.empty(n, np.int64), np.empty(2 * n, np.int32))
    em.scratch["update"] = scratch
    return scratch


def _second_thread_scratch(em: EnvironmentMap, log_capacity: int) -> tuple[np.ndarray, np.ndarray, ChangeLog]:
    """The second part's z-buffer band, tile flags and change log (as long as the map's, or empty
    when the map is not recording): the update kernel splits the map's bands in two parts."""
    zband, tiles = _update_scratch(em)[:2]
    scratch = em.scratch.get("update_2t")
    if scratch is None:
        scratch = (np.full_like(zband, kernels.EMPTY_Z), np.zeros_like(tiles), _NO_LOG)
    if scratch[2].capacity != log_capacity:
        scratch = (*scratch[:2], _NO_LOG if log_capacity == 0 else ChangeLog(log_capacity))
    em.scratch["update_2t"] = scratch
    return scratch


_NO_LOG = ChangeLog(0)  # passed to the kernel when the map is not recording


def update(
    em: EnvironmentMap,
    points_world: np.ndarray,
    colours: np.ndarray,
    device_position: np.ndarray,
    focal_px: float,
    config: UpdateConfig = UpdateConfig(),
    fill_only: np.ndarray | None = None,
    seen: SeenDepth | None = None,
    *,
    clipped: np.ndarray | None = None,
    threads: int = 2,
) -> UpdateStats:
    """Project (N, 3) world points with (N, 3) reference-space linear colours into ``em`` in place.

    ``device_position`` (3,) is the sensor's world position at capture; ``focal_px`` its focal length
    in pixels (sets the footprint). ``fill_only`` (N,) bool marks samples the "closer" rule does not
    apply to (they still fill empty pixels and obey the trusted-sphere and removal rules; see
    :class:`rgbd_envmap.capture.CaptureConfig.edge_margin_px`). ``seen``: the frame's measured depth,
    for free-space carving (``config.carve``; without it no pixel is freed). ``clipped``: (N,) bool,
    the samples with a channel at the camera's clip level (HDR capture, docs/design/hdr.md): such a
    sample never overwrites an unclipped colour of the same surface (counted ``kept_clipped``), over
    a clipped colour it keeps the larger value per channel, and an unclipped sample replaces a
    clipped colour (the map keeps per-pixel flags, :func:`clip_flags`, once any update passed
    ``clipped``; None: no sample is clipped). ``threads``: 1 or 2 (more
    are used as 2, and 2 as 1 where numba has one thread); the map, counts and change log are the
    same bit for bit. Returns what the update did.
    The first update allocates the map's scratch: a z-buffer of 16 map rows (256 KB at 2000×1000)
    and per-sample buffers (about 40 bytes a sample), grown to the largest frame.

    Raises:
        RangeError: ``focal_px`` not positive and finite while splatting.
        InvalidInputError: more than 2³⁰ points.
    """
    check_map(em, writable=True)
    if not isinstance(config, UpdateConfig):
        raise DTypeError(f"config: expected an UpdateConfig, got {type(config).__name__}")
    if seen is not None and not isinstance(seen, SeenDepth):
        raise DTypeError(f"seen: expected a SeenDepth or None, got {type(seen).__name__}")
    check_positive_int(threads, "threads")
    focal_px = check_number(focal_px, "focal_px")
    pts = check_array(points_world, "points_world", shape=("N", 3), dtype="float").astype(np.float64, copy=False)
    col = check_array(colours, "colours", shape=(pts.shape[0], 3), dtype="float").astype(np.float32, copy=False)
    dev = check_array(device_position, "device_position", shape=(3,), dtype="float", finite=True).astype(np.float64)
    if config.splat and not 0.0 < float(focal_px) < math.inf:
        raise RangeError(f"focal_px: expected a positive finite focal length in pixels, got {focal_px}")
    # Non-finite points or colours are skipped inside the kernel (cheaper than a numpy pre-pass).
    if len(pts) > kernels.INDEX_MAX + 1:
        raise InvalidInputError(f"points_world: expected at most {kernels.INDEX_MAX + 1} points, got {len(pts)}")
    zband, tiles, rec, rec_key, listed = _update_scratch(em, len(pts))
    pts = np.ascontiguousarray(pts)
    flags = np.zeros(len(pts), bool) if fill_only is None else check_array(fill_only, "fill_only", shape=(len(pts),), dtype="bool")
    clip_args = _clip_arrays(em, clipped, len(pts))
    log = _NO_LOG if em.change_log is None else em.change_log
    carve = bool(config.carve) and seen is not None
    cam, seen_depth = _seen_arrays(seen, config) if carve else (_NO_CAM, _NO_SEEN)
    args = (
        pts, np.ascontiguousarray(col), np.ascontiguousarray(flags), em.origin, dev, em.height, em.width,
        float(focal_px), bool(config.splat), float(config.splat_scale), int(config.max_splat_px),
        em.radiance_planes, em.depth_m, em.valid,
        float(config.trusted_radius_m), float(config.removal_radius_m), zband, tiles, rec, rec_key, listed,
        *trig_tables(em.height, em.width), log.idx, log.old, log.was_valid, log.n, carve, cam, seen_depth,
        *_averaging(em, config), *clip_args,
    )
    zband2, tiles2, log2 = _second_thread_scratch(em, log.capacity)
    n_touched, counts, n_logged = parallel_call(kernels.update_kernel, *args, zband2, tiles2, log2.idx, log2.old,
                                                log2.was_valid, threads=threads)
    if log is not _NO_LOG:
        log.n = int(n_logged)
        log.updates += 1
    return UpdateStats(len(pts), int(n_touched), *(int(c) for c in counts))


def _averaging(em: EnvironmentMap, config: UpdateConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernels' (H·W,) uint8 per-pixel average counts, (4,) float64 (colour_average, tolerance
    relative, absolute, view_ratio) and (H·W,) float32 viewpoint distances (:func:`view_distances`);
    a map that never averages, or an update without the viewpoint rule, gets one-entry dummies."""
    n = int(config.colour_average)
    counts = em.colour_counts().reshape(-1) if n > 1 else _NO_AVERAGED
    ratio = float(config.view_ratio)
    views = view_distances(em).reshape(-1) if ratio < math.inf else _NO_VIEWS
    return counts, np.array([n, float(config.carve_tol_rel), float(config.carve_tol_abs_m), ratio], np.float64), views


def _clip_arrays(em: EnvironmentMap, clipped: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """The kernel's (N,) uint8 sample flags, (H·W,) uint8 pixel flags and ``hdr`` switch: on when
    ``clipped`` is given or the map already keeps flags (then a call without it has no clipped
    sample); off: one-entry zero dummies."""
    held = em.scratch.get("clip_flags")
    kept = held is not None and held[0] is em.colour_counts()
    if clipped is None and not kept:
        return _NO_CLIPPED, _NO_CLIPPED, False
    if clipped is None:
        samples = np.zeros(max(n, 1), np.uint8)
    else:
        samples = np.ascontiguousarray(check_array(clipped, "clipped", shape=(n,), dtype="bool")).view(np.uint8)
        samples = samples if n > 0 else np.zeros(1, np.uint8)
    return samples, clip_flags(em).reshape(-1), True


def clip_flags(em: EnvironmentMap) -> np.ndarray:
    """(H, W) uint8: 1 where the pixel's colour came from a clipped sample (a lower bound of its
    radiance; ``clipped`` of :func:`update`), 0 elsewhere. Kept with the map's colour counts, as
    :func:`view_distances`: all 0 whenever they restart (``copy``, ``translate``, ``from_arrays``,
    ``mark_modified``)."""
    counts = em.colour_counts()
    held = em.scratch.get("clip_flags")
    if held is None or held[0] is not counts:
        held = (counts, np.zeros((em.height, em.width), np.uint8))
        em.scratch["clip_flags"] = held
    return held[1]


def view_distances(em: EnvironmentMap) -> np.ndarray:
    """(H, W) float32: per pixel, the nearest distance from the origin of the devices that saw its
    surface (``UpdateConfig.view_ratio``), inf where unknown. Kept with the map's colour counts: it
    starts at inf (any viewpoint acceptable) whenever they restart (``copy``, ``translate``,
    ``from_arrays``, ``mark_modified``)."""
    counts = em.colour_counts()
    held = em.scratch.get("view_distances")
    if held is None or held[0] is not counts:
        held = (counts, np.full((em.height, em.width), np.inf, np.float32))
        em.scratch["view_distances"] = held
    return held[1]


_NO_AVERAGED = np.zeros(1, np.uint8)
_NO_VIEWS = np.full(1, np.inf, np.float32)
_NO_CLIPPED = np.zeros(1, np.uint8)
_NO_CAM = np.zeros(23)
_NO_SEEN = np.zeros((1, 1), np.float32)


@lru_cache(maxsize=8)
def _window(size: int) -> np.ndarray:
    """The structuring element of the carving window (``UpdateConfig.carve_window``)."""
    return np.ones((size, size), np.uint8)



def _seen_arrays(seen: SeenDepth, config: UpdateConfig) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's view of ``seen``: (23,) float64 camera (see ``_is_free`` in the kernels) and (H, W) float32
    depth, 0 where not measured (or not finite)."""
    intr = seen.intrinsics
    if not isinstance(intr, Intrinsics) or not isinstance(seen.T_world_from_cam, RigidTransform):
        raise InvalidInputError("seen: expected Intrinsics and a RigidTransform")
    check_transform(seen.T_world_from_cam, "seen.T_world_from_cam", "world")
    shape = (intr.height, intr.width)
    depth = check_array(seen.depth_m, "seen.depth_m", shape=shape, dtype="float")
    known = check_array(seen.known, "seen.known", shape=shape, dtype="bool")
    for name in ("carve_tol_rel", "carve_tol_abs_m"):
        if not 0.0 <= float(getattr(config, name)) < math.inf:
            raise RangeError(f"UpdateConfig.{name}: expected a finite value ≥ 0, got {getattr(config, name)}")
    # float64 stays float64 (a value beyond float32's range must become inf, as numpy's cast does).
    d = kernels.measured_depth(np.ascontiguousarray(depth, np.float64 if depth.dtype.itemsize > 4 else np.float32),
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


def map_coordinates(points_world: np.ndarray, origin: np.ndarray, height: int, width: int) -> tuple[np.ndarray, ...]:
    """Continuous map coordinates of (N, 3) world points exactly as :func:`update` computes them:
    (N,) float64 row ``v`` and column ``u`` (pixel (row, col) = (⌊v⌋, ⌊u⌋); row 0 at the zenith) and
    distance ``r`` from ``origin`` (a non-finite point gives non-finite coordinates in its own entry;
    :func:`update` drops such points). The update's arctangent is a polynomial within 1.2e-8 rad of
    libm's, so a point that close to a pixel edge may land next door compared with
    :func:`rgbd_envmap.geometry.directions_to_equirect`. Non-finite points give meaningless values."""
    pts = np.ascontiguousarray(check_array(points_world, "points_world", shape=("N", 3), dtype="float"), np.float64)
    o = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    h, w = check_positive_int(height, "height"), check_positive_int(width, "width")
    n = len(pts)
    bx, by, bz, bv, bu, br = (np.empty(max(n, 1)) for _ in range(6))
    kernels.block_coords(pts, 0, n, o[0], o[1], o[2], h / math.pi, w / (2 * math.pi), bx, by, bz, bv, bu, br)
    return bv[:n].copy(), bu[:n].copy(), br[:n].copy()
