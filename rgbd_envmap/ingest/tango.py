"""Tango ingest (paper 003 §4.1): a ToF point cloud and an NV21 colour image → an RGB-D frame.

Per depth packet:

1. **Depth image.** Each point (depth sensor frame) goes through the depth sensor's own distortion and
   intrinsics to its nearest pixel of the 224×172 frame. Points with confidence < 0.7 are unknown and
   take part in nothing; among the confident points landing on one pixel, the closest (smallest z) wins.
2. **Colour.** Each winning point goes to the colour camera frame (``T_colour_from_depth``), through
   the colour camera's Brown distortion and intrinsics, and takes the bilinear interpolation of the four
   surrounding pixels *after* sRGB decoding (interpolating encoded values would bias colours dark).
   A pixel is **known** only when its point also lands inside the colour image: depth without colour
   can feed neither the colour correction nor the environment map.
3. **Filled pixels** (after hole filling) get their colour the same way, from the 3-D point their
   estimated depth gives (as the authors' implementation does): :func:`colour_filled_pixels`.

``T_colour_from_depth`` comes either from the calibration (the paper: both sensors fire together) or,
by default, from the two packets' poses, ``inv(T_world_from_colour) @ T_world_from_depth``, which also
undoes device motion between the depth packet and the nearest colour frame.

The work is numba kernels on one thread (:mod:`rgbd_envmap._kernels.tango`), split into passes so
that the arithmetic runs as SIMD code: both projections of every point in one branch-free pass, then
the z-buffer, then the bilinear lookups (scatter and gather, scalar). The arithmetic is the same IEEE
sequence as one plain per-point loop, :func:`rgbd_envmap.reference.tango.rgbd_frame_reference`, so
the results are bit for bit those of that loop (tested); projection matches
:func:`rgbd_envmap.geometry.project_points` and OpenCV (tested). benchmarks/bench_ingest.py times it.

References:
    Monroy, Hudon, Smolic (2018), §4.1 (RGB-D image), §4.2 (hole filling, colour of filled pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap._kernels import tango as kernels
from rgbd_envmap.checks import check_array, check_instance, check_method, check_number
from rgbd_envmap.colour.nv21 import decode_nv21, srgb8_to_linear_lut
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, Intrinsics, RGBDFrame, RigidTransform, check_transform

__all__ = [
    "TangoIngestConfig",
    "DepthImage",
    "depth_image_from_points",
    "colour_at_points",
    "decode_colour",
    "colour_registration",
    "registration_matrix",
    "rgbd_frame_from_packets",
    "colour_filled_pixels",
    "colour_filled",
    "REGISTRATION_METHODS",
    "TangoIngestResult",
    "ingest_tango",
]

REGISTRATION_METHODS = ("poses", "extrinsics")


@dataclass(frozen=True)
class TangoIngestConfig:
    """Settings of the point-cloud → RGB-D stage (paper defaults)."""

    #: points below this confidence are unknown (paper §4.1: 0.7).
    confidence_threshold: float = 0.7
    #: "poses": T_colour_from_depth from the packets' poses; "extrinsics": from the calibration.
    registration: str = "poses"
    #: method names of :func:`rgbd_envmap.depth.mark_reliable` and :func:`rgbd_envmap.depth.fill_holes`;
    #: ``fill_method=None`` switches hole filling off.
    reliability_method: str = "noise_model"
    fill_method: str | None = "monroy2018"
    #: "monroy2018" only (the other methods ignore it): holes whose eq. (1) sources span depths with
    #: max / min above this are flagged (:attr:`TangoIngestResult.across_edges`; None: none). Their
    #: depth lies between a foreground and a background, and the capture projects them only from
    #: inside its trusted sphere, where such a depth error barely moves them as seen from the origin
    #: (:meth:`rgbd_envmap.pipeline.capture.EnvironmentCapture.process`; docs/design/hole_filling.md).
    fill_max_source_ratio: float | None = 1.5
    #: edge-aware plane-fit denoising of the measured depth before anything else uses it
    #: (:func:`rgbd_envmap.depth.denoise.denoise_frame`, a departure from the paper): the half-width
    #: of its window, or None for the paper's raw depth. 2 (5×5) gives the best map on the default
    #: session, ahead of 3×3 and 7×7 (docs/studies/em_error_study.md).
    denoise_half_window: int | None = 2
    #: the denoiser's inlier tolerance and fewest inliers (``tol_rel``, ``min_inliers`` of
    #: :func:`rgbd_envmap.depth.denoise.denoise_frame`; the function's defaults are 0.04 and 6).
    #: 0.05 suits the 5×5 window better than the function's 0.04 (docs/studies/em_error_study.md).
    denoise_tol_rel: float = 0.05
    denoise_min_inliers: int = 6

    def __post_init__(self) -> None:
        name = "TangoIngestConfig."
        check_number(self.confidence_threshold, name + "confidence_threshold", low=0.0, high=1.0)
        check_method(self.registration, REGISTRATION_METHODS, name + "registration")
        # Checked here, not at the first frame: an unknown name fails when the config is made.
        from rgbd_envmap.depth import FILL_METHODS, RELIABILITY_METHODS  # the depth package imports nothing of ingest

        check_method(self.reliability_method, RELIABILITY_METHODS, "TangoIngestConfig.reliability_method")
        if self.fill_method is not None:
            check_method(self.fill_method, FILL_METHODS, "TangoIngestConfig.fill_method")
        # The denoiser's window is (2 half + 1)²; past 32 the kernel's per-pixel fit is pointless.
        check_number(self.denoise_half_window, name + "denoise_half_window", low=1, high=32, integer=True, optional=True)
        check_number(self.denoise_tol_rel, name + "denoise_tol_rel", low=0.0, high=1.0, low_open=True, high_open=True)
        check_number(self.denoise_min_inliers, name + "denoise_min_inliers", low=3, integer=True)
        check_number(self.fill_max_source_ratio, name + "fill_max_source_ratio", low=1.0, optional=True)

    def fill(self, depth_m: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hole filling with ``fill_method`` (not None): (depth, known_after, across_edges), the last
        all False unless the method is "monroy2018" and ``fill_max_source_ratio`` is set."""
        from rgbd_envmap.depth import fill_holes, fill_holes_flagged  # the depth package imports nothing of ingest

        if self.fill_method == "monroy2018" and self.fill_max_source_ratio is not None:
            return fill_holes_flagged(depth_m, known, self.fill_max_source_ratio)
        depth, after = fill_holes(depth_m, known, method=self.fill_method)
        return depth, after, np.zeros(after.shape, bool)


