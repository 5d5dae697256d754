"""Geometry: camera projection with Brown distortion, SE(3) helpers and the equirectangular mapping.

Conventions (docs/reference/conventions.md):

* Camera frames are OpenCV (x right, y down, z forward); pixel centres at integer coordinates.
  Focal lengths are signed (``Intrinsics``): u = fx·x′ + cx, v = fy·y′ + cy hold as written, so
  projection, unprojection and the Newton undistortion (which works on x′, y′ alone) need no case
  for fy < 0 (ICL-NUIM's y-up camera frame).
* World frame is right-handed with z up.
* Equirectangular maps have shape (H, W), W = 2H. Pixel (row v, column u) has its centre at polar
  angle θ = π (v + 0.5) / H from +z and azimuth φ = 2π (u + 0.5) / W − π from +x towards +y;
  d = (sin θ cos φ, sin θ sin φ, cos θ). Row 0 is the zenith. Continuous (u, v) coordinates put pixel
  centres at integers, like camera images, so ``round`` gives the pixel index (the column wraps).

References:
    Brown, D. C. (1966). Decentering distortion of lenses. (OpenCV's k1, k2, p1, p2, k3 model.)
    Monroy, Hudon, Smolic (2018). Dynamic Environment Mapping for AR on Mobile Devices, §4.1, §6.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np

from rgbd_envmap.checks import check_array, check_instance, check_number, check_positive_int
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.types import Distortion, Intrinsics, RigidTransform, check_transform

__all__ = [
    "brown_distort",
    "distort_normalized",
    "undistort_normalized",
    "project_points",
    "unproject_pixels",
    "pixel_rays",
    "look_at",
    "opengl_from_opencv",
    "equirect_directions",
    "equirect_solid_angles",
    "directions_to_equirect",
    "equirect_to_directions",
    "equirect_pixel_index",
]

#: Axis flip between OpenCV (x right, y down, z forward) and OpenGL (x right, y up, z backward) cameras.
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@numba.njit(cache=True)
def brown_distort(x, y, k1, k2, p1, p2, k3):  # pragma: no cover - compiled
    """Brown's model on one normalised point (x, y) = (X/Z, Y/Z), for numba kernels: the distorted
    (x, y). :func:`distort_normalized` is the array version (same formula)."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def distort_normalized(xy: np.ndarray, distortion: Distortion) -> np.ndarray:
    """Apply Brown distortion to (..., 2) normalised image coordinates (x/z, y/z), OpenCV's model.
    A non-finite coordinate gives non-finite values in its own row only."""
    xy = check_array(xy, "xy", shape=("*", 2), dtype=("float", "int")).astype(np.float64)
    check_instance(distortion, Distortion, "distortion")
    if distortion.is_zero:
        return xy.copy()
    k1, k2, p1, p2, k3 = distortion.coefficients
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_normalized(xy_distorted: np.ndarray, distortion: Distortion, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort_normalized` for (..., 2) coordinates by Newton's method with the
    analytic Jacobian (converges to ~1e-15 in a few steps for lens-like coefficients; OpenCV's
    ``undistortPoints`` uses a fixed-point iteration that stops at ~1e-6). A non-finite coordinate
    gives non-finite values in its own row only; ``iterations`` is an integer in [0, 1000]."""
    target = check_array(xy_distorted, "xy_distorted", shape=("*", 2), dtype=("float", "int")).astype(np.float64)
    check_instance(distortion, Distortion, "distortion")
    iterations = check_number(iterations, "iterations", low=0, high=1000, integer=True)
    if distortion.is_zero or target.size == 0:
        return target.copy()
    k1, k2, p1, p2, k3 = distortion.coefficients
    xy = target.copy()
    for _ in range(iterations):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - target[..., 0]
        fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - target[..., 1]
        j11 = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
        j12 = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
        j21 = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
        j22 = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
        det = j11 * j22 - j12 * j21
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (j22 * fx - j12 * fy) / det
            dy = (j11 * fy - j21 * fx) / det
        xy[..., 0] -= dx
        xy[..., 1] -= dy
        if np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) < 1e-15:
            break
    return xy


def project_points(points_cam: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) camera-frame points to pixel coordinates with distortion.

    Returns:
        uv: (N, 2) float64 pixel coordinates (column, row), pixel centres at integers; NaN where not
            ``in_front``.
        in_front: (N,) bool, True where z > 0 and the point is finite.
    """
    p = check_array(points_cam, "points_cam", shape=("N", 3), dtype=("float", "int")).astype(np.float64)
    check_instance(intrinsics, Intrinsics, "intrinsics")
    z = p[:, 2]
    in_front = np.isfinite(p).all(axis=1) & (z > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = p[:, :2] / z[:, None]
    xy[~in_front] = np.nan
    xyd = distort_normalized(xy, intrinsics.distortion)
    uv = np.empty_like(xyd)
    uv[:, 0] = intrinsics.fx * xyd[:, 0] + intrinsics.cx
    uv[:, 1] = intrinsics.fy * xyd[:, 1] + intrinsics.cy
    return uv, in_front


def unproject_pixels(uv: np.ndarray, depth_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Lift (N, 2) pixel coordinates with (N,) z-depths (metres) to (N, 3) camera-frame points. A
    non-finite coordinate or depth gives non-finite values in its own row only."""
    check_instance(intrinsics, Intrinsics, "intrinsics")
    uv = check_array(uv, "uv", shape=("N", 2), dtype=("float", "int")).astype(np.float64)
    z = check_array(depth_m, "depth_m", shape=(uv.shape[0],), dtype=("float", "int")).astype(np.float64)
    xyd = np.stack([(uv[:, 0] - intrinsics.cx) / intrinsics.fx, (uv[:, 1] - intrinsics.cy) / intrinsics.fy], axis=-1)
    xy = undistort_normalized(xyd, intrinsics.distortion)
    return np.concatenate([xy * z[:, None], z[:, None]], axis=1)


@lru_cache(maxsize=16)
def _pixel_rays_cached(intrinsics: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64), np.arange(intrinsics.height, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], axis=-1)
    rays = unproject_pixels(uv, np.ones(len(uv)), intrinsics).reshape(intrinsics.height, intrinsics.width, 3)
    rays.setflags(write=False)
    return rays


def pixel_rays(intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) float64 camera-frame rays through each pixel centre, scaled to z = 1 (so a z-depth
    times the ray is the point). Cached per intrinsics; the array is read-only."""
    check_instance(intrinsics, Intrinsics, "intrinsics")
    return _pixel_rays_cached(intrinsics)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> RigidTransform:
    """``T_world_from_cam`` of an OpenCV camera at ``eye`` looking at ``target`` with world ``up``
    pointing towards the image top."""
    eye = check_array(eye, "eye", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    target = check_array(target, "target", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    up = check_array(up, "up", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    forward = target - eye
    n = np.linalg.norm(forward)
    if n < 1e-12:
        raise InvalidInputError(f"target: expected a point other than eye, got {target} (eye {eye})")
    forward /= n
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise InvalidInputError(f"up: expected a direction not parallel to target − eye, got {up}")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return RigidTransform.from_rt(np.stack([right, down, forward], axis=1), eye, "world", "cam")


def opengl_from_opencv(T_world_from_cam: RigidTransform) -> RigidTransform:
    """The same camera pose with OpenGL camera axes (x right, y up, looking down −z), as rasterisers
    such as pyrender expect."""
    check_transform(T_world_from_cam, "T_world_from_cam", "world")
    return RigidTransform(T_world_from_cam.matrix @ _CV_TO_GL, T_world_from_cam.dst, "cam_gl")


#: the most pixels an equirect table is made for (8192 × 4096, the largest map the library makes).
MAX_EQUIRECT_PIXELS = 8192 * 4096


def _check_equirect_size(height: int, width: int) -> tuple[int, int]:
    height = check_positive_int(height, "height")
    width = check_positive_int(width, "width")
    if height * width > MAX_EQUIRECT_PIXELS:
        raise RangeError(f"height × width: {height}×{width} directions would take about "
                         f"{height * width * 12 / 2**30:.1f} GiB; at most {MAX_EQUIRECT_PIXELS:,} pixels (e.g. 8192×4096)")
    return height, width


@lru_cache(maxsize=8)
def _equirect_directions_cached(height: int, width: int) -> np.ndarray:
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    st = np.sin(theta)[:, None]
    d = np.empty((height, width, 3), dtype=np.float32)
    d[..., 0] = st * np.cos(phi)[None, :]
    d[..., 1] = st * np.sin(phi)[None, :]
    d[..., 2] = np.cos(theta)[:, None]
    d.setflags(write=False)
    return d


def equirect_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) float32 unit directions at equirect pixel centres (cached, read-only)."""
    return _equirect_directions_cached(*_check_equirect_size(height, width))


@lru_cache(maxsize=8)
def _equirect_solid_angles_cached(height: int, width: int) -> np.ndarray:
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    row = (2.0 * np.pi / width) * (edges[:-1] - edges[1:])
    out = np.repeat(row[:, None], width, axis=1)
    out.setflags(write=False)
    return out


def equirect_solid_angles(height: int, width: int) -> np.ndarray:
    """(H, W) float64 exact solid angle of each pixel, (2π/W)(cos θ_top − cos θ_bottom); sums to 4π.
    Cached, read-only."""
    return _equirect_solid_angles_cached(*_check_equirect_size(height, width))


def directions_to_equirect(dirs: np.ndarray, height: int, width: int) -> np.ndarray:
    """Map (..., 3) directions (any non-zero length) to (..., 2) float64 continuous (u, v) pixel
    coordinates, pixel centres at integers: u ∈ [−0.5, W − 0.5), v ∈ [−0.5, H − 0.5].

    Zero or non-finite directions give NaN. The length of a direction does not matter.
    """
    height, width = _check_equirect_size(height, width)
    d = check_array(dirs, "dirs", shape=("*", 3), dtype=("float", "int")).astype(np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    # arctan2 of (hypot, z) does not depend on the vector's length (no overflow at 1e170, no
    # underflow at 1e-170) and stays accurate near the poles, where arccos(z / |d|) loses digits.
    theta = np.arctan2(np.hypot(x, y), z)
    phi = np.arctan2(y, x)
    u = np.mod((phi + np.pi) * (width / (2.0 * np.pi)), width) - 0.5
    v = theta * (height / np.pi) - 0.5
    uv = np.stack([u, v], axis=-1)
    usable = np.isfinite(d).all(axis=-1) & np.any(d != 0.0, axis=-1)
    uv[~usable] = np.nan
    return uv


def equirect_to_directions(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """Inverse of :func:`directions_to_equirect`: (..., 2) (u, v) → (..., 3) float64 unit directions;
    a non-finite (u, v) gives a non-finite direction in its own row only."""
    height, width = _check_equirect_size(height, width)
    uv = check_array(uv, "uv", shape=("*", 2), dtype=("float", "int")).astype(np.float64)
    theta = np.pi * (uv[..., 1] + 0.5) / height
    phi = 2.0 * np.pi * (uv[..., 0] + 0.5) / width - np.pi
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def equirect_pixel_index(dirs: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (row, column) containing each (..., 3) direction.

    Returns ``(rows, cols, valid)``: int64 arrays with the column wrapped into [0, W) and the row
    clamped to [0, H − 1] (directions exactly at a pole land in the pole row); ``valid`` is False for
    zero or non-finite directions, whose row and column are 0.
    """
    uv = directions_to_equirect(dirs, height, width)
    valid = np.isfinite(uv).all(axis=-1)
    uv = np.where(valid[..., None], uv, 0.0)
    cols = np.floor(uv[..., 0] + 0.5).astype(np.int64) % width
    rows = np.clip(np.floor(uv[..., 1] + 0.5).astype(np.int64), 0, height - 1)
    return rows, cols, valid
