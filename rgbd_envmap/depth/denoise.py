"""Edge-aware depth denoising: a local plane fit of inverse depth (a departure from paper 003).

The ToF's range noise (about 1 % of the distance) is what leaves most of the map's error
(docs/studies/em_error_study.md): a table sample lifted by 7 mm moves up ~10 map rows as seen from an origin
5 cm above the table, wins "closer" over the panel behind, and stays. Averaging neighbouring samples
of the same surface removes most of that noise before anything is projected.

For a plane seen by a pinhole camera, inverse depth is affine in the normalised image coordinates:
a plane n·X = d gives 1/z = (n_x x + n_y y + n_z) / d at the ray (x, y, 1). So at every measured
pixel the denoiser fits 1/z = a·x + b·y + c by least squares over the measured pixels of its
(2h+1)² window whose depth lies within ``tol_rel`` of the centre's (the edge-aware part: the other
side of a depth edge is left out), and evaluates the fit at the centre. A plane is reproduced
exactly, curved surfaces to second order over the window. With fewer than ``min_inliers`` inliers
(or a degenerate window) the pixel keeps its measurement.

On the default session the measured pixels' depth error falls from 1.00 % to 0.22 % of the distance
(robust σ; docs/studies/em_error_study.md, "depth denoised, plane fit of 1/z, 5×5").

The fit runs in numba kernels (:mod:`rgbd_envmap._kernels.denoise`): a general one for any window
and two specialisations for the 3×3 and 5×5 windows the pipeline uses, bit for bit the general one's
result (tested). :func:`rgbd_envmap.reference.denoise.plane_fit_reference` is the same fit written
with numpy's least squares, one pixel at a time.

References:
    Monroy, Hudon, Smolic (2018), §4 (the depth that feeds the map; no denoising there).
    Hartley & Zisserman (2004), Multiple View Geometry, §8 (planes and homographies: 1/z affine in
    image coordinates for a plane).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import denoise as kernels
from rgbd_envmap.checks import check_array, check_instance, check_number, check_positive_int
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Intrinsics, RGBDFrame

__all__ = ["denoise_depth", "denoise_frame"]


@lru_cache(maxsize=8)
def _ray_planes(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 x and y of the normalised rays (distortion removed), cached per camera."""
    rays = pixel_rays(intrinsics)
    rx, ry = np.ascontiguousarray(rays[..., 0], np.float32), np.ascontiguousarray(rays[..., 1], np.float32)
    rx.setflags(write=False)
    ry.setflags(write=False)
    return rx, ry