@dataclass(frozen=True)
class DepthImage:
    """A point cloud rasterised into its sensor's image.

    Attributes:
        depth_m: (H, W) float32 z-depth in metres; 0 where not ``known``.
        known: (H, W) bool, a confident point landed here.
        point_index: (H, W) int32 index of the winning point, −1 where not ``known``.
    """

    depth_m: np.ndarray
    known: np.ndarray
    point_index: np.ndarray


#: (intrinsics, (fx, fy, cx, cy), distortion) of the cameras last seen; the frozen Intrinsics is held,
#: so its id cannot be reused while it is here.
_CAMERAS: dict[int, tuple[Intrinsics, np.ndarray, np.ndarray]] = {}


def _camera_arrays(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    hit = _CAMERAS.get(id(intr))
    if hit is not None and hit[0] is intr:
        return hit[1], hit[2]
    cam, dist = np.array([intr.fx, intr.fy, intr.cx, intr.cy]), intr.distortion.coefficients
    if len(_CAMERAS) >= 8:
        _CAMERAS.clear()
    _CAMERAS[id(intr)] = (intr, cam, dist)
    return cam, dist


#: Per-point scratch of the point-cloud kernels, reused between packets (grown on demand). Each public
#: function fills and reads it within one kernel call, and the kernels hold the GIL (no ``nogil``), so
#: two threads never use it at once.
_SCRATCH: dict[str, np.ndarray] = {}


def _scratch(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pix int32, off int32, wu float64, wv float64), each of length ≥ n, sliced to n."""
    if _SCRATCH.get("pix") is None or len(_SCRATCH["pix"]) < n:
        size = max(n, 1)
        _SCRATCH.update(pix=np.empty(size, np.int32), off=np.empty(size, np.int32), wu=np.empty(size), wv=np.empty(size))
    return _SCRATCH["pix"][:n], _SCRATCH["off"][:n], _SCRATCH["wu"][:n], _SCRATCH["wv"][:n]


_LUT64: list[np.ndarray] = []


def _lut64() -> np.ndarray:
    """:func:`srgb8_to_linear_lut` widened to float64 (exact): the interpolation runs in float64, and
    loading doubles saves twelve conversions per pixel."""
    if not _LUT64:
        _LUT64.append(srgb8_to_linear_lut().astype(np.float64))
    return _LUT64[0]


_INT32_LIMIT = 2**31 - 1


def _check_index_range(intr: Intrinsics, name: str, channels: int = 1) -> None:
    """The kernels index pixels with int32 (SIMD-friendly); refuse an absurdly large image."""
    if intr.width * intr.height * channels > _INT32_LIMIT:
        raise InvalidInputError(f"{name}: expected fewer than 2³¹ pixel values, got {intr.width}×{intr.height}×{channels}")


_FRAME_FIELDS = ("rgb", "depth_m", "known", "T_world_from_cam", "intrinsics", "timestamp_ns", "clipped")


_NO_CONFIG = object()


def _check_packets(depth_packet: object, T_world_from_colour: object, calibration: object,
                   config: object = _NO_CONFIG) -> None:
    """The ingest's packet arguments: a DepthPacket, a pose into the world of the colour camera, a
    Calibration and (if given) a TangoIngestConfig. About 1 µs."""
    check_instance(depth_packet, DepthPacket, "depth_packet")
    check_transform(T_world_from_colour, "T_world_from_colour", "world", "colour")
    check_instance(calibration, Calibration, "calibration")
    if config is not _NO_CONFIG:
        check_instance(config, TangoIngestConfig, "config")


def _owned_frame(rgb: np.ndarray, depth_m: np.ndarray, known: np.ndarray, T_world_from_cam: RigidTransform,
                 intrinsics: Intrinsics, timestamp_ns: int) -> RGBDFrame:
    """An :class:`RGBDFrame` of arrays a kernel here just allocated, with the shapes and dtypes the
    frame requires, referenced nowhere else: they are made read-only and taken as they are, where
    ``RGBDFrame.__post_init__`` would copy each twice (``astype`` then a frozen copy), twice per
    packet. The same object as ``RGBDFrame(...)`` builds (tested)."""
    h, w = intrinsics.height, intrinsics.width
    if not (rgb.shape == (h, w, 3) and rgb.dtype == np.float32 and depth_m.shape == (h, w) and depth_m.dtype == np.float32
            and known.shape == (h, w) and known.dtype == np.bool_):  # never: the kernels allocate these
        return RGBDFrame(rgb, depth_m, known, T_world_from_cam, intrinsics, timestamp_ns)
    frame = object.__new__(RGBDFrame)
    for name, value in zip(_FRAME_FIELDS, (rgb, depth_m, known, T_world_from_cam, intrinsics, int(timestamp_ns), None)):
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        object.__setattr__(frame, name, value)
    return frame


def depth_image_from_points(
    points_m: np.ndarray, confidence: np.ndarray, intrinsics: Intrinsics, confidence_threshold: float = 0.7
) -> DepthImage:
    """Rasterise (N, 3) depth-frame points with (N,) confidence into an (H, W) depth image.

    Non-finite points, points at z ≤ 0 and points projecting outside the image are dropped; so are
    points with confidence below ``confidence_threshold`` (or NaN). Closest z wins a shared pixel.
    """
    check_instance(intrinsics, Intrinsics, "intrinsics")
    pts = check_array(points_m, "points_m", shape=("N", 3), dtype="float")
    conf = check_array(confidence, "confidence", shape=(pts.shape[0],), dtype=("float", "int"))
    confidence_threshold = check_number(confidence_threshold, "confidence_threshold", low=0.0, high=1.0)
    _check_index_range(intrinsics, "intrinsics")
    cam, dist = _camera_arrays(intrinsics)
    pts = np.ascontiguousarray(pts)
    depth, index = kernels.depth_image_kernel(pts, np.ascontiguousarray(conf), float(confidence_threshold), cam, dist,
                                       intrinsics.height, intrinsics.width, _scratch(len(pts))[0])
    return DepthImage(depth, index >= 0, index)


def _sample(points: np.ndarray, T_colour_from_depth: RigidTransform, intr: Intrinsics, img: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear linear colour of C-contiguous (N, 3) points: (rgb (N, 3) float32, seen (N,) bool)."""
    cam, dist = _camera_arrays(intr)
    _, off, wu, wv = _scratch(len(points))
    return kernels.colour_kernel(points, np.ascontiguousarray(T_colour_from_depth.rotation),
                          np.ascontiguousarray(T_colour_from_depth.translation), cam, dist, img, _lut64(), off, wu, wv)


def colour_at_points(
    points_m: np.ndarray, srgb8: np.ndarray, T_colour_from_depth: RigidTransform, colour_intrinsics: Intrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Linear colour of (N, 3) depth-frame points, bilinear in the (H, W, 3) uint8 sRGB colour image.

    Returns ``(rgb (N, 3) float32 linear, valid (N,) bool)``; invalid points (behind the colour camera,
    outside its image, non-finite) have zero colour.
    """
    check_instance(colour_intrinsics, Intrinsics, "colour_intrinsics")
    check_transform(T_colour_from_depth, "T_colour_from_depth", "colour", "depth")
    pts = check_array(points_m, "points_m", shape=("N", 3), dtype="float")
    img = check_array(srgb8, "srgb8", shape=(colour_intrinsics.height, colour_intrinsics.width, 3), dtype=np.uint8)
    _check_index_range(colour_intrinsics, "colour_intrinsics", 3)
    return _sample(np.ascontiguousarray(pts), T_colour_from_depth, colour_intrinsics, np.ascontiguousarray(img))


def decode_colour(packet: ColourPacket) -> np.ndarray:
    """(H, W, 3) uint8 sRGB image of a colour packet (NV21 decode)."""
    check_instance(packet, ColourPacket, "packet")
    return decode_nv21(packet.nv21, packet.height, packet.width)


#: The last "poses" registration: [T_world_from_colour, T_world_from_depth, 4×4 matrix, RigidTransform
#: or None]. Both keys are immutable (frozen, read-only matrix) and held here, so identity means equal
#: inputs. The pipeline needs the registration twice per packet: its matrix in the ingest, the
#: RigidTransform for the colour of filled pixels. Inverse and product are computed once, and the
#: RigidTransform (whose checks cost more than the product) only when asked for.
_LAST_REGISTRATION: list[list] = []


def _registration_matrix(depth_packet: DepthPacket, T_world_from_colour: RigidTransform) -> list:
    T_world_from_depth = depth_packet.T_world_from_depth
    if _LAST_REGISTRATION:
        entry = _LAST_REGISTRATION[0]
        if entry[0] is T_world_from_colour and entry[1] is T_world_from_depth:
            return entry
    m = np.linalg.inv(T_world_from_colour.matrix) @ T_world_from_depth.matrix
    entry = [T_world_from_colour, T_world_from_depth, m, None]
    if isinstance(T_world_from_colour, RigidTransform) and isinstance(T_world_from_depth, RigidTransform):
        _LAST_REGISTRATION[:] = [entry]
    return entry


def colour_registration(
    depth_packet: DepthPacket, T_world_from_colour: RigidTransform, calibration: Calibration, method: str = "poses"
) -> RigidTransform:
    """``T_colour_from_depth`` for one depth packet and one colour frame (see module docstring)."""
    _check_packets(depth_packet, T_world_from_colour, calibration)
    check_method(method, REGISTRATION_METHODS, "registration")
    if method == "extrinsics":
        return calibration.T_colour_from_depth
    entry = _registration_matrix(depth_packet, T_world_from_colour)
    if entry[3] is None:
        entry[3] = RigidTransform(entry[2], "colour", "depth")
    return entry[3]


def rgbd_frame_from_packets(
    depth_packet: DepthPacket,
    srgb8: np.ndarray,
    T_world_from_colour: RigidTransform,
    calibration: Calibration,
    config: TangoIngestConfig = TangoIngestConfig(),
) -> tuple[RGBDFrame, DepthImage]:
    """The RGB-D frame of a depth packet and its (decoded) colour frame.

    Returns the frame (known pixels carry depth and linear colour; pixels whose point falls outside
    the colour image are unknown) and the :class:`DepthImage` behind it (depth-only knowledge).
    """
    _check_packets(depth_packet, T_world_from_colour, calibration, config)
    dc, cc = calibration.depth, calibration.colour
    pts = check_array(depth_packet.points_m, "points_m", shape=("N", 3), dtype="float")
    conf = check_array(depth_packet.confidence, "confidence", shape=(pts.shape[0],), dtype=("float", "int"))
    img = check_array(srgb8, "srgb8", shape=(cc.height, cc.width, 3), dtype=np.uint8)
    _check_index_range(dc, "calibration.depth")
    _check_index_range(cc, "calibration.colour", 3)
    if config.registration == "poses":  # the matrix only; the RigidTransform when someone asks for it
        m = _registration_matrix(depth_packet, T_world_from_colour)[2]
    else:
        m = colour_registration(depth_packet, T_world_from_colour, calibration, config.registration).matrix
    dcam, ddist = _camera_arrays(dc)
    ccam, cdist = _camera_arrays(cc)
    pts = np.ascontiguousarray(pts)
    raw, index, raw_known, depth, known, rgb = kernels.rgbd_kernel(
        pts, np.ascontiguousarray(conf), float(config.confidence_threshold), dcam, ddist, dc.height, dc.width,
        m, ccam, cdist, np.ascontiguousarray(img), _lut64(), *_scratch(len(pts)),
    )
    frame = _owned_frame(rgb, depth, known, depth_packet.T_world_from_depth, dc, depth_packet.timestamp_ns)
    return frame, DepthImage(raw, raw_known, index)


def colour_filled_pixels(
    frame: RGBDFrame,
    filled_depth_m: np.ndarray,
    filled_known: np.ndarray,
    srgb8: np.ndarray,
    T_colour_from_depth: RigidTransform,
    colour_intrinsics: Intrinsics,
) -> RGBDFrame:
    """A new frame with the hole-filled depth, whose newly known pixels take the colour seen at the 3-D
    point of their estimated depth. Pixels known before keep depth and colour unchanged; filled pixels
    whose point the colour camera does not see stay unknown."""
    check_transform(T_colour_from_depth, "T_colour_from_depth", "colour", "depth")
    return colour_filled(frame, filled_depth_m, filled_known, srgb8, T_colour_from_depth.matrix, colour_intrinsics)


def colour_filled(frame: RGBDFrame, filled_depth_m: np.ndarray, filled_known: np.ndarray, srgb8: np.ndarray,
                  colour_from_depth: np.ndarray, colour_intrinsics: Intrinsics) -> RGBDFrame:
    """:func:`colour_filled_pixels` with the registration as a (4, 4) ``T_colour_from_depth`` matrix
    (:func:`registration_matrix`): the pipeline has the matrix from the ingest and skips building a
    checked ``RigidTransform`` every depth frame. The matrix is checked for its shape only."""
    check_instance(frame, RGBDFrame, "frame")
    check_instance(colour_intrinsics, Intrinsics, "colour_intrinsics")
    colour_from_depth = check_array(colour_from_depth, "colour_from_depth", shape=(4, 4), dtype="float")
    h, w = frame.intrinsics.height, frame.intrinsics.width
    depth = check_array(filled_depth_m, "filled_depth_m", shape=(h, w), dtype="float")
    known = check_array(filled_known, "filled_known", shape=(h, w), dtype="bool")
    img = check_array(srgb8, "srgb8", shape=(colour_intrinsics.height, colour_intrinsics.width, 3), dtype=np.uint8)
    _check_index_range(colour_intrinsics, "colour_intrinsics", 3)
    cam, dist = _camera_arrays(colour_intrinsics)
    rgb, out_depth, known_after = kernels.filled_kernel(
        frame.rgb, frame.depth_m, frame.known, np.ascontiguousarray(depth), np.ascontiguousarray(known),
        pixel_rays(frame.intrinsics), np.ascontiguousarray(colour_from_depth[:3, :3]),
        np.ascontiguousarray(colour_from_depth[:3, 3]), cam, dist, np.ascontiguousarray(img), _lut64(),
    )
    return _owned_frame(rgb, out_depth, known_after, frame.T_world_from_cam, frame.intrinsics, frame.timestamp_ns)


def registration_matrix(depth_packet: DepthPacket, T_world_from_colour: RigidTransform, calibration: Calibration,
                        method: str = "poses") -> np.ndarray:
    """:func:`colour_registration` as a (4, 4) matrix, without building the ``RigidTransform`` for the
    "poses" method (the same matrix ``rgbd_frame_from_packets`` uses, cached for the last pair of poses)."""
    _check_packets(depth_packet, T_world_from_colour, calibration)
    check_method(method, REGISTRATION_METHODS, "registration")
    if method == "extrinsics":
        return calibration.T_colour_from_depth.matrix
    return _registration_matrix(depth_packet, T_world_from_colour)[2]


@dataclass(frozen=True)
class TangoIngestResult:
    """Everything the ingest of one depth packet produces.

    Attributes:
        frame: the RGB-D frame before hole filling (only confident points are known).
        reliable: (H, W) bool, pixels fit for colour-correction pairs (marked before hole filling).
        filled: the frame after hole filling, filled pixels coloured from their estimated 3-D point
            (``frame`` itself when hole filling is off).
        T_colour_from_depth: the registration used.
        across_edges: (H, W) bool, filled pixels whose eq. (1) sources lie on both sides of a depth
            edge (``TangoIngestConfig.fill_max_source_ratio``); pass it to the capture.
    """

    frame: RGBDFrame
    reliable: np.ndarray
    filled: RGBDFrame
    T_colour_from_depth: RigidTransform
    across_edges: np.ndarray


def ingest_tango(
    depth_packet: DepthPacket,
    srgb8: np.ndarray,
    T_world_from_colour: RigidTransform,
    calibration: Calibration,
    config: TangoIngestConfig = TangoIngestConfig(),
) -> TangoIngestResult:
    """Point cloud → RGB-D frame → reliability marking → hole filling → colour of filled pixels.

    ``srgb8`` is the decoded colour frame nearest in time (:func:`decode_colour`), whose pose is
    ``T_world_from_colour``.
    """
    from rgbd_envmap.depth import mark_reliable  # the depth package imports nothing of ingest
    from rgbd_envmap.depth.denoise import denoise_frame

    _check_packets(depth_packet, T_world_from_colour, calibration, config)

    frame, _ = rgbd_frame_from_packets(depth_packet, srgb8, T_world_from_colour, calibration, config)
    if config.denoise_half_window is not None:
        frame = denoise_frame(frame, half_window=config.denoise_half_window, tol_rel=config.denoise_tol_rel,
                              min_inliers=config.denoise_min_inliers)
    reliable = mark_reliable(frame.rgb, frame.depth_m, frame.known, method=config.reliability_method)
    T_cd = colour_registration(depth_packet, T_world_from_colour, calibration, config.registration)
    if config.fill_method is None:
        return TangoIngestResult(frame, reliable, frame, T_cd, np.zeros(frame.known.shape, bool))
    depth, known, across = config.fill(frame.depth_m, frame.known)
    filled = colour_filled_pixels(frame, depth, known, srgb8, T_cd, calibration.colour)
    return TangoIngestResult(frame, reliable, filled, T_cd, across & filled.known)
