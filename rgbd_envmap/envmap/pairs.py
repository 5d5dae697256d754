"""Colour pairs and frame samples (paper 003 §5.2): what a frame and the map share.

A frame's reliable pixels, placed in the world, fall into map pixels; where the map has data at
(nearly) the same distance, the frame's colour and the map's colour form a *pair* for fitting the
colour-correction matrix (:mod:`rgbd_envmap.colour`). :func:`collect_pairs` is the plain form (world
points in, pairs out); :func:`frame_pairs` and :func:`frame_pair_sums` do the same from a depth
image in one pass (the latter reduces the pairs straight to the fit's normal-equation sums);
:func:`frame_points` and :func:`frame_samples` give the frame's samples for :func:`update`.
The numpy spec is in :mod:`rgbd_envmap.reference.envmap`.

References:
    Monroy, Hudon, Smolic (2018), §5.2.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels import envmap_pairs as kernels
from rgbd_envmap._kernels.parallel import parallel_call
from rgbd_envmap.checks import check_array, check_number, check_positive_int
from rgbd_envmap.envmap.map import EnvironmentMap, check_map
from rgbd_envmap.errors import DTypeError, InvalidInputError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics, RigidTransform, check_transform

__all__ = ["collect_pairs", "frame_points", "frame_pairs", "frame_pair_sums", "frame_samples"]


def _check_camera(intrinsics: object, T_world_from_cam: object) -> None:
    """The frame's camera: Intrinsics and a RigidTransform into the world frame."""
    if not isinstance(intrinsics, Intrinsics):
        raise DTypeError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    if not isinstance(T_world_from_cam, RigidTransform):
        raise DTypeError(f"T_world_from_cam: expected a RigidTransform, got {type(T_world_from_cam).__name__}")
    check_transform(T_world_from_cam, "T_world_from_cam", "world")  # unnamed frames are taken as they come


def _check_max_diff(value: object) -> float:
    return float(check_number(value, "max_depth_diff_m", low=0.0))


def _frame_pair_inputs(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                       T_world_from_cam: RigidTransform, rgb: np.ndarray) -> tuple:
    """The checked arguments of the frame pair kernels up to the map's arrays."""
    check_map(em)
    _check_camera(intrinsics, T_world_from_cam)
    shape = intrinsics.shape
    depth = check_array(depth_m, "depth_m", shape=shape, dtype="float")
    ok = check_array(mask, "mask", shape=shape, dtype="bool")
    colours = check_array(rgb, "rgb", shape=(*shape, 3), dtype="float")
    if colours.dtype != np.float32:  # collect_pairs keeps the colours' values; float32 is what frames hold
        raise InvalidInputError(f"rgb: expected float32, got {colours.dtype}")
    return (np.ascontiguousarray(depth), np.ascontiguousarray(ok), pixel_rays(intrinsics),
            np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation),
            np.ascontiguousarray(colours), em.origin, em.height, em.width, em.depth_m, em.valid, em.radiance_planes)