@lru_cache(maxsize=8)
def _padded_ray_planes(intrinsics: Intrinsics, pad: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_ray_planes` padded by ``pad`` pixels (zeros; only ever weighted by m = 0) for
    the 3×3 (1) and 5×5 (2) kernels, cached per camera."""
    rx, ry = _ray_planes(intrinsics)
    rxp, ryp = np.pad(rx, pad), np.pad(ry, pad)
    rxp.setflags(write=False)
    ryp.setflags(write=False)
    return rxp, ryp


def denoise_depth(depth_m: np.ndarray, known: np.ndarray, intrinsics: Intrinsics, *, half_window: int = 2,
                  tol_rel: float = 0.04, min_inliers: int = 6) -> np.ndarray:
    """Edge-aware plane-fit denoising of a z-depth image (see the module docstring).

    Args:
        depth_m: (H, W) float z-depth in metres (along the optical axis).
        known: (H, W) bool, the measured pixels. Pixels not known, or with a non-finite or
            non-positive depth, are neither fitted nor used.
        intrinsics: the depth image's camera (``pixel_rays`` gives the normalised rays, distortion
            included).
        half_window: h of the (2h+1)² window (2: 5×5, the measured best; 1 and 3 were worse).
        tol_rel: a neighbour is an inlier when its depth is within ``tol_rel`` × the centre's.
        min_inliers: fewer inliers (centre included) keep the measured depth; at least 3.

    Returns:
        (H, W) float32 depth: fitted at known pixels with enough inliers, the input elsewhere.

    Raises:
        ShapeError / DTypeError: bad arrays. RangeError: bad parameters, or intrinsics of another
        image size.
    """
    z = check_array(depth_m, "depth_m", shape=("H", "W"), dtype=("float", "int"))
    k = check_array(known, "known", shape=z.shape, dtype="bool")
    half, tol, min_in = _check_parameters(z.shape, intrinsics, half_window, tol_rel, min_inliers)
    return _denoise(z, k, intrinsics, half, tol, min_in, False)


def _check_parameters(shape: tuple[int, ...], intrinsics: Intrinsics, half_window: int, tol_rel: float,
                      min_inliers: int) -> tuple[int, float, float]:
    """(half window, tolerance, minimum inliers as a float) after the checks of :func:`denoise_depth`."""
    check_instance(intrinsics, Intrinsics, "intrinsics")
    half = check_positive_int(half_window, "half_window")
    min_in = check_positive_int(min_inliers, "min_inliers")
    if min_in < 3:
        raise RangeError(f"min_inliers: a plane needs at least 3 points, got {min_in}")
    tol_rel = check_number(tol_rel, "tol_rel", low=0.0, high=1.0, low_open=True, high_open=True)
    if (intrinsics.height, intrinsics.width) != shape:
        raise RangeError(f"intrinsics: expected a {shape[0]}×{shape[1]} camera for this depth image, got "
                         f"{intrinsics.height}×{intrinsics.width}")
    return half, float(tol_rel), float(min_in)


def _denoise(z: np.ndarray, k: np.ndarray, intrinsics: Intrinsics, half: int, tol_rel: float, min_in: float,
             zero_unknown: bool) -> np.ndarray:
    """:func:`denoise_depth` after its checks; ``zero_unknown``: 0 at the pixels not ``k``.

    The 3×3 and 5×5 windows of float32 depth (every frame of the pipeline) take their own kernels,
    bit for bit the general kernel's result (tested); any other window or dtype the general kernel, whose
    float64 → float32 preparation is kept as it is (a float64 depth that over- or underflows float32
    is a measured pixel there)."""
    if half in (1, 2) and z.dtype == np.float32:
        rxp, ryp = _padded_ray_planes(intrinsics, half)
        kernel = kernels.plane_fit_3x3 if half == 1 else kernels.plane_fit_5x5
        return kernel(np.ascontiguousarray(z), np.ascontiguousarray(k), zero_unknown, rxp, ryp, tol_rel, min_in, 0.0)
    z64 = z.astype(np.float64)
    with np.errstate(invalid="ignore"):
        ok = k & np.isfinite(z64) & (z64 > 0.0)
    out = z.astype(np.float32)  # a copy
    rx, ry = _ray_planes(intrinsics)
    kernels.plane_fit_rows(np.where(ok, z64, 1.0).astype(np.float32), ok, rx, ry, half, tol_rel, min_in, out)
    if zero_unknown:
        out[~k] = 0.0
    return out


def denoise_frame(frame: RGBDFrame, *, half_window: int = 2, tol_rel: float = 0.04, min_inliers: int = 6) -> RGBDFrame:
    """``frame`` with its known pixels' depth replaced by :func:`denoise_depth`'s; colours, mask and
    pose unchanged. The colour of a pixel was looked up at the measured point; the fit moves the
    point along its ray by about 1 % of its depth, which shifts it in the colour image by ~1 % of the
    depth-to-colour parallax (a few hundredths of a pixel), so it is not looked up again.

    The denoised depth goes into a new frame by :meth:`RGBDFrame.with_depth`, which shares the
    input's read-only colours and mask (the constructor would check and copy all three arrays,
    which costs more than the fit of a small frame).
    """
    if not isinstance(frame, RGBDFrame):
        raise InvalidInputError(f"frame: expected an RGBDFrame, got {type(frame).__name__}")
    half, tol, min_in = _check_parameters(frame.depth_m.shape, frame.intrinsics, half_window, tol_rel, min_inliers)
    depth = _denoise(frame.depth_m, frame.known, frame.intrinsics, half, tol, min_in, True)
    depth.setflags(write=False)  # ours alone: with_depth then keeps it without a copy
    return frame.with_depth(depth)
