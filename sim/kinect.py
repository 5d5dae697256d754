"""Kinect-like structured-light RGB-D camera: 640×480 depth registered to colour at 30 Hz.

Geometry. One optical frame for depth and colour (depth registered to colour, as in the TUM RGB-D
benchmark): the TUM default intrinsics fx = fy = 525, cx = 319.5, cy = 239.5, no distortion. The
trajectory moves this camera. The IR projector sits ``projector_baseline_m`` = 7.5 cm along the
camera's +x axis.

Depth model, per pixel, in this order (each cause sets a bit of :data:`DROPOUT_BITS`; a pixel is
``known`` when no bit is set):

1. Lateral noise (Nguyen et al. 2012, eq. 7): σ_L(θ) = 0.8 + 0.035 θ / (π/2 − θ) px, θ the incidence
   angle. A correlation-window sensor shows it only where the window straddles a depth edge (on a smooth
   surface the window's disparity is that of its centre), so pixels within 2 px of a discontinuity take
   the surface seen through a pixel offset by round(N(0, σ_L)) in u and v (at most 3 px): edges jitter.
2. Range: true z-depth outside [0.4, 4.5] m, or no surface → ``range`` / ``no_surface``.
3. Depth discontinuities (mixed pixels): a pixel whose 4-neighbour's z differs by more than
   ``edge_rel_jump`` (5 %) of the nearer of the two, or has no surface, is dropped → ``edge``; both
   sides of an edge lose ``edge_hole_px`` pixels.
4. Projector shadow: a ray from the projector to the surface point must reach it (open3d occlusion
   test, ``shadow_tolerance_m`` short of it) and the surface must face the projector → else ``shadow``.
   With the projector on +x, a foreground object's shadow falls on the background beside its −x
   (image-left) edge, opposite the projector.
5. Grazing incidence: dropped with probability rising linearly from 0 at ``grazing_start_deg`` (70°) to 1
   at ``grazing_stop_deg`` (85°), θ the larger of the camera's and the projector's incidence angles.
6. Materials (scene flags): ``dark`` (weak IR return) dropped with probability ``dark_dropout``,
   ``shiny`` with ``shiny_dropout`` plus always inside the specular cone (half-vector of projector and
   camera within ``specular_cone_deg`` of the normal: the pattern saturates), ``emissive`` (IR from
   lamps, sunlit windows swamps the pattern) with ``emissive_dropout``. Draws are i.i.d. per pixel.
7. Axial noise and disparity quantisation: the disparity d = F·b / z (F = ``disparity_focal_px`` = 580 px,
   the IR camera's focal length; b = 7.5 cm; so F·b = 43.5 px·m) gets Gaussian noise, is quantised to
   ``disparity_step_px`` = 1/8 px (Khoshelham & Elberink 2012; Konolige & Mihelich), turned back into
   z = F·b / d and rounded to ``depth_unit_m`` = 1 mm (OpenNI's output unit). The quantisation step in
   depth is Δz = z² · (1/8) / 43.5 m (2.9 mm at 1 m, 26 mm at 3 m, 58 mm at 4.5 m). The Gaussian's σ is
   chosen so that the *total* error (noise + both quantisations, each uniform: Δ²/12) has Nguyen's
   axial σ_z(z, θ) = 0.0012 + 0.0019 (z − 0.4)² m, plus 0.0001 θ² / (√z (π/2 − θ)²) m for θ > 60°
   (Nguyen's eqs. 5–6 were fitted to real residuals, quantisation included). σ_z is 1.9 mm at 1 m and
   14.0 mm at 3 m.

Sentinel: ``depth_m`` is 0 where not ``known`` (as in the TUM PNGs); use ``known``, not the value.

Colour: the same ray cast's radiance goes through the simulated colour camera's exposure (gains from
auto-exposure / auto-white-balance with lag, shot + read noise, sRGB, 8 bits; ``sim.colour_camera``)
at the Kinect's intrinsics, with no distortion and no chroma subsampling (the Kinect delivers RGB).

Cost per 640×480 frame on the 2-core box: one camera ray cast (≈ 45–60 ms through
``SceneRaycaster.cast``), one projector occlusion test (≈ 15–20 ms), ≈ 15 ms of noise and masks, ≈ 5 ms
colour; see ``benchmarks/bench_kinect_sim.py`` for measured figures.

Determinism: frame i draws from ``default_rng([seed, stream, i])`` per stream (depth, colour, tracking),
like ``sim.session``; the colour stream also depends on the auto-exposure state of frame i − 1, so
frames are generated in order. Timestamps are whole microseconds, as in the TUM benchmark.

References:
    Nguyen, Izadi, Lovell, "Modeling Kinect Sensor Noise for Improved 3D Reconstruction and Tracking",
    3DIMPVT 2012 (eqs. 5–7: axial and lateral noise).
    Khoshelham, Elberink, "Accuracy and Resolution of Kinect Depth Data for Indoor Mapping
    Applications", Sensors 12(2), 2012 (disparity d = f b / z, 1/8 px quantisation, Δz ∝ z²).
    Konolige, Mihelich, "Technical description of Kinect calibration" (ROS wiki, 2011): b ≈ 7.5 cm,
    IR focal length ≈ 580 px, disparity in 1/8 px.
    Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012 (registered images,
    default intrinsics).
    Handa et al., "A Benchmark for RGB-D Visual Odometry, 3D Reconstruction and SLAM" (ICL-NUIM), ICRA
    2014 (a simulated Kinect with disparity noise and quantisation).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numba
import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from rgbd_envmap.checks import check_range
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.tum import TUM_DEFAULT_INTRINSICS
from rgbd_envmap.types import Calibration, Distortion, Intrinsics, RigidTransform
from sim.colour_camera import (
    NOISE_BANK_SIZE,
    SRGB8_LUT,
    AutoExposureState,
    ColourCameraConfig,
    expose_quantise,
    noise_bank,
)
from sim.raycast import SceneRaycaster
from sim.scene import FLAG_BITS, Scene
from sim.trajectory import Trajectory

__all__ = ["DROPOUT_BITS", "KinectConfig", "KinectDepthCapture", "KinectFrame", "KinectSimulator",
           "capture_kinect_depth", "nguyen_axial_sigma_m", "nguyen_lateral_sigma_px"]

#: Bit of each reason a depth pixel has no measurement, in :attr:`KinectDepthCapture.dropout`.
DROPOUT_BITS = {"no_surface": 1, "range": 2, "edge": 4, "shadow": 8, "grazing": 16, "dark": 32, "shiny": 64, "emissive": 128}

_DEPTH, _COLOUR, _TRACKING = 1, 2, 3
# Plain int globals, which the numba kernels compile in as constants.
_B_RANGE, _B_SHADOW, _B_GRAZING, _B_DARK, _B_SHINY, _B_EMISSIVE = (
    DROPOUT_BITS[k] for k in ("range", "shadow", "grazing", "dark", "shiny", "emissive"))
_F_EMISSIVE, _F_SHINY, _F_DARK = FLAG_BITS["emissive"], FLAG_BITS["shiny"], FLAG_BITS["dark"]
_FRAMES = ("world", "colour")
_MAX_LATERAL_PX = 3
_LATERAL_ZONE_PX = 2


def _default_colour() -> ColourCameraConfig:
    fx = TUM_DEFAULT_INTRINSICS.fx
    hfov = float(np.degrees(2.0 * np.arctan(TUM_DEFAULT_INTRINSICS.width / 2.0 / fx)))
    return ColourCameraConfig(width=640, height=480, hfov_deg=hfov, distortion=Distortion())


def nguyen_axial_sigma_m(z_m: np.ndarray, theta_rad: np.ndarray | float = 0.0) -> np.ndarray:
    """Nguyen et al. 2012 axial noise σ_z (metres) at z-depth ``z_m`` (metres) and incidence ``theta_rad``.

    σ_z = 0.0012 + 0.0019 (z − 0.4)², plus 0.0001 / √z · θ² / (π/2 − θ)² for θ > 60° (θ clipped at 89°).
    Shapes broadcast; float64.
    """
    z = np.asarray(z_m, dtype=np.float64)
    theta = np.minimum(np.asarray(theta_rad, dtype=np.float64), np.radians(89.0))
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        extra = 0.0001 / np.sqrt(z) * theta**2 / (np.pi / 2 - theta) ** 2
    return sigma + np.where(theta > np.radians(60.0), extra, 0.0)


def nguyen_lateral_sigma_px(theta_rad: np.ndarray | float) -> np.ndarray:
    """Nguyen et al. 2012 lateral noise σ_L in pixels at incidence ``theta_rad`` (clipped at 85°)."""
    theta = np.minimum(np.asarray(theta_rad, dtype=np.float64), np.radians(85.0))
    return 0.8 + 0.035 * theta / (np.pi / 2 - theta)


@dataclass(frozen=True)
class KinectConfig:
    """Kinect (v1, structured light) parameters; defaults as in the module docstring.

    ``colour`` supplies only the colour camera's exposure, noise and AE / AWB settings; the image
    geometry is ``intrinsics`` (its width and height must agree). Use :meth:`with_resolution` for a
    smaller camera (tests).
    """

    intrinsics: Intrinsics = TUM_DEFAULT_INTRINSICS
    rate_hz: float = 30.0
    #: true z-depths outside [min, max] give no measurement (metres).
    min_depth_m: float = 0.4
    max_depth_m: float = 4.5
    #: the IR projector's offset along the camera's +x axis (metres).
    projector_baseline_m: float = 0.075
    #: focal length (px) of the IR camera the disparity is measured in, and the disparity quantum (px).
    disparity_focal_px: float = 580.0
    disparity_step_px: float = 0.125
    #: output depth unit (metres; OpenNI delivers millimetres); None keeps the disparity-quantised value.
    depth_unit_m: float | None = 0.001
    #: Nguyen's axial and lateral noise models; False turns one off (quantisation stays).
    axial_noise: bool = True
    lateral_noise: bool = True
    #: relative z jump to a 4-neighbour that marks a discontinuity, and pixels dropped on each side (0: none).
    edge_rel_jump: float = 0.05
    edge_hole_px: int = 1
    #: the occlusion ray from the projector stops this far short of the surface point (metres).
    shadow_tolerance_m: float = 0.002
    #: incidence angles over which the grazing dropout probability rises from 0 to 1 (degrees).
    grazing_start_deg: float = 70.0
    grazing_stop_deg: float = 85.0
    #: dropout probabilities per material flag; shiny surfaces also drop inside the specular cone.
    dark_dropout: float = 0.8
    shiny_dropout: float = 0.5
    emissive_dropout: float = 0.9
    specular_cone_deg: float = 10.0
    #: white noise on the *reported* pose (true poses stay exact in the ground truth).
    tracking_noise_m: float = 0.0
    tracking_noise_deg: float = 0.0
    colour: ColourCameraConfig = field(default_factory=_default_colour)

    def __post_init__(self) -> None:
        if not isinstance(self.intrinsics, Intrinsics) or not self.intrinsics.distortion.is_zero:
            raise InvalidInputError(f"KinectConfig.intrinsics: expected undistorted Intrinsics, got {self.intrinsics!r}")
        if (self.colour.width, self.colour.height) != (self.intrinsics.width, self.intrinsics.height):
            raise InvalidInputError(f"KinectConfig.colour: size {self.colour.width}×{self.colour.height} differs from the "
                                    f"intrinsics' {self.intrinsics.width}×{self.intrinsics.height}; use with_resolution()")
        if isinstance(self.edge_hole_px, bool) or not isinstance(self.edge_hole_px, (int, np.integer)) or self.edge_hole_px < 0:
            raise RangeError(f"KinectConfig.edge_hole_px: expected an integer >= 0, got {self.edge_hole_px!r}")
        for name in ("rate_hz", "min_depth_m", "disparity_focal_px", "disparity_step_px", "projector_baseline_m", "edge_rel_jump"):
            if not float(getattr(self, name)) > 0:
                raise RangeError(f"KinectConfig.{name}: expected > 0, got {getattr(self, name)}")
        if not self.max_depth_m > self.min_depth_m:
            raise RangeError(f"KinectConfig: expected max_depth_m > min_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        if self.depth_unit_m is not None and not self.depth_unit_m > 0:
            raise RangeError(f"KinectConfig.depth_unit_m: expected > 0 or None, got {self.depth_unit_m}")
        if not 0 <= self.grazing_start_deg < self.grazing_stop_deg <= 90:
            raise RangeError(f"KinectConfig: expected 0 <= grazing_start_deg < grazing_stop_deg <= 90, got "
                             f"{self.grazing_start_deg}, {self.grazing_stop_deg}")
        check_range(np.array([self.dark_dropout, self.shiny_dropout, self.emissive_dropout]), "KinectConfig dropout probabilities", 0.0, 1.0)

    @property
    def fb_px_m(self) -> float:
        """Disparity focal length × baseline: d [px] = fb / z [m]."""
        return self.disparity_focal_px * self.projector_baseline_m

    def with_resolution(self, width: int, height: int) -> KinectConfig:
        """The same sensor at ``width`` × ``height`` (intrinsics scaled, pixel-centre convention kept). The
        disparity model (F, b, quantum) is unchanged, so depth noise and quantisation per metre stay those
        of the full sensor; only the image is coarser."""
        intr = self.intrinsics.scaled(width, height)
        colour = dataclasses.replace(self.colour, width=width, height=height)
        return dataclasses.replace(self, intrinsics=intr, colour=colour)

    def calibration(self) -> Calibration:
        """A ``kinect`` :class:`Calibration`: depth and colour share the intrinsics, identity extrinsics."""
        return Calibration("kinect", self.intrinsics, self.intrinsics, RigidTransform.identity("colour", "depth"),
                           self.rate_hz, self.rate_hz)

    def reported(self, T_true: RigidTransform, rng: np.random.Generator) -> RigidTransform:
        """The pose the device reports for a true pose (tracking noise applied)."""
        if self.tracking_noise_m == 0.0 and self.tracking_noise_deg == 0.0:
            return T_true
        dt = rng.normal(0.0, self.tracking_noise_m, 3)
        drot = Rotation.from_rotvec(rng.normal(0.0, np.radians(self.tracking_noise_deg), 3)).as_matrix()
        return RigidTransform.from_rt(T_true.rotation @ drot, T_true.translation + dt, T_true.dst, T_true.src)


@dataclass(frozen=True)
class KinectDepthCapture:
    """One simulated Kinect depth image with its ground truth; all images (H, W).

    Attributes:
        depth_m: float32 measured z-depth in metres; 0 where not ``known``.
        known: bool, a measurement exists (``dropout == 0``).
        dropout: uint8 OR of :data:`DROPOUT_BITS`, why a pixel has no measurement.
        true_depth_m: float32 true z-depth (0 where not ``true_valid``).
        true_valid: bool, a surface within [min_depth_m, max_depth_m].
        true_normals_cam: (H, W, 3) float32 unit surface normals in the *camera* frame (OpenCV axes),
            facing the camera; zero where no surface.
        object_index: int16 index into ``scene.objects`` (−1 none). flags: uint8 material flag bits.
        radiance: (H, W, 3) float32 true linear radiance seen by each pixel (the colour ground truth).
        source_index: int32 flat index (row * W + col) of the pixel whose surface the measurement
            came from: the pixel itself except where lateral noise moved an edge.

    ``true_*``, ``object_index``, ``flags`` and ``radiance`` describe each pixel's own ray.
    """

    depth_m: np.ndarray
    known: np.ndarray
    dropout: np.ndarray
    true_depth_m: np.ndarray
    true_valid: np.ndarray
    true_normals_cam: np.ndarray
    object_index: np.ndarray
    flags: np.ndarray
    radiance: np.ndarray
    source_index: np.ndarray


@lru_cache(maxsize=4)
def _rays(intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float32 unit camera-frame directions and (N,) float64 their z = 1 ray lengths."""
    rays = pixel_rays(intrinsics).reshape(-1, 3)
    length = np.linalg.norm(rays, axis=1)
    dirs = (rays / length[:, None]).astype(np.float32)
    dirs.setflags(write=False)
    length.setflags(write=False)
    return dirs, length