def frame_pairs(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                 T_world_from_cam: RigidTransform, rgb: np.ndarray, max_depth_diff_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """``collect_pairs(em, frame_points(depth_m, mask, …), rgb[mask], max_depth_diff_m)`` in one pass
    over the frame (identical pairs, without the boolean gathers)."""
    args = _frame_pair_inputs(em, depth_m, mask, intrinsics, T_world_from_cam, rgb)
    return kernels.frame_pairs_kernel(*args, _check_max_diff(max_depth_diff_m))


def frame_pair_sums(em: EnvironmentMap, depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics,
                     T_world_from_cam: RigidTransform, rgb: np.ndarray, max_depth_diff_m: float = 0.01,
                     saturation: float = 1.0, threads: int = 1) -> tuple[np.ndarray, np.ndarray, float, int, int, int, int]:
    """The pairs of :func:`frame_pairs` reduced, in the same pass, to the colour fit's
    normal-equation sums: ``(AᵀA, AᵀB, tr(BᵀB), kept, non-finite, saturated, pairs)``, bit for bit
    what :func:`rgbd_envmap.colour.ccm_sums` gives for those pairs (same values, same order).
    No pair array is written or read back. ``threads``: 1 or 2, the same result bit for bit."""
    check_positive_int(threads, "threads")
    args = _frame_pair_inputs(em, depth_m, mask, intrinsics, T_world_from_cam, rgb)
    sums, counts = np.zeros(16), np.zeros(3, np.int64)
    saturation = check_number(saturation, "saturation", low=0.0, low_open=True)
    k = parallel_call(kernels.frame_pair_sums_kernel, *args, _check_max_diff(max_depth_diff_m), sums, counts, saturation,
                      threads=threads)
    ata = sums[[0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(3, 3)
    return ata, sums[6:15].reshape(3, 3).copy(), float(sums[15]), int(counts[0]), int(counts[1]), int(counts[2]), int(k)


def collect_pairs(
    em: EnvironmentMap, points_world: np.ndarray, colours: np.ndarray, max_depth_diff_m: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Colour pairs (paper §5.2): for (N, 3) world points of *reliable* frame pixels with their (N, 3)
    current-space colours, the EM pixel each falls in; a pair is kept where the EM has data whose
    depth differs by at most ``max_depth_diff_m``. Returns (src (M, 3) float32 frame colours, dst
    (M, 3) float32 EM colours in the reference space), in the order of the points. A non-finite point
    falls in no pixel and gives no pair; non-finite colours are passed through as they are (the colour
    fit drops such pairs and counts them, :func:`rgbd_envmap.colour.ccm_sums`)."""
    check_map(em)
    max_diff = _check_max_diff(max_depth_diff_m)
    pts = check_array(points_world, "points_world", shape=("N", 3), dtype="float").astype(np.float64, copy=False)
    col = check_array(colours, "colours", shape=(pts.shape[0], 3), dtype="float")
    n = len(pts)
    src, dst = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    k = kernels.pairs_kernel(np.ascontiguousarray(pts), np.ascontiguousarray(col), em.origin, em.height, em.width, em.depth_m,
                      em.valid, em.radiance_planes, max_diff, src, dst)
    return src[:k], dst[:k]


def frame_points(depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, T_world_from_cam: RigidTransform) -> np.ndarray:
    """(M, 3) float64 world points of the ``mask`` pixels of a z-depth image, in raster order. A
    non-finite depth gives a non-finite point in its own row (:func:`update` skips such samples)."""
    _check_camera(intrinsics, T_world_from_cam)
    depth_m = check_array(depth_m, "depth_m", shape=intrinsics.shape, dtype="float")
    mask = check_array(mask, "mask", shape=intrinsics.shape, dtype="bool")
    return kernels.world_points(np.ascontiguousarray(depth_m), np.ascontiguousarray(mask), pixel_rays(intrinsics),
                         np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation))



def frame_samples(depth_m: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, T_world_from_cam: RigidTransform,
                   rgb: np.ndarray, flag: np.ndarray | None = None,
                   matrix: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples of the ``mask`` pixels of an RGB-D frame, in raster order: (M, 3) float64 world
    points (exactly :func:`frame_points`), (M, 3) float32 colours ``rgb[mask]`` (corrected by
    ``matrix`` when given: ``rgb[mask] @ matrix.T`` in float32, as
    :func:`rgbd_envmap.colour.apply_ccm` computes it up to rounding) and (M,) bool ``flag[mask]`` (all False when ``flag`` is None). One pass over
    the frame instead of numpy's boolean gathers.

    Args:
        depth_m: (H, W) float z-depth in metres; mask: (H, W) bool; rgb: (H, W, 3) float linear RGB;
        flag: (H, W) bool or uint8 (non-zero is True), or None; matrix: (3, 3) finite, or None.
        A non-finite depth or colour is passed through into its own sample (:func:`update` skips
        such samples).
    """
    _check_camera(intrinsics, T_world_from_cam)
    shape = intrinsics.shape
    depth = check_array(depth_m, "depth_m", shape=shape, dtype="float")
    ok = check_array(mask, "mask", shape=shape, dtype="bool")
    colours = check_array(rgb, "rgb", shape=(*shape, 3), dtype="float")
    flags = np.zeros(shape, np.uint8) if flag is None else check_array(flag, "flag", shape=shape, dtype=("bool", np.uint8))
    m = np.eye(3, dtype=np.float32) if matrix is None else check_array(matrix, "matrix", shape=(3, 3), dtype="float", finite=True)
    return kernels.frame_samples_kernel(np.ascontiguousarray(depth), np.ascontiguousarray(ok), pixel_rays(intrinsics),
                           np.ascontiguousarray(T_world_from_cam.rotation), np.ascontiguousarray(T_world_from_cam.translation),
                           np.ascontiguousarray(colours, dtype=np.float32), np.ascontiguousarray(flags).view(np.uint8),
                           np.ascontiguousarray(m, dtype=np.float32), matrix is not None)