def _jumps(z: np.ndarray, rel: float) -> np.ndarray:
    """(H, W) bool: a 4-neighbour's z differs by more than ``rel`` × the nearer z (inf = no surface)."""
    out = np.zeros(z.shape, bool)
    with np.errstate(invalid="ignore"):
        for a, b, sa, sb in ((z[:, 1:], z[:, :-1], np.s_[:, 1:], np.s_[:, :-1]), (z[1:], z[:-1], np.s_[1:], np.s_[:-1])):
            jump = np.abs(a - b) > rel * np.minimum(a, b)  # inf − inf is NaN: two misses are no edge
            out[sa] |= jump
            out[sb] |= jump
    return out


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    if radius <= 0:
        return mask
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(mask.view(np.uint8), kernel).view(bool)


def _occluded(raycaster: SceneRaycaster, rays: np.ndarray, t_s: float) -> np.ndarray:
    """(N,) bool: something lies on each (N, 6) ray (origin, direction) for t in [0, 1] (an any-hit
    test, ~3× cheaper than a closest-hit cast). Uses the raycaster's cached BVH for time ``t_s``."""
    bvh, geometry_to_object = raycaster._bvh(t_s)
    if len(rays) == 0 or len(geometry_to_object) == 1:
        return np.zeros(len(rays), bool)
    return bvh.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=1.0).numpy().astype(bool)


@numba.njit(cache=True)
def _projector_rays(sc, dirs_world, dist, normal, cam_minus_proj, projector, tolerance):  # pragma: no cover - compiled
    """Per candidate: the ray (projector, P − projector shortened by ``tolerance``) as (M, 6) float32, so
    t ∈ [0, 1] spans it (test_occlusions takes one scalar tfar), and the cosine between the normal and
    the direction to the projector (> 0 when the surface faces it)."""
    m = sc.shape[0]
    rays = np.empty((m, 6), np.float32)
    cos_proj = np.empty(m, np.float32)
    for i in range(m):
        j = sc[i]
        x = cam_minus_proj[0] + dirs_world[j, 0] * dist[j]
        y = cam_minus_proj[1] + dirs_world[j, 1] * dist[j]
        z = cam_minus_proj[2] + dirs_world[j, 2] * dist[j]
        length = np.sqrt(x * x + y * y + z * z)
        cos_proj[i] = -(normal[j, 0] * x + normal[j, 1] * y + normal[j, 2] * z) / length
        scale = max(length - tolerance, 0.0) / length
        rays[i, 0], rays[i, 1], rays[i, 2] = projector[0], projector[1], projector[2]
        rays[i, 3], rays[i, 4], rays[i, 5] = x * scale, y * scale, z * scale
    return rays, cos_proj


@numba.njit(cache=True)
def _dropouts_and_depth(sc, z, normal, dirs_world, flags, rays, cos_proj, shadow, u, noise, p):  # pragma: no cover - compiled
    """Steps 4–7 of the model per candidate: (M,) uint8 dropout bits and (M,) float32 measured z-depth.

    ``p``: grazing start, stop (rad), dark, shiny, emissive dropout, cos of the specular cone, F·b,
    disparity step, depth unit (0 = none), axial noise on (1) / off (0).
    """
    m = sc.shape[0]
    bits = np.zeros(m, np.uint8)
    out = np.zeros(m, np.float32)
    g0, g1, p_dark, p_shiny, p_emissive, cos_cone, fb, q, unit, axial = p
    half_pi = np.pi / 2.0
    cos_g0 = np.cos(g0)
    cos_60 = 0.5
    for i in range(m):
        j = sc[i]
        b = np.uint8(0)
        if shadow[i]:
            b |= _B_SHADOW
        cos_c = abs(normal[j, 0] * dirs_world[j, 0] + normal[j, 1] * dirs_world[j, 1] + normal[j, 2] * dirs_world[j, 2])
        cos_c = min(cos_c, 1.0)
        cos_min = min(cos_c, abs(cos_proj[i]))
        if cos_min < cos_g0 and u[0, i] < (np.arccos(cos_min) - g0) / (g1 - g0):
            b |= _B_GRAZING
        f = flags[j]
        if (f & _F_DARK) and u[1, i] < p_dark:
            b |= _B_DARK
        if (f & _F_EMISSIVE) and u[3, i] < p_emissive:
            b |= _B_EMISSIVE
        if f & _F_SHINY:
            # Half vector of point → projector and point → camera against the normal.
            lx = rays[i, 3]
            ly = rays[i, 4]
            lz = rays[i, 5]
            ll = np.sqrt(lx * lx + ly * ly + lz * lz)
            hx = -lx / ll - dirs_world[j, 0]
            hy = -ly / ll - dirs_world[j, 1]
            hz = -lz / ll - dirs_world[j, 2]
            hl = np.sqrt(hx * hx + hy * hy + hz * hz)
            if u[2, i] < p_shiny or (hx * normal[j, 0] + hy * normal[j, 1] + hz * normal[j, 2]) > cos_cone * hl:
                b |= _B_SHINY
        bits[i] = b
        zj = np.float64(z[j])
        disparity = fb / zj
        if axial > 0.0:
            sigma = 0.0012 + 0.0019 * (zj - 0.4) ** 2
            if cos_c < cos_60:  # θ > 60°: Nguyen's eq. 6 (θ clipped at 89°)
                theta_c = min(np.arccos(cos_c), np.radians(89.0))
                sigma += 0.0001 / np.sqrt(zj) * theta_c**2 / (half_pi - theta_c) ** 2
            quant = zj * zj * q / fb
            var = sigma * sigma - quant * quant / 12.0 - unit * unit / 12.0
            disparity += noise[i] * np.sqrt(max(var, 0.0)) * fb / (zj * zj)
        steps = np.rint(disparity / q)
        if steps > 0.0:
            value = fb / (steps * q)
            if unit > 0.0:
                value = np.rint(value / unit) * unit
            out[i] = value
        else:  # a disparity rounded to 0 (never within 4.5 m) is beyond the sensor's range
            bits[i] |= _B_RANGE
    return bits, out
def _rotate_rows(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) float32 rows of ``v`` rotated by the (3, 3) ``R`` (``v @ R.T``) without BLAS: a (N, 3) @ (3, 3)
    sgemm hands 3-wide rows to threads and stalls on a busy 2-core box (6 ms vs 20–100 ms measured)."""
    R = R.astype(np.float32)
    out = np.empty(v.shape, np.float32)
    for k in range(3):
        np.multiply(v[:, 0], R[k, 0], out=out[:, k])
        out[:, k] += v[:, 1] * R[k, 1]
        out[:, k] += v[:, 2] * R[k, 2]
    return out


def _dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) row-wise dot product of two (N, 3) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def capture_kinect_depth(
    raycaster: SceneRaycaster, T_world_from_cam: RigidTransform, t_s: float, config: KinectConfig, rng: np.random.Generator
) -> KinectDepthCapture:
    """Simulate one Kinect depth image of the scene at time ``t_s`` from the true camera pose.

    Args:
        raycaster: the scene. T_world_from_cam: the (colour = depth) camera's true pose.
        t_s: scene time in seconds. config: the sensor. rng: all randomness of this frame.

    Returns:
        A :class:`KinectDepthCapture` (model in the module docstring).
    """
    intr = config.intrinsics
    h, w = intr.shape
    n = h * w
    dirs_cam, ray_len = _rays(intr)
    dirs_world = _rotate_rows(T_world_from_cam.rotation, dirs_cam)
    origin = T_world_from_cam.translation
    hits = raycaster.cast(origin, dirs_world, t_s)
    dist = hits.distance_m
    z_hit = (dist / ray_len).astype(np.float32)  # inf for misses
    true_valid = hits.hit & (z_hit >= config.min_depth_m) & (z_hit <= config.max_depth_m)

    # 1. Lateral noise: pixels near an edge look through a jittered pixel ``src``.
    src = np.arange(n)
    z = z_hit
    zone = np.flatnonzero(_dilate(_jumps(z_hit.reshape(h, w), config.edge_rel_jump), _LATERAL_ZONE_PX))
    if config.lateral_noise and zone.size:
        cos_zone = np.abs(_dot_rows(hits.normal[zone], dirs_world[zone]))
        sigma = nguyen_lateral_sigma_px(np.arccos(np.clip(cos_zone, 0.0, 1.0)))
        du, dv = np.clip(np.rint(rng.standard_normal((2, zone.size)) * sigma), -_MAX_LATERAL_PX, _MAX_LATERAL_PX).astype(np.int64)
        rows, cols = np.divmod(zone, w)
        src[zone] = np.clip(rows + dv, 0, h - 1) * w + np.clip(cols + du, 0, w - 1)
        z = z_hit.copy()
        z[zone] = z_hit[src[zone]]
    hit = np.isfinite(z)

    # 2.–3. Range and discontinuities.
    dropout = np.zeros(n, np.uint8)
    dropout[~hit] = DROPOUT_BITS["no_surface"]
    in_range = (z >= config.min_depth_m) & (z <= config.max_depth_m)
    dropout[hit & ~in_range] |= DROPOUT_BITS["range"]
    if config.edge_hole_px > 0:
        edge = _dilate(_jumps(z.reshape(h, w), config.edge_rel_jump), config.edge_hole_px - 1).reshape(-1)
        dropout[edge & hit] |= DROPOUT_BITS["edge"]

    # 4. Projector shadow, on every surface point in range (``sc``: the pixel each candidate looks through).
    cand = np.flatnonzero(in_range)
    sc = src[cand]
    projector = T_world_from_cam.apply(np.array([config.projector_baseline_m, 0.0, 0.0]))
    rays, cos_proj = _projector_rays(sc, dirs_world, dist, hits.normal, (origin - projector).astype(np.float32),
                                     projector.astype(np.float32), np.float32(config.shadow_tolerance_m))
    shadow = (cos_proj <= 0.0) | _occluded(raycaster, rays, t_s)

    # 5.–7. Grazing, materials, then axial noise and disparity quantisation (one pass; draws i.i.d.).
    u = rng.random((4, cand.size), dtype=np.float32)
    noise = rng.standard_normal(cand.size, dtype=np.float32)
    bits, measured = _dropouts_and_depth(
        sc, z_hit, hits.normal, dirs_world, hits.flags, rays, cos_proj, shadow, u, noise,
        np.array([np.radians(config.grazing_start_deg), np.radians(config.grazing_stop_deg), config.dark_dropout,
                  config.shiny_dropout, config.emissive_dropout, np.cos(np.radians(config.specular_cone_deg)),
                  config.fb_px_m, config.disparity_step_px, config.depth_unit_m or 0.0, float(config.axial_noise)]),
    )
    dropout[cand] |= bits
    keep = dropout[cand] == 0
    depth = np.zeros(n, np.float32)
    depth[cand[keep]] = measured[keep]

    return KinectDepthCapture(
        depth_m=depth.reshape(h, w),
        known=(dropout == 0).reshape(h, w),
        dropout=dropout.reshape(h, w),
        true_depth_m=np.where(true_valid, z_hit, np.float32(0.0)).reshape(h, w),
        true_valid=true_valid.reshape(h, w),
        true_normals_cam=_rotate_rows(T_world_from_cam.rotation.T, hits.normal).reshape(h, w, 3),
        object_index=hits.object_index.reshape(h, w).astype(np.int16),
        flags=hits.flags.reshape(h, w),
        radiance=hits.radiance.reshape(h, w, 3),
        source_index=src.astype(np.int32).reshape(h, w),
    )


def _expose(radiance: np.ndarray, state: AutoExposureState, config: ColourCameraConfig, rng: np.random.Generator):
    """(H, W, 3) radiance → ((H, W, 3) uint8 sRGB, (3,) gains used, next AE state); as capture_colour."""
    h, w, _ = radiance.shape
    flat = np.ascontiguousarray(radiance.reshape(-1, 3), dtype=np.float32)
    n_values = flat.size
    if n_values > NOISE_BANK_SIZE:
        noise = rng.standard_normal(n_values, dtype=np.float32)
    else:
        offset = int(rng.integers(0, NOISE_BANK_SIZE))
        noise = noise_bank()[offset:offset + n_values]
    srgb8 = expose_quantise(flat, state.gains.astype(np.float32), np.float32(config.shot_noise),
                             np.float32(config.read_noise**2), noise, SRGB8_LUT).reshape(h, w, 3)
    s = config.meter_stride
    return srgb8, state.gains, state.update(radiance[::s, ::s].reshape(-1, 3).astype(np.float64), config)


@dataclass(frozen=True)
class KinectFrame:
    """One simulated Kinect frame (registered depth + colour) with the truth behind it.

    The first five fields are those of ``rgbd_envmap.tum.TumFrame``, so a simulated run can be written
    with ``write_tum_sequence`` directly.

    Attributes:
        timestamp_ns: capture time (depth and colour are synchronous), whole microseconds.
        rgb: (H, W, 3) uint8 sRGB colour image.
        depth_m: (H, W) float32 measured z-depth in metres; 0 where not ``known``.
        known: (H, W) bool, a measurement exists.
        T_world_from_cam: the *reported* pose of the camera (tracking noise, if any), frames ("world", "colour").
        true_T_world_from_cam: the true pose.
        true_depth_m, true_valid, true_normals_cam, dropout, object_index, flags, source_index: as in
            :class:`KinectDepthCapture` (normals in the camera frame).
        radiance: (H, W, 3) float32 true linear radiance. gains: (3,) float64 true colour gains
            (exposure × white balance) of this frame.
        t_s: scene time in seconds. index: frame number.
    """

    timestamp_ns: int
    rgb: np.ndarray
    depth_m: np.ndarray
    known: np.ndarray
    T_world_from_cam: RigidTransform
    true_T_world_from_cam: RigidTransform
    true_depth_m: np.ndarray
    true_valid: np.ndarray
    true_normals_cam: np.ndarray
    dropout: np.ndarray
    object_index: np.ndarray
    flags: np.ndarray
    radiance: np.ndarray
    source_index: np.ndarray
    gains: np.ndarray
    t_s: float
    index: int


class KinectSimulator:
    """Simulates a Kinect-like camera moving along ``trajectory`` (which moves the camera) through ``scene``.

    Args:
        scene, trajectory: what is seen and how the camera moves.
        config: the sensor (default :class:`KinectConfig`).
        seed: all randomness derives from it (per frame and stream).
        start_ns: timestamp of frame 0; must be a whole microsecond.
    """

    def __init__(self, scene: Scene, trajectory: Trajectory, config: KinectConfig | None = None, seed: int = 0,
                 start_ns: int = 1_000_000_000) -> None:
        self.scene = scene
        self.trajectory = trajectory
        self.config = config or KinectConfig()
        self.seed = int(seed)
        self.start_ns = int(start_ns)
        if self.start_ns < 0 or self.start_ns % 1000:
            raise InvalidInputError(f"start_ns: expected a whole microsecond >= 0, got {start_ns}")
        self.raycaster = SceneRaycaster(scene)
        self.calibration = self.config.calibration()

    def _rng(self, stream: int, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, stream, index])

    def schedule(self, duration_s: float) -> list[int]:
        """Timestamps (ns) of the frames in [0, duration_s): frame i at i / rate_hz, rounded to 1 µs."""
        count = int(np.ceil(duration_s * self.config.rate_hz - 1e-9))
        return [self.start_ns + 1000 * round(i * 1e6 / self.config.rate_hz) for i in range(max(count, 0))]

    def true_pose(self, t_s: float) -> RigidTransform:
        """True ``T_world_from_cam`` (the colour camera = the registered depth camera) at ``t_s``."""
        return RigidTransform(self.trajectory.pose(t_s).matrix, *_FRAMES)

    def run(self, duration_s: float) -> Iterator[KinectFrame]:
        """Yield the frames of the first ``duration_s`` seconds in time order."""
        state = AutoExposureState()
        for index, timestamp_ns in enumerate(self.schedule(duration_s)):
            t_s = (timestamp_ns - self.start_ns) * 1e-9
            T_true = self.true_pose(t_s)
            cap = capture_kinect_depth(self.raycaster, T_true, t_s, self.config, self._rng(_DEPTH, index))
            rgb, gains, state = _expose(cap.radiance, state, self.config.colour, self._rng(_COLOUR, index))
            yield KinectFrame(
                timestamp_ns=timestamp_ns, rgb=rgb, depth_m=cap.depth_m, known=cap.known,
                T_world_from_cam=self.config.reported(T_true, self._rng(_TRACKING, index)),
                true_T_world_from_cam=T_true, true_depth_m=cap.true_depth_m, true_valid=cap.true_valid,
                true_normals_cam=cap.true_normals_cam, dropout=cap.dropout, object_index=cap.object_index,
                flags=cap.flags, radiance=cap.radiance, source_index=cap.source_index, gains=np.asarray(gains, dtype=np.float64), t_s=t_s, index=index,
            )
